"""Particle-filter benchmarks: step time, and observation models compared.

Usage (from the project root)::

    python benchmarks/bench_filter.py speed            # step timings -> results/filter_speed.md
    python benchmarks/bench_filter.py compare [NAMES]  # model comparison -> results/filter_compare.md

``speed`` times :meth:`Localizer.step` with 2,000 particles on a chain of N = 3,576
places (Nordland's size): (a) with the observation precomputed (a stand-in model that
returns a fixed log-ratio vector), i.e. motion + injection + reweighting + resampling +
summary; (b) with the online histogram model. Medians over several runs of many steps.

``compare`` runs :func:`catgraph.compare.compare_models` on the synthetic world,
Nordland 32×16 summer→winter in order and shuffled (``shuffle_segments(seed=0)``, frame
tolerance ±2) and UJI Wi-Fi (month 01 trn01 reference vs months 02–06 tst01 queries, 2 m
on the same floor). Datasets under ``../shared/data`` are skipped when absent. NAMES picks
datasets (``synthetic,nordland,nordland-shuffled,uji``).

Timings are reported, never asserted.
"""

from __future__ import annotations

import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "data"


class _FixedModel:
    """Observation precomputed: returns the same log-ratio every step."""

    def __init__(self, log_ratio):
        from catgraph.observation import Observation

        self._obs = Observation(log_ratio, -1.0, True)

    def reset(self):
        pass

    def observe(self, row):
        return self._obs


def _time_steps(loc, rows, n_warm=20):
    loc.reset()
    for r in rows[:n_warm]:
        loc.step(r)
    start = time.perf_counter()
    for r in rows[n_warm:]:
        loc.step(r)
    return (time.perf_counter() - start) / (len(rows) - n_warm)


def speed(n_places: int = 3576, n_particles: int = 2000, n_steps: int = 220, repeats: int = 5) -> str:
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.observation import HistogramObservation

    rng = np.random.default_rng(0)
    g = PlaceGraph.chain(n_places)
    # rows that favour a place moving one frame per step, plus noise
    j = np.arange(n_places)
    rows = np.array([np.minimum(np.abs(j - (100 + k)), 10) / 5.0 + rng.normal(0, 0.5, n_places)
                     for k in range(n_steps)])
    rows = (rows - rows.mean(1, keepdims=True)) / rows.std(1, keepdims=True)
    lines = [f"# Particle filter step time\n",
             f"{platform.processor() or platform.machine()}, Python {platform.python_version()}; "
             f"N = {n_places} places (chain), {n_particles} particles, median of {repeats} runs of "
             f"{n_steps - 20} steps (after 20 warm-up steps).\n",
             "| configuration | median ms/step | min | max |", "|---|---|---|---|"]
    cases = {
        "filter step, observation precomputed": lambda: Localizer(g, _FixedModel(-rows[50] ** 2 / 2), n_particles, seed=0),
        "filter step + online histogram model": lambda: Localizer(g, HistogramObservation(n_init=10), n_particles, seed=0),
        "online histogram model alone": None,
    }
    out = {}
    for name, make in cases.items():
        times = []
        for _ in range(repeats):
            if make is None:
                model = HistogramObservation(n_init=10)
                for r in rows[:20]:
                    model.observe(r)
                start = time.perf_counter()
                for r in rows[20:]:
                    model.observe(r)
                times.append((time.perf_counter() - start) / (n_steps - 20))
            else:
                times.append(_time_steps(make(), rows))
        ms = [1000 * t for t in times]
        out[name] = statistics.median(ms)
        lines.append(f"| {name} | {statistics.median(ms):.3f} | {min(ms):.3f} | {max(ms):.3f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    return text


def _datasets(names):
    from catgraph.traverse import FrameTolerance, shuffle_segments

    if "synthetic" in names:
        from catgraph.datasets.synthetic import make_world

        w = make_world(0)
        yield "synthetic world (seed 0), metric 10 m", w.reference, w.query, w.ground_truth(), {
            "junctions": w.reference_junctions(), "confidence_radius_m": w.tolerance_m}
    nordland = DATA / "nordland" / "32x16"
    if nordland.exists() and ({"nordland", "nordland-shuffled"} & set(names)):
        from catgraph.datasets import load_traverse

        ref = load_traverse(nordland / "summer")
        qry = load_traverse(nordland / "winter")
        gt = FrameTolerance(len(ref), 2)
        if "nordland" in names:
            yield "Nordland 32×16 summer→winter, in order, ±2 frames", ref, qry, gt, {}
        if "nordland-shuffled" in names:
            yield "Nordland 32×16 summer→winter, shuffled (seed 0), ±2 frames", ref, shuffle_segments(qry, seed=0), gt, {}
    uji = DATA / "uji-lib" / "db"
    if uji.exists() and "uji" in names:
        from catgraph.datasets import load_traverse
        from catgraph.traverse import MetricTolerance

        ref = load_traverse(uji / "01" / "trn01")
        for month in ("02", "03", "04", "05", "06"):
            qry = load_traverse(uji / month / "tst01")
            yield (f"UJI library Wi-Fi, 01/trn01 → {month}/tst01, 2 m same floor", ref, qry,
                   MetricTolerance.between(qry, ref, 2.0),
                   {"edge_length": "frames", "junction_radius_m": 1.0, "confidence_radius_m": 2.0})


def compare(names=("synthetic", "nordland", "nordland-shuffled", "uji")) -> str:
    from catgraph.compare import compare_models, format_table
    from catgraph.graph import PlaceGraph

    parts = ["# Observation models in the particle filter, compared\n",
             "Filter: 2,000 particles, seed 0, systematic resampling at ESS < 0.5 N, 2 % of particles "
             "re-drawn each step near the 10 best single-frame matches; a frame's confidence is the smaller of "
             "the posterior log-odds and the model's recent support at the answer (`confidence_score=\"joint\"`); "
             "the combined model tempers each part by its online reliability. Baselines: the standalone "
             "sequence matcher (adaptive window; fixed L = 50). ms/frame: the method alone, difference "
             "matrix excluded. Generated by `benchmarks/bench_filter.py compare`.\n"]
    for title, ref, qry, gt, extra in _datasets(names):
        print(title, flush=True)
        extra = dict(extra)
        junctions = extra.pop("junctions", None)
        if junctions is not None:
            extra["graph"] = PlaceGraph.from_traverse(ref, junctions=junctions)
        rows = compare_models(ref, qry, gt, progress=lambda s: print("  ", s, time.strftime("%X"), flush=True),
                              **extra)
        table = format_table(rows, title)
        print(table, flush=True)
        parts.append(table)
    return "\n".join(parts)


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    what = argv[0] if argv else "speed"
    RESULTS.mkdir(parents=True, exist_ok=True)
    if what == "speed":
        (RESULTS / "filter_speed.md").write_text(speed())
    elif what == "compare":
        names = argv[1].split(",") if len(argv) > 1 else ["synthetic", "nordland", "nordland-shuffled", "uji"]
        (RESULTS / "filter_compare.md").write_text(compare(names))
    else:
        raise SystemExit("usage: bench_filter.py speed | compare [synthetic,nordland,nordland-shuffled,uji]")


if __name__ == "__main__":
    main()
