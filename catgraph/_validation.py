"""Checks at the public boundary, and seeding.

Public functions validate here and then call private kernels that trust their inputs
(the networkx pattern). Messages follow scikit-learn's form: what, where, the allowed
range, what was given.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from .exceptions import DataError, InvalidParameterError

__all__ = ["as_generator", "check_array", "check_scalar"]


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
        out = np.asarray(array) if dtype is None else np.asarray(array, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} could not be read as a numeric array: {exc}") from None
    if out.dtype == object:
        raise DataError(f"{name} must be a numeric array, not an array of Python objects.")
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if out.ndim not in allowed:
            raise DataError(f"{name} must have {' or '.join(map(str, allowed))} dimensions; got shape {out.shape}.")
    if not allow_empty and out.size == 0:
        raise DataError(f"{name} is empty (shape {out.shape}); at least one frame is needed.")
    if finite and np.issubdtype(out.dtype, np.floating):
        bad = ~np.isfinite(out)
        if bad.any():
            first = int(np.argwhere(bad)[0][0])
            raise DataError(
                f"{name} contain {int(bad.sum())} NaN or infinite values (first at row {first}); "
                "clean or drop those frames before localising."
            )
    return out
