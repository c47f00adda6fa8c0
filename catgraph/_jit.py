"""Compiled kernels that start fast: numba's on-disk cache, always somewhere writable.

A numba kernel compiles the first time it is called with a new signature — seconds
per kernel on a small machine, paid again by every process unless the machine code
is cached on disk (``cache=True``). numba looks for a cache folder in this order:
``NUMBA_CACHE_DIR`` when set, the ``__pycache__`` folder beside the module, then the
user's cache folder (``~/.cache/numba``). Where none of them is writable — an
installed package in a read-only ``site-packages``, a container whose home directory
is read-only — numba refuses to decorate a ``cache=True`` function at all
(``RuntimeError: cannot cache function``), so a library cannot simply ask for caching.

:func:`njit` is ``numba.njit`` with ``cache=True`` and that gap closed: before the
first kernel is decorated it checks that one of numba's own locations is writable
and, if none is, points numba at a private folder in the system's temporary
directory (``catgraph-numba-<user>``; set ``NUMBA_CACHE_DIR`` to choose another).
The compiled code is then reused by every later process on the machine; the first
process still compiles (measured figures: ``benchmarks/results/live.md``).

A package built by ``pip install .`` carries the kernels compiled at build time in its
``__pycache__`` (``setup.py``), where numba finds them only while that folder is writable.
Where it is not (a system ``site-packages``, a container's image run by another user),
:func:`cache_location` copies them once into numba's folder for the package in the cache
it chose instead, so the first run there loads them too.

Every kernel module of the package decorates with it::

    from ._jit import njit

    @njit(nogil=True)
    def kernel(x, out): ...
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["cache_location", "njit"]

_CHECKED = False
#: no folder can be written at all: kernels are compiled without a disk cache
_NOWHERE = False


def _writable(folder: Path) -> bool:
    """Whether ``folder`` exists (or can be made) and a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _numba_user_cache() -> Path | None:
    try:
        from numba.misc.appdirs import AppDirs
    except ImportError:  # pragma: no cover - older numba
        return None
    return Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)


def _package_cache() -> Path:
    """The ``__pycache__`` beside the package's modules: numba's in-tree cache, and where a
    built package carries the kernels compiled at build time."""
    return Path(__file__).resolve().parent / "__pycache__"


def _seed(shipped: Path, cache_root: Path) -> int:
    """Copy the kernels compiled at build time (``shipped``) into numba's folder for this
    package's sources under ``cache_root`` — where numba looks once the package's own
    folder is read-only — each file that is not there yet (data files before their
    indexes); returns how many. numba loads a copied kernel only where its source, the
    numba version and the processor are the ones it was compiled for."""
    import shutil

    try:
        from numba.core.caching import _CacheLocator

        files = sorted((f for f in shipped.iterdir() if f.suffix in (".nbc", ".nbi")), key=lambda f: f.suffix)
        target = cache_root / _CacheLocator.get_suitable_cache_subpath(__file__)  # numba: the module path as imported
    except (ImportError, AttributeError, OSError):
        return 0
    copied = 0
    try:
        for f in files:
            dest = target / f.name
            if not dest.exists():
                target.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(f, dest)
                copied += 1
    except OSError:  # a full or vanished folder: the kernels compile as they would have
        pass
    return copied


def cache_location() -> Path:
    """The folder the package's compiled kernels are cached in (made writable first).

    ``NUMBA_CACHE_DIR`` when set and writable (set but read-only: a
    :class:`~catgraph.exceptions.CatgraphWarning`, and the folders below); else
    ``catgraph/__pycache__`` when writable; else numba's user cache folder when writable;
    else a private folder in the system's temporary directory, which is then handed to
    numba. In the last two the kernels the package was built with are copied in first
    (:func:`_seed`). Where not even that folder can be written, :func:`njit` compiles
    without a disk cache (every process compiles again) rather than fail.
    """
    global _CHECKED, _NOWHERE
    import numba

    if numba.config.CACHE_DIR:
        chosen = Path(numba.config.CACHE_DIR)
        if _writable(chosen):
            _CHECKED = True
            return chosen
        # numba would refuse every cached kernel ("cannot cache function"): a cache folder
        # that cannot be written is not a reason to stop working
        from .exceptions import warn

        numba.config.CACHE_DIR = ""
        where = cache_location()
        warn(f"NUMBA_CACHE_DIR={chosen} cannot be written; compiled kernels are cached in {where} instead "
             f"(point NUMBA_CACHE_DIR at a writable folder, or unset it).")
        return where
    beside = _package_cache()
    if _writable(beside):
        _CHECKED = True
        return beside
    user = _numba_user_cache()
    if user is not None and _writable(user):
        _CHECKED = True
        _seed(beside, user)
        return user
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    private = Path(tempfile.gettempdir()) / f"catgraph-numba-{uid}"
    try:
        private.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        pass
    if not _writable(private):  # not even the temporary folder: the kernels compile in every process
        _NOWHERE = True
        _CHECKED = True
        return private
    numba.config.CACHE_DIR = str(private)
    _CHECKED = True
    _seed(beside, private)
    return private


def njit(*args, **options):
    """``numba.njit`` with ``cache=True`` by default and a writable cache guaranteed.

    Used like ``numba.njit``: ``@njit``, ``@njit(nogil=True)``; ``cache=False`` opts out.
    """
    import numba

    options.setdefault("cache", True)
    if options["cache"] and not _CHECKED:
        cache_location()
    if _NOWHERE:
        options["cache"] = False
    return numba.njit(*args, **options)
