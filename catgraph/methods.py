"""The registry of localisation methods: every name, parameter and choice, once.

A *method* turns a prepared reference (a :class:`~catgraph.io.CatgraphMap`), a query
traverse and the query × reference difference matrix into per-frame matches and
confidences (:class:`~catgraph.results.RunResult`). Every entry point — the CLI
commands, experiment configurations, sweeps, the demo and the benchmarks — runs methods
through :func:`catgraph.experiment.run` and so through this registry; the CLI builds its
options and the configuration checker its checks from the :class:`Param` declarations
here, so a name or a choice exists in one place only.

Methods
-------
``single-frame``
    The nearest reference place per query frame; confidence = margin to the best place
    outside ``± exclusion`` places.
``sequence``
    SeqSLAM sequence matching with a fixed ``window`` or the adaptive window of paper 1
    (``window="adaptive"``; then ``approximation``, ``rule``, ``l_min``, ``l_max``,
    ``grid`` apply).
``histogram``
    Single-frame recognition with paper 2's histogram model P(d|L), P(d|¬L), learned
    ``online`` (training-free), ``bootstrap`` (from the map's own frames) or ``trained``
    (fitted from the labelled query: an oracle baseline, the only method that reads
    ground truth).
``filter``
    A Bayes filter on the map's place graph with observation ``model`` (see
    :data:`FILTER_MODELS`; default ``tempered``, the hub-corrected whole-image evidence
    tempered by the filter's own answers): the exact grid filter over (place, velocity)
    (``mode="grid"``) or the CAT-Graph particle filter (``mode="particles"``,
    signed-velocity motion by default); ``mode="auto"`` (default) takes the grid up to
    :data:`GRID_MAX_PLACES` places and particles above. ``model="combined"`` adds the
    adaptive sequence matcher's evidence to the tempered whole-image evidence, its ratios
    tempered by how often the filter confirms the matcher's best place and each frame counted
    at most once (one over the longest window so far); ``"histogram-combined"`` is paper 2's product of the bootstrapped
    histogram model and the sequence scores' online histograms. The observation model's options
    (``window``, ``approximation``, ``n_init`` …) are parameters of the filter method,
    so a sweep can vary them.

A method's parameters belong to the method: none is derived from the evaluation (the
filter's ``confidence_radius`` is its own, in places, whatever tolerance the run is
scored with). A parameter that does not apply to the chosen variant (``rule`` with a
fixed window, ``window`` with the ``adaptive`` model) is refused, not ignored.
"""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .exceptions import InvalidParameterError
from .results import RunResult

if TYPE_CHECKING:  # pragma: no cover
    from .experiment import MethodInputs

__all__ = ["Param", "Method", "METHODS", "FILTER_MODELS", "get_method", "resolve_params"]

#: Observation models of the particle filter.
FILTER_MODELS = ("tempered", "histogram", "histogram-bootstrap", "sequence", "adaptive", "combined",
                 "histogram-combined")
_LEARNING = ("online", "bootstrap", "trained")


