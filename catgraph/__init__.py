"""catgraph: probabilistic, appearance-based localisation along known routes.

The public API, by concept (each module's docstring explains its maths):

- traverses and ground truth: :class:`Traverse`, :func:`shuffle_segments`,
  :class:`FrameTolerance`, :class:`MetricTolerance`, :class:`ExplicitGroundTruth`;
- data: :func:`load_traverse` (image folders, UJI Wi-Fi, arrays), :func:`make_world`;
- differences: :func:`difference_matrix`, :func:`normalise_rows`;
- sequence matching (paper 1): :func:`match_sequences`, :class:`SequenceMatcher`;
- histogram likelihoods (paper 2): :class:`HistogramLikelihood`,
  :class:`HistogramPlaceRecogniser`;
- the particle filter: :class:`PlaceGraph`, :class:`Localizer`, :func:`localize`,
  :func:`compare_models`;
- evaluation: :func:`evaluate`; maps and sweeps: :func:`save_map`, :func:`load_map`,
  :func:`build_map`, :func:`load_config`, :func:`run_sweep`.

Heavy modules (numba kernels, matplotlib, dask) load on first use, not on import.
"""

from __future__ import annotations

import importlib

from . import exceptions
from .exceptions import CatgraphError
from .traverse import (
    ExplicitGroundTruth,
    FrameTolerance,
    GroundTruth,
    MetricTolerance,
    Traverse,
    shuffle_segments,
)

#: the package's version (PEP 440), written here only: pyproject.toml reads it
__version__ = "0.2.0.dev0"

_LAZY = {
    "load_traverse": "datasets.loaders",
    "make_world": "datasets.synthetic",
    "SyntheticWorld": "datasets.synthetic",
    "difference_matrix": "differences",
    "normalise_rows": "differences",
    "match_sequences": "sequence",
    "SequenceMatcher": "sequence",
    "HistogramLikelihood": "likelihood",
    "HistogramPlaceRecogniser": "likelihood",
    "PlaceGraph": "graph",
    "Localizer": "localizer",
    "localize": "compare",
    "compare_models": "compare",
    "evaluate": "metrics",
    "RunResult": "results",
    "save_map": "io",
    "load_map": "io",
    "build_map": "io",
    "CatgraphMap": "io",
    "load_config": "config",
    "run_sweep": "sweep",
    "run_experiment": "experiment",
}

__all__ = [
    "CatgraphError",
    "ExplicitGroundTruth",
    "FrameTolerance",
    "GroundTruth",
    "MetricTolerance",
    "Traverse",
    "exceptions",
    "shuffle_segments",
    "__version__",
    *_LAZY,
]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'catgraph' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
