"""Compiled kernels for :mod:`catgraph.sequence` (numba, ``cache=True``).

Importing this module compiles nothing: numba compiles each kernel on its first call
(or loads it from the on-disk cache), so ``import catgraph`` stays cheap.
:mod:`catgraph.sequence` imports this module only when a matcher first runs.

The kernels trust their inputs (shapes, dtypes, ranges); the public functions in
:mod:`catgraph.sequence` validate first. The streaming matcher and the batch function
call the *same* kernels in the same order, so their results agree bit for bit.

Notation (see :mod:`catgraph.sequence`): ``ring`` is ``(R, N)`` float64 holding the
last ``R`` diagonal prefix-sum rows ``C_i[j] = d_ij + C_{i-1}[j-1]``; row ``C_i`` sits at
``ring[i % R]``, and ``mring[i % R]`` holds ``M_i``, the running sum of the
rows' mean differences (used to fill terms before the reference's start). ``grid`` holds the candidate window lengths (ascending).
"""

from __future__ import annotations

import numpy as np
from numba import njit

APPROX_GAUSSIAN = 0
APPROX_ROBUST = 1
APPROX_GMM = 2


@njit(cache=True)
def advance(ring, mring, i, d_row):
    """Write ``C_i`` into ``ring[i % R]`` (from ``C_{i-1}``; zeros before the start) and
    the running sum of row means ``M_i = M_{i-1} + mean_j d_ij`` into ``mring[i % R]``."""
    r = ring.shape[0]
    n = d_row.shape[0]
    out = ring[i % r]
    total = 0.0
    for j in range(n):
        total += d_row[j]
    if i == 0:
        for j in range(n):
            out[j] = d_row[j]
        mring[0] = total / n
        return
    prev = ring[(i - 1) % r]
    # prev and out are different rows because R >= 2
    out[0] = d_row[0]
    for j in range(1, n):
        out[j] = d_row[j] + prev[j - 1]
    mring[i % r] = mring[(i - 1) % r] + total / n


@njit(cache=True)
def _window(ring, mring, i, length, j):
    r = ring.shape[0]
    eff = length if length <= i + 1 else i + 1
    v = ring[i % r][j]
    if j >= eff:
        if i >= eff:
            v -= ring[(i - eff) % r][j - eff]
    elif j < eff - 1:
        # the window runs off the start of the reference: terms k = j+1 .. eff-1 are
        # filled with their query row's mean difference, M_{i-j-1} - M_{i-eff}
        v += mring[(i - j - 1) % r]
        if i >= eff:
            v -= mring[(i - eff) % r]
    return v / eff


@njit(cache=True)
def window_scores(ring, mring, i, length, s):
    """Scores ``s_ij(L)`` of query frame ``i`` against every reference ``j`` into ``s``;
    returns their sum.

    Policy: the window has ``L_eff = min(L, i + 1)`` terms (before the query's start
    there is nothing to sum); terms before the reference's start are filled with their
    query row's mean difference (no evidence either way); the sum is divided by
    ``L_eff``. Same arithmetic as :func:`score_at`.
    """
    n = s.shape[0]
    r = ring.shape[0]
    eff = length if length <= i + 1 else i + 1
    head = eff if eff < n else n
    total = 0.0
    for j in range(head):
        v = _window(ring, mring, i, length, j)
        s[j] = v
        total += v
    cur = ring[i % r]
    if i >= eff:
        back = ring[(i - eff) % r]
        for j in range(head, n):
            v = (cur[j] - back[j - eff]) / eff
            s[j] = v
            total += v
    else:
        for j in range(head, n):
            v = cur[j] / eff
            s[j] = v
            total += v
    return total


@njit(cache=True)
def score_at(ring, mring, i, length, j):
    """One score ``s_ij(L)`` (same policy and arithmetic as :func:`window_scores`)."""
    return _window(ring, mring, i, length, j)


@njit(cache=True)
def _median_mad(s, work):
    n = s.shape[0]
    for j in range(n):
        work[j] = s[j]
    med = np.median(work)
    for j in range(n):
        work[j] = abs(s[j] - med)
    mad = np.median(work)
    return med, 1.4826 * mad


@njit(cache=True)
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


@njit(cache=True)
def frame_stats(ring, mring, i, grid, approx, n_components, n_iter, em_stride, radius,
                best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp):
    """Everything the selection rules need for query frame ``i``, per candidate window.

    Outputs (``G = len(grid)``, ``K = n_components``): ``best_j, best_s, second_s, mean,
    std`` ``(G,)``; ``weights, locs, scales`` ``(G, K)`` — the approximation's components
    (one component for the Gaussian and robust Gaussian); ``sub`` ``(G, G)`` (or ``(G, 0)`` when not needed) with
    ``sub[g, h] = s_{i, best_j[g]}(grid[h])``, the best hypothesis of window ``g`` scored
    over window ``h``. Mixtures are fitted to every ``em_stride``-th score. ``second_s`` is the best score more than ``radius`` places away
    from ``best_j`` (``+inf`` where none exists).
    """
    g_count = grid.shape[0]
    n = s.shape[0]
    coef = np.empty(n_components)
    inv = np.empty(n_components)
    for g in range(g_count):
        total = window_scores(ring, mring, i, grid[g], s)
        m = total / n
        jb = 0
        vb = s[0]
        acc = 0.0
        for j in range(n):
            v = s[j]
            if v < vb:
                vb = v
                jb = j
            dev = v - m
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
    if sub.shape[1] == g_count:  # only the consistent and sustained rules need them
        for g in range(g_count):
            for h in range(g_count):
                sub[g, h] = score_at(ring, mring, i, grid[h], best_j[g])


@njit(cache=True)
def run_batch(d, start, ring, mring, grid, approx, n_components, n_iter, em_stride, radius,
              best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp):
    """:func:`advance` then :func:`frame_stats` for every row of ``d``, in order; row
    ``t`` of ``d`` is query frame ``start + t``.

    ``ring``/``mring`` must have at least ``max(grid) + 1`` rows, start as zeros and
    carry over from the previous block.
    """
    for t in range(d.shape[0]):
        i = start + t
        advance(ring, mring, i, d[t])
        frame_stats(ring, mring, i, grid, approx, n_components, n_iter, em_stride, radius,
                    best_j[t], best_s[t], second_s[t], mean[t], std[t], weights[t], locs[t],
                    scales[t], sub[t], s, work, resp)


@njit(cache=True)
def fixed_scores(d, length):
    """All scores ``s_ij(L)`` for one fixed ``L``, ``(n_query, N)`` (batch helper)."""
    n_q, n = d.shape
    out = np.empty((n_q, n))
    ring = np.zeros((length + 1, n))
    mring = np.zeros(length + 1)
    for i in range(n_q):
        advance(ring, mring, i, d[i])
        window_scores(ring, mring, i, length, out[i])
    return out