# ---------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Param:
    """One method parameter: its type, range or choices, default and help.

    ``kind`` is ``"int"``, ``"float"``, ``"bool"``, ``"str"`` (with ``choices``),
    ``"window"`` (an int ≥ 1 or ``"adaptive"``), ``"grid"`` (``"geometric"``, ``"all"``,
    an int ≥ 1 or a list of ints ≥ 1) or ``"floats"`` (a list of at most ``high``, default
    64, finite numbers: velocities). ``default=None`` with ``optional=True`` means
    "not set" (the method decides). ``flag`` is the command-line option.
    """

    name: str
    kind: str
    default: Any
    help: str
    choices: tuple | None = None
    low: float | None = None
    high: float | None = None
    optional: bool = False
    flag: str | None = None

    @property
    def _max_count(self) -> int:
        """``"floats"``: the most values a list may hold (``high``, default 64)."""
        return int(self.high) if self.high is not None else 64

    @property
    def option(self) -> str:
        return self.flag or "--" + self.name.replace("_", "-")

    def describe(self) -> str:
        """What a valid value is, in words."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind == "window":
            return "an int ≥ 1 or 'adaptive'"
        if self.kind == "grid":
            return "'geometric', 'all', an int ≥ 1 or a list of ints ≥ 1"
        if self.kind == "bool":
            return "true or false"
        if self.kind == "floats":
            from .sequence import MAX_VELOCITY

            return f"a list of 1 to {self._max_count} distinct numbers in [-{MAX_VELOCITY:g}, {MAX_VELOCITY:g}]"
        what = {"int": "an int", "float": "a number", "str": "a string"}[self.kind]
        if self.low is not None and self.high is not None:
            return f"{what} in [{self.low:g}, {self.high:g}]"
        if self.low is not None:
            return f"{what} ≥ {self.low:g}"
        return what

    def check(self, value: Any, owner: str, label: str | None = None) -> Any:
        """``value`` converted to the parameter's type; :class:`InvalidParameterError` if invalid.

        ``label`` names the value in the message (default ``"The 'NAME' parameter of OWNER"``).
        """
        if value is None and self.optional:
            return None

        def bad() -> InvalidParameterError:
            what = label or f"The '{self.name}' parameter of {owner}"
            return InvalidParameterError(f"{what} must be {self.describe()}. Got {value!r} instead.")

        is_int = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        if self.kind == "window":
            if value == "adaptive":
                return value
            if not is_int or value < 1:
                raise bad()
            return int(value)
        if self.kind == "grid":
            if value in ("geometric", "all"):
                return value
            if is_int and value >= 1:
                return int(value)
            if isinstance(value, (list, tuple)) and value and all(
                    isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in value):
                return [int(v) for v in value]
            raise bad()
        if self.kind == "floats":  # the velocities of the sequence lines
            from .sequence import MAX_VELOCITY

            ok = isinstance(value, (list, tuple)) and 0 < len(value) <= self._max_count and all(
                isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)
                and abs(v) <= MAX_VELOCITY for v in value)
            ok = ok and len({float(v) for v in value}) == len(value)
            if not ok:
                raise bad()
            return [float(v) for v in value]
        if self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise bad()
            return bool(value)
        if self.kind == "str":
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise bad()
            return value
        if self.kind == "int":
            if not is_int:
                raise bad()
            value = int(value)
        elif self.kind == "float":
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise bad()
            value = float(value)
            if not math.isfinite(value):
                raise bad()
        if (self.low is not None and value < self.low) or (self.high is not None and value > self.high):
            raise bad()
        return value


# shared declarations: one per concept, reused by every method that has it
_EXCLUSION = Param("exclusion", "int", 10, "confidence = margin to the best match outside ± this many places",
                   low=0, high=1_000_000)
_WINDOW_ADAPTIVE = ("approximation", "rule", "l_min", "l_max", "grid", "recent_fraction")


def _sequence_params(window_default: Any, window_optional: bool = False) -> tuple[Param, ...]:
    import inspect

    from .sequence import APPROXIMATIONS, RULES, match_sequences

    default = {k: v.default for k, v in inspect.signature(match_sequences).parameters.items()}  # one owner
    return (
        Param("window", "window", window_default,
              "sequence length in frames, or 'adaptive' (paper 1: chosen per frame)", optional=window_optional),
        Param("approximation", "str", default["approximation"],
              "adaptive window: approximation of the score distribution", choices=APPROXIMATIONS),
        Param("rule", "str", default["rule"], "adaptive window: how the window length is chosen (see docs/sequence.md)",
              choices=RULES),
        Param("l_min", "int", default["l_min"], "adaptive window: shortest window", low=1, high=100_000),
        Param("l_max", "int", default["l_max"], "adaptive window: longest window", low=1, high=100_000),
        Param("grid", "grid", default["grid"],
              "adaptive window: candidate lengths ('geometric', 'all', a count or a list)"),
        Param("recent_fraction", "float", default["recent_fraction"], "adaptive window: sub-windows from this "
              "fraction of the window are tested for a discontinuity (0: every shorter one)", low=0.0, high=1.0),
    )


def _velocity_params() -> tuple[Param, ...]:
    import inspect

    from .sequence import match_sequences

    velocities = inspect.signature(match_sequences).parameters["velocities"].default
    return (
        Param("velocities", "floats", list(velocities), "slopes of the sequence lines searched, in places per frame "
              "(negative: driven backwards; 1 alone: the classic SeqSLAM diagonal)"),
        Param("hub_correction", "bool", True, "correct outlying hub references found in the map (catgraph.hubs)"),
    )


def _histogram_params() -> tuple[Param, ...]:
    return (
        Param("n_init", "int", 100, "online learning: initialisation frames T_init", low=1, high=1_000_000,
              flag="--init-frames"),
        Param("exclusion_radius", "int", 5, "places around the best match that do not give ¬L samples",
              low=0, high=1_000_000),
        Param("n_bins", "int", 100, "histogram bins", low=2, high=100_000),
        Param("same_place_m", "float", None, "reference places within METRES count as the same place (needs "
              "positions; default: ± a few places along the route)", low=0.0, optional=True),
        Param("gap", "int", None, "bootstrap: reference frames more than GAP places apart are different places",
              low=1, optional=True),
        Param("max_different", "int", 100_000, "bootstrap: ¬L samples drawn from the map", low=1, high=10_000_000),
    )


# ---------------------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """A registered method: its parameters and the function that runs it."""

    name: str
    summary: str
    params: tuple[Param, ...]
    run: Callable[[dict, "MethodInputs"], RunResult]
    not_applicable: Callable[[dict], dict[str, str]] = field(default=lambda p: {})
    #: checks across parameters that need no data (``l_min`` ≤ ``l_max`` …): a sweep is refused at once
    check: Callable[[dict, set], None] = field(default=lambda p, given: None)

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)

    def resolve(self, params: Mapping[str, Any] | None) -> dict[str, Any]:
        """Every parameter, checked, defaults filled in; unknown or inapplicable ones refused."""
        params = dict(params or {})
        owner = f"method {self.name!r}"
        known = {p.name: p for p in self.params}
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise InvalidParameterError(f"{owner} has no parameter{'s' if len(unknown) > 1 else ''} "
                                        f"{', '.join(repr(u) for u in unknown)}; its parameters: "
                                        f"{', '.join(known)}.")
        out = {name: p.check(params[name], owner) if name in params else p.default for name, p in known.items()}
        refused = self.not_applicable(out)
        given = [name for name in params if name in refused and params[name] is not None]
        if given:
            name = given[0]
            raise InvalidParameterError(f"'{name}' does not apply to {owner} here: {refused[name]}.")
        out = {name: value for name, value in out.items() if name not in refused}
        self.check(out, {name for name, value in params.items() if value is not None})
        return out


def _single_frame(params: dict, inputs: "MethodInputs") -> RunResult:
    from .matching import best_matches

    start = time.perf_counter()
    rows = inputs.difference_rows()
    match, confidence = np.empty(len(rows), dtype=np.int64), np.empty(len(rows))
    for first, block in rows.blocks():  # row by row: a block at a time, never the matrix
        match[first:first + len(block)], confidence[first:first + len(block)] = best_matches(
            block, exclusion=params["exclusion"])
    return RunResult("single-frame", dict(params), inputs.query.index, match, confidence,
                     seconds=time.perf_counter() - start)


def _sequence_kwargs(params: dict) -> dict:
    kwargs = {"window": params["window"], "velocities": tuple(params["velocities"])}
    if params["window"] == "adaptive":
        kwargs.update({k: params[k] for k in _WINDOW_ADAPTIVE})
    return kwargs


def check_sequence_length(params: dict, n_query: int) -> None:
    """Refuse a ``sequence`` run whose (shortest) window is longer than the query."""
    shortest = params["window"] if params["window"] != "adaptive" else params.get("l_min", 1)
    if isinstance(shortest, int) and shortest > n_query:
        what = "window" if params["window"] != "adaptive" else "l_min (the shortest adaptive window)"
        raise InvalidParameterError(f"{what} = {shortest} frames is longer than the query ({n_query} frames); "
                                    f"choose at most {n_query}.")


def sequence_run_name(params: dict) -> str:
    """The result name of a ``sequence`` run: ``adaptive`` or ``sequence-L<window>``."""
    return "adaptive" if params["window"] == "adaptive" else f"sequence-L{params['window']}"


def _sequence(params: dict, inputs: "MethodInputs") -> RunResult:
    from .sequence import match_sequences

    check_sequence_length(params, len(inputs.query))
    start = time.perf_counter()
    hubs = inputs.hub_offsets() if params["hub_correction"] else None
    res = match_sequences(inputs.difference_rows(), radius=params["exclusion"], hub_offsets=hubs,
                          **_sequence_kwargs(params))
    return RunResult(sequence_run_name(params), dict(params), inputs.query.index, res.match, res.confidence,
                     extra={"window_length": res.window_length}, seconds=time.perf_counter() - start)


def _not_adaptive(params: dict) -> dict[str, str]:
    if params.get("window") == "adaptive":
        return {}
    return {k: "it sets the adaptive window; give window 'adaptive' or leave it out" for k in _WINDOW_ADAPTIVE}


def _check_sequence(params: dict, given: set) -> None:
    """The ``sequence`` method's checks across parameters."""
    _check_window_range(params)
    if params.get("window") == "adaptive" and params.get("rule") == "tracked":
        reads = {"exclusion": "exclusion around the best match", "recent_fraction": "recent sub-windows"}
        for name in sorted(given & set(reads)):  # its confidence is its tracking filter's mass
            raise InvalidParameterError(
                f"'{name}' does not apply to method 'sequence' here: rule 'tracked' takes its confidence from its "
                f"tracking filter, which reads no {reads[name]}; choose another rule (e.g. 'challenged') to set it, "
                f"or leave '{name}' out.")


