"""Traverses and ground truth.

A *traverse* is one pass along a route: ``n`` frames, each a raw image or a descriptor
vector, in the order they were recorded, with whatever else the sensor gave — metric
positions (metres), a floor or level, timestamps (seconds), ids, odometry (metres
travelled since the previous frame).

``Traverse.index`` is the frame's index *in the traverse as loaded*. Transforms that
reorder frames (:func:`shuffle_segments`) carry it along, so ground truth and results
always refer to the frames as loaded, whatever order they were processed in.

Ground truth between a query and a reference comes in the three forms users have:

* :class:`FrameTolerance` — the same index is the same place (Nordland), correct within
  ``± tolerance`` frames;
* :class:`MetricTolerance` — positions in metres (and the same floor where known);
* :class:`ExplicitGroundTruth` — a list of true ``(query, reference)`` pairs or a
  (soft) ``(n_query, n_reference)`` matrix.

All take indices *as loaded* and answer two vectorised questions: is a match correct,
and does a query frame have any true match in the reference (the recall denominator).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError

__all__ = [
    "Traverse",
    "GroundTruth",
    "FrameTolerance",
    "MetricTolerance",
    "ExplicitGroundTruth",
    "shuffle_segments",
    "segment_order",
]


def _optional(values: Any, name: str, n: int, ndim: int | tuple[int, ...], dtype=np.float64):
    if values is None:
        return None
    out = check_array(values, name, ndim=ndim, dtype=dtype)
    if out.shape[0] != n:
        raise ShapeMismatchError(f"{name} has {out.shape[0]} rows but the traverse has {n} frames; give one per frame.")
    return out


#: ``meta`` entries the library writes about a traverse as a whole (never per frame)
_WHOLE_TRAVERSE_META = frozenset({"segments", "traversal"})


@dataclass(frozen=True, eq=False)
class Traverse:
    """One pass along a route.

    Parameters
    ----------
    frames : ndarray, shape (n, ...)
        Images ``(n, h, w)``/``(n, h, w, c)`` or descriptors ``(n, d)``. Must be finite.
    positions : ndarray, shape (n, 2) or (n, 3), optional
        Metric positions in metres.
    floors : ndarray, shape (n,), optional
        Floor or level (int); ground truth by distance then requires the same floor.
    timestamps : ndarray, shape (n,), optional
        Seconds.
    ids : ndarray, shape (n,), optional
        Identifiers from the source (file numbers, sample ids).
    odometry : ndarray, shape (n,), optional
        Metres travelled since the previous frame (``odometry[0]`` is ignored).
    index : ndarray of int, shape (n,), optional
        Index of each frame in the traverse as loaded; defaults to ``arange(n)``.
    name : str
        Human-readable name (a folder or file name).
    meta : dict
        Anything else the source knows. An entry that is an array or a list with one
        item per frame (an image folder's ``"files"``, the synthetic world's ``"street"``,
        ``"new_place"`` …) travels with its frames when they are reordered or thinned
        (:meth:`take`: conditions, shuffles); the others are kept as they are.
    """

    frames: np.ndarray
    positions: np.ndarray | None = None
    floors: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    ids: np.ndarray | None = None
    odometry: np.ndarray | None = None
    index: np.ndarray | None = None
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        frames = check_array(self.frames, f"frames of traverse {self.name!r}", dtype=None)
        if not (np.issubdtype(frames.dtype, np.number) or frames.dtype == bool):
            raise DataError(f"frames of traverse {self.name!r} must be numeric; got dtype {frames.dtype}.")
        if frames.ndim < 2:
            raise DataError(
                f"frames of traverse {self.name!r} must have shape (n, ...) with one row per frame; got shape {frames.shape}."
            )
        n = frames.shape[0]
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "positions", _optional(self.positions, "positions", n, 2))
        if self.positions is not None and self.positions.shape[1] not in (2, 3):
            raise DataError(f"positions must have 2 or 3 columns (metres); got {self.positions.shape[1]}.")
        object.__setattr__(self, "floors", _optional(self.floors, "floors", n, 1, dtype=np.int64))
        object.__setattr__(self, "timestamps", _optional(self.timestamps, "timestamps", n, 1))
        object.__setattr__(self, "ids", _optional(self.ids, "ids", n, 1, dtype=None))
        object.__setattr__(self, "odometry", _optional(self.odometry, "odometry", n, 1))
        index = np.arange(n) if self.index is None else _optional(self.index, "index", n, 1, dtype=np.int64)
        object.__setattr__(self, "index", index)

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    def __repr__(self) -> str:
        extras = [k for k in ("positions", "floors", "timestamps", "ids", "odometry") if getattr(self, k) is not None]
        return f"Traverse(name={self.name!r}, n={len(self)}, frame_shape={self.frames.shape[1:]}, with={extras})"

    def take(self, order: np.ndarray) -> "Traverse":
        """Frames ``order`` (ints), everything carried along, ``index`` included, and every
        ``meta`` entry with one item per frame (an array or a list of ``len(self)``)."""
        order = np.asarray(order, dtype=np.int64)
        sub = lambda a: None if a is None else a[order]  # noqa: E731
        n = len(self)
        meta = {}
        for key, value in self.meta.items():
            if key not in _WHOLE_TRAVERSE_META and isinstance(value, np.ndarray) and value.ndim >= 1 \
                    and value.shape[0] == n:
                value = value[order]
            elif key not in _WHOLE_TRAVERSE_META and isinstance(value, list) and len(value) == n:
                value = [value[k] for k in order]
            meta[key] = value
        return replace(
            self,
            meta=meta,
            frames=self.frames[order],
            positions=sub(self.positions),
            floors=sub(self.floors),
            timestamps=sub(self.timestamps),
            ids=sub(self.ids),
            odometry=sub(self.odometry),
            index=self.index[order],
        )

    def with_frames(self, frames: np.ndarray) -> "Traverse":
        """The same traverse with new frames (e.g. descriptors from a front-end)."""
        return replace(self, frames=frames)


def segment_order(n: int, seed: int | np.random.Generator | None, min_fraction: float = 0.02,
                  max_fraction: float = 0.20) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Frame order of a segment shuffle and its segments ``(start, stop)`` as they now appear.

    Segment lengths are drawn uniformly from ``[min_fraction, max_fraction]`` of ``n``
    (at least one frame); the last segment takes what is left; the segments are then
    permuted. The one implementation behind :func:`catgraph.traverse.shuffle_segments`
    and :class:`Condition`.
    """
    if not (0.0 < min_fraction <= max_fraction <= 1.0):
        raise InvalidParameterError(
            f"segment fractions must satisfy 0 < MIN ≤ MAX ≤ 1; got {min_fraction}:{max_fraction}.")
    rng = as_generator(seed)
    bounds = [0]
    while bounds[-1] < n:
        length = max(1, int(round(rng.uniform(min_fraction, max_fraction) * n)))
        bounds.append(min(n, bounds[-1] + length))
    segments = list(zip(bounds[:-1], bounds[1:]))
    permutation = rng.permutation(len(segments))
    segments = [segments[k] for k in permutation]
    order = np.concatenate([np.arange(a, b) for a, b in segments]) if segments else np.zeros(0, np.int64)
    return order.astype(np.int64), segments


