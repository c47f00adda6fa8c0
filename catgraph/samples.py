"""Choosing the samples a histogram model learns from (paper 2 and its variants).

* :func:`online_samples`: the paper's online choice for one frame, ``d_min`` and the
  smallest difference not from the same location;
* :func:`labelled_samples`: from a labelled traverse (the "trained" baseline);
* :func:`reference_samples`: from a reference-vs-reference difference matrix.

From a saved map, by sampled pairs and never an N × N matrix, the ``¬L`` samples are
:func:`catgraph.live.map_bootstrap_samples`' and the hub levels
:func:`catgraph.hubs.map_hub_offsets`'.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError

__all__ = ["OnlineSamples", "online_samples", "labelled_samples", "reference_samples"]


@dataclass(frozen=True)
class OnlineSamples:
    """The paper's online choice of samples for one frame.

    Attributes
    ----------
    best : int
        Reference index of the smallest difference.
    d_min : float
        The smallest difference (to ``L`` after initialisation, else to ``¬L``).
    d_other : float
        Smallest difference outside ``best ± exclusion_radius`` (to ``¬L``); NaN when
        every place lies in that neighbourhood.
    d_random : tuple of float
        Differences to places drawn uniformly outside that neighbourhood (also to
        ``¬L``; empty unless the recogniser asks for them).
    """

    best: int
    d_min: float
    d_other: float
    d_random: tuple[float, ...] = ()


def online_samples(
    differences: np.ndarray, exclusion_radius: int, same_place: np.ndarray | None = None
) -> OnlineSamples:
    """``d_min`` and the smallest difference not from the same location, O(n_ref).

    Parameters
    ----------
    differences : ndarray, shape (n_ref,)
        One frame's difference to every reference place (trusted: finite, 1-D).
    exclusion_radius : int
        Reference indices ``best ± exclusion_radius`` count as the same location.
    same_place : ndarray of int, optional
        Indices of the places that count as the best match's location (e.g. every place
        within some metres of it); replaces ``exclusion_radius`` when given.
    """
    best = int(np.argmin(differences))
    if same_place is not None:
        rest = np.delete(differences, same_place)
        other = rest.min() if rest.size else math.nan
        return OnlineSamples(best, float(differences[best]), float(other))
    lo, hi = max(0, best - exclusion_radius), best + exclusion_radius + 1
    left, right = differences[:lo], differences[hi:]
    other = min(left.min() if left.size else np.inf, right.min() if right.size else np.inf)
    return OnlineSamples(best, float(differences[best]), float(other) if np.isfinite(other) else math.nan)


def labelled_samples(
    differences: Any,
    ground_truth: Any,
    query_index: Any = None,
    max_different: int | None = 100_000,
    seed: int | np.random.Generator | None = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Same- and different-place differences from a labelled traverse ("trained" mode).

    Parameters
    ----------
    differences : array_like, shape (n_query, n_reference), or DifferenceRows
        Difference matrix; column ``j`` is reference frame ``j`` as loaded. Or its rows
        block by block (:class:`~catgraph.differences.DifferenceRows`): the same samples,
        one block of rows in memory at a time.
    ground_truth : catgraph.traverse.GroundTruth
        Decides which ``(query, reference)`` pairs show the same place.
    query_index : array_like of int, shape (n_query,), optional
        Loaded index of each query row (``Traverse.index``); default ``arange(n_query)``.
    max_different : int or None
        Keep at most this many ``¬L`` samples, drawn without replacement with ``seed``
        (``None``: keep all).
    seed : int, Generator or None

    Returns
    -------
    d_same, d_different : ndarray, float64
        Pass to ``HistogramLikelihood.fit``. ``d_same`` in row order; ``d_different`` the
        draws in the order drawn (every different-place value in row order where all are kept).
    """
    from .differences import DifferenceRows

    if not isinstance(differences, DifferenceRows):
        differences = DifferenceRows.of(check_array(differences, "differences", ndim=2))
    n_query, n_ref = differences.shape
    q = np.arange(n_query) if query_index is None else np.asarray(query_index)
    if q.shape != (n_query,):
        raise ShapeMismatchError(f"query_index has shape {q.shape} but differences have {n_query} rows.")
    if max_different is not None:
        check_scalar(max_different, "max_different", "labelled_samples", int, 1)
    columns = np.arange(n_ref)
    # which pairs show the same place: from the ground truth alone, one row at a time
    same_rows = [np.flatnonzero(ground_truth.correct(np.full(n_ref, q[row], dtype=np.int64), columns))
                 for row in range(n_query)]
    n_different = n_query * n_ref - sum(len(cols) for cols in same_rows)
    picks = None  # positions in the row-order sequence of different-place values, as drawn
    if max_different is not None and n_different > max_different:
        picks = as_generator(seed).choice(n_different, size=max_different, replace=False)
        order = np.argsort(picks, kind="stable")
        wanted, d_diff = picks[order], np.empty(max_different)
    same_parts, diff_parts, seen, taken = [], [], 0, 0
    for start, block in differences.checked():
        mask = np.zeros(block.shape, dtype=bool)
        for k in range(len(block)):
            mask[k, same_rows[start + k]] = True
        same_parts.append(block[mask])
        values = block[~mask]
        if picks is None:
            diff_parts.append(values)
        else:  # the draws that fall in this block, gathered in position order
            stop = np.searchsorted(wanted, seen + len(values), side="left")
            d_diff[order[taken:stop]] = values[wanted[taken:stop] - seen]
            taken = stop
        seen += len(values)
    d_same = np.concatenate(same_parts) if same_parts else np.empty(0)
    if picks is None:
        d_diff = np.concatenate(diff_parts) if diff_parts else np.empty(0)
    return d_same, d_diff


