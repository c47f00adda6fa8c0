"""Per-frame results of a localisation run, and their JSON form.

Every command that evaluates writes::

    {"method": str, "params": {...},
     "metrics": {"auc", "recall_at_100p", "recall_at_99p", "recall_at_90p", "mtl", "accuracy", "n_queries"},
     "frames": {"query_index": [...], "match": [int or null], "confidence": [float or null],
                "correct": [bool], ...extra per-frame fields...},
     "environment": {"catgraph", "python", "numpy", ..., "processor", "compiled_for"}}

``frames`` lists the query frames in the order they were processed (after any
shuffle); ``query_index`` is the frame's index in the query as loaded and ``match`` an
index into the reference as loaded, so anyone can recheck correctness. Frames with no
output have ``match`` and ``confidence`` null. Extra per-frame arrays (e.g.
``window_length``, ``p_new_place``) appear beside them. Files are written atomically
(temporary file, then rename) so a crash never leaves half a result. ``environment``
(:func:`catgraph.environment.environment`) names the versions and the CPU the kernels
were compiled for, which decides the last bits of their sums (``docs/evaluation.md``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_open
from .exceptions import DataError, DataNotFoundError
from .metrics import Evaluation, evaluate
from .traverse import GroundTruth

__all__ = ["RunResult", "write_json_atomic", "read_result", "read_results"]


@dataclass
class RunResult:
    """What a method produced for each processed query frame.

    Attributes
    ----------
    method : str
    params : dict
        JSON-ready parameters that reproduce the run.
    query_index : ndarray of int, shape (n,)
    match : ndarray of int, shape (n,)  (-1 = no output)
    confidence : ndarray of float, shape (n,)  (higher = surer)
    extra : dict of str → ndarray, shape (n,)
        Further per-frame outputs (``window_length``, ``p_new_place`` …).
    seconds : float
        Wall time of the method (difference matrix excluded unless stated in params).
    """

    method: str
    params: dict
    query_index: np.ndarray
    match: np.ndarray
    confidence: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    seconds: float = float("nan")

    def evaluate(self, ground_truth: GroundTruth) -> Evaluation:
        return evaluate(self.query_index, self.match, self.confidence, ground_truth)

    def to_dict(self, evaluation: Evaluation | None = None) -> dict[str, Any]:
        has = self.match >= 0
        frames: dict[str, list] = {
            "query_index": [int(v) for v in self.query_index],
            "match": [int(m) if h else None for m, h in zip(self.match, has)],
            "confidence": [_finite_or_none(c) if h else None for c, h in zip(self.confidence, has)],
        }
        if evaluation is not None:
            frames["correct"] = [bool(v) for v in evaluation.correct]
            frames["has_true_match"] = [bool(v) for v in evaluation.has_true_match]
        for key, values in self.extra.items():
            frames[key] = [_json_scalar(v) for v in np.asarray(values).tolist()]
        out: dict[str, Any] = {"method": self.method, "params": _jsonable(self.params)}
        out["metrics"] = evaluation.metrics.as_dict() if evaluation is not None else None
        if math.isfinite(self.seconds):
            out["seconds"] = self.seconds
        out["frames"] = frames
        return out


def _finite_or_none(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def _json_scalar(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json_atomic(path: str | os.PathLike, payload: dict) -> Path:
    """Write ``payload`` as JSON to ``path`` atomically; return the path."""
    with atomic_open(path, "w") as fh:
        json.dump(payload, fh, indent=None, separators=(",", ":"), allow_nan=False)
        fh.write("\n")
    return Path(path)


def read_result(path: str | os.PathLike) -> dict:
    """Read a result JSON written by :meth:`RunResult.to_dict` (checked for its keys)."""
    results = read_results(path)
    if len(results) != 1:
        raise DataError(f"{path} holds {len(results)} runs; read it with read_results.")
    return results[0]


def read_results(path: str | os.PathLike) -> list[dict]:
    """Read the runs of a result JSON: one payload, or ``{"runs": [...]}`` as
    ``catgraph compare --output`` writes; each is checked for its keys."""
    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"result file {path} does not exist.")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path} is not valid JSON: {exc}") from None
    runs = data["runs"] if isinstance(data, dict) and isinstance(data.get("runs"), list) else [data]
    for run in runs:
        missing = [k for k in ("method", "params", "metrics", "frames") if not isinstance(run, dict) or k not in run]
        if missing:
            raise DataError(f"{path} is not a catgraph result file (missing {', '.join(missing)}).")
    return runs
