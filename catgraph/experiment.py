"""One way to run a method: inputs → ground truth → condition → differences → method → result.

Every entry point — ``catgraph match``/``localize``/``compare``, ``catgraph bench`` and
its sweeps, the demo, the benchmarks — describes what to run as an :class:`Experiment`
and runs it through :func:`prepare` and :func:`run_method` (or :func:`run`, both at
once). The stages, each owned by one function:

1. **Inputs** (:func:`prepare`). The reference becomes a *map*
   (:class:`~catgraph.io.CatgraphMap`): either a saved map file, used as saved, or one
   built in memory from a reference traverse with :func:`catgraph.io.build_map` — the
   same function ``catgraph build-map`` saves — so a saved map and its reference folder
   give the same answers for every method. Front-end options (``size``, ``patch``,
   ``metric``, ``normalise``) and graph options (``junction_radius_m``) shape a map
   when it is built; with a saved map they are refused (its front-end and graph are
   fixed), and ``junction_radius_m`` without reference positions is refused too.
2. **Ground truth** (optional): a frame tolerance, a metric tolerance or a file
   (:func:`catgraph.datasets.ground_truth.load_ground_truth`), always about frames *as
   loaded*. Without one, a run still produces every frame's answer; only the metrics
   are missing. The method never sees it (except the ``trained`` histogram baseline,
   which is fitted from it by definition).
3. **Condition** (:class:`~catgraph.conditions.Condition`): the query in order,
   shuffled, reversed or at another speed; ground truth follows the frames.
4. **Differences**: the query through the map's own front-end (described once, in
   :func:`prepare`) against the map's descriptors, normalised per query. Every method
   walks them block by block as it reads them (:meth:`Prepared.difference_rows`,
   :func:`catgraph.io.query_difference_rows`: about 32 MiB of rows at a time), so a run
   never holds the ``n_query × N`` matrix, whatever the query's length; the matrix
   (:attr:`Prepared.differences`, :func:`catgraph.io.query_differences`, the same bits)
   is made only where it is read, and then kept. The ``¬L`` samples that bootstrapped
   models learn from come from the map too, by sampled pairs
   (:meth:`Prepared.bootstrap_samples`), computed once and only when needed.
5. **Method** (:mod:`catgraph.methods`): by name, with its checked parameters.
6. **Result**: a :class:`~catgraph.results.RunResult`, its evaluation where there is
   ground truth, and the JSON payload every command writes (:func:`payload`).

An experiment is plain data (:meth:`Experiment.from_spec` / :meth:`Experiment.spec`),
so sweeps can run it in any process or on any Dask worker: same spec, same result.

A map too large for one machine
-------------------------------
:func:`run_on_cluster` runs a ``sequence`` experiment on a Dask cluster
(``catgraph match --scheduler ADDRESS``): stages 1–3 as above, then the map's
descriptors are sharded over the workers (:mod:`catgraph.distributed`) and stage 4
happens there — difference rows, normalisation and window scores are computed where
the shards live, and only per-frame matches return. No ``n_query × N`` matrix exists
anywhere; the matches are those of :func:`run` on one machine (tested).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .conditions import Condition
from .environment import environment
from .exceptions import ConfigError, InvalidParameterError
from .methods import get_method
from .pipeline import FrontEnd
from .results import RunResult
from .traverse import FrameTolerance, GroundTruth, MetricTolerance, Traverse

if TYPE_CHECKING:  # pragma: no cover
    from .differences import DifferenceRows
    from .graph import PlaceGraph
    from .io import CatgraphMap
    from .metrics import Evaluation

__all__ = ["Experiment", "Prepared", "MethodInputs", "prepare", "prepared_from", "run_method", "run", "payload", "run_experiment",
           "run_on_cluster", "load_input", "SPEC_KEYS", "FRONTEND_KEYS"]

SPEC_KEYS = ("name", "reference", "map", "query", "method", "params", "tolerance", "tolerance_m", "ground_truth",
             "condition", "frontend", "junction_radius_m")
#: the front-end's settings (their one owner: :attr:`catgraph.pipeline.FrontEnd.KEYS`)
FRONTEND_KEYS = FrontEnd.KEYS


# ---------------------------------------------------------------------------- sources
@lru_cache(maxsize=4)
def synthetic_world(seed: int):
    """The built-in synthetic world for ``seed`` (cached: it is immutable)."""
    from .datasets.synthetic import make_world

    return make_world(seed=seed)


def is_synthetic_name(text: str) -> bool:
    """``"synthetic"`` or ``"synthetic:SEED"``: the built-in world, not a path (``synthetic_gt.csv`` is one)."""
    return text == "synthetic" or text.startswith("synthetic:")


def _synthetic_seed(text: str) -> int | None:
    """The seed of ``"synthetic"``/``"synthetic:SEED"``; ``None`` for anything else."""
    if not is_synthetic_name(text):
        return None
    _, _, seed = text.partition(":")
    if seed and not seed.isdigit():
        raise InvalidParameterError(f"{text!r}: write the synthetic world as 'synthetic' or 'synthetic:SEED' "
                                    "(SEED an integer ≥ 0).")
    return int(seed or 0)


def load_input(source: str | Path | Traverse, role: str, fps: float | None = None) -> Traverse:
    """A traverse from a path, from ``"synthetic[:SEED]"`` (the built-in world), or as given.
    ``fps``: a video's frames kept per second, for a video file only (others are refused)."""
    from .datasets.video import is_video

    if fps is not None and not is_video(source):
        raise InvalidParameterError(f"fps (--fps) picks the frames of a video; the {role} is not one. Leave it out.")
    if isinstance(source, Traverse):
        return source
    text = str(source)
    seed = _synthetic_seed(text)
    if seed is not None:
        world = synthetic_world(seed)
        return world.reference if role == "reference" else world.query
    from .datasets import load_traverse

    return load_traverse(source, fps=fps)


