"""Compiled passes of the observation models (imported lazily: numba).

The models of :mod:`catgraph.observation` make several passes over the places per frame
(levels, deviations, hub counts, centring …). These kernels fuse consecutive elementwise
passes into one, each value going through the same IEEE operations, in the same order,
as in the numpy formulas they replace, so the floats are the same bit for bit
(``tests/test_observation_kernels.py``). ``exp`` stays numpy's (numba's differs in the
last bit on a few per cent of values). A sum fused into a pass replays numpy's own
pairwise summation (below: :func:`block_starts`, :func:`pairwise_sum`), so it is the
float ``np.sum`` of the materialised values would give; a maximum is exact in any order.

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
    how many values lie below and inside; the values inside are copied, in order, to
    ``work[:inside]`` (``work`` may be ``values``: a value is written only over one
    already read). The ``k``-th smallest value (from 0) lies inside exactly when
    ``below ≤ k < below + inside``, and it is then their ``(k − below)``-th smallest.

    One pass, without branches: every value is stored at the next free place of ``work``
    and the place advances only for a value inside (at 10⁶ places, flushed from the
    caches: 1.4 ms against 1.9–3.9 ms for a vectorised counting pass and a copying pass,
    whose branch on the 1–3 % of values inside mispredicts; the same in cache).
    """
    below = 0
    m = 0
    n = values.shape[0]
    low = -radius
    if absolute:
        for i in range(n):
            v = abs(values[i] - centre)
            d = v - mid
            below += d < low
            work[m] = v
            m += abs(d) <= radius
    else:
        for i in range(n):
            v = values[i]
            d = v - mid
            below += d < low
            work[m] = v
            m += abs(d) <= radius
    return below, m


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
def count_below(x, threshold):  # pragma: no cover - compiled
    """``np.count_nonzero(x < threshold)``, without the boolean temporary."""
    k = 0
    for i in range(x.shape[0]):
        k += x[i] < threshold
    return k


@njit(nogil=True)
def hub_tempered_ratios(row, level, mean, shrink, scale, keep_base, base, r):  # pragma: no cover - compiled
    """:func:`tempered_ratios` with the hub correction formed on the fly: ``h = level −
    mean`` (:func:`centred_count`'s values), times ``shrink`` unless it is exactly 1
    (the model's ``out *= shrink``), ``base = −(row − h)``, ``r = scale · base``; the
    same floats, without the correction's array written and read back. ``base`` is
    written only where ``keep_base``.

    Returns ``(r.max(), np.argmax(base))``, as :func:`tempered_ratios`."""
    top = -np.inf
    best = 0
    largest = -np.inf
    scaled = shrink != 1.0
    for i in range(row.shape[0]):
        h = level[i] - mean
        if scaled:
            h = h * shrink
        b = -(row[i] - h)
        if keep_base:
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


# ---------------------------------------------------------------------------------------
# numpy's pairwise sum, for passes that fuse a sum with other work
#
# ``np.sum`` of a contiguous float64 array (and so ``mean``, ``var``, ``std``) adds the
# values pairwise: the array is halved (the first half cut to a multiple of 8) down to
# blocks of at most 128 values; a block of 8 or more is summed in eight interleaved
# accumulators, combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then its
# last ``n mod 8`` values added in order; a shorter block is added in order; the
# result is then added to the reduction's identity 0.0. The kernels below replay that
# tree on values they compute on the fly (a block at a time, through a small buffer),
# so a fused pass returns the very float numpy's sum of the materialised values would
# (``tests/test_observation_kernels.py`` checks them against numpy on every length up
# to a few hundred and on long arrays).

_BLOCK = 128


