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
   With hub offsets (:func:`catgraph.hubs.map_hub_offsets`, computed from the map),
   each worker subtracts its places' offsets and the rows are normalised again as
   :func:`catgraph.hubs.apply_hub_offsets` does it, with the rows' numpy ``mean()`` and
   ``std()`` reduced in numpy's own order (see 6; two more rounds).
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
5. **Matching** (:func:`match_fixed_window`). Per row and velocity each shard returns, in one round:
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
6. **Adaptive window** (:func:`match_adaptive_window`; the library's matcher with the rules that
   read its statistics alone, default :data:`catgraph.sequence.DEFAULT_LINE_RULE`; the local
   default rule "tracked" runs a filter over the whole map beside the matcher, which no shard
   holds, and is refused here).
   The same summaries for every candidate length ``L`` of the grid (the block carries
   ``l_max`` earlier rows, the halos reach ``l_max`` frames back), and, per length
   ``g``, the sums of every length ``h`` at the shard's own best place of length ``g``:
   the global best of length ``g`` is the first best of the shard that holds it, so the
   client takes these from that shard and has the local kernel's sub-window scores
   exactly, in the same round. The statistics are those the local kernel hands to the
   window rule; the default approximation ("gaussian") is built from them alone (the
   robust and mixture approximations need every score of a window in one place: the
   median, or an EM fit on a subsample, and are refused). The confidences "posterior"
   (the default) and "support" also read the current frame's own row: its difference at
   the match (each shard returns its row's value at its best places) and the row's
   ``mean()`` and ``std()`` as numpy computes them. numpy sums a contiguous float64 row
   pairwise (halves cut at a multiple of 8, blocks of at most 128 values with eight
   interleaved accumulators), so a sum of shard sums would differ in the last bits; the
   client plans numpy's tree for ``N`` values, each shard sums the subtrees that lie in
   it with numpy itself (the same values in the same order), the at most 128-value
   blocks across a shard edge are gathered, and the client adds the parts along the
   tree (two rounds: the sums, then the squared deviations from the mean, formed as
   numpy forms them; ``tests/test_distributed.py`` checks this against the installed
   numpy's own ``mean()`` and ``std()``). The rule, the velocity, the length and the confidence then come
   from :func:`catgraph._window_rule._decide` itself. Matches, scores, velocities,
   window lengths and confidences equal the local :func:`catgraph.sequence.match_sequences`
   bit for bit (tested: every rule, every confidence, in order, reversed, at speed 2,
   frames without information), within the ``2^53`` bound of step 5.

7. **Rules that read the rows** ("predictive", "decorrelated"; :mod:`catgraph._window_rule`).
   Both keep a record from frame to frame: at frame ``i`` each length's line of frame
   ``i - K`` (its best place at the frame's velocity, both fixed by the window statistics
   before the rule runs) predicts a place, and the rule reads the row's standardised
   value there. The client plans these ``G`` places per frame from the statistics and
   the record the previous block left (:func:`_predicted_places`), and the shard that
   holds each place returns its value in the first round of the row moments (6), so the
   lookups add no round: ``16 G`` bytes per frame (an int32 row and column out, a
   float64 back; 208 bytes for the default 13 lengths), and the rows stay where they
   were computed. Rule "predictive" (``K`` = :data:`~catgraph._window_rule.PREDICTION_HORIZON`)
   needs nothing more; with a confidence other than "posterior"/"support" it adds the two
   moment rounds. Rule "decorrelated" also needs each frame's horizon ``K_t``
   (:class:`catgraph._window_rule._Horizon`), which averages the row's standardised values
   at its ``m`` best places *in the order* :func:`numpy.argpartition` *returns them over the
   whole row* (and, where the ``m``-th value is tied, in the set it picks). That order is
   the outcome of a comparison-based selection over every value of the row (and of the
   CPU's sorting kernels); no merge of per-shard best places reproduces it, and a float64
   sum of ``m`` values depends on its order. So the whole row meets in one place: per
   chunk of :data:`HORIZON_ROWS` frames each shard's columns go to the worker of shard 0,
   which runs the local ``_Horizon.update`` on each whole row (the same contiguous
   float64 values) in a chain of tasks that carries the horizon from chunk to chunk; the
   client gathers only ``K_t`` (8 bytes per frame), with the summaries, in the same round.
   Cost per frame: ``8 (N - N_0)`` bytes between workers (``N_0`` the places of shard 0),
   never through the client, and the local rule's own ``O(N)`` work on that worker. The
   record then reads its ``G`` lookups as "predictive" does. Matches, scores, velocities,
   window lengths and confidences equal the local run bit for bit (tested: in order,
   reversed, shuffled, at speed 2, hub-corrected, frames without information, blocks
   and horizon chunks cut mid-record). A rule that averaged its best places in a
   canonical order (by value, then place) would need only per-shard best places
   (``16 m`` bytes per frame and shard) and ``HORIZON_MAX m`` lookups per frame; that is
   a change of the local rule, not made here.

8. **Rule "spanning"** (:mod:`catgraph._window_rule`). It keeps the tests of "unrivalled"
   and reads the clock of "decorrelated": a sub-window's best line counts as a rival only
   where its length spans the frame's horizon ``K_t``, and where the chosen window spans
   ``K_t`` the velocity is re-chosen at that length. Beyond what "unrivalled" already
   reads, the rule reads (a) ``K_t``; (b) the admissibility of the chosen length at
   *every* velocity (the rival test on each velocity's sub-window sums, and ``log p`` of
   every velocity at the chosen length); (c) with the confidences "posterior" and
   "support", the current frame's difference at the re-chosen velocity's match. (b) and
   (c) are already on the client: the summaries carry every velocity's statistics and
   sub-window sums at every length (step 6), and each shard returns its row's value at
   its best place of every velocity and length (``8 V G`` bytes per frame and shard, sent
   for those confidences whatever the rule). Only (a) is new, and it is served as for
   "decorrelated": the whole rows meet on shard 0's worker, which runs the local
   ``_Horizon.update`` in the chain of tasks of step 7, and ``K_t`` (8 bytes per frame)
   comes back in the summaries' round: ``8 (N - N_0)`` bytes per frame between workers,
   no new client round. The rule keeps no record of lines, so none of the ``G`` lookups
   of step 7 is planned, and with a confidence other than "posterior"/"support" the row
   moments are not reduced at all (the rule hands each row only to the replayed clock).
   Matches, scores, velocities, window lengths and confidences equal the local run bit
   for bit (tested: in order, reversed, shuffled, at speed 2, on a route driven at a
   varying speed across shard edges where a wrong horizon changes the answers,
   hub-corrected, frames without information; and on the real data,
   ``benchmarks/results/distributed_identity_spanning.md``: Nordland and UJI, one shard
   and padded to two shards with the edge in the route's middle, every frame identical).

9. **Confidence "changepoint"** (:mod:`catgraph._window_rule`, ``T`` =
   :data:`~catgraph._window_rule.CHANGE_POINT_FRAMES`). It weighs the standardised
   differences of the latest ``T`` frames at the places the frame's chosen line passes:
   ``d_{i-f}[match_i - (pos_v(i) - pos_v(i - f))]``, ``f < T``, each with its row's mean and
   spread. The line is known only once the rule has chosen it, so these values are asked
   for after the rule, by the rule itself (the rows handed to
   :func:`catgraph._window_rule._decide` serve them, :class:`_Lines`): each shard returns
   the values of the (frame, place) pairs it holds, in one more round per block, from the
   normalised rows it already has (the block carries ``l_max >= T - 1`` earlier rows, so
   frames of the previous block are there too, the same values). ``f = 0`` (the current
   frame at its match) is served with the summaries (6), and so is every frame of the
   block at its best places of every velocity and length (where a line that holds passes),
   so at most ``T - 1`` pairs per frame travel: ``16 (T - 1)`` bytes per frame (an int32
   row and column out, a float64 back: 64 bytes with ``T = 5``), fewer where the line has
   left the map, a row is flat, or the value was served already (measured on the real
   data, ``benchmarks/results/distributed_identity_spanning_changepoint.md``: 0.15–0.23
   pairs per frame on Nordland, 0.03–0.16 on UJI 02, i.e. 2–4 bytes per frame).
   The earlier rows' means and spreads are those the client reduced for the previous block
   (step 6), carried in the record (``16 (T - 1)`` bytes). Matches, scores, velocities,
   window lengths and confidences equal the local run bit for bit (tested: in order,
   reversed, at speed 2, shuffled, blocks of 37 frames on a route that crosses two shard
   edges; rules "unrivalled", "predictive" and "decorrelated" hub-corrected with frames
   without information; and on the real data padded to two shards, every frame).

10. **Rule "punctuated"** (:mod:`catgraph._window_rule`). It is "spanning" with the spread
    test read only on the sub-windows that span half the horizon ``K_t`` or hold a *break*
    of the rows (a frame whose best places are random places for each of the
    :data:`~catgraph._window_rule.BREAK_LAGS` rows before it). A break is read from the
    clock's own ratios (the same best places of whole rows), so it is computed where the
    horizon is: the worker of step 7 runs the local :class:`catgraph._window_rule._Breaks`
    (the clock of "decorrelated" that also marks the breaks) on the whole rows, and returns
    with each ``K_t`` the frames since the latest break (8 more bytes per frame, in the same
    round). Everything else is read as for "spanning". Matches, scores, velocities, window
    lengths and confidences equal the local run bit for bit (tested as for "spanning",
    with the confidence "changepoint" among them).

11. **Rule "gated"** (:mod:`catgraph._window_rule`). It is "spanning" with the spread test
    read on the sub-windows that span the horizon ``K_t`` and, below it, only where the
    window's own line is weak. The line's strength is the window's score against the
    random places' mean and common spread at each sub-window's length, statistics the
    summaries already carry (step 8): no bytes and no round beyond those of "spanning".
    Matches, scores, velocities, window lengths and confidences equal the local run bit
    for bit (tested as for "spanning"). Rule "contested" adds a rival read from the same
    statistics (the line's strength, each length's significance and the horizon ``K_t``):
    again no bytes and no round beyond those of "spanning".

Per block, only ``O(rows V G (radius + G + 8))`` numbers per shard return to the client
(``G`` candidate lengths, 1 for a fixed window): four client rounds for a fixed window
(two for the normalisation, one for the mean codes, one for the summaries; one more per
query for the quantum), two more for the row moments of the adaptive window's
confidence (one more with "changepoint"), two more for the hub correction; the full
``n_query × N`` matrix is never gathered
(:func:`difference_matrix` gathers it on request, for tests and small maps).

What to call
------------
:func:`shard_reference` once per map (``client`` from ``distributed.Client(ADDRESS)``
or a ``LocalCluster``), then :func:`match_adaptive_window` or :func:`match_fixed_window`
for matches (every velocity of :data:`catgraph.sequence.DEFAULT_VELOCITIES` by
default, as locally) or
:func:`difference_matrix` / :func:`window_scores` for the arrays. A command line option
``--scheduler ADDRESS`` maps to ``shard_reference(descriptors, metric,
distributed.Client(ADDRESS))`` (:func:`catgraph.experiment.run_on_cluster`). Sizing
for a 10⁷-place map, from measured per-shard figures, is in ``docs/live.md``.

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
from ._window_rule import (CHANGE_POINT_FRAMES, RECORD_RULES, WEIGHED_CONFIDENCES, _decide, _log_p, _needs_sub,
                           _new_record, _position, _Record, _Stats)
from .differences import LAYOUTS, METRICS, PreparedReference, RowSource, _combine, _zero_spread, code_scale
from .exceptions import InvalidParameterError, MissingDependencyError
from .hubs import HUB_ROWS, HUB_THRESHOLD
from .sequence import DEFAULT_CONFIDENCE, DEFAULT_GRID, DEFAULT_LINE_RULE, DEFAULT_VELOCITIES, _config, _velocity_set

#: Shards hold a whole multiple of this many places (the normalisation's sum chunk);
#: a window may not be longer (its sums' squares then stay exact in int64).
SHARD_UNIT = 4096

#: Window rules that :func:`match_adaptive_window` runs exactly (every rule of
#: :data:`catgraph.sequence.RULES`). The first five decide a frame from that frame's
#: window statistics (and its own row) alone. "predictive" also reads, per frame, the
#: row's mean and spread and its values at the ``G`` places the lines of ``K`` frames back
#: predict: ``16 G`` bytes per frame, no extra round with the default confidence (two
#: rounds per block otherwise). "decorrelated" reads the same and its horizon ``K_t``,
#: which needs each whole row in one place: ``8 N`` bytes per frame between workers
#: (never through the client), no extra client round (step 7 of the module notes).
#: "spanning" reads that horizon and, beyond it, only statistics the summaries already
#: carry: the same ``8 N`` bytes between workers, no lookups, no extra round (step 8).
#: "punctuated" reads the same horizon and, from the same worker, the frames since the latest
#: break of the rows (8 more bytes per frame, in the same round; step 10).
#: "gated" and "contested" read what "spanning" reads (step 11), "persistent" and "challenged" what
#: "punctuated" reads.
#: Every rule also runs exactly with the confidence "changepoint": ``16 (T - 1)`` bytes per
#: frame and one more round per block (step 9).
EXACT_RULES = ("unrivalled", "evident", "consistent", "sustained", "literal", "predictive", "decorrelated",
               "spanning", "punctuated", "gated", "contested", "persistent", "challenged")

__all__ = ["ShardedReference", "ShardedMatches", "shard_reference", "difference_matrix", "map_hub_offsets",
           "window_scores", "match_fixed_window", "match_adaptive_window"]


def _client(scheduler: Any):
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - dask is installed with the [dask] extra
        raise MissingDependencyError('Dask sharding needs dask.distributed: pip install "catgraph[dask]".') from None
    if isinstance(scheduler, Client):
        return scheduler
    if isinstance(scheduler, str):
        from .sweep import connect

        return connect(scheduler)
    raise InvalidParameterError(
        f"scheduler must be a Dask scheduler address ('tcp://host:8786') or a distributed.Client; got {scheduler!r}."
    )


# ---------------------------------------------------------------------------------------
# worker-side functions (module level: they travel by reference)


#: Bytes of descriptors :func:`shard_reference` reads and sends at once: a larger shard
#: goes in pieces, so the client holds one piece, not one shard, and a worker the shard's
#: rows and at most two pieces in flight.
SHARD_PIECE_BYTES = 64 << 20


def _send_in_pieces(client, ref, lo: int, hi: int, piece_rows: int, pin: dict):
    """Rows ``lo:hi`` of ``ref`` sent to the worker of ``pin`` a piece at a time: the
    shard's rows are made there (:func:`_empty_rows`), each piece is scattered, copied
    into them (:func:`_write_rows`) and released, and the next piece but one is read only
    once that copy is done. Returns the future of the filled rows (:func:`_filled`): a
    task's result like any other, so the rows go when the client lets go of them (a client
    that stops half way leaves nothing behind)."""
    rows = client.submit(_empty_rows, hi - lo, ref.shape[1], ref.dtype, **pin)
    written = []
    for a in range(lo, hi, piece_rows):
        piece = client.scatter(np.ascontiguousarray(ref[a : min(hi, a + piece_rows)]), workers=pin["workers"],
                               direct=False, hash=False)
        written.append(client.submit(_write_rows, rows, piece, a - lo, **pin))
        del piece  # the worker keeps it until its copy is done, then frees it
        if len(written) >= 2:
            written[-2].result()  # at most two pieces in flight
    return client.submit(_filled, rows, *written, **pin)


def _empty_rows(n: int, dim: int, dtype) -> np.ndarray:
    return np.empty((n, dim), dtype=dtype)


def _write_rows(rows: np.ndarray, piece: np.ndarray, offset: int) -> int:
    """Copy ``piece`` into ``rows`` (the worker's own array, the result of
    :func:`_empty_rows`, which tasks on the same worker receive as it is, not a copy)."""
    rows[offset : offset + piece.shape[0]] = piece
    return piece.shape[0]


def _filled(rows: np.ndarray, *written: int) -> np.ndarray:
    if sum(written) != rows.shape[0]:  # pragma: no cover - every piece is awaited as an argument
        raise RuntimeError(f"a shard received {sum(written)} of its {rows.shape[0]} rows")
    return rows


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


def _row_peaks(block: np.ndarray) -> np.ndarray:
    """``max_j |d_row,j|`` of each row over the shard's columns (the quantum's reduction)."""
    return np.abs(block).max(axis=1) if block.shape[1] else np.zeros(block.shape[0])


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
def _line_pass(d, ext_lo, n, lo, w, first_row, skip, windows, v, mean_codes, vi, radius, scores, low, place, total,
               high_sq, low_sq, outside, pre, suf, prev_sum, prev_here, sub):  # pragma: no cover - compiled
    """Integer window sums ``S`` of velocity ``v`` and every length in ``windows`` along
    lines, for the shard's places ``lo … lo + w - 1`` and block rows ``skip …`` (block row
    ``r`` is query frame ``first_row + r``), and their per-row summaries.

    ``d`` holds the codes of places ``ext_lo …`` (the shard and its halo); a term whose
    place lies outside ``[0, n)`` is its row's mean code (``mean_codes``), the edge policy
    of :mod:`catgraph.sequence`. Row ``r`` sums the ``e = min(L, i + 1, r + 1)`` latest
    terms of each line: the window itself from row ``skip - 1`` on (the block carries
    ``max(windows)`` earlier rows), fewer before. A line that continues from the previous
    row within the shard takes one new term and drops the one ``L`` frames back (the
    local matcher's update); a line that enters the shard's places is summed term by term
    (``|Δpos|`` lines per row, ``O(L)`` each). The sums are integers, so they equal the
    local running sums exactly, however they were added.

    Per output row ``o = r - skip``, velocity index ``vi`` and length index ``g``: the
    smallest sum and its first place, the sum of the sums and of their squares (split at
    ``2^32`` so that the halves add up exactly), the smallest sum more than ``radius``
    places from the shard's best (``outside``), ``pre[o, vi, g, k] = min S[lo + k:]`` and
    ``suf[o, vi, g, k] = min S[:hi - k]`` (``k < K``: the second best when the global best
    lies within ``radius`` of the shard's edge), the previous row's sum at place
    ``(pos_v(i-1) - pos_v(i)) mod n`` where the shard holds it (the local kernel's shift
    for the moments), and, when ``sub`` is not empty, ``sub[o, vi, g, h]``: the sum of
    length ``h`` at the shard's best place of length ``g``. ``scores`` (``(rows, w)`` or
    empty) receives the sums of the first length.
    """
    rows = d.shape[0]
    g_count = windows.shape[0]
    k_count = pre.shape[3]
    last = np.zeros((g_count, w), dtype=np.int64)
    cur = np.zeros((g_count, w), dtype=np.int64)
    base = lo - ext_lo  # column of place lo in d
    for r in range(rows):
        i = first_row + r
        p = position(v, i)
        delta = 0
        c_lo = 0
        c_hi = 0
        if r > 0:  # places whose line continues from the previous row within the shard
            delta = p - position(v, i - 1)
            c_lo = max(0, delta)
            c_hi = min(w, w + delta)
        if c_hi <= c_lo:
            c_lo = 0
            c_hi = 0
        new = d[r, base:base + w]
        for g in range(g_count):
            window = windows[g]
            e = min(window, i + 1, r + 1)
            cg = cur[g]
            lg = last[g]
            # lines entering the shard's places: their window term by term
            for k in range(0, c_lo):
                cg[k] = _direct(d, mean_codes, ext_lo, n, first_row, v, p, i, e, lo + k)
            for k in range(c_hi, w):
                cg[k] = _direct(d, mean_codes, ext_lo, n, first_row, v, p, i, e, lo + k)
            if c_hi <= c_lo:
                continue
            # lines continuing within the shard: one new term, the one L frames back dropped
            if r < window:
                _add_new(cg[c_lo:c_hi], lg[c_lo - delta:c_hi - delta], new[c_lo:c_hi])
                continue
            off = p - position(v, i - window)  # the line through place j met place j - off then
            m_old = np.int64(mean_codes[r - window])
            old = d[r - window]
            in_lo = min(max(c_lo, off - lo), c_hi)  # old place inside [0, n) for k in [in_lo, in_hi)
            in_hi = max(min(c_hi, n + off - lo), in_lo)
            _add_new_fill(cg[c_lo:in_lo], lg[c_lo - delta:in_lo - delta], new[c_lo:in_lo], m_old)
            _add_new_old(cg[in_lo:in_hi], lg[in_lo - delta:in_hi - delta], new[in_lo:in_hi],
                         old[base - off + in_lo:base - off + in_hi])
            _add_new_fill(cg[in_hi:c_hi], lg[in_hi - delta:c_hi - delta], new[in_hi:c_hi], m_old)
        if r >= skip:
            o = r - skip
            ps = (position(v, i - 1) - p) % n if i >= 1 else -1
            for g in range(g_count):
                row = cur[g]
                m, tot, qh, ql = _int_moments(row)
                jm = 0
                while row[jm] != m:
                    jm += 1
                low[o, vi, g] = m
                place[o, vi, g] = lo + jm
                total[o, vi, g] = tot
                high_sq[o, vi, g] = qh
                low_sq[o, vi, g] = ql
                outside[o, vi, g] = min(_min_of(row[:max(0, jm - radius)]), _min_of(row[min(w, jm + radius + 1):]))
                if w >= 2 * k_count:  # pre[k] = min row[k:], suf[k] = min row[:w - k], k < K
                    tail = _min_of(row[k_count:w - k_count])
                    head = tail
                    for k in range(w - k_count, w):
                        tail = min(tail, row[k])
                    for k in range(0, k_count):
                        head = min(head, row[k])
                else:
                    tail = _min_of(row[k_count:])
                    head = _min_of(row[:w - k_count])
                for k in range(k_count - 1, -1, -1):
                    tail = min(tail, row[k])
                    pre[o, vi, g, k] = tail
                for k in range(k_count - 1, -1, -1):
                    head = min(head, row[w - k - 1])
                    suf[o, vi, g, k] = head
                if lo <= ps < lo + w:
                    prev_sum[o, vi, g] = last[g, ps - lo]
                    prev_here[o, vi, g] = True
                if sub.shape[3] > 0:
                    for h in range(g_count):
                        sub[o, vi, g, h] = cur[h, jm]
            if scores.shape[0] > 0:
                for k in range(w):
                    scores[o, k] = cur[0, k]
        last, cur = cur, last


@njit(nogil=True)
def _direct(d, mean_codes, ext_lo, n, first_row, v, p, i, e, j):  # pragma: no cover - compiled
    """The window sum of the line through place ``j`` at frame ``i`` (``e`` terms), term by term."""
    s = np.int64(0)
    for t in range(i - e + 1, i + 1):
        q = j - (p - position(v, t))
        rr = t - first_row
        s += np.int64(d[rr, q - ext_lo]) if 0 <= q < n else np.int64(mean_codes[rr])
    return s


@njit(nogil=True)
def _add_new(out, prev, new):  # pragma: no cover - compiled
    """``out = prev + new`` (equal-length views: a plain loop the compiler vectorises)."""
    for k in range(out.shape[0]):
        out[k] = prev[k] + np.int64(new[k])


@njit(nogil=True)
def _add_new_old(out, prev, new, old):  # pragma: no cover - compiled
    """``out = prev + new - old``."""
    for k in range(out.shape[0]):
        out[k] = prev[k] + (np.int64(new[k]) - np.int64(old[k]))


@njit(nogil=True)
def _add_new_fill(out, prev, new, fill):  # pragma: no cover - compiled
    """``out = prev + new - fill`` (the dropped term off the reference: its row's mean code)."""
    for k in range(out.shape[0]):
        out[k] = prev[k] + (np.int64(new[k]) - fill)


@njit(nogil=True)
def _min_of(seg):  # pragma: no cover - compiled
    """The smallest of some integer sums (``_NONE`` for none)."""
    m = _NONE
    for k in range(seg.shape[0]):
        x = seg[k]
        m = x if x < m else m
    return m


@njit(nogil=True)
def _int_moments(seg):  # pragma: no cover - compiled
    """The smallest sum, the sum of the sums and of their squares, the squares split at
    ``2^32`` so that both halves add up exactly in int64 (``|S| < 2^27``: ``S^2`` exact)."""
    mask = (np.int64(1) << 32) - 1
    m = _NONE
    t = np.int64(0)
    qh = np.int64(0)
    ql = np.int64(0)
    for k in range(seg.shape[0]):
        x = seg[k]
        m = x if x < m else m
        t += x
        sq = x * x
        qh += sq >> 32
        ql += sq & mask
    return m, t, qh, ql


def _shard_lines(codes: tuple, left: list, right: list, first_row: int, skip: int, windows: np.ndarray,
                 velocities: np.ndarray, mean_codes: np.ndarray, lo: int, n: int, radius: int,
                 want_sums: bool = False, want_sub: bool = False, block: np.ndarray | None = None) -> dict:
    """One shard's window sums along the lines of every velocity and length
    (:func:`_line_pass`), with the code columns ``left`` and ``right`` of it (the halos,
    from the neighbours); with ``block`` (the shard's normalised rows), also each best
    place's own difference (``"at_best"``, for the current frame's term of the
    confidence)."""
    coded = codes[0]
    rows, w = coded.shape
    d = np.concatenate([*left, coded, *right], axis=1) if left or right else coded
    ext_lo = lo - sum(h.shape[1] for h in left)
    shape = (rows - skip, velocities.shape[0], windows.shape[0])
    k_count = min(radius + 1, w)
    out = {name: np.zeros(shape, dtype=np.int64)
           for name in ("low", "place", "total", "high_sq", "low_sq", "outside", "prev_sum")}
    out["prev_here"] = np.zeros(shape, dtype=np.bool_)
    out["pre"] = np.empty((*shape, k_count), dtype=np.int64)
    out["suf"] = np.empty((*shape, k_count), dtype=np.int64)
    out["sub"] = np.empty((*shape, windows.shape[0] if want_sub else 0), dtype=np.int64)
    sums = np.empty((shape[1], shape[0] if want_sums else 0, w if want_sums else 0), dtype=np.int64)
    for vi in range(shape[1]):
        _line_pass(d, ext_lo, n, lo, w, first_row, skip, windows, float(velocities[vi]), mean_codes, vi, radius,
                   sums[vi], out["low"], out["place"], out["total"], out["high_sq"], out["low_sq"], out["outside"],
                   out["pre"], out["suf"], out["prev_sum"], out["prev_here"], out["sub"])
    if want_sums:
        out["sums"] = sums
    if block is not None:
        rows_out = np.arange(skip, rows)[:, None, None]
        out["at_best"] = block[rows_out, out["place"] - lo]
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


#: Seconds :func:`shard_reference` waits for a first worker where the cluster has none (one
#: still starting, or whose workers are reconnecting after a busy spell)
WORKER_WAIT_S = 30.0


def _worker_addresses(client) -> list[str]:
    """The cluster's worker addresses, sorted; where it has none yet, waits up to
    :data:`WORKER_WAIT_S` seconds for one before refusing."""
    addresses = sorted(client.scheduler_info().get("workers", {}))
    if addresses:
        return addresses
    try:
        client.wait_for_workers(1, timeout=WORKER_WAIT_S)
        addresses = sorted(client.scheduler_info().get("workers", {}))
    except TimeoutError:
        pass
    if not addresses:
        raise InvalidParameterError(f"the Dask cluster has no workers (none joined in {WORKER_WAIT_S:g} s); start "
                                    "some before sharding a reference.")
    return addresses


def shard_reference(descriptors, metric: str, scheduler, shard_places: int | None = None,
                    layout: str = "float32") -> ShardedReference:
    """Cut a reference into shards and prepare each on a worker.

    Parameters
    ----------
    descriptors : array_like, shape (N, d)
        Reference descriptors (after the front-end). For a map larger than this
        machine, pass a memory-mapped array (``numpy.load(..., mmap_mode="r")``) or a
        map file's descriptors left in the file
        (``catgraph.io.load_map(path, descriptors="stream").descriptors``): each shard
        is read and sent on its own.
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
    ref = descriptors if isinstance(descriptors, (np.memmap, RowSource)) else np.asarray(descriptors)
    if ref.ndim != 2 or ref.shape[0] == 0:
        raise InvalidParameterError(f"reference descriptors must have shape (N, d) with N ≥ 1; got {ref.shape}.")
    n = ref.shape[0]
    addresses = _worker_addresses(client)
    if shard_places is None:
        shard_places = -(-n // len(addresses))
    check_scalar(shard_places, "shard_places", "shard_reference", int, 1)
    shard_places = -(-int(shard_places) // SUM_CHUNK) * SUM_CHUNK
    bounds = [(lo, min(n, lo + shard_places)) for lo in range(0, n, shard_places)]
    workers, shards = [], []
    piece_rows = max(1, SHARD_PIECE_BYTES // (ref.shape[1] * ref.dtype.itemsize))
    for s, (lo, hi) in enumerate(bounds):
        where = addresses[s % len(addresses)]
        pin = {"workers": [where], "allow_other_workers": False, "pure": False}
        if hi - lo <= piece_rows:
            block = client.scatter(np.ascontiguousarray(ref[lo:hi]), workers=[where], direct=False, hash=False)
        else:  # in pieces, each written into the shard's rows on its worker as it arrives
            block = _send_in_pieces(client, ref, lo, hi, piece_rows, pin)
        shards.append(client.submit(_prepare_shard, block, metric, layout, scale, **pin))
        workers.append(where)
    dim = ref.shape[1] * (8 if metric == "hamming" and ref.dtype == np.uint8 else 1)
    return ShardedReference(client, shards, bounds, metric, n, int(dim), workers, layout, scale)


# ---------------------------------------------------------------------------------------
# blocks of query rows


def _normalised_blocks(ref: ShardedReference, q: np.ndarray, normalise: bool, blank: np.ndarray | None = None,
                       hubs: list | None = None, flat: np.ndarray | None = None) -> list:
    """Futures of each shard's (normalised) columns for query rows ``q``; rows where
    ``blank`` is true become zeros (a frame with no information, as locally); with
    ``hubs`` (each shard's hub offsets, :func:`_hub_futures`), hub-corrected. ``flat``
    (bool, one per row of ``q``; normalised rows only) is set to the rows that come out as
    zeros (no spread, or blank): those local matching gives no output."""
    c = ref.client
    # every scatter under a key of its own (hash=False): the same rows scattered again while the
    # scheduler still releases their last copy, under the same content key, race there
    q_fut = c.scatter(q, broadcast=True, direct=False, hash=False)
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
    if flat is not None:
        flat[:] = std == 0.0
    scaled = [ref.submit(s, _scale, b, mean, std) for s, b in enumerate(raw)]
    if hubs is None:
        return scaled
    # the hub correction (catgraph.hubs.apply_hub_offsets): the offsets subtracted, each row
    # normalised again with its numpy mean and std (two rounds, numpy's summation order);
    # a row of zeros (no spread, or no information) is left as it is
    flat = std == 0.0
    shifted = [ref.submit(s, _subtract, b, o, flat) for s, (b, o) in enumerate(zip(scaled, hubs))]
    mean, std = _row_moments(ref, shifted)
    return [ref.submit(s, _renormalise, b, mean, std) for s, b in enumerate(shifted)]


def _subtract(block: np.ndarray, offsets: np.ndarray, flat: np.ndarray) -> np.ndarray:
    out = block - offsets
    out[flat] = block[flat]
    return out


def _renormalise(block: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """:func:`catgraph.hubs.apply_hub_offsets`'s second normalisation, element by element."""
    out = block - mean[:, None]
    return np.divide(out, np.where(std > 0, std, 1.0)[:, None], out=out)


def _hub_futures(ref: ShardedReference, hub_offsets, owner: str) -> list | None:
    """Each shard's hub offsets, on its worker (``None``: no correction)."""
    if hub_offsets is None:
        return None
    offsets = np.asarray(hub_offsets, dtype=np.float64)
    if offsets.shape != (ref.n_places,):
        raise InvalidParameterError(f"The 'hub_offsets' parameter of {owner} must have one offset per reference "
                                    f"place ({ref.n_places}); got shape {offsets.shape}. Compute them from the "
                                    "same map (catgraph.hubs.map_hub_offsets).")
    return [ref.client.scatter(np.ascontiguousarray(offsets[lo:hi]), workers=[ref.workers[s]], direct=False,
                               hash=False)
            for s, (lo, hi) in enumerate(ref.bounds)]


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


def map_hub_offsets(ref: ShardedReference, descriptors, normalise: bool = True, threshold: float = HUB_THRESHOLD,
                    max_rows: int = HUB_ROWS) -> np.ndarray:
    """:func:`catgraph.hubs.map_hub_offsets` computed where the shards live.

    The same sampled map frames (:func:`catgraph.hubs.hub_sample`) are sent to every
    worker as queries; each worker adds its shard's fixed-chunk partial sums of their
    differences (two rounds: the rows' means, then their spreads, as in
    :func:`difference_matrix`) and then the median of each of its places' normalised
    differences to them (:func:`catgraph.hubs.typical_columns`), a column block at a
    time; only the sums and ``N`` medians travel. The client reads the sampled frames
    alone (``descriptors[rows]``; a map file's descriptors left in the file,
    :class:`catgraph.io.StoredDescriptors`, in one pass without holding them whole).
    With float32 shards the offsets equal :func:`catgraph.hubs.map_hub_offsets` of the
    map bit for bit; with ``uint8`` shards, :func:`catgraph.live.reference_hub_offsets`
    of the compact reference (tested).

    Parameters
    ----------
    ref : ShardedReference
        The map's shards (:func:`shard_reference`).
    descriptors : array_like or RowSource, shape (N, d)
        The descriptors the shards were cut from.
    normalise : bool
        The map's per-query normalisation.
    threshold, max_rows
        As in :func:`catgraph.hubs.map_hub_offsets`.

    Returns
    -------
    ndarray of float64, shape (N,)
    """
    from .differences import _column_block, take_rows
    from .hubs import _outlying, hub_sample

    check_scalar(threshold, "threshold", "map_hub_offsets", float, 0.0)
    if len(descriptors) != ref.n_places:
        raise InvalidParameterError(f"the descriptors hold {len(descriptors)} places but the shards {ref.n_places}; "
                                    "give the descriptors the shards were cut from.")
    n = ref.n_places
    if n < 3:  # as catgraph.hubs.map_hub_offsets
        return np.zeros(n)
    rows = hub_sample(n, max_rows)
    q = ref.prepare_query(take_rows(descriptors, rows))
    block_places = _column_block(q.shape[0], None, "map_hub_offsets")
    c = ref.client
    q_fut = c.scatter(q, broadcast=True, direct=False, hash=False)
    mean = std = None
    if normalise:
        parts = c.gather([ref.submit(s, _sample_sums, shard, q_fut, block_places, None)
                          for s, shard in enumerate(ref.shards)])
        mean = _combine(np.concatenate(parts, axis=1)) / n
        parts = c.gather([ref.submit(s, _sample_sums, shard, q_fut, block_places, mean)
                          for s, shard in enumerate(ref.shards)])
        std = np.sqrt(_combine(np.concatenate(parts, axis=1)) / n)
        std[_zero_spread(std, mean)] = 0.0
    typical = c.gather([ref.submit(s, _sample_typical, shard, q_fut, rows, lo, block_places, mean, std)
                        for s, (shard, (lo, _)) in enumerate(zip(ref.shards, ref.bounds))])
    return _outlying(np.concatenate(typical), threshold)


def _sample_sums(shard: PreparedReference, q: np.ndarray, block_places: int, centre) -> np.ndarray:
    from .differences import _column_chunk_sums

    return _column_chunk_sums(shard, q, block_places, centre)


def _sample_typical(shard: PreparedReference, q: np.ndarray, rows: np.ndarray, lo: int, block_places: int,
                    mean, std) -> np.ndarray:
    """Each of the shard's places' typical difference to the sampled map frames ``rows``."""
    from .differences import _scaled_columns
    from .hubs import typical_columns

    out = np.empty(shard.n_places)
    for a, block in _scaled_columns(shard, q, block_places, mean, std):
        out[a : a + block.shape[1]] = typical_columns(block, rows, lo + a)
    return out


def _quantum(ref: ShardedReference, blocks: list) -> float | None:
    """The local matcher's quantum (:func:`catgraph._sequence_kernels.unit_of`) from the
    first row of ``blocks`` that is not all zeros: each row's largest ``|d_j|`` of every
    shard, reduced here. ``None`` where every row is zeros (blank frames, normalised):
    the next block fixes it, as the local matcher's first such row does."""
    peaks = np.max(ref.client.gather([ref.submit(s, _row_peaks, b) for s, b in enumerate(blocks)]), axis=0)
    nonzero = np.flatnonzero(peaks > 0)
    return float(unit_of(np.array([peaks[nonzero[0]]]))) if len(nonzero) else None

def _halo(velocities: np.ndarray, first: int, stop: int, window: int) -> tuple[int, int]:
    """Columns a shard needs left and right of its places for query frames ``first …
    stop - 1`` and windows up to ``window``: the largest ``pos_v(i) - pos_v(i - L)`` over
    the rows and the forward (left) and backward (right) velocities, from the kernels'
    own ``pos_v`` arithmetic (``pos_v`` is monotone, so no earlier term of a window, and
    no shorter window, reaches further)."""
    i = np.arange(first, stop, dtype=np.float64)
    left = right = 0
    for v in velocities:
        reach = np.floor(v * i + 0.5) - np.floor(v * (i - window) + 0.5)
        if reach.size:
            left, right = max(left, int(reach.max())), max(right, int(-reach.min()))
    return left, right


def _line_blocks(ref: ShardedReference, q: np.ndarray, start: int, stop: int, windows: np.ndarray,
                 velocities: np.ndarray, unit: float | None, radius: int, want_sums: bool = False,
                 blank: np.ndarray | None = None, want_sub: bool = False,
                 keep_rows: bool = False, hubs: list | None = None,
                 at_best: bool | None = None, back: int = 0,
                 flat: np.ndarray | None = None) -> tuple[list, float, list | None]:
    """Futures of each shard's window sums and summaries (:func:`_shard_lines`) for query
    rows ``[start, stop)``, every velocity and every length in ``windows``; the quantum
    (fixed by the first block when ``unit`` is ``None``); with ``keep_rows``, the futures
    of the shards' normalised rows (else ``None``); with ``at_best`` (default: ``keep_rows``),
    each shard's row values at its best places come back with the summaries; with ``back``,
    the kept rows begin up to ``back`` frames before ``start`` (the latest rows the confidence
    "changepoint" reads), as ``(rows, earlier)``: the rows from ``start`` and those from
    ``start - min(back, start)``; ``flat`` (bool, one per row ``[start, stop)``) is set to the
    rows that are zeros once normalised (:func:`_normalised_blocks`)."""
    c = ref.client
    at_best = keep_rows if at_best is None else at_best
    longest = int(windows[-1])
    first = max(0, start - max(longest, back))
    zeros = None if flat is None else np.zeros(stop - first, dtype=bool)
    blocks = _normalised_blocks(ref, q[first:stop], True, None if blank is None else blank[first:stop], hubs,
                                zeros)
    if flat is not None:
        flat[:] = zeros[start - first:]
    if unit is None:  # the first block starts at query frame 0 (or every row before it was zeros)
        unit = _quantum(ref, blocks)
    # rows of zeros only so far: codes 0 in any quantum (1 stands in; the scores are 0)
    coded = [ref.submit(s, _codes, b, 1.0 if unit is None else unit) for s, b in enumerate(blocks)]
    # each row's mean code (the fill outside the reference), as the local ring rounds it
    totals = np.sum(c.gather([ref.submit(s, _totals, b) for s, b in enumerate(coded)]), axis=0)
    mean_codes = np.rint(totals / ref.n_places).astype(np.int64)
    reach_left, reach_right = _halo(velocities, first, stop, longest)
    out = []
    for s, (lo, hi) in enumerate(ref.bounds):
        # the code columns [lo - reach_left, lo) and [hi, hi + reach_right) on the map, from
        # whichever shards hold them: 2 bytes per column and query row
        parts = []
        for a, b in ((max(0, lo - reach_left), lo), (hi, min(ref.n_places, hi + reach_right))):
            parts.append([ref.submit(t, _columns, coded[t], max(a, t_lo) - t_lo, min(b, t_hi) - t_lo)
                          for t, (t_lo, t_hi) in enumerate(ref.bounds) if t_lo < b and a < t_hi])
        out.append(ref.submit(s, _shard_lines, coded[s], parts[0], parts[1], first, start - first, windows,
                              velocities, mean_codes, lo, ref.n_places, radius, want_sums, want_sub,
                              blocks[s] if at_best else None))
    rows = [ref.submit(s, _rows_from, b, start - first) for s, b in enumerate(blocks)] if keep_rows else None
    if keep_rows and back:
        earlier = min(back, start)
        rows = (rows, [ref.submit(s, _rows_from, b, start - first - earlier) for s, b in enumerate(blocks)])
    return out, unit, rows


def _rows_from(block: np.ndarray, skip: int) -> np.ndarray:
    return block[skip:]


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
        futs, unit, _ = _line_blocks(ref, q, start, stop, np.array([window]), velocities, unit, 0, want_sums=True)
        eff = _effective(start, stop, window)[:, None]
        for (lo, hi), block in zip(ref.bounds, ref.client.gather([ref.submit(s, _sums_only, f)
                                                                  for s, f in enumerate(futs)])):
            out[start:stop, lo:hi] = block[0].astype(np.float64) * (unit or 0.0) / eff
    return out


@dataclass(frozen=True)
class ShardedMatches:
    """Per-frame results of :func:`match_fixed_window` and :func:`match_adaptive_window`
    (processing order), as :class:`catgraph.sequence.SequenceResult` has them.

    Attributes
    ----------
    match : ndarray of int, shape (n_query,)
    score, confidence : ndarray of float, shape (n_query,)
    velocity : ndarray of float, shape (n_query,)
        The velocity chosen per frame.
    window_length : ndarray of int, shape (n_query,)
        The effective window length per frame.
    """

    match: np.ndarray
    score: np.ndarray
    confidence: np.ndarray
    velocity: np.ndarray | None = None
    window_length: np.ndarray | None = None


def _second_best(parts: list, bounds: list, best_j: np.ndarray, radius: int) -> np.ndarray:
    """The smallest sum more than ``radius`` places from the global best ``best_j``
    (``(rows, V, G)``), from each shard's summaries, exactly: a shard that holds the best
    gives its own minimum outside the best's neighbourhood; one that the neighbourhood
    does not reach gives its minimum; one whose first (last) places it covers gives the
    minimum of the rest (``pre``, ``suf``); one it covers whole gives nothing."""
    second = np.full(best_j.shape, _NONE, dtype=np.int64)
    for part, (lo, hi) in zip(parts, bounds):
        za, zb = np.maximum(best_j - radius, lo), np.minimum(best_j + radius, hi - 1)
        k_count = part["pre"].shape[-1]
        head = np.take_along_axis(part["pre"], np.clip(zb + 1 - lo, 0, k_count - 1)[..., None], axis=-1)[..., 0]
        tail = np.take_along_axis(part["suf"], np.clip(hi - za, 0, k_count - 1)[..., None], axis=-1)[..., 0]
        value = np.select([za > zb, (best_j >= lo) & (best_j < hi), (za <= lo) & (zb >= hi - 1), za <= lo],
                          [part["low"], part["outside"], _NONE, head], tail)
        second = np.minimum(second, value)
    return second


def _moments(parts: list, n: int, unit: float, eff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's, velocity's and length's score mean and spread, as the local kernel
    computes them (:func:`catgraph._sequence_kernels._window`): ``y = S - shift`` with
    ``shift`` the previous row's sum at place ``(pos_v(i-1) - pos_v(i)) mod N`` (0 at
    frame 0), ``E[y] = sum(y) / N``, ``var = sum(y^2) / N - E[y]^2``, mean ``(shift +
    E[y]) u / L_eff`` and spread ``sqrt(var) u / L_eff`` (``eff``: ``L_eff``, broadcast
    against ``(rows, V, G)``).

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
    mean = (shift.astype(np.float64) + my) * unit / eff
    with np.errstate(invalid="ignore"):
        std = np.where(var > 0.0, np.sqrt(np.where(var > 0.0, var, 0.0)) * unit / eff, 0.0)
    return mean, std


# ---------------------------------------------------------------------------------------
# the current frame's mean and spread, as numpy computes them

#: numpy sums a contiguous float64 row pairwise: halves (cut at a multiple of 8) down to
#: blocks of at most this many values, each added with eight interleaved accumulators
_PAIRWISE_BLOCK = 128


def _pairwise_plan(n: int, bounds: list) -> tuple[Any, list, list]:
    """numpy's pairwise summation tree of a row of ``n`` values, cut at the shards: the
    tree, per shard the ``(a, b)`` column ranges of its whole subtrees, per shard the
    column ranges of its part of each block that straddles a shard edge.

    Every subtree that lies in one shard is summed there by numpy itself (the same
    recursion on the same values: the same float64 result); a block of at most
    :data:`_PAIRWISE_BLOCK` values across an edge is gathered and summed here; the
    client adds the subtrees' sums along the tree, in numpy's order.
    """
    los = [lo for lo, _ in bounds]
    whole: list[list] = [[] for _ in bounds]
    pieces: list[list] = [[] for _ in bounds]

    def build(a: int, m: int):
        s = int(np.searchsorted(los, a, side="right")) - 1
        lo, hi = bounds[s]
        if a + m <= hi:
            whole[s].append((a - lo, a + m - lo))
            return ("whole", s, len(whole[s]) - 1)
        if m <= _PAIRWISE_BLOCK:
            refs = []
            for t, (t_lo, t_hi) in enumerate(bounds):
                if t_lo < a + m and a < t_hi:
                    pieces[t].append((max(a, t_lo) - t_lo, min(a + m, t_hi) - t_lo))
                    refs.append((t, len(pieces[t]) - 1))
            return ("block", refs)
        half = m // 2
        half -= half % 8
        return ("pair", build(a, half), build(a + half, m - half))

    return build(0, n), whole, pieces


def _pairwise_parts(rows: np.ndarray, whole: list, pieces: list, centre: np.ndarray | None) -> tuple[list, list]:
    """A shard's sums of its whole subtrees and its parts of the straddling blocks, of
    the rows (``centre is None``) or of their squared deviations from ``centre``, formed
    as :meth:`numpy.ndarray.std` forms them (``x = row - mean; x = x * x``)."""
    x = rows
    if centre is not None:
        x = rows - centre[:, None]
        x = np.multiply(x, x, out=x)
    return [x[:, a:b].sum(axis=1) for a, b in whole], [np.ascontiguousarray(x[:, a:b]) for a, b in pieces]


def _pairwise_sum(tree, sums: list, parts: list) -> np.ndarray:
    kind = tree[0]
    if kind == "whole":
        return sums[tree[1]][0][tree[2]]
    if kind == "block":
        return np.concatenate([parts[t][1][k] for t, k in tree[1]], axis=1).sum(axis=1)
    return _pairwise_sum(tree[1], sums, parts) + _pairwise_sum(tree[2], sums, parts)


def _parts_and_values(rows: np.ndarray, whole: list, pieces: list, at_row: np.ndarray,
                      at_col: np.ndarray) -> tuple[list, list, np.ndarray]:
    """:func:`_pairwise_parts` of the rows, and the rows' values at the (row, shard column)
    pairs ``at_row``, ``at_col`` (the places a window rule reads, served in the same round)."""
    sums, parts = _pairwise_parts(rows, whole, pieces, None)
    return sums, parts, rows[at_row, at_col]


def _row_moments(ref: ShardedReference, rows: list, asks: np.ndarray | None = None):
    """Each row's ``row.mean()`` and ``row.std()`` as numpy computes them on the whole
    row (two rounds: the sums, then the squared deviations from the mean).

    With ``asks`` (``(rows, k)`` places, ``-1`` for none), also each row's values at those
    places, read in the first round by the shard that holds each place (``(rows, k)``;
    ``nan`` where none was asked): the lookups of rule "predictive", at no extra round.
    """
    tree, whole, pieces = _pairwise_plan(ref.n_places, ref.bounds)
    c = ref.client
    if asks is None:
        parts = c.gather([ref.submit(s, _pairwise_parts, r, whole[s], pieces[s], None) for s, r in enumerate(rows)])
    else:
        futs, where = [], []
        for s, r in enumerate(rows):
            lo, hi = ref.bounds[s]
            at_row, at_k = np.nonzero((asks >= lo) & (asks < hi))
            where.append((at_row, at_k))
            futs.append(ref.submit(s, _parts_and_values, r, whole[s], pieces[s], at_row.astype(np.int32),
                                   (asks[at_row, at_k] - lo).astype(np.int32)))
        parts = c.gather(futs)
        looked = np.full(asks.shape, np.nan)
        for (at_row, at_k), part in zip(where, parts):
            looked[at_row, at_k] = part[2]
    mean = _pairwise_sum(tree, parts, parts) / ref.n_places
    parts2 = c.gather([ref.submit(s, _pairwise_parts, r, whole[s], pieces[s], mean) for s, r in enumerate(rows)])
    std = np.sqrt(_pairwise_sum(tree, parts2, parts2) / ref.n_places)
    return (mean, std) if asks is None else (mean, std, looked)


class _Row:
    """One difference row as the window rule reads it (:func:`catgraph._window_rule._current_z`,
    :meth:`catgraph._window_rule._Record.loss`): its width, its mean, its spread and its
    values at the places served for it."""

    def __init__(self, mean: np.float64, std: np.float64, values: dict, n: int = 0):
        self._mean, self._std, self._values = mean, std, values
        self.shape = (n,)

    def mean(self) -> np.float64:
        return self._mean

    def std(self) -> np.float64:
        return self._std

    def __getitem__(self, place):
        if np.ndim(place) == 0:
            return self._values[int(place)]
        places = np.asarray(place)
        return np.array([self._values[int(j)] for j in places.ravel()], dtype=np.float64).reshape(places.shape)


class _Rows:
    """The block of difference rows the window rule is handed: their shape, and each row
    as a :class:`_Row` (the rows themselves stay on the shards). ``places`` and
    ``values`` (each ``(rows, ...)``) are the values served for each row; a place below
    0 marks an unused slot. Without ``mean`` nothing is served: each row's mean and
    spread are ``nan`` (the rule then reads only the rows' width, and rule "spanning"
    hands each row to the replayed clock, which does not read it)."""

    def __init__(self, n: int, mean=None, std=None, places=None, values=None, rows: int = 0, lines=None):
        self.shape = (rows if mean is None else mean.shape[0], n)
        self._mean, self._std, self._places, self._values = mean, std, places, values
        self._lines = lines
        if lines is not None:
            self.line_values = self._line_values

    def _line_values(self, rel: np.ndarray, places: np.ndarray) -> np.ndarray:
        """Confidence "changepoint": the rows' values at ``places`` of the frames ``rel``
        (block rows; negative: the frames before the block), those already served for the
        current frame (its best places) from here, the others in one round from the shards
        that hold them (:class:`_Lines`)."""
        out = np.empty(rel.shape[0])
        known = np.zeros(rel.shape[0], dtype=bool)
        for k in np.flatnonzero(rel >= 0):
            row = self._places[rel[k]].ravel()
            hit = np.flatnonzero(row == places[k])
            if hit.size:
                out[k], known[k] = self._values[rel[k]].ravel()[hit[0]], True
        ask = ~known
        out[ask] = self._lines.serve(rel[ask], places[ask])
        return out

    def __getitem__(self, t: int) -> _Row:
        if self._mean is None:  # nothing served: only the replayed clock is handed the row, and ignores it
            return _Row(np.float64(np.nan), np.float64(np.nan), {}, self.shape[1])
        places, values = self._places[t].ravel(), self._values[t].ravel()
        used = places >= 0
        return _Row(self._mean[t], self._std[t], dict(zip(places[used].tolist(), values[used])), self.shape[1])


def _values_at(rows: np.ndarray, at_row: np.ndarray, at_col: np.ndarray) -> np.ndarray:
    return rows[at_row, at_col]


class _Lines:
    """Confidence "changepoint" on the cluster: the rows' values along the chosen lines.

    ``earlier`` are the futures of each shard's normalised rows from ``back`` frames before
    the block (the block carries ``l_max`` earlier rows anyway: the same values a local run
    keeps). :meth:`serve` sends each shard the (row, column) pairs it holds, in one round,
    and counts the round and the pairs (``16`` bytes each: an int32 row and column out, a
    float64 back)."""

    def __init__(self, ref: ShardedReference, earlier: list, back: int):
        self.ref, self.earlier, self.back = ref, earlier, back
        self.rounds, self.pairs = 0, 0

    def serve(self, rel: np.ndarray, places: np.ndarray) -> np.ndarray:
        out = np.empty(rel.shape[0])
        if not rel.shape[0]:
            return out
        futs, where = [], []
        for s, (lo, hi) in enumerate(self.ref.bounds):
            here = np.flatnonzero((places >= lo) & (places < hi))
            if here.size:
                where.append(here)
                futs.append(self.ref.submit(s, _values_at, self.earlier[s], (rel[here] + self.back).astype(np.int32),
                                            (places[here] - lo).astype(np.int32)))
        for here, got in zip(where, self.ref.client.gather(futs)):
            out[here] = got
        self.rounds += 1
        self.pairs += rel.shape[0]
        return out


def _predicted_places(st: _Stats, cfg, record: _Record, start: int, n: int,
                      horizons: np.ndarray | None = None) -> np.ndarray:
    """``(rows, G)``: for every frame of the block, the places the record rules read in
    its row (:meth:`catgraph._window_rule._Record.loss`: each length's line of frame
    ``i - K`` carried on to frame ``i``, place 0 where it has left the reference), ``-1``
    for frames before ``K``. ``K`` is the record's constant horizon (rule "predictive"),
    or each frame's in ``horizons`` (rule "decorrelated"). The lines are those
    :func:`catgraph._window_rule._decide` will remember: each length's best place at the
    frame's velocity, which the window statistics fix before the rule runs; lines of
    frames before the block come from the record as the previous block left it (it
    holds the last ``K`` frames, or :data:`catgraph._window_rule.HORIZON_MAX`)."""
    rows, _, g_count = st.best_j.shape
    v = np.argmin(_log_p(st).sum(axis=2), axis=1)  # _decide's velocity
    out = np.full((rows, g_count), -1, dtype=np.int64)
    for t in range(rows):
        i = start + t
        k = record.horizon if horizons is None else int(horizons[t])
        if i < k:
            continue
        s = i - k
        if s >= start:
            velocity = float(cfg.velocities[v[s - start]])
            offsets = st.best_j[s - start, v[s - start]] - _position(velocity, s)
        else:
            slot = s % record.offsets.shape[0]
            velocity, offsets = record.velocity[slot], record.offsets[slot]
        places = offsets + _position(velocity, i)
        out[t] = np.where((places >= 0) & (places < n), places, 0)
    return out


#: rule "decorrelated": query rows per horizon task (bounds the gathered rows' memory on
#: the worker that keeps the horizon to ``HORIZON_ROWS × N`` float64)
HORIZON_ROWS = 64


def _row_slice(block: np.ndarray, a: int, b: int) -> np.ndarray:
    return block[a:b]


def _horizon_steps(state, first_frame: int, *parts: np.ndarray) -> tuple:
    """Rule "decorrelated" on the worker that keeps its horizon: the whole rows of frames
    ``first_frame …`` put together from the shards' columns (the same float64 values, one
    contiguous row each, as locally), each read by the local
    :meth:`catgraph._window_rule._Horizon.update` with the row's own ``std()``, as
    :meth:`catgraph._window_rule._Record.loss` calls it. ``state``: the horizon as the
    previous task left it (or a fresh one), copied, never changed. Returns the horizon
    after these frames, each frame's ``K`` and (rule "punctuated", a
    :class:`catgraph._window_rule._Breaks` clock) each frame's frames since the latest
    break of the rows, ``None`` otherwise."""
    import copy

    clock = copy.deepcopy(state[0] if isinstance(state, tuple) else state)
    rows = np.concatenate(parts, axis=1) if len(parts) > 1 else np.ascontiguousarray(parts[0])
    ks = np.empty(rows.shape[0], dtype=np.int64)
    since = np.empty(rows.shape[0], dtype=np.int64) if hasattr(clock, "since") else None
    for r in range(rows.shape[0]):
        row = rows[r]
        ks[r] = clock.update(row, first_frame + r, row.std())
        if since is not None:
            since[r] = clock.since
    return clock, ks, since


def _horizons_of(state: tuple) -> tuple:
    return state[1], state[2]


class _Replayed:
    """The record's clock on the client (rules "decorrelated" and "spanning"): the
    horizons the worker computed from the whole rows, handed to
    :meth:`catgraph._window_rule._Record.loss` (or, rule "spanning",
    :func:`catgraph._window_rule._horizons`) frame by frame; the row and spread it is
    handed are not read. Rule "punctuated" also reads, after each update, the frames since
    the latest break of the rows (:attr:`since`), computed on the same worker."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.start, self.ks, self.breaks = 0, np.empty(0, dtype=np.int64), None
        self.since = None

    def update(self, row, i: int, spread, centre=None) -> int:
        if self.breaks is not None:
            self.since = int(self.breaks[i - self.start])
        return int(self.ks[i - self.start])


# ---------------------------------------------------------------------------------------
# matching


def _match(query, ref: ShardedReference, cfg, block_rows: int, no_information, owner: str,
           hub_offsets=None) -> ShardedMatches:
    """Match every query frame with the window rule of ``cfg`` (:func:`catgraph.sequence._config`)."""
    check_scalar(block_rows, "block_rows", owner, int, 1)
    c = ref.client
    q = ref.prepare_query(query)
    n_q, n = q.shape[0], ref.n_places
    blank = None
    if no_information is not None:
        blank = np.asarray(no_information, dtype=bool)
        if blank.shape != (n_q,):
            raise InvalidParameterError(f"no_information must have one flag per query frame ({n_q}); got shape "
                                        f"{blank.shape}.")
    hubs = _hub_futures(ref, hub_offsets, owner)
    with_sub = _needs_sub(cfg)
    # the current frame's term of the confidence ("posterior", "support" with an adaptive window)
    current = not cfg.fixed and cfg.confidence in WEIGHED_CONFIDENCES
    # confidence "changepoint": the latest rows along the chosen line, served after the rule
    # has chosen it (one more round per block)
    back = CHANGE_POINT_FRAMES - 1 if current and cfg.confidence == "changepoint" else 0
    # rules "predictive" and "decorrelated": a record carried from block to block, and G
    # lookups per row; rule "spanning" reads only the record's clock (no lookups)
    record = _new_record(cfg)
    lookups = record is not None and cfg.rule in RECORD_RULES
    clock = replay = None
    if record is not None and record.clock is not None:  # the rules of a horizon ("decorrelated", HORIZON_RULES)
        clock, replay = record.clock, _Replayed(record.clock.capacity)
        record.clock = replay
    windows = cfg.grid
    match, score, conf = np.empty(n_q, dtype=np.int64), np.empty(n_q), np.empty(n_q)
    velocity, length = np.empty(n_q), np.empty(n_q, dtype=np.int64)
    unit = None
    for start in range(0, n_q, block_rows):
        stop = min(n_q, start + block_rows)
        flat = np.zeros(stop - start, dtype=bool)
        futs, unit, rows = _line_blocks(ref, q, start, stop, windows, cfg.velocities, unit, cfg.radius, blank=blank,
                                        want_sub=with_sub, keep_rows=current or record is not None, hubs=hubs,
                                        at_best=current, back=back, flat=flat)
        lines = None
        if back:
            rows, earlier = rows
            lines = _Lines(ref, earlier, min(back, start))
        summaries = [ref.submit(s, _summaries_only, f) for s, f in enumerate(futs)]
        if clock is not None:  # chained on one worker, gathered with the summaries
            ends = []
            for a in range(0, stop - start, HORIZON_ROWS):
                b = min(stop - start, a + HORIZON_ROWS)
                slices = [ref.submit(s, _row_slice, r, a, b) for s, r in enumerate(rows)]
                clock = ref.submit(0, _horizon_steps, clock, start + a, *slices)
                ends.append(ref.submit(0, _horizons_of, clock))
            got = c.gather(summaries + ends)
            parts = got[:len(summaries)]
            chunks = got[len(summaries):]
            replay.start, replay.ks = start, np.concatenate([k for k, _ in chunks])
            replay.breaks = None if chunks[0][1] is None else np.concatenate([b for _, b in chunks])
        else:
            parts = c.gather(summaries)
        values = np.stack([p["low"] for p in parts])
        pick = np.argmin(values, axis=0)[None]  # the first shard holding the minimum: the lowest place, as locally
        best = np.take_along_axis(values, pick, axis=0)[0]
        best_j = np.take_along_axis(np.stack([p["place"] for p in parts]), pick, axis=0)[0]
        second = _second_best(parts, ref.bounds, best_j, cfg.radius)
        eff = np.minimum(windows[None, None, :], np.arange(start + 1, stop + 1)[:, None, None])  # (rows, 1, G)
        quantum = unit or 0.0  # (rows of zeros only so far: every score 0, as the local matcher's)
        mean, std = _moments(parts, n, quantum, eff)
        # the statistics the local kernel hands to the window rule (_sequence_kernels._window, _sub_scores)
        st = _Stats(stop - start, cfg.velocities.shape[0], windows.shape[0], 1, with_sub=with_sub)
        st.best_j[...] = best_j
        st.best_s[...] = best.astype(np.float64) * quantum / eff
        st.second_s[...] = np.where(second == _NONE, np.inf, second.astype(np.float64) * quantum / eff)
        st.mean[...], st.std[...] = mean, std
        st.weights[...] = 1.0
        st.locs[..., 0], st.scales[..., 0] = mean, std
        if with_sub:
            sub = np.take_along_axis(np.stack([p["sub"] for p in parts]), pick[..., None], axis=0)[0]
            st.sub[...] = sub.astype(np.float64) * quantum / eff[:, :, None, :]
        if current or lookups:
            places, values = np.empty((stop - start, 0), dtype=np.int64), np.empty((stop - start, 0))
            if lookups:  # the places the record reads, in the first moments round
                asks = _predicted_places(st, cfg, record, start, n, None if replay is None else replay.ks)
                row_mean, row_std, looked = _row_moments(ref, rows, asks)
                places, values = asks, looked
            else:
                row_mean, row_std = _row_moments(ref, rows)
            if current:
                at_best = np.take_along_axis(np.stack([p["at_best"] for p in parts]), pick, axis=0)[0]
                places = np.concatenate([best_j.reshape(stop - start, -1), places], axis=1)
                values = np.concatenate([at_best.reshape(stop - start, -1), values], axis=1)
            rows_d = _Rows(n, row_mean, row_std, places, values, lines=lines)
        else:  # the rule reads the rows' width only (and, rule "spanning", hands them to the replayed clock)
            rows_d = _Rows(n, rows=stop - start)
        m, s, k, w, v, _ = _decide(st, cfg, np.arange(start, stop), False, rows_d, record, blank=flat)
        match[start:stop], score[start:stop], conf[start:stop], length[start:stop], velocity[start:stop] = m, s, k, w, v
    return ShardedMatches(match, score, conf, velocity, length)


def match_fixed_window(query, ref: ShardedReference, window: int, radius: int = 10,
                       velocities=DEFAULT_VELOCITIES, confidence: str = DEFAULT_CONFIDENCE,
                       block_rows: int = 256, no_information: np.ndarray | None = None,
                       hub_offsets: np.ndarray | None = None) -> ShardedMatches:
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
    confidence : {"changepoint", "posterior", "support", "gap", "neglogp", "z"}
        As :func:`~catgraph.sequence.match_sequences` with a fixed window (the first four
        are then SeqSLAM's gap; default :data:`catgraph.sequence.DEFAULT_CONFIDENCE`).
    block_rows : int
        Query rows per round.
    no_information : ndarray of bool, shape (n_query,), optional
        Frames with no information (:func:`catgraph.frontends.check_information`):
        their normalised rows are zeros, as :func:`catgraph.io.query_differences`
        makes them.
    hub_offsets : ndarray, shape (N,), optional
        The map's hub offsets (:func:`catgraph.hubs.map_hub_offsets`): every row is
        corrected and normalised again as :func:`catgraph.hubs.apply_hub_offsets` does
        it (the row's numpy mean and std, reduced in numpy's order: two more rounds).
    """
    check_scalar(window, "window", "match_fixed_window", int, 1, SHARD_UNIT)
    cfg = _config("match_fixed_window", int(window), "gaussian", "unrivalled", confidence, 1, 1, 1, radius, 0.0,
                  velocities, None)
    return _match(query, ref, cfg, block_rows, no_information, "match_fixed_window", hub_offsets)


def check_cluster_rule(rule: str, owner: str) -> None:
    """Refuse a window rule the cluster does not reproduce exactly, naming the fix."""
    if rule == "tracked":
        raise InvalidParameterError(
            f"{owner}: rule 'tracked' (the local default) runs a grid filter over every place of the map beside the "
            f"matcher, which no shard holds; on the cluster choose rule {DEFAULT_LINE_RULE!r} (the default among the "
            "rules it reproduces exactly), or run match_sequences on one machine.")
    if rule not in EXACT_RULES:
        raise InvalidParameterError(
            f"The 'rule' parameter of {owner} must be one of {EXACT_RULES} (the rules the cluster reproduces "
            f"exactly). Got {rule!r} instead; run match_sequences on one machine for it.")


def match_adaptive_window(query, ref: ShardedReference, rule: str = DEFAULT_LINE_RULE,
                          confidence: str = DEFAULT_CONFIDENCE,
                          l_min: int = 5, l_max: int = 500, grid=DEFAULT_GRID, radius: int = 10,
                          recent_fraction: float = 0.05, velocities=DEFAULT_VELOCITIES,
                          approximation: str = "gaussian", block_rows: int = 512,
                          no_information: np.ndarray | None = None,
                          hub_offsets: np.ndarray | None = None) -> ShardedMatches:
    """Adaptive-window sequence matching on the cluster (paper 2; default rule
    :data:`catgraph.sequence.DEFAULT_LINE_RULE`, the local default "tracked" excepted).

    The answers of :func:`catgraph.sequence.match_sequences` with ``window="adaptive"``
    and the same parameters on the normalised difference matrix (Gaussian approximation,
    the default: the only one whose statistics are reductions over the places). For every
    frame, velocity and candidate length the shards return the summaries of
    :func:`match_fixed_window` and the sums of every length at their best place of each
    length (the sub-window scores the rules test); the client rebuilds the local kernel's
    statistics from them and hands them to the local window rule
    (:func:`catgraph._window_rule._decide`). The confidences "changepoint" (the default,
    :data:`catgraph.sequence.DEFAULT_CONFIDENCE`), "posterior" and "support" also read the
    current frame's mean and spread over the whole row, which the client reduces in numpy's
    own pairwise order from the shards' subtree sums (:func:`_row_moments`, two more rounds),
    and the frame's difference at the match; "changepoint" also the latest ``T - 1`` rows'
    values along the chosen line (one more round; module notes, step 9).
    Rules "predictive" and "decorrelated" read ``G`` more values of each row, served in
    the first of those rounds; "decorrelated" and "spanning" put each whole row together
    on one worker for its horizon (``8 N`` bytes per frame between workers, the horizon
    back with the summaries; module notes, steps 7 and 8).
    Matches, scores, velocities, window lengths and confidences are then identical, bit
    for bit, within the bound of :func:`match_fixed_window` (tested). The block carries
    ``l_max`` earlier rows, so ``block_rows`` well above ``l_max`` keeps that overhead
    small.

    Parameters
    ----------
    query : array_like, shape (n_query, d)
    ref : ShardedReference
    rule, confidence, l_min, l_max, grid, radius, recent_fraction, velocities, approximation
        As :func:`catgraph.sequence.match_sequences` (``rule`` one of
        :data:`EXACT_RULES`, every rule but "tracked"; ``l_max`` at most :data:`SHARD_UNIT`; ``approximation``
        "gaussian" only).
    block_rows : int
        Query rows per round.
    no_information, hub_offsets
        As :func:`match_fixed_window`.
    """
    owner = "match_adaptive_window"
    if approximation != "gaussian":
        raise InvalidParameterError(
            f"The 'approximation' parameter of {owner} must be 'gaussian' (the others need every score of a "
            f"window in one place). Got {approximation!r} instead; run match_sequences on one machine for it.")
    check_cluster_rule(rule, owner)
    check_scalar(l_max, "l_max", owner, int, 1, SHARD_UNIT)
    cfg = _config(owner, "adaptive", approximation, rule, confidence, l_min, l_max, grid, radius, recent_fraction,
                  velocities, None)
    return _match(query, ref, cfg, block_rows, no_information, owner, hub_offsets)