def shuffle_segments(
    traverse: Traverse,
    seed: int | np.random.Generator | None = 0,
    min_fraction: float = 0.02,
    max_fraction: float = 0.20,
) -> Traverse:
    """Cut a traverse into contiguous segments and reorder them at random.

    Segment lengths are drawn uniformly from ``[min_fraction, max_fraction]`` of the
    traverse length (at least one frame); the last segment takes what is left. The
    segments are then permuted (seeded). Everything per frame — ``index`` included —
    travels with its frame, so ground truth follows (paper 1, §IV; DESIGN.md §7).

    Returns
    -------
    Traverse
        The shuffled traverse; ``meta["segments"]`` lists the ``(start, stop)`` of each
        segment in the original order, in the order they now appear.
    """
    check_scalar(min_fraction, "min_fraction", "shuffle_segments", float, 0.0, 1.0, low_inclusive=False)
    check_scalar(max_fraction, "max_fraction", "shuffle_segments", float, min_fraction, 1.0)
    frame_order, segments = segment_order(len(traverse), seed, min_fraction, max_fraction)
    out = traverse.take(frame_order)
    meta = dict(out.meta)
    meta["segments"] = segments
    return replace(out, meta=meta, name=f"{traverse.name} (shuffled)")


class GroundTruth(ABC):
    """Which reference frames are true matches of which query frames.

    Both methods take indices of frames *as loaded* (``Traverse.index``).
    """

    @abstractmethod
    def correct(self, query_index: np.ndarray, match: np.ndarray) -> np.ndarray:
        """``(k,) bool``: is ``match[i]`` (reference index, ``-1`` = no output) a true
        match of query frame ``query_index[i]``? No output is never correct."""

    @abstractmethod
    def has_true_match(self, query_index: np.ndarray) -> np.ndarray:
        """``(k,) bool``: does query frame ``query_index[i]`` have any true match?"""

    def describe(self) -> dict:
        """JSON-ready parameters, for result files."""
        return {"type": type(self).__name__}