def _video_fps(exp: Experiment, map_fps: float | None) -> float | None:
    """The frames per second the experiment's video inputs are read at: the front-end's (a
    map's own where the map is saved); refused where it was given and no input is a video."""
    from .datasets.video import is_video

    given = (exp.frontend or {}).get("fps")
    if given is not None and not any(is_video(s) for s in (exp.reference, exp.query)):
        raise InvalidParameterError("fps (--fps) picks the frames of a video, and neither the reference nor the "
                                    "query is one; leave it out.")
    return given if exp.map is None else map_fps


# ---------------------------------------------------------------------------- the description
@dataclass(frozen=True)
class Experiment:
    """What to run: inputs, optional ground truth, condition, front-end, method.

    Parameters
    ----------
    query : path, ``"synthetic[:SEED]"`` or Traverse
    method : str
        A name in :data:`catgraph.methods.METHODS`.
    params : dict
        The method's parameters (checked; defaults filled in).
    reference : path, ``"synthetic[:SEED]"`` or Traverse, optional
        The reference traverse; exactly one of ``reference`` and ``map``.
    map : path or CatgraphMap, optional
        A saved map (``catgraph build-map``).
    tolerance : int, optional
        Ground truth: the same index ± ``tolerance`` frames is the same place.
    tolerance_m : float, optional
        Ground truth: positions within ``tolerance_m`` metres (and the same floor).
    ground_truth : path, optional
        Ground truth from a file (pairs CSV or matrix).
    condition : Condition
        How the query is driven (default: in order).
    frontend : dict, optional
        Front-end settings (``size``, ``patch``, ``metric``, ``normalise``) for a map
        built from ``reference``.
    junction_radius_m : float, optional
        Join places of different parts of the route within this many metres (a map built
        from a reference with positions).
    name : str, optional
        A label for sweeps and reports.
    """

    query: Any
    method: str = "single-frame"
    params: dict = field(default_factory=dict)
    reference: Any = None
    map: Any = None
    tolerance: int | None = None
    tolerance_m: float | None = None
    ground_truth: Any = None
    condition: Condition = Condition()
    frontend: dict | None = None
    junction_radius_m: float | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        if (self.reference is None) == (self.map is None):
            raise InvalidParameterError("give a reference traverse or a saved map (exactly one of them).")
        given = [k for k, v in (("tolerance", self.tolerance), ("tolerance_m", self.tolerance_m),
                                ("ground_truth", self.ground_truth)) if v is not None]
        if len(given) > 1:
            raise InvalidParameterError(f"give one ground truth, not {' and '.join(given)}.")
        if self.tolerance is not None and (isinstance(self.tolerance, (bool, np.bool_))
                                           or not isinstance(self.tolerance, (int, np.integer)) or self.tolerance < 0):
            raise InvalidParameterError(f"the tolerance must be an int ≥ 0 (frames); got {self.tolerance!r}.")
        if self.tolerance is not None:
            object.__setattr__(self, "tolerance", int(self.tolerance))  # a numpy integer as the int it holds
        if self.tolerance_m is not None and not (_is_real(self.tolerance_m) and 0 <= self.tolerance_m < float("inf")):
            raise InvalidParameterError(f"the metric tolerance must be a number ≥ 0 (metres); got {self.tolerance_m!r}.")
        if self.tolerance_m is not None:
            object.__setattr__(self, "tolerance_m", float(self.tolerance_m))
        if self.map is not None:
            if self.frontend:
                raise InvalidParameterError(
                    f"front-end options ({', '.join(self.frontend)}) do not apply to a saved map: its front-end is "
                    "fixed when it is built (catgraph build-map); drop them or build a new map.")
            if self.junction_radius_m is not None:
                raise InvalidParameterError("junction_radius_m does not apply to a saved map: its place graph is "
                                            "fixed when it is built (catgraph build-map --junction-radius-m).")
        if self.frontend:
            unknown = sorted(set(self.frontend) - set(FRONTEND_KEYS))
            if unknown:
                raise InvalidParameterError(f"unknown front-end options {unknown}; allowed: {', '.join(FRONTEND_KEYS)}.")
        if self.junction_radius_m is not None and not (_is_real(self.junction_radius_m)
                                                       and 0 < self.junction_radius_m < float("inf")):
            raise InvalidParameterError(f"junction_radius_m must be a number > 0 (metres); got "
                                        f"{self.junction_radius_m!r}.")
        if not isinstance(self.condition, Condition):
            object.__setattr__(self, "condition", Condition.parse(self.condition) if isinstance(self.condition, str)
                               else Condition.from_dict(self.condition))
        # the method and its parameters are checked now, not after the inputs are loaded
        get_method(self.method).resolve(self.params)
        object.__setattr__(self, "params", dict(self.params or {}))

    # -- plain-data form --------------------------------------------------------------
    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> "Experiment":
        """From a JSON-ready dict with the keys :data:`SPEC_KEYS`."""
        unknown = sorted(set(spec) - set(SPEC_KEYS))
        if unknown:
            raise ConfigError(f"unknown run keys {unknown}; allowed: {', '.join(SPEC_KEYS)}.")
        if "query" not in spec:
            raise ConfigError("a run needs 'query'.")
        return cls(**{k: v for k, v in spec.items()})

    def spec(self) -> dict[str, Any]:
        """The JSON-ready dict :meth:`from_spec` reads (sources as strings)."""
        out: dict[str, Any] = {"query": _source_name(self.query), "method": self.method, "params": dict(self.params)}
        if self.reference is not None:
            out["reference"] = _source_name(self.reference)
        else:
            out["map"] = _source_name(self.map)
        for key in ("tolerance", "tolerance_m", "ground_truth", "frontend", "junction_radius_m", "name"):
            value = getattr(self, key)
            if value is not None:
                out[key] = str(value) if key == "ground_truth" else value
        out["condition"] = self.condition.as_dict()
        return out

    def with_method(self, method: str, params: dict | None = None) -> "Experiment":
        from dataclasses import replace

        return replace(self, method=method, params=dict(params or {}))


