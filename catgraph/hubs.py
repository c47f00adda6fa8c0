"""Hub references: map frames that are close to every query, and their correction.

Some reference frames look like everything: a flat, textureless image (Nordland's
tunnels, a white wall, snow) is at a small difference from every query frame, so after
per-query normalisation its column of the difference matrix is low everywhere and it
attracts matches that belong elsewhere (a *hub*, as in nearest-neighbour search in high
dimensions). A correction must come from the reference map alone — no training and no
query ground truth — and must leave a map without hubs alone.

The map's own difference matrix ``R`` (``N x N``, each reference frame compared with
every other one and normalised per row exactly like a query, e.g.
``catgraph.pipeline.differences(reference, reference)``) tells which frames are hubs: a
reference ``j`` whose *typical* normalised difference to the other map frames,

    h_j = median_{r != j} R[r, j],

is far below the typical ``h`` is close to almost every frame, not only to its own
place. The median (over ``N - 1`` frames) ignores the few frames of ``j``'s own place,
however the map was recorded (several scans per point, as in a Wi-Fi survey, or one
frame per metre). The offsets are

    o_j = h_j - median(h)   if h_j < median(h) - threshold * 1.4826 * MAD(h),   else 0,

so only *outlying* hubs are corrected, by their whole excess. On a map whose ``h`` has no
outlying low tail (measured: the UJI Wi-Fi survey) every offset is zero and the
correction changes nothing; on Nordland about 2 % of the frames (the tunnels) are
corrected. Correcting every column by ``h_j - median(h)`` instead (a plain column
standardisation) was measured to help Nordland's short windows but to hurt every window
length on UJI (single-frame AUC 0.39 -> 0.22): there the spread of ``h`` is a property
of the places, not a defect. See ``docs/sequence.md``.

Applying the offsets (:func:`apply_hub_offsets`) subtracts them from every query row and
normalises each row again (mean 0, standard deviation 1), so the result is on the same
scale as the input and can be given to any method that takes a difference matrix.

Public functions (small and stable)::

    hub_offsets(map_differences, threshold=3.0, rows=None) -> (N,) float64
    apply_hub_offsets(differences, offsets, renormalise=True) -> (n_query, N) float64
"""

from __future__ import annotations

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError, ShapeMismatchError

__all__ = ["hub_offsets", "map_hub_offsets", "apply_hub_offsets", "hub_sample", "typical_columns", "HUB_THRESHOLD",
           "HUB_ROWS"]

#: outlying hubs lie more than this many robust standard deviations below the typical frame
HUB_THRESHOLD = 3.0
#: a map's hub offsets are estimated from at most this many of its frames
HUB_ROWS = 2048


def hub_offsets(map_differences: np.ndarray, threshold: float = HUB_THRESHOLD,
                rows: np.ndarray | None = None) -> np.ndarray:
    """Per-reference offsets that cancel outlying hubs, ``(N,) float64`` (0 = no correction).

    Parameters
    ----------
    map_differences : ndarray, shape (N, N)
        The reference map against itself, normalised per row like a query's differences
        (row ``r`` = map frame ``r`` seen as a query). The diagonal is ignored.
    threshold : float
        A frame is an outlying hub when its typical difference ``h_j`` lies more than
        ``threshold`` robust standard deviations (``1.4826 * MAD``) below the median
        ``h``.
    rows : ndarray of int, shape (k,), optional
        With a large map, the medians can come from a sample of ``k`` map frames:
        ``map_differences`` is then ``(k, N)``, row ``t`` being map frame ``rows[t]``
        (whose own entry is ignored).

    Returns
    -------
    ndarray, shape (N,)
        ``h_j - median(h)`` (negative) for outlying hubs, ``0`` elsewhere.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> r = rng.normal(size=(200, 200))
    >>> r[:, 7] -= 3.0                       # frame 7 is close to everything
    >>> offsets = hub_offsets(r)
    >>> int(np.flatnonzero(offsets)[0]), bool(offsets[7] < -2.5)
    (7, True)
    """
    r = check_array(map_differences, "map difference matrix", ndim=2)
    if rows is None:
        if r.shape[0] != r.shape[1] or r.shape[0] < 3:
            raise ShapeMismatchError(
                f"the map difference matrix must be square (reference x reference) with at least 3 frames; got shape "
                f"{r.shape}. Compute it as differences(reference, reference).")
        rows = np.arange(r.shape[0])
    rows = np.asarray(rows)
    if rows.dtype.kind not in "iu":
        raise DataError(f"rows must be map frame indices (integers); got dtype {rows.dtype}.")
    rows = rows.astype(np.int64)
    if rows.shape != (r.shape[0],) or r.shape[0] < 3 or rows.min() < 0 or rows.max() >= r.shape[1]:
        raise ShapeMismatchError(f"give one map frame index per row of the {r.shape} map differences (at least 3).")
    if len(np.unique(rows)) != len(rows):
        raise DataError("rows name a map frame twice; give each sampled map frame once (a frame's own difference "
                        "is left out of its column, and a column left with no other frame would drop every offset).")
    check_scalar(threshold, "threshold", "hub_offsets", float, 0.0)
    m = np.array(r, dtype=np.float64, copy=True)
    m[np.arange(len(rows)), rows] = np.nan
    return _outlying(np.nanmedian(m, axis=0), threshold)


