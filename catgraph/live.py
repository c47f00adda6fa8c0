"""Live localisation: one sensor frame in, one answer out.

A navigation stack does not hold a query traverse: a camera frame or a Wi-Fi scan
arrives, an answer must leave, in bounded time and memory. This module is that path.

1. **Prepare the map once** — :class:`LiveMap` (from a saved map,
   :func:`catgraph.io.load_map`, or a reference traverse): the reference descriptors
   validated and laid out for the difference kernels
   (:class:`~catgraph.differences.PreparedReference`; cosine norms precomputed), the
   front-end settings and data kind the map was built with, its place graph and,
   on request, statistics of the map against itself (:meth:`LiveMap.bootstrap`):
   ``¬L`` samples for the bootstrapped histogram model and each place's typical
   normalised difference to places far from it (the "hub" statistic).
2. **Step once per frame** — :class:`LiveLocalizer`: ``step(frame)`` applies exactly the
   map's front-end to the raw frame (:func:`describe_frame`), computes its difference to
   every place (one row, all cores), normalises it, and runs the particle filter (or,
   with ``model="matcher"``, the sequence matcher alone). It returns a
   :class:`LiveEstimate`: place, confidence, ``P(new place)``, the chosen window
   and velocity, and the time each stage took.

Same answers as the batch commands
----------------------------------
Every stage is the batch code, called one row at a time: :func:`describe_frame`
equals :func:`catgraph.pipeline.describe` on that frame, the difference row equals the
row of :func:`catgraph.differences.difference_matrix` bit for bit (one kernel), the
model is built as :func:`catgraph.compare.build_model` builds it, and the filter is
:class:`~catgraph.localizer.Localizer` with the settings of
:func:`catgraph.compare.localize`. So feeding a query frame by frame gives the places
and scores ``catgraph localize`` writes (tested).

Bootstrap without an ``N × N`` matrix
-------------------------------------
The bootstrapped ``¬L`` histogram draws pairs of reference places more than ``gap``
apart (:func:`catgraph.likelihood.reference_samples`). :meth:`LiveMap.bootstrap` draws
the *same* pairs with the same seed and computes only the rows they need, a block at a
time, so memory is ``O(block × N)``; the result equals the batch model bit for bit.
Above ``anchor_rows`` places (default 4096) the rows are restricted to a seeded sample
of ``anchor_rows`` places (columns anywhere at least ``gap`` away): cost
``O(anchor_rows × N × d)`` instead of ``O(N² d)``, so bootstrap and combined models
run at ``N = 10⁵`` and beyond.

Cold start
----------
Every compiled kernel is cached on disk the first time a process compiles it
(:mod:`catgraph._jit`), but that first process pays the compilation — seconds per
kernel, dominated by the sequence matcher's and the grid filter's. :func:`warm_up` runs
small maps through every live path (both layouts, the filter's models, the matcher; a
map in each size regime of the filter's defaults, :data:`WARM_UP_PLACES`) so that a
deployment can pay it once, at install or image-build time
(``python -c "import catgraph.live as l; l.warm_up()"``); the first real run then
starts as fast as any later one.

Memory of one step
------------------
The map (``N × d`` float32, or ``N × d`` bytes with ``layout="uint8"``: the compact
map keeps no float copy, its bootstrap samples and hub levels are computed from the
codes — :func:`reference_bootstrap_samples`, :func:`reference_hub_offsets` — the
differences its live rows are matched with), one float64 difference row written in
place every frame, and what the models hold: the filter ``O(N)`` (grid) or
``O(n_particles)``, the sequence matcher its ring of the last ``l_max + 1`` rows and
its running sums per velocity and window length (:mod:`catgraph.sequence`), the
histogram models ``O(N)``. Measured figures: ``benchmarks/results/live.md``.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validation import as_generator, check_array, check_scalar
from .differences import LAYOUTS, PreparedReference
from .hubs import HUB_ROWS, HUB_THRESHOLD
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .methods import FILTER_MODELS

__all__ = [
    "LIVE_MODELS",
    "LiveEstimate",
    "LiveLocalizer",
    "LiveMap",
    "bootstrap_pairs",
    "describe_frame",
    "map_bootstrap",
    "map_bootstrap_samples",
    "reference_bootstrap_samples",
    "reference_hub_offsets",
    "release_free_memory",
    "warm_up",
    "warm_up_batch",
]

#: Models a :class:`LiveLocalizer` runs: the filter's observation models
#: (:data:`catgraph.methods.FILTER_MODELS`) and the standalone sequence matcher.
LIVE_MODELS = (*FILTER_MODELS, "matcher")


# ---------------------------------------------------------------------------------------
# front-end of one frame


def describe_frame(frame, kind: str, frontend=None, not_detected: float = 100.0) -> np.ndarray:
    """The descriptor of one raw frame, as :func:`catgraph.pipeline.describe` makes it.

    Parameters
    ----------
    frame : array_like
        ``kind="images"``: one image ``(h, w)`` or ``(h, w, channels)``;
        ``"wifi"``: one scan ``(n_access_points,)`` in dBm (``not_detected`` = not
        seen); ``"descriptors"``: one feature vector (any shape, flattened).
    kind : {"images", "wifi", "descriptors"}
        The map's data kind (``LiveMap.kind``).
    frontend : FrontEnd, optional
        The map's front-end settings (default ``FrontEnd()``).
    not_detected : float
        Wi-Fi code for "access point not seen" (UJI: +100).

    Returns
    -------
    ndarray, shape (d,)
        float32 (bool for boolean descriptors; uint8 for bits packed in bytes under the
        ``hamming`` metric).
    """
    from .frontends import seqslam_preprocess, wifi_vectors
    from .pipeline import FrontEnd

    frontend = FrontEnd() if frontend is None else frontend
    x = np.asarray(frame)
    if kind == "images":
        if x.ndim not in (2, 3):
            raise DataError(f"a live image frame must have shape (h, w) or (h, w, channels); got {x.shape}.")
        return seqslam_preprocess(x[None], size=frontend.size, patch=frontend.patch, crop=frontend.crop)[0]
    if kind == "wifi":
        if x.ndim != 1:
            raise DataError(f"a live Wi-Fi scan must have shape (n_access_points,); got {x.shape}.")
        return wifi_vectors(x[None], not_detected=not_detected)[0]
    if kind == "descriptors":
        flat = x.reshape(-1)
        if flat.dtype.kind not in "biuf":
            raise DataError(f"a live descriptor must be numeric or boolean; got dtype {flat.dtype}.")
        if flat.dtype == bool or (flat.dtype == np.uint8 and frontend.metric == "hamming"):
            return flat  # bits, or bits packed in bytes (compared as bits)
        with np.errstate(over="ignore"):
            out = flat.astype(np.float32)
        overflowed = flat.dtype.kind == "f" and flat.dtype.itemsize > 4 and not np.isfinite(out).all()
        if overflowed and np.isfinite(flat).all():
            raise DataError("a live descriptor holds values too large for float32 (|x| > 3.4e38); rescale them.")
        return out
    raise InvalidParameterError(f"unknown data kind {kind!r}; a map holds 'images', 'wifi' or 'descriptors'.")


# ---------------------------------------------------------------------------------------
# the prepared map


def bootstrap_pairs(n_places: int, gap: int, max_different: int = 100_000, seed=0,
                    anchor_rows: int | None = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of reference places ``(rows, cols)`` more than ``gap`` apart, drawn for the
    bootstrapped ``¬L`` histogram.

    With ``n_places <= anchor_rows`` (or ``anchor_rows=None``) the draws are those of
    :func:`catgraph.likelihood.reference_samples` (same seed, same pairs). Above it,
    ``rows`` come from a seeded sample of ``anchor_rows`` places and each ``col`` is
    uniform among the places more than ``gap`` from its row.

    Returns
    -------
    rows, cols : ndarray of int64, shape (max_different,)
    """
    n = int(n_places)
    check_scalar(gap, "gap", "bootstrap_pairs", int, 0, n - 2)
    check_scalar(max_different, "max_different", "bootstrap_pairs", int, 1)
    rng = as_generator(seed)
    if anchor_rows is None or n <= anchor_rows:
        # the draws of catgraph.likelihood.reference_samples, step for step
        offsets = np.arange(gap + 1, n)
        weights = (n - offsets).astype(np.float64)
        k = rng.choice(offsets, size=max_different, p=weights / weights.sum())
        j = np.floor(rng.random(max_different) * (n - k)).astype(np.int64)
        flip = rng.random(max_different) < 0.5
        return np.where(flip, j + k, j), np.where(flip, j, j + k)
    check_scalar(anchor_rows, "anchor_rows", "bootstrap_pairs", int, 1)
    anchors = np.sort(rng.choice(n, size=anchor_rows, replace=False))
    rows = anchors[rng.integers(0, anchor_rows, size=max_different)]
    lo, hi = np.maximum(rows - gap, 0), np.minimum(rows + gap, n - 1)
    width = hi - lo + 1
    u = np.floor(rng.random(max_different) * (n - width)).astype(np.int64)
    cols = np.where(u < lo, u, u + width)
    return rows.astype(np.int64), cols


