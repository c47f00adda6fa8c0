"""One evaluated run from a plain, JSON-ready description (the unit of every sweep).

A *run spec* is a dict::

    {"reference": "../shared/data/nordland/32x16/summer",  # or "synthetic:SEED"
     "query": "../shared/data/nordland/32x16/winter",      # or "synthetic:SEED"
     "method": "adaptive",                                  # see catgraph.methods.METHODS
     "params": {...},                                       # the method's parameters
     "tolerance": 2, "tolerance_m": null,                   # ground truth (one of them)
     "shuffle": 0 or null,                                  # shuffle the query (seed)
     "frontend": {"size": null, "patch": 4, "metric": null}}

:func:`run_experiment` loads, describes, computes differences, runs the method and
returns the result payload (the JSON every command writes). It is a pure function of the
spec — same spec, same result — so sweeps can run it in any process or on any Dask
worker and compare.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

from .exceptions import ConfigError
from .pipeline import FrontEnd, differences, ground_truth_for
from .traverse import Traverse, shuffle_segments

__all__ = ["load_input", "run_experiment", "SPEC_KEYS"]

SPEC_KEYS = {"reference", "query", "method", "params", "tolerance", "tolerance_m", "shuffle", "frontend", "name"}


@lru_cache(maxsize=4)
def synthetic_world(seed: int):
    """The built-in synthetic world for ``seed`` (cached: it is immutable)."""
    from .datasets.synthetic import make_world

    return make_world(seed=seed)


def _synthetic_seed(text: str) -> int:
    _, _, seed = text.partition(":")
    try:
        return int(seed or 0)
    except ValueError:
        raise ConfigError(f"{text!r}: write the synthetic world as 'synthetic' or 'synthetic:SEED'.") from None


def default_tolerance_m(source: str | Path) -> float | None:
    """The ground-truth tolerance (metres) that goes with a source when none is given:
    the synthetic world's own; ``None`` for real data (the user must choose)."""
    text = str(source)
    return synthetic_world(_synthetic_seed(text)).tolerance_m if text.startswith("synthetic") else None


def load_input(source: str | Path, role: str) -> Traverse:
    """A traverse from a path, or from ``"synthetic[:SEED]"`` (the built-in world)."""
    text = str(source)
    if text.startswith("synthetic"):
        world = synthetic_world(_synthetic_seed(text))
        return world.reference if role == "reference" else world.query
    from .datasets import load_traverse

    return load_traverse(source)


def run_experiment(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one spec and return its result payload (method, params, metrics, frames)."""
    from .methods import run_method

    unknown = set(spec) - SPEC_KEYS
    if unknown:
        raise ConfigError(f"unknown run keys {sorted(unknown)}; allowed: {sorted(SPEC_KEYS)}.")
    for key in ("reference", "query", "method"):
        if key not in spec:
            raise ConfigError(f"a run needs '{key}'.")
    reference = load_input(spec["reference"], "reference")
    query = load_input(spec["query"], "query")
    tolerance, tolerance_m = spec.get("tolerance"), spec.get("tolerance_m")
    if tolerance is None and tolerance_m is None:
        tolerance_m = default_tolerance_m(spec["reference"])
    ground_truth = ground_truth_for(reference, query, tolerance, tolerance_m)
    if spec.get("shuffle") is not None:
        query = shuffle_segments(query, seed=int(spec["shuffle"]))
    frontend = FrontEnd(**{k: (tuple(v) if k == "size" and v else v) for k, v in (spec.get("frontend") or {}).items()})
    diff = differences(reference, query, frontend)
    result = run_method(spec["method"], dict(spec.get("params") or {}), reference=reference, query=query,
                        differences=diff, ground_truth=ground_truth, frontend=frontend)
    result.params.update({"reference": str(spec["reference"]), "query": str(spec["query"]),
                          "shuffle": spec.get("shuffle"), "frontend": frontend.as_dict(),
                          "ground_truth": ground_truth.describe()})
    payload = result.to_dict(result.evaluate(ground_truth))
    if spec.get("name"):
        payload["name"] = spec["name"]
    return payload
