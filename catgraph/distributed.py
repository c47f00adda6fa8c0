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
4. **Window sums** ``S_ij(L) = s_ij(L) L_eff / u`` need the diagonal ``d_{i−k, j−k}``,
   which crosses into the previous shard: each worker receives the last ``L`` code
   columns of its left neighbour (a halo of ``2 L`` bytes per query row) and the query
   block carries ``L`` earlier rows, so every sum is computed locally from integer
   diagonal prefix sums. Integer sums do not depend on where they start or in which
   order they are added: they equal the local matcher's running sums exactly, and the
   scores ``S u / L_eff`` are :func:`catgraph.sequence.fixed_window_scores` bit for bit.
5. **Matching** (fixed window, SeqSLAM's gap confidence): per-shard integer minima → the
   global best place (ties: the lowest index, as locally), then per-shard minima outside
   ``± radius`` of it → the second best; the score spread from each shard's exact
   integer sums of ``S`` and ``S²``, combined on the client as the local kernel's
   ``y = S − shift`` moments (``shift``: the previous row's sum at place ``N − 1``, from
   the last shard). Matches and scores are those of
   :func:`catgraph.sequence.match_sequences` (``window=L``, ``velocities=(1.0,)``,
   ``confidence="gap"``) bit for bit; so are the confidences while each row's
   ``Σ_j y_j² < 2^53`` (the local float64 sums are then exact). Beyond it the local
   kernel's float64 sums round in their own order, and a confidence differs by at most
   ``1.5 N 2^-53 (1 + ȳ² / var y)`` relative (the standard bound on a float64 sum of
   ``N`` rounded terms, carried through ``var = E[y²] − ȳ²`` and the square root).
   Measured on the benchmark data (rows normalised, every traversal condition):
   ``Σ_j y_j²`` at most ``2^46.1`` (Nordland, 3,576 places, ``L = 100``), and the
   largest mean ``y²`` per place (UJI month 02, ``L = 100``) would reach ``2^53`` at
   about 2.6 × 10⁵ places (8 × 10⁵ at ``L = 50``), so larger maps of such data are in
   the bounded regime.

Only ``O(rows)`` numbers per shard return to the client per block (five client rounds
per block, one more for the quantum), and the full
``n_query × N`` matrix is never gathered (:func:`difference_matrix` gathers it on
request, for tests and small maps).

What to call
------------
:func:`shard_reference` once per map (``client`` from ``distributed.Client(ADDRESS)``
or a ``LocalCluster``), then :func:`match_fixed_window` for matches or
:func:`difference_matrix` / :func:`window_scores` for the arrays. A command line option
``--scheduler ADDRESS`` maps to ``shard_reference(descriptors, metric,
distributed.Client(ADDRESS))``. Sizing for a 10⁷-place map, from measured per-shard
figures, is in ``docs/live.md``.

Workers run the same compiled kernels; on machines with different SIMD widths the
last bits of the raw differences can differ (see :mod:`catgraph._diff_kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._jit import njit
from ._sequence_kernels import _NONE, encode, unit_of
from ._validation import check_scalar
from .differences import LAYOUTS, METRICS, PreparedReference, _combine, _zero_spread, code_scale
from .exceptions import InvalidParameterError, MissingDependencyError

#: Shards hold a whole multiple of this many places (the normalisation's sum chunk);
#: a window may not be longer (its halo comes from one neighbour).
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


def _tail(codes: tuple, width: int) -> np.ndarray:
    """The last ``width`` code columns of a shard (its right neighbour's halo)."""
    block = codes[0]
    return np.ascontiguousarray(block[:, block.shape[1] - width :])


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


def _first(pair: tuple) -> np.ndarray:
    return pair[0]


@njit(nogil=True)
def _diagonal_sums(d, offset, first_row, skip, window, cum, lo, out, last):  # pragma: no cover - compiled
    """Integer window sums (the kernel of :func:`_window_sums`); ``last[a - skip]`` gets
    the sum of row ``a - 1`` at the shard's last place (``0`` for query frame 0)."""
    rows, cols = d.shape
    width = out.shape[1]
    c = np.zeros((rows + 1, cols + 1), dtype=np.int64)  # c[a + 1, b + 1]: diagonal prefix sum ending at (a, b)
    for a in range(rows):
        for b in range(cols):
            c[a + 1, b + 1] = d[a, b] + c[a, b]
    start = skip - 1 if skip > 0 else 0
    for a in range(start, rows):
        eff = min(window, first_row + a + 1)
        for k in range(width):
            g = lo + k  # place index
            b = offset + k  # column in d
            if g >= eff - 1:  # every term of the window lies on the reference
                v = c[a + 1, b + 1] - c[a - eff + 1, b - eff + 1]
            else:  # terms before the reference start: their rows' mean codes
                v = c[a + 1, b + 1] + (cum[a - g] - cum[a - eff + 1])
            if a >= skip:
                out[a - skip, k] = v
            if k == width - 1 and a + 1 >= skip and a + 1 < rows:
                last[a + 1 - skip] = v
    if skip == 0 and rows > 0:
        last[0] = 0  # query frame 0 (the block starts the query): the matcher's sums start at zero


def _window_sums(codes: tuple, halo: np.ndarray | None, first_row: int, skip: int, window: int,
                 mean_codes: np.ndarray, lo: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer window sums ``S`` of rows ``skip:`` of the coded block (block row ``a`` is
    query frame ``first_row + a``) for the shard's places ``lo …``; ``halo`` holds the
    codes of the columns left of the shard (``None`` for the first shard), ``mean_codes``
    the rows' mean codes (the fill before the reference start). Edge policy of
    :mod:`catgraph.sequence`; ``S`` equals the local matcher's running sums exactly.

    Also returns, per row, the previous row's sum at the shard's last place (the local
    kernel's shift for the moments, read from the last shard only).
    """
    block = codes[0]
    d = block if halo is None else np.concatenate([halo, block], axis=1)
    offset = 0 if halo is None else halo.shape[1]
    cum = np.concatenate([[0], np.cumsum(mean_codes, dtype=np.int64)])
    out = np.empty((block.shape[0] - skip, block.shape[1]), dtype=np.int64)
    last = np.zeros(block.shape[0] - skip, dtype=np.int64)
    _diagonal_sums(d, offset, first_row, skip, window, cum, lo, out, last)
    return out, last


@njit(nogil=True)
def _summarise(s, lo, low, place, total, high_sq, low_sq):  # pragma: no cover - compiled
    """Per row: the smallest sum and its first place, the sum of the sums and of their
    squares, the squares split at ``2^32`` so that both halves add up exactly in int64."""
    mask = (np.int64(1) << 32) - 1
    for a in range(s.shape[0]):
        m = s[a, 0]
        jm = 0
        t = np.int64(0)
        qh = np.int64(0)
        ql = np.int64(0)
        for k in range(s.shape[1]):
            x = s[a, k]
            if x < m:
                m = x
                jm = k
            t += x
            sq = x * x  # |S| < 2^31: exact in int64
            qh += sq >> 32
            ql += sq & mask
        low[a] = m
        place[a] = jm + lo
        total[a] = t
        high_sq[a] = qh
        low_sq[a] = ql


def _row_summary(sums: tuple, lo: int) -> tuple[np.ndarray, ...]:
    """``(min, first place of the min, sum S, sum S^2 high half, low half, previous row's
    last sum)`` per row of the shard's window sums (all int64, exact)."""
    s, last = sums
    out = tuple(np.empty(s.shape[0], dtype=np.int64) for _ in range(5))
    _summarise(s, lo, *out)
    return (*out, last)


def _row_min_outside(sums: tuple, lo: int, best_j: np.ndarray, radius: int) -> np.ndarray:
    """The smallest sum more than ``radius`` places from ``best_j`` (``_NONE`` if none)."""
    s = sums[0]
    g = lo + np.arange(s.shape[1])
    inside = np.abs(g[None, :] - best_j[:, None]) <= radius
    return np.where(inside, _NONE, s).min(axis=1)


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


def _sum_blocks(ref: ShardedReference, q: np.ndarray, start: int, stop: int, window: int,
                unit: float | None, blank: np.ndarray | None = None) -> tuple[list, float]:
    """Futures of each shard's integer window sums (and previous-row last sums) for query
    rows ``[start, stop)``, and the quantum (fixed by the first block when ``unit`` is
    ``None``)."""
    c = ref.client
    first = max(0, start - window)
    blocks = _normalised_blocks(ref, q[first:stop], True, None if blank is None else blank[first:stop])
    if unit is None:  # the first block starts at query frame 0
        unit = _quantum(ref, blocks)
    coded = [ref.submit(s, _codes, b, unit) for s, b in enumerate(blocks)]
    del blocks  # the float64 columns are freed once coded
    # each row's mean code (the fill before the reference start), as the local ring rounds it
    totals = np.sum(c.gather([ref.submit(s, _totals, b) for s, b in enumerate(coded)]), axis=0)
    mean_codes = np.rint(totals / ref.n_places).astype(np.int64)
    out = []
    for s, ((lo, hi), block) in enumerate(zip(ref.bounds, coded)):
        # the last L code columns of the left neighbour: 2 L bytes per row
        halo = None if s == 0 else ref.submit(s - 1, _tail, coded[s - 1], window)
        out.append(ref.submit(s, _window_sums, block, halo, first, start - first, window, mean_codes, lo))
    return out, unit


def _totals(codes: tuple) -> np.ndarray:
    return codes[1]


def _effective(start: int, stop: int, window: int) -> np.ndarray:
    """``L_eff = min(L, i + 1)`` of query frames ``start … stop - 1`` (int64)."""
    return np.minimum(window, np.arange(start + 1, stop + 1, dtype=np.int64))


def window_scores(query, ref: ShardedReference, window: int, block_rows: int = 256) -> np.ndarray:
    """All fixed-window scores ``s_ij(L)``, ``(n_query, N)``, gathered to the client
    (tests and small maps): identical, bit for bit, to
    :func:`catgraph.sequence.fixed_window_scores` on the normalised difference matrix
    (``S u / L_eff`` from the same integer sums)."""
    check_scalar(window, "window", "window_scores", int, 1, SHARD_UNIT)
    q = ref.prepare_query(query)
    out = np.empty((q.shape[0], ref.n_places))
    unit = None
    for start in range(0, q.shape[0], block_rows):
        stop = min(q.shape[0], start + block_rows)
        futs, unit = _sum_blocks(ref, q, start, stop, window, unit)
        eff = _effective(start, stop, window)[:, None]
        for (lo, hi), block in zip(ref.bounds, ref.client.gather([ref.submit(s, _first, f)
                                                                  for s, f in enumerate(futs)])):
            out[start:stop, lo:hi] = block.astype(np.float64) * unit / eff
    return out


@dataclass(frozen=True)
class ShardedMatches:
    """Per-frame results of :func:`match_fixed_window` (processing order)."""

    match: np.ndarray
    score: np.ndarray
    confidence: np.ndarray


def _spread(summaries: list, n: int, unit: float, eff: np.ndarray) -> np.ndarray:
    """Each row's score spread, as the local kernel computes it (:func:`_window`):
    ``y = S - shift`` with ``shift`` the previous row's sum at the last place,
    ``var = sum(y^2) / N - (sum(y) / N)^2`` and ``sqrt(var) u / L_eff``.

    The shards' integer sums are combined exactly (Python integers), so ``sum(y)`` and
    ``sum(y^2)`` are the exact sums, rounded once to float64; the local kernel adds the
    same integer terms in float64, exactly while ``sum(y^2) < 2^53`` (every partial sum
    is then an integer below ``2^53``). Within that bound the spread is the local one,
    bit for bit.
    """
    shift = summaries[-1][5]  # the last shard holds place N - 1
    std = np.empty(eff.shape[0])
    for a in range(eff.shape[0]):
        total = sum(int(s[2][a]) for s in summaries)
        squares = sum((int(s[3][a]) << 32) + int(s[4][a]) for s in summaries)
        h = int(shift[a])
        sy = total - n * h
        syy = squares - 2 * h * total + n * h * h
        my = float(sy) / n
        var = float(syy) / n - my * my
        std[a] = np.sqrt(var) * unit / float(eff[a]) if var > 0.0 else 0.0
    return std


def match_fixed_window(query, ref: ShardedReference, window: int, radius: int = 10,
                       block_rows: int = 256, no_information: np.ndarray | None = None) -> ShardedMatches:
    """Fixed-window sequence matching on the cluster (SeqSLAM gap confidence).

    The answers of :func:`catgraph.sequence.match_sequences` with ``window=L``,
    ``velocities=(1.0,)``, ``confidence="gap"`` and ``radius`` on the normalised
    difference matrix: the same quantum and int16 codes, the same integer window sums,
    so matches and scores are identical, bit for bit; confidences too while each row's
    ``sum_j y_j^2 < 2^53`` with ``y_j = S_ij - shift_i`` in codes (:func:`_spread`).
    Beyond it the local float64 sums round in their own order, and a confidence differs
    by at most ``1.5 N 2^-53 (1 + mean(y)^2 / var(y))`` relative (tested). Only
    ``O(block_rows)`` values per shard and block return to the client.

    Parameters
    ----------
    query : array_like, shape (n_query, d)
        Query descriptors in processing order (after the map's front-end).
    ref : ShardedReference
    window : int
    radius : int
        Places either side of the best excluded when finding the second best.
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
    c = ref.client
    q = ref.prepare_query(query)
    n_q = q.shape[0]
    blank = None
    if no_information is not None:
        blank = np.asarray(no_information, dtype=bool)
        if blank.shape != (n_q,):
            raise InvalidParameterError(f"no_information must have one flag per query frame ({n_q}); got shape "
                                        f"{blank.shape}.")
    match, score, conf = np.empty(n_q, dtype=np.int64), np.empty(n_q), np.empty(n_q)
    unit = None
    for start in range(0, n_q, block_rows):
        stop = min(n_q, start + block_rows)
        sums, unit = _sum_blocks(ref, q, start, stop, window, unit, blank)
        summaries = c.gather([ref.submit(k, _row_summary, s, lo)
                              for k, (s, (lo, _)) in enumerate(zip(sums, ref.bounds))])
        values = np.stack([m[0] for m in summaries])
        places = np.stack([m[1] for m in summaries])
        pick = np.argmin(values, axis=0)  # first shard holding the minimum: the lowest place, as locally
        rows = np.arange(stop - start)
        best, best_j = values[pick, rows], places[pick, rows]
        second = np.min(c.gather([ref.submit(k, _row_min_outside, s, lo, best_j, radius)
                                  for k, (s, (lo, _)) in enumerate(zip(sums, ref.bounds))]), axis=0)
        eff = _effective(start, stop, window)
        # the local kernel's arithmetic (_sequence_kernels._window, _window_rule._decide)
        best_s = best.astype(np.float64) * unit / eff
        second_s = np.where(second == _NONE, np.inf, second.astype(np.float64) * unit / eff)
        std = _spread(summaries, ref.n_places, unit, eff)
        with np.errstate(divide="ignore", invalid="ignore"):
            gap = np.where(std > 0, (second_s - best_s) / std, 0.0)
        match[start:stop], score[start:stop] = best_j, best_s
        conf[start:stop] = np.where(np.isfinite(gap), gap, 0.0)
    return ShardedMatches(match, score, conf)
