"""Compiled kernels for :mod:`catgraph.sequence` (numba, cached on disk: :func:`catgraph._jit.njit`).

Importing this module compiles nothing: numba compiles each kernel on its first call
(or loads it from the on-disk cache), so ``import catgraph`` stays cheap.
:mod:`catgraph.sequence` imports this module only when a matcher first runs.

The kernels trust their inputs (shapes, dtypes, ranges); the public functions in
:mod:`catgraph.sequence` validate first. The streaming matcher and the batch function
call the *same* kernels in the same order, so their results agree bit for bit.

Notation (see :mod:`catgraph.sequence`). Velocity ``v`` places query frame ``i`` at
reference offset ``pos_v(i) = floor(v * i + 1/2)``; one step moves the line by
``delta_v(i) = pos_v(i) - pos_v(i - 1)`` places. ``ring`` is ``(V, R, N)`` float64: for
each velocity the last ``R`` prefix-sum rows along its lines,
``C^v_i[j] = d_ij + C^v_{i-1}[j - delta_v(i)]`` (a term whose place falls outside
``[0, N)`` ends the chain), row ``C^v_i`` at ``ring[v, i % R]``. ``mring[i % R]`` holds
``M_i``, the running sum of the rows' mean differences (the fill for terms outside the
reference). ``grid`` holds the candidate window lengths (ascending). The line through
``(i, j)`` visits place ``j - (pos_v(i) - pos_v(i - t))`` at frame ``i - t``.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ._jit import njit

APPROX_GAUSSIAN = 0
APPROX_ROBUST = 1
APPROX_GMM = 2


@njit
def position(v, i):
    """``pos_v(i) = floor(v * i + 1/2)`` (int)."""
    return np.int64(np.floor(v * i + 0.5))


@njit
def advance_means(mring, i, d_row):
    """Write ``M_i = M_{i-1} + mean_j d_ij`` into ``mring[i % R]``."""
    r = mring.shape[0]
    n = d_row.shape[0]
    total = 0.0
    for j in range(n):
        total += d_row[j]
    if i == 0:
        mring[0] = total / n
    else:
        mring[i % r] = mring[(i - 1) % r] + total / n


@njit
def advance_line(ring_v, i, d_row, v):
    """Write ``C^v_i`` into ``ring_v[i % R]`` (from ``C^v_{i-1}``; zeros before the start)."""
    r = ring_v.shape[0]
    n = d_row.shape[0]
    out = ring_v[i % r]
    if i == 0:
        for j in range(n):
            out[j] = d_row[j]
        return
    prev = ring_v[(i - 1) % r]  # a different row because R >= 2
    delta = position(v, i) - position(v, i - 1)
    lo = delta if delta > 0 else 0
    hi = n + delta if delta < 0 else n
    if lo > n:
        lo = n
    if hi < 0:
        hi = 0
    for j in range(0, lo):
        out[j] = d_row[j]
    for j in range(lo, hi):
        out[j] = d_row[j] + prev[j - delta]
    for j in range(max(hi, lo), n):
        out[j] = d_row[j]


@njit
def advance(ring, mring, i, d_row, velocities):
    """:func:`advance_means` and :func:`advance_line` for every velocity (``ring`` is
    ``(V, R, N)``)."""
    advance_means(mring, i, d_row)
    for vi in range(velocities.shape[0]):
        advance_line(ring[vi], i, d_row, velocities[vi])


@njit
def _exit_time(v, i, eff, j, n):
    """First ``t`` in ``[1, eff - 1]`` whose place ``j - (pos(i) - pos(i - t))`` lies
    outside ``[0, N)`` (the caller knows one exists); binary search, the offsets being
    monotone in ``t``."""
    p = position(v, i)
    lo = 0
    hi = eff - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        k = j - (p - position(v, i - mid))
        if k < 0 or k >= n:
            hi = mid
        else:
            lo = mid
    return hi


@njit
def score_at(ring_v, mring, i, v, length, j):
    """One score ``s_ij(L, v)`` (same policy and arithmetic as :func:`window_scores`)."""
    r = ring_v.shape[0]
    n = ring_v.shape[1]
    eff = length if length <= i + 1 else i + 1
    p = position(v, i)
    k_last = j - (p - position(v, i - eff + 1))
    val = ring_v[i % r][j]
    if 0 <= k_last < n:
        if i >= eff:
            kb = j - (p - position(v, i - eff))
            if 0 <= kb < n:
                val -= ring_v[(i - eff) % r][kb]
    else:
        t_exit = _exit_time(v, i, eff, j, n)
        val += mring[(i - t_exit) % r]
        if i >= eff:
            val -= mring[(i - eff) % r]
    return val / eff


@njit
def window_scores(ring_v, mring, i, v, length, s):
    """Scores ``s_ij(L, v)`` of query frame ``i`` against every reference ``j`` into ``s``;
    returns their sum.

    Policy: the window has ``L_eff = min(L, i + 1)`` terms; a term whose place falls
    outside the reference is filled with its query row's mean difference; the sum is
    divided by ``L_eff``. Same arithmetic as :func:`score_at`.
    """
    r = ring_v.shape[0]
    n = s.shape[0]
    eff = length if length <= i + 1 else i + 1
    p = position(v, i)
    last = p - position(v, i - eff + 1)  # offset of the oldest term
    back_off = p - position(v, i - eff)
    has_back = i >= eff
    cur = ring_v[i % r]
    back = ring_v[(i - eff) % r]
    mback = mring[(i - eff) % r]
    # regular places: the whole window lies inside the reference
    jlo = last if last > 0 else 0
    jhi = n + last if last < 0 else n
    if jlo > n:
        jlo = n
    if jhi < jlo:
        jhi = jlo
    total = 0.0
    if has_back:
        blo = back_off if back_off > jlo else jlo
        if blo > jhi:
            blo = jhi
        bhi = n + back_off if n + back_off < jhi else jhi
        if bhi < blo:
            bhi = blo
        for j in range(jlo, blo):
            val = cur[j] / eff
            s[j] = val
            total += val
        for j in range(blo, bhi):
            val = (cur[j] - back[j - back_off]) / eff
            s[j] = val
            total += val
        for j in range(bhi, jhi):
            val = cur[j] / eff
            s[j] = val
            total += val
    else:
        for j in range(jlo, jhi):
            val = cur[j] / eff
            s[j] = val
            total += val
    # places whose window runs off the reference: the chain ends at the exit time
    if last > 0:
        t = 1
        for j in range(0, jlo):
            while p - position(v, i - t) <= j:
                t += 1
            val = cur[j] + mring[(i - t) % r]
            if has_back:
                val -= mback
            val = val / eff
            s[j] = val
            total += val
    elif last < 0:
        t = 1
        for j in range(n - 1, jhi - 1, -1):
            while j - (p - position(v, i - t)) <= n - 1:
                t += 1
            val = cur[j] + mring[(i - t) % r]
            if has_back:
                val -= mback
            val = val / eff
            s[j] = val
            total += val
    return total


@njit
def _median_mad(s, work):
    n = s.shape[0]
    for j in range(n):
        work[j] = s[j]
    med = np.median(work)
    for j in range(n):
        work[j] = abs(s[j] - med)
    mad = np.median(work)
    return med, 1.4826 * mad


@njit
def _gmm_em(s, stride, mean, std, n_iter, w, mu, sd, resp, coef, inv):
    """Fit a K-component 1-D Gaussian mixture to ``s[::stride]`` by ``n_iter`` EM steps.

    Start: equal weights, standard deviations ``std``, means spread evenly over
    ``mean ± std``. Variances are floored at ``1e-6 * std**2`` (no collapse onto one
    point). ``resp`` is ``(K, N)`` scratch, ``coef``/``inv`` ``(K,)`` scratch.
    """
    k_count = w.shape[0]
    n = (s.shape[0] + stride - 1) // stride
    for k in range(k_count):
        w[k] = 1.0 / k_count
        sd[k] = std
        if k_count == 1:
            mu[k] = mean
        else:
            mu[k] = mean + std * (2.0 * k / (k_count - 1) - 1.0)
    if std <= 0.0:
        return
    floor = 1e-6 * std * std
    for _ in range(n_iter):
        for k in range(k_count):
            coef[k] = np.log(w[k]) - np.log(sd[k])
            inv[k] = 1.0 / sd[k]
        # E step: responsibilities, normalised per point in log space
        for t in range(n):
            x = s[t * stride]
            top = -np.inf
            for k in range(k_count):
                z = (x - mu[k]) * inv[k]
                v = coef[k] - 0.5 * z * z
                resp[k, t] = v
                if v > top:
                    top = v
            tot = 0.0
            for k in range(k_count):
                e = np.exp(resp[k, t] - top)
                resp[k, t] = e
                tot += e
            for k in range(k_count):
                resp[k, t] /= tot
        # M step
        for k in range(k_count):
            nk = 0.0
            sx = 0.0
            for t in range(n):
                nk += resp[k, t]
                sx += resp[k, t] * s[t * stride]
            if nk <= 1e-12:
                # an empty component keeps its parameters with a negligible weight
                w[k] = 1e-12
                continue
            m = sx / nk
            sxx = 0.0
            for t in range(n):
                dev = s[t * stride] - m
                sxx += resp[k, t] * dev * dev
            var = sxx / nk
            if var < floor:
                var = floor
            w[k] = nk / n
            mu[k] = m
            sd[k] = np.sqrt(var)
        tw = 0.0
        for k in range(k_count):
            tw += w[k]
        for k in range(k_count):
            w[k] /= tw


@njit
def _velocity_stats(ring_v, mring, i, v, grid, approx, n_iter, em_stride, radius,
                    best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp):
    """:func:`frame_stats` for one velocity (outputs indexed by window only)."""
    g_count = grid.shape[0]
    n = s.shape[0]
    n_components = weights.shape[1]
    coef = np.empty(n_components)
    inv = np.empty(n_components)
    for g in range(g_count):
        total = window_scores(ring_v, mring, i, v, grid[g], s)
        m = total / n
        jb = 0
        vb = s[0]
        acc = 0.0
        for j in range(n):
            val = s[j]
            if val < vb:
                vb = val
                jb = j
            dev = val - m
            acc += dev * dev
        sdv = np.sqrt(acc / n)
        best_j[g] = jb
        best_s[g] = vb
        v2 = np.inf
        lo = jb - radius
        hi = jb + radius
        for j in range(0, lo if lo < n else n):
            if s[j] < v2:
                v2 = s[j]
        for j in range(hi + 1 if hi + 1 > 0 else 0, n):
            if s[j] < v2:
                v2 = s[j]
        second_s[g] = v2
        mean[g] = m
        std[g] = sdv
        if approx == APPROX_GAUSSIAN:
            weights[g, 0] = 1.0
            locs[g, 0] = m
            scales[g, 0] = sdv
        elif approx == APPROX_ROBUST:
            med, mad = _median_mad(s, work)
            weights[g, 0] = 1.0
            locs[g, 0] = med
            scales[g, 0] = mad
        else:
            _gmm_em(s, em_stride, m, sdv, n_iter, weights[g], locs[g], scales[g], resp, coef, inv)
    if sub.shape[1] == g_count:  # only the consistency tests need them
        for g in range(g_count):
            for h in range(g_count):
                sub[g, h] = score_at(ring_v, mring, i, v, grid[h], best_j[g])


@njit
def frame_stats(ring, mring, i, velocities, grid, approx, n_iter, em_stride, radius,
                best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp):
    """Everything the selection rules need for query frame ``i``, per velocity and window.

    Outputs (``V`` velocities, ``G = len(grid)``, ``K`` components): ``best_j, best_s,
    second_s, mean, std`` ``(V, G)``; ``weights, locs, scales`` ``(V, G, K)`` — the
    approximation's components; ``sub`` ``(V, G, G)`` (or ``(V, G, 0)`` when not needed)
    with ``sub[v, g, h] = s_{i, best_j[v, g]}(grid[h], v)``, window ``g``'s best hypothesis
    scored over window ``h`` along the same line. Mixtures are fitted to every
    ``em_stride``-th score. ``second_s`` is the best score more than ``radius`` places
    from ``best_j`` at the same velocity (``+inf`` where none exists). Scratch ``s, work``
    ``(V, N)``, ``resp`` ``(V, K, N)``.
    """
    for vi in range(velocities.shape[0]):
        _velocity_stats(ring[vi], mring, i, velocities[vi], grid, approx, n_iter, em_stride, radius,
                        best_j[vi], best_s[vi], second_s[vi], mean[vi], std[vi], weights[vi], locs[vi],
                        scales[vi], sub[vi], s[vi], work[vi], resp[vi])


@njit(parallel=True)
def run_batch(d, start, ring, mring, velocities, grid, approx, n_iter, em_stride, radius,
              best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp):
    """:func:`advance` then :func:`frame_stats` for every row of ``d``, in order; row
    ``t`` of ``d`` is query frame ``start + t``.

    ``ring``/``mring`` must have at least ``max(grid) + 1`` rows, start as zeros and
    carry over from the previous block. The velocities are independent, so they run in
    parallel threads over the whole block (one parallel region, not one per frame); each
    keeps its own copy of the row-mean ring, computed by the same arithmetic, so the
    numbers equal the streaming form's and do not depend on the thread count.
    """
    v_count = velocities.shape[0]
    means = np.empty((v_count, mring.shape[0]))
    for vi in range(v_count):
        means[vi] = mring
    for vi in prange(v_count):
        for t in range(d.shape[0]):
            i = start + t
            advance_means(means[vi], i, d[t])
            advance_line(ring[vi], i, d[t], velocities[vi])
            _velocity_stats(ring[vi], means[vi], i, velocities[vi], grid, approx, n_iter, em_stride, radius,
                            best_j[t, vi], best_s[t, vi], second_s[t, vi], mean[t, vi], std[t, vi],
                            weights[t, vi], locs[t, vi], scales[t, vi], sub[t, vi], s[vi], work[vi], resp[vi])
    mring[:] = means[0]


@njit
def fixed_scores(d, length, v):
    """All scores ``s_ij(L, v)`` for one window and velocity, ``(n_query, N)`` (batch helper)."""
    n_q, n = d.shape
    out = np.empty((n_q, n))
    ring = np.zeros((1, length + 1, n))
    mring = np.zeros(length + 1)
    vel = np.array([v])
    for i in range(n_q):
        advance(ring, mring, i, d[i], vel)
        window_scores(ring[0], mring, i, v, length, out[i])
    return out
