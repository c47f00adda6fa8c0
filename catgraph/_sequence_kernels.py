"""Compiled kernels for :mod:`catgraph.sequence` (numba, cached on disk: :func:`catgraph._jit.njit`).

Importing this module compiles nothing: numba compiles each kernel on its first call
(or loads it from the on-disk cache), so ``import catgraph`` stays cheap.
:mod:`catgraph.sequence` imports this module only when a matcher first runs.

The kernels trust their inputs (shapes, dtypes, ranges); the public functions in
:mod:`catgraph.sequence` validate first. The streaming matcher and the batch function
call the *same* kernels in the same order, so their results agree bit for bit.

Layout (see :mod:`catgraph.sequence`). Velocity ``v`` places query frame ``i`` at
reference offset ``pos_v(i) = floor(v * i + 1/2)``; the *line* ``c = j - pos_v(i)``
visits place ``c + pos_v(t)`` at frame ``t``. Lines are global, so one history serves
every velocity. Every stored value is an integer *code*, a multiple of the quantum
``u = state[0]`` that the first row fixes (:func:`unit_of`: ``u = 2^(e - 12)`` with
``max_j |d_0j| < 2^e``, so the first row's codes lie below ``2^12`` in magnitude; rows
of zeros before it, blank frames once normalised, are codes 0 in any quantum and leave
it unfixed, ``state[0] = 0``; ``state[1]``, where the state has it, counts the values
stored at the largest code):

``ring`` ``(R, N) int16``
    the last ``R >= l_max + 1`` difference rows, row ``t`` at ``ring[t % R]``, stored
    once on arrival (:func:`advance`) as ``code = rint(d / u)``, saturated at
    ``±CODE_MAX = ±32767``: a difference up to ``2^15 / 2^12 = 8`` times the first
    row's largest keeps its value to ``u / 2``; a larger one is stored as ``±32767 u``
    (it never wraps around). Every later use reads these codes: ``2 R`` bytes per place.
``mring`` ``(R,) int16``
    the mean code of each stored row, rounded to an integer (the fill for a term whose
    place lies outside ``[0, N)``).
``sums`` ``(V, G, N) int32``
    for each velocity and candidate length ``L``, the window sum of codes along every
    line that currently meets the reference, ``S_{v,L}(i, c) = sum_{t=i-L_eff+1}^{i}
    code(t, c)`` with ``L_eff = min(L, i + 1)`` and ``code(t, c)`` the code of
    ``d[t, c + pos_v(t)]`` (the row's mean code outside the reference): ``4 V G`` bytes
    per place. ``|S| <= l_max * 32767 < 2^31`` for ``l_max <= 65,538``, so integer
    arithmetic is exact (the matcher keeps ``int64`` sums for longer windows). Line
    ``c`` lives in slot ``c mod N``: the ``N`` lines meeting the reference at any frame
    are ``N`` consecutive integers, so a line that leaves hands its slot to the one that
    enters.

One frame updates each sum in ``O(1)``:
``S(i, c) = S(i - 1, c) + code(i, c) - code(i - L, c)`` (no subtraction while
``i < L``); a line entering the reference at frame ``i`` was outside for all earlier
frames, so it starts from the sum of the row means of the window's earlier frames.
Integer sums never drift: the running sums equal a window summed term by term
(:func:`direct_scores`) exactly, after any number of frames, and places whose windows
tie exactly keep tying. A score is ``S u / L_eff``, converted to float64 once where it
is divided; against the float64 score of the same differences it is off by at most
``u / 2`` (each term by at most ``u / 2``), plus the saturation of terms beyond
``32767 u``.

The streaming and the batch form both call :func:`run_batch` (one row, or blocks of
rows with a ring a few rows longer), which stores the rows and runs the same compiled
per-velocity code (:func:`run_velocities`, or for the default approximation
:func:`run_velocities_exact`, compiled without the median and the mixture fit) on the same
stored codes in the same order, so their results agree bit for bit; the velocities
are shared among threads, each writing only its own sums and outputs.

The hot loop (:func:`_update_stats`, per frame, velocity and window) is one pass over
the places, cut into stretches whose slots are contiguous and whose old term is of one
kind, and those into chunks of :data:`CHUNK` places, each a plain loop over
equal-length views that the compiler vectorises (integer additions, float64 moments of
``y = S - shift``, the smallest ``S``): it updates the sums, accumulates the window's
moments and takes the chunk's smallest sum in the same loop. Nothing is divided or
copied per place: the statistics are taken on the integer sums ``S`` and scaled by
``u / L_eff`` once (the order, and so the best place and the best and second-best
scores, are the same). A chunk never crosses a multiple of :data:`CHUNK` places, so its
minimum is the minimum of one block of :data:`CHUNK` places; the best place is then
searched in the first block holding the smallest minimum, and the second best reads the
minima of the blocks clear of the excluded radius and vectorised minima over the places
of the (one or two) blocks it meets. Measured at ``N = 10^5`` (one thread, CPU time,
medians of 31 interleaved runs on the shared machine): taking the minima in the update
loop instead of a second pass over blocks of 256 places, 13.8 -> 12.3 ms per frame for
the eight velocities; the moments' vectorised order is unchanged by the extra
reduction (the same machine code for them; ``tests/test_matcher_identity.py`` holds
digests of the outputs before the change, including rows whose moments round). What
kept earlier loops scalar: the block bounds computed inside a loop over blocks (the
compiler then vectorises neither the minimum nor the sums), a floating-point minimum
(needs ``nnan`` on the whole function), and floating-point sums without reassociation;
a per-place division cost as much again as the update. Splitting the update into an
integer pass and a moments pass keeps the same bits but costs more (measured: 8.9 ->
9.9 ms); the moments are about a third of the loop's time and their order fixes their
bits, so they stay as they are.

Cold compile. numba compiles every kernel into a code library of its own, links the
libraries of the kernels it calls into it, and then optimises and generates machine code
for the linked whole once more, so code ``k`` kernels deep is optimised and generated
``k`` times. Measured on the first default adaptive call with an empty
``NUMBA_CACHE_DIR`` (numba's compile events, one signature per kernel: nothing compiles
twice, no second dtype path), LLVM took about 60 % of the time and the four levels above
:func:`_stretch` (the per-velocity loop, its per-window wrapper, :func:`_window`,
:func:`_update_stats`) each spent 0.5 to 1.2 s re-optimising and re-generating the same
update below them. The kernels with one call site whose body is not a loop that must
vectorise on its own are therefore inlined into their caller by numba
(``inline="always"``: :func:`_velocity_stats_gaussian`, :func:`_window`,
:func:`_stretch`, :func:`_fill_sum`, :func:`score_at`, :func:`encode`,
:func:`unit_of`). The vectorised loops (:func:`_add_row` and its two variants with their
fast-math flags, :func:`_block_min`) stay kernels of their own, compiled exactly as
before, and so does :func:`_update_stats` (inlining it costs more in numba's typing than
it saves); the results are bit-identical. Measured in one run (``bench_matcher.py
--out matcher_compile``, medians of 3 processes, CPU seconds): cold first call 7.6 s ->
5.3 s, warm load from the cache 0.45 s -> 0.46 s, streaming step at ``N = 10^5``
9.9 ms -> 10.0 ms (noise); the mixture path, compiled only when asked for, 6.3 s ->
6.6 s.

Exact moments (the default approximation: :func:`run_velocities_exact`). The moments are
sums of the integers ``y = S - shift`` and ``y^2``; while the sum of ``y^2`` over a window's
places stays below ``2^53``, every partial sum is exact in float64 in any order, so
:func:`_update_stats_exact` adds the int32 sums in int32 lanes (twice as many places per
vector) and the moments in whatever order the compiler vectorises, and gets the bits of
:func:`_update_stats`. A window beyond ``2^53`` (long windows of large, alike codes; every
window of the benchmark rows stays below it) is marked, the kernel returns after that
frame, and :func:`_settle_window` adds its moments again in the order of
:func:`_update_stats` from the sums as that frame left them (:func:`_run_exact`), compiled
only when first needed; the robust and mixture approximations (:func:`run_velocities`) run on
the same update, the mixture fitted again from a settled window's moments. Measured
(``benchmarks/results/matcher_step.md``): the one-thread step at ``N = 10^5`` 8.15 ->
6.75 ms, whole Nordland 2.31 -> 1.76 s, but 3-5 % of the CPU where the sums come from
memory; the cold first call within the spread of before (the fallback compiled into the
kernel instead cost 2.1 s more). :func:`run_velocities_gaussian` (the update of
:func:`_update_stats`) stays the reference.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit

APPROX_GAUSSIAN = 0
APPROX_ROBUST = 1
APPROX_GMM = 2

#: the largest stored code in magnitude (int16, symmetric: larger values saturate)
CODE_MAX = 32767
#: the first row's largest difference lies below ``2**FIRST_ROW_BITS`` quanta
FIRST_ROW_BITS = 12
#: block minimum of a block with no place (larger than any sum)
_NONE = np.int64(1) << 62


def sums_dtype(l_max):
    """``int32`` running sums where ``l_max * CODE_MAX < 2**31`` (any ``l_max <= 65,538``),
    else ``int64``: integer window sums never overflow."""
    return np.int32 if int(l_max) * CODE_MAX < 2**31 else np.int64


@njit
def position(v, i):
    """``pos_v(i) = floor(v * i + 1/2)`` (int)."""
    return np.int64(np.floor(v * i + 0.5))


@njit(inline="always")
def unit_of(d_row):
    """The quantum ``u = 2**(e - FIRST_ROW_BITS)`` fixed by the first row, ``max|d_0j| < 2**e``."""
    top = 0.0
    for j in range(d_row.shape[0]):
        a = abs(d_row[j])
        if a > top:
            top = a
    _, e = math.frexp(top)  # top = m 2**e, 0.5 <= m < 1 (e = 0 for a zero row)
    return math.ldexp(1.0, e - FIRST_ROW_BITS)


@njit(inline="always")
def quantum_of(d_row):
    """:func:`unit_of` of a row, or 0 for a row of zeros (no scale to fix)."""
    for j in range(d_row.shape[0]):
        if d_row[j] != 0.0:
            return unit_of(d_row)
    return 0.0


@njit(inline="always")
def encode(x, unit):
    """``x`` as a code: ``rint(x / unit)`` saturated at ``±CODE_MAX`` (int64)."""
    c = np.rint(x / unit)
    if c > CODE_MAX:
        c = CODE_MAX
    elif c < -CODE_MAX:
        c = -CODE_MAX
    return np.int64(c)


@njit(inline="always")
def encode_scaled(x, inv):
    """:func:`encode` with the reciprocal of the quantum: ``x * inv`` is ``x / unit`` exactly
    where ``unit`` is a power of two whose reciprocal is a float64 (both are ``x 2^-k``,
    rounded once)."""
    c = np.rint(x * inv)
    if c > CODE_MAX:
        c = CODE_MAX
    elif c < -CODE_MAX:
        c = -CODE_MAX
    return np.int64(c)


@njit
def advance(ring, mring, state, i, d_row):
    """Store query frame ``i``'s row as codes in ``ring[i % R]`` and its mean code in
    ``mring``; the first row that is not all zeros fixes the quantum ``state[0]`` (0
    until then: a blank first frame, normalised to zeros, is all codes 0 in any
    quantum, and would otherwise fix ``2^-12``, saturating every later difference
    beyond ±8)."""
    if i == 0:
        state[0] = 0.0
    if state[0] == 0.0:
        state[0] = quantum_of(d_row)
    unit = state[0]
    r = ring.shape[0]
    out = ring[i % r]
    n = d_row.shape[0]
    if unit == 0.0:  # every value 0 so far
        for j in range(n):
            out[j] = 0
        mring[i % r] = 0
        return
    total = 0
    inv = 1.0 / unit  # a power of two: d * inv is d / unit, the same float (one multiplication, not a division)
    if inv < np.inf:
        for j in range(n):
            c = encode_scaled(d_row[j], inv)
            out[j] = c
            total += c
    else:  # a row of subnormal differences: 1 / unit is beyond float64
        for j in range(n):
            c = encode(d_row[j], unit)
            out[j] = c
            total += c
    mring[i % r] = np.int64(np.rint(total / n))
    if state.shape[0] > 1:  # state[1] counts the values stored at the largest code (clipped there)
        clipped = 0
        for j in range(n):
            if out[j] == CODE_MAX or out[j] == -CODE_MAX:
                clipped += 1
        state[1] += clipped


@njit(inline="always")
def _fill_sum(mring, i, eff):
    """Sum of the mean codes of frames ``i - eff + 1 .. i - 1`` (a new line's earlier terms)."""
    r = mring.shape[0]
    total = 0
    for t in range(i - eff + 1, i):
        total += np.int64(mring[t % r])
    return total


# Fast-math flags for the update loops below: reassociation lets the compiler keep the
# float64 moments in vector lanes. The window sums are integers (exact in any order), and
# so is each ``y = S - shift`` in float64; the moments' order is the compiler's, but fixed
# for one compiled kernel and one row length, and the streaming and the batch forms run
# the same kernel on the same codes, so their results still agree bit for bit.
_REDUCE = {"reassoc", "nsz", "contract"}


@njit(fastmath=_REDUCE)
def _add_row(sums, cur, shift):
    """``S += cur``; returns the sums of ``y = S - shift`` and ``y^2`` in float64 and the
    smallest updated ``S`` (int64) (equal-length, non-empty views: one plain loop the
    compiler vectorises; the sum of ``y`` is exact while its partial sums stay below
    ``2^53``, e.g. for ``N < 2^21`` places).

    Each new sum is formed in int64 (exact: ``|S| < 2^31`` for int32 sums) and stored;
    the minimum is one more vector reduction in the same loop, beside the moments, whose
    vectorised order (four accumulators of four lanes each, added in a fixed tree) it
    leaves as it was without it: ``y`` has the same value converted from int64 as from
    the stored int32, and the moments' bits are those of the loop without the minimum
    (``tests/test_matcher_identity.py``, with window sums whose squares' sum rounds)."""
    a = 0.0
    q = 0.0
    m = sums[0] + cur[0]  # the first updated sum
    for k in range(sums.shape[0]):
        x = sums[k] + cur[k]
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit(fastmath=_REDUCE)
def _add_row_fill(sums, cur, fill, shift):
    """``S += cur - fill`` (the old term outside the reference); the sums of ``y`` and
    ``y^2`` and the smallest sum as :func:`_add_row`."""
    a = 0.0
    q = 0.0
    m = sums[0] + (cur[0] - fill)
    for k in range(sums.shape[0]):
        x = sums[k] + (cur[k] - fill)
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit(fastmath=_REDUCE)
def _add_row_old(sums, cur, old, shift):
    """``S += cur - old``; the sums of ``y`` and ``y^2`` and the smallest sum as
    :func:`_add_row`."""
    a = 0.0
    q = 0.0
    m = sums[0] + (cur[0] - old[0])
    for k in range(sums.shape[0]):
        x = sums[k] + (cur[k] - old[k])
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit
def _block_min(seg):
    """The smallest of some integer sums (a plain loop the compiler vectorises)."""
    m = seg[0]
    for j in range(1, seg.shape[0]):
        x = seg[j]
        m = x if x < m else m
    return m


@njit
def _segment_min(seg, j_lo, bmin):
    """Fold the sums ``seg`` of places ``j_lo ..`` into the minima ``bmin`` of their
    blocks of :data:`BLOCK` places (exact: a minimum does not depend on the order).
    A separate pass over freshly written sums; the matcher now takes each chunk's
    minimum in its update loop (:func:`_add_row`) instead."""
    j_hi = j_lo + seg.shape[0]
    if j_hi <= j_lo:
        return
    for blk in range(j_lo // BLOCK, (j_hi - 1) // BLOCK + 1):
        a = blk * BLOCK if blk * BLOCK > j_lo else j_lo
        b = (blk + 1) * BLOCK if (blk + 1) * BLOCK < j_hi else j_hi
        m = np.int64(_block_min(seg[a - j_lo:b - j_lo]))
        if m < bmin[blk]:
            bmin[blk] = m


#: places updated per call of the update loops, and places per block of the block
#: minima: a chunk never crosses a multiple of CHUNK, so its minimum (taken in the update
#: loop) folds into the minimum of one block
CHUNK = 2048


@njit
def _block_places(n, bmin):
    """Places per block of the block minima ``bmin`` of ``n`` places: :data:`CHUNK` (the
    matcher's: each chunk's minimum is taken in its update loop) or, for an array sized
    for them, :data:`BLOCK` (a separate pass, :func:`_segment_min`). The two sizes give
    different block counts beyond ``BLOCK`` places; below, one block holds every place."""
    return CHUNK if bmin.shape[0] == (n + CHUNK - 1) // CHUNK else BLOCK


@njit(inline="always")
def _stretch(sums_g, cur, old, fill, kind, lo, hi, sh, off, shift, bmin):
    """Places ``[lo, hi)`` (slots ``lo + sh ..``) of one kind of old term (``kind`` 0:
    none yet, 1: the old row, place ``j - off``; 2: outside, the fill), in chunks of
    :data:`CHUNK` places: update the sums, the moments and the chunk's smallest sum in one
    loop, and fold that minimum into its block's (block ``c // CHUNK``: a chunk lies in
    one block; :func:`_segment_min` instead where ``bmin`` holds blocks of :data:`BLOCK`
    places). Returns the sums of ``y`` and ``y^2``."""
    sa = 0.0
    sq = 0.0
    c = lo
    while c < hi:
        e = (c // CHUNK + 1) * CHUNK
        e = e if e < hi else hi
        if kind == 0:
            da, dq, m = _add_row(sums_g[c + sh:e + sh], cur[c:e], shift)
        elif kind == 1:
            da, dq, m = _add_row_old(sums_g[c + sh:e + sh], cur[c:e], old[c - off:e - off], shift)
        else:
            da, dq, m = _add_row_fill(sums_g[c + sh:e + sh], cur[c:e], fill, shift)
        sa += da
        sq += dq
        if bmin.shape[0] == (sums_g.shape[0] + CHUNK - 1) // CHUNK:  # blocks of CHUNK places
            m = np.int64(m)
            if m < bmin[c // CHUNK]:
                bmin[c // CHUNK] = m
        else:  # blocks of BLOCK places: a pass over the fresh sums
            _segment_min(sums_g[c + sh:e + sh], c, bmin)
        c = e
    return sa, sq


@njit
def _update_stats(sums_g, ring, mring, i, v, length, shift, bmin):
    """Advance one velocity's window sums of length ``length`` to frame ``i``; returns
    the sums of ``y = S - shift`` and ``y^2`` (float64) over the places and writes the
    minimum sum of every block of places into ``bmin`` (int64; blocks of :data:`CHUNK`
    places, or of :data:`BLOCK` where ``bmin`` is sized for them, :func:`_block_places`).

    One pass: each stretch of places whose slots are contiguous and whose old term is of
    one kind (none yet, inside the reference, outside it) is cut into chunks of
    :data:`CHUNK` places (:func:`_stretch`), each a plain vectorised loop over
    equal-length views (:func:`_add_row`, ...) that updates the sums and accumulates the
    moments; the chunk's block minima follow from the freshly written sums while they
    are still in the first-level cache. No per-place division and no copy: the scores are ``S u / L_eff`` and the
    callers scale once per statistic (or per place, :func:`scores_from_sums`, where
    they need the scores themselves).
    """
    r = ring.shape[0]
    n = sums_g.shape[0]
    for blk in range(bmin.shape[0]):
        bmin[blk] = _NONE
    cur = ring[i % r]
    p = position(v, i)
    sbase = p % n  # slot of place j is (j - sbase) mod N
    eff = length if length <= i + 1 else i + 1
    fshift = np.float64(shift)
    sa = 0.0
    sq = 0.0
    # places whose line enters the reference at this frame: [e_lo, e_hi)
    if i == 0:
        e_lo = 0
        e_hi = n
    else:
        delta = p - position(v, i - 1)
        if delta >= n or delta <= -n:
            e_lo = 0
            e_hi = n
        elif delta > 0:
            e_lo = 0
            e_hi = delta
        elif delta < 0:
            e_lo = n + delta
            e_hi = n
        else:
            e_lo = 0
            e_hi = 0
    if e_hi > e_lo:
        block = _block_places(n, bmin)
        fill = _fill_sum(mring, i, eff)
        for j in range(e_lo, e_hi):
            slot = j - sbase
            if slot < 0:
                slot += n
            val = fill + np.int64(cur[j])
            sums_g[slot] = val
            y = np.float64(val) - fshift
            sa += y
            sq += y * y
            blk = j // block
            if val < bmin[blk]:
                bmin[blk] = val
    # the other places continue their line: [0, e_lo) and [e_hi, n)
    if i >= length:
        old = ring[(i - length) % r]
        m_old = np.int32(mring[(i - length) % r])
        off = p - position(v, i - length)  # the line through j met place j - off then
    else:
        old = cur
        m_old = np.int32(0)
        off = 0
    for part in range(2):
        a = 0 if part == 0 else e_hi
        b = e_lo if part == 0 else n
        if b <= a:
            continue
        # slots wrap at j = sbase
        for seg in range(2):
            lo = a if seg == 0 else (sbase if sbase > a else a)
            hi = (sbase if sbase < b else b) if seg == 0 else b
            if hi <= lo:
                continue
            sh = n - sbase if seg == 0 else -sbase
            if i < length:  # no old term yet: one stretch
                k_lo = lo
                k_hi = lo
            else:  # the old term lies inside the reference for j - off in [0, n)
                k_lo = off if off > lo else lo
                k_hi = n + off if n + off < hi else hi
                if k_hi < k_lo:
                    k_lo = hi
                    k_hi = hi
            # [lo, k_lo) and [k_hi, hi): old term outside (or none yet); [k_lo, k_hi): inside.
            # One call site for every kind keeps the compiled code (and the compile) small.
            for q in range(3):
                s_lo = lo if q == 0 else (k_lo if q == 1 else k_hi)
                s_hi = k_lo if q == 0 else (k_hi if q == 1 else hi)
                kind = 1 if q == 1 else (0 if i < length else 2)
                da, dq = _stretch(sums_g, cur, old, m_old, kind, s_lo, s_hi, sh, off, fshift, bmin)
                sa += da
                sq += dq
    return sa, sq


#: ``2^53``: a float64 sum of integers whose every partial sum stays below it is exact
_EXACT = 2.0 ** 53


@njit(fastmath=_REDUCE)
def _add_row_exact(sums, cur, shift):
    """:func:`_add_row` in int32 lanes (twice as many per vector) and in the compiler's own
    order of the moments; the same sums, the same smallest sum and, while the result is
    below :data:`_EXACT`, the same moments (:func:`_update_stats_exact`)."""
    a = 0.0
    q = 0.0
    m = np.int32(sums[0] + cur[0])
    for k in range(sums.shape[0]):
        x = np.int32(sums[k] + cur[k])
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit(fastmath=_REDUCE)
def _add_row_fill_exact(sums, cur, fill, shift):
    """:func:`_add_row_fill` as :func:`_add_row_exact`."""
    a = 0.0
    q = 0.0
    m = np.int32(sums[0] + (cur[0] - fill))
    for k in range(sums.shape[0]):
        x = np.int32(sums[k] + (cur[k] - fill))
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit(fastmath=_REDUCE)
def _add_row_old_exact(sums, cur, old, shift):
    """:func:`_add_row_old` as :func:`_add_row_exact`."""
    a = 0.0
    q = 0.0
    m = np.int32(sums[0] + (cur[0] - old[0]))
    for k in range(sums.shape[0]):
        x = np.int32(sums[k] + (cur[k] - old[k]))
        sums[k] = x
        m = x if x < m else m
        y = np.float64(x) - shift
        a += y
        q += y * y
    return a, q, m


@njit(inline="always")
def _stretch_exact(sums_g, cur, old, fill, kind, lo, hi, sh, off, shift, bmin):
    """:func:`_stretch` (blocks of :data:`CHUNK` places) with the int32 loops of
    :func:`_add_row_exact`."""
    sa = 0.0
    sq = 0.0
    c = lo
    while c < hi:
        e = (c // CHUNK + 1) * CHUNK
        e = e if e < hi else hi
        if kind == 0:
            da, dq, m = _add_row_exact(sums_g[c + sh:e + sh], cur[c:e], shift)
        elif kind == 1:
            da, dq, m = _add_row_old_exact(sums_g[c + sh:e + sh], cur[c:e], old[c - off:e - off], shift)
        else:
            da, dq, m = _add_row_fill_exact(sums_g[c + sh:e + sh], cur[c:e], fill, shift)
        sa += da
        sq += dq
        m = np.int64(m)
        if m < bmin[c // CHUNK]:
            bmin[c // CHUNK] = m
        c = e
    return sa, sq


@njit
def _update_stats_exact(sums_g, ring, mring, i, v, length, shift, bmin):
    """:func:`_update_stats` (blocks of :data:`CHUNK` places) with the same results, bit for bit,
    in fewer instructions.

    The sums and the block minima are integers, the same in any order and lane width. The
    moments are sums of the integers ``y = S - shift`` and ``y^2``, held exactly in float64
    while every partial sum stays below :data:`_EXACT` = ``2^53``. The terms ``y^2`` are not
    negative, so a rounded partial sum of them can only be at least ``2^53`` once the true one
    is (rounding is monotone and ``2^53`` is a float64): where the sum of ``y^2`` comes out
    below ``2^53`` (and ``N < 2^21``, so that ``|sum y| <= sqrt(N sum y^2) < 2^37``), every
    partial sum of both moments was exact, in this order and in the order of
    :func:`_update_stats`, and the two agree bit for bit. That holds for every window measured
    on normalised rows at ``N = 10^5`` (``y`` a few thousand codes times ``sqrt(L)``). Returns
    the sums of ``y`` and ``y^2`` and whether they are exact; where they are not (long windows
    of large, alike codes) the caller adds the moments again from the updated sums in the
    order of :func:`_update_stats` itself (:func:`_settle_window`). That fallback is called
    from Python and compiled only when a window first needs it: compiled into this kernel, the
    second set of update loops cost 2.1 s more of every cold first call, for a case that
    normalised rows rarely reach.

    The update loops add the int32 sums in int32 lanes (a sum is stored as int32 anyway and
    never overflows it), so a vector holds twice as many places as in :func:`_add_row`, and
    the moments are added in whatever order the compiler vectorises them.
    """
    r = ring.shape[0]
    n = sums_g.shape[0]
    for blk in range(bmin.shape[0]):
        bmin[blk] = _NONE
    cur = ring[i % r]
    p = position(v, i)
    sbase = p % n
    eff = length if length <= i + 1 else i + 1
    fshift = np.float64(shift)
    sa = 0.0
    sq = 0.0
    if i == 0:
        e_lo = 0
        e_hi = n
    else:
        delta = p - position(v, i - 1)
        if delta >= n or delta <= -n:
            e_lo = 0
            e_hi = n
        elif delta > 0:
            e_lo = 0
            e_hi = delta
        elif delta < 0:
            e_lo = n + delta
            e_hi = n
        else:
            e_lo = 0
            e_hi = 0
    if e_hi > e_lo:
        fill = _fill_sum(mring, i, eff)
        for j in range(e_lo, e_hi):
            slot = j - sbase
            if slot < 0:
                slot += n
            val = fill + np.int64(cur[j])
            sums_g[slot] = val
            y = np.float64(val) - fshift
            sa += y
            sq += y * y
            blk = j // CHUNK
            if val < bmin[blk]:
                bmin[blk] = val
    if i >= length:
        old = ring[(i - length) % r]
        m_old = np.int32(mring[(i - length) % r])
        off = p - position(v, i - length)
    else:
        old = cur
        m_old = np.int32(0)
        off = 0
    for part in range(2):
        a = 0 if part == 0 else e_hi
        b = e_lo if part == 0 else n
        if b <= a:
            continue
        for seg in range(2):
            lo = a if seg == 0 else (sbase if sbase > a else a)
            hi = (sbase if sbase < b else b) if seg == 0 else b
            if hi <= lo:
                continue
            sh = n - sbase if seg == 0 else -sbase
            if i < length:
                k_lo = lo
                k_hi = lo
            else:
                k_lo = off if off > lo else lo
                k_hi = n + off if n + off < hi else hi
                if k_hi < k_lo:
                    k_lo = hi
                    k_hi = hi
            for q in range(3):
                s_lo = lo if q == 0 else (k_lo if q == 1 else k_hi)
                s_hi = k_lo if q == 0 else (k_hi if q == 1 else hi)
                kind = 1 if q == 1 else (0 if i < length else 2)
                da, dq = _stretch_exact(sums_g, cur, old, m_old, kind, s_lo, s_hi, sh, off, fshift, bmin)
                sa += da
                sq += dq
    return sa, sq, sq < _EXACT and n < (1 << 21)


@njit
def _replay_moments(sums_g, i, v, length, shift, e_lo, e_hi, zeros):
    """The moments of :func:`_update_stats` in its own order, from sums already updated to
    frame ``i``: the same traversal (entering places, then the stretches and chunks) and the
    same compiled loops (:func:`_add_row`, ...) adding a row of zeros (``zeros``: int16,
    ``N``), which leaves the sums as they are."""
    n = sums_g.shape[0]
    p = position(v, i)
    sbase = p % n
    fshift = np.float64(shift)
    bmin = np.empty((n + CHUNK - 1) // CHUNK, dtype=np.int64)
    sa = 0.0
    sq = 0.0
    for j in range(e_lo, e_hi):
        slot = j - sbase
        if slot < 0:
            slot += n
        y = np.float64(np.int64(sums_g[slot])) - fshift
        sa += y
        sq += y * y
    off = p - position(v, i - length) if i >= length else 0
    for part in range(2):
        a = 0 if part == 0 else e_hi
        b = e_lo if part == 0 else n
        if b <= a:
            continue
        for seg in range(2):
            lo = a if seg == 0 else (sbase if sbase > a else a)
            hi = (sbase if sbase < b else b) if seg == 0 else b
            if hi <= lo:
                continue
            sh = n - sbase if seg == 0 else -sbase
            if i < length:
                k_lo = lo
                k_hi = lo
            else:
                k_lo = off if off > lo else lo
                k_hi = n + off if n + off < hi else hi
                if k_hi < k_lo:
                    k_lo = hi
                    k_hi = hi
            for q in range(3):
                s_lo = lo if q == 0 else (k_lo if q == 1 else k_hi)
                s_hi = k_lo if q == 0 else (k_hi if q == 1 else hi)
                kind = 1 if q == 1 else (0 if i < length else 2)
                da, dq = _stretch(sums_g, zeros, zeros, np.int32(0), kind, s_lo, s_hi, sh, off, fshift, bmin)
                sa += da
                sq += dq
    return sa, sq


@njit(nogil=True)
def scores_from_sums(sums_g, i, v, length, unit, s):
    """Scores ``s_ij(L, v) = S u / L_eff`` in place order into ``s``."""
    n = s.shape[0]
    eff = length if length <= i + 1 else i + 1
    sbase = position(v, i) % n
    for j in range(0, sbase):
        s[j] = np.float64(sums_g[j + n - sbase]) * unit / eff
    for j in range(sbase, n):
        s[j] = np.float64(sums_g[j - sbase]) * unit / eff


@njit(inline="always")
def score_at(sums_g, i, v, length, unit, j):
    """One score ``s_ij(L, v)`` from the window sums (same arithmetic as :func:`scores_from_sums`)."""
    n = sums_g.shape[0]
    eff = length if length <= i + 1 else i + 1
    slot = j - position(v, i) % n
    if slot < 0:
        slot += n
    return np.float64(sums_g[slot]) * unit / eff


@njit(nogil=True)
def direct_scores(ring, mring, i, v, length, unit, s):
    """Scores of any length ``L <= R - 1`` summed term by term from the ring (``O(N L)``).

    For lengths outside the candidate grid; the same codes as the running sums, added
    in time order (int64, exact).
    """
    r = ring.shape[0]
    n = s.shape[0]
    eff = length if length <= i + 1 else i + 1
    p = position(v, i)
    acc = np.zeros(n, dtype=np.int64)
    for t in range(i - eff + 1, i + 1):
        row = ring[t % r]
        m = np.int64(mring[t % r])
        off = p - position(v, t)
        for j in range(n):
            k = j - off
            if 0 <= k < n:
                acc[j] += row[k]
            else:
                acc[j] += m
    for j in range(n):
        s[j] = np.float64(acc[j]) * unit / eff


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


#: places per block of :func:`_segment_min` (the matcher's own block minima are per
#: :data:`CHUNK` places, taken in its update loops)
BLOCK = 256


@njit
def _places_min(sums_g, sbase, a, b):
    """The smallest sum of places ``[a, b)`` (``_NONE`` if none), place ``j`` in slot
    ``(j - sbase) mod N``: at most two contiguous runs of slots, each one vectorised
    minimum (:func:`_block_min`)."""
    n = sums_g.shape[0]
    m = _NONE
    if b <= a:
        return m
    if a < sbase:
        hi = b if b < sbase else sbase
        x = np.int64(_block_min(sums_g[a - sbase + n:hi - sbase + n]))
        m = x if x < m else m
    if b > sbase:
        lo = a if a > sbase else sbase
        x = np.int64(_block_min(sums_g[lo - sbase:b - sbase]))
        m = x if x < m else m
    return m


@njit
def _first_place(sums_g, sbase, a, b, value):
    """The first place in ``[a, b)`` whose sum is ``value`` (``b`` if none), in place
    order over the (at most two) contiguous runs of slots."""
    n = sums_g.shape[0]
    if a < sbase:
        hi = b if b < sbase else sbase
        seg = sums_g[a - sbase + n:hi - sbase + n]
        for t in range(seg.shape[0]):
            if seg[t] == value:
                return a + t
    if b > sbase:
        lo = a if a > sbase else sbase
        seg = sums_g[lo - sbase:b - sbase]
        for t in range(seg.shape[0]):
            if seg[t] == value:
                return lo + t
    return b


@njit
def _best_and_second(sums_g, sbase, bmin, radius):
    """The first place of the smallest sum, that sum, and the smallest sum more than
    ``radius`` places away (``_NONE`` if none), from the minima ``bmin`` of the blocks of
    places (:func:`_block_places`; place ``j`` in slot ``(j - sbase) mod N``): the first block
    holding the smallest minimum is searched for its first place with that sum; a block
    clear of the excluded places ``[jb - radius, jb + radius]`` gives its minimum, one
    that meets them the minima of its places either side (:func:`_places_min`)."""
    n = sums_g.shape[0]
    nb = bmin.shape[0]
    block = _block_places(n, bmin)
    kb = 0
    for blk in range(1, nb):
        if bmin[blk] < bmin[kb]:
            kb = blk
    vb = bmin[kb]
    b_end = kb * block + block if kb * block + block < n else n
    jb = _first_place(sums_g, sbase, kb * block, b_end, vb)
    lo = jb - radius  # places in [lo, hi] are excluded
    hi = jb + radius
    v2 = _NONE
    for blk in range(nb):
        b_lo = blk * block
        b_hi = b_lo + block if b_lo + block < n else n  # exclusive
        if b_hi <= lo or b_lo > hi:
            if bmin[blk] < v2:
                v2 = bmin[blk]
        else:
            x = _places_min(sums_g, sbase, b_lo, lo if lo < b_hi else b_hi)
            v2 = x if x < v2 else v2
            x = _places_min(sums_g, sbase, hi + 1 if hi + 1 > b_lo else b_lo, b_hi)
            v2 = x if x < v2 else v2
    return jb, vb, v2


@njit(inline="always")
def _window(sums_g, ring, mring, i, v, length, unit, radius, bmin, g, best_j, best_s, second_s, mean, std):
    """Advance one window's sums to frame ``i`` and write its best place, best and
    second-best score, mean and spread into the outputs at ``g``.

    Everything is computed on the integer sums and scaled by ``u / L_eff`` once at the
    end, not per place. The best and second-best scores are those of the places with
    the smallest sums (a positive factor keeps the order; ``S u`` is exact in float64,
    so ``min(S) u / L_eff`` has the bits of that place's own score). Mean and spread
    from the update's one pass, shifted by the sum in place 0's slot before the update
    (``var = E[y^2] - E[y]^2`` with ``y = S - shift``: a recent sum of the same window,
    so no cancellation unless it lies many spreads from the mean; ``E[y]`` from an exact
    integer sum); the best and second-best from the minima of blocks of places.
    """
    n = sums_g.shape[0]
    sbase = position(v, i) % n
    shift = np.int64(sums_g[n - sbase if sbase > 0 else 0])
    eff = length if length <= i + 1 else i + 1
    sy, syy = _update_stats(sums_g, ring, mring, i, v, length, shift, bmin)
    _best_out(sums_g, sbase, bmin, radius, unit, eff, g, best_j, best_s, second_s)
    _moments_out(n, sy, syy, shift, unit, eff, g, mean, std)


@njit(inline="always")
def _best_out(sums_g, sbase, bmin, radius, unit, eff, g, best_j, best_s, second_s):
    """A window's best place and its best and second-best scores into the outputs at ``g``."""
    jb, vb, v2 = _best_and_second(sums_g, sbase, bmin, radius)
    best_j[g] = jb
    best_s[g] = np.float64(vb) * unit / eff
    second_s[g] = np.inf if v2 == _NONE else np.float64(v2) * unit / eff


@njit(inline="always")
def _moments_out(n, sy, syy, shift, unit, eff, g, mean, std):
    """A window's mean and spread from the sums ``sy`` and ``syy`` of ``y = S - shift`` and
    ``y^2`` over its ``n`` places, into the outputs at ``g`` (the one copy of this arithmetic:
    the kernels and the fallback of :func:`_settle_window` give the same floats)."""
    my = sy / n
    var = syy / n - my * my
    mean[g] = (shift + my) * unit / eff
    std[g] = np.sqrt(var) * unit / eff if var > 0.0 else 0.0


@njit(inline="always")
def _window_exact(sums_g, ring, mring, i, v, length, unit, radius, bmin, g, best_j, best_s, second_s, mean, std):
    """:func:`_window` with the update of :func:`_update_stats_exact`; returns whether the
    moments were exact and the ``shift`` they were taken about (the mean and the spread
    written at ``g`` are those of the window only where they were exact)."""
    n = sums_g.shape[0]
    sbase = position(v, i) % n
    shift = np.int64(sums_g[n - sbase if sbase > 0 else 0])
    eff = length if length <= i + 1 else i + 1
    sy, syy, exact = _update_stats_exact(sums_g, ring, mring, i, v, length, shift, bmin)
    _best_out(sums_g, sbase, bmin, radius, unit, eff, g, best_j, best_s, second_s)
    _moments_out(n, sy, syy, shift, unit, eff, g, mean, std)
    return exact, shift


@njit
def _settle_window(sums_g, i, v, length, unit, shift, g, approx, n_iter, em_stride, mean, std, weights, locs, scales,
                   s, resp):
    """The fallback of :func:`_update_stats_exact`: a window's mean and spread from the moments
    added again in the order of :func:`_update_stats`, from the sums just updated to frame ``i``
    (:func:`_replay_moments`), and the approximation that reads them (the Gaussian component;
    the mixture, fitted again from the window's scores; the median and MAD read neither). Called
    from Python between kernel calls (:func:`_run_exact`), so it compiles only when a window
    first needs it."""
    n = sums_g.shape[0]
    e_lo, e_hi = _entering(v, i, n)
    sy, syy = _replay_moments(sums_g, i, v, length, shift, e_lo, e_hi, np.zeros(n, dtype=np.int16))
    eff = length if length <= i + 1 else i + 1
    _moments_out(n, sy, syy, shift, unit, eff, g, mean, std)
    if approx == APPROX_GAUSSIAN:
        locs[g, 0] = mean[g]
        scales[g, 0] = std[g]
    elif approx == APPROX_GMM:
        k = weights.shape[1]
        scores_from_sums(sums_g, i, v, length, unit, s)
        _gmm_em(s, em_stride, mean[g], std[g], n_iter, weights[g], locs[g], scales[g], resp, np.empty(k),
                np.empty(k))


@njit(inline="always")
def _entering(v, i, n):
    """The places ``[e_lo, e_hi)`` whose line enters the reference at frame ``i``."""
    if i == 0:
        return 0, n
    delta = position(v, i) - position(v, i - 1)
    if delta >= n or delta <= -n:
        return 0, n
    if delta > 0:
        return 0, delta
    if delta < 0:
        return n + delta, n
    return 0, 0


@njit
def _sub_scores(sums_v, i, v, grid, unit, best_j, sub):
    """``sub[g, h]``: window ``g``'s best place scored over window ``h`` (when asked for)."""
    g_count = grid.shape[0]
    if sub.shape[1] == g_count:  # only the consistency rules need them
        for g in range(g_count):
            for h in range(g_count):
                sub[g, h] = score_at(sums_v[h], i, v, grid[h], unit, best_j[g])


@njit(inline="always")
def _velocity_stats_gaussian(sums_v, ring, mring, i, v, grid, unit, radius,
                             best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s):
    """:func:`_velocity_stats` for the Gaussian approximation alone (compiles without the
    median and the mixture fit; ``s`` is not read: the statistics come from the sums)."""
    bmin = np.empty((sums_v.shape[1] + CHUNK - 1) // CHUNK, dtype=np.int64)
    for g in range(grid.shape[0]):
        _window(sums_v[g], ring, mring, i, v, grid[g], unit, radius, bmin, g, best_j, best_s, second_s, mean, std)
        weights[g, 0] = 1.0
        locs[g, 0] = mean[g]
        scales[g, 0] = std[g]
    _sub_scores(sums_v, i, v, grid, unit, best_j, sub)


@njit
def _velocity_stats(sums_v, ring, mring, i, v, grid, unit, approx, n_iter, em_stride, radius,
                    best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp, pend, pend_shift):
    """Advance one velocity's window sums to frame ``i`` and summarise every window
    (:func:`_window_exact`), then fit the approximation to each window's scores. Marks in
    ``pend`` (``(G,)``, the shift in ``pend_shift``) each window whose moments were not exact
    (its mean, spread and mixture are settled by :func:`_settle_window`); returns how many."""
    n_components = weights.shape[1]
    coef = np.empty(n_components)
    inv = np.empty(n_components)
    bmin = np.empty((s.shape[0] + CHUNK - 1) // CHUNK, dtype=np.int64)
    count = 0
    for g in range(grid.shape[0]):
        exact, shift = _window_exact(sums_v[g], ring, mring, i, v, grid[g], unit, radius, bmin, g, best_j, best_s,
                                     second_s, mean, std)
        if not exact:
            pend[g] = 1
            pend_shift[g] = shift
            count += 1
        if approx != APPROX_GAUSSIAN:
            scores_from_sums(sums_v[g], i, v, grid[g], unit, s)  # the scores themselves, for the median or mixture
        if approx == APPROX_GAUSSIAN:
            weights[g, 0] = 1.0
            locs[g, 0] = mean[g]
            scales[g, 0] = std[g]
        elif approx == APPROX_ROBUST:
            med, mad = _median_mad(s, work)
            weights[g, 0] = 1.0
            locs[g, 0] = med
            scales[g, 0] = mad
        else:
            _gmm_em(s, em_stride, mean[g], std[g], n_iter, weights[g], locs[g], scales[g], resp, coef, inv)
    _sub_scores(sums_v, i, v, grid, unit, best_j, sub)
    return count


@njit(nogil=True)
def store_rows(d, c0, c1, start, ring, mring, state):
    """:func:`advance` for rows ``c0 .. c1 - 1`` of ``d`` (query frames ``start + t``)."""
    for t in range(c0, c1):
        advance(ring, mring, state, start + t, d[t])


@njit(nogil=True)
def run_velocities(chosen, c0, c1, t_first, start, sums, ring, mring, state, velocities, grid, approx, n_iter,
                   em_stride, radius, best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp,
                   pend, pend_shift):
    """:func:`_velocity_stats` for the velocities ``chosen`` over frames ``start + c0 ..
    start + c1 - 1`` (rows already stored; the first velocity from ``start + t_first`` on);
    releases the GIL, so threads share the work. Stops after the first frame with a window whose
    moments were not exact and returns ``(q, t)`` as :func:`run_velocities_exact`; ``(-1, -1)``
    once done."""
    for q in range(chosen.shape[0]):
        vi = chosen[q]
        for t in range(t_first if q == 0 else c0, c1):
            if _velocity_stats(sums[vi], ring, mring, start + t, velocities[vi], grid, state[0], approx, n_iter,
                               em_stride, radius, best_j[t, vi], best_s[t, vi], second_s[t, vi], mean[t, vi],
                               std[t, vi], weights[t, vi], locs[t, vi], scales[t, vi], sub[t, vi], s[vi],
                               work[vi], resp[vi], pend[vi], pend_shift[vi]) > 0:
                return q, t
    return -1, -1


@njit(nogil=True)
def run_velocities_gaussian(chosen, c0, c1, start, sums, ring, mring, state, velocities, grid, radius, best_j,
                            best_s, second_s, mean, std, weights, locs, scales, sub, s):
    """:func:`run_velocities` for the Gaussian approximation (the default): compiled
    without the median and the mixture fit, which are compiled only when asked for, and
    without the arguments only they read (the approximation code, the EM settings and
    scratch): five arguments fewer to type and unbox, about 10 % of its cold compile."""
    for q in range(chosen.shape[0]):
        vi = chosen[q]
        for t in range(c0, c1):
            _velocity_stats_gaussian(sums[vi], ring, mring, start + t, velocities[vi], grid, state[0], radius,
                                     best_j[t, vi], best_s[t, vi], second_s[t, vi], mean[t, vi], std[t, vi],
                                     weights[t, vi], locs[t, vi], scales[t, vi], sub[t, vi], s[vi])


@njit(inline="always")
def _velocity_stats_exact(sums_v, ring, mring, i, v, grid, unit, radius, best_j, best_s, second_s, mean, std,
                          weights, locs, scales, sub, pend, pend_shift):
    """:func:`_velocity_stats_gaussian` with the update of :func:`_update_stats_exact`: marks in
    ``pend`` (``(G,)``, with the shift in ``pend_shift``) each window whose moments were not
    exact; returns how many."""
    bmin = np.empty((sums_v.shape[1] + CHUNK - 1) // CHUNK, dtype=np.int64)
    count = 0
    for g in range(grid.shape[0]):
        exact, shift = _window_exact(sums_v[g], ring, mring, i, v, grid[g], unit, radius, bmin, g, best_j, best_s,
                                     second_s, mean, std)
        weights[g, 0] = 1.0
        locs[g, 0] = mean[g]
        scales[g, 0] = std[g]
        if not exact:
            pend[g] = 1
            pend_shift[g] = shift
            count += 1
    _sub_scores(sums_v, i, v, grid, unit, best_j, sub)
    return count


@njit(nogil=True)
def run_velocities_exact(chosen, c0, c1, t_first, start, sums, ring, mring, state, velocities, grid, radius, best_j,
                         best_s, second_s, mean, std, weights, locs, scales, sub, pend, pend_shift):
    """:func:`run_velocities_gaussian` on the update of :func:`_update_stats_exact`, the first
    velocity of ``chosen`` from frame ``start + t_first`` on. Stops after the first frame with a
    window whose moments were not exact and returns ``(q, t)``, its velocity's position in
    ``chosen`` and its row (the caller settles the windows marked in ``pend`` from the sums as
    that frame left them, then goes on); ``(-1, -1)`` once every velocity and frame is done."""
    for q in range(chosen.shape[0]):
        vi = chosen[q]
        for t in range(t_first if q == 0 else c0, c1):
            if _velocity_stats_exact(sums[vi], ring, mring, start + t, velocities[vi], grid, state[0], radius,
                                     best_j[t, vi], best_s[t, vi], second_s[t, vi], mean[t, vi], std[t, vi],
                                     weights[t, vi], locs[t, vi], scales[t, vi], sub[t, vi], pend[vi],
                                     pend_shift[vi]) > 0:
                return q, t
    return -1, -1


def _run_exact(kernel, settle, chosen, c0, c1, start, sums, ring, mring, state, *rest):
    """The outputs of the update of :func:`_update_stats`, bit for bit, from ``kernel``
    (:func:`run_velocities_exact` or :func:`run_velocities`, whose last two arguments are
    ``pend`` and ``pend_shift``): where a window's moments were not exact, ``settle(vi, t, g)``
    settles it in the order of :func:`_update_stats` (:func:`_settle_window`) before the velocity
    goes on to its next frame."""
    pend = rest[-2]
    q0, t0 = 0, c0
    while q0 < chosen.shape[0]:
        q, t = kernel(chosen[q0:], c0, c1, t0, start, sums, ring, mring, state, *rest)
        if q < 0:
            return
        vi = int(chosen[q0 + q])
        for g in np.flatnonzero(pend[vi]):
            settle(vi, t, int(g))
        pend[vi] = 0
        q0, t0 = q0 + q, t + 1
        if t0 >= c1:
            q0, t0 = q0 + 1, c0


#: Window sums updated per thread below which the velocities run on the calling thread
#: alone (a small map: handing work to a second thread costs more than it saves).
WORK_PER_THREAD = 1 << 18

_POOL = {}


def _pool(threads):
    """A pool of ``threads - 1`` worker threads (the caller's thread is the last one)."""
    if threads not in _POOL:
        from concurrent.futures import ThreadPoolExecutor

        _POOL[threads] = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="catgraph-matcher")
    return _POOL[threads]


def run_batch(d, start, sums, ring, mring, state, velocities, grid, approx, n_iter, em_stride, radius,
              best_j, best_s, second_s, mean, std, weights, locs, scales, sub, s, work, resp, beside=None):
    """Match the rows of ``d`` in order (row ``t`` is query frame ``start + t``): store
    each (:func:`advance`) and compute everything the selection rules need, per frame,
    velocity and window. The streaming form calls it with one row, the batch form with
    blocks of rows; the state (``sums``, ``ring``, ``mring``, ``state``) starts as zeros
    and carries over from call to call.

    Outputs (``n`` rows, ``V`` velocities, ``G = len(grid)``, ``K`` components):
    ``best_j, best_s, second_s, mean, std`` ``(n, V, G)``; ``weights, locs, scales``
    ``(n, V, G, K)`` — the approximation's components; ``sub`` ``(n, V, G, G)`` (or
    ``(n, V, G, 0)`` when not needed) with
    ``sub[t, v, g, h] = s_{i, best_j[t, v, g]}(grid[h], v)``, window ``g``'s best
    hypothesis scored over window ``h`` along the same line. Mixtures are fitted to every
    ``em_stride``-th score. ``second_s`` is the best score more than ``radius`` places
    from ``best_j`` at the same velocity (``+inf`` where none exists). Scratch ``s``
    ``(V, N)``; ``work`` ``(V, N)`` (robust) and ``resp`` ``(V, K, N)`` (mixtures), else
    empty.

    The Gaussian approximation runs :func:`run_velocities_exact`, the others
    :func:`run_velocities`, both on the update of :func:`_update_stats_exact` through
    :func:`_run_exact` (windows whose moments round settled in the order of
    :func:`_update_stats`); the outputs are those of the update of :func:`_update_stats`
    (:func:`run_velocities_gaussian`), bit for bit.

    The ring holds ``R >= max(grid) + 1`` rows, so ``C = R - max(grid)`` new rows fit
    beside the longest window's history: the rows are stored ``C`` at a time, then the
    velocities are handed out one at a time to ``numba.get_num_threads()`` threads (fewer
    below :data:`WORK_PER_THREAD` window sums per thread; the
    caller's and a pool's; compiled code without the GIL, and a waiting thread sleeps
    instead of spinning, which matters on a busy machine), each taking the next velocity
    of those ``C`` frames as soon as it is free — a thread that shares its core with
    other work takes fewer. Each velocity reads the shared ring and writes only its own
    sums and outputs, so the numbers depend neither on ``C``, nor on the thread count,
    nor on which thread ran which velocity.

    ``beside`` (optional, a function of no arguments): work that reads none of the kernels'
    outputs (the streaming step's reads of its row, :func:`catgraph._window_rule._row_reads`),
    run once on the calling thread while the other threads take the first velocities (where
    there are none, before the kernels); the calling thread then takes velocities too.
    """
    import numba

    chunk = ring.shape[0] - int(grid[-1])
    v_count = velocities.shape[0]
    updates = min(chunk, d.shape[0]) * sums.shape[2] * grid.shape[0] * v_count  # window sums per kernel round
    threads = max(1, min(v_count, numba.get_num_threads(), updates // WORK_PER_THREAD))
    pend = np.zeros((v_count, grid.shape[0]), dtype=np.uint8)  # windows whose moments await settling
    pend_shift = np.zeros((v_count, grid.shape[0]), dtype=np.int64)

    def settle(vi, t, g):
        _settle_window(sums[vi, g], start + t, float(velocities[vi]), int(grid[g]), state[0],
                       np.int64(pend_shift[vi, g]), g, approx, n_iter, em_stride, mean[t, vi], std[t, vi],
                       weights[t, vi], locs[t, vi], scales[t, vi], s[vi], resp[vi])

    if approx == APPROX_GAUSSIAN:
        rest = (run_velocities_exact, settle, velocities, grid, radius, best_j, best_s, second_s, mean, std, weights,
                locs, scales, sub, pend, pend_shift)
    else:
        rest = (run_velocities, settle, velocities, grid, approx, n_iter, em_stride, radius, best_j, best_s,
                second_s, mean, std, weights, locs, scales, sub, s, work, resp, pend, pend_shift)

    def run(chosen, c0, c1, start, sums, ring, mring, state, kernel, settle, *args):
        _run_exact(kernel, settle, chosen, c0, c1, start, sums, ring, mring, state, *args)

    if threads == 1:
        if beside is not None:
            beside()
        every = _velocity_sets(v_count)[-1]
        for c0 in range(0, d.shape[0], chunk):
            c1 = min(d.shape[0], c0 + chunk)
            store_rows(d, c0, c1, start, ring, mring, state)
            run(every, c0, c1, start, sums, ring, mring, state, *rest)
        return
    single = _velocity_sets(v_count)[:-1]
    pool = _pool(threads)
    for c0 in range(0, d.shape[0], chunk):
        c1 = min(d.shape[0], c0 + chunk)
        store_rows(d, c0, c1, start, ring, mring, state)
        queue = iter(single)  # shared: each thread takes the next velocity when it is free

        def take(queue=queue, c0=c0, c1=c1):
            for chosen in queue:
                run(chosen, c0, c1, start, sums, ring, mring, state, *rest)

        jobs = [pool.submit(take) for _ in range(threads - 1)]
        try:
            if beside is not None:
                beside, once = None, beside
                once()
            take()
        finally:
            for job in jobs:
                job.result()


_VELOCITY_SETS = {}


def _velocity_sets(v_count):
    """``[array([0]), ..., array([V - 1]), arange(V)]``: the index arrays the
    per-velocity kernels take (made once per ``V``)."""
    if v_count not in _VELOCITY_SETS:
        _VELOCITY_SETS[v_count] = [np.array([k], dtype=np.int64) for k in range(v_count)] + [
            np.arange(v_count, dtype=np.int64)]
    return _VELOCITY_SETS[v_count]


def matcher_kernel(approx):
    """The compiled matcher for an approximation code (the signature of :func:`run_batch`)."""
    return run_batch


@njit
def fixed_scores(d, length, v):
    """All scores ``s_ij(L, v)`` for one window and velocity, ``(n_query, N)`` (batch
    helper; the matcher's arithmetic and codes, with int64 sums for any length)."""
    n_q, n = d.shape
    out = np.empty((n_q, n))
    ring = np.zeros((length + 1, n), dtype=np.int16)
    mring = np.zeros(length + 1, dtype=np.int16)
    state = np.zeros(1)
    sums = np.zeros(n, dtype=np.int64)
    bmin = np.empty((n + CHUNK - 1) // CHUNK, dtype=np.int64)
    for i in range(n_q):
        advance(ring, mring, state, i, d[i])
        _update_stats(sums, ring, mring, i, v, length, np.int64(0), bmin)
        scores_from_sums(sums, i, v, length, state[0], out[i])
    return out


@njit(nogil=True)
def smallest_places(row, idx, val):  # pragma: no cover - compiled
    """The ``k = idx.shape[0]`` smallest values of ``row`` (``k <= row.shape[0]``) and
    their places, in ascending (value, place) order, into ``val`` and ``idx``: one pass
    over the row, each value compared with the ``k``-th smallest so far and, when below
    it, inserted into the short sorted list (a value equal to a kept one goes after it,
    its place being larger). The decorrelation horizon's best places
    (:class:`catgraph._window_rule._Horizon`) without standardising the row or
    partitioning it.

    Once ``k`` values are kept, the row is read in blocks of :data:`SCAN_BLOCK` values, and a
    block with no value below the ``k``-th smallest kept is passed over whole (one vectorised
    count): each of its values would have been passed over one by one, as the ``k``-th
    smallest only falls when a value is inserted. The same values are inserted in the same
    order (NaN, below nothing, is passed over in a block as it is one by one)."""
    k = idx.shape[0]
    n = row.shape[0]
    filled = 0
    j = 0
    while j < n:
        if filled == k and j + SCAN_BLOCK <= n:
            if _count_below(row[j:j + SCAN_BLOCK], val[k - 1]) == 0:
                j += SCAN_BLOCK
                continue
            stop = j + SCAN_BLOCK
        else:
            stop = j + 1
        while j < stop:
            v = row[j]
            if filled == k:
                if not v < val[k - 1]:
                    j += 1
                    continue
                p = k - 1
            else:
                p = filled
                filled += 1
            while p > 0 and val[p - 1] > v:
                val[p] = val[p - 1]
                idx[p] = idx[p - 1]
                p -= 1
            val[p] = v
            idx[p] = j
            j += 1


#: values per block of :func:`smallest_places`
SCAN_BLOCK = 64


@njit
def _count_below(seg, top):
    """How many of ``seg`` lie below ``top`` (a plain loop the compiler vectorises)."""
    c = 0
    for j in range(seg.shape[0]):
        c += 1 if seg[j] < top else 0
    return c
