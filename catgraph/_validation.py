"""Checks at the public boundary, and seeding.

Public functions validate here and then call private kernels that trust their inputs
(the networkx pattern). Messages follow scikit-learn's form: what, where, the allowed
range, what was given.

Arrays (:func:`check_array`) must be numeric and real: an array of Python objects, of
strings or of complex numbers is refused rather than silently converted (converting a
complex array to float would drop its imaginary part). Values are checked for NaN and
infinity *after* the conversion to the requested dtype, so a float64 value too large
for float32 is reported rather than becoming ``inf`` downstream.

Memory (:func:`check_memory`): a computation whose size follows from the input (an
``N × N`` matrix, ``n_particles`` arrays) estimates its bytes first and calls
``check_memory(n_bytes, what, fix)``, which refuses with
:class:`~catgraph.exceptions.InsufficientMemoryError` when the estimate exceeds the
memory the machine has available — before allocating, never after the kernel has
killed the process.
"""

from __future__ import annotations

import numbers
import os
from typing import Any

import numpy as np

from .exceptions import DataError, InsufficientMemoryError, InvalidParameterError

__all__ = ["as_generator", "available_memory", "check_array", "check_memory", "check_scalar"]

#: Share of the available memory one computation may plan to use.
MEMORY_FRACTION = 0.8


def as_generator(seed: int | np.random.Generator | None) -> np.random.Generator:
    """Return a ``numpy.random.Generator`` from a seed, a generator or ``None``.

    ``None`` gives a fresh, OS-seeded generator; an int gives a reproducible one; a
    generator is returned as is (shared state, like scikit-learn's ``random_state``).
    """
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or (isinstance(seed, numbers.Integral) and not isinstance(seed, bool)):
        if seed is not None and int(seed) < 0:
            raise InvalidParameterError(f"A seed must be a non-negative int. Got {seed} instead.")
        return np.random.default_rng(seed)
    raise InvalidParameterError(
        f"A seed must be None, a non-negative int or a numpy.random.Generator. Got {seed!r} instead."
    )


