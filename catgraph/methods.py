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


def _single_frame(params, *, reference, query, differences, ground_truth) -> RunResult:
    return match_single_frames(differences, query.index, exclusion=int(params.get("exclusion", 10)))


_SEQUENCE_KEYS = ("window", "approximation", "rule", "confidence", "l_min", "l_max", "grid", "radius")


def _sequence(params, *, reference, query, differences, ground_truth) -> RunResult:
    """SeqSLAM sequence matching, fixed (``window`` int) or adaptive (``"adaptive"``)."""
    import time

    from .sequence import match_sequences

    unknown = set(params) - set(_SEQUENCE_KEYS)
    if unknown:
        raise InvalidParameterError(f"unknown sequence-matching parameters {sorted(unknown)}; "
                                    f"allowed: {', '.join(_SEQUENCE_KEYS)}.")
    kwargs = {k: v for k, v in params.items() if v is not None}
    kwargs.setdefault("window", "adaptive")
    start = time.perf_counter()
    res = match_sequences(differences, **kwargs)
    seconds = time.perf_counter() - start
    name = "adaptive" if kwargs["window"] == "adaptive" else f"sequence-L{kwargs['window']}"
    return RunResult(name, dict(kwargs), np.asarray(query.index), res.match, res.confidence,
                     extra={"window_length": res.window_length}, seconds=seconds)


METHODS: dict[str, Callable[..., RunResult]] = {
    "single-frame": _single_frame,
    "sequence": _sequence,
}


def run_method(name: str, params: dict, *, reference: Traverse, query: Traverse, differences: np.ndarray,
               ground_truth: GroundTruth | None = None) -> RunResult:
    """Run method ``name`` with ``params``; see :data:`METHODS` for the names."""
    if name not in METHODS:
        raise InvalidParameterError(f"unknown method {name!r}; choose one of {', '.join(sorted(METHODS))}.")
    return METHODS[name](params, reference=reference, query=query, differences=differences,
                         ground_truth=ground_truth)
