"""Compiled prediction and update of the particle filter's jump grid (imported lazily: numba).

The jump grid (:class:`~catgraph.localizer.Localizer`, ``jump_graduation < 1``) keeps the
recovery share exactly over (place, velocity bin) and predicts it as the grid filter
predicts (:func:`catgraph.grid.predict`: velocity transition, shift, blur, mass lost past
a route end given back to the rest), then mixes in the new jump mass and weighs it by the
frame::

    J_t = (c · blur(shift(S · T)) + a · v_jump) · e

with ``S`` the stored grid (a scalar multiple of the last ``J``), ``c`` the scale that
renormalises what ran past a route end (:func:`jump_lost` gives that mass) and ``a =
ε / n``. :func:`jump_step` does it in one pass over the grid on a route whose places
follow each other by index (``fwd[j] ∈ {j + 1, −1}``: every map built from traverses in
order; ``seg`` names each place's stretch of unbroken route), block by block, fixed runs
of blocks shared among the free cores' threads (the kernel releases the GIL; the floats do
not depend on the number of threads), and writes every sum the filter's step reads from
the grid: the predicted place masses, the cumulative of ``J_t``'s place marginal (the
births' proposal) and its velocity sums per block.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit

#: Places per block of :func:`jump_step` (a block's transition rows, shifted rows and
#: halo stay in the first- and second-level caches).
JUMP_BLOCK = 2048
#: Runs of whole blocks :func:`jump_step` hands out to its threads, each to whichever is
#: free (fixed: the floats do not depend on the number of threads).
JUMP_PIECES = 8


def line_segments(fwd: np.ndarray, bwd: np.ndarray) -> np.ndarray | None:
    """Each place's stretch of unbroken route, where the route follows the place index
    (``fwd[j]`` is ``j + 1`` or none, ``bwd[j]`` is ``j − 1`` or none, and they undo each
    other); ``None`` for any other route (the jump grid then takes
    :func:`catgraph.grid.predict`)."""
    n = len(fwd)
    idx = np.arange(n)
    if not (np.all((fwd == idx + 1) | (fwd < 0)) and np.all((bwd == idx - 1) | (bwd < 0))):
        return None
    if n > 1 and not np.array_equal(fwd[:-1] >= 0, bwd[1:] >= 0):
        return None
    breaks = np.r_[0, (fwd[:-1] < 0).astype(np.int64)] if n else np.zeros(0, dtype=np.int64)
    return np.cumsum(breaks).astype(np.int64)


def segment_edges(seg: np.ndarray, reach: int) -> np.ndarray:
    """The places within ``reach`` places of their stretch's first or last place: the only
    ones whose mass can run past a route end in one prediction (:func:`jump_lost`)."""
    n = len(seg)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    last = np.r_[first[1:] - 1, n - 1]
    near = np.zeros(n, dtype=bool)
    for a, z in zip(first, last):
        near[a:min(z + 1, a + reach)] = True
        near[max(a, z + 1 - reach):z + 1] = True
    return np.flatnonzero(near).astype(np.int64)


def block_starts(seg: np.ndarray, reach: int, block: int = JUMP_BLOCK) -> np.ndarray:
    """The blocks of :func:`jump_step`: each stretch of route (``seg``) cut into a small
    block at either end (the places within ``reach + 3`` of it, whose moves and blur see the
    end) and blocks of at most ``block`` places between them, whose halo of ``reach + 2``
    places holds no end (they move by index alone). Returns the first place of every block
    and ``n`` (int64)."""
    n = len(seg)
    if n == 0:
        return np.zeros(1, dtype=np.int64)
    first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    last = np.r_[first[1:], n]
    edge = reach + 3
    starts = []
    for a, z in zip(first, last):
        if z - a <= 2 * edge:
            starts.append(a)
            continue
        starts.append(a)
        inner = z - a - 2 * edge
        pieces = -(-inner // block)
        starts += [a + edge + inner * p // pieces for p in range(pieces)]
        starts.append(z - edge)
    return np.array(starts + [n], dtype=np.int64)


@njit
def jump_lost(s, seg, edges, t_ptr, t_src, t_val, whole, frac, sign):  # pragma: no cover - compiled
    """The mass of ``s`` (bins × places) that one prediction moves past a route end: from
    the places ``edges`` (:func:`segment_edges`), the transition's row times the share of
    the bin's move (``whole`` or ``whole + 1`` places, direction ``sign``) that leaves the
    place's stretch (``seg``)."""
    nb, n = s.shape
    lost = 0.0
    for i in range(len(edges)):
        j = edges[i]
        for b in range(nb):
            q = 0.0
            for c in range(t_ptr[b], t_ptr[b + 1]):
                q += s[t_src[c], j] * t_val[c]
            for part in range(2):
                hops = whole[b] + part
                share = 1.0 - frac[b] if part == 0 else frac[b]
                if share == 0.0 or hops == 0:
                    continue
                d = j + sign[b] * hops
                if d < 0 or d >= n or seg[d] != seg[j]:
                    lost += share * q
    return lost