def _as_index(values, name: str, n: int | None = None, present: np.ndarray | None = None) -> np.ndarray:
    """``values`` as int64 indices; with ``n``, each a frame in ``[0, n)`` (and, with
    ``present``, one the traverse holds) or a :class:`DataError` naming it."""
    out = np.asarray(values)
    if out.dtype.kind not in "iu":
        raise DataError(f"{name} must be integer indices; got dtype {out.dtype}.")
    out = out.astype(np.int64, copy=False)
    if n is not None and out.size:
        bad = (out < 0) | (out >= n)
        if present is not None:
            bad[~bad] = ~present[out[~bad]]
        if bad.any():
            raise DataError(f"{name} {int(out[bad][0])} is not a frame of this ground truth's query "
                            f"({n} frames as loaded); give indices as loaded (Traverse.index).")
    return out


@dataclass(frozen=True)
class FrameTolerance(GroundTruth):
    """Same index = same place; a match is correct within ``± tolerance`` frames.

    ``n_reference`` bounds the reference: a query frame ``i`` has a true match iff some
    ``j`` in ``[i - tolerance, i + tolerance]`` lies in ``[0, n_reference)``.
    """

    n_reference: int
    tolerance: int = 0
    offset: int = 0

    def __post_init__(self) -> None:
        check_scalar(self.n_reference, "n_reference", "FrameTolerance", int, 1)
        # at most 2^62, so that an index plus or minus the tolerance stays inside int64
        check_scalar(self.tolerance, "tolerance", "FrameTolerance", int, 0, 2 ** 62)
        check_scalar(self.offset, "offset", "FrameTolerance", int)

    def correct(self, query_index, match):
        q = _as_index(query_index, "query_index") + self.offset
        m = _as_index(match, "match")
        return (m >= 0) & (m < self.n_reference) & (np.abs(m - q) <= self.tolerance)

    def has_true_match(self, query_index):
        q = _as_index(query_index, "query_index") + self.offset
        return (q + self.tolerance >= 0) & (q - self.tolerance < self.n_reference)

    def describe(self):
        return {"type": "frame", "tolerance": self.tolerance, "offset": self.offset}