def _check_window_range(params: dict) -> None:
    """``l_min`` ≤ ``l_max`` where both apply."""
    lo, hi = params.get("l_min"), params.get("l_max")
    if lo is not None and hi is not None and lo > hi:
        raise InvalidParameterError(f"'l_min' ({lo}) is longer than 'l_max' ({hi}): the adaptive window's shortest "
                                    "length must not exceed its longest.")


def _check_filter(params: dict, given: set) -> None:
    """The ``filter`` method's checks across parameters."""
    _check_window_range(params)
    graduation = params.get("jump_graduation")
    if graduation is None:
        return
    if graduation <= 0.0:
        raise InvalidParameterError(f"'jump_graduation' must lie in (0, 1] (1: no jump grid); got {graduation}.")
    proposal = _proposal(params)
    if graduation < 1.0 and proposal != "likelihood":
        raise InvalidParameterError(f"'jump_graduation' below 1 draws the births from the jump grid, which needs "
                                    f"proposal 'likelihood' (got {proposal!r}); give jump_graduation 1 or that "
                                    "proposal.")


def _same_place(params: dict, inputs: "MethodInputs") -> dict:
    """Histogram-model options for "the same place" by position (metres; floors 100 m apart)."""
    if params["same_place_m"] is None:
        return {}
    positions = inputs.map.positions
    if positions is None:
        raise InvalidParameterError("same_place_m needs reference positions; this reference has none.")
    if inputs.map.floors is not None:
        positions = np.column_stack([positions, 100.0 * inputs.map.floors])
    return {"reference_positions": positions, "confidence_distance": params["same_place_m"],
            "exclusion_distance": params["same_place_m"]}


def _bootstrap_gap(params: dict, n: int) -> int:
    """"Far apart along the route": ``gap`` places (:func:`catgraph.samples.default_bootstrap_gap`
    where unset)."""
    from .samples import default_bootstrap_gap

    gap = params["gap"] if params["gap"] is not None else default_bootstrap_gap(n)
    return max(1, min(int(gap), n - 2))


def _histogram(params: dict, inputs: "MethodInputs") -> RunResult:  # noqa: C901
    from .likelihood import HistogramLikelihood, HistogramPlaceRecogniser, labelled_samples

    start = time.perf_counter()
    model = HistogramLikelihood(n_bins=params["n_bins"])
    common = {"exclusion_radius": params["exclusion_radius"], "confidence_radius": params["confidence_radius"],
              "new_place_prior": params["new_place_prior"], "random_state": params["seed"],
              **_same_place(params, inputs)}
    learning = params["learning"]
    if learning == "online":
        if params["n_init"] >= len(inputs.query):
            from .exceptions import warn

            warn(
                f"n_init (T_init) = {params['n_init']} frames is not shorter than the query ({len(inputs.query)} "
                "frames): the online model spends every frame learning and localises none (every confidence 0). "
                "Choose fewer initialisation frames or learning 'bootstrap'.")
        recogniser = HistogramPlaceRecogniser(model, n_init=params["n_init"], **common)
    elif learning == "bootstrap":
        model.fit(np.empty(0), inputs.bootstrap_samples(_bootstrap_gap(params, inputs.map.n_places),
                                                        params["max_different"], params["seed"]))
        recogniser = HistogramPlaceRecogniser(model, n_init=0, **common)
    else:  # trained: an oracle baseline fitted on the labelled query
        if inputs.ground_truth is None:
            raise InvalidParameterError("the trained histogram model is fitted from ground truth; give --tolerance, "
                                        "--tolerance-m or --ground-truth, or use learning 'online' or 'bootstrap'.")
        model.fit(*labelled_samples(inputs.difference_rows(), inputs.ground_truth, inputs.query.index,
                                    max_different=params["max_different"], seed=params["seed"]))
        recogniser = HistogramPlaceRecogniser(model, n_init=0, learn=False, **common)
    rec = recogniser.run(inputs.difference_rows())
    return RunResult(f"histogram-{learning}", dict(params), inputs.query.index, rec.match, rec.confidence,
                     extra={"p_new_place": rec.new_place_probability}, seconds=time.perf_counter() - start)


