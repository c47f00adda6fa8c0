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
3. **Window scores** ``s_ij(L)`` (:mod:`catgraph.sequence`, same edge policy) need the
   diagonal ``d_{i−k, j−k}``, which crosses into the previous shard: each worker
   receives the last ``L`` normalised columns of its left neighbour (a halo of
   ``L × rows × 8`` bytes) and the query block carries ``L`` earlier rows, so every
   score is computed locally with diagonal prefix sums. The sums start at the block's
   edge instead of the query's first frame, so scores agree with
   :func:`catgraph.sequence.fixed_window_scores` to rounding (``~1e-12``), not bit
   for bit; the matches agree exactly.
4. **Matching** (fixed window, SeqSLAM's gap confidence): per-shard minima → the global
   best place (ties: the lowest index, as locally), then per-shard minima outside
   ``± radius`` of it → the second best, and the score spread from partial sums.

Only ``O(rows)`` numbers per shard return to the client per block; the full
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


def _tail(block: np.ndarray, width: int) -> np.ndarray:
    return np.ascontiguousarray(block[:, block.shape[1] - width :])


def _scores(block: np.ndarray, halo: np.ndarray | None, first_row: int, skip: int, window: int,
            means: np.ndarray, lo: int) -> np.ndarray:
    """Window scores of rows ``skip:`` of ``block`` (block row ``a`` is query frame
    ``first_row + a``) for the shard's places ``lo …``; ``halo`` holds the normalised
    columns left of the shard (``None`` for the first shard), ``means`` the normalised
    rows' means (the fill before the reference start). Edge policy of
    :mod:`catgraph.sequence`."""
    d = block if halo is None else np.concatenate([halo, block], axis=1)
    offset = 0 if halo is None else halo.shape[1]
    rows, cols = d.shape
    c = np.zeros((rows + 1, cols + 1))  # c[a + 1, b + 1]: diagonal prefix sum ending at (a, b)
    for a in range(rows):
        c[a + 1, 1:] = d[a] + c[a, :-1]
    cum = np.concatenate([[0.0], np.cumsum(means)])
    width = block.shape[1]
    g = lo + np.arange(width)  # place index
    b = offset + np.arange(width)  # column in d
    out = np.empty((rows - skip, width))
    for a in range(skip, rows):
        eff = min(window, first_row + a + 1)
        cur = c[a + 1, b + 1]
        v = np.empty(width)
        full = g >= eff - 1  # every term of the window lies on the reference
        v[full] = cur[full] - c[a - eff + 1, b[full] - eff + 1]
        fill = ~full  # terms before the reference start: their rows' mean difference
        v[fill] = cur[fill] + (cum[a - g[fill]] - cum[a - eff + 1])
        out[a - skip] = v / eff
    return out


def _row_min(scores: np.ndarray, lo: int) -> tuple[np.ndarray, np.ndarray]:
    j = np.argmin(scores, axis=1)
    return scores[np.arange(len(j)), j], j + lo


def _row_min_outside(scores: np.ndarray, lo: int, best_j: np.ndarray, radius: int) -> np.ndarray:
    g = lo + np.arange(scores.shape[1])
    inside = np.abs(g[None, :] - best_j[:, None]) <= radius
    return np.where(inside, np.inf, scores).min(axis=1)


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


def _score_blocks(ref: ShardedReference, q: np.ndarray, start: int, stop: int, window: int,
                  blank: np.ndarray | None = None) -> list:
    """Futures of each shard's window scores for query rows ``[start, stop)``."""
    c = ref.client
    first = max(0, start - window)
    blocks = _normalised_blocks(ref, q[first:stop], True, None if blank is None else blank[first:stop])
    # running sum of the normalised rows' means (the fill before the reference start)
    parts = c.gather([ref.submit(s, _chunk_sums, b, None, 1) for s, b in enumerate(blocks)])
    means = _combine(np.concatenate(parts, axis=1)) / ref.n_places
    out = []
    for s, ((lo, hi), block) in enumerate(zip(ref.bounds, blocks)):
        halo = None if s == 0 else ref.submit(s - 1, _tail, blocks[s - 1], window)  # moves L columns
        out.append(ref.submit(s, _scores, block, halo, first, start - first, window, means, lo))
    return out


def window_scores(query, ref: ShardedReference, window: int, block_rows: int = 256) -> np.ndarray:
    """All fixed-window scores ``s_ij(L)``, ``(n_query, N)``, gathered to the client
    (tests and small maps; see :func:`catgraph.sequence.fixed_window_scores`)."""
    check_scalar(window, "window", "window_scores", int, 1, SHARD_UNIT)
    q = ref.prepare_query(query)
    out = np.empty((q.shape[0], ref.n_places))
    for start in range(0, q.shape[0], block_rows):
        stop = min(q.shape[0], start + block_rows)
        for (lo, hi), block in zip(ref.bounds, ref.client.gather(_score_blocks(ref, q, start, stop, window))):
            out[start:stop, lo:hi] = block
    return out


@dataclass(frozen=True)
class ShardedMatches:
    """Per-frame results of :func:`match_fixed_window` (processing order)."""

    match: np.ndarray
    score: np.ndarray
    confidence: np.ndarray


def match_fixed_window(query, ref: ShardedReference, window: int, radius: int = 10,
                       block_rows: int = 256, no_information: np.ndarray | None = None) -> ShardedMatches:
    """Fixed-window sequence matching on the cluster (SeqSLAM gap confidence).

    The same answers as :func:`catgraph.sequence.match_sequences` with ``window=L``,
    ``confidence="gap"`` and ``radius``: matches identical, scores and confidences to
    rounding. Only ``O(block_rows)`` values per shard and block return to the client.

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
    for start in range(0, n_q, block_rows):
        stop = min(n_q, start + block_rows)
        scores = _score_blocks(ref, q, start, stop, window, blank)
        mins = c.gather([ref.submit(k, _row_min, s, lo) for k, (s, (lo, _)) in enumerate(zip(scores, ref.bounds))])
        values = np.stack([v for v, _ in mins])
        places = np.stack([j for _, j in mins])
        pick = np.argmin(values, axis=0)  # first shard holding the minimum: the lowest index
        rows = np.arange(stop - start)
        best, best_j = values[pick, rows], places[pick, rows]
        second = np.min(c.gather([ref.submit(k, _row_min_outside, s, lo, best_j, radius)
                                  for k, (s, (lo, _)) in enumerate(zip(scores, ref.bounds))]), axis=0)
        parts = c.gather([ref.submit(k, _chunk_sums, s, None, 1) for k, s in enumerate(scores)])
        mean = _combine(np.concatenate(parts, axis=1)) / ref.n_places
        parts = c.gather([ref.submit(k, _chunk_sums, s, mean, 2) for k, s in enumerate(scores)])
        std = np.sqrt(_combine(np.concatenate(parts, axis=1)) / ref.n_places)
        with np.errstate(divide="ignore", invalid="ignore"):
            gap = np.where(std > 0, (second - best) / std, 0.0)
        match[start:stop], score[start:stop] = best_j, best
        conf[start:stop] = np.where(np.isfinite(gap), gap, 0.0)
    return ShardedMatches(match, score, conf)
