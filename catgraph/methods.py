"""The registry of localisation methods, by name.

Every method takes the same inputs — reference and query traverses, the query ×
reference difference matrix (normalised per query, in processing order), and, for the
"trained" baselines only, the ground truth — and returns a :class:`RunResult`. The CLI,
the experiment runner and the sweeps all go through :func:`run_method`, so a method
added here is available everywhere.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .exceptions import InvalidParameterError
from .pipeline import match_single_frames
from .results import RunResult
from .traverse import GroundTruth, Traverse

__all__ = ["METHODS", "run_method"]


def _check_keys(params: dict, allowed: tuple[str, ...], what: str) -> None:
    unknown = set(params) - set(allowed)
    if unknown:
        raise InvalidParameterError(f"unknown {what} parameters {sorted(unknown)}; allowed: {', '.join(allowed)}.")


def _single_frame(params, *, reference, query, differences, ground_truth, frontend=None, graph=None) -> RunResult:
    return match_single_frames(differences, query.index, exclusion=int(params.get("exclusion", 10)))


_SEQUENCE_KEYS = ("window", "approximation", "rule", "confidence", "l_min", "l_max", "grid", "radius")


def _sequence(params, *, reference, query, differences, ground_truth, frontend=None, graph=None) -> RunResult:
    """SeqSLAM sequence matching, fixed (``window`` int) or adaptive (``"adaptive"``)."""
    import time

    from .sequence import match_sequences

    _check_keys(params, _SEQUENCE_KEYS, "sequence-matching")
    kwargs = {k: v for k, v in params.items() if v is not None}
    kwargs.setdefault("window", "adaptive")
    start = time.perf_counter()
    res = match_sequences(differences, **kwargs)
    seconds = time.perf_counter() - start
    name = "adaptive" if kwargs["window"] == "adaptive" else f"sequence-L{kwargs['window']}"
    return RunResult(name, dict(kwargs), np.asarray(query.index), res.match, res.confidence,
                     extra={"window_length": res.window_length}, seconds=seconds)


_HISTOGRAM_KEYS = ("learning", "n_init", "exclusion_radius", "confidence_radius", "new_place_prior", "n_bins", "gap",
                   "max_different", "seed", "confidence_distance", "exclusion_distance")


def _histogram(params, *, reference, query, differences, ground_truth, frontend=None, graph=None) -> RunResult:
    """Single-frame recognition with the histogram model P(d|L), P(d|¬L) (paper 2).

    ``learning``: ``"online"`` (training-free, the paper), ``"bootstrap"`` (¬L from
    reference pairs more than ``gap`` places apart, so no initialisation wait) or
    ``"trained"`` (fitted from the labelled query itself: an oracle baseline).
    """
    import time

    from .likelihood import HistogramLikelihood, HistogramPlaceRecogniser, labelled_samples, reference_samples

    _check_keys(params, _HISTOGRAM_KEYS, "histogram-model")
    p = {"learning": "online", "n_init": 100, "exclusion_radius": 5, "confidence_radius": 2,
         "new_place_prior": 0.01, "n_bins": 100, "gap": None, "max_different": 100_000, "seed": 0}
    p.update({k: v for k, v in params.items() if v is not None})
    start = time.perf_counter()
    model = HistogramLikelihood(n_bins=int(p["n_bins"]))
    common = {"exclusion_radius": int(p["exclusion_radius"]), "confidence_radius": int(p["confidence_radius"]),
              "new_place_prior": float(p["new_place_prior"]), "random_state": int(p["seed"])}
    if p.get("confidence_distance") is not None or p.get("exclusion_distance") is not None:
        # "the same place" by position (metres; floors 100 m apart) instead of by index
        if reference.positions is None:
            raise InvalidParameterError("confidence_distance/exclusion_distance need reference positions.")
        positions = reference.positions if reference.floors is None else \
            np.column_stack([reference.positions, 100.0 * reference.floors])
        common.update(reference_positions=positions, confidence_distance=p.get("confidence_distance"),
                      exclusion_distance=p.get("exclusion_distance"))
    if p["learning"] == "online":
        recogniser = HistogramPlaceRecogniser(model, n_init=int(p["n_init"]), **common)
    elif p["learning"] == "bootstrap":
        from .pipeline import FrontEnd, differences as diff_of

        rr = diff_of(reference, reference, frontend or FrontEnd())
        if p["gap"] is None:  # "far apart along the route": 50 places, or a fifth of a short route
            p["gap"] = min(50, max(1, len(reference) // 5))
        model.fit(*reference_samples(rr, int(p["gap"]), max_different=int(p["max_different"]), seed=int(p["seed"])))
        recogniser = HistogramPlaceRecogniser(model, n_init=0, **common)
    elif p["learning"] == "trained":
        if ground_truth is None:
            raise InvalidParameterError("the trained histogram model needs ground truth to fit from.")
        model.fit(*labelled_samples(differences, ground_truth, np.asarray(query.index),
                                    max_different=int(p["max_different"]), seed=int(p["seed"])))
        recogniser = HistogramPlaceRecogniser(model, n_init=0, learn=False, **common)
    else:
        raise InvalidParameterError(f"unknown learning {p['learning']!r}; choose online, trained or bootstrap.")
    rec = recogniser.run(differences)
    return RunResult(f"histogram-{p['learning']}", p, np.asarray(query.index), rec.match, rec.confidence,
                     extra={"p_new_place": rec.new_place_probability}, seconds=time.perf_counter() - start)


_FILTER_KEYS = ("n_particles", "seed", "window", "junction_radius_m", "edge_length", "use_odometry",
                "confidence_radius", "confidence_radius_m", "resampler", "ess_threshold", "redraw_fraction",
                "proposal", "new_place_prior")


def confidence_from_ground_truth(ground_truth: GroundTruth) -> dict:
    """The filter's confidence is the posterior mass within the tolerance the evaluation
    uses (DESIGN §6): ``confidence_radius`` (places) or ``confidence_radius_m`` (metres)."""
    described = ground_truth.describe()
    if described.get("type") == "metric":
        return {"confidence_radius_m": float(described["metres"])}
    if described.get("type") == "frame":
        return {"confidence_radius": max(1, int(described["tolerance"]))}
    return {}


def _filter(model: str):
    """The CAT-Graph particle filter with observation model ``model``."""

    def run(params, *, reference, query, differences, ground_truth, frontend=None, graph=None) -> RunResult:
        from .compare import localize

        _check_keys(params, _FILTER_KEYS, "particle-filter")
        kwargs = {k: v for k, v in params.items() if v is not None}
        if "confidence_radius" not in kwargs and "confidence_radius_m" not in kwargs and ground_truth is not None:
            kwargs.update(confidence_from_ground_truth(ground_truth))
        if graph is not None:  # a saved map's graph replaces the one built from the reference
            kwargs.pop("junction_radius_m", None)
        return localize(reference, query, model=model, differences=differences, frontend=frontend, graph=graph,
                        **kwargs)

    run.__doc__ = f"Particle filter with the {model!r} observation model."
    return run


METHODS: dict[str, Callable[..., RunResult]] = {
    "single-frame": _single_frame,
    "sequence": _sequence,
    "histogram": _histogram,
    **{f"filter-{m}": _filter(m) for m in ("histogram", "histogram-bootstrap", "sequence", "adaptive", "combined")},
}


def run_method(name: str, params: dict, *, reference: Traverse, query: Traverse, differences: np.ndarray,
               ground_truth: GroundTruth | None = None, frontend=None, graph=None) -> RunResult:
    """Run method ``name`` with ``params``; see :data:`METHODS` for the names.

    ``frontend`` (a :class:`~catgraph.pipeline.FrontEnd`) is needed by methods that
    compare reference frames with each other (bootstrapped histograms, the filter);
    ``graph`` (a :class:`~catgraph.graph.PlaceGraph`, e.g. from a saved map) replaces the
    place graph the filter methods would build from the reference.
    """
    if name not in METHODS:
        raise InvalidParameterError(f"unknown method {name!r}; choose one of {', '.join(sorted(METHODS))}.")
    return METHODS[name](params, reference=reference, query=query, differences=differences,
                         ground_truth=ground_truth, frontend=frontend, graph=graph)