@njit(fastmath=True, nogil=True)
def _jump_blocks(s, out, seg, t_ptr, t_src, t_val, whole, frac, sign, halo, centre, side, read, a, jv, e, unit, starts,
                 predicted, like, bins, totals, k_start, k_stop):  # pragma: no cover - compiled
    """Blocks ``k_start .. k_stop − 1`` of :func:`jump_step` (each block's own places of
    ``out``, ``predicted``, ``like`` (its cumulative within the block), ``bins[k]`` and
    ``totals[k]`` (its sum)). Per block and bin: the row of ``T · s`` over the block and
    its halo; inside the route (no end within the halo) the shift and the blur are index
    offsets, one four-point stencil on that row; else the shift with each source's stretch
    checked, then the blur with the route ends' own."""
    nb, n = out.shape
    block = 0
    for k in range(k_start, k_stop):
        block = max(block, starts[k + 1] - starts[k])
    sh_all = np.zeros(block + 2)  # one bin's shifted row over a block and one place either side
    q_all = np.zeros(block + 2 * halo)  # one bin's row of T · s over a block and its halo
    eu_all = np.empty(block)
    for k in range(k_start, k_stop):
        t0 = starts[k]
        t1 = starts[k + 1]
        qa = max(0, t0 - halo)
        qz = min(n, t1 + halo)
        width = qz - qa
        xa = max(0, t0 - 1)
        xz = min(n, t1 + 1)
        w = xz - xa
        m = t1 - t0
        pm = predicted[t0:t1]
        et = e[t0:t1]
        eu = eu_all[:m]
        for i in range(m):
            pm[i] = 0.0
            eu[i] = et[i] * unit
        plain = t0 - halo >= 0 and t1 + halo <= n and seg[qa] == seg[qz - 1]
        sh = sh_all[:w]
        q = q_all[:width]
        if not read:
            q[:] = 0.0
            sh[:] = 0.0
        for b in range(nb):
            step = sign[b] * whole[b]
            f0 = 1.0 - frac[b]
            f1 = frac[b]
            if read:
                c0 = t_ptr[b]
                kc = t_ptr[b + 1] - c0
                if kc <= 4:  # velocity_transition's columns: the bin, two neighbours, the mirror
                    r0 = s[t_src[c0], qa:qz]
                    r1 = s[t_src[c0 + 1], qa:qz] if kc > 1 else r0
                    r2 = s[t_src[c0 + 2], qa:qz] if kc > 2 else r0
                    r3 = s[t_src[c0 + 3], qa:qz] if kc > 3 else r0
                    v0 = t_val[c0]
                    v1 = t_val[c0 + 1] if kc > 1 else 0.0
                    v2 = t_val[c0 + 2] if kc > 2 else 0.0
                    v3 = t_val[c0 + 3] if kc > 3 else 0.0
                    for i in range(width):
                        q[i] = v0 * r0[i] + v1 * r1[i] + v2 * r2[i] + v3 * r3[i]
                else:
                    v0 = t_val[c0]
                    r0 = s[t_src[c0], qa:qz]
                    for i in range(width):
                        q[i] = v0 * r0[i]
                    for cc in range(c0 + 1, c0 + kc):
                        vc = t_val[cc]
                        rc = s[t_src[cc], qa:qz]
                        for i in range(width):
                            q[i] += vc * rc[i]
            base = a * jv[b]
            o = out[b, t0:t1]
            acc = 0.0
            if plain:
                # place t0 + i reads q at i + o0 (+ the split move's i + o0 − sign, the blur's ± 1)
                o0 = t0 - step - qa
                g = o0 - 1 if sign[b] > 0 else o0 - 2  # the stencil's first tap
                if sign[b] > 0:  # taps o0 − 2 .. o0 + 1
                    w0, w1, w2, w3 = f1 * side, f1 * centre + f0 * side, f0 * centre + f1 * side, f0 * side
                    g = o0 - 2
                else:  # taps o0 − 1 .. o0 + 2
                    w0, w1, w2, w3 = f0 * side, f0 * centre + f1 * side, f1 * centre + f0 * side, f1 * side
                    g = o0 - 1
                # views, so that every index is the loop's own (no negative-index wrap to check)
                q0, q1, q2, q3 = q[g:g + m], q[g + 1:g + 1 + m], q[g + 2:g + 2 + m], q[g + 3:g + 3 + m]
                for i in range(m):
                    v = w0 * q0[i] + w1 * q1[i] + w2 * q2[i] + w3 * q3[i] + base
                    pm[i] += v
                    x = v * eu[i]
                    o[i] = x
                    acc += x
            else:
                if read:
                    for i in range(w):
                        x = xa + i
                        sx = seg[x]
                        src = x - step
                        v = 0.0
                        if 0 <= src < n and seg[src] == sx:
                            v = f0 * q[src - qa]
                            if f1 > 0.0:
                                src2 = src - sign[b]
                                if 0 <= src2 < n and seg[src2] == sx:
                                    v += f1 * q[src2 - qa]
                        sh[i] = v
                d = t0 - xa  # sh's index of place t0
                for i in range(m):
                    t = t0 + i
                    st = seg[t]
                    # a route end keeps the blur that would leave it
                    back = i + d - 1 if t > 0 and seg[t - 1] == st else i + d
                    ahead = i + d + 1 if t + 1 < n and seg[t + 1] == st else i + d
                    v = centre * sh[i + d] + side * (sh[back] + sh[ahead]) + base
                    pm[i] += v
                    x = v * eu[i]
                    o[i] = x
                    acc += x
            bins[k, b] = acc / unit
        lk = like[t0:t1]
        running = 0.0
        for i in range(m):
            running += pm[i] * et[i]
            lk[i] = running
        totals[k] = running