def _histogram_not_applicable(params: dict) -> dict[str, str]:
    out = {}
    if params["learning"] != "online":
        out["n_init"] = "only online learning has an initialisation stage"
    if params["learning"] != "bootstrap":
        out.update(gap="it sets the bootstrap from the map; use learning 'bootstrap'")
        if params["learning"] == "online":
            out["max_different"] = "online learning draws no samples from the map or the ground truth"
    return out


def observation_model(params: dict, n_places: int, bootstrap_samples: Callable[[int, int, int], np.ndarray]):
    """The filter's observation model from the ``filter`` method's resolved parameters.

    ``bootstrap_samples(gap, max_different, seed)`` gives the map's ``¬L`` samples (e.g.
    :meth:`catgraph.experiment.Prepared.bootstrap_samples`); the batch method and the live
    API (:mod:`catgraph.live`) build their models here, so both run the same model.
    """
    from .likelihood import HistogramLikelihood
    from .observation import CombinedObservation, HistogramObservation, SequenceObservation, TemperedObservation

    model = params["model"]

    def histogram(bootstrap: bool) -> HistogramObservation:
        kw = {"exclusion_radius": params["exclusion_radius"], "seed": params["seed"]}
        if not bootstrap:
            return HistogramObservation(n_init=params["n_init"], **kw)
        values = bootstrap_samples(_bootstrap_gap(params, n_places), params["max_different"], params["seed"])
        return HistogramObservation(mode="bootstrap", likelihood=HistogramLikelihood().fit(np.empty(0), values), **kw)

    def sequence(default_window, **calibration) -> SequenceObservation:
        window = params.get("window") or default_window
        matcher = {k: params[k] for k in _WINDOW_ADAPTIVE} if window == "adaptive" else {}
        # the matcher searches its velocities; the observation reads the lines of the chosen one
        return SequenceObservation(window=window, matcher_params=matcher, **calibration)

    if model == "tempered":
        return TemperedObservation()
    if model == "histogram":
        return histogram(False)
    if model == "histogram-bootstrap":
        return histogram(True)
    if model == "sequence":
        return sequence(50)
    if model == "adaptive":
        return sequence("adaptive")
    if model == "histogram-combined":
        return CombinedObservation([histogram(True), sequence("adaptive")])
    # "combined": the whole-image evidence of the default model and the sequence part, its
    # ratios tempered by how often the filter confirms its best place and each frame counted at
    # most once, by the longest window so far (docs/particle_filter.md, "the combined model")
    part = sequence("adaptive", calibration="agreement", temperature="longest", agreement_scale=1.0)
    return CombinedObservation([TemperedObservation(), part], reliability=None)


_PARTICLE_KEYS = ("n_particles", "resampler", "ess_threshold", "redraw_fraction", "proposal", "jump_graduation")
#: the grid filter's own parameters (the particle filter has none of them)
_GRID_KEYS = ("jump_velocity", "rigid_prior", "home_speed_odds", "outlier_probability", "velocity_bins",
              "varying_prior")
#: ``mode="auto"`` runs the exact grid filter on maps up to this many places
GRID_MAX_PLACES = 100_000


#: the particle filter's ``jump_graduation`` where the method leaves it unset, on maps of at most
#: :data:`JUMP_GRID_MAX_PLACES` places (above: 1, no jump grid). Measured on the whole condition
#: table, filter seeds 0–4 (``benchmarks/results/particles_jump_grid.md``; docs/particle_filter.md,
#: "Twelfth round" and "The jump grid by default on small maps"): the seed spread ≤ 0.02 in 10 of
#: 14 Nordland cells against 1 without it; the largest fall of a cell's mean AUC 0.0013 (UJI,
#: shuffled 2–20 %, seed 4).
JUMP_GRADUATION = 0.2
#: the largest map on which the jump grid is on by default: its pass over places × velocity
#: bins costs a step ×1.36 at 3,576 places, ×1.40 at 5,000 and ×1.55 at 8,192 (2,000 particles,
#: fresh processes alternated; docs/particle_filter.md), and a default is held to ×1.5
JUMP_GRID_MAX_PLACES = 5_000

#: the grid filter's rigid line (``GridLocalizer(rigid_prior=...)``), prior weight, where the method
#: leaves ``rigid_prior`` unset on maps of at most :data:`RIGID_MAX_PLACES` places: the query is one
#: unbroken line at one speed with this prior probability. It keeps a long traverse through a
#: stretch where the frames say little, as a long window does, and costs the shuffles a few frames
#: after a jump (``docs/particle_filter.md``, eleventh round and "The rigid line by default")
RIGID_PRIOR = 0.05
#: the largest map on which the rigid line is on by default: it doubles the grid's state and
#: step. Measured in the live step (compact map, combined model): at 10⁴ places 1.4 ms and a
#: 201 MB streaming peak with it; at 10⁵ a 416 MB peak against the 400 MB the live step is
#: held to (398 MB without it; ``docs/particle_filter.md``)
RIGID_MAX_PLACES = 10_000


#: the share of the grid filter's velocity prior on the reference's own speed, ``±1`` place per
#: frame together, at the start and where a jump lands, where the method leaves ``home_speed_odds``
#: unset: a weak start-up (UJI 06: the first 37 frames held at half speed) follows the speed a
#: traverse most often has (``docs/particle_filter.md``, "The reference's own speed"). The odds
#: against each other velocity follow from the velocity bins (:func:`home_speed_odds`)
HOME_SPEED_SHARE = 0.5
#: the odds that share gives the eight velocities of ``grid.DEFAULT_VELOCITIES``: ``±1`` three
#: times as likely as each other velocity
HOME_SPEED_ODDS = 3.0

#: the grid filter's velocity bins are ``grid.DENSE_VELOCITIES`` (every tenth from 0.9 to 4 places
#: per frame, and a half, two thirds and three quarters, both ways: 88 bins with the phases) on
#: maps of at most this many places where the method leaves ``velocity_bins`` unset, and
#: ``grid.DEFAULT_VELOCITIES`` (±0.5, 1, 2, 3: 10 bins) above. A query driven between the bins'
#: speeds drifts from every track (``docs/particle_filter.md``, "Speeds between the bins"). The
#: dense bins make the state nine times as large (the live step's filter at 10⁴ places 2.4 ms
#: against 0.55 ms, ``benchmarks/results/live.md``), held back on large maps as the rigid line is
DENSE_VELOCITY_MAX_PLACES = 10_000


