"""From loaded traverses to evaluated runs: the path every command takes.

1. :func:`describe` turns a traverse's frames into descriptors with the front-end its
   kind calls for — images: the SeqSLAM pipeline (greyscale, resize, 4×4 patch
   normalisation) compared with SAD; Wi-Fi: strength-above-floor vectors, SAD;
   descriptor arrays: as given, cosine (boolean arrays: Hamming).
2. :func:`differences` computes the query × reference difference matrix, normalised per
   query (paper 1) unless asked otherwise.
3. A method turns it into per-frame matches and confidences (:class:`RunResult`), which
   :func:`ground_truth_for` and :mod:`catgraph.metrics` evaluate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .differences import difference_matrix
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .frontends import seqslam_preprocess, wifi_vectors
from .matching import best_matches
from .results import RunResult
from .traverse import FrameTolerance, GroundTruth, MetricTolerance, Traverse

__all__ = ["FrontEnd", "describe", "differences", "ground_truth_for", "match_single_frames"]


@dataclass(frozen=True)
class FrontEnd:
    """Front-end settings (stored with results and maps).

    Parameters
    ----------
    size : (width, height) or None
        Image resize target; ``None`` keeps the images' size.
    patch : int
        Patch-normalisation patch side (0 = off).
    metric : str or None
        Difference metric; ``None`` picks by data kind (images/Wi-Fi: SAD, feature
        vectors: cosine, booleans: Hamming).
    normalise : bool
        Per-query normalisation of the difference matrix (paper 1).
    """

    size: tuple[int, int] | None = None
    patch: int = 4
    metric: str | None = None
    normalise: bool = True

    def as_dict(self) -> dict:
        return {"size": list(self.size) if self.size else None, "patch": self.patch, "metric": self.metric,
                "normalise": self.normalise}


def _kind(traverse: Traverse) -> str:
    kind = traverse.meta.get("kind")
    if kind:
        return kind
    return "images" if traverse.frames.ndim >= 3 else "descriptors"


def describe(traverse: Traverse, frontend: FrontEnd = FrontEnd()) -> tuple[np.ndarray, str]:
    """Descriptors ``(n, d)`` for a traverse and the metric to compare them with."""
    kind = _kind(traverse)
    if kind == "images":
        return seqslam_preprocess(traverse.frames, size=frontend.size, patch=frontend.patch), frontend.metric or "sad"
    if kind == "wifi":
        return wifi_vectors(traverse.frames, not_detected=traverse.meta.get("not_detected", 100.0)), \
            frontend.metric or "sad"
    frames = traverse.frames.reshape(len(traverse), -1)
    if frames.dtype == bool:
        return frames, frontend.metric or "hamming"
    return frames.astype(np.float32), frontend.metric or "cosine"


def differences(reference: Traverse, query: Traverse, frontend: FrontEnd = FrontEnd()) -> np.ndarray:
    """The ``(n_query, n_reference)`` difference matrix, in the query's processing order."""
    kinds = (_kind(reference), _kind(query))
    if kinds[0] != kinds[1]:
        raise DataError(f"the reference holds {kinds[0]} but the query holds {kinds[1]}; compare like with like.")
    r, metric = describe(reference, frontend)
    q, _ = describe(query, frontend)
    if r.shape[1] != q.shape[1]:
        raise ShapeMismatchError(
            f"reference frames give {r.shape[1]} values per descriptor but query frames give {q.shape[1]}; "
            "use the same image size (or --size WxH) and the same access-point list for both."
        )
    return difference_matrix(q, r, metric, normalise=frontend.normalise)


def ground_truth_for(reference: Traverse, query: Traverse, tolerance: int | None = None,
                     tolerance_m: float | None = None) -> GroundTruth:
    """Frame-index ground truth (``tolerance``) or metric ground truth (``tolerance_m``)."""
    if (tolerance is None) == (tolerance_m is None):
        raise InvalidParameterError(
            "give exactly one ground truth: a frame tolerance (--tolerance FRAMES, same index = same place) "
            "or a metric one (--tolerance-m METRES, needs positions in both traverses)."
        )
    if tolerance_m is not None:
        return MetricTolerance.between(query, reference, tolerance_m)
    return FrameTolerance(len(reference), tolerance)


def match_single_frames(diff: np.ndarray, query_index: np.ndarray, exclusion: int = 10) -> RunResult:
    """Single-frame matching: the nearest reference place per query frame.

    Confidence is the margin to the best place outside ``± exclusion`` of the match.
    """
    start = time.perf_counter()
    match, confidence = best_matches(diff, exclusion=exclusion)
    return RunResult("single-frame", {"window": 1, "exclusion": exclusion}, np.asarray(query_index), match,
                     confidence, seconds=time.perf_counter() - start)
