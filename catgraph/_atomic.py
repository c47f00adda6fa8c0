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

__all__ = ["atomic_open", "write_text_atomic", "check_writable"]


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


def check_writable(path: str | os.PathLike, what: str = "output") -> Path:
    """Check, before any work is done, that ``path`` can be written (its folder exists or can
    be created, is writable, and ``path`` is not a folder); return it.

    Raises :class:`~catgraph.exceptions.InvalidParameterError` naming the problem.
    """
    from .exceptions import InvalidParameterError

    path = Path(path)
    if path.is_dir():
        raise InvalidParameterError(f"the {what} {path} is a folder; give a file name.")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InvalidParameterError(f"cannot write the {what} {path}: {folder} is not a folder.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"cannot write the {what} {path}: no permission to write in {folder}.")
    if path.exists() and not os.access(path, os.W_OK) and not os.access(folder, os.W_OK):
        raise InvalidParameterError(f"cannot write the {what} {path}: the file is read-only.")
    return path