#: the share of what the rigid line leaves that the grid filter's varying speed
#: (``GridLocalizer(varying_prior=...)``) takes as its prior where the method leaves
#: ``varying_prior`` unset, on maps of at most :data:`DENSE_VELOCITY_MAX_PLACES` places (it moves
#: through the dense bins): the filter's own motion and the varying speed's share evenly, and Bayes'
#: rule weighs them by the frames. A query whose speed changes all the time drifts off the own
#: motion's sticky velocity (``docs/particle_filter.md``, "A speed that changes all the time")
VARYING_SHARE = 0.5


def varying_prior(params: dict, n_places: int, rigid: float) -> float:
    """The grid filter's ``varying_prior`` on a map of ``n_places`` beside a rigid line of
    prior ``rigid``: the method's parameter where set, else :data:`VARYING_SHARE` of ``1 −
    rigid`` up to :data:`DENSE_VELOCITY_MAX_PLACES` places, else 0."""
    if params.get("varying_prior") is not None:
        return float(params["varying_prior"])
    return VARYING_SHARE * (1.0 - rigid) if n_places <= DENSE_VELOCITY_MAX_PLACES else 0.0


def home_speed_odds(velocities, share: float = HOME_SPEED_SHARE) -> float:
    """The odds of each of ``±1`` against each other velocity of ``velocities`` that give
    the two together ``share`` of the prior (every velocity where ``±1`` are not among them:
    1).

    Examples
    --------
    >>> home_speed_odds((-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0))
    3.0
    """
    v = np.abs(np.asarray(velocities, dtype=np.float64))
    home = int(np.count_nonzero(np.abs(v - 1.0) < 1e-12))
    other = len(v) - home
    if home == 0 or other == 0:
        return 1.0
    return float(share * other / (home * (1.0 - share)))


#: The filters' ``repeat_prior`` (grid and particles) where the ``filter`` method leaves it unset: the prior
#: probability that a query stands still while its frame comes again unchanged. Low, because
#: in the real data such a frame is a camera or scanner that repeated itself while the robot
#: moved on (Nordland's winter video at its two ends, a Wi-Fi scan delivered twice on UJI);
#: the frames after a run decide for a query that does stand still (stops, slow speeds).
#: Chosen between 0.1 and 0.5 for the grid filter on the condition table, stops and speeds
#: (``docs/particle_filter.md``, "Frames that come again"); the particle filter takes the same
#: value, measured at it on every cell of the table with seeds 0–4 and on the stops, not chosen
#: among others (``docs/particle_filter.md``, "The particle filter's twin").
REPEAT_PRIOR = 0.1


def velocity_bins(params: dict, n_places: int) -> list[float]:
    """The grid filter's velocity bins on a map of ``n_places``: the method's
    ``velocity_bins`` where set, else ``grid.DENSE_VELOCITIES`` up to
    :data:`DENSE_VELOCITY_MAX_PLACES` places, else ``grid.DEFAULT_VELOCITIES``."""
    if params.get("velocity_bins") is not None:
        return [float(v) for v in params["velocity_bins"]]
    from .grid import DEFAULT_VELOCITIES, DENSE_VELOCITIES

    return list(DENSE_VELOCITIES if n_places <= DENSE_VELOCITY_MAX_PLACES else DEFAULT_VELOCITIES)


#: the grid filter's prior probability that a frame shows no place of the map
#: (``GridLocalizer(outlier_probability=...)``), where the method leaves it unset: a frame's
#: likelihood at each place is ``(1 − p) e^{r_j} + p e^{r_new}``, so one glitch, occlusion or
#: blank frame cannot move a track by more than about ``log(1/p)`` nats. Chosen on the condition
#: table, ten 357-frame sections of Nordland and the UJI walks (``docs/particle_filter.md``,
#: "Outlier frames")
OUTLIER_PROBABILITY = 0.01

#: the grid filter's ``jump_velocity`` where the method leaves it unset: a jump lands with the
#: query's long-run velocity distribution (``GridLocalizer(jump_velocity=...)``)
JUMP_VELOCITY = "long-run"


def jump_graduation(params: dict, n_places: int) -> float:
    """The particle filter's ``jump_graduation`` on a map of ``n_places``: the method's
    parameter where set, else :data:`JUMP_GRADUATION` up to :data:`JUMP_GRID_MAX_PLACES`
    places with the likelihood proposal (the grid's births need it), else 1."""
    if params.get("jump_graduation") is not None:
        return float(params["jump_graduation"])
    if n_places <= JUMP_GRID_MAX_PLACES and _proposal(params) == "likelihood":
        return JUMP_GRADUATION
    return 1.0


def _proposal(params: dict) -> str:
    """The particle filter's proposal: the method's parameter where set, else the filter's own."""
    if params.get("proposal") is not None:
        return params["proposal"]
    from .localizer import Localizer

    return particle_defaults(Localizer)["proposal"]


def rigid_prior(params: dict, n_places: int) -> float:
    """The grid filter's ``rigid_prior`` on a map of ``n_places``: the method's parameter
    where set, else :data:`RIGID_PRIOR` up to :data:`RIGID_MAX_PLACES` places, else 0."""
    if params.get("rigid_prior") is not None:
        return float(params["rigid_prior"])
    return RIGID_PRIOR if n_places <= RIGID_MAX_PLACES else 0.0


def filter_mode(params: dict, n_places: int) -> str:
    """``"grid"`` or ``"particles"``: what ``mode`` means on a map of ``n_places``."""
    if params["mode"] != "auto":
        return params["mode"]
    return "grid" if n_places <= GRID_MAX_PLACES else "particles"


def particle_defaults(localizer_class) -> dict[str, Any]:
    """The particle filter's own defaults of the ``filter`` method's particle-only parameters
    (``n_particles``, ``resampler`` …): the method leaves them unset and the filter decides."""
    own = inspect.signature(localizer_class.__init__).parameters
    return {k: own[k].default for k in _PARTICLE_KEYS if k != "jump_graduation"}


