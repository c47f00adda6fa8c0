"""Plots of localisation runs: arrays in, a matplotlib ``Axes`` out.

Every function takes an optional ``ax``; when it is ``None`` a new
:class:`matplotlib.figure.Figure` (not pyplot state, so nothing is shown and no global
figure registry grows) is created with one axes. The axes is returned so calls compose
into the caller's own layouts. matplotlib is imported inside the functions only:
``import catgraph`` never imports it.

The plots and what they show
----------------------------
* :func:`plot_pr_curves` — precision against recall, one line per method. From a result
  payload the curve is rebuilt with :func:`catgraph.metrics.pr_curve` from the per-frame
  ``correct``/``match``/``confidence``; like :func:`catgraph.metrics.auc`, the curve is
  extended to recall 0 at the precision of its first point, so the area under the drawn
  line is the reported AUC.
* :func:`plot_metric_bars` — one metric (AUC, MTL, R@P …) as a bar per method, as in the
  bar charts of the adaptive-window paper comparing fixed and adaptive windows.
* :func:`plot_difference_matrix` — the difference matrix ``D`` (query × reference) as an
  image with query frames along x and reference places along y, the ground truth and the
  chosen matches overlaid (correct matches and wrong ones in different colours).
* :func:`plot_window_length` — the window length ``L_i`` the adaptive matcher chose for
  each query frame; :func:`plot_window_curves` — the curves ``log p_i(L)`` it minimised.
* :func:`plot_posterior` — the particle filter's posterior over places for each frame
  (an image, frames along x), with the estimate and the truth overlaid.
* :func:`plot_new_place_probability` — ``P(new place | Z^k)`` over the frames.
* :func:`plot_localisation_timeline` — per method a strip over the frames, coloured by
  correct / wrong / no output; the longest gap in a strip is the MTL.
* :func:`plot_likelihood` — the learned densities ``P(d|L)`` and ``P(d|¬L)`` from
  histogram bin edges and counts (or densities).
* :func:`plot_place_graph` — the place graph from positions and edges, with highlighted
  places (the estimate), optional per-place mass (the posterior) and the true position.

Frames are drawn in the order given (processing order for result payloads), so a
shuffled query shows the jumps it was processed with.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .exceptions import DataError, InvalidParameterError, ShapeMismatchError

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

__all__ = [
    "METRIC_LABELS",
    "new_axes",
    "method_colors",
    "pr_curve_from_result",
    "plot_pr_curves",
    "plot_metric_bars",
    "plot_difference_matrix",
    "plot_window_length",
    "plot_window_curves",
    "plot_posterior",
    "plot_new_place_probability",
    "plot_localisation_timeline",
    "plot_likelihood",
    "plot_place_graph",
]

#: Display names of the metrics in a result payload.
METRIC_LABELS = {
    "auc": "AUC",
    "recall_at_100p": "R@100P",
    "recall_at_99p": "R@99P",
    "recall_at_90p": "R@90P",
    "mtl": "MTL (frames)",
    "accuracy": "accuracy",
    "n_queries": "n",
}

_CORRECT, _WRONG, _NONE, _TRUTH = "#2ca02c", "#d62728", "#bbbbbb", "cyan"  # truth: cyan, as on the posterior


# ---------------------------------------------------------------------------- helpers
def new_axes(ax: "Axes | None" = None, figsize: tuple[float, float] = (6.4, 4.0)) -> "Axes":
    """Return ``ax``, or one axes on a new :class:`~matplotlib.figure.Figure`.

    The figure is not registered with pyplot (no window, no global state); save it
    with ``ax.figure.savefig(...)``.
    """
    if ax is not None:
        return ax
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return fig.add_subplot()


def method_colors(n: int) -> list:
    """``n`` distinct colours, the same for method ``k`` in every plot (tab10, then tab20)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if n <= 10 else colormaps["tab20"]
    return [cmap(k % cmap.N) for k in range(n)]


def _vector(x: Any, name: str, dtype=np.float64, allow_nan: bool = True) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be a 1-D array of numbers; got {type(x).__name__}.") from None
    if a.ndim != 1:
        raise DataError(f"{name} must be 1-D; got shape {a.shape}.")
    if not allow_nan and a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise DataError(f"{name} must be finite; it holds NaN or infinity.")
    return a


