"""Benchmark: the observation models' share of one live step, before and after a change.

The grid filter's step at large maps is dominated by per-place passes: the difference
row, the sequence matcher, and the observation model's own arithmetic (hub statistic,
single-frame ratios, novelty weight, new-place ratio, the combined model's sum). This
script times the models of two versions of :mod:`catgraph.observation` side by side in
one process — the working tree's and the one committed at ``--before`` (default
``HEAD``), loaded from git under another module name — on the same rows, interleaved
step by step, so the shared machine's load hits both alike. It checks on the way that
both versions give bit-identical matches, scores, confidences and log-ratios
(``np.array_equal``), on random rows and, where the data is present, on a sample of
Nordland's normalised difference rows.

Models: ``GridLocalizer(PlaceGraph.chain(N), TemperedObservation())`` and the registry's
``combined`` model (:func:`catgraph.methods.observation_model`) on the same chain; the
identity checks also run both under the particle filter (500 particles, seed 0), whose
confidence score reads the combined model's recent support. A model's time is its
``observe`` and its ``feedback`` together (the filter calls both every frame). A second
table times the combined model with its weights learned online
(``CombinedObservation(weights="predictive")``, whose candidates are scored in
``feedback``) against the plain sum, both the working tree's.

Writes ``benchmarks/results/models.md`` (``--out``). Run from the repository root::

    python benchmarks/bench_models.py [--sizes 10000,100000] [--steps 25] [--before REV]
        [--profile] [--full]

``--full``: check identity on the whole Nordland traverse, in order and under the
condition table's first shuffle (else on its first 300 rows).

``--profile``: also profile both versions' steps (cProfile, top functions by own time)
and add the tables to the results file.
"""

from __future__ import annotations

import argparse
import cProfile
import contextlib
import importlib.util
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe_machine  # noqa: E402

import catgraph.observation as current  # noqa: E402
from catgraph.graph import PlaceGraph  # noqa: E402
from catgraph.grid import GridLocalizer  # noqa: E402
from catgraph.methods import observation_model, resolve_params  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parent.parent