def _source_name(source: Any) -> str:
    if isinstance(source, Traverse):
        return source.name or "<traverse>"
    if hasattr(source, "descriptors"):
        return getattr(source, "name", "") or "<map>"
    return str(source)


# ---------------------------------------------------------------------------- prepared inputs
@dataclass(eq=False)
class Prepared:
    """An experiment's inputs, ready for any method (see :func:`prepare`).

    Attributes
    ----------
    map : CatgraphMap
        The reference, described (saved, or built in memory).
    reference : Traverse or None
        The reference traverse it was built from (``None`` for a saved map).
    query : Traverse
        The query under the experiment's condition, in processing order.
    differences : ndarray, shape (n_query, n_places)
        Query × map differences, normalised per query, in processing order: computed on
        first use and kept (``n_query × N`` float64). The methods read
        :meth:`difference_rows` instead, which walks them block by block and holds the
        matrix only where it is already kept.
    ground_truth : GroundTruth or None
    sources : dict
        What the inputs were (recorded in every result).
    """

    map: "CatgraphMap"
    reference: Traverse | None
    query: Traverse
    ground_truth: GroundTruth | None
    sources: dict
    junction_radius_m: float | None = None
    _graph: "PlaceGraph | None" = None
    _bootstrap: dict = field(default_factory=dict)
    _hubs: np.ndarray | None = None
    _differences: np.ndarray | None = None
    _described: tuple | None = None  # the query through the map's front-end: (descriptors, informative)

    @property
    def differences(self) -> np.ndarray:
        """The ``(n_query, N)`` difference matrix (computed once, then kept)."""
        if self._differences is None:
            from .io import query_differences

            self._differences = query_differences(self.map, self.query, self._described)
        return self._differences

    def difference_rows(self) -> "DifferenceRows":
        """The difference rows block by block (:class:`~catgraph.differences.DifferenceRows`):
        views of the matrix where it is kept, else computed a block at a time, never the
        whole matrix."""
        from .differences import DifferenceRows
        from .io import query_difference_rows

        if self._differences is not None:
            return DifferenceRows.of(self._differences)
        return query_difference_rows(self.map, self.query, self._described)

    def with_differences(self, differences: np.ndarray) -> "Prepared":
        """The same inputs with this difference matrix kept (rows in processing order, shape
        ``(n_query, N)``): for benchmarks that edit the rows."""
        from dataclasses import replace

        d = np.asarray(differences)
        if d.shape != (len(self.query), self.map.n_places):
            from .exceptions import ShapeMismatchError

            raise ShapeMismatchError(f"the differences have shape {d.shape}; expected (n_query, n_reference) = "
                                     f"({len(self.query)}, {self.map.n_places}).")
        return replace(self, _differences=d)

    def graph(self) -> "PlaceGraph":
        """The place graph: the saved map's, or built from the reference (once)."""
        if self._graph is None:
            from .exceptions import DataError
            from .io import place_graph

            if self.reference is None:
                raise DataError("this map was saved without a place graph (build-map --no-graph); the particle "
                                "filter needs one: build the map again without --no-graph.")
            self._graph = place_graph(self.reference, self.junction_radius_m)
        return self._graph

    def bootstrap_samples(self, gap: int, max_different: int, seed: int) -> np.ndarray:
        """``¬L`` samples from the map: normalised differences between places more than
        ``gap`` apart, drawn by sampled pairs (never an ``N × N`` matrix; computed once per
        setting). See :func:`catgraph.live.map_bootstrap_samples`."""
        key = (gap, max_different, seed)
        if key not in self._bootstrap:
            from .live import map_bootstrap_samples

            self._bootstrap[key] = map_bootstrap_samples(self.map, gap, max_different, seed)[0]
        return self._bootstrap[key]

    def hub_offsets(self) -> np.ndarray:
        """The map's hub offsets (:func:`catgraph.hubs.map_hub_offsets`; computed once)."""
        if self._hubs is None:
            from .hubs import map_hub_offsets

            self._hubs = map_hub_offsets(self.map)
        return self._hubs

    def under(self, condition: Condition) -> "Prepared":
        """The same inputs with the query driven under ``condition`` (from the query as loaded)."""
        from dataclasses import replace

        if self.query.meta.get("traversal") is not None:
            raise InvalidParameterError("apply a condition to inputs whose query is in order as loaded.")
        # each row depends on its own frame only: the rows (or the described frames) reordered
        order = condition.order(len(self.query))
        described = None if self._described is None else tuple(a[order] for a in self._described)
        kept = None if self._differences is None else self._differences[order]
        return replace(self, query=condition.apply(self.query), _differences=kept, _described=described)