def concrete_params(params: dict, n_places: int) -> dict[str, Any]:
    """The ``filter`` method's resolved ``params`` as they apply on a map of ``n_places``:
    ``mode`` the filter that runs, the other filter's parameters dropped and the unset ones of
    this filter filled in (the particle filter's own defaults; the grid's rigid line by map size).

    Under ``mode="auto"`` a parameter of the filter it does not choose (``n_particles`` where
    the grid runs, ``rigid_prior`` where particles run …) would be ignored: it is an
    :class:`InvalidParameterError` naming the mode that applies it.
    """
    mode = filter_mode(params, n_places)
    other = {"grid": (*_PARTICLE_KEYS, "motion"), "particles": _GRID_KEYS}[mode]
    given = [k for k in other if params.get(k) is not None]
    if given:
        which = ("the exact grid filter", "has no particles", "particles") if mode == "grid" else \
            ("the particle filter", "has no grid", "grid")
        raise InvalidParameterError(
            f"'{given[0]}' does not apply here: mode '{params['mode']}' runs {which[0]} on this map of "
            f"{n_places:,} places (the grid up to {GRID_MAX_PLACES:,}), which {which[1]}; choose mode "
            f"'{which[2]}', or leave '{given[0]}' out.")
    out = {k: v for k, v in params.items() if k not in other}
    out["mode"] = mode
    if out.get("new_place_prior") is None:  # the filter's own default, recorded as it runs
        from .grid import GridLocalizer
        from .localizer import Localizer

        owner = GridLocalizer if mode == "grid" else Localizer
        out["new_place_prior"] = inspect.signature(owner.__init__).parameters["new_place_prior"].default
    out["repeat_prior"] = REPEAT_PRIOR if params.get("repeat_prior") is None else float(params["repeat_prior"])
    if mode == "grid":
        out["jump_velocity"] = params.get("jump_velocity") or JUMP_VELOCITY
        out["rigid_prior"] = rigid_prior(params, n_places)
        out["varying_prior"] = varying_prior(params, n_places, out["rigid_prior"])
        out["velocity_bins"] = velocity_bins(params, n_places)
        if params.get("home_speed_odds") is None:
            out["home_speed_odds"] = home_speed_odds(out["velocity_bins"])
        if params.get("outlier_probability") is None:
            out["outlier_probability"] = OUTLIER_PROBABILITY
        return out
    from .localizer import Localizer

    for k, value in particle_defaults(Localizer).items():
        if out.get(k) is None:
            out[k] = value
    if out.get("motion") is None:
        out["motion"] = "velocity"
    out["jump_graduation"] = jump_graduation(out, n_places)
    return out


def make_filter(params: dict, graph, model):
    """The filter the ``filter`` method's resolved parameters describe, on ``graph`` with
    observation ``model``: a particle filter (``mode="particles"``) or the exact grid filter."""
    params = concrete_params(params, graph.n_places)
    common = {k: params[k] for k in ("seed", "confidence_radius", "confidence_radius_m") if k in params}
    if params.get("new_place_prior") is not None:
        common["new_place_prior"] = params["new_place_prior"]
    if params["mode"] == "grid":
        from .grid import GridLocalizer

        common.pop("seed", None)
        return GridLocalizer(graph, model, velocities=tuple(params["velocity_bins"]),
                             jump_velocity=params["jump_velocity"],
                             rigid_prior=params["rigid_prior"], varying_prior=params["varying_prior"],
                             home_speed_odds=params["home_speed_odds"],
                             outlier_probability=params["outlier_probability"],
                             repeat_prior=params["repeat_prior"], **common)
    from .localizer import Localizer
    from .motion import VelocityMotion

    motion = VelocityMotion() if params["motion"] == "velocity" else None
    particles = {k: params[k] for k in _PARTICLE_KEYS}
    return Localizer(graph, model, motion=motion, repeat_prior=params["repeat_prior"], **common, **particles)


def check_use_odometry(use: bool | None, has_odometry: bool, unit: str) -> None:
    """Refuse ``use_odometry`` given as true where there is no odometry to use: a query
    without it, or a place graph in frames (a reference without positions or odometry)."""
    if not use or (has_odometry and unit == "m"):
        return
    why = "the query has no odometry" if not has_odometry else \
        f"the map's place graph is in {unit}s, not metres (its reference has no positions or odometry)"
    raise InvalidParameterError(f"'use_odometry' does not apply here: {why}; leave it out.")


def _filter(params: dict, inputs: "MethodInputs") -> RunResult:
    if params.get("window") is not None:  # a sequence model's window, as the matcher's own run checks it
        check_sequence_length(params, len(inputs.query))
    graph = inputs.graph()
    given_graduation = params.get("jump_graduation")
    params = concrete_params(params, graph.n_places)
    check_use_odometry(params["use_odometry"], inputs.query.odometry is not None, graph.unit)
    odometry = inputs.query.odometry if params["use_odometry"] is not False and graph.unit == "m" else None
    obs = observation_model(params, inputs.map.n_places, inputs.bootstrap_samples)
    loc = make_filter(params, graph, obs)
    if params["mode"] == "particles" and params["jump_graduation"] < 1.0:
        # the jump grid rides on the velocity-marginalised particles, on frames without odometry
        if odometry is not None or not loc.marginal_applies():
            if given_graduation is not None:
                why = "odometry drives the particles" if odometry is not None else \
                    "the particles' motion is 'frame'" if params["motion"] != "velocity" else "the route has junctions"
                raise InvalidParameterError(
                    f"'jump_graduation' does not apply here: the jump grid rides on the velocity-marginalised "
                    f"particles, and {why}; leave it out" + (" or give use_odometry false." if odometry is not None
                                                               else "."))
            params = dict(params, jump_graduation=1.0)  # recorded as it ran: no jump grid
            loc.jump_graduation = 1.0
    params = dict(params, use_odometry=odometry is not None)  # recorded: whether odometry drove the motion
    start = time.perf_counter()
    mode = params["mode"]
    kwargs = {"progress": inputs.progress} if mode == "particles" else {}
    res = loc.run(inputs.difference_rows(), odometry=odometry, query_index=inputs.query.index, **kwargs)
    seconds = time.perf_counter() - start
    name = "grid-filter" if mode == "grid" else "particle-filter"
    return RunResult(f"{name}/{params['model']}", dict(params), inputs.query.index, res.place, res.score,
                     extra={"posterior_mass": res.confidence, "log_odds": res.log_odds,
                            "p_new_place": res.new_place_probability, "ess": res.ess}, seconds=seconds)


