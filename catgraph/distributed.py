"""Batch evaluation against a map too large for one machine, on a Dask cluster.

The reference is cut into *shards* of consecutive places, each prepared
(:class:`~catgraph.differences.PreparedReference`) and kept on a Dask worker. A block of
query frames is sent to every worker; the differences and the window scores of that
block are computed *where the shards live*, and only per-frame summaries travel back:

1. **Differences.** Each worker computes its shard's columns of the raw difference
   block with the same kernel as a local run, so the values are the same bit for bit.
2. **Normalisation** (paper 1: per query row over *all* places). Each worker returns
   the partial sums of its columns over the fixed chunks of
   :data:`catgraph._diff_kernels.SUM_CHUNK` places that the local normalisation uses;
   shards are whole multiples of that chunk, so the client adds exactly the partial
   sums a local run adds, in the same order: the means and standard deviations, and
   so the normalised block, are identical to :func:`catgraph.differences.difference_matrix`
   with ``normalise=True`` (two small round trips: means, then squared deviations).
3. **Codes** (:mod:`catgraph.sequence`, "Precision"). The local matcher stores each
   normalised difference once as an int16 code of a quantum ``u`` fixed by the query's
   first row. The client reduces ``max_j |d_0j|`` over the shards once per query and
   fixes ``u`` with the matcher's own :func:`~catgraph._sequence_kernels.unit_of`; each
   worker codes its columns with the matcher's own rounding
   (:func:`~catgraph._sequence_kernels.encode`: nearest code, saturated at ``±32767``)
   and returns each row's integer code sum, from which the client rounds the row's mean
   code (the fill before the reference start) exactly as the local ring does.
4. **Window sums along lines** (:mod:`catgraph.sequence`, "Scores along lines"). For
   every velocity ``v`` searched, ``S_ij(L, v)`` adds the codes of the line that places
   query frame ``t`` at ``j - (pos_v(i) - pos_v(t))``, ``pos_v(i) = floor(v i + 1/2)``,
   with the row's mean code where that place is off the map. A line reaches
   ``|pos_v(i) - pos_v(i - L)| <= ⌈|v| L⌉`` places back (the client takes the exact
   reach from ``pos_v`` itself): into the left neighbour for ``v > 0``, the right one
   for ``v < 0``. Each worker receives the code columns its lines reach on each side, from
   whichever shards hold them (several, where a line crosses a whole shard), and the
   query block carries ``L`` earlier rows; it then runs the local matcher's update on
   its own places (a line that continues within the shard adds its new term and drops
   the one ``L`` frames back; a line entering the shard is summed term by term). **Halo
   cost per velocity**: ``2 ⌈|v| L⌉`` bytes per query row from one neighbour, so
   ``2 L`` (``v = ±1``), ``L`` (``±0.5``), ``4 L`` (``±2``), ``6 L`` (``±3``); the
   velocities share one halo per side, the widest: ``6 L`` bytes per row from each
   neighbour for the default set (``±0.5, ±1, ±2, ±3``). Integer sums do not depend on
   where they start or in which order they are added: they equal the local matcher's
   running sums exactly, and the scores ``S u / L_eff`` are
   :func:`catgraph.sequence.fixed_window_scores` bit for bit, for every velocity.
5. **Matching** (fixed window). Per row and velocity each shard returns, in one round:
   its smallest sum and that sum's first place, its exact integer sums of ``S`` and
   ``S²``, its smallest sum more than ``radius`` places from its own best, the smallest
   sums of its places past the first (last) ``k ≤ radius`` (for a global best within
   ``radius`` of its edge), and the previous row's sum at place ``(pos_v(i-1) -
   pos_v(i)) mod N`` if it holds that place (the local kernel's ``shift`` for the
   moments). The client reduces these to the global best (ties: the lowest place, as
   locally), the second best outside ``± radius`` of it, and the mean and spread of
   ``y = S − shift`` as the local kernel computes them, i.e. exactly the per-velocity
   statistics the local kernel hands to the window rule, and calls that rule
   (:func:`catgraph._window_rule._decide`): the velocity, the match, the score and the
   confidence are chosen by the same code. Matches, scores and velocities are those of
   :func:`catgraph.sequence.match_sequences` (``window=L``, same ``velocities``,
   ``radius``, ``confidence``) bit for bit; so are the confidences while each row's
   ``Σ_j y_j² < 2^53`` (the local float64 sums are then exact). Beyond it the local
   kernel's float64 sums round in their own order, and a spread differs by at most
   ``1.5 N 2^-53 (1 + ȳ² / var y)`` relative (the standard bound on a float64 sum of
   ``N`` rounded terms, carried through ``var = E[y²] − ȳ²`` and the square root); with
   several velocities a spread so perturbed can, in principle, also tip the velocity
   chosen where two velocities are within that bound of each other.
   Measured on the benchmark data (rows normalised, every traversal condition,
   ``v = 1``): ``Σ_j y_j²`` at most ``2^46.1`` (Nordland, 3,576 places, ``L = 100``),
   and the largest mean ``y²`` per place (UJI month 02, ``L = 100``) would reach
   ``2^53`` at about 2.6 × 10⁵ places (8 × 10⁵ at ``L = 50``), so larger maps of such
   data are in the bounded regime.

Only ``O(rows V (radius + 8))`` numbers per shard return to the client per block (four
client rounds per block: two for the normalisation, one for the mean codes, one for
the summaries; one more per query for the quantum), and the full ``n_query × N``
matrix is never gathered (:func:`difference_matrix` gathers it on request, for tests
and small maps).

The adaptive window is not run here: its rule needs, besides per-length versions of
the same reductions and the sub-window scores of each length's best line (one more
round), the current frame's mean and spread over the whole row as numpy computes them
(the ``"posterior"`` confidence), which a sum over shards does not reproduce bit for
bit (numpy's pairwise summation follows the row's length, not the shards).

What to call
------------
:func:`shard_reference` once per map (``client`` from ``distributed.Client(ADDRESS)``
or a ``LocalCluster``), then :func:`match_fixed_window` for matches (every velocity
of :data:`catgraph.sequence.DEFAULT_VELOCITIES` by default, as locally) or
:func:`difference_matrix` / :func:`window_scores` for the arrays. A command line option
``--scheduler ADDRESS`` maps to ``shard_reference(descriptors, metric,
distributed.Client(ADDRESS))`` (:func:`catgraph.experiment.run_on_cluster`). Sizing for a 10⁷-place map, from measured per-shard
figures, is in ``docs/live.md``.

Workers run the same compiled kernels; on machines with different SIMD widths the
last bits of the raw differences can differ (see :mod:`catgraph._diff_kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._jit import njit
from ._sequence_kernels import _NONE, encode, position, unit_of
from ._validation import check_scalar
from .differences import LAYOUTS, METRICS, PreparedReference, _combine, _zero_spread, code_scale
from ._window_rule import _decide, _Stats
from .exceptions import InvalidParameterError, MissingDependencyError
from .sequence import DEFAULT_VELOCITIES, _config, _velocity_set

#: Shards hold a whole multiple of this many places (the normalisation's sum chunk);
#: a window may not be longer (its sums' squares then stay exact in int64).
SHARD_UNIT = 4096

__all__ = ["ShardedReference", "shard_reference", "difference_matrix", "window_scores", "match_fixed_window"]


def _client(scheduler: Any):
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - dask is installed with the [dask] extra
        raise MissingDependencyError('Dask sharding needs dask.distributed: pip install "catgraph[dask]".') from None
    if isinstance(scheduler, Client):
        return scheduler
    if isinstance(scheduler, str):
        return Client(scheduler)
    raise InvalidParameterError(
        f"scheduler must be a Dask scheduler address ('tcp://host:8786') or a distributed.Client; got {scheduler!r}."
    )


# ---------------------------------------------------------------------------------------
# worker-side functions (module level: they travel by reference)


def _prepare_shard(block: np.ndarray, metric: str, layout: str = "float32",
                   scale: tuple[float, float] | None = None) -> PreparedReference:
    if layout == "uint8":
        return PreparedReference(block, metric, layout, code_scale=scale)
    return PreparedReference(block, metric)


def _raw(shard: PreparedReference, q: np.ndarray) -> np.ndarray:
    return shard._fill(q, False, np.empty((q.shape[0], shard.n_places)))


def _chunk_sums(block: np.ndarray, centre: np.ndarray | None, power: int) -> np.ndarray:
    from . import _diff_kernels as k

    m, n = block.shape
    out = np.empty((m, -(-n // k.SUM_CHUNK)))
    k.chunk_sums(block, np.zeros(m) if centre is None else centre, power, out)
    return out


def _scale(block: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    from . import _diff_kernels as k

    out = np.empty_like(block)
    k.scale_rows(block, mean, std, out)
    return out


def _columns(codes: tuple, a: int, b: int) -> np.ndarray:
    """Code columns ``a:b`` of a shard (part of a neighbour's halo)."""
    return np.ascontiguousarray(codes[0][:, a:b])


def _row_peak(block: np.ndarray, row: int) -> float:
    """``max_j |d_row,j|`` over the shard's columns (the quantum's reduction)."""
    return float(np.abs(block[row]).max()) if block.shape[1] else 0.0


@njit(nogil=True)
def _encode_block(block, unit, codes, totals):  # pragma: no cover - compiled
    """``codes[a, b]``: ``block[a, b]`` coded as the local matcher codes it
    (:func:`catgraph._sequence_kernels.encode`); ``totals[a]``: the row's code sum."""
    for a in range(block.shape[0]):
        total = 0
        for b in range(block.shape[1]):
            c = encode(block[a, b], unit)
            codes[a, b] = c
            total += c
        totals[a] = total


def _codes(block: np.ndarray, unit: float) -> tuple[np.ndarray, np.ndarray]:
    """The shard's normalised columns as int16 codes of the quantum ``unit``, and each
    row's (exact, int64) code sum over the shard."""
    codes = np.empty(block.shape, dtype=np.int16)
    totals = np.empty(block.shape[0], dtype=np.int64)
    _encode_block(block, unit, codes, totals)
    return codes, totals


@njit(nogil=True)
def _line_pass(d, ext_lo, n, lo, first_row, skip, window, v, mean_codes, vi, scores, low, place, total,
               high_sq, low_sq, outside, pre, suf, prev_sum, prev_here, radius, w):  # pragma: no cover - compiled
    """Integer window sums ``S`` of velocity ``v`` along lines, for the shard's places
    ``lo … lo + w - 1`` and block rows ``skip …`` (block row ``r`` is query frame
    ``first_row + r``), and their per-row summaries.

    ``d`` holds the codes of places ``ext_lo …`` (the shard and its halo); a term whose
    place lies outside ``[0, n)`` is its row's mean code (``mean_codes``), the edge policy
    of :mod:`catgraph.sequence`. Row ``r`` sums the ``e = min(L, i + 1, r + 1)`` latest
    terms of each line: the window itself from row ``skip - 1`` on (the block carries
    ``L`` earlier rows), fewer before. A line that continues from the previous row within
    the shard takes one new term and drops the one ``L`` frames back (the local matcher's
    update); a line that enters the shard's places is summed term by term (``|Δpos|`` per
    row, ``O(L)`` each). The sums are integers, so they equal the local running sums
    exactly, however they were added.

    Per output row ``o = r - skip`` and velocity index ``vi``: the smallest sum and its
    first place, the sum of the sums and of their squares (split at ``2^32`` so that the
    halves add up exactly), the smallest sum more than ``radius`` places from the shard's
    best (``outside``), ``pre[o, vi, k] = min S[lo + k:]`` and ``suf[o, vi, k] = min
    S[:hi - k]`` (``k < K``: the second best when the global best lies within ``radius``
    of the shard's edge), and the previous row's sum at place ``(pos_v(i-1) - pos_v(i))
    mod n`` where the shard holds it (the local kernel's shift for the moments).
    ``scores`` (``(rows, w)`` or empty) receives the sums themselves.
    """
    rows = d.shape[0]
    k_count = pre.shape[2]
    mask = (np.int64(1) << 32) - 1
    last = np.zeros(w, dtype=np.int64)
    cur = np.zeros(w, dtype=np.int64)
    want = scores.shape[0] > 0
    for r in range(rows):
        i = first_row + r
        p = position(v, i)
        e = min(window, i + 1, r + 1)
        delta = 0
        c_lo = 0
        c_hi = 0
        if r > 0:  # places whose line continues from the previous row within the shard
            delta = p - position(v, i - 1)
            c_lo = max(0, delta)
            c_hi = min(w, w + delta)
        drop = r >= window
        off = p - position(v, i - window) if drop else 0
        m_old = np.int64(mean_codes[r - window]) if drop else np.int64(0)
        for k in range(w):
            j = lo + k
            if c_lo <= k < c_hi:
                s = last[k - delta] + np.int64(d[r, j - ext_lo])
                if drop:
                    q = j - off
                    s -= np.int64(d[r - window, q - ext_lo]) if 0 <= q < n else m_old
            else:  # a line entering the shard's places: its window term by term
                s = np.int64(0)
                for t in range(i - e + 1, i + 1):
                    q = j - (p - position(v, t))
                    rr = t - first_row
                    s += np.int64(d[rr, q - ext_lo]) if 0 <= q < n else np.int64(mean_codes[rr])
            cur[k] = s
        if r >= skip:
            o = r - skip
            m = cur[0]
            jm = 0
            tot = np.int64(0)
            qh = np.int64(0)
            ql = np.int64(0)
            for k in range(w):
                x = cur[k]
                if x < m:
                    m = x
                    jm = k
                tot += x
                sq = x * x  # |S| <= 4096 * 32767 < 2^27: exact in int64
                qh += sq >> 32
                ql += sq & mask
            low[o, vi] = m
            place[o, vi] = lo + jm
            total[o, vi] = tot
            high_sq[o, vi] = qh
            low_sq[o, vi] = ql
            mo = _NONE
            for k in range(w):
                if (k < jm - radius or k > jm + radius) and cur[k] < mo:
                    mo = cur[k]
            outside[o, vi] = mo
            tail = _NONE
            for k in range(k_count, w):
                tail = min(tail, cur[k])
            for k in range(k_count - 1, -1, -1):
                tail = min(tail, cur[k])
                pre[o, vi, k] = tail
            head = _NONE
            for k in range(0, w - k_count):
                head = min(head, cur[k])
            for k in range(k_count - 1, -1, -1):
                head = min(head, cur[w - k - 1])
                suf[o, vi, k] = head
            if i >= 1:
                ps = (position(v, i - 1) - p) % n
                if lo <= ps < lo + w:
                    prev_sum[o, vi] = last[ps - lo]
                    prev_here[o, vi] = True
            if want:
                for k in range(w):
                    scores[o, k] = cur[k]
        last, cur = cur, last


def _shard_lines(codes: tuple, left: list, right: list, first_row: int, skip: int, window: int,
                 velocities: np.ndarray, mean_codes: np.ndarray, lo: int, n: int, radius: int,
                 want_sums: bool) -> dict:
    """One shard's window sums along the lines of every velocity (:func:`_line_pass`),
    with the code columns ``left`` and ``right`` of it (the halos, from the neighbours)."""
    block = codes[0]
    rows, w = block.shape
    d = np.concatenate([*left, block, *right], axis=1) if left or right else block
    ext_lo = lo - sum(h.shape[1] for h in left)
    v_count, out_rows = velocities.shape[0], rows - skip
    k_count = min(radius + 1, w)
    out = {name: np.zeros((out_rows, v_count), dtype=np.int64)
           for name in ("low", "place", "total", "high_sq", "low_sq", "outside", "prev_sum")}
    out["prev_here"] = np.zeros((out_rows, v_count), dtype=np.bool_)
    pre = np.empty((out_rows, v_count, k_count), dtype=np.int64)
    suf = np.empty((out_rows, v_count, k_count), dtype=np.int64)
    sums = np.empty((v_count, out_rows if want_sums else 0, w if want_sums else 0), dtype=np.int64)
    for vi in range(v_count):
        _line_pass(d, ext_lo, n, lo, first_row, skip, window, float(velocities[vi]), mean_codes, vi, sums[vi],
                   out["low"], out["place"], out["total"], out["high_sq"], out["low_sq"], out["outside"],
                   pre, suf, out["prev_sum"], out["prev_here"], radius, w)
    out["pre"], out["suf"] = pre, suf
    if want_sums:
        out["sums"] = sums
    return out


# ---------------------------------------------------------------------------------------
# the sharded reference


@dataclass
class ShardedReference:
    """A reference cut into shards of consecutive places, prepared on Dask workers.

    Attributes
    ----------
    client : distributed.Client
    shards : list of Future
        One :class:`~catgraph.differences.PreparedReference` per shard, on a worker.
    bounds : list of (int, int)
        ``[lo, hi)`` places of each shard.
    metric : str
    n_places, dim : int
    """

    client: Any
    shards: list
    bounds: list
    metric: str
    n_places: int
    dim: int
    workers: list
    layout: str = "float32"
    code_scale: tuple | None = None

    def submit(self, shard: int, fn, *args):
        """Run ``fn(*args)`` on the worker that holds shard ``shard`` (never elsewhere:
        moving a block would cost more than computing it)."""
        return self.client.submit(fn, *args, workers=[self.workers[shard]], allow_other_workers=False, pure=False)

    def prepare_query(self, descriptors) -> np.ndarray:
        """Validate query descriptors as a local run would (float32 or the map's codes, same width)."""
        probe = PreparedReference(np.zeros((1, self.dim), dtype=np.float32) if self.metric != "hamming"
                                  else np.zeros((1, self.dim), dtype=bool), self.metric, self.layout,
                                  **({"code_scale": self.code_scale} if self.layout == "uint8" else {}))
        return probe.prepare_query(descriptors)


def shard_reference(descriptors, metric: str, scheduler, shard_places: int | None = None,
                    layout: str = "float32") -> ShardedReference:
    """Cut a reference into shards and prepare each on a worker.

    Parameters
    ----------
    descriptors : array_like, shape (N, d)
        Reference descriptors (after the front-end). For a map larger than this
        machine, pass a memory-mapped array (``numpy.load(..., mmap_mode="r")``): each
        shard is read and sent on its own.
    metric : {"sad", "ssd", "cosine", "hamming"}
    scheduler : str or distributed.Client
        Scheduler address (``"tcp://host:8786"``) or a client.
    shard_places : int, optional
        Places per shard, rounded up to a multiple of ``SUM_CHUNK`` (4096). Default:
        ``N`` split evenly over the workers.
    layout : {"float32", "uint8"}
        How workers hold their shards (:class:`~catgraph.differences.PreparedReference`);
        ``"uint8"`` codes every shard with the whole map's scale
        (:func:`~catgraph.differences.code_scale`), so the results equal a local run on
        ``PreparedReference(descriptors, metric, "uint8")``, bit for bit, in a quarter
        of the worker memory.

    Returns
    -------
    ShardedReference
    """
    from ._diff_kernels import SUM_CHUNK

    if metric not in METRICS:
        raise InvalidParameterError(f"Unknown difference metric {metric!r}; choose one of {', '.join(METRICS)}.")
    if layout not in LAYOUTS:
        raise InvalidParameterError(f"The 'layout' parameter of shard_reference must be one of {LAYOUTS}. "
                                    f"Got {layout!r} instead.")
    scale = code_scale(descriptors, metric) if layout == "uint8" else None
    client = _client(scheduler)
    ref = np.asarray(descriptors) if not isinstance(descriptors, np.memmap) else descriptors
    if ref.ndim != 2 or ref.shape[0] == 0:
        raise InvalidParameterError(f"reference descriptors must have shape (N, d) with N ≥ 1; got {ref.shape}.")
    n = ref.shape[0]
    if shard_places is None:
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        shard_places = -(-n // workers)
    check_scalar(shard_places, "shard_places", "shard_reference", int, 1)
    shard_places = -(-int(shard_places) // SUM_CHUNK) * SUM_CHUNK
    bounds = [(lo, min(n, lo + shard_places)) for lo in range(0, n, shard_places)]
    addresses = sorted(client.scheduler_info().get("workers", {}))
    if not addresses:
        raise InvalidParameterError("the Dask cluster has no workers; start some before sharding a reference.")
    workers, shards = [], []
    for s, (lo, hi) in enumerate(bounds):
        where = addresses[s % len(addresses)]
        block = client.scatter(np.ascontiguousarray(ref[lo:hi]), workers=[where], direct=False)
        shards.append(client.submit(_prepare_shard, block, metric, layout, scale, workers=[where],
                                    allow_other_workers=False, pure=False))
        workers.append(where)
    dim = ref.shape[1] * (8 if metric == "hamming" and ref.dtype == np.uint8 else 1)
    return ShardedReference(client, shards, bounds, metric, n, int(dim), workers, layout, scale)


# ---------------------------------------------------------------------------------------
# blocks of query rows


def _normalised_blocks(ref: ShardedReference, q: np.ndarray, normalise: bool, blank: np.ndarray | None = None) -> list:
    """Futures of each shard's (normalised) columns for query rows ``q``; rows where
    ``blank`` is true become zeros (a frame with no information, as locally)."""
    c = ref.client
    q_fut = c.scatter(q, broadcast=True, direct=False)
    raw = [ref.submit(s, _raw, shard, q_fut) for s, shard in enumerate(ref.shards)]
    if not normalise:
        return raw
    parts = c.gather([ref.submit(s, _chunk_sums, b, None, 1) for s, b in enumerate(raw)])
    mean = _combine(np.concatenate(parts, axis=1)) / ref.n_places
    parts = c.gather([ref.submit(s, _chunk_sums, b, mean, 2) for s, b in enumerate(raw)])
    std = np.sqrt(_combine(np.concatenate(parts, axis=1)) / ref.n_places)
    std[_zero_spread(std, mean)] = 0.0
    if blank is not None:
        std[blank] = 0.0
    return [ref.submit(s, _scale, b, mean, std) for s, b in enumerate(raw)]


def difference_matrix(query, ref: ShardedReference, normalise: bool = True, block_rows: int = 256) -> np.ndarray:
    """The full ``(n_query, N)`` difference matrix, gathered to the client.

    Identical, bit for bit, to :func:`catgraph.differences.difference_matrix` on the
    whole reference. Meant for tests and maps that fit here; large runs use
    :func:`match_fixed_window`, which gathers per-frame summaries only.
    """
    q = ref.prepare_query(query)
    out = np.empty((q.shape[0], ref.n_places))
    for start in range(0, q.shape[0], block_rows):
        futs = _normalised_blocks(ref, q[start : start + block_rows], normalise)
        for (lo, hi), block in zip(ref.bounds, ref.client.gather(futs)):
            out[start : start + block.shape[0], lo:hi] = block
    return out


def _quantum(ref: ShardedReference, blocks: list) -> float:
    """The local matcher's quantum (:func:`catgraph._sequence_kernels.unit_of`) from
    row 0 of ``blocks`` (query frame 0): the largest ``|d_0j|`` of every shard, reduced
    here, once per query."""
    peaks = ref.client.gather([ref.submit(s, _row_peak, b, 0) for s, b in enumerate(blocks)])
    return float(unit_of(np.array([max(peaks)])))

def _halo(velocities: np.ndarray, first: int, stop: int, window: int) -> tuple[int, int]:
    """Columns a shard needs left and right of its places for query frames ``first …
    stop - 1``: the largest ``pos_v(i) - pos_v(i - L)`` over the rows and the forward
    (left) and backward (right) velocities, from the kernels' own ``pos_v`` arithmetic
    (``pos_v`` is monotone, so no earlier term of a window reaches further)."""
    i = np.arange(first, stop, dtype=np.float64)
    left = right = 0
    for v in velocities:
        reach = np.floor(v * i + 0.5) - np.floor(v * (i - window) + 0.5)
        if reach.size:
            left, right = max(left, int(reach.max())), max(right, int(-reach.min()))
    return left, right


def _line_blocks(ref: ShardedReference, q: np.ndarray, start: int, stop: int, window: int,
                 velocities: np.ndarray, unit: float | None, radius: int, want_sums: bool = False,
                 blank: np.ndarray | None = None) -> tuple[list, float]:
    """Futures of each shard's window sums and summaries (:func:`_shard_lines`) for query
    rows ``[start, stop)`` and every velocity, and the quantum (fixed by the first block
    when ``unit`` is ``None``)."""
    c = ref.client
    first = max(0, start - window)
    blocks = _normalised_blocks(ref, q[first:stop], True, None if blank is None else blank[first:stop])
    if unit is None:  # the first block starts at query frame 0
        unit = _quantum(ref, blocks)
    coded = [ref.submit(s, _codes, b, unit) for s, b in enumerate(blocks)]
    del blocks  # the float64 columns are freed once coded
    # each row's mean code (the fill outside the reference), as the local ring rounds it
    totals = np.sum(c.gather([ref.submit(s, _totals, b) for s, b in enumerate(coded)]), axis=0)
    mean_codes = np.rint(totals / ref.n_places).astype(np.int64)
    reach_left, reach_right = _halo(velocities, first, stop, window)
    out = []
    for s, (lo, hi) in enumerate(ref.bounds):
        # the code columns [lo - reach_left, lo) and [hi, hi + reach_right) on the map, from
        # whichever shards hold them: 2 bytes per column and query row
        parts = []
        for a, b in ((max(0, lo - reach_left), lo), (hi, min(ref.n_places, hi + reach_right))):
            parts.append([ref.submit(t, _columns, coded[t], max(a, t_lo) - t_lo, min(b, t_hi) - t_lo)
                          for t, (t_lo, t_hi) in enumerate(ref.bounds) if t_lo < b and a < t_hi])
        out.append(ref.submit(s, _shard_lines, coded[s], parts[0], parts[1], first, start - first, window,
                              velocities, mean_codes, lo, ref.n_places, radius, want_sums))
    return out, unit


def _totals(codes: tuple) -> np.ndarray:
    return codes[1]


def _sums_only(out: dict) -> np.ndarray:
    return out["sums"]


def _summaries_only(out: dict) -> dict:
    return out


def _effective(start: int, stop: int, window: int) -> np.ndarray:
    """``L_eff = min(L, i + 1)`` of query frames ``start … stop - 1`` (int64)."""
    return np.minimum(window, np.arange(start + 1, stop + 1, dtype=np.int64))


def window_scores(query, ref: ShardedReference, window: int, velocity: float = 1.0,
                  block_rows: int = 256) -> np.ndarray:
    """All fixed-window scores ``s_ij(L, v)`` of one velocity, ``(n_query, N)``, gathered
    to the client (tests and small maps): identical, bit for bit, to
    :func:`catgraph.sequence.fixed_window_scores` on the normalised difference matrix
    (``S u / L_eff`` from the same integer sums)."""
    check_scalar(window, "window", "window_scores", int, 1, SHARD_UNIT)
    check_scalar(block_rows, "block_rows", "window_scores", int, 1)
    velocities = _velocity_set([velocity], "window_scores")
    q = ref.prepare_query(query)
    out = np.empty((q.shape[0], ref.n_places))
    unit = None
    for start in range(0, q.shape[0], block_rows):
        stop = min(q.shape[0], start + block_rows)
        futs, unit = _line_blocks(ref, q, start, stop, window, velocities, unit, 0, want_sums=True)
        eff = _effective(start, stop, window)[:, None]
        for (lo, hi), block in zip(ref.bounds, ref.client.gather([ref.submit(s, _sums_only, f)
                                                                  for s, f in enumerate(futs)])):
            out[start:stop, lo:hi] = block[0].astype(np.float64) * unit / eff
    return out


@dataclass(frozen=True)
class ShardedMatches:
    """Per-frame results of :func:`match_fixed_window` (processing order).

    Attributes
    ----------
    match : ndarray of int, shape (n_query,)
    score, confidence : ndarray of float, shape (n_query,)
    velocity : ndarray of float, shape (n_query,)
        The velocity chosen per frame (as :attr:`catgraph.sequence.SequenceResult.velocity`).
    """

    match: np.ndarray
    score: np.ndarray
    confidence: np.ndarray
    velocity: np.ndarray | None = None


def _second_best(parts: list, bounds: list, best_j: np.ndarray, radius: int) -> np.ndarray:
    """The smallest sum more than ``radius`` places from the global best ``best_j``
    (``(rows, V)``), from each shard's summaries, exactly: a shard that holds the best
    gives its own minimum outside the best's neighbourhood; one that the neighbourhood
    does not reach gives its minimum; one whose first (last) places it covers gives the
    minimum of the rest (``pre``, ``suf``); one it covers whole gives nothing."""
    second = np.full(best_j.shape, _NONE, dtype=np.int64)
    for part, (lo, hi) in zip(parts, bounds):
        za, zb = np.maximum(best_j - radius, lo), np.minimum(best_j + radius, hi - 1)
        k_count = part["pre"].shape[2]
        head = np.take_along_axis(part["pre"], np.clip(zb + 1 - lo, 0, k_count - 1)[..., None], axis=2)[..., 0]
        tail = np.take_along_axis(part["suf"], np.clip(hi - za, 0, k_count - 1)[..., None], axis=2)[..., 0]
        value = np.select([za > zb, (best_j >= lo) & (best_j < hi), (za <= lo) & (zb >= hi - 1), za <= lo],
                          [part["low"], part["outside"], _NONE, head], tail)
        second = np.minimum(second, value)
    return second


def _moments(parts: list, n: int, unit: float, eff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's and velocity's score mean and spread, as the local kernel computes them
    (:func:`catgraph._sequence_kernels._window`): ``y = S - shift`` with ``shift`` the
    previous row's sum at place ``(pos_v(i-1) - pos_v(i)) mod N`` (0 at frame 0),
    ``E[y] = sum(y) / N``, ``var = sum(y^2) / N - E[y]^2``, mean ``(shift + E[y]) u /
    L_eff`` and spread ``sqrt(var) u / L_eff``.

    The shards' integer sums are combined exactly (Python integers), so ``sum(y)`` and
    ``sum(y^2)`` are the exact sums, rounded once to float64; the local kernel adds the
    same integer terms in float64, exactly while ``sum(y^2) < 2^53`` (every partial sum
    is then an integer below ``2^53``). Within that bound both are the local ones, bit
    for bit.
    """
    shift = sum(np.where(p["prev_here"], p["prev_sum"], 0) for p in parts)  # one shard holds it
    total = sum(p["total"].astype(object) for p in parts)
    squares = sum((p["high_sq"].astype(object) << 32) + p["low_sq"].astype(object) for p in parts)
    h = shift.astype(object)
    sy = (total - n * h).astype(np.float64)
    syy = (squares - 2 * h * total + n * h * h).astype(np.float64)
    my = sy / n
    var = syy / n - my * my
    eff = eff[:, None]
    mean = (shift.astype(np.float64) + my) * unit / eff
    with np.errstate(invalid="ignore"):
        std = np.where(var > 0.0, np.sqrt(np.where(var > 0.0, var, 0.0)) * unit / eff, 0.0)
    return mean, std


def match_fixed_window(query, ref: ShardedReference, window: int, radius: int = 10,
                       velocities=DEFAULT_VELOCITIES, confidence: str = "posterior",
                       block_rows: int = 256, no_information: np.ndarray | None = None) -> ShardedMatches:
    """Fixed-window sequence matching on the cluster, searching velocities.

    The answers of :func:`catgraph.sequence.match_sequences` with ``window=L`` and the
    same ``radius``, ``velocities`` and ``confidence`` on the normalised difference
    matrix: the same quantum and int16 codes, the same integer window sums along the
    lines of every velocity, the same per-velocity statistics handed to the same window
    rule (:func:`catgraph._window_rule._decide`), so matches, scores and chosen
    velocities are identical, bit for bit; confidences too while each row's
    ``sum_j y_j^2 < 2^53`` with ``y_j = S_ij - shift_i`` in codes (:func:`_moments`).
    Beyond it the local float64 sums round in their own order, and a score spread
    differs by at most ``1.5 N 2^-53 (1 + mean(y)^2 / var(y))`` relative (tested). Only
    ``O(block_rows V (radius + 8))`` values per shard and block return to the client.

    Parameters
    ----------
    query : array_like, shape (n_query, d)
        Query descriptors in processing order (after the map's front-end).
    ref : ShardedReference
    window : int
    radius : int
        Places either side of the best excluded when finding the second best.
    velocities : sequence of float
        Velocities searched (default: those of :func:`~catgraph.sequence.match_sequences`).
    confidence : {"posterior", "support", "gap", "neglogp", "z"}
        As :func:`~catgraph.sequence.match_sequences` with a fixed window (the first three
        are then SeqSLAM's gap).
    block_rows : int
        Query rows per round.
    no_information : ndarray of bool, shape (n_query,), optional
        Frames with no information (:func:`catgraph.frontends.check_information`):
        their normalised rows are zeros, as :func:`catgraph.io.query_differences`
        makes them.
    """
    check_scalar(window, "window", "match_fixed_window", int, 1, SHARD_UNIT)
    check_scalar(radius, "radius", "match_fixed_window", int, 0)
    check_scalar(block_rows, "block_rows", "match_fixed_window", int, 1)
    cfg = _config("match_fixed_window", int(window), "gaussian", "unrivalled", confidence, 1, 1, 1, radius, 0.0,
                  velocities, None)
    c = ref.client
    q = ref.prepare_query(query)
    n_q, n = q.shape[0], ref.n_places
    blank = None
    if no_information is not None:
        blank = np.asarray(no_information, dtype=bool)
        if blank.shape != (n_q,):
            raise InvalidParameterError(f"no_information must have one flag per query frame ({n_q}); got shape "
                                        f"{blank.shape}.")
    match, score, conf = np.empty(n_q, dtype=np.int64), np.empty(n_q), np.empty(n_q)
    velocity = np.empty(n_q)
    unit = None
    for start in range(0, n_q, block_rows):
        stop = min(n_q, start + block_rows)
        futs, unit = _line_blocks(ref, q, start, stop, window, cfg.velocities, unit, radius, blank=blank)
        parts = c.gather([ref.submit(s, _summaries_only, f) for s, f in enumerate(futs)])
        values = np.stack([p["low"] for p in parts])
        pick = np.argmin(values, axis=0)[None]  # the first shard holding the minimum: the lowest place, as locally
        best = np.take_along_axis(values, pick, axis=0)[0]
        best_j = np.take_along_axis(np.stack([p["place"] for p in parts]), pick, axis=0)[0]
        second = _second_best(parts, ref.bounds, best_j, radius)
        eff = _effective(start, stop, window)
        mean, std = _moments(parts, n, unit, eff)
        # the statistics the local kernel hands to the window rule (_sequence_kernels._window)
        st = _Stats(stop - start, cfg.velocities.shape[0], 1, 1, with_sub=False)
        st.best_j[..., 0] = best_j
        st.best_s[..., 0] = best.astype(np.float64) * unit / eff[:, None]
        st.second_s[..., 0] = np.where(second == _NONE, np.inf, second.astype(np.float64) * unit / eff[:, None])
        st.mean[..., 0], st.std[..., 0] = mean, std
        st.weights[...] = 1.0
        st.locs[..., 0, 0], st.scales[..., 0, 0] = mean, std
        # a fixed window's rule reads the rows' width only (no sub-windows, no current-frame term)
        rows_d = np.broadcast_to(np.zeros((1, 1)), (stop - start, n))
        m, s, k, _, v, _ = _decide(st, cfg, np.arange(start, stop), False, rows_d)
        match[start:stop], score[start:stop], conf[start:stop], velocity[start:stop] = m, s, k, v
    return ShardedMatches(match, score, conf, velocity)
