"""Atomic file writes: a temporary file in the destination folder, flushed, then renamed
over the destination (``os.replace``), so readers never see half a file and a crash never
destroys the previous version."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

__all__ = ["atomic_open", "write_text_atomic", "check_writable", "check_writable_folder"]


@contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file for writing that replaces ``path`` when the block succeeds.

    The folder is created if needed; the file gets ordinary permissions (0644, or the
    mode of the file it replaces) rather than ``mkstemp``'s private 0600.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else encoding) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, path.stat().st_mode & 0o777 if path.exists() else 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; return the path."""
    with atomic_open(path, "w") as fh:
        fh.write(text)
    return Path(path)


def _spellings(path: str | os.PathLike) -> set[Path]:
    """``path`` as written (absolute) and with every link resolved."""
    return {Path(os.path.abspath(path)), Path(os.path.realpath(path))}


def _overwrites_input(path: Path, inputs) -> str | None:
    """The input that writing ``path`` would destroy: ``path`` is that input file, or an
    existing file inside that input folder (a frame, a CSV of the traverse); else None."""
    out = _spellings(path)
    for given in inputs:
        if given is None or not os.path.exists(given):
            continue  # not a path (``synthetic:0``) or not there: nothing to destroy
        for source in _spellings(given):
            if source in out:
                return str(given)
            if source.is_dir() and path.exists() and any(source in o.parents for o in out):
                return str(given)
    return None


def check_writable(path: str | os.PathLike, what: str = "output", inputs=()) -> Path:
    """Check, before any work is done, that ``path`` can be written (its folder exists or can
    be created, is writable, ``path`` is not a folder) without destroying one of the
    command's ``inputs`` (the file itself, or an existing file inside an input folder);
    return it.

    Raises :class:`~catgraph.exceptions.InvalidParameterError` naming the problem.
    """
    from .exceptions import InvalidParameterError

    path = Path(path)
    if path.is_dir():
        raise InvalidParameterError(f"the {what} {path} is a folder; give a file name.")
    source = _overwrites_input(path, inputs)
    if source is not None:
        inside = "" if Path(source).is_file() else " (a file inside that folder)"
        raise InvalidParameterError(f"the {what} {path} would overwrite the input {source}{inside}; write it "
                                    "elsewhere.")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InvalidParameterError(f"cannot write the {what} {path}: {folder} is not a folder.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"cannot write the {what} {path}: no permission to write in {folder}.")
    if path.exists() and not os.access(path, os.W_OK) and not os.access(folder, os.W_OK):
        raise InvalidParameterError(f"cannot write the {what} {path}: the file is read-only.")
    if folder == path.parent:  # the folder is there: a trial file says what permissions may not (/proc, a full disk)
        _trial_file(folder, f"cannot write the {what} {path}")
    return path


def _trial_file(folder: Path, failure: str) -> None:
    """Create and remove a file in ``folder``; where that fails, an InvalidParameterError
    ``failure: the reason in folder``."""
    from .exceptions import InvalidParameterError

    try:
        fd, trial = tempfile.mkstemp(prefix=".catgraph.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise InvalidParameterError(f"{failure}: {exc.strerror or exc} in {folder}.") from None
    os.close(fd)
    os.unlink(trial)


def check_writable_folder(path: str | os.PathLike, what: str = "output folder") -> Path:
    """Check, before any work is done, that files can be written into the folder ``path``
    (it exists as a folder or can be created, and takes a trial file); return it.

    Raises :class:`~catgraph.exceptions.InvalidParameterError` naming the problem.
    """
    from .exceptions import InvalidParameterError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InvalidParameterError(f"the {what} {path} is a file; give a folder (it is created if missing).")
    folder = path
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InvalidParameterError(f"cannot write into the {what} {path}: {folder} is not a folder.")
    _trial_file(folder, f"cannot write into the {what} {path}")
    return path