def _filter_not_applicable(params: dict) -> dict[str, str]:
    model = params["model"]
    out: dict[str, str] = {}
    sequence_models = ("sequence", "adaptive", "combined", "histogram-combined")
    histogram_models = ("histogram", "histogram-bootstrap", "histogram-combined")
    if params["mode"] == "grid":  # "auto" keeps them: they apply where it chooses particles
        # the seed also draws the histogram models' samples, so it stays for those
        for k in (*_PARTICLE_KEYS, "motion", *(("seed",) if model not in histogram_models else ())):
            out[k] = "the grid filter has no particles (it is exact); use mode 'particles'"
    if params["mode"] != "grid":
        from .localizer import Localizer

        own = particle_defaults(Localizer)
        redraw = own["redraw_fraction"] if params.get("redraw_fraction") is None else params["redraw_fraction"]
        n = own["n_particles"] if params.get("n_particles") is None else params["n_particles"]
        if n >= 2 and int(round(redraw * n)) > 0:  # (the filter's births: Localizer.reset)
            out["ess_threshold"] = (f"with particles born each frame (redraw_fraction {redraw:g}) the particle "
                                    "filter resamples every frame; give redraw_fraction 0 to resample by ESS")
    if params["mode"] == "particles":
        out["jump_velocity"] = "it sets the grid filter's jumps; the particle filter's recovery particles are drawn"
        out["rigid_prior"] = "the rigid line is the grid filter's; the particle filter has none"
        out["varying_prior"] = "the varying speed's motion is the grid filter's; the particle filter has none"
        out["home_speed_odds"] = "it sets the grid filter's velocity prior; the particle filter's is uniform"
        out["outlier_probability"] = "the outlier frames are the grid filter's; the particle filter has none"
    if model not in sequence_models:
        for k in ("window", *_WINDOW_ADAPTIVE):
            out[k] = f"model {model!r} has no sequence matcher"
    else:
        if model == "adaptive":
            out["window"] = "model 'adaptive' is the sequence model with the adaptive window; for a fixed window " \
                            "use model 'sequence'"
        window = params["window"] or (50 if model == "sequence" else "adaptive")
        if window != "adaptive":
            for k in _WINDOW_ADAPTIVE:
                out[k] = "it sets the adaptive window, and this model's window is fixed"
    if model not in histogram_models:
        for k in ("n_init", "exclusion_radius"):
            out[k] = f"model {model!r} has no histogram model"
    if model != "histogram":
        out.setdefault("n_init", "only the online histogram model has an initialisation stage")
    if model not in ("histogram-bootstrap", "histogram-combined"):
        for k in ("gap", "max_different"):
            out[k] = f"model {model!r} is not bootstrapped from the map"
    if params["confidence_radius_m"] is not None:
        out["confidence_radius"] = "give one confidence radius: places or metres"
    return out