def default_bootstrap_gap(n_places: int) -> int:
    """Places more than this many apart along the route count as different places where a
    bootstrap from the map leaves ``gap`` unset: 50, or a fifth of a short route, at least 1
    and at most ``n_places − 2`` (the one default of the method registry, the live map and
    :meth:`catgraph.observation.HistogramObservation.bootstrap`)."""
    return max(1, min(50, n_places // 5, n_places - 2))


def reference_samples(
    reference_differences: Any,
    gap: int,
    max_different: int = 100_000,
    same_radius: int = 0,
    seed: int | np.random.Generator | None = 0,
    reference_positions: Any = None,
    min_distance: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Bootstrap samples from the reference map alone (reference vs reference).

    Parameters
    ----------
    reference_differences : array_like, shape (n_reference, n_reference)
        Differences between reference frames (same metric and normalisation as the
        query differences will have).
    gap : int
        Pairs ``(j, j')`` with ``|j − j'| > gap`` count as different places.
    max_different : int
        Number of ``¬L`` pairs drawn (seeded, with replacement among eligible pairs).
    same_radius : int
        ``0`` (default): no ``L`` samples, ``P(d|L)`` starts uniform (a weak prior) and
        is learned online. ``r > 0``: the pairs with ``1 ≤ |j − j'| ≤ r`` are ``L``.
    seed : int, Generator or None
    reference_positions : array_like, shape (n_reference, n_dims), optional
        Metric positions; with ``min_distance``, pairs closer than that are never
        ``¬L`` (a route that passes a place twice is far apart in index there).
    min_distance : float, optional
        Needed with ``reference_positions``.

    Returns
    -------
    d_same, d_different : ndarray, float64
    """
    r = check_array(reference_differences, "reference differences", ndim=2)
    n = r.shape[0]
    if r.shape[1] != n:
        raise ShapeMismatchError(f"reference differences must be square (n_reference, n_reference); got {r.shape}.")
    check_scalar(gap, "gap", "reference_samples", int, 0, n - 2)
    check_scalar(max_different, "max_different", "reference_samples", int, 1)
    check_scalar(same_radius, "same_radius", "reference_samples", int, 0, gap)
    rng = as_generator(seed)
    # draw the offset |j − j'| in (gap, n) weighted by how many pairs have it, then j
    offsets = np.arange(gap + 1, n)
    weights = (n - offsets).astype(np.float64)
    k = rng.choice(offsets, size=max_different, p=weights / weights.sum())
    j = np.floor(rng.random(max_different) * (n - k)).astype(np.int64)
    flip = rng.random(max_different) < 0.5
    rows, cols = np.where(flip, j + k, j), np.where(flip, j, j + k)
    if reference_positions is not None:
        pos = check_array(reference_positions, "reference_positions", ndim=2)
        if pos.shape[0] != n:
            raise ShapeMismatchError(f"reference_positions has {pos.shape[0]} rows for {n} reference frames.")
        if min_distance is None:
            raise InvalidParameterError("reference_samples with reference_positions needs min_distance.")
        check_scalar(min_distance, "min_distance", "reference_samples", float, 0.0)
        keep = np.linalg.norm(pos[rows] - pos[cols], axis=1) > min_distance
        # top up with further seeded draws among far pairs, a bounded number of rounds
        for _ in range(50):
            if keep.sum() >= max_different:
                break
            k2 = rng.choice(offsets, size=max_different, p=weights / weights.sum())
            j2 = np.floor(rng.random(max_different) * (n - k2)).astype(np.int64)
            far = np.linalg.norm(pos[j2] - pos[j2 + k2], axis=1) > min_distance
            rows, cols = np.concatenate([rows[keep], j2[far]]), np.concatenate([cols[keep], (j2 + k2)[far]])
            keep = np.ones(rows.size, dtype=bool)
        rows, cols = rows[keep][:max_different], cols[keep][:max_different]
        if rows.size == 0:
            raise DataError(
                f"no reference pairs are more than {min_distance} apart and {gap} frames apart; lower min_distance."
            )
    d_diff = r[rows, cols]
    if same_radius:
        parts = [np.diagonal(r, o) for o in range(1, same_radius + 1)] + [
            np.diagonal(r, -o) for o in range(1, same_radius + 1)
        ]
        d_same = np.concatenate(parts)
    else:
        d_same = np.empty(0, dtype=np.float64)
    return d_same, d_diff