@njit
def _cumulate_blocks(like, totals, starts):  # pragma: no cover - compiled
    """Each block's cumulative of :func:`_jump_blocks` made the whole route's: the sums of
    the blocks before it added, in block order."""
    n = like.shape[0]
    offset = 0.0
    for k in range(totals.shape[0]):
        if k > 0:
            for t in range(starts[k], starts[k + 1]):
                like[t] += offset
        offset += totals[k]


_POOL = {}  # worker threads, by their number


def jump_threads(n_values: int) -> int:
    """Threads for a pass over ``n_values`` grid values: as many as the work is worth
    (:data:`catgraph.grid.LINE_WORK_PER_THREAD` values each), at most the cores not busy
    with other processes (:func:`catgraph.grid._cores_free`; a thread on a core another
    process holds stalls the pass for whole time slices)."""
    from .differences import _threads_available
    from .grid import LINE_WORK_PER_THREAD, _cores_free

    threads = min(_threads_available(), n_values // LINE_WORK_PER_THREAD)
    return _cores_free(threads) if threads > 1 else 1


def jump_step(s, out, seg, t_ptr, t_src, t_val, whole, frac, sign, reach, blur, c, a, jv, e, unit, starts,
              predicted, like, bins, totals, threads=None) -> None:
    """One prediction and update of the jump grid (module docstring), in one pass; the
    grids velocity-major, ``(n_bins, n_places)``.

    With ``J[b, t] = (c · blur(shift(T · s))[b, t] + a · jv[b]) · e[t]``: ``out = unit · J``
    (the stored grid in units of its predicted mass, so that its values stay of order
    ``1 / n`` however small its mass; ``s`` is not read where ``c == 0``); ``predicted[t] = Σ_b (c ·
    blur(shift(T · s))[b, t] + a · jv[b])``; ``like`` the cumulative of ``Σ_b J[b, t]`` over
    ``t``; ``bins[k, b]`` block ``k``'s ``Σ_t J[b, t]``. ``totals``: scratch, one per block
    (block ``k``: places ``starts[k] .. starts[k + 1] − 1``, :func:`block_starts`). Each block works
    from its own places of ``s`` and a halo of ``reach + 2`` places (the largest hop, one
    more for a split move, one for the blur) in its own buffers and writes its own places;
    the blocks are cut into :data:`JUMP_PIECES` fixed runs, each taken by whichever of
    ``threads`` threads is free (default :func:`jump_threads`; the kernel releases the
    GIL), so the floats are the same on any number of threads."""
    nb, n = out.shape
    blocks = bins.shape[0]
    halo = reach + 2
    read = c != 0.0
    centre = c * (1.0 - 2.0 * blur)
    side = c * blur
    if threads is None:
        threads = jump_threads(nb * n)
    args = (s, out, seg, t_ptr, t_src, t_val, whole, frac, sign, halo, centre, side, read, a, jv, e, unit, starts,
            predicted, like, bins, totals)
    threads = int(max(1, min(threads, blocks)))
    if threads == 1:
        _jump_blocks(*args, 0, blocks)
    else:
        pieces = min(blocks, JUMP_PIECES)
        queue = iter([(blocks * p // pieces, blocks * (p + 1) // pieces) for p in range(pieces)])
        if threads - 1 not in _POOL:
            from concurrent.futures import ThreadPoolExecutor

            _POOL[threads - 1] = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="catgraph-jumps")

        def take():
            for lo, hi in queue:
                _jump_blocks(*args, lo, hi)

        jobs = [_POOL[threads - 1].submit(take) for _ in range(threads - 1)]
        try:
            take()
        finally:
            for job in jobs:
                job.result()
    _cumulate_blocks(like, totals, starts)