def _reference_rows(reference: PreparedReference, rows: np.ndarray, normalise: bool, block_values: int = 1 << 21):
    """Yield ``(places, block)``: the map against itself for the given places,
    ``(len(places), N)`` float64, at most ``block_values`` values per block."""
    step = max(1, block_values // reference.n_places)
    for start in range(0, len(rows), step):
        places = rows[start : start + step]
        out = np.empty((len(places), reference.n_places))
        yield places, reference._fill(reference.descriptors[places], normalise, out)


def map_bootstrap(catgraph_map, gap: int | None = None, max_different: int = 100_000, seed=0,
                  anchor_rows: int | None = 4096, reference: PreparedReference | None = None):
    """The bootstrapped ``¬L`` model of a map and its hub statistic (see
    :func:`map_bootstrap_samples`): ``(HistogramLikelihood, hub)``."""
    from .likelihood import HistogramLikelihood

    values, hub = map_bootstrap_samples(catgraph_map, gap, max_different, seed, anchor_rows, reference)
    return HistogramLikelihood().fit(np.empty(0), values), hub


def map_bootstrap_samples(catgraph_map, gap: int | None = None, max_different: int = 100_000, seed=0,
                          anchor_rows: int | None = 4096, reference: PreparedReference | None = None):
    """The bootstrapped ``¬L`` samples of a map, without an ``N × N`` matrix.

    Draws the pairs of :func:`bootstrap_pairs` and computes only the reference rows
    they need, a block at a time. With ``N <= anchor_rows`` the fitted model equals
    :meth:`catgraph.observation.HistogramObservation.bootstrap` on the full normalised
    reference-vs-reference matrix, bit for bit.

    Parameters
    ----------
    catgraph_map : CatgraphMap
    gap : int, optional
        Places more than ``gap`` apart are different (default
        :func:`catgraph.samples.default_bootstrap_gap`: 50, or a fifth of a short route;
        capped at ``N − 2``).
    max_different : int
        ``¬L`` samples.
    seed : int, Generator or None
    anchor_rows : int or None
        Above this many places, rows come from a seeded sample of this many.
    reference : PreparedReference, optional
        The map's prepared descriptors, if already at hand.

    Returns
    -------
    values : ndarray of float64, shape (max_different,)
        Normalised differences between map places more than ``gap`` apart.
    hub : ndarray of float64, shape (N,)
        Each place's mean normalised difference to the sampled places more than
        ``gap`` from it (low: close to everything, a hub).
    """
    reference = PreparedReference(catgraph_map.descriptors, catgraph_map.metric) if reference is None else reference
    return reference_bootstrap_samples(reference, bool(catgraph_map.frontend.get("normalise", True)), gap,
                                       max_different, seed, anchor_rows)


def reference_bootstrap_samples(reference: PreparedReference, normalise: bool = True, gap: int | None = None,
                                max_different: int = 100_000, seed=0, anchor_rows: int | None = 4096):
    """:func:`map_bootstrap_samples` from a prepared reference alone: its rows as held
    (float32 values or ``uint8`` codes), so a compact live map needs no float copy.

    Parameters
    ----------
    reference : PreparedReference
    normalise : bool
        Whether the map's rows are normalised per query (its front-end's ``normalise``).
    gap, max_different, seed, anchor_rows
        As in :func:`map_bootstrap_samples`.

    Returns
    -------
    values, hub : ndarray of float64
        As in :func:`map_bootstrap_samples`.
    """
    n = reference.n_places
    if n < 3:
        raise DataError(f"a bootstrap needs at least 3 map places; the map has {n}.")
    from .samples import default_bootstrap_gap

    gap = default_bootstrap_gap(n) if gap is None else gap
    gap = min(gap, n - 2)
    rows, cols = bootstrap_pairs(n, gap, max_different, seed, anchor_rows)
    order = np.argsort(rows, kind="stable")
    sorted_rows = rows[order]
    values = np.empty(len(rows))
    hub_sum, hub_count = np.zeros(n), np.zeros(n)
    for places, block in _reference_rows(reference, np.unique(rows), normalise):
        lo = np.searchsorted(sorted_rows, places[0], "left")
        hi = np.searchsorted(sorted_rows, places[-1], "right")
        idx = order[lo:hi]
        values[idx] = block[np.searchsorted(places, rows[idx]), cols[idx]]
        for t, p in enumerate(places):  # hub statistic: mean over places far from the row
            hub_sum += block[t]
            hub_count += 1
            near = slice(max(0, p - gap), p + gap + 1)
            hub_sum[near] -= block[t, near]
            hub_count[near] -= 1
    hub = np.divide(hub_sum, hub_count, out=np.zeros(n), where=hub_count > 0)
    return values, hub


def reference_hub_offsets(reference: PreparedReference, normalise: bool = True, threshold: float = HUB_THRESHOLD,
                          max_rows: int = HUB_ROWS) -> np.ndarray:
    """:func:`catgraph.hubs.map_hub_offsets` from a prepared reference alone.

    The same sampled rows (all places up to ``max_rows``, else a sample drawn with
    seed 0), the median of each place's normalised difference to them, and the same
    outlier rule; the differences are the reference's own (its ``uint8`` codes on a
    compact map, the differences its live rows are matched with). With the float32
    layout the result equals :func:`~catgraph.hubs.map_hub_offsets` of the map bit for bit.

    Parameters
    ----------
    reference : PreparedReference
    normalise : bool
        The map's per-query normalisation.
    threshold, max_rows
        As in :func:`catgraph.hubs.map_hub_offsets`.

    Returns
    -------
    ndarray of float64, shape (N,)
    """
    from .differences import iter_reference_columns
    from .hubs import _outlying, hub_sample, typical_columns

    check_scalar(threshold, "threshold", "reference_hub_offsets", float, 0.0)
    n = reference.n_places
    rows = hub_sample(n, max_rows)
    typical = np.empty(n)
    for lo, block in iter_reference_columns(reference, rows, normalise=normalise):
        typical[lo : lo + block.shape[1]] = typical_columns(block, rows, lo)
    return _outlying(typical, threshold)


def release_free_memory() -> bool:
    """Hand the memory the process has freed but the C allocator still keeps back to the
    operating system (glibc's ``malloc_trim``), so a live process starts streaming from
    what it holds, not from the high-water mark of its preparation (coding scratch,
    bootstrap blocks, the place graph's construction). Called once a
    :class:`LiveLocalizer` is built; nothing is freed that is in use.

    Returns
    -------
    bool
        Whether the allocator could be asked (``False`` off glibc: nothing happens).
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return False
    trim.argtypes = [ctypes.c_size_t]
    trim(0)
    return True


class LiveMap:
    """A map prepared for one-frame-at-a-time localisation.

    Parameters
    ----------
    source : CatgraphMap, path or Traverse
        A saved map (:func:`catgraph.io.load_map`) or its file, or a reference
        traverse, which is described with ``frontend`` (its place graph built with
        :meth:`~catgraph.graph.PlaceGraph.from_traverse`, junctions within
        ``junction_radius_m``). A map file with ``layout="uint8"`` is read in row
        blocks and coded as it is read (``load_map(path, descriptors="stream")``): the
        float map is never in memory whole.
    frontend : FrontEnd, optional
        Only with a traverse (a map carries its own).
    junction_radius_m : float, optional
        Only with a traverse.
    not_detected : float
        Wi-Fi code for "not seen" in the live scans.
    layout : {"float32", "uint8"}
        How the reference is held for the difference kernels
        (:class:`~catgraph.differences.PreparedReference`): ``"uint8"`` reads a quarter
        of the bytes per frame (values coded to 256 levels of the map's range; exact for
        Wi-Fi strengths and bits, within a stated bound otherwise — see
        :mod:`catgraph.differences`); ``"float32"`` (default) gives the batch commands'
        differences bit for bit. Cosine maps keep float32.

    Attributes
    ----------
    map : CatgraphMap or None
        The source map, held with the float32 layout (whose kernel array is the map's
        own float32 descriptors, no copy). ``None`` with ``layout="uint8"``: once the
        codes are made, nothing on the live path reads the float descriptors (the
        bootstrap and the hub levels come from the codes), so they are not kept — the
        map in memory is ``N × d`` bytes.
    reference : PreparedReference
    kind : str
        ``"images"``, ``"wifi"`` or ``"descriptors"``: what a live frame must be.
    frontend : FrontEnd
    metric : str
    graph : PlaceGraph
    positions : ndarray or None
    hub_ : ndarray of float64, shape (N,)
        After :meth:`bootstrap`: each place's mean normalised difference to the sampled
        places more than ``gap`` from it (low = close to everything: a hub).
    """

    def __init__(self, source, frontend=None, junction_radius_m: float | None = None,
                 not_detected: float = 100.0, layout: str = "float32") -> None:
        from .io import CatgraphMap, build_map
        from .pipeline import FrontEnd
        from .traverse import Traverse

        if isinstance(source, (str, os.PathLike)):
            from .io import load_map

            source = load_map(source, descriptors="stream" if layout == "uint8" else "memory")
        if isinstance(source, Traverse):
            if isinstance(frontend, dict) or frontend is None:
                frontend = FrontEnd.from_dict(frontend)
            source = build_map(source, frontend, junction_radius_m=junction_radius_m)
        elif isinstance(source, CatgraphMap):
            if frontend is not None or junction_radius_m is not None:
                raise InvalidParameterError("a saved map carries its front-end and place graph; give neither "
                                            "frontend nor junction_radius_m with a map.")
        else:
            raise InvalidParameterError(
                "LiveMap needs a CatgraphMap (catgraph.io.load_map), a map file or a reference Traverse; got "
                f"{type(source).__name__}."
            )
        if source.graph is None:
            raise DataError("this map holds no place graph (saved with build-map --no-graph, or built with "
                            "build_map(..., graph=False), as catgraph.experiment.prepare builds its map); "
                            "live localisation needs one: give LiveMap the reference traverse, or a map built "
                            "with its graph.")
        self.frontend = source.frontend_settings()
        self.kind = str(source.meta.get("kind", "descriptors"))
        self._meta = dict(source.meta)
        self.metric = source.metric
        self.graph = source.graph
        self.positions = source.positions
        self.name = source.name
        self.not_detected = float(not_detected)
        self.reference = PreparedReference(source.descriptors, self.metric, layout=layout)
        # the compact map keeps no float copy: every statistic reads the codes
        self.map = source if self.reference.layout == "float32" else None

    @property
    def n_places(self) -> int:
        """Number of places ``N``."""
        return self.reference.n_places

    def describe(self, frame) -> np.ndarray:
        """One raw frame through the map's front-end, ``(d,)``."""
        if self.kind == "images" and self.frontend.size is None and "image_shape" in self._meta:
            from .io import check_image_shape

            shape = np.shape(frame)
            check_image_shape(self._meta, self.frontend, shape[:2] if len(shape) in (2, 3) else None, "live images")
        return describe_frame(frame, self.kind, self.frontend, self.not_detected)

    def check_query(self, traverse) -> None:
        """Refuse a query traverse of another kind than the map's (images against a map of
        descriptors …), as the batch commands do (:func:`catgraph.io.describe_query`);
        one frame alone cannot say its kind.

        Raises
        ------
        DataError
        """
        from .io import check_query_kind

        check_query_kind(self.kind, traverse)

    def difference_row(self, frame, out: np.ndarray | None = None) -> np.ndarray:
        """The frame's (normalised, as the map's front-end says) difference to every place.
        A frame with no information (a black image, a scan that detected nothing: every
        value of its descriptor equal) gets a constant row, as in the batch commands
        (:func:`catgraph.io.query_differences`): no match, no evidence."""
        descriptor = self.describe(frame)
        return self._no_information(descriptor, self.reference.row(descriptor, normalise=self.frontend.normalise,
                                                                    out=out))

    def _no_information(self, descriptor: np.ndarray, row: np.ndarray) -> np.ndarray:
        """``row`` made constant (0 where normalised, else its mean) where ``descriptor``
        carries no information."""
        from .frontends import informative_frames
        from .io import no_information_rows

        no_information_rows(row.reshape(1, -1), informative_frames(descriptor.reshape(1, -1)), self.frontend.normalise)
        return row

    def _row_into(self, descriptor: np.ndarray, out: np.ndarray) -> np.ndarray:
        """A described frame's row into ``out`` (C-contiguous float64 ``(N,)``):
        :meth:`PreparedReference.row` with the normalisation's passes in one compiled
        call (:func:`catgraph._diff_kernels.normalise_row`; the same floats, tested)."""
        from ._diff_kernels import normalise_row

        reference = self.reference
        reference._raw(reference.prepare_query(descriptor, single=True), out.reshape(1, -1))
        if self.frontend.normalise:
            normalise_row(out, out)
        return self._no_information(descriptor, out)

    def bootstrap(self, gap: int | None = None, max_different: int = 100_000, seed=0,
                  anchor_rows: int | None = 4096):
        """A fitted ``HistogramLikelihood`` whose ``¬L`` histogram comes from the map
        (:func:`map_bootstrap`); also sets :attr:`hub_`."""
        from .likelihood import HistogramLikelihood

        values, self.hub_ = reference_bootstrap_samples(self.reference, self.frontend.normalise, gap, max_different,
                                                        seed, anchor_rows)
        return HistogramLikelihood().fit(np.empty(0), values)

    def hub_offsets(self) -> np.ndarray:
        """The map's hub offsets for the sequence matcher (:func:`reference_hub_offsets`;
        computed once)."""
        if getattr(self, "_hub_offsets", None) is None:
            self._hub_offsets = reference_hub_offsets(self.reference, self.frontend.normalise)
        return self._hub_offsets

    def __repr__(self) -> str:
        return (f"LiveMap(name={self.name!r}, n_places={self.n_places}, kind={self.kind!r}, metric={self.metric!r}, "
                f"layout={self.reference.layout!r}, frontend={self.frontend})")


# ---------------------------------------------------------------------------------------
# one step per frame


@dataclass(frozen=True)
class LiveEstimate:
    """The answer for one live frame.

    Attributes
    ----------
    place : int
        Most likely map place.
    position : ndarray or None
        Its metric position, where the map has positions.
    score : float
        What to threshold (and rank frames by): the filter's :attr:`Estimate.score`
        (log-odds of the posterior mass near ``place``, capped by the recent support);
        the matcher's confidence with ``model="matcher"``.
    confidence : float
        Posterior mass within the confidence radius of ``place`` (filter); the
        matcher's confidence with ``model="matcher"``.
    new_place_probability : float
        ``P(new place | frames so far)`` (NaN for the matcher alone).
    window_length : int or None
        The sequence window the frame was matched with (models with a sequence part).
    velocity : float or None
        Places per frame of the chosen sequence hypothesis (1.0 while the matcher
        searches the diagonal only).
    seconds : dict
        Wall time of ``frontend``, ``difference`` and ``model`` for this frame.
    """

    place: int
    position: np.ndarray | None
    score: float
    confidence: float
    new_place_probability: float
    window_length: int | None
    velocity: float | None
    seconds: dict


def _sequence_part(model):
    """The SequenceObservation inside a model, if any."""
    from .observation import CombinedObservation, SequenceObservation

    if isinstance(model, SequenceObservation):
        return model
    if isinstance(model, CombinedObservation):
        for part in model.models:
            found = _sequence_part(part)
            if found is not None:
                return found
    return None


class LiveLocalizer:
    """Localise one frame at a time against a :class:`LiveMap`.

    Parameters
    ----------
    live_map : LiveMap
    model : str
        One of :data:`LIVE_MODELS`: an observation model of the particle filter,
        built as the batch ``filter`` method builds it (bootstrapped ones through
        :meth:`LiveMap.bootstrap`), or ``"matcher"``: the sequence matcher alone.
    anchor_rows : int or None
        Passed to :meth:`LiveMap.bootstrap`.
    **params
        Parameters of the batch method — ``filter`` (``n_particles``, ``seed``,
        ``confidence_radius``, ``window`` …; see ``catgraph localize --help``), or
        ``sequence`` for ``"matcher"`` (``window``, ``exclusion`` …) — with the same
        defaults and checks.

    Attributes
    ----------
    params_ : dict
        The resolved parameters (the filter's: its mode as chosen on this map, its defaults filled in).
    localizer_ : Localizer or None
    matcher_ : SequenceMatcher or None

    Examples
    --------
    >>> from catgraph.datasets.synthetic import make_world
    >>> world = make_world(seed=1, blocks=(2, 2), as_images=True)
    >>> live = LiveLocalizer(LiveMap(world.reference), model="adaptive", mode="particles", n_particles=200)
    >>> est = live.step(world.query.frames[0])
    >>> 0 <= est.place < live.live_map.n_places
    True
    """

    def __init__(self, live_map: LiveMap, model: str = "combined", anchor_rows: int | None = 4096,
                 **params: Any) -> None:
        from .methods import resolve_params

        if not isinstance(live_map, LiveMap):
            raise InvalidParameterError(f"LiveLocalizer needs a LiveMap; got {type(live_map).__name__}.")
        if model not in LIVE_MODELS:
            raise InvalidParameterError(
                f"The 'model' parameter of LiveLocalizer must be one of {LIVE_MODELS}. Got {model!r} instead."
            )
        self.live_map = live_map
        self.model_name = model
        self._row = np.empty(live_map.n_places)
        self._last_descriptor = None  # the descriptor whose row ``_row`` holds (read only by the step)
        self.localizer_ = self.matcher_ = None
        if model == "matcher":
            from .methods import _sequence_kwargs
            from .sequence import SequenceMatcher

            self.params_ = resolve_params("sequence", {"window": "adaptive", **params})
            hubs = live_map.hub_offsets() if self.params_["hub_correction"] else None
            self.matcher_ = SequenceMatcher(radius=self.params_["exclusion"], hub_offsets=hubs,
                                            **_sequence_kwargs(self.params_))
            release_free_memory()
            return
        from .methods import check_use_odometry, concrete_params, make_filter, observation_model

        # the filter's parameters as they apply on this map (mode 'auto' chooses by its size)
        self.params_ = p = concrete_params(resolve_params("filter", {"model": model, **params}), live_map.n_places)

        def bootstrap_samples(gap: int, max_different: int, seed: int) -> np.ndarray:
            values, self.live_map.hub_ = reference_bootstrap_samples(live_map.reference, live_map.frontend.normalise,
                                                                     gap, max_different, seed, anchor_rows)
            return values

        obs = observation_model(p, live_map.n_places, bootstrap_samples)
        self.model_ = obs
        self._sequence = _sequence_part(obs)
        check_use_odometry(p["use_odometry"], True, live_map.graph.unit)  # each frame brings its own, or none
        self.use_odometry = p["use_odometry"] is not False and live_map.graph.unit == "m"
        self.localizer_ = make_filter(p, live_map.graph, obs)
        self.localizer_.reset()
        release_free_memory()

    def reset(self) -> "LiveLocalizer":
        """Start a new query (models and filter forget every frame)."""
        if self.localizer_ is None:
            self.matcher_.reset()
        else:
            self.localizer_.reset()
        return self

    def step(self, frame, odometry: float | None = None) -> LiveEstimate:
        """Localise one raw frame (image, scan or descriptor, as the map's kind says).

        A frame described exactly as the previous one (a scanner that reports its last scan
        again, a camera that stood still and sent the same pixels) reuses that frame's
        difference row instead of reading the map again: the same row, so the same answer.

        Parameters
        ----------
        frame : array_like
            See :func:`describe_frame`.
        odometry : float, optional
            Distance travelled since the previous frame (metric graphs only).

        Returns
        -------
        LiveEstimate
        """
        t0 = time.perf_counter()
        descriptor = self.live_map.describe(frame)
        t1 = time.perf_counter()
        row = self._row
        last = self._last_descriptor
        if last is None or not np.array_equal(last, descriptor):  # (unequal shapes: not equal)
            # a frame described exactly as the previous one has its row already (a sensor that
            # sends the same scan again, a camera that stood still): no pass over the map
            self._last_descriptor = None  # until the row is whole
            self.live_map._row_into(descriptor, row)
            self._last_descriptor = np.array(descriptor, copy=True)
        t2 = time.perf_counter()
        if self.localizer_ is None:
            m = self.matcher_.step(row)
            t3 = time.perf_counter()
            return LiveEstimate(int(m.match), None, float(m.confidence), float(m.confidence), float("nan"),
                                int(m.window_length), float(getattr(m, "velocity", 1.0)),
                                {"frontend": t1 - t0, "difference": t2 - t1, "model": t3 - t2})
        if odometry is not None:
            check_scalar(odometry, "odometry", "LiveLocalizer.step", float, 0.0)
        est = self.localizer_.step(row, float(odometry) if (odometry is not None and self.use_odometry) else None)
        t3 = time.perf_counter()
        window = velocity = None
        last = getattr(self._sequence, "last_match_", None)
        if last is not None:
            window = int(last.window_length)
            velocity = float(getattr(last, "velocity", 1.0))
        return LiveEstimate(int(est.place), est.position, float(est.score), float(est.confidence),
                            float(est.new_place_probability), window, velocity,
                            {"frontend": t1 - t0, "difference": t2 - t1, "model": t3 - t2})

    def run(self, frames, odometry=None) -> list[LiveEstimate]:
        """:meth:`step` through frames (a convenience for tests and examples)."""
        odometry = None if odometry is None else check_array(odometry, "odometry", ndim=1)
        if odometry is not None and len(odometry) != len(frames):
            raise ShapeMismatchError(f"odometry has {len(odometry)} entries for {len(frames)} frames; give one per "
                                     "frame.")
        return [self.step(f, None if odometry is None or k == 0 else float(odometry[k])) for k, f in enumerate(frames)]


def _warm_up_places() -> tuple[int, ...]:
    """A map size in each regime of the registry's filter, whose defaults change with the
    map's size (:data:`catgraph.methods.JUMP_GRID_MAX_PLACES`, ``RIGID_MAX_PLACES``,
    ``DENSE_VELOCITY_MAX_PLACES``, ``GRID_MAX_PLACES``: the jump grid, the rigid line and
    the varying speed's dense velocities on small maps, the particle filter above the
    grid's limit): 600 places, and one place beyond each limit."""
    from . import methods

    limits = (methods.JUMP_GRID_MAX_PLACES, methods.RIGID_MAX_PLACES, methods.DENSE_VELOCITY_MAX_PLACES,
              methods.GRID_MAX_PLACES)
    return (600, *sorted({int(limit) + 1 for limit in limits}))


#: Map sizes :func:`warm_up` steps by default: one in each size regime of the filter's
#: defaults, so that the first frames on a map of any size load their kernels instead of
#: compiling them (on a 10⁵-place map the grid filter's single-rate update, above 10⁵
#: places the particle filter's motion, which no smaller map runs).
WARM_UP_PLACES = _warm_up_places()


def warm_up(models: tuple[str, ...] = ("combined", "tempered", "histogram-bootstrap", "matcher"),
            layouts: tuple[str, ...] = LAYOUTS, steps: int = 40,
            places: tuple[int, ...] = WARM_UP_PLACES) -> dict[str, float]:
    """Compile (and cache on disk) the kernels of the live paths once, on small maps.

    Parameters
    ----------
    models : tuple of str
        Models of :data:`LIVE_MODELS` to step.
    layouts : tuple of str
        Map layouts to prepare (:data:`catgraph.differences.LAYOUTS`).
    steps : int
        Frames stepped per model, layout and map (at most 100; some of the particle
        filter's passes run only once it has stepped a few dozen frames).
    places : tuple of int
        Sizes of the maps stepped (routes of 16 values per place; at least 200 places):
        :data:`WARM_UP_PLACES`, one in each size regime of the filter's defaults. The
        largest map costs the process about 150 MB while it is stepped.

    Returns
    -------
    dict
        Seconds spent per ``"model/layout"``, all the maps together.
    """
    from .graph import PlaceGraph
    from .io import CatgraphMap

    unknown = [m for m in models if m not in LIVE_MODELS]
    if unknown:
        raise InvalidParameterError(f"unknown live models {unknown}; choose from {LIVE_MODELS}.")
    check_scalar(steps, "steps", "warm_up", int, 1, 100)
    for n in places:
        check_scalar(n, "places", "warm_up", int, 200)
    rng = np.random.default_rng(0)
    dim = 16
    seconds = {f"{model}/{layout}": 0.0 for layout in layouts for model in models}
    for i, n in enumerate(places):
        descriptors = np.cumsum(rng.standard_normal((n, dim)), axis=0).astype(np.float32)
        the_map = CatgraphMap(descriptors, "sad", {"size": None, "patch": 0, "metric": "sad", "normalise": True},
                              PlaceGraph.chain(n), meta={"kind": "descriptors"})
        # the layouts differ in the difference row alone, which every size runs alike: the
        # larger maps (the filter's other regimes) in one layout
        for layout in layouts if i == 0 else layouts[:1]:
            live_map = LiveMap(the_map, layout=layout)
            for model in models:
                start = time.perf_counter()
                live = LiveLocalizer(live_map, model=model)  # the registry's filter for a map of this size
                for k in range(steps):
                    live.step(descriptors[100 + k])
                del live
                seconds[f"{model}/{layout}"] += time.perf_counter() - start
    # the particle filter's likelihood on maps of 2 · EXP_WORK_PER_THREAD places or more
    # (131,072: larger than the maps stepped here) forms its terms on two threads, with
    # kernels of their own, when a core is free
    from .localizer import likelihood_cumulative

    likelihood_cumulative(np.zeros(64), np.empty(64), 0.0, threads=2)
    return seconds


#: What :func:`warm_up_batch` runs: every registry method, the filter with every model
#: in both modes (the batch commands ``match``, ``localize``, ``compare`` and the demo).
BATCH_PLAN = (
    ("single-frame", {}),
    ("sequence", {"window": 10}),
    ("sequence", {"window": "adaptive"}),
    ("histogram", {"learning": "online", "n_init": 20}),
    ("histogram", {"learning": "bootstrap"}),
    *(("filter", {"model": model}) for model in FILTER_MODELS),  # mode auto: the grid on these maps
    *(("filter", {"model": model, "mode": "particles", "n_particles": 100}) for model in FILTER_MODELS),
    ("filter", {"model": "histogram", "mode": "particles", "motion": "frame", "n_particles": 100}),  # the demo's figure
)


def warm_up_batch(plan: tuple = BATCH_PLAN) -> dict[str, float]:
    """Compile (and cache on disk) the kernels of the batch methods once, on tiny inputs.

    Runs each ``(method, params)`` of ``plan`` through :func:`catgraph.experiment.run_method`
    twice: on a small synthetic image world (a place graph with junctions; SAD) and on a
    chain of random descriptors (the straight-route paths a map without positions
    takes; cosine), so a first ``catgraph demo``, ``match`` or ``localize`` after it loads its
    kernels instead of compiling them.

    Returns
    -------
    dict
        Seconds spent per ``"method/params/input"``.
    """
    from .datasets.synthetic import make_world
    from .experiment import prepared_from, run_method
    from .traverse import Traverse

    world = make_world(seed=0, blocks=(2, 2), as_images=True)
    rng = np.random.default_rng(0)
    chain = np.cumsum(rng.standard_normal((400, 16)), axis=0).astype(np.float32)
    inputs = {
        "graph": prepared_from(world.reference, world.query.take(np.arange(min(80, len(world.query)))),
                               junction_radius_m=world.junction_radius_m),
        "chain": prepared_from(Traverse(chain, meta={"kind": "descriptors"}, name="warm-up map"),
                               Traverse(chain[50:130] + 0.1 * rng.standard_normal((80, 16)).astype(np.float32),
                                        meta={"kind": "descriptors"}, name="warm-up query"),
                               frontend={"metric": "cosine"}),  # the graph world uses sad
    }
    seconds = {}
    for name, prepared in inputs.items():
        for method, params in plan:
            start = time.perf_counter()
            run_method(method, params, prepared)
            seconds[f"{method}/{','.join(f'{k}={v}' for k, v in params.items())}/{name}"] = time.perf_counter() - start
    return seconds