def _outlying(typical: np.ndarray, threshold: float) -> np.ndarray:
    """``h_j - median(h)`` where ``h_j`` lies more than ``threshold`` robust standard
    deviations below the median of the typical differences ``h``, ``0`` elsewhere."""
    centre = float(np.median(typical))
    spread = 1.4826 * float(np.median(np.abs(typical - centre)))
    return np.where(typical < centre - threshold * spread, typical - centre, 0.0)


def map_hub_offsets(catgraph_map, threshold: float = HUB_THRESHOLD, max_rows: int = HUB_ROWS) -> np.ndarray:
    """:func:`hub_offsets` of a :class:`~catgraph.io.CatgraphMap`: the map against itself,
    or, above ``max_rows`` places, a seeded sample of ``max_rows`` of its frames against
    the whole map, read in blocks of places (never an ``N × N`` matrix, nor the whole
    ``max_rows × N`` one)."""
    from .differences import iter_difference_columns, take_rows

    d, n = catgraph_map.descriptors, catgraph_map.n_places
    check_scalar(threshold, "threshold", "hub_offsets", float, 0.0)
    if n < 3:  # as hub_offsets: no typical difference to stand out from (one place has no other)
        return np.zeros(n)
    rows = hub_sample(n, max_rows)
    typical = np.empty(n)
    for lo, block in iter_difference_columns(take_rows(d, rows), d, catgraph_map.metric,
                                             normalise=bool(catgraph_map.frontend.get("normalise", True))):
        typical[lo : lo + block.shape[1]] = typical_columns(block, rows, lo)
    return _outlying(typical, threshold)


def hub_sample(n: int, max_rows: int = HUB_ROWS) -> np.ndarray:
    """The map frames whose differences give a map's hub offsets (:func:`map_hub_offsets`):
    every frame up to ``max_rows``, else a seeded sample of ``max_rows`` (sorted), the same
    for every run on the map and for the cluster's (:func:`catgraph.distributed.map_hub_offsets`)."""
    check_scalar(max_rows, "max_rows", "map_hub_offsets", int, 1)
    return np.arange(n) if n <= max_rows else np.sort(np.random.default_rng(0).choice(n, max_rows, replace=False))


def typical_columns(block: np.ndarray, rows: np.ndarray, lo: int) -> np.ndarray:
    """Each column's typical difference ``h_j`` (:func:`hub_offsets`) from the map frames
    ``rows`` against places ``lo …`` (``block``: their normalised differences, ``(len(rows),
    width)`` float64, overwritten): the median over the rows, each frame's own place left out."""
    own = np.flatnonzero((rows >= lo) & (rows < lo + block.shape[1]))
    block[own, rows[own] - lo] = np.nan
    return np.nanmedian(block, axis=0)


#: Values per block of rows renormalised at once by :func:`apply_hub_offsets`.
RENORMALISE_VALUES = 1 << 22


def apply_hub_offsets(differences: np.ndarray, offsets: np.ndarray, renormalise: bool = True) -> np.ndarray:
    """Subtract the hub offsets from every query row (and normalise each row again).

    Parameters
    ----------
    differences : ndarray, shape (n_query, N) or (N,)
        Query × reference differences (usually per-query normalised).
    offsets : ndarray, shape (N,)
        From :func:`hub_offsets`.
    renormalise : bool
        Give each corrected row mean 0 and standard deviation 1 again.

    A row with no information (constant: a frame that tells no places apart, such as a
    blank frame's zeros, :mod:`catgraph.matching`) is not corrected: it stays constant
    (shifted to 0 with ``renormalise``), where the offsets alone would rank the map's
    hubs first for it.

    Returns
    -------
    ndarray, same shape as ``differences``, float64
    """
    d = check_array(differences, "difference matrix")
    o = check_array(offsets, "hub offsets", ndim=1)
    if d.ndim not in (1, 2) or d.shape[-1] != o.shape[0]:
        raise ShapeMismatchError(
            f"the difference matrix has {d.shape[-1] if d.ndim else 0} reference places but there are "
            f"{o.shape[0]} hub offsets; compute the offsets from the same reference map.")
    values = np.asarray(d, dtype=np.float64)
    out = values - o
    flat = np.ptp(values.reshape(-1, values.shape[-1]), axis=1) == 0
    if flat.any():
        out.reshape(-1, out.shape[-1])[flat] = values.reshape(-1, values.shape[-1])[flat]
    if renormalise:  # in place, in blocks of rows: one copy of a large matrix, not four
        rows = out.reshape(-1, out.shape[-1])
        step = max(1, RENORMALISE_VALUES // rows.shape[1])
        for start in range(0, rows.shape[0], step):
            block = rows[start : start + step]
            mean = block.mean(axis=-1, keepdims=True)
            std = block.std(axis=-1, keepdims=True)
            np.subtract(block, mean, out=block)
            np.divide(block, np.where(std > 0, std, 1.0), out=block)
    return out
