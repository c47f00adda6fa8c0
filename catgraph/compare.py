"""Several methods on the same inputs: the ``catgraph compare`` plan and its table.

Comparing observation models on the same data is a first-class use (DESIGN.md §6).
:func:`compare_plan` lists what ``catgraph compare`` runs — the standalone matchers
(single frame, a fixed window, the adaptive window), the histogram recogniser, and the
particle filter with every observation model of :data:`catgraph.methods.FILTER_MODELS`
— as ``(method, params)`` pairs for :func:`catgraph.experiment.run_method`, all on one
:class:`~catgraph.experiment.Prepared` input (one difference matrix).
:func:`format_table` renders evaluated rows as Markdown.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

from .methods import FILTER_MODELS

if TYPE_CHECKING:  # pragma: no cover
    from .results import RunResult
    from .traverse import GroundTruth, Traverse

__all__ = ["COMPARE_WINDOW", "compare_window", "compare_plan", "compare_models", "localize", "format_table"]

#: The fixed window (frames) of a comparison's standalone matcher and of its filter's
#: ``sequence`` model where none is given (:func:`compare_window`).
COMPARE_WINDOW = 50


def compare_window(n_query: int, window: int | None = None) -> int:
    """The fixed window a comparison runs: ``window`` where given, else
    :data:`COMPARE_WINDOW` or the query's ``n_query`` frames, whichever is shorter (a
    window longer than the query is refused, and a default should not be).

    Examples
    --------
    >>> compare_window(3576), compare_window(30), compare_window(30, 10)
    (50, 30, 10)
    """
    return min(COMPARE_WINDOW, max(int(n_query), 1)) if window is None else window


def compare_plan(window: int = COMPARE_WINDOW, filter_params: dict[str, Any] | None = None,
                 models: Sequence[str] = FILTER_MODELS) -> list[tuple[str, dict]]:
    """``(method, params)`` pairs that ``catgraph compare`` runs.

    Parameters
    ----------
    window : int
        The fixed window of the standalone matcher and of the filter's ``sequence`` model.
    filter_params : dict, optional
        Parameters every filter run gets (``n_particles``, ``seed`` …).
    models : sequence of str
        Observation models of the filter runs.
    """
    plan = [("single-frame", {}), ("sequence", {"window": window}), ("sequence", {"window": "adaptive"}),
            ("histogram", {"learning": "online"})]
    for model in models:
        params = {"model": model, **(filter_params or {})}
        if model == "sequence":
            params["window"] = window
        plan.append(("filter", params))
    return plan


def localize(reference: "Traverse", query: "Traverse", model: str = "histogram", differences=None,
             frontend: dict | None = None, junction_radius_m: float | None = None, progress: bool = False,
             **params: Any) -> "RunResult":
    """The particle filter with observation ``model`` on loaded traverses (method ``filter``)."""
    from .experiment import prepared_from, run_method

    prepared = prepared_from(reference, query, differences, frontend=frontend, junction_radius_m=junction_radius_m)
    return run_method("filter", {"model": model, **params}, prepared, progress=progress)


def compare_models(reference: "Traverse", query: "Traverse", ground_truth: "GroundTruth",
                   models: Sequence[str] = FILTER_MODELS, window: int | None = None, progress=None,
                   junction_radius_m: float | None = None, **filter_params: Any) -> list[dict]:
    """Run :func:`compare_plan` on one traverse pair; one evaluated row per method (see
    :func:`format_table`). ``window``: the fixed window, by default :func:`compare_window`'s."""
    from .experiment import prepared_from, run_method

    prepared = prepared_from(reference, query, ground_truth=ground_truth, junction_radius_m=junction_radius_m)
    rows = []
    for method, params in compare_plan(compare_window(len(prepared.query), window), filter_params, models):
        if progress:
            progress(method if method != "filter" else f"filter + {params['model']}")
        result = run_method(method, params, prepared)
        m = result.evaluate(ground_truth).metrics
        rows.append({"method": result.method, "auc": m.auc, "recall_at_100p": m.recall_at_100p,
                     "recall_at_99p": m.recall_at_99p, "recall_at_90p": m.recall_at_90p, "mtl": m.mtl,
                     "accuracy": m.accuracy, "ms_per_frame": 1000.0 * result.seconds / max(len(query), 1)})
    return rows


def format_table(rows: Sequence[dict], title: str | None = None) -> str:
    """Markdown table of rows with ``method``, ``auc``, ``recall_at_100p``, ``recall_at_99p``,
    ``recall_at_90p``, ``mtl``, ``accuracy`` and ``ms_per_frame``."""
    head = "| method | AUC | R@100P | R@99P | R@90P | MTL | accuracy | ms/frame |\n|---|---|---|---|---|---|---|---|\n"
    body = "".join(
        f"| {r['method']} | {r['auc']:.3f} | {r['recall_at_100p']:.3f} | {r['recall_at_99p']:.3f} | "
        f"{r['recall_at_90p']:.3f} | {r['mtl']} | {r['accuracy']:.3f} | {r['ms_per_frame']:.2f} |\n"
        for r in rows
    )
    return (f"### {title}\n\n" if title else "") + head + body