def _matrix(x: Any, name: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be a 2-D array of numbers; got {type(x).__name__}.") from None
    if a.ndim != 2 or a.size == 0:
        raise DataError(f"{name} must be a non-empty 2-D array; got shape {a.shape}.")
    return a


def _optional_list(values: Any) -> list:
    """Payload lists may hold ``None``; turn them into NaN floats."""
    return [np.nan if v is None else v for v in values]


def _labels(items: Sequence, labels: Sequence[str] | None) -> list[str]:
    if labels is not None:
        labels = [str(v) for v in labels]
        if len(labels) != len(items):
            raise ShapeMismatchError(f"{len(labels)} labels given for {len(items)} curves; give one label per curve.")
        return labels
    out = []
    for k, item in enumerate(items):
        if isinstance(item, Mapping):
            out.append(str(item.get("name") or item.get("method") or f"run {k + 1}"))
        else:
            out.append(f"run {k + 1}")
    return out


def _colors(n: int, colors: Sequence | None) -> list:
    if colors is None:
        return method_colors(n)
    colors = list(colors)
    if len(colors) != n:
        raise ShapeMismatchError(f"{len(colors)} colours given for {n} methods; give one colour per method.")
    return colors


# ---------------------------------------------------------------------------- PR curves
def pr_curve_from_result(result: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Recall and precision of a result payload's PR curve (as :func:`catgraph.metrics.evaluate` drew it).

    The number of query frames with a true match (recall's denominator) is taken from
    ``frames["has_true_match"]`` where present; otherwise it is recovered from the
    stored accuracy (``correct / accuracy``), or else taken as every frame.

    Parameters
    ----------
    result : dict
        A payload from :meth:`catgraph.results.RunResult.to_dict` with ground truth.

    Returns
    -------
    recall, precision : ndarray of float64, shape (m,)
        One point per distinct confidence, highest confidence first.
    """
    from .metrics import pr_curve

    frames = result.get("frames") if isinstance(result, Mapping) else None
    if not isinstance(frames, Mapping) or "correct" not in frames:
        raise DataError(
            "this result has no per-frame 'correct' field, so its PR curve cannot be drawn; "
            "evaluate the run with ground truth (--tolerance or --tolerance-m)."
        )
    correct = _vector(frames["correct"], "frames['correct']", dtype=bool)
    match = frames.get("match", [])
    has_output = np.array([m is not None and m >= 0 for m in match], dtype=bool)
    confidence = _vector(_optional_list(frames.get("confidence", [])), "frames['confidence']")
    if not (correct.shape == has_output.shape == confidence.shape):
        raise ShapeMismatchError(
            f"frames of result '{result.get('method')}' disagree in length: correct {correct.size}, "
            f"match {has_output.size}, confidence {confidence.size}."
        )
    has_output &= np.isfinite(confidence)
    n_correct = int(correct.sum())
    if "has_true_match" in frames:
        n_positive = int(np.sum(_vector(frames["has_true_match"], "frames['has_true_match']", dtype=bool)))
    else:
        metrics = result.get("metrics") or {}
        accuracy = metrics.get("accuracy")
        if accuracy and accuracy > 0:
            n_positive = int(round(n_correct / accuracy))
        else:
            n_positive = int(correct.size)
    curve = pr_curve(correct, has_output, confidence, n_positive)
    return curve.recall, curve.precision


def plot_pr_curves(
    curves: Sequence[Any],
    labels: Sequence[str] | None = None,
    ax: "Axes | None" = None,
    colors: Sequence | None = None,
) -> "Axes":
    """Precision–recall curves of several methods, one line each.

    Parameters
    ----------
    curves : sequence
        Each item is a result payload (dict), a :class:`catgraph.metrics.PRCurve`, or a
        pair ``(recall, precision)`` of arrays of shape (m,).
    labels : sequence of str, optional
        Legend entries; by default the payload's ``name`` or ``method``.
    ax : matplotlib Axes, optional
    colors : sequence, optional
        One matplotlib colour per curve (default :func:`method_colors`).

    Returns
    -------
    matplotlib Axes
        With one ``Line2D`` per curve, in the order given.
    """
    curves = list(curves)
    labels = _labels(curves, labels)
    colors = _colors(len(curves), colors)
    ax = new_axes(ax)
    for item, label, color in zip(curves, labels, colors):
        if isinstance(item, Mapping):
            recall, precision = pr_curve_from_result(item)
        elif hasattr(item, "recall") and hasattr(item, "precision"):
            recall, precision = np.asarray(item.recall, float), np.asarray(item.precision, float)
        else:
            try:
                recall, precision = item
            except (TypeError, ValueError):
                raise DataError(
                    f"a PR curve must be a result dict, a PRCurve or a (recall, precision) pair; "
                    f"got {type(item).__name__}."
                ) from None
            recall = _vector(recall, "recall")
            precision = _vector(precision, "precision")
        if recall.shape != precision.shape:
            raise ShapeMismatchError(f"recall has {recall.size} points but precision {precision.size}.")
        if recall.size:
            recall = np.r_[0.0, recall]
            precision = np.r_[precision[0], precision]
        ax.plot(recall, precision, label=label, color=color, linewidth=1.5)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, alpha=0.3)
    if curves:
        ax.legend(loc="lower left", fontsize="small")
    return ax


# ---------------------------------------------------------------------------- metric bars
def plot_metric_bars(
    results: Sequence[Mapping[str, Any]] | Mapping[str, float],
    metric: str = "auc",
    labels: Sequence[str] | None = None,
    ax: "Axes | None" = None,
    colors: Sequence | None = None,
    annotate: bool = True,
) -> "Axes":
    """One metric as a bar per method (AUC, MTL, R@P …).

    Parameters
    ----------
    results : sequence of dict, or mapping label → value
        Result payloads (``metrics[metric]`` is read), or the values themselves.
    metric : str
        A key of the payload's ``metrics``: ``"auc"``, ``"mtl"``, ``"recall_at_100p"``,
        ``"recall_at_99p"``, ``"recall_at_90p"``, ``"accuracy"``.
    labels : sequence of str, optional
        Tick labels (default: the payload's ``name``/``method``, or the mapping's keys).
    ax : matplotlib Axes, optional
    colors : sequence, optional
        One colour per bar.
    annotate : bool
        Write each value above its bar.

    Returns
    -------
    matplotlib Axes
        With one bar (``Rectangle`` in ``ax.patches``) per method; a method without the
        metric gets a bar of height 0 and the annotation "–".
    """
    if isinstance(results, Mapping) and not ("metrics" in results and "method" in results):
        names = [str(k) for k in results]
        values = [results[k] for k in results]
        labels = names if labels is None else _labels(names, labels)
    else:
        items = list(results)
        labels = _labels(items, labels)
        values = []
        for item in items:
            metrics = item.get("metrics") if isinstance(item, Mapping) else None
            values.append(None if not metrics else metrics.get(metric))
    heights = np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    colors = _colors(len(heights), colors)
    ax = new_axes(ax)
    x = np.arange(len(heights))
    bars = ax.bar(x, np.nan_to_num(heights, nan=0.0), color=colors, edgecolor="black", linewidth=0.5)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30 if len(labels) > 3 else 0, ha="right" if len(labels) > 3 else "center",
                       fontsize="small")
    ax.set_ylabel(METRIC_LABELS.get(metric, metric))
    if metric in ("auc", "recall_at_100p", "recall_at_99p", "recall_at_90p", "accuracy"):
        ax.set_ylim(0.0, 1.1)
    ax.grid(True, axis="y", alpha=0.3)
    if annotate:
        integer = metric in ("mtl", "n_queries")
        texts = ["–" if not np.isfinite(h) else (f"{h:.0f}" if integer else f"{h:.3f}") for h in heights]
        ax.bar_label(bars, labels=texts, fontsize="x-small", padding=2)
        if integer and np.isfinite(heights).any():
            ax.set_ylim(0.0, 1.12 * max(1.0, float(np.nanmax(heights))))
    return ax


# ---------------------------------------------------------------------------- difference matrix
def plot_difference_matrix(
    differences: Any,
    true_match: Any = None,
    match: Any = None,
    correct: Any = None,
    ax: "Axes | None" = None,
    cmap: str = "viridis",
    colorbar: bool = True,
) -> "Axes":
    """The difference matrix with the ground truth and the matches overlaid.

    Query frames run along x, reference places along y (origin bottom left).

    Parameters
    ----------
    differences : array-like, shape (n_query, n_reference)
        ``D[i, j]``, the difference of query frame ``i`` to reference place ``j``.
    true_match : array-like, optional
        Ground truth: shape (n_query,) int, the true reference index per query frame
        (``-1`` = none), or shape (n_query, n_reference) bool, every acceptable pair.
    match : array-like of int, shape (n_query,), optional
        The reference index each frame was matched to (``-1`` or NaN = no output).
    correct : array-like of bool, shape (n_query,), optional
        Colours the matches (green correct, red wrong); without it they are white.
    ax : matplotlib Axes, optional
    cmap : str
        Colour map of the image.
    colorbar : bool
        Add a colour bar.

    Returns
    -------
    matplotlib Axes
        With one ``AxesImage``; the truth and the matches are ``ax.collections``
        (scatter) labelled "ground truth", "correct match", "wrong match", "match".
    """
    d = _matrix(differences, "differences")
    n_query, n_reference = d.shape
    ax = new_axes(ax, figsize=(6.4, 5.0))
    finite = d[np.isfinite(d)]
    vmin, vmax = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
    image = ax.imshow(d.T, origin="lower", aspect="auto", cmap=cmap, interpolation="nearest", vmin=vmin, vmax=vmax,
                      extent=(-0.5, n_query - 0.5, -0.5, n_reference - 0.5))
    if colorbar:
        ax.figure.colorbar(image, ax=ax, label="difference")
    marker = max(0.5, min(8.0, 2000.0 / max(n_query, 1)))
    truth = (np.zeros(0), np.zeros(0))
    if true_match is not None:
        t = np.asarray(true_match)
        if t.ndim == 2:
            if t.shape != d.shape:
                raise ShapeMismatchError(f"true_match has shape {t.shape} but differences {d.shape}; they must agree.")
            qi, rj = np.nonzero(t.astype(bool))
        else:
            t = _vector(_optional_list(t) if t.dtype == object else t, "true_match")
            if t.size != n_query:
                raise ShapeMismatchError(f"true_match has {t.size} entries for {n_query} query frames.")
            qi = np.flatnonzero(np.isfinite(t) & (t >= 0))
            rj = t[qi]
        truth = (qi, rj)
    if match is not None:
        m = np.asarray(_optional_list(match) if isinstance(match, list) else match, dtype=np.float64)
        m = _vector(m, "match")
        if m.size != n_query:
            raise ShapeMismatchError(f"match has {m.size} entries for {n_query} query frames.")
        has = np.isfinite(m) & (m >= 0)
        if correct is None:
            ax.scatter(np.flatnonzero(has), m[has], s=marker, color="white", marker="x", linewidths=0.8, label="match",
                       zorder=2)
        else:
            c = _vector(correct, "correct", dtype=bool)
            if c.size != n_query:
                raise ShapeMismatchError(f"correct has {c.size} entries for {n_query} query frames.")
            for mask, color, name in ((has & c, _CORRECT, "correct match"), (has & ~c, _WRONG, "wrong match")):
                ax.scatter(np.flatnonzero(mask), m[mask], s=marker * 1.5, color=color, marker="x",
                           linewidths=0.8, label=name, zorder=2)
    if true_match is not None:
        # the truth is drawn last, smaller and on top, so no match marker can hide it
        ax.scatter(*truth, s=marker * 0.6, color=_TRUTH, alpha=0.9, linewidths=0, label="ground truth", zorder=3)
    ax.set_xlim(-0.5, n_query - 0.5)
    ax.set_ylim(-0.5, n_reference - 0.5)
    ax.set_xlabel("query frame")
    ax.set_ylabel("reference place")
    if true_match is not None or match is not None:
        ax.legend(loc="upper left", fontsize="x-small", markerscale=3)
    return ax


# ---------------------------------------------------------------------------- adaptive window
def plot_window_length(
    window_length: Any | Sequence[Any],
    labels: Sequence[str] | None = None,
    ax: "Axes | None" = None,
    colors: Sequence | None = None,
    log_scale: bool = False,
) -> "Axes":
    """Window length chosen for each query frame (one step line per run).

    Parameters
    ----------
    window_length : array-like, shape (n,), or a sequence of them
        ``L_i`` per frame in processing order (NaN/None where undefined).
    labels : sequence of str, optional
    ax : matplotlib Axes, optional
    colors : sequence, optional
    log_scale : bool
        Logarithmic y axis (useful for a geometric grid of window lengths).

    Returns
    -------
    matplotlib Axes
        With one ``Line2D`` per run.
    """
    series = _series(window_length, "window_length")
    ax = new_axes(ax, figsize=(7.0, 3.0))
    names = _labels(series, labels) if labels is not None or len(series) > 1 else [None]
    for values, label, color in zip(series, names, _colors(len(series), colors)):
        ax.step(np.arange(values.size), values, where="mid", linewidth=0.9, color=color, label=label)
    ax.set_xlabel("query frame (processing order)")
    ax.set_ylabel("window length L (frames)")
    if log_scale:
        ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    if names[0] is not None:
        ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_window_curves(
    window_grid: Any,
    log_p: Any,
    frames: Sequence[int] | None = None,
    ax: "Axes | None" = None,
) -> "Axes":
    """The curves ``log p_i(L)`` the adaptive matcher minimises, for a few frames.

    Parameters
    ----------
    window_grid : array-like of int, shape (G,)
        Candidate window lengths.
    log_p : array-like, shape (n, G) or (G,)
        ``log p_i(L)`` per frame and candidate (``+inf`` where a window is inadmissible).
    frames : sequence of int, optional
        Rows to draw (default: up to five evenly spaced rows).
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib Axes
        One ``Line2D`` per frame drawn, each with its minimum marked.
    """
    grid = _vector(window_grid, "window_grid")
    lp = np.asarray(log_p, dtype=np.float64)
    if lp.ndim == 1:
        lp = lp[None, :]
    if lp.ndim != 2 or lp.shape[1] != grid.size:
        raise ShapeMismatchError(f"log_p must have shape (n, {grid.size}) to match window_grid; got {lp.shape}.")
    if frames is None:
        frames = np.unique(np.linspace(0, lp.shape[0] - 1, min(5, lp.shape[0])).round().astype(int))
    frames = [int(f) for f in frames]
    bad = [f for f in frames if not 0 <= f < lp.shape[0]]
    if bad:
        raise InvalidParameterError(f"frames {bad} are outside 0..{lp.shape[0] - 1}.")
    ax = new_axes(ax)
    for f, color in zip(frames, method_colors(len(frames))):
        row = np.where(np.isfinite(lp[f]), lp[f], np.nan)
        ax.plot(grid, row, color=color, linewidth=1.2, label=f"frame {f}")
        if np.isfinite(row).any():
            k = int(np.nanargmin(row))
            ax.plot(grid[k], row[k], "o", color=color, markersize=5)
    ax.set_xscale("log" if grid.min() > 0 and grid.max() / grid.min() > 20 else "linear")
    ax.set_xlabel("window length L (frames)")
    ax.set_ylabel("log p_i(L)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return ax


def _series(values: Any, name: str) -> list[np.ndarray]:
    """One 1-D array, or a sequence of 1-D arrays (lengths may differ)."""
    if isinstance(values, np.ndarray) and values.ndim == 1:
        return [_vector(values, name)]
    values = list(values)
    if values and all(np.ndim(v) == 0 for v in values):
        return [_vector(_optional_list(values), name)]
    return [_vector(_optional_list(list(v)), f"{name}[{k}]") for k, v in enumerate(values)]


# ---------------------------------------------------------------------------- particle filter
def plot_posterior(
    posterior: Any,
    estimate: Any = None,
    true_place: Any = None,
    ax: "Axes | None" = None,
    log: bool = False,
    cmap: str = "magma",
    colorbar: bool = True,
) -> "Axes":
    """The posterior over places for every frame, as an image (frames along x).

    Parameters
    ----------
    posterior : array-like, shape (n_frames, n_places)
        ``P(L_k = place | Z^k)``, one row per frame.
    estimate : array-like of int, shape (n_frames,), optional
        The place reported per frame (``-1`` = none); drawn as white dots.
    true_place : array-like, shape (n_frames,), optional
        The true place per frame (``-1``/NaN = none, e.g. a new place); drawn in cyan.
    ax : matplotlib Axes, optional
    log : bool
        Show ``log10`` of the posterior (floored at 1e-6) instead of the posterior.
    cmap : str
    colorbar : bool

    Returns
    -------
    matplotlib Axes
        With one ``AxesImage``; overlays are scatter collections.
    """
    p = _matrix(posterior, "posterior")
    n_frames, n_places = p.shape
    ax = new_axes(ax, figsize=(7.0, 4.0))
    shown = np.log10(np.maximum(p, 1e-6)) if log else p
    image = ax.imshow(shown.T, origin="lower", aspect="auto", cmap=cmap, interpolation="nearest",
                      extent=(-0.5, n_frames - 0.5, -0.5, n_places - 0.5))
    if colorbar:
        ax.figure.colorbar(image, ax=ax, label="log10 posterior" if log else "posterior")
    marker = max(1.0, min(10.0, 2000.0 / max(n_frames, 1)))
    for values, color, name, style in ((true_place, "cyan", "true place", "_"), (estimate, "white", "estimate", ".")):
        if values is None:
            continue
        v = _vector(_optional_list(values) if isinstance(values, list) else values, name)
        if v.size != n_frames:
            raise ShapeMismatchError(f"{name} has {v.size} entries for {n_frames} frames.")
        ok = np.isfinite(v) & (v >= 0)
        ax.scatter(np.flatnonzero(ok), v[ok], s=marker * 2, color=color, marker=style, linewidths=1.0, label=name)
    ax.set_xlim(-0.5, n_frames - 0.5)
    ax.set_ylim(-0.5, n_places - 0.5)
    ax.set_xlabel("query frame (processing order)")
    ax.set_ylabel("place")
    if estimate is not None or true_place is not None:
        ax.legend(loc="upper left", fontsize="x-small", markerscale=2)
    return ax


def plot_new_place_probability(
    p_new_place: Any | Sequence[Any],
    labels: Sequence[str] | None = None,
    is_new_place: Any = None,
    threshold: float | None = None,
    ax: "Axes | None" = None,
    colors: Sequence | None = None,
) -> "Axes":
    """``P(new place | Z^k)`` over the frames, one line per run.

    Parameters
    ----------
    p_new_place : array-like, shape (n,), or a sequence of them
        Probability per frame in processing order.
    labels : sequence of str, optional
    is_new_place : array-like of bool, shape (n,), optional
        Frames truly outside the map; shaded grey.
    threshold : float, optional
        Decision threshold, drawn as a dashed line.
    ax : matplotlib Axes, optional
    colors : sequence, optional

    Returns
    -------
    matplotlib Axes
        With one ``Line2D`` per run (plus the threshold line, when given).
    """
    series = _series(p_new_place, "p_new_place")
    ax = new_axes(ax, figsize=(7.0, 3.0))
    if is_new_place is not None:
        truth = _vector(is_new_place, "is_new_place", dtype=bool)
        edges = np.diff(np.r_[0, truth.astype(np.int8), 0])
        for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            ax.axvspan(start - 0.5, stop - 0.5, color="0.85", zorder=0, linewidth=0)
    names = _labels(series, labels) if labels is not None or len(series) > 1 else [None]
    for values, label, color in zip(series, names, _colors(len(series), colors)):
        ax.plot(np.arange(values.size), values, linewidth=0.9, color=color, label=label)
    if threshold is not None:
        ax.axhline(float(threshold), color="black", linestyle="--", linewidth=0.8)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("query frame (processing order)")
    ax.set_ylabel("P(new place)")
    ax.grid(True, alpha=0.3)
    if names[0] is not None:
        ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_localisation_timeline(
    results: Sequence[Mapping[str, Any]] | Sequence[Any],
    labels: Sequence[str] | None = None,
    ax: "Axes | None" = None,
    initialisation: Sequence[int] | None = None,
) -> "Axes":
    """Per method a strip over the frames: correct (green), wrong (red), no output (grey).

    Parameters
    ----------
    results : sequence
        Result payloads (``frames["correct"]`` and ``frames["match"]`` are read) or
        boolean arrays of shape (n,) (correct per frame).
    labels : sequence of str, optional
    ax : matplotlib Axes, optional
    initialisation : sequence of int, optional
        Per method, the number of first frames spent learning (an online model's
        ``T_init``); hatched, so that they are not read as failures of the method.

    Returns
    -------
    matplotlib Axes
        With one ``AxesImage`` of shape (n_methods, n_frames).
    """
    from matplotlib.colors import ListedColormap

    items = list(results)
    labels = _labels(items, labels)
    rows = []
    for item in items:
        if isinstance(item, Mapping):
            frames = item.get("frames") or {}
            if "correct" not in frames:
                raise DataError(
                    f"result '{item.get('method')}' has no per-frame 'correct'; evaluate it with ground truth."
                )
            ok = _vector(frames["correct"], "correct", dtype=bool)
            has = np.array([m is not None and m >= 0 for m in frames.get("match", [True] * ok.size)], dtype=bool)
        else:
            ok = _vector(item, "correct", dtype=bool)
            has = np.ones_like(ok)
        rows.append(np.where(ok, 2, np.where(has, 1, 0)))
    n = max((r.size for r in rows), default=0)
    code = np.full((len(rows), max(n, 1)), -1.0)
    for k, r in enumerate(rows):
        code[k, : r.size] = r
    ax = new_axes(ax, figsize=(7.0, 0.6 + 0.35 * max(len(rows), 1)))
    cmap = ListedColormap(["white", _NONE, _WRONG, _CORRECT])
    ax.imshow(code, aspect="auto", interpolation="nearest", cmap=cmap, vmin=-1.5, vmax=2.5,
              extent=(-0.5, code.shape[1] - 0.5, len(rows) - 0.5, -0.5))
    if initialisation is not None:
        from matplotlib.patches import Rectangle

        spans = list(initialisation)
        if len(spans) != len(rows):
            raise ShapeMismatchError(f"initialisation has {len(spans)} entries for {len(rows)} methods.")
        hatched = False
        for k, frames in enumerate(spans):
            frames = min(int(frames or 0), code.shape[1])
            if frames > 0:
                ax.add_patch(Rectangle((-0.5, k - 0.5), frames, 1.0, fill=False, hatch="////", edgecolor="black",
                                       linewidth=0.0, alpha=0.45, label=None if hatched else "learning (T_init)"))
                hatched = True
        if hatched:
            ax.legend(loc="upper right", fontsize="x-small", framealpha=0.8)
    ax.set_yticks(np.arange(len(rows)))
    ax.set_yticklabels(labels, fontsize="small")
    ax.set_xlabel("query frame (processing order)")
    return ax


# ---------------------------------------------------------------------------- likelihood model
def plot_likelihood(
    bin_edges: Any,
    same: Any,
    different: Any,
    ax: "Axes | None" = None,
    normalize: bool = True,
    labels: tuple[str, str] = ("P(d | L)  same place", "P(d | ¬L)  different place"),
) -> "Axes":
    """The learned densities ``P(d|L)`` and ``P(d|¬L)`` as step lines.

    Parameters
    ----------
    bin_edges : array-like, shape (s + 1,)
        Histogram bin edges over the difference ``d``, increasing.
    same, different : array-like, shape (s,)
        Counts (or densities) per bin for same-place and different-place differences,
        e.g. ``HistogramLikelihood.counts_same_`` and ``.counts_different_``.
    ax : matplotlib Axes, optional
    normalize : bool
        Divide each histogram by its total times the bin width, so both integrate to 1
        (a density is left unchanged by this).
    labels : pair of str

    Returns
    -------
    matplotlib Axes
        With two ``StepPatch`` in ``ax.patches`` (same place first).
    """
    edges = _vector(bin_edges, "bin_edges", allow_nan=False)
    if edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise DataError("bin_edges must hold at least two strictly increasing values.")
    width = np.diff(edges)
    ax = new_axes(ax)
    for values, label, color in ((same, labels[0], _CORRECT), (different, labels[1], _WRONG)):
        h = _vector(values, label.split()[0], allow_nan=False)
        if h.size != width.size:
            raise ShapeMismatchError(f"{h.size} histogram values for {width.size} bins; give one value per bin.")
        if np.any(h < 0):
            raise DataError("histogram counts and densities must be ≥ 0.")
        if normalize:
            total = float(np.sum(h * width))
            h = h / total if total > 0 else h
        ax.stairs(h, edges, label=label, color=color, linewidth=1.4, fill=False)
    ax.set_xlabel("difference d")
    ax.set_ylabel("density" if normalize else "count")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return ax


# ---------------------------------------------------------------------------- place graph
def plot_place_graph(
    positions: Any,
    edges: Any,
    highlight: Any = None,
    place_weights: Any = None,
    true_position: Any = None,
    ax: "Axes | None" = None,
    node_size: float = 6.0,
) -> "Axes":
    """The place graph drawn at the places' positions, with the estimate highlighted.

    Parameters
    ----------
    positions : array-like, shape (N, 2) or (N, 3)
        Place positions (only x and y are drawn), e.g. ``PlaceGraph.positions``.
    edges : array-like of int, shape (E, 2)
        Source and target place of each edge, e.g.
        ``numpy.column_stack([graph.source, graph.target])``. Edges in both directions
        are drawn once.
    highlight : int or array-like of int, optional
        Places to mark (the estimate), drawn as large red circles.
    place_weights : array-like, shape (N,), optional
        Mass per place (e.g. the posterior); colours the nodes.
    true_position : array-like, shape (2,) or (2|3,), optional
        The true position, drawn as a star.
    ax : matplotlib Axes, optional
    node_size : float
        Marker area of an ordinary node.

    Returns
    -------
    matplotlib Axes
        ``ax.collections`` holds the edges (a ``LineCollection``), the nodes, and one
        collection each for the highlighted places and the true position.
    """
    from matplotlib.collections import LineCollection

    pos = _matrix(positions, "positions")
    if pos.shape[1] < 2:
        raise DataError(f"positions must have 2 or 3 columns (x, y[, z]); got {pos.shape[1]}.")
    xy = pos[:, :2]
    n = len(xy)
    e = np.asarray(edges)
    if e.size == 0:
        e = np.zeros((0, 2), dtype=np.int64)
    if e.ndim != 2 or e.shape[1] != 2 or e.dtype.kind not in "iu":
        raise DataError(
            f"edges must be an (E, 2) integer array of place indices; got shape {e.shape}, dtype {e.dtype}."
        )
    if e.size and (e.min() < 0 or e.max() >= n):
        raise DataError(f"edges refer to places outside 0..{n - 1}.")
    undirected = np.unique(np.sort(e, axis=1), axis=0) if e.size else e
    ax = new_axes(ax, figsize=(6.0, 6.0))
    ax.add_collection(LineCollection(xy[undirected], colors="0.6", linewidths=0.8, zorder=1))
    if place_weights is not None:
        w = _vector(place_weights, "place_weights", allow_nan=False)
        if w.size != n:
            raise ShapeMismatchError(f"place_weights has {w.size} entries for {n} places.")
        order = np.argsort(w)
        nodes = ax.scatter(xy[order, 0], xy[order, 1], c=w[order], s=node_size * 1.5, cmap="viridis", zorder=2)
        ax.figure.colorbar(nodes, ax=ax, label="posterior mass", shrink=0.8)
    else:
        ax.scatter(xy[:, 0], xy[:, 1], s=node_size, color="0.3", zorder=2)
    if highlight is not None:
        h = np.atleast_1d(np.asarray(highlight))
        if h.dtype.kind not in "iu" or (h.size and (h.min() < 0 or h.max() >= n)):
            raise DataError(f"highlight must be place indices in 0..{n - 1}; got {highlight!r}.")
        ax.scatter(xy[h, 0], xy[h, 1], s=node_size * 12, facecolors="none", edgecolors=_WRONG, linewidths=1.8,
                   zorder=3, label="estimate")
    if true_position is not None:
        t = _vector(true_position, "true_position", allow_nan=False)
        if t.size < 2:
            raise DataError("true_position needs at least x and y.")
        ax.scatter([t[0]], [t[1]], s=node_size * 20, marker="*", color="gold", edgecolors="black", linewidths=0.6,
                   zorder=4, label="true position")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if highlight is not None or true_position is not None:
        ax.legend(loc="best", fontsize="small")
    return ax
