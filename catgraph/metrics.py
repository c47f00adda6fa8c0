"""Evaluation: precision–recall, AUC, recall at precision, MTL, accuracy.

Every method yields, per query frame in the order it was processed, a best reference
match (``-1`` = no output) and a confidence (higher = surer). With a
:class:`~catgraph.traverse.GroundTruth`:

* **correct** — the frame has an output and it is a true match (within tolerance).
* **PR curve** — sweep a threshold ``t`` over the distinct confidences, highest first;
  a frame is *accepted* when it has an output and ``confidence ≥ t`` (frames with equal
  confidence enter together, so ties never depend on order).
  ``precision(t) = TP / accepted`` and ``recall(t) = TP / P``, where ``P`` is the number
  of query frames that have a true match in the reference.
* **AUC** — the area under the PR curve by the trapezoid rule over recall, the curve
  being extended to recall 0 at the precision of its first point.
* **R@100P, R@99P, R@90P** — the largest recall among curve points whose precision is
  ≥ 1.00, 0.99, 0.90 (0 when no point is).
* **MTL** (maximum time to localisation) — the longest run of consecutive query frames,
  in processing order, without a correct match; frames with no output count as not
  localised.
* **accuracy** — correct frames / ``P`` (top-1 correct fraction of the frames that can
  be localised).

When ``P = 0`` recall-based figures are 0. All functions are pure.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .exceptions import DataError, ShapeMismatchError
from .traverse import GroundTruth

__all__ = ["PRCurve", "Metrics", "Evaluation", "pr_curve", "auc", "recall_at_precision", "max_time_to_localisation",
           "evaluate"]


@dataclass(frozen=True)
class PRCurve:
    """Points of a precision–recall curve, one per distinct confidence, highest first."""

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray


@dataclass(frozen=True)
class Metrics:
    auc: float
    recall_at_100p: float
    recall_at_99p: float
    recall_at_90p: float
    mtl: int
    accuracy: float
    n_queries: int

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Evaluation:
    metrics: Metrics
    correct: np.ndarray
    has_true_match: np.ndarray
    curve: PRCurve


def pr_curve(correct: np.ndarray, has_output: np.ndarray, confidence: np.ndarray, n_positive: int) -> PRCurve:
    """Precision–recall points from per-frame correctness and confidence.

    Parameters
    ----------
    correct, has_output : ndarray of bool, shape (n,)
    confidence : ndarray of float, shape (n,)
        Only frames with an output are read; they must be finite.
    n_positive : int
        Frames with a true match (recall's denominator).
    """
    correct = np.asarray(correct, dtype=bool)
    has_output = np.asarray(has_output, dtype=bool)
    conf = np.asarray(confidence, dtype=np.float64)
    c = conf[has_output]
    if not np.all(np.isfinite(c)):
        raise DataError("confidences of frames with an output must be finite; got NaN or infinity.")
    ok = correct[has_output]
    order = np.argsort(-c, kind="stable")
    c, ok = c[order], ok[order]
    if c.size == 0:
        empty = np.zeros(0)
        return PRCurve(empty, empty, empty)
    last_of_tie = np.r_[c[1:] != c[:-1], True]
    tp = np.cumsum(ok)[last_of_tie]
    accepted = np.flatnonzero(last_of_tie) + 1
    precision = tp / accepted
    recall = tp / n_positive if n_positive > 0 else np.zeros(len(tp))
    return PRCurve(c[last_of_tie], precision, recall)


def auc(curve: PRCurve) -> float:
    """Area under the PR curve (trapezoid over recall, extended to recall 0)."""
    if curve.recall.size == 0:
        return 0.0
    r = np.r_[0.0, curve.recall]
    p = np.r_[curve.precision[0], curve.precision]
    return float(np.sum(np.diff(r) * (p[1:] + p[:-1]) / 2.0))


def recall_at_precision(curve: PRCurve, precision: float) -> float:
    """Largest recall among points with precision ≥ ``precision`` (0 if none)."""
    ok = curve.precision >= precision - 1e-12
    return float(curve.recall[ok].max()) if ok.any() else 0.0


def max_time_to_localisation(correct: np.ndarray) -> int:
    """Longest run of consecutive ``False`` in ``correct`` (processing order)."""
    c = np.asarray(correct, dtype=bool)
    if c.size == 0:
        return 0
    # indices of correct frames, with sentinels before the start and after the end
    hits = np.r_[-1, np.flatnonzero(c), c.size]
    return int(np.max(np.diff(hits)) - 1)


def evaluate(query_index, match, confidence, ground_truth: GroundTruth) -> Evaluation:
    """Evaluate per-frame outputs, given in processing order, against ground truth.

    Parameters
    ----------
    query_index : ndarray of int, shape (n,)
        Index of each processed frame in the query as loaded (``Traverse.index``).
    match : ndarray of int, shape (n,)
        Reference index (as loaded) of the best match; ``-1`` for no output.
    confidence : ndarray of float, shape (n,)
        Higher = surer; ignored where there is no output.
    ground_truth : GroundTruth

    Returns
    -------
    Evaluation
        ``metrics`` (AUC, R@100P/99P/90P, MTL, accuracy, n_queries), per-frame
        ``correct`` and ``has_true_match``, and the PR ``curve``.
    """
    q = np.asarray(query_index)
    m = np.asarray(match)
    conf = np.asarray(confidence, dtype=np.float64)
    if not (q.shape == m.shape == conf.shape) or q.ndim != 1:
        raise ShapeMismatchError(
            f"query_index, match and confidence must be 1-D of one length; got {q.shape}, {m.shape}, {conf.shape}."
        )
    correct = ground_truth.correct(q, m)
    has = ground_truth.has_true_match(q)
    n_positive = int(has.sum())
    curve = pr_curve(correct, m >= 0, conf, n_positive)
    metrics = Metrics(
        auc=auc(curve),
        recall_at_100p=recall_at_precision(curve, 1.0),
        recall_at_99p=recall_at_precision(curve, 0.99),
        recall_at_90p=recall_at_precision(curve, 0.90),
        mtl=max_time_to_localisation(correct),
        accuracy=float(correct.sum() / n_positive) if n_positive else 0.0,
        n_queries=int(q.size),
    )
    return Evaluation(metrics, correct, has, curve)
