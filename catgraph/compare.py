"""Run the particle filter with several observation models on one traverse pair.

Comparing observation models on the same data is a first-class use (DESIGN.md §6).
:func:`localize` runs the filter once and returns a :class:`~catgraph.results.RunResult`
(what the ``catgraph localize`` command writes); :func:`compare_models` runs it with each
model, plus the standalone sequence matcher as a baseline, on the *same* difference
matrix, and returns one table row per method with AUC, R@100P, R@99P, MTL, accuracy and
the time per frame; :func:`format_table` renders the rows as Markdown.

Everything uses the project's default pipeline: :func:`catgraph.pipeline.differences`
(front-end by data kind, per-query normalised differences) and a place graph from the
reference (:meth:`PlaceGraph.from_traverse`: chain, reverse edges, and junctions found
from positions where the reference has them). Time per frame counts the filter step
with its observation model, not the difference matrix, which every method shares.

Model names (``MODEL_NAMES``):

``histogram``
    :class:`~catgraph.observation.HistogramObservation`, online and training-free
    (paper 2).
``histogram-bootstrap``
    The same, its ``¬L`` histogram started from reference-vs-reference differences.
``sequence``
    :class:`~catgraph.observation.SequenceObservation`, fixed window ``window``.
``adaptive``
    :class:`~catgraph.observation.SequenceObservation`, adaptive window.
``combined``
    :class:`~catgraph.observation.CombinedObservation` of ``histogram-bootstrap`` and
    ``adaptive``, each part's log-ratios tempered by its online reliability.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from .exceptions import InvalidParameterError
from .graph import PlaceGraph
from .localizer import Localizer
from .observation import CombinedObservation, HistogramObservation, ObservationModel, SequenceObservation
from .results import RunResult
from .traverse import GroundTruth, Traverse

__all__ = ["MODEL_NAMES", "build_model", "localize", "compare_models", "format_table"]

MODEL_NAMES = ("histogram", "histogram-bootstrap", "sequence", "adaptive", "combined")


def _reference_differences(reference: Traverse, frontend) -> np.ndarray:
    from .differences import difference_matrix
    from .pipeline import describe

    r, metric = describe(reference, frontend)
    return difference_matrix(r, r, metric, normalise=frontend.normalise)


def build_model(name: str, reference: Traverse | None = None, window: int = 50, frontend=None,
                reference_differences: np.ndarray | None = None) -> ObservationModel:
    """An observation model by name (see the module docstring).

    ``histogram-bootstrap`` and ``combined`` need the reference (or its
    ``reference_differences``, ``(n, n)``) to bootstrap ``¬L``.
    """
    from .pipeline import FrontEnd

    frontend = frontend or FrontEnd()

    def boot() -> HistogramObservation:
        nonlocal reference_differences
        if reference_differences is None:
            if reference is None:
                raise InvalidParameterError(f"model {name!r} needs the reference traverse to bootstrap its histograms.")
            reference_differences = _reference_differences(reference, frontend)
        return HistogramObservation.bootstrap(reference_differences)

    if name == "histogram":
        return HistogramObservation()
    if name == "histogram-bootstrap":
        return boot()
    if name == "sequence":
        return SequenceObservation(window=window)
    if name == "adaptive":
        return SequenceObservation(window="adaptive")
    if name == "combined":
        return CombinedObservation([boot(), SequenceObservation(window="adaptive")])
    raise InvalidParameterError(f"The 'model' parameter must be one of {list(MODEL_NAMES)}. Got {name!r} instead.")


def _graph_for(reference: Traverse, graph: PlaceGraph | None, junction_radius_m: float | None,
               edge_length: str) -> PlaceGraph:
    if graph is not None:
        return graph
    return PlaceGraph.from_traverse(reference, junction_radius_m=junction_radius_m if reference.positions is not None
                                    else None, edge_length=edge_length)


def localize(reference: Traverse, query: Traverse, model: str | ObservationModel = "histogram",
             n_particles: int = 2000, seed: int = 0, window: int = 50, graph: PlaceGraph | None = None,
             junction_radius_m: float | None = None, edge_length: str = "auto", use_odometry: bool = True,
             confidence_radius: int = 2, confidence_radius_m: float | None = None, frontend=None,
             differences: np.ndarray | None = None, progress: bool = False,
             **localizer_params: Any) -> RunResult:
    """Localise every query frame with the particle filter.

    Parameters
    ----------
    reference, query : Traverse
        Map and query (frames in the query's processing order).
    model : str or ObservationModel
        A name from :data:`MODEL_NAMES` or a model instance.
    n_particles, seed : int
    window : int
        Fixed window of the ``"sequence"`` model.
    graph : PlaceGraph, optional
        Default: :meth:`PlaceGraph.from_traverse` of the reference.
    junction_radius_m : float, optional
        Find junctions within this radius (references with positions).
    edge_length : str
        See :meth:`PlaceGraph.from_traverse`.
    use_odometry : bool
        Drive the motion model by the query's odometry where it has one.
    confidence_radius : int
        Places counted in a confidence.
    confidence_radius_m : float, optional
        Metric confidence radius instead.
    frontend : catgraph.pipeline.FrontEnd, optional
    differences : ndarray, shape (n_query, n_reference), optional
        Precomputed difference matrix (normalised like the front-end says).
    progress : bool
        Show a progress bar (on stderr) while localising.
    **localizer_params
        Further :class:`~catgraph.localizer.Localizer` parameters.

    Returns
    -------
    RunResult
        ``match`` = most likely place; ``confidence`` = :attr:`Estimate.score`, the
        log-odds of the posterior mass within the tolerance, capped by the model's
        recent support at the answer (``confidence_score="joint"``);
        ``extra`` holds ``posterior_mass``, ``log_odds``, ``p_new_place`` and ``ess``; ``seconds`` the
        filter's wall time.
    """
    from .pipeline import FrontEnd
    from .pipeline import differences as pipeline_differences

    frontend = frontend or FrontEnd()
    d = pipeline_differences(reference, query, frontend) if differences is None else differences
    g = _graph_for(reference, graph, junction_radius_m, edge_length)
    name = model if isinstance(model, str) else type(model).__name__
    obs = build_model(model, reference, window, frontend) if isinstance(model, str) else model
    loc = Localizer(g, obs, n_particles=n_particles, seed=seed, confidence_radius=confidence_radius,
                    confidence_radius_m=confidence_radius_m, **localizer_params)
    odometry = query.odometry if use_odometry and g.unit == "m" else None
    start = time.perf_counter()
    res = loc.run(d, odometry=odometry, query_index=query.index, progress=progress)
    seconds = time.perf_counter() - start
    params = {"model": name, "n_particles": n_particles, "seed": seed, "window": window,
              "junction_radius_m": junction_radius_m, "edge_length": edge_length,
              "odometry": odometry is not None, "confidence_radius": confidence_radius,
              "confidence_radius_m": confidence_radius_m, **localizer_params}
    return RunResult(f"particle-filter/{name}", params, np.asarray(query.index), res.place, res.score,
                     extra={"posterior_mass": res.confidence, "log_odds": res.log_odds,
                            "p_new_place": res.new_place_probability,
                            "ess": res.ess}, seconds=seconds)


def compare_models(reference: Traverse, query: Traverse, ground_truth: GroundTruth,
                   models: Sequence[str] = ("histogram", "histogram-bootstrap", "sequence", "adaptive", "combined"),
                   baselines: Sequence[str] = ("adaptive matcher", "fixed matcher"), window: int = 50,
                   progress: Callable[[str], None] | None = None, **localize_params: Any) -> list[dict]:
    """Run the filter with each model (and the standalone matchers) on one traverse pair.

    Parameters
    ----------
    reference, query : Traverse
    ground_truth : GroundTruth
    models : sequence of str
        Names from :data:`MODEL_NAMES`.
    baselines : sequence of str
        ``"adaptive matcher"`` and/or ``"fixed matcher"`` (window ``window``): the
        standalone :func:`catgraph.sequence.match_sequences`.
    window : int
        Fixed window length (``"sequence"`` model and ``"fixed matcher"``).
    progress : callable, optional
        Called with each method's name before it runs.
    **localize_params
        Passed to :func:`localize` (``n_particles``, ``seed``, ``junction_radius_m``,
        ``edge_length``, ``confidence_radius``, ``confidence_radius_m`` …).

    Returns
    -------
    list of dict
        One row per method: ``method``, ``auc``, ``recall_at_100p``, ``recall_at_99p``,
        ``recall_at_90p``, ``mtl``, ``accuracy``, ``ms_per_frame``.
    """
    from .pipeline import FrontEnd
    from .pipeline import differences as pipeline_differences
    from .sequence import match_sequences

    frontend = localize_params.pop("frontend", None) or FrontEnd()
    d = pipeline_differences(reference, query, frontend)
    needs_boot = any(m in ("histogram-bootstrap", "combined") for m in models)
    r_diff = _reference_differences(reference, frontend) if needs_boot else None
    rows = []

    def row(method: str, result: RunResult) -> dict:
        m = result.evaluate(ground_truth).metrics
        return {"method": method, "auc": m.auc, "recall_at_100p": m.recall_at_100p, "recall_at_99p": m.recall_at_99p,
                "recall_at_90p": m.recall_at_90p, "mtl": m.mtl, "accuracy": m.accuracy,
                "ms_per_frame": 1000.0 * result.seconds / max(len(query), 1)}

    for base in baselines:
        if base not in ("adaptive matcher", "fixed matcher"):
            raise InvalidParameterError(f"unknown baseline {base!r}; use 'adaptive matcher' or 'fixed matcher'.")
        if progress:
            progress(base)
        start = time.perf_counter()
        seq = match_sequences(d, window="adaptive" if base == "adaptive matcher" else window)
        name = base if base == "adaptive matcher" else f"fixed matcher (L={window})"
        rows.append(row(name, RunResult(name, {}, np.asarray(query.index), seq.match, seq.confidence,
                                        seconds=time.perf_counter() - start)))
    for name in models:
        if progress:
            progress(name)
        model = build_model(name, reference, window, frontend, reference_differences=r_diff)
        label = f"filter + {name}" + (f" (L={window})" if name == "sequence" else "")
        rows.append(row(label, localize(reference, query, model, window=window, differences=d, frontend=frontend,
                                        **localize_params)))
    return rows


def format_table(rows: Sequence[dict], title: str | None = None) -> str:
    """Markdown table of :func:`compare_models` rows."""
    head = "| method | AUC | R@100P | R@99P | R@90P | MTL | accuracy | ms/frame |\n|---|---|---|---|---|---|---|---|\n"
    body = "".join(
        f"| {r['method']} | {r['auc']:.3f} | {r['recall_at_100p']:.3f} | {r['recall_at_99p']:.3f} | "
        f"{r['recall_at_90p']:.3f} | {r['mtl']} | {r['accuracy']:.3f} | {r['ms_per_frame']:.2f} |\n"
        for r in rows
    )
    return (f"### {title}\n\n" if title else "") + head + body