def check_scalar(
    value: Any,
    name: str,
    owner: str,
    kind: type | tuple[type, ...],
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> Any:
    """Check a scalar parameter's type and range; return it.

    ``kind`` is ``int`` (any integral, not bool), ``float`` (any real, not bool) or a
    tuple of such. Raises :class:`InvalidParameterError` with a message like
    ``"The 'n_bins' parameter of HistogramModel must be an int in the range [2, inf).
    Got 0 instead."``
    """
    kinds = kind if isinstance(kind, tuple) else (kind,)
    abstract = tuple(numbers.Integral if k is int else numbers.Real if k is float else k for k in kinds)
    type_name = " or ".join("an int" if k is int else "a float" if k is float else k.__name__ for k in kinds)
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    interval = f"{'[' if low_inclusive and low is not None else '('}{lo}, {hi}{']' if high_inclusive and high is not None else ')'}"
    message = f"The '{name}' parameter of {owner} must be {type_name} in the range {interval}. Got {value!r} instead."
    if isinstance(value, bool) or not isinstance(value, abstract):
        raise InvalidParameterError(message)
    if isinstance(value, numbers.Real) and not np.isfinite(float(value)):
        raise InvalidParameterError(message)
    if low is not None and (value < low or (value == low and not low_inclusive)):
        raise InvalidParameterError(message)
    if high is not None and (value > high or (value == high and not high_inclusive)):
        raise InvalidParameterError(message)
    return value


def check_fps(fps) -> float | None:
    """A video's frames kept per second (:attr:`catgraph.pipeline.FrontEnd.fps`,
    :func:`catgraph.datasets.video.load_video`) as a float > 0; ``None`` stays ``None``
    (every frame)."""
    if fps is None:
        return None
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
            or not np.isfinite(float(fps)) or float(fps) <= 0:
        raise InvalidParameterError(f"fps (video frames kept per second) must be a number > 0; got {fps!r}.")
    return float(fps)


def check_array(
    array: Any,
    name: str,
    ndim: int | tuple[int, ...] | None = None,
    dtype: type | None = np.float64,
    allow_empty: bool = False,
    finite: bool = True,
) -> np.ndarray:
    """Convert to an ndarray and check dimensionality, emptiness and finiteness.

    Raises :class:`DataError` naming the array and the problem (``"query descriptors
    contain 3 NaN or infinite values (first at row 12); clean or drop those frames."``).
    """
    try:
        raw = array if isinstance(array, np.ndarray) else np.asarray(array)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} could not be read as a numeric array: {exc}") from None
    if raw.dtype == object:
        raise DataError(f"{name} must be a numeric array, not an array of Python objects.")
    if np.issubdtype(raw.dtype, np.complexfloating):
        raise DataError(
            f"{name} hold complex numbers (dtype {raw.dtype}); catgraph needs real values. "
            "Pass the magnitude (np.abs) or the real part (.real) explicitly."
        )
    if raw.dtype.kind not in "biuf":
        raise DataError(f"{name} must be a numeric array; got dtype {raw.dtype}.")
    if dtype is None or raw.dtype == dtype:
        out = raw
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            out = raw.astype(dtype, copy=False)
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if out.ndim not in allowed:
            raise DataError(f"{name} must have {' or '.join(map(str, allowed))} dimensions; got shape {out.shape}.")
    if not allow_empty and out.size == 0:
        raise DataError(f"{name} is empty (shape {out.shape}); at least one frame is needed.")
    if finite and out.dtype.kind == "f" and not np.isfinite(out).all():
        bad = ~np.isfinite(out)
        first = int(np.argwhere(bad)[0][0]) if out.ndim else 0
        where = (f" (first at row {first})" if out.ndim > 1 else f" (first at index {first})") if out.ndim else ""
        converted = (
            f" after conversion to {np.dtype(dtype).name}"
            if dtype is not None and raw.dtype.kind == "f" and np.all(np.isfinite(raw)) else ""
        )
        raise DataError(
            f"{name} holds {int(bad.sum())} NaN or infinite values{converted}{where}; "
            "clean or drop those frames before localising."
        )
    return out


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``), or
    ``None`` where the platform does not say."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _human(n_bytes: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if abs(n_bytes) < 1024 or unit == "TiB":
            return f"{n_bytes:.0f} {unit}" if unit == "bytes" else f"{n_bytes:.1f} {unit}"
        n_bytes /= 1024
    return f"{n_bytes:.1f} TiB"  # pragma: no cover


def check_memory(n_bytes: float, what: str, fix: str, available: int | None = None) -> None:
    """Refuse a computation whose memory estimate exceeds what is available.

    Parameters
    ----------
    n_bytes : float
        Estimated bytes the computation will allocate (e.g. ``n * n * 8`` for an
        ``(n, n)`` float64 matrix).
    what : str
        What needs the memory, for the message (``"the (100000, 100000) float64
        reference difference matrix"``).
    fix : str
        How to need less (``"use fewer particles (--particles)"``).
    available : int, optional
        Bytes available; by default :func:`available_memory`. A computation may plan
        to use :data:`MEMORY_FRACTION` of it.

    Raises
    ------
    InsufficientMemoryError
        With the estimate, the memory available and ``fix``.

    Examples
    --------
    >>> check_memory(8 * 1000 ** 2, "a (1000, 1000) float64 matrix", "use fewer frames", available=2 ** 30)
    >>> check_memory(8 * 10 ** 10, "a (100000, 100000) float64 matrix", "use fewer frames", available=2 ** 30)
    Traceback (most recent call last):
    ...
    catgraph.exceptions.InsufficientMemoryError: a (100000, 100000) float64 matrix needs 74.5 GiB but 1.0 GiB of memory is available; use fewer frames.
    """
    need = float(n_bytes)
    if not np.isfinite(need) or need < 0:
        raise InvalidParameterError(f"a memory estimate must be a finite number of bytes ≥ 0; got {n_bytes!r}.")
    avail = available_memory() if available is None else int(available)
    if avail is None:
        return
    if need > MEMORY_FRACTION * avail:
        raise InsufficientMemoryError(
            f"{what} needs {_human(need)} but {_human(avail)} of memory is available; {fix}."
        )