def prepared_from(reference: Traverse, query: Traverse, differences: np.ndarray | None = None,
                  ground_truth: GroundTruth | None = None, frontend: dict | None = None,
                  junction_radius_m: float | None = None) -> Prepared:
    """Prepared inputs from loaded traverses (and, optionally, their difference matrix).

    For benchmarks and notebooks that compute a difference matrix once and run many
    methods or conditions on it (:meth:`Prepared.under`). ``differences`` must be what
    :func:`catgraph.io.query_differences` gives for ``query`` against ``reference``'s map.
    """
    from .io import build_map, query_differences

    the_map = build_map(reference, FrontEnd.from_dict(frontend), graph=False)
    d = query_differences(the_map, query) if differences is None else np.asarray(differences)
    if d.shape != (len(query), the_map.n_places):
        from .exceptions import ShapeMismatchError

        raise ShapeMismatchError(f"the differences have shape {d.shape}; expected (n_query, n_reference) = "
                                 f"({len(query)}, {the_map.n_places}).")
    return Prepared(the_map, reference, query, ground_truth,
                    {"reference": _source_name(reference), "query": _source_name(query)},
                    junction_radius_m=junction_radius_m, _differences=d)


@dataclass(frozen=True, eq=False)
class MethodInputs:
    """What a method may read: the map, the query, the differences (and the graph)."""

    prepared: Prepared
    ground_truth: GroundTruth | None = None  # the ``trained`` baseline only
    progress: bool = False

    @property
    def map(self) -> "CatgraphMap":
        return self.prepared.map

    @property
    def query(self) -> Traverse:
        return self.prepared.query

    @property
    def differences(self) -> np.ndarray:
        return self.prepared.differences

    def difference_rows(self) -> "DifferenceRows":
        return self.prepared.difference_rows()

    def graph(self) -> "PlaceGraph":
        return self.prepared.graph()

    def bootstrap_samples(self, gap: int, max_different: int, seed: int) -> np.ndarray:
        return self.prepared.bootstrap_samples(gap, max_different, seed)

    def hub_offsets(self) -> np.ndarray:
        return self.prepared.hub_offsets()


