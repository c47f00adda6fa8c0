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

Frames with no output
    ``match = -1`` means "no output" (a frame with no information, or a method that
    abstains). Its confidence is never read, whatever it holds (``0``, ``-inf``, NaN),
    so no convention for it can leak into a curve; confidences of frames *with* an
    output must be finite. Inputs are checked at the boundary: indices must be
    integers (or floats holding whole numbers), one per frame, and ``match`` must lie
    in ``[-1, n_reference)`` where the ground truth knows ``n_reference``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
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


def _indices(values, name: str) -> np.ndarray:
    """1-D integer indices (whole-number floats accepted), possibly empty."""
    arr = check_array(values, name, ndim=1, dtype=None, allow_empty=True, finite=False)
    if arr.dtype.kind in "iu":
        return arr.astype(np.int64, copy=False)
    if arr.dtype.kind == "f":
        if arr.size and (not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)) or np.abs(arr).max() > 2**62):
            raise DataError(f"{name} must hold whole-number indices; found NaN, infinite or fractional values.")
        return arr.astype(np.int64)
    raise DataError(f"{name} must be integer indices; got dtype {arr.dtype}.")


def _flags(values, name: str) -> np.ndarray:
    """1-D booleans (0/1 integers accepted), possibly empty."""
    arr = check_array(values, name, ndim=1, dtype=None, allow_empty=True, finite=False)
    if arr.dtype.kind == "b":
        return arr
    if arr.dtype.kind in "iuf" and np.all((arr == 0) | (arr == 1)):
        return arr.astype(bool)
    raise DataError(f"{name} must be booleans (or 0/1), one per frame; got dtype {arr.dtype} with other values.")


def _confidences(values, name: str = "confidence") -> np.ndarray:
    """1-D real confidences; NaN/inf allowed here (only frames with an output are checked)."""
    return check_array(values, name, ndim=1, dtype=np.float64, allow_empty=True, finite=False)


def pr_curve(correct: np.ndarray, has_output: np.ndarray, confidence: np.ndarray, n_positive: int) -> PRCurve:
    """Precision–recall points from per-frame correctness and confidence.

    Parameters
    ----------
    correct, has_output : ndarray of bool, shape (n,)
    confidence : ndarray of float, shape (n,)
        Only frames with an output are read; they must be finite.
    n_positive : int
        Frames with a true match (recall's denominator); at least the number of
        correct frames with an output.
    """
    correct = _flags(correct, "correct")
    has_output = _flags(has_output, "has_output")
    conf = _confidences(confidence)
    if not correct.shape == has_output.shape == conf.shape:
        raise ShapeMismatchError(
            f"correct, has_output and confidence must have one value per frame; got shapes {correct.shape}, "
            f"{has_output.shape} and {conf.shape}."
        )
    check_scalar(n_positive, "n_positive", "pr_curve", int, 0)
    if int(np.count_nonzero(correct & has_output)) > n_positive:
        raise DataError(
            f"{int(np.count_nonzero(correct & has_output))} frames are correct but n_positive is {n_positive}; "
            "n_positive counts the frames with a true match and cannot be smaller."
        )
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
    """Largest recall among points with precision ≥ ``precision`` (0 if none), the
    precision a fraction in ``(0, 1]`` (0.99, not 99)."""
    if isinstance(precision, bool) or not isinstance(precision, (int, float, np.integer, np.floating)) \
            or not 0.0 < precision <= 1.0:
        raise InvalidParameterError(f"the precision must be a fraction in (0, 1], e.g. 0.99 for 99 %; got {precision!r}.")
    ok = curve.precision >= precision - 1e-12
    return float(curve.recall[ok].max()) if ok.any() else 0.0


def max_time_to_localisation(correct: np.ndarray) -> int:
    """Longest run of consecutive ``False`` in ``correct`` (processing order)."""
    c = _flags(correct, "correct")
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
    q = _indices(query_index, "query_index")
    m = _indices(match, "match")
    conf = _confidences(confidence)
    if not (q.shape == m.shape == conf.shape):
        raise ShapeMismatchError(
            f"query_index, match and confidence must be 1-D of one length; got {q.shape}, {m.shape}, {conf.shape}."
        )
    if not isinstance(ground_truth, GroundTruth):
        raise DataError(f"ground_truth must be a catgraph GroundTruth; got {type(ground_truth).__name__}.")
    if np.any(m < -1):
        raise DataError(f"match holds {int(np.sum(m < -1))} values below -1; use -1 for 'no output'.")
    n_reference = getattr(ground_truth, "n_reference", None)
    if isinstance(n_reference, (int, np.integer)) and np.any(m >= n_reference):
        raise DataError(
            f"match holds reference indices up to {int(m.max())} but the reference has {int(n_reference)} places."
        )
    if np.any(q < 0):
        raise DataError("query_index holds negative values; give each frame's index in the query as loaded.")
    correct = ground_truth.correct(q, m)
    has = ground_truth.has_true_match(q)
    n_positive = int(has.sum())
    has_output = m >= 0
    if not np.all(np.isfinite(conf[has_output])):
        bad = int(np.count_nonzero(~np.isfinite(conf[has_output])))
        raise DataError(
            f"{bad} frames with an output have a NaN or infinite confidence; a confidence must be a finite number "
            "(a frame with no output has match -1)."
        )
    if n_positive == 0 and q.size:
        from .exceptions import warn

        warn(f"none of the {q.size} query frames has a true match in the ground truth, so every figure is 0 "
             f"and MTL is {q.size}. Check that the ground truth and the traverses number their frames alike "
             "(query frames by Traverse.index as loaded, which a slice keeps; reference places by row).")
    curve = pr_curve(correct, has_output, conf, n_positive)
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
