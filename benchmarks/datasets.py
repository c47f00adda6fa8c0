"""The benchmark datasets and the traversal-condition table, shared by every benchmark.

Each *case* is a reference, a query, its ground truth and the query × reference
difference matrix (the project's default front-end, normalised per query). A condition
(:mod:`catgraph.conditions`) only reorders the query, so the difference matrix is
computed once per dataset and each condition takes its rows: ``D[order]``.

Datasets (DESIGN.md §8): Nordland 32×16 summer → winter (±2 frames); UJI library Wi-Fi,
month 01 ``trn01`` → months 02–06 ``tst01`` (3 m, same floor); the synthetic world
(seed 0, its own tolerance). Real data are read from ``../shared/data`` and skipped
where absent.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from catgraph.conditions import Condition, condition_table
from catgraph.datasets import load_traverse
from catgraph.pipeline import differences
from catgraph.traverse import FrameTolerance, GroundTruth, MetricTolerance, Traverse

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
WIFI_METRES = 3.0
NORDLAND_FRAMES = 2

__all__ = ["Case", "nordland", "uji_months", "synthetic", "conditioned", "condition_table", "DATA"]


@dataclass(frozen=True, eq=False)
class Case:
    """One reference/query pair, ready for any method."""

    name: str
    reference: Traverse
    query: Traverse
    ground_truth: GroundTruth
    differences: np.ndarray  # (n_query, n_reference), the query's processing order
    condition: Condition = Condition()


def have_data() -> bool:
    return DATA.is_dir()


def nordland(size: str = "32x16") -> Case:
    ref = load_traverse(DATA / "nordland" / size / "summer")
    query = load_traverse(DATA / "nordland" / size / "winter")
    return Case("Nordland", ref, query, FrameTolerance(len(ref), NORDLAND_FRAMES), differences(ref, query))


def uji_months(months=range(2, 7)) -> list[Case]:
    db = DATA / "uji-lib" / "db"
    ref = load_traverse(db / "01" / "trn01")
    out = []
    for month in months:
        query = load_traverse(db / f"{month:02d}" / "tst01")
        out.append(Case(f"UJI {month:02d}", ref, query, MetricTolerance.between(query, ref, WIFI_METRES),
                        differences(ref, query)))
    return out


def synthetic(seed: int = 0) -> Case:
    from catgraph.datasets.synthetic import make_world

    world = make_world(seed=seed)
    return Case(f"synthetic {seed}", world.reference, world.query, world.ground_truth(),
                differences(world.reference, world.query))


def conditioned(case: Case, condition: Condition) -> Case:
    """The case with its query driven under ``condition`` (ground truth follows the frames)."""
    order = condition.order(len(case.query))
    return replace(case, query=condition.apply(case.query), differences=case.differences[order],
                   condition=condition)


def prepare_kept(exp):
    """:func:`catgraph.experiment.prepare` with the difference matrix computed once and kept:
    the benchmarks run many methods and conditions on one matrix (``Prepared.under``
    reorders it), and time the methods alone, as the commands' runs on a kept matrix."""
    from catgraph.experiment import prepare

    prepared = prepare(exp)
    prepared.differences  # computed here, once
    return prepared


#: the names :func:`prepared_datasets` knows (the benchmarks' ``--datasets``)
DATASET_NAMES = ("nordland", "uji", "synthetic")


def prepared_datasets(names) -> dict:
    """Experiment-layer inputs (:func:`catgraph.experiment.prepare`) per dataset name:
    ``"nordland"`` (±2 frames), ``"uji"`` (months 02–06 against 01, 3 m), ``"synthetic"``
    (seed 0); those whose data are absent are left out."""
    from catgraph.experiment import Experiment

    unknown = sorted(set(names) - set(DATASET_NAMES))
    if unknown:  # a misspelt name would otherwise measure nothing and say nothing
        raise SystemExit(f"unknown dataset name(s) {', '.join(unknown)}; choose from {', '.join(DATASET_NAMES)}.")
    out = {}
    if "nordland" in names and (DATA / "nordland").is_dir():
        d = DATA / "nordland" / "32x16"
        out["Nordland"] = [prepare_kept(Experiment(query=d / "winter", reference=d / "summer",
                                                   tolerance=NORDLAND_FRAMES))]
    if "uji" in names and (DATA / "uji-lib").is_dir():
        db = DATA / "uji-lib" / "db"
        out["UJI 02-06"] = [prepare_kept(Experiment(query=db / f"{m:02d}" / "tst01", reference=db / "01" / "trn01",
                                                    tolerance_m=WIFI_METRES)) for m in range(2, 7)]
    if "synthetic" in names:
        out["synthetic"] = [prepare_kept(Experiment(query="synthetic:0", reference="synthetic:0"))]
    return out


def benchmark_conditions(quick: bool) -> list[Condition]:
    """The 14 conditions; ``quick``: in order, shuffled 2–20 % and 0.5–3 % (seed 0),
    reversed, speed 2."""
    if quick:
        return [Condition(), Condition("shuffle", seed=0), Condition("shuffle", seed=0, segment_range=(0.005, 0.03)),
                Condition("reverse"), Condition("speed", factor=2.0)]
    return condition_table()