def _filter_params() -> tuple[Param, ...]:
    from .localizer import PROPOSALS, Localizer
    from .particles import RESAMPLERS

    own = particle_defaults(Localizer)
    from .sequence import DEFAULT_LINE_RULE, RULES

    seq = {p.name: p for p in _sequence_params(None, window_optional=True)}
    seq["rule"] = Param("rule", "str", DEFAULT_LINE_RULE, "sequence models, adaptive window: how the window length "
                        "is chosen (the matcher's statistics alone: the filter is the tracker)", choices=RULES)
    seq["window"] = Param("window", "window", None, "sequence models: window length in frames or 'adaptive' "
                          "(default: 50 for model 'sequence', adaptive otherwise)", optional=True)
    hist = {p.name: p for p in _histogram_params()}
    return (
        Param("model", "str", "tempered", "observation model", choices=FILTER_MODELS),
        Param("mode", "str", "auto", "'grid': the exact Bayes filter over (place, velocity); 'particles': the "
              "CAT-Graph particle filter; 'auto': the grid up to 100,000 places, particles above",
              choices=("auto", "grid", "particles")),
        Param("motion", "str", None, "particles: 'velocity' (a signed velocity per particle, driven forwards or "
              "backwards at 0.5-3 places per frame) or 'frame' (one frame per step, odometry where given) "
              "(default velocity)", choices=("velocity", "frame"), optional=True),
        Param("n_particles", "int", None, f"particles: number of particles (default {own['n_particles']})", low=1,
              high=10_000_000, flag="--particles", optional=True),
        Param("seed", "int", 0, "seed of the particle filter and of the histogram models' samples", low=0),
        Param("confidence_radius", "int", 2, "places either side of the answer counted in its confidence "
              "(the grid: the map's mean spacings along the route; a parameter of the method, not of the "
              "evaluation)", low=0, high=1_000_000),
        Param("confidence_radius_m", "float", None, "count posterior mass within METRES instead (needs positions)",
              low=0.0, optional=True),
        Param("use_odometry", "bool", None, "drive the motion model by the query's odometry (default: where the "
              "query has odometry and the map's place graph is in metres; given, both are required)", optional=True),
        Param("resampler", "str", None, f"particles: resampling scheme (default {own['resampler']})",
              choices=tuple(RESAMPLERS), optional=True),
        Param("ess_threshold", "float", None, "particles: resample when ESS < this fraction of the particles "
              f"(default {own['ess_threshold']})", low=0.0, high=1.0, optional=True),
        Param("redraw_fraction", "float", None, "particles: particles born each step to carry the jump (recovery) "
              f"share, as a fraction of the particles (0: no recovery; default {own['redraw_fraction']})", low=0.0,
              high=0.99,
              optional=True),
        Param("proposal", "str", None, f"particles: where the recovery particles born each step are drawn "
              f"(default {own['proposal']})", choices=PROPOSALS, optional=True),
        Param("jump_graduation", "float", None, "particles: share of the exact jump grid born as particles each "
              "step (1: no grid, births only; smaller: a steadier recovery after jumps, at about twice the "
              "step's cost on a route of 10^5 places; default: 0.2 on maps of at most 5,000 places, 1 above)",
              low=0.0, high=1.0, optional=True),
        Param("new_place_prior", "float", None, "per-step probability of entering unmapped space (default: the "
              "filter's own, 0.05 for the grid)",
              low=0.0, high=0.99, optional=True),
        Param("jump_velocity", "str", None, "grid: the velocity a jump lands with: 'long-run' (the query's "
              "long-run velocity distribution) or 'current' (half the current marginal, half uniform) "
              f"(default {JUMP_VELOCITY})", choices=("long-run", "current"), optional=True),
        Param("rigid_prior", "float", None, "grid: prior probability that the query is one unbroken line "
              "at one speed (a rigid-line motion averaged with the filter's by Bayes' rule; 0: off). It holds long "
              "unbroken traverses through weak stretches and is slower to follow real jumps (default: 0.05 on "
              "maps of at most 10,000 places, 0 above: it doubles the grid's state and step)",
              low=0.0, high=0.99, optional=True),
        Param("varying_prior", "float", None, "grid: prior probability that the query's speed changes all "
              "the time (a motion whose velocity changes ten times as often as the filter's own, averaged with it "
              "by Bayes' rule; 0: off). It follows a speed that keeps changing (default: half of what the rigid "
              f"line leaves on maps of at most {DENSE_VELOCITY_MAX_PLACES:,} places, 0 above: one more copy of the "
              "grid's state and step)", low=0.0, high=0.99, optional=True),
        Param("repeat_prior", "float", None, "prior probability that the query stands still while its "
              "frame comes again unchanged (the same frame twice in a row, without odometry): from the first such "
              "frame the filter runs a twin that stands still through them beside itself, which moves on, and "
              "answers with both, each weighed by its evidence (0: off, the filter moves on; default "
              f"{REPEAT_PRIOR:g}; docs/particle_filter.md, \"Frames that come again\")", low=0.0, high=1.0,
              optional=True),
        Param("home_speed_odds", "float", None, "grid: prior odds of the reference's own speed (one "
              "place per frame, either direction) against each other velocity, at the start and where a jump lands "
              f"(1: uniform; default: the odds that give the two {HOME_SPEED_SHARE:g} of the prior, "
              f"{HOME_SPEED_ODDS:g} with the 8 velocities above {DENSE_VELOCITY_MAX_PLACES:,} places)", low=1.0,
              high=1000.0, optional=True),
        Param("velocity_bins", "floats", None, "grid: the signed speeds of the motion's velocity bins, places "
              "per frame (negative: driven backwards; default: every tenth from 0.9 to 4, and 1/2, 2/3 and 3/4, "
              f"both ways, on maps of at most {DENSE_VELOCITY_MAX_PLACES:,} places; ±0.5, 1, 2, 3 above)",
              high=256, optional=True),
        Param("outlier_probability", "float", None, "grid: prior probability that a frame shows no place of "
              "the map (a glitch, an occlusion, a blank scan), its likelihood then the new-place hypothesis's, so "
              f"that one such frame cannot pull a track away (0: off; default {OUTLIER_PROBABILITY:g})",
              low=0.0, high=0.99, optional=True),
        *seq.values(),
        hist["n_init"], hist["exclusion_radius"], hist["gap"], hist["max_different"],
    )


def _histogram_method_params() -> tuple[Param, ...]:
    return (
        Param("learning", "str", "online", "online (training-free), bootstrap (from the map) or trained (fitted on "
              "the labelled query: an upper-bound baseline)", choices=_LEARNING),
        *_histogram_params(),
        Param("confidence_radius", "int", 2, "places either side of the answer counted in its confidence",
              low=0, high=1_000_000),
        Param("new_place_prior", "float", 0.01, "prior probability of a new place", low=0.0, high=0.99),
        Param("seed", "int", 0, "seed of the ¬L samples", low=0),
    )


def _registry() -> dict[str, Method]:
    return {m.name: m for m in (
        Method("single-frame", "nearest reference place per frame", (_EXCLUSION,), _single_frame),
        Method("sequence", "SeqSLAM sequence matching, fixed or adaptive window, with velocity search",
               (*_sequence_params(50), *_velocity_params(), _EXCLUSION), _sequence, _not_adaptive, _check_sequence),
        Method("histogram", "single-frame recognition with the histogram model P(d|L), P(d|¬L)",
               _histogram_method_params(), _histogram, _histogram_not_applicable),
        Method("filter", "CAT-Graph particle filter on the place graph", _filter_params(), _filter,
               _filter_not_applicable, _check_filter),
    )}


class _Registry(Mapping):
    """The methods by name (built on first use: declarations import the modules that own the choices)."""

    _methods: dict[str, Method] | None = None

    def _all(self) -> dict[str, Method]:
        if self._methods is None:
            type(self)._methods = _registry()
        return self._methods

    def __getitem__(self, name: str) -> Method:
        return self._all()[name]

    def __iter__(self):
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


#: Every method by name.
METHODS: Mapping[str, Method] = _Registry()


def get_method(name: str) -> Method:
    """The method ``name``; :class:`InvalidParameterError` naming the known ones otherwise."""
    if name not in METHODS:
        import difflib

        close = difflib.get_close_matches(str(name), list(METHODS), n=1, cutoff=0.5)
        hint = f" did you mean {close[0]!r}?" if close else ""
        raise InvalidParameterError(f"unknown method {name!r};{hint} choose one of {', '.join(METHODS)}.")
    return METHODS[name]


def resolve_params(name: str, params: Mapping[str, Any] | None) -> dict[str, Any]:
    """All parameters of method ``name``, checked, with defaults (see :meth:`Method.resolve`)."""
    return get_method(name).resolve(params)
