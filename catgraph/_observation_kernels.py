"""Compiled passes of the observation models (imported lazily: numba).

The models of :mod:`catgraph.observation` make several passes over the places per frame
(levels, deviations, hub counts, centring …). These kernels fuse consecutive elementwise
passes into one, each value going through the same IEEE operations, in the same order,
as in the numpy formulas they replace, so the floats are the same bit for bit
(``tests/test_observation_kernels.py``). Sums, maxima and ``exp`` stay numpy's: its
pairwise, vectorised sums are both faster than a compiled loop here and the reference
floats.

:func:`bracket` serves the hub statistic's medians: the median of the reference levels
(and that of their absolute deviations) moves little from one frame to the next, so most
values lie outside a narrow bracket around the previous frame's median; one pass counts
them and keeps the few inside, and the order statistic is selected among those
(:class:`catgraph.observation._NearMedian`). An order statistic is a value of the array,
so the result is exact whichever way it is selected.

Kernels trust their input: 1-D, C-contiguous float64 of equal lengths, finite.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit


@njit(nogil=True)
def bracket(values, centre, absolute, mid, radius, k, work):  # pragma: no cover - compiled
    """Split the values ``v`` (``values``, or ``|values − centre|`` where ``absolute``)
    around the bracket of the ``v`` with ``|v − mid| ≤ radius``.

    ``v − mid`` is rounded monotonically in ``v``, so the bracket is an interval of
    values: those with ``v − mid < −radius`` lie below it. Returns ``(below, inside)``,
    how many values lie below and inside. The ``k``-th smallest value (from 0) lies
    inside exactly when ``below ≤ k < below + inside``; then (only then) the values
    inside are copied to ``work[:inside]``, and it is their ``(k − below)``-th smallest.
    """
    # first count (a branch-free pass, vectorised), then copy only where it pays
    below = 0
    inside = 0
    n = values.shape[0]
    for i in range(n):
        v = values[i]
        if absolute:
            v = abs(v - centre)
        d = v - mid
        below += d < -radius
        inside += abs(d) <= radius
    if not (below <= k < below + inside):
        return below, inside
    m = 0
    for i in range(n):
        v = values[i]
        if absolute:
            v = abs(v - centre)
        if abs(v - mid) <= radius:  # few values: a predictable branch
            work[m] = v
            m += 1
    return below, inside


@njit(nogil=True)
def largest_below(values, centre, absolute, mid, radius):  # pragma: no cover - compiled
    """The largest value ``v`` (as in :func:`bracket`) below the bracket (``−inf`` if none)."""
    top = -np.inf
    for i in range(values.shape[0]):
        v = values[i]
        if absolute:
            v = abs(v - centre)
        if v - mid < -radius:
            top = max(top, v)
    return top


@njit(nogil=True)
def negated_difference(row, h, out):  # pragma: no cover - compiled
    """``out = −(row − h)``: numpy's ``np.subtract`` then ``np.negative``, one pass."""
    for i in range(row.shape[0]):
        out[i] = -(row[i] - h[i])


@njit(nogil=True)
def absolute_deviations(x, centre, out):  # pragma: no cover - compiled
    """``out = |x − centre|``: ``np.subtract`` then ``np.abs``, one pass."""
    for i in range(x.shape[0]):
        out[i] = abs(x[i] - centre)


@njit(nogil=True)
def centred_squared(x, mean, out, square):  # pragma: no cover - compiled
    """``out = x − mean`` and ``square = out * out``: ``np.subtract`` then ``np.multiply``, one pass."""
    for i in range(x.shape[0]):
        d = x[i] - mean
        out[i] = d
        square[i] = d * d


@njit(nogil=True)
def centred_count(x, mean, threshold, out):  # pragma: no cover - compiled
    """``out = x − mean``; returns ``np.count_nonzero(x < threshold)``, one pass."""
    k = 0
    for i in range(x.shape[0]):
        v = x[i]
        out[i] = v - mean
        k += v < threshold
    return k


@njit(nogil=True)
def tempered_ratios(row, h, corrected, scale, base, r):  # pragma: no cover - compiled
    """``base = −(row − h)`` (``−row`` unless ``corrected``) and ``r = scale · base``, one pass.

    Returns ``(r.max(), np.argmax(base))`` (the first place of the largest ``base``).
    """
    top = -np.inf
    best = 0
    largest = -np.inf
    for i in range(row.shape[0]):
        b = -(row[i] - h[i]) if corrected else -row[i]
        base[i] = b
        v = scale * b
        r[i] = v
        top = max(top, v)
        if b > largest:
            largest = b
            best = i
    return top, best



@njit(nogil=True)
def row_sums(a, prior):  # pragma: no cover - compiled
    """``(Σ_j a_j, Σ_j a_j prior_j)``, one pass (summed in order)."""
    s = 0.0
    t = 0.0
    for j in range(a.shape[0]):
        v = a[j]
        s += v
        t += v * prior[j]
    return s, t


@njit(nogil=True)
def product_sums(a, b, prior):  # pragma: no cover - compiled
    """``(Σ_j a_j b_j, Σ_j a_j b_j prior_j)``, one pass (summed in order): the uniform and
    the predicted sums of one candidate combination, ``a`` and ``b`` its factors."""
    s = 0.0
    t = 0.0
    for j in range(a.shape[0]):
        v = a[j] * b[j]
        s += v
        t += v * prior[j]
    return s, t