def _is_real(value) -> bool:
    """A real number: a Python or numpy int or float, not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def check_frame_pairing(reference: Traverse, query: Traverse) -> int:
    """Warn (:class:`~catgraph.exceptions.CatgraphWarning`) where a frame tolerance's
    pairing by index (query frame ``i`` is reference frame ``i``) disagrees with the frames'
    names: both traverses name their frames (``ids``, e.g. file names), the query's names
    are among the reference's, and some query frame's name is not that of the reference
    frame of its index — a frame missing from one folder shifts every later pair, and the
    figures come out wrong without a sign. Traverses that name their frames each their own
    way say nothing. Returns the number of query frames whose pair disagrees."""
    if reference.ids is None or query.ids is None:
        return 0
    ref_ids, qry_ids = np.asarray(reference.ids).astype(str), np.asarray(query.ids).astype(str)
    shared = np.isin(qry_ids, ref_ids)
    if not shared.any():
        return 0
    index = np.asarray(query.index)
    inside = index < len(ref_ids)
    paired = np.where(inside, ref_ids[np.minimum(index, len(ref_ids) - 1)], "")
    differ = shared & (~inside | (qry_ids != paired))
    n = int(differ.sum())
    if n:
        from .exceptions import warn

        k = int(np.flatnonzero(differ)[0])
        at = f"reference frame {index[k]} is {str(paired[k])!r}" if inside[k] else \
            f"the reference has no frame {index[k]}"
        warn(f"the frame tolerance pairs query frame i with reference frame i, but {n} of {len(qry_ids)} "
             f"query frames carry the name of another reference frame (query frame {index[k]} is "
             f"{str(qry_ids[k])!r}; {at}): a frame missing from one folder shifts every later pair. Check the "
             "folders, or give the pairs as a ground-truth file.")
    return n


def _ground_truth(exp: Experiment, reference, query: Traverse, n_places: int) -> GroundTruth | None:
    """The experiment's ground truth; ``reference``: the reference :class:`Traverse` or the
    :class:`~catgraph.io.CatgraphMap` (of either, the places' ``positions``, ``floors`` and
    ``ids`` are read)."""
    if exp.tolerance is not None:
        check_frame_pairing(reference, query)
        return FrameTolerance(n_places, exp.tolerance)
    tolerance_m = exp.tolerance_m
    if tolerance_m is None and exp.ground_truth is None:
        # the synthetic world knows its own tolerance (an evaluation default only)
        seed = _synthetic_seed(str(exp.query)) if isinstance(exp.query, (str, Path)) else None
        if seed is None:
            return None
        # only against that world's own reference: another world's, or a reference without
        # positions, is not scored by default (it was: AUC 0 against the wrong streets, or an error)
        other = _synthetic_seed(str(exp.reference)) if isinstance(exp.reference, (str, Path)) else None
        if (isinstance(exp.reference, (str, Path)) and other != seed) or reference.positions is None \
                or query.positions is None:
            return None
        tolerance_m = synthetic_world(seed).tolerance_m
    if tolerance_m is not None:
        return MetricTolerance.between(query, reference, float(tolerance_m))
    from .datasets.ground_truth import load_ground_truth

    return load_ground_truth(exp.ground_truth, len(query), n_places)


def _inputs(exp: Experiment, descriptors: str = "memory", graph: bool = True) -> tuple:
    """Stages 1–2: ``(map, reference or None, graph or None, sources, query, ground_truth)``.
    ``descriptors``, ``graph``: how a map file is loaded (:func:`catgraph.io.load_map`)."""
    from .datasets.video import is_video
    from .io import build_map, load_map

    if exp.map is not None:
        the_map = exp.map if hasattr(exp.map, "descriptors") else load_map(exp.map, descriptors=descriptors, graph=graph)
        fps = _video_fps(exp, the_map.frontend_settings().fps)
    else:
        fps = _video_fps(exp, None)
    query = load_input(exp.query, "query", fps if is_video(exp.query) else None)
    if exp.map is not None:
        reference = None
        graph = the_map.graph
        sources = {"map": _source_name(exp.map)}
    else:
        from .pipeline import check_image_options

        reference = load_input(exp.reference, "reference", fps if is_video(exp.reference) else None)
        if exp.junction_radius_m is not None and reference.positions is None:
            raise InvalidParameterError("junction_radius_m joins places by position, but the reference has no "
                                        "positions; leave it out.")
        # an option given explicitly is refused where it does not apply, its default value too
        check_image_options(reference, {k for k in FrontEnd.IMAGE_KEYS if (exp.frontend or {}).get(k) is not None})
        frontend = FrontEnd.from_dict(exp.frontend)
        the_map = build_map(reference, frontend, graph=False)
        graph = None
        sources = {"reference": _source_name(exp.reference)}
    sources["query"] = _source_name(exp.query)
    # a map's places: its positions, floors and ids (CatgraphMap carries them), never its descriptors
    ground_truth = _ground_truth(exp, reference if reference is not None else the_map, query, the_map.n_places)
    return the_map, reference, graph, sources, query, ground_truth


def prepare(exp: Experiment) -> Prepared:
    """Load and describe an experiment's inputs (stages 1–4 of the module docstring): the
    query is described through the map's front-end here (a query the map cannot compare
    is refused here); its difference rows are computed when a method reads them."""
    from .io import describe_query

    the_map, reference, graph, sources, query, ground_truth = _inputs(exp)
    # the condition reorders the frames before they are described: each difference row
    # depends on its own frame only, so this equals Prepared.under
    if exp.condition.kind != "in-order":
        if query.meta.get("traversal") is not None:  # a second condition on a driven query: one would be lost
            raise InvalidParameterError(
                f"the query is already driven under {query.meta['traversal']}; give the query as loaded with the "
                f"condition {exp.condition.label!r}, or leave the condition out.")
        query = exp.condition.apply(query)
    return Prepared(the_map, reference, query, ground_truth, sources, junction_radius_m=exp.junction_radius_m,
                    _graph=graph, _described=describe_query(the_map, query))


# ---------------------------------------------------------------------------- running
def run_method(method: str, params: dict | None, prepared: Prepared, progress: bool = False) -> RunResult:
    """Run method ``method`` with ``params`` on prepared inputs (stage 5)."""
    if not isinstance(prepared, Prepared):
        raise InvalidParameterError("run_method needs the inputs as catgraph.experiment.prepare gives them "
                                    f"(a Prepared); got {type(prepared).__name__}.")
    m = get_method(method)
    resolved = m.resolve(params)
    trained = method == "histogram" and resolved.get("learning") == "trained"
    inputs = MethodInputs(prepared, prepared.ground_truth if trained else None, progress)
    return m.run(resolved, inputs)


def payload(result: RunResult, prepared: Prepared, exp: Experiment | None = None) -> tuple[dict, "Evaluation | None"]:
    """The result JSON every command writes, and the evaluation (``None`` without ground truth)."""
    evaluation = result.evaluate(prepared.ground_truth) if prepared.ground_truth is not None else None
    result.params.update(prepared.sources)
    result.params.update({
        "condition": prepared.query.meta.get("traversal", {"kind": "in-order"}),
        "frontend": {**prepared.map.frontend, "metric": prepared.map.metric},
        "ground_truth": None if prepared.ground_truth is None else prepared.ground_truth.describe(),
    })
    if prepared.junction_radius_m is not None:
        result.params["junction_radius_m"] = prepared.junction_radius_m
    out = result.to_dict(evaluation)
    if exp is not None and exp.name:
        out["name"] = exp.name
    out["environment"] = environment()  # the versions and the compile target behind the numbers
    return out, evaluation


def run(exp: Experiment, progress: bool = False) -> tuple[RunResult, dict, "Evaluation | None"]:
    """Prepare, run and evaluate one experiment: ``(result, payload, evaluation)``."""
    prepared = prepare(exp)
    result = run_method(exp.method, exp.params, prepared, progress=progress)
    out, evaluation = payload(result, prepared, exp)
    return result, out, evaluation


def _cluster_params(exp: Experiment) -> dict:
    """The resolved ``sequence`` parameters (another method is refused: the cluster path
    does sequence matching only)."""
    if exp.method != "sequence":
        raise InvalidParameterError(
            f"a cluster run (--scheduler) does sequence matching; got method {exp.method!r}. Give "
            "--window N (N ≥ 2) or --window adaptive, or run without --scheduler.")
    return get_method("sequence").resolve(exp.params)


def run_on_cluster(exp: Experiment, scheduler, shard_places: int | None = None,
                   block_rows: int = 256, layout: str = "float32") -> tuple[RunResult, dict, "Evaluation | None"]:
    """Run a ``sequence`` experiment with the map sharded over a Dask cluster.

    Parameters
    ----------
    exp : Experiment
        Method ``sequence`` (a fixed or the adaptive ``window``, any ``velocities``; the
        hub offsets, when asked for, are computed on the cluster from the map's shards,
        :func:`catgraph.distributed.map_hub_offsets`, the same as locally); a map whose
        differences are normalised. A map given as its file is never read whole here:
        its descriptors stay in the file (:func:`catgraph.io.load_map` with
        ``descriptors="stream"``; its place graph is checked, not built), each shard is
        read and sent on its own, and the hub offsets read the sampled frames alone.
    scheduler : str or distributed.Client
        A scheduler address (``"tcp://host:8786"``) or a client.
    shard_places : int, optional
        Places per shard (default: the map split evenly over the workers).
    block_rows : int
        Query frames per round trip.
    layout : {"float32", "uint8"}
        How workers hold their shards (:func:`catgraph.distributed.shard_reference`):
        ``"uint8"`` in a quarter of the memory, with the differences of the compact layout
        (then the answers are those of the local matcher on
        ``PreparedReference(descriptors, metric, "uint8")``, not of the float run).

    Returns
    -------
    (RunResult, payload, Evaluation or None)
        As :func:`run`: the same matches, scores and confidences (bit for bit while each
        row's moment sum stays below 2**53; see :mod:`catgraph.distributed`).
    """
    import time

    from .distributed import (_client, check_cluster_rule, map_hub_offsets, match_adaptive_window, match_fixed_window,
                              shard_reference)
    from .methods import _WINDOW_ADAPTIVE, check_sequence_length, sequence_run_name
    from .io import describe_query

    params = _cluster_params(exp)
    # a map file's descriptors stay in the file (each shard is read and sent on its own), and its
    # place graph, which matching never reads, is not built
    the_map, reference, graph, sources, query, ground_truth = _inputs(exp, descriptors="stream", graph=False)
    if not the_map.frontend_settings().normalise:
        raise InvalidParameterError("a cluster run normalises every difference row; this map was built with "
                                    "normalise off: build it again with normalisation, or run without --scheduler.")
    if exp.condition.kind != "in-order":
        query = exp.condition.apply(query)
    adaptive = params["window"] == "adaptive"
    check_sequence_length(params, len(query))
    if adaptive:
        check_cluster_rule(params["rule"], "a cluster run")
    q, informative = describe_query(the_map, query)
    start = time.perf_counter()
    client = _client(scheduler)
    try:
        sharded = shard_reference(the_map.descriptors, the_map.metric, client, shard_places, layout=layout)
        common = {"radius": int(params["exclusion"]), "velocities": tuple(params["velocities"]),
                  "block_rows": block_rows, "no_information": ~informative,
                  "hub_offsets": map_hub_offsets(sharded, the_map.descriptors) if params["hub_correction"] else None}
        if adaptive:
            res = match_adaptive_window(q, sharded, **{k: params[k] for k in _WINDOW_ADAPTIVE}, **common)
        else:
            res = match_fixed_window(q, sharded, int(params["window"]), **common)
    finally:
        if client is not scheduler:  # a client made here from an address is closed here
            client.close()
    result = RunResult(sequence_run_name(params), dict(params), query.index,
                       res.match, res.confidence, extra={"window_length": res.window_length},
                       seconds=time.perf_counter() - start)
    prepared = Prepared(the_map, reference, query, ground_truth, sources, junction_radius_m=exp.junction_radius_m,
                        _graph=graph)
    out, evaluation = payload(result, prepared, exp)
    return result, out, evaluation


def run_experiment(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one plain-data spec (:meth:`Experiment.from_spec`) and return its payload (for sweeps)."""
    return run(Experiment.from_spec(spec))[1]
