"""``catgraph`` command line: one parser, one error boundary.

Each sub-command is a thin function that parses its options, calls the public API and
prints or writes the result. :func:`main` is the only place that catches errors: a
:class:`~catgraph.exceptions.CatgraphError` (a user's mistake: a missing folder, a bad
value) or a command line argparse cannot read becomes one line on stderr and exit code
1 — never a traceback or a usage block.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Sequence

from ..exceptions import CatgraphError, CatgraphWarning
from . import commands

__all__ = ["main", "build_parser"]


class _UsageError(Exception):
    """A command line argparse cannot read (reported as one line, exit code 1)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # argparse would print the usage block and exit 2
        raise _UsageError(f"{self.prog.split()[-1] if ' ' in self.prog else ''}: {message}".lstrip(": ")
                          + f" (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="catgraph",
        description="Probabilistic, appearance-based localisation along known routes.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"catgraph {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    commands.load_command_modules()
    for register in commands.REGISTRY:
        register(sub)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning is one line on stderr, like an error (no file name, no source line)."""
    text = " ".join(str(message).split())
    prefix = "" if issubclass(category, CatgraphWarning) else f"{category.__name__}: "
    print(f"catgraph: warning: {prefix}{text}", file=sys.stderr)


#: The commands whose method parameters are command-line options (``bench`` takes them from
#: a configuration, where they keep their names).
_FLAG_COMMANDS = ("match", "localize", "compare")


def _in_option_terms(message: str) -> str:
    """An error about a method parameter (``The 'l_max' parameter of match_sequences …``) in
    the terms of the command line (``--l-max …``), from the method registry's options."""
    import re

    from ..methods import METHODS

    options = {param.name: param.option for method in METHODS.values() for param in method.params}
    message = re.sub(r"The '(\w+)' parameter of [\w.' ]+? must",
                     lambda m: f"{options[m.group(1)]} must" if m.group(1) in options else m.group(0), message)
    # the checks across parameters: "'l_min' (600) is longer than 'l_max' (100)", "'jump_graduation' must …"
    message = re.sub(r"'(\w+)'(?= \(\d| must | below )", lambda m: options.get(m.group(1), m.group(0)), message)
    # "'n_particles' does not apply … leave 'n_particles' out" (the filter's mode decides)
    return re.sub(r"(^|leave )'(\w+)'( does not apply| out)",
                  lambda m: f"{m.group(1)}{options[m.group(2)]}{m.group(3)}" if m.group(2) in options else m.group(0),
                  message)


def _usable_streams() -> None:
    """Standard streams every message can be written to: one the caller closed (``>&-``,
    where Python leaves ``None``) writes to nowhere, and one whose encoding cannot spell a
    character (``≥``, ``×`` under an ASCII or Latin-1 locale) escapes it instead of failing."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is None:
            setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))
            continue
        encoding = (getattr(stream, "encoding", None) or "utf-8").lower().replace("-", "").replace("_", "")
        if encoding != "utf8" and hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    _usable_streams()
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        # ``match REFERENCE --window 5 QUERY``: argparse ends the paths at the first option;
        # the paths after it are the same paths
        if extra and hasattr(args, "inputs") and not any(a.startswith("-") for a in extra):
            args.inputs = [*args.inputs, *extra]
        elif extra:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    except _UsageError as exc:
        print(f"catgraph: error: {exc}", file=sys.stderr)
        return 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.showwarning = _show_warning
            return int(args.func(args) or 0)
    except CatgraphError as exc:
        message = _in_option_terms(str(exc)) if args.command in _FLAG_COMMANDS else str(exc)
        print(f"catgraph: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("catgraph: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # writing an output file: permission denied, disk full …
        print(f"catgraph: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
