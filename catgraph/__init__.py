"""catgraph: probabilistic, appearance-based localisation along known routes."""

from __future__ import annotations

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

__version__ = "0.1.0"

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
]