class MetricTolerance(GroundTruth):
    """A match is correct when the two positions lie within ``metres`` (same floor).

    Parameters
    ----------
    query_positions, reference_positions : ndarray, shape (n, 2|3)
    metres : float
        Distance threshold (inclusive).
    query_floors, reference_floors : ndarray of int, optional
        Where both are given, a match must also be on the same floor.
    """

    def __init__(self, query_positions, reference_positions, metres: float,
                 query_floors=None, reference_floors=None) -> None:
        self.metres = float(check_scalar(metres, "metres", "MetricTolerance", float, 0.0))
        self.query_positions = check_array(query_positions, "query positions", ndim=2)
        self.reference_positions = check_array(reference_positions, "reference positions", ndim=2)
        if self.query_positions.shape[1] != self.reference_positions.shape[1]:
            raise ShapeMismatchError(
                f"query positions have {self.query_positions.shape[1]} coordinates but reference positions have "
                f"{self.reference_positions.shape[1]}; give both in the same frame."
            )
        use_floors = query_floors is not None and reference_floors is not None
        self.query_floors = np.asarray(query_floors, dtype=np.int64) if use_floors else None
        self.reference_floors = np.asarray(reference_floors, dtype=np.int64) if use_floors else None
        if use_floors:
            for name, floors, positions in (("query", self.query_floors, self.query_positions),
                                            ("reference", self.reference_floors, self.reference_positions)):
                if floors.shape != (len(positions),):
                    raise ShapeMismatchError(f"{name} floors have shape {floors.shape} but there are "
                                             f"{len(positions)} {name} positions; give one floor per position.")
        #: the query frames (as loaded) the traverse holds; ``None``: all (see :meth:`between`)
        self._present: np.ndarray | None = None
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.reference_positions)
        self._has = np.zeros(len(self.query_positions), dtype=bool)
        # the tree's candidates, a little beyond the threshold, then the very distance that
        # correct() measures: a pair exactly at the threshold is a true match for both (the
        # tree's own arithmetic may put it an ulp outside, and the recall would lose it)
        reach = self.metres * (1.0 + 1e-9) + 1e-12
        for i, neighbours in enumerate(self._tree.query_ball_point(self.query_positions, reach)):
            if not neighbours:
                continue
            j = np.asarray(neighbours, dtype=np.int64)
            ok = _distances(self.query_positions[np.full(len(j), i)], self.reference_positions[j]) <= self.metres
            if use_floors:
                ok &= self.reference_floors[j] == self.query_floors[i]
            self._has[i] = bool(ok.any())

    @classmethod
    def between(cls, query: Traverse, reference: Traverse, metres: float) -> "MetricTolerance":
        """Ground truth from the positions (and floors) of two traverses."""
        if query.positions is None or reference.positions is None:
            raise DataError(
                "metric ground truth needs positions in both traverses; "
                "use a frame tolerance (--tolerance) for data without positions."
            )
        # the query's positions by frame as loaded (``index``: a shuffled, repeated or thinned
        # query keeps its frames' numbers); the reference's by place, its rows, which matches name
        n = int(query.index.max()) + 1 if len(query) else 0
        present = np.zeros(n, dtype=bool)
        present[query.index] = True
        qpos = np.zeros((n, query.positions.shape[1]), dtype=np.float64)
        qpos[query.index] = query.positions
        qf = rf = None
        if query.floors is not None and reference.floors is not None:
            qf = np.zeros(n, dtype=np.int64)
            qf[query.index] = query.floors
            rf = reference.floors
        out = cls(qpos, reference.positions, metres, qf, rf)
        if not present.all():
            out._present = present
            out._has &= present
        return out

    def correct(self, query_index, match):
        q = _as_index(query_index, "query_index", len(self.query_positions), self._present)
        m = _as_index(match, "match")
        valid = (m >= 0) & (m < len(self.reference_positions))
        mm = np.where(valid, m, 0)
        ok = valid & (_distances(self.query_positions[q], self.reference_positions[mm]) <= self.metres)
        if self.query_floors is not None:
            ok &= self.query_floors[q] == self.reference_floors[mm]
        return ok

    def has_true_match(self, query_index):
        return self._has[_as_index(query_index, "query_index", len(self.query_positions), self._present)]

    @property
    def n_reference(self) -> int:
        """The reference's places (a match past them is refused by :func:`~catgraph.metrics.evaluate`)."""
        return len(self.reference_positions)

    def describe(self):
        return {"type": "metric", "metres": self.metres, "floors": self.query_floors is not None}


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance of each row pair: one formula for :meth:`MetricTolerance.correct`
    and its recall denominator, so that they agree to the last bit."""
    return np.linalg.norm(a - b, axis=1)


class ExplicitGroundTruth(GroundTruth):
    """Ground truth given as true pairs or as a (soft) matrix.

    Parameters
    ----------
    matrix : array or scipy.sparse matrix, shape (n_query, n_reference)
        Entry ``[i, j]`` is the degree to which reference ``j`` is a true match of query
        ``i`` (bool or float in [0, 1]). A match is correct where it is ``>= threshold``.
    threshold : float
        Soft matrices: smallest value that counts as a true match (default: any
        positive value).
    """

    def __init__(self, matrix, threshold: float | None = None) -> None:
        import scipy.sparse

        m = scipy.sparse.csr_array(matrix)
        if m.ndim != 2:
            raise DataError(f"a ground-truth matrix must be 2-D (n_query, n_reference); got shape {m.shape}.")
        m.sum_duplicates()
        data = np.asarray(m.data, dtype=np.float64)
        if not np.all(np.isfinite(data)):
            raise DataError("the ground-truth matrix contains NaN or infinite values.")
        if threshold is not None:
            # at or below 0 every entry — the matrix's zeros and absent ones too — would be a match
            check_scalar(threshold, "threshold", "ExplicitGroundTruth", float, 0.0, low_inclusive=False)
            threshold = float(threshold)
        self.threshold = threshold
        keep = data >= threshold if threshold is not None else data > 0
        m = scipy.sparse.csr_array((keep, m.indices, m.indptr), shape=m.shape)
        m.eliminate_zeros()
        self.matrix = m.astype(bool)
        self._has = np.asarray(self.matrix.sum(axis=1)).ravel() > 0

    @classmethod
    def from_pairs(cls, pairs, n_query: int, n_reference: int) -> "ExplicitGroundTruth":
        """From ``(k, 2)`` integer ``(query_index, reference_index)`` pairs."""
        p = np.asarray(pairs)
        if p.ndim != 2 or p.shape[1] != 2 or (p.size and p.dtype.kind not in "iu"):
            raise DataError(f"ground-truth pairs must be an integer array of shape (k, 2); got shape {p.shape}.")
        p = p.astype(np.int64)
        if p.size and (p[:, 0].min() < 0 or p[:, 0].max() >= n_query or p[:, 1].min() < 0 or p[:, 1].max() >= n_reference):
            raise DataError(f"ground-truth pairs index outside a {n_query} × {n_reference} query × reference grid.")
        import scipy.sparse

        m = scipy.sparse.coo_array((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n_query, n_reference))
        return cls(m)

    def correct(self, query_index, match):
        q = _as_index(query_index, "query_index", self.matrix.shape[0])
        m = _as_index(match, "match")
        valid = (m >= 0) & (m < self.matrix.shape[1])
        out = np.zeros(len(q), dtype=bool)
        if valid.any():
            out[valid] = np.asarray(self.matrix[q[valid], m[valid]]).ravel()
        return out

    def has_true_match(self, query_index):
        return self._has[_as_index(query_index, "query_index", len(self._has))]

    @property
    def n_reference(self) -> int:
        """The reference's places (a match past them is refused by :func:`~catgraph.metrics.evaluate`)."""
        return int(self.matrix.shape[1])

    def describe(self):
        return {"type": "explicit", "threshold": self.threshold}
