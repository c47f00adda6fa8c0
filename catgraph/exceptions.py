"""Typed exceptions.

Every error catgraph raises for a user's mistake is a :class:`CatgraphError`. Each
subclass also derives from the built-in exception a Python user would expect
(``ValueError``, ``FileNotFoundError`` …), so ``except ValueError`` keeps working. The
command line turns any ``CatgraphError`` into one line on stderr and exit code 1.

Messages name the problem *and* the fix, e.g. ``"The 'n_bins' parameter of
HistogramModel must be an int in the range [2, inf). Got 0 instead."``
"""

from __future__ import annotations

__all__ = [
    "CatgraphError",
    "InvalidParameterError",
    "DataError",
    "DataNotFoundError",
    "ShapeMismatchError",
    "NotFittedError",
    "MapFileError",
    "ConfigError",
    "MissingDependencyError",
    "InsufficientMemoryError",
    "CatgraphWarning",
    "warn",
]


class CatgraphError(Exception):
    """Base class of every error catgraph raises on purpose."""


class InvalidParameterError(CatgraphError, ValueError):
    """A parameter has the wrong type or is out of its range."""


class DataError(CatgraphError, ValueError):
    """Input data is malformed: NaN, wrong shape, unreadable file, missing column."""


class DataNotFoundError(CatgraphError, FileNotFoundError):
    """A path given by the user does not exist or holds no usable data."""


class ShapeMismatchError(DataError):
    """Two arrays that must agree in shape (query vs reference descriptors) do not."""


class NotFittedError(CatgraphError, AttributeError):
    """A model was used before ``fit``/``partial_fit`` gave it its learned state."""


class MapFileError(DataError):
    """A saved map is corrupt, truncated, tampered with or from a newer version."""


class ConfigError(CatgraphError, ValueError):
    """An experiment configuration has unknown keys or values of the wrong type."""


class MissingDependencyError(CatgraphError, ImportError):
    """An optional dependency needed for the requested feature is not installed
    (the message names the extra to install, e.g. ``pip install "catgraph[dask]"``)."""


class InsufficientMemoryError(CatgraphError, MemoryError):
    """A computation would need more memory than the machine has available; raised
    *before* allocating (the message gives the estimate and how to need less)."""


class CatgraphWarning(UserWarning):
    """Something in the input deserves attention but does not stop the run (a frame
    with no information, a timestamp that cannot be read, an option with no effect on
    this input). The command line prints each as one line on stderr."""


def warn(message: str, category: type[Warning] = CatgraphWarning) -> None:
    """Issue a warning at the line of the caller's own code that led to it.

    The first frame outside the catgraph package (import machinery skipped, as
    :func:`warnings.warn` skips it) is where the warning is reported, whatever depth the
    call came from: ``load_traverse`` and ``catgraph.experiment.run`` reach the same loader
    through different paths, and a fixed ``stacklevel`` would name a line of catgraph for
    one of them (Python 3.12's ``skip_file_prefixes`` does this; 3.11 is supported).
    """
    import os
    import sys
    import warnings

    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame = sys._getframe(1)
    while frame is not None and (frame.f_code.co_filename.startswith(package)
                                 or ("importlib" in frame.f_code.co_filename
                                     and "_bootstrap" in frame.f_code.co_filename)):
        frame = frame.f_back
    if frame is None:  # nothing outside catgraph called it
        warnings.warn(message, category, stacklevel=2)
        return
    module_globals = frame.f_globals
    warnings.warn_explicit(message, category, frame.f_code.co_filename, frame.f_lineno,
                           module=module_globals.get("__name__", "<string>"),
                           registry=module_globals.setdefault("__warningregistry__", {}),
                           module_globals=module_globals)