def load_before(rev: str):
    """:mod:`catgraph.observation` as committed at ``rev``, as module ``catgraph._observation_before``.

    The data classes the filters check against (``Observation``, ``FilterFeedback``,
    ``CheckedRow``) are the current module's, so the filters treat both alike.
    """
    text = subprocess.run(["git", "show", f"{rev}:catgraph/observation.py"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "observation_before.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("catgraph._observation_before", path)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "catgraph"
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    for name in ("Observation", "FilterFeedback", "CheckedRow"):
        setattr(module, name, getattr(current, name))
    return module


@contextlib.contextmanager
def observation_module(module):
    """Let :func:`catgraph.methods.observation_model` build its models from ``module``."""
    saved = sys.modules["catgraph.observation"]
    sys.modules["catgraph.observation"] = module
    try:
        yield
    finally:
        sys.modules["catgraph.observation"] = saved


def make_model(kind: str, module, n: int):
    if kind == "tempered":
        return module.TemperedObservation()
    with observation_module(module):
        model = observation_model(resolve_params("filter", {"model": "combined"}), n, None)
    if kind == "combined, weights learned":
        model.weights = "predictive"
    return model


def weights_cost(n: int, steps: int, warm: int, seed: int) -> dict[str, float]:
    """Median ms per frame of the registry's combined model (``observe`` + ``feedback``)
    with the plain sum and with ``weights="predictive"``, both the working tree's, on the
    same random rows under the grid filter, stepped alternately."""
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((warm + steps, n))
    graph = PlaceGraph.chain(n)
    runs = {}
    for kind in ("combined", "combined, weights learned"):
        timer = Timer(make_model(kind, current, n))
        runs[kind] = (timer, GridLocalizer(graph, timer))
    times = {kind: [] for kind in runs}
    for k, row in enumerate(rows):
        for kind in (list(runs) if k % 2 == 0 else list(runs)[::-1]):
            timer, loc = runs[kind]
            loc.step(row)
            if k >= warm:
                times[kind].append(timer.last)
    return {kind: 1e3 * float(np.median(v)) for kind, v in times.items()}


class Recorder:
    """Wraps a model, keeping a copy of every observation it hands the filter."""

    def __init__(self, model) -> None:
        self.model, self.seen = model, []

    def reset(self) -> None:
        self.model.reset()

    def feedback(self, feedback) -> None:
        self.model.feedback(feedback)

    def observe(self, row):
        obs = self.model.observe(row)
        self.seen.append((obs.log_ratio.copy(), obs.new_place_log_ratio,
                          None if obs.support is None else obs.support.copy()))
        return obs


class Timer(Recorder):
    """Wraps a model, timing its ``observe`` and its ``feedback`` (``last``: both, of the latest frame)."""

    def observe(self, row):
        t = time.perf_counter()
        obs = self.model.observe(row)
        self.last = time.perf_counter() - t
        return obs

    def feedback(self, feedback) -> None:
        t = time.perf_counter()
        self.model.feedback(feedback)
        self.last += time.perf_counter() - t


def check_identical(kind: str, before, rows: np.ndarray, particles: bool = False) -> list[str]:
    """Run both versions through ``rows`` (grid filter, or the particle filter, whose
    confidence score reads the recent support); the differences found (empty: bit-identical)."""
    from catgraph.localizer import Localizer

    n = rows.shape[1]
    out, problems = [], []
    for module in (before, current):
        rec = Recorder(make_model(kind, module, n))
        loc = (Localizer(PlaceGraph.chain(n), rec, n_particles=500, seed=0) if particles
               else GridLocalizer(PlaceGraph.chain(n), rec))
        est = [loc.step(r) for r in rows]
        out.append((np.array([e.place for e in est]), np.array([e.score for e in est]),
                    np.array([e.confidence for e in est]), rec.seen))
    (p0, s0, c0, o0), (p1, s1, c1, o1) = out
    for name, a, b in (("matches", p0, p1), ("scores", s0, s1), ("confidences", c0, c1)):
        if not np.array_equal(a, b):
            problems.append(f"{name} differ")
    for k, (x, y) in enumerate(zip(o0, o1)):
        if not (np.array_equal(x[0], y[0]) and x[1] == y[1]
                and (x[2] is None) == (y[2] is None) and (x[2] is None or np.array_equal(x[2], y[2]))):
            problems.append(f"observation of frame {k} differs")
            break
    return problems


def time_steps(kind: str, before, n: int, steps: int, warm: int, seed: int, profile: bool):
    """Median ms per step (the model alone, and the whole filter step) of both versions."""
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((warm + steps, n))
    graph = PlaceGraph.chain(n)
    runs = {}
    for name, module in (("before", before), ("after", current)):
        timer = Timer(make_model(kind, module, n))
        runs[name] = (timer, GridLocalizer(graph, timer))
    times = {name: {"step": [], "observe": []} for name in runs}
    profs = {name: cProfile.Profile() for name in runs} if profile else None
    for k, row in enumerate(rows):
        order = ("before", "after") if k % 2 == 0 else ("after", "before")
        for name in order:
            timer, loc = runs[name]
            prof = profs[name] if profs is not None and k >= warm else None
            if prof is not None:
                prof.enable()
            t = time.perf_counter()
            loc.step(row)
            dt = time.perf_counter() - t
            if prof is not None:
                prof.disable()
            if k >= warm:
                times[name]["step"].append(dt)
                times[name]["observe"].append(timer.last)
    out = {name: {k: 1e3 * float(np.median(v)) for k, v in t.items()} for name, t in times.items()}
    if profs is not None:
        out["profile"] = {name: profile_rows(prof, steps) for name, prof in profs.items()}
    return out


def tempered_parts(before, n: int, steps: int, warm: int, seed: int) -> dict[str, dict[str, float]]:
    """Median ms of the tempered model's per-frame parts, both versions, interleaved.

    Each model first runs ``warm`` frames under the grid filter (so the online hub levels
    exist), then its parts are called on fresh rows: the hub correction (``_hub``: levels,
    median, MAD, hub count, excess), the single-frame ratios (``_base``, the hub
    correction included), the novelty weight (``_novelty``), and the whole ``observe``.
    """
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((warm + steps, n))
    graph = PlaceGraph.chain(n)
    models = {}
    for name, module in (("before", before), ("after", current)):
        model = module.TemperedObservation()
        loc = GridLocalizer(graph, model)
        for row in rows[:warm]:
            loc.step(row)
        models[name] = model
    parts = ("_hub", "_base", "_novelty", "observe")
    times = {name: {p: [] for p in parts} for name in models}
    for k, row in enumerate(rows[warm:]):
        for name in (("before", "after") if k % 2 == 0 else ("after", "before")):
            model = models[name]
            for part in parts:
                fn = getattr(model, part)
                t = time.perf_counter()
                fn() if part == "_hub" else fn(row)
                times[name][part].append(time.perf_counter() - t)
    return {name: {p: 1e3 * float(np.median(v)) for p, v in t.items()} for name, t in times.items()}


def profile_rows(prof: cProfile.Profile, steps: int, top: int = 12) -> list[tuple[str, float, float]]:
    """The ``top`` functions by own time: (name, own ms per step, cumulative ms per step)."""
    stats = pstats.Stats(prof).stats
    rows = []
    for (path, line, func), (_, _, tottime, cumtime, _) in stats.items():
        where = f"{Path(path).name}:{line}({func})" if path != "~" else func
        rows.append((where, 1e3 * tottime / steps, 1e3 * cumtime / steps))
    rows.sort(key=lambda r: -r[1])
    return rows[:top]


def nordland_samples(count: int | None) -> list[tuple[str, np.ndarray]]:
    """Nordland's normalised difference rows: the first ``count`` in order, or (``None``)
    the whole traverse in order and under the table's first shuffle (2–20 %, seed 0)."""
    from datasets import have_data, nordland

    from catgraph.conditions import condition_table

    if not have_data():
        return []
    d = nordland().differences
    n = d.shape[1]
    if count is not None:
        return [(f"Nordland 32x16, first {count} normalised rows, N = {n}",
                 np.ascontiguousarray(d[:count], dtype=np.float64))]
    out = []
    for cond in condition_table()[:2]:
        rows = np.ascontiguousarray(d[cond.order(len(d))], dtype=np.float64)
        out.append((f"Nordland 32x16, all {len(d)} normalised rows, {cond.label}, N = {n}", rows))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--steps", type=int, default=25)
    ap.add_argument("--warm", type=int, default=5)
    ap.add_argument("--before", default="HEAD")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--full", action="store_true", help="check identity on the whole Nordland traverse, "
                    "in order and shuffled (else its first 300 rows)")
    ap.add_argument("--out", default="models.md")
    args = ap.parse_args(argv)
    before = load_before(args.before)
    rev = subprocess.run(["git", "rev-parse", "--short", args.before], cwd=ROOT, capture_output=True,
                         text=True).stdout.strip()

    checks = []
    rng = np.random.default_rng(1)
    samples = [("random rows, N = 500", rng.standard_normal((120, 500)))]
    samples += nordland_samples(None if args.full else 300)
    for kind in ("tempered", "combined"):
        for label, rows in samples:
            for particles in (False, True):
                problems = check_identical(kind, before, rows, particles)
                checks.append((kind, "particle filter" if particles else "grid filter", label,
                               "bit-identical" if not problems else "; ".join(problems)))
                print(checks[-1], flush=True)

    sizes = [int(s) for s in args.sizes.split(",")]
    table = {}
    for kind in ("tempered", "combined"):
        for n in sizes:
            table[(kind, n)] = time_steps(kind, before, n, args.steps, args.warm, 0, False)
            print(kind, n, table[(kind, n)], flush=True)
    parts = {n: tempered_parts(before, n, args.steps, args.warm, 0) for n in sizes}
    print(parts, flush=True)
    learned = {n: weights_cost(n, args.steps, args.warm, 0) for n in sizes}
    print(learned, flush=True)
    profiles = {}
    if args.profile:  # a separate run: the profiler's overhead stays out of the medians
        for kind in ("tempered", "combined"):
            profiles[(kind, sizes[-1])] = time_steps(kind, before, sizes[-1], args.steps, args.warm, 0,
                                                     True)["profile"]

    lines = [
        "# Observation models: time per live step, before and after",
        "",
        f"Generated by `benchmarks/bench_models.py`; `before` = `catgraph/observation.py` at {rev}, "
        "`after` = the working tree, both in one process on the same random rows, stepped "
        f"alternately (interleaved), medians of {args.steps} steps after {args.warm} warm-up steps; "
        f"grid filter on `PlaceGraph.chain(N)`; {describe_machine()}, "
        "2 cores shared with other work (compare the two columns of a row, not rows across runs).",
        "",
        "| model | N | model's `observe` + `feedback`, before | after | × | whole grid step, before | after | × |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (kind, n), t in table.items():
        b, a = t["before"], t["after"]
        lines.append(f"| {kind} | {n:,} | {b['observe']:.2f} ms | {a['observe']:.2f} ms | "
                     f"{b['observe'] / a['observe']:.2f} | {b['step']:.2f} ms | {a['step']:.2f} ms | "
                     f"{b['step'] / a['step']:.2f} |")
    lines += ["", "The combined model with its weights learned online (`CombinedObservation(weights=\"predictive\")`, "
              "five candidates) against the plain sum, both the working tree's, same rows, stepped alternately; "
              "the model's own time per frame (`observe` + `feedback`, where the candidates are scored), medians:",
              "", "| N | combined, sum | combined, weights learned | × |", "|---|---|---|---|"]
    for n, t in learned.items():
        a, b = t["combined"], t["combined, weights learned"]
        lines.append(f"| {n:,} | {a:.2f} ms | {b:.2f} ms | {b / a:.2f} |")
    lines += ["", "The tempered model's parts, called one after another on a model warmed up under the grid "
              "filter (medians over the same steps, both versions interleaved; `_base` includes `_hub`, "
              "`observe` includes all):", "",
              "| part | " + " | ".join(f"N = {n:,}, before | after" for n in sizes) + " |",
              "|---|" + "---|---|" * len(sizes)]
    labels = {"_hub": "hub correction (`_hub`: levels, median, MAD, count, excess)",
              "_base": "single-frame ratios (`_base`, hub correction included)",
              "_novelty": "novelty weight (`_novelty`)", "observe": "`observe`, all of it"}
    for part, label in labels.items():
        lines.append(f"| {label} | " + " | ".join(
            f"{parts[n]['before'][part]:.2f} ms | {parts[n]['after'][part]:.2f} ms" for n in sizes) + " |")
    profiled = list(profiles.items())
    if profiled:
        lines += ["", "cProfile of the largest map's steps, a separate run of both versions interleaved the same "
                  "way (mean own time and cumulative time per step, ms; the profiler's overhead included; numpy's C calls are listed by "
                  "method, e.g. `partition`, `reduce` = every numpy sum, max and mean):"]
        for (kind, n), prof in profiled:
            for name in ("before", "after"):
                lines += ["", f"{kind}, N = {n:,}, {name}:", "", "| function | own ms | cumulative ms |",
                          "|---|---|---|"]
                lines += [f"| `{f}` | {own:.2f} | {cum:.2f} |" for f, own, cum in prof[name]]
    lines += ["", "Results compared with `np.array_equal` (matches, scores, confidences of every frame; every "
              "observation's log-ratios, new-place ratio and support):", "",
              "| model | filter | rows | result |", "|---|---|---|---|"]
    lines += [f"| {k} | {f} | {label} | {res} |" for k, f, label, res in checks]
    (RESULTS / args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