@njit(nogil=True)
def _block_sum(a, n):  # pragma: no cover - compiled
    """numpy's sum of one block ``a[:n]`` (``n ≤ 128``)."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[0], a[1], a[2], a[3]
    r4, r5, r6, r7 = a[4], a[5], a[6], a[7]
    m = n - n % 8
    for q in range(1, m // 8):
        # unsigned indices: no negative-index handling, so the eight loads are one
        # contiguous vector load and the eight accumulators one vector (2.3x faster)
        i = np.uint64(8 * q)
        r0 += a[i]
        r1 += a[i + np.uint64(1)]
        r2 += a[i + np.uint64(2)]
        r3 += a[i + np.uint64(3)]
        r4 += a[i + np.uint64(4)]
        r5 += a[i + np.uint64(5)]
        r6 += a[i + np.uint64(6)]
        r7 += a[i + np.uint64(7)]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(m, n):
        res += a[i]
    return res


def _half(n):
    """The first half of numpy's split of ``n > 128`` values (a multiple of 8)."""
    h = n // 2
    return h - h % 8


_half = njit(nogil=True, inline="always")(_half)


@njit(nogil=True)
def block_starts(n):  # pragma: no cover - compiled
    """The starts of numpy's blocks over ``n`` values, in order, with ``n`` appended
    (the tree walked depth first, left half first; no recursion: numba's on-disk cache
    does not keep recursive kernels)."""
    starts = np.empty(n // 64 + 3, dtype=np.int64)
    lo_stack = np.empty(64, dtype=np.int64)
    n_stack = np.empty(64, dtype=np.int64)
    lo_stack[0], n_stack[0] = 0, n
    top = 1
    k = 0
    while top > 0:
        top -= 1
        lo, m = lo_stack[top], n_stack[top]
        if m <= _BLOCK:
            starts[k] = lo
            k += 1
            continue
        h = _half(m)
        lo_stack[top], n_stack[top] = lo + h, m - h  # the right half, after
        lo_stack[top + 1], n_stack[top + 1] = lo, h  # the left half, first
        top += 2
    starts[k] = n
    return starts[:k + 1]


@njit(nogil=True)
def _combine(sums, n):  # pragma: no cover - compiled
    """The blocks' sums (in :func:`block_starts` order) added along numpy's tree over
    ``n`` values, each node its left half's sum plus its right half's."""
    size = np.empty(64, dtype=np.int64)  # the path from the root to the current node
    left = np.empty(64)  # a node's left sum, once its right half is being summed
    stage = np.zeros(64, dtype=np.int64)  # 0: in its left half, 1: in its right half
    depth = 0
    size[0] = n
    k = 0
    while True:
        m = size[depth]
        if m > _BLOCK:  # descend into the left half
            stage[depth] = 0
            depth += 1
            size[depth] = _half(m)
            continue
        v = sums[k]
        k += 1
        while True:  # hand the sum up until a node still has its right half to do
            if depth == 0:
                return v
            depth -= 1
            if stage[depth] == 0:
                left[depth] = v
                stage[depth] = 1
                depth += 1
                size[depth] = size[depth - 1] - _half(size[depth - 1])
                break
            v = left[depth] + v


@njit(nogil=True)
def pairwise_sum(a):  # pragma: no cover - compiled
    """``np.sum(a)`` of a contiguous float64 array, the same float (the reference of the
    fused passes: the same tree, the blocks read in place)."""
    n = a.shape[0]
    starts = block_starts(n)
    sums = np.empty(len(starts) - 1)
    for b in range(len(starts) - 1):
        sums[b] = _block_sum(a[starts[b]:starts[b + 1]], starts[b + 1] - starts[b])
    return 0.0 + _combine(sums, n)


@njit(nogil=True)
def product_sum(x, y):  # pragma: no cover - compiled
    """numpy's ``(x * y).sum()`` of two contiguous float64 arrays, the same float, without
    the products stored and on the calling thread: where ``np.dot`` would hand a long
    product to BLAS, whose threads then spin on the cores the step's own threads need."""
    n = x.shape[0]
    starts = block_starts(n)
    nb = len(starts) - 1
    sp = np.empty(nb)
    bp = np.empty(_BLOCK)
    for b in range(nb):
        lo = starts[b]
        w = starts[b + 1] - lo
        xs, ys = x[lo:lo + w], y[lo:lo + w]
        for t in range(np.uint64(w)):
            bp[t] = xs[t] * ys[t]
        sp[b] = _block_sum(bp, w)
    return 0.0 + _combine(sp, n)


@njit(nogil=True)
def centred_sums(x, mean, other, out):  # pragma: no cover - compiled
    """``out = x − mean`` and numpy's ``(out * out).sum()`` and, where ``other`` is not
    empty, ``(out * other).sum()`` (0 otherwise), in one pass; an empty ``out``: the
    centred values are not stored (the squares' sum alone, ``other`` empty).

    The centring, squares and products of ``np.subtract`` / ``np.multiply`` then
    ``np.sum``, without the squares or products stored: for the novelty weight's
    correlation and the standardised window scores."""
    n = x.shape[0]
    both = other.shape[0] > 0
    starts = block_starts(n)
    nb = len(starts) - 1
    s2, sp = np.empty(nb), np.empty(nb)
    b2, bp = np.empty(_BLOCK), np.empty(_BLOCK)
    if out.shape[0] == 0:  # the sum of squares only
        for b in range(nb):
            lo = starts[b]
            w = starts[b + 1] - lo
            xs = x[lo:lo + w]
            for t in range(np.uint64(w)):
                d = xs[t] - mean
                b2[t] = d * d
            s2[b] = _block_sum(b2, w)
        return 0.0 + _combine(s2, n), 0.0
    for b in range(nb):
        lo = starts[b]
        w = starts[b + 1] - lo
        xs, os = x[lo:lo + w], out[lo:lo + w]  # views, unsigned indices: no negative-index handling
        for t in range(np.uint64(w)):
            d = xs[t] - mean
            os[t] = d
            b2[t] = d * d
        s2[b] = _block_sum(b2, w)
        if both:
            ot = other[lo:lo + w]
            for t in range(np.uint64(w)):
                bp[t] = os[t] * ot[t]
            sp[b] = _block_sum(bp, w)
    squares = 0.0 + _combine(s2, n)
    products = 0.0 + _combine(sp, n) if both else 0.0
    return squares, products


@njit(nogil=True)
def accumulated_levels(total, row, count, new_total, level):  # pragma: no cover - compiled
    """``new_total = total + row`` (``np.add``; ``new_total`` may be ``total``: in place),
    ``level = new_total / count`` (``np.divide``) and numpy's ``level.sum()``, in one
    pass: the online hub levels of the next frame and their sum, formed while the frame
    is added to the running total."""
    n = total.shape[0]
    starts = block_starts(n)
    nb = len(starts) - 1
    sums = np.empty(nb)
    for b in range(nb):
        lo = starts[b]
        w = starts[b + 1] - lo
        ts, rs, ns, ls = total[lo:lo + w], row[lo:lo + w], new_total[lo:lo + w], level[lo:lo + w]
        for t in range(np.uint64(w)):
            v = ts[t] + rs[t]
            ns[t] = v
            ls[t] = v / count
        sums[b] = _block_sum(ls, w)
    return 0.0 + _combine(sums, n)


@njit(nogil=True)
def mean_std(x):  # pragma: no cover - compiled
    """``(x.mean(), x.std())`` as numpy computes them (its sums, its order), in two
    passes and no temporary: the mean, then the centred squares summed as they are
    formed."""
    n = x.shape[0]
    mean = pairwise_sum(x) / n
    starts = block_starts(n)
    nb = len(starts) - 1
    sums = np.empty(nb)
    buf = np.empty(_BLOCK)
    for b in range(nb):
        lo = starts[b]
        w = starts[b + 1] - lo
        xs = x[lo:lo + w]
        for t in range(np.uint64(w)):
            d = xs[t] - mean
            buf[t] = d * d
        sums[b] = _block_sum(buf, w)
    return mean, np.sqrt((0.0 + _combine(sums, n)) / n)


@njit(nogil=True)
def standardised_ratios(s, mean, sd, scale, tau, r):  # pragma: no cover - compiled
    """The standardised scores' tempered ratios in one pass from the scores ``s``:
    ``z = (s − mean) / sd`` (``_standardised``'s centring and division, ``z`` not
    stored), ``r = (scale · −z) · tau`` (the tempered model's ratio ``scale · base``,
    ``base = −z``, then the sequence part's window temperature).

    Returns ``(r.max(), np.argmax(−z), finite)``, ``finite`` whether every ``z`` is."""
    top = -np.inf
    best = 0
    largest = -np.inf
    finite = True
    for i in range(s.shape[0]):
        v = (s[i] - mean) / sd
        finite &= np.isfinite(v)
        b = -v
        w = (scale * b) * tau
        r[i] = w
        top = max(top, w)
        if b > largest:
            largest = b
            best = i
    return top, best, finite


@njit(nogil=True)
def sum_max(a, b, out):  # pragma: no cover - compiled
    """``out = a + b`` (``np.add``); returns ``out.max()``: the value a running
    ``max(top, v)`` over the values in order returns (NaN skipped, of equal values the
    first, so of a largest 0 its sign).

    The maximum is kept in eight interleaved running maxima (each value compared with
    the one of its lane; the same largest value, in 0.07 instead of 0.18 ms at 10⁵
    places: one compare chain held back every value); only the sign of a largest 0
    depends on which lane saw it, and is then read from the first 0."""
    n = a.shape[0]
    m = n - n % 8
    t0 = t1 = t2 = t3 = t4 = t5 = t6 = t7 = -np.inf
    for q in range(m // 8):
        # unsigned indices: no negative-index handling (one vector load per eight values)
        i = np.uint64(8 * q)
        v = a[i] + b[i]
        out[i] = v
        t0 = v if v > t0 else t0
        v = a[i + np.uint64(1)] + b[i + np.uint64(1)]
        out[i + np.uint64(1)] = v
        t1 = v if v > t1 else t1
        v = a[i + np.uint64(2)] + b[i + np.uint64(2)]
        out[i + np.uint64(2)] = v
        t2 = v if v > t2 else t2
        v = a[i + np.uint64(3)] + b[i + np.uint64(3)]
        out[i + np.uint64(3)] = v
        t3 = v if v > t3 else t3
        v = a[i + np.uint64(4)] + b[i + np.uint64(4)]
        out[i + np.uint64(4)] = v
        t4 = v if v > t4 else t4
        v = a[i + np.uint64(5)] + b[i + np.uint64(5)]
        out[i + np.uint64(5)] = v
        t5 = v if v > t5 else t5
        v = a[i + np.uint64(6)] + b[i + np.uint64(6)]
        out[i + np.uint64(6)] = v
        t6 = v if v > t6 else t6
        v = a[i + np.uint64(7)] + b[i + np.uint64(7)]
        out[i + np.uint64(7)] = v
        t7 = v if v > t7 else t7
    top = max(max(max(t0, t1), max(t2, t3)), max(max(t4, t5), max(t6, t7)))
    for j in range(m, n):
        v = a[j] + b[j]
        out[j] = v
        top = max(top, v)
    if top == 0.0:  # +0 or −0: the first zero's, as the running maximum keeps it
        for j in range(n):
            if out[j] == 0.0:
                return out[j]
    return top


@njit(nogil=True)
def all_finite(x):  # pragma: no cover - compiled
    """``np.isfinite(x).all()``, without the boolean temporary."""
    ok = True
    for i in range(x.shape[0]):
        ok &= np.isfinite(x[i])
    return ok
