"""Benchmark: the particle filter beside the exact grid filter, on every condition and dataset.

The particle filter (``catgraph.localizer.Localizer`` with ``VelocityMotion``) is a Monte
Carlo version of the grid filter (``catgraph.grid.GridLocalizer``): same motion, same
recovery share, same observation model. This benchmark runs both through the registry
(``run_method("filter", {"mode": "grid"|"particles", ...})``), so it measures exactly
what a user gets, on the whole condition table (``catgraph.conditions.condition_table``)
of Nordland 32×16 summer → winter (±2 frames), UJI Wi-Fi month 01 → months 02–06 (3 m;
means over the months) and the synthetic world (seed 0). The particle filter runs with
seeds 0–4: each cell gives the grid's AUC, the particles' mean AUC and the spread
(max − min) over seeds.

It also times one filter step with the observation excluded (a fixed log-ratio
vector), as medians of several runs and as a ratio to the grid filter timed in the same
run, and measures the total-variation distance between the two posteriors as the
particles grow.

Writes ``benchmarks/results/particles.md`` and ``particles.json``. From the repository root::

    python benchmarks/bench_particles.py [--quick] [--datasets nordland,uji,synthetic]
        [--params '{"n_particles": 2000}'] [--seeds 0,1,2,3,4] [--out particles]

``--quick``: in order, shuffled 2–20 % seed 0, shuffled 0.5–3 % seed 0, reversed, speed 2.

``--sampled-velocity``: the particle filter with one sampled velocity bin per particle
(``Localizer(marginal_velocity=False)``, the filter before its velocity was
Rao–Blackwellised), for a before/after measured in one code state.

``--unsmoothed-feedback``: the particle filter handing its observation model the posterior
at single places (``Localizer(smooth_feedback=False)``, the filter before its feedback was
smoothed over the confidence neighbourhoods), for a before/after in one code state.

``--jump-graduation X``: the particle filter with its jump grid (the ``filter`` method's
``jump_graduation=X``, the same as ``--params '{"jump_graduation": X}'``), for a
before/after in one code state.

``--jump-timing [--before PATH]``: the step time with and without the jump grid
(``jump_graduation`` 0.2 and 1) at 10⁴ and 10⁵ places (a chain, a fixed log-ratio vector,
2,000 particles), each measurement in a fresh process, the configurations alternated,
the one-minute load average beside each; with ``--before``, the same from the checkout
at PATH alternated with this one; and the jump kernels' compile time in a process with
an empty numba cache. Writes ``particles_jump_grid_speed.md`` / ``.json``.

``--large-timing [--before PATH]``: the same at 3,576 (Nordland's size), 10⁵ and 10⁶
places (30 steps per timing); writes ``particles_step_speed.md`` / ``.json``.

``--diagnose``: where the seeds differ on Nordland, shuffled 0.5–3 % (seed 4): the share of
frames answered correctly by frames since the last jump, per filter seed, and the frames
each seed takes to the first correct answer of a segment (printed, nothing written).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import describe_machine  # noqa: E402
from bench_filter import _FixedModel, _time_steps  # noqa: E402
from datasets import benchmark_conditions, prepare_kept, prepared_datasets  # noqa: E402

from catgraph.experiment import Experiment, run_method  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def _run(params: dict, prepared: list) -> tuple[float, float, float, float, list[float]]:
    """Mean AUC, R@100P, MTL over the cases, seconds per frame, and each case's AUC."""
    metrics, seconds, frames = [], 0.0, 0
    for p in prepared:
        result = run_method("filter", params, p)
        metrics.append(result.evaluate(p.ground_truth).metrics.as_dict())
        seconds += result.seconds
        frames += len(p.query)
    return (float(np.mean([m["auc"] for m in metrics])), float(np.mean([m["recall_at_100p"] for m in metrics])),
            float(np.mean([m["mtl"] for m in metrics])), seconds / frames, [float(m["auc"]) for m in metrics])


def accuracy(datasets: dict, conditions: list, params: dict, seeds: list[int]) -> list[dict]:
    rows = []
    for ds, cases in datasets.items():
        for condition in conditions:
            prepared = [case.under(condition) if condition.kind != "in-order" else case for case in cases]
            grid = _run({"mode": "grid"}, prepared)
            runs = [_run({"mode": "particles", "seed": s, **params}, prepared) for s in seeds]
            aucs = [r[0] for r in runs]
            row = {"dataset": ds, "condition": condition.label, "condition_spec": condition.as_dict(),
                   "grid": {"auc": grid[0], "recall_at_100p": grid[1], "mtl": grid[2], "seconds_per_frame": grid[3]},
                   "particles": {"auc": aucs, "recall_at_100p": [r[1] for r in runs], "mtl": [r[2] for r in runs],
                                 "seconds_per_frame": [r[3] for r in runs], "auc_by_case": [r[4] for r in runs]},
                   "grid_auc_by_case": grid[4],
                   "auc_mean": float(np.mean(aucs)), "auc_spread": float(np.ptp(aucs)),
                   # the spread of each case (UJI: each month) on its own, the largest
                   "case_spread": float(np.max(np.ptp(np.array([r[4] for r in runs]), axis=0)))}
            rows.append(row)
            print(f"{ds:10s} {condition.label:28s} grid {grid[0]:.3f}  particles {row['auc_mean']:.3f} "
                  f"(spread {row['auc_spread']:.3f})  {time.strftime('%X')}", flush=True)
    return rows


def diagnose(params: dict, seeds: list[int]) -> None:
    """Print, per filter seed, the share of correct answers by frames since the last jump
    and the mean re-acquisition delay (frames to a segment's first correct answer)."""
    from catgraph.conditions import Condition

    p = prepared_datasets(["nordland"])["Nordland"][0].under(Condition("shuffle", seed=4,
                                                                      segment_range=(0.005, 0.03)))
    correct = []
    for s in seeds:
        r = run_method("filter", {"mode": "particles", "seed": s, **params}, p)
        correct.append(p.ground_truth.correct(r.query_index, r.match))
        print(f"seed {s}: AUC {r.evaluate(p.ground_truth).metrics.auc:.3f}", flush=True)
    correct = np.array(correct)
    qi = r.query_index
    starts = np.flatnonzero(np.r_[True, np.diff(qi) != 1])
    since = np.arange(len(qi)) - starts[np.searchsorted(starts, np.arange(len(qi)), side="right") - 1]
    for lo, hi in ((0, 1), (1, 3), (3, 6), (6, 10), (10, 20), (20, 40), (40, len(qi))):
        m = (since >= lo) & (since < hi)
        print(f"{lo}–{hi - 1} frames after a jump ({m.sum()} frames):", np.round(correct[:, m].mean(1), 3))
    ends = np.r_[starts[1:], len(qi)]
    delay = np.array([[np.argmax(c[a:b]) if c[a:b].any() else b - a for c in correct] for a, b in zip(starts, ends)])
    print(f"{len(starts)} segments; mean re-acquisition delay per seed:", np.round(delay.mean(0), 1),
          "; segments whose delays differ by more than 5 frames:", int(np.sum(np.ptp(delay, 1) > 5)))


def step_times(repeats: int = 7) -> list[dict]:
    """Step time (observation excluded) on a 3,576-place chain, medians of ``repeats``
    runs, particles and grid alternating so both see the same machine load."""
    from catgraph.graph import PlaceGraph
    from catgraph.grid import GridLocalizer
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion

    rng = np.random.default_rng(0)
    n = 3576
    rows = rng.standard_normal((110, n))
    g = PlaceGraph.chain(n)
    out = []
    grid_t = []
    pf_t = {(k, True): [] for k in (1000, 2000, 5000, 10000)}
    pf_t[2000, False] = []
    for _ in range(repeats):
        grid_t.append(_time_steps(GridLocalizer(g, _FixedModel(0.3 * rows[0], 0.0)), rows))
        for k, marginal in pf_t:
            pf_t[k, marginal].append(_time_steps(Localizer(g, _FixedModel(0.3 * rows[0], 0.0), k, motion=VelocityMotion(),
                                                           marginal_velocity=marginal, seed=0), rows))
    grid_ms = 1e3 * statistics.median(grid_t)
    out.append({"filter": "grid filter, 8 velocity bins", "places": n, "ms": grid_ms, "ratio_to_grid": 1.0})
    for (k, marginal), t in pf_t.items():
        ms = 1e3 * statistics.median(t)
        label = "" if marginal else ", one sampled velocity per particle"
        out.append({"filter": f"particle filter, {k:,} particles{label}", "places": n, "ms": ms,
                    "ratio_to_grid": ms / grid_ms})
    return out


_ONE_TIMING = """
import json, os, statistics, sys, time
import numpy as np
sys.path.insert(0, {bench!r})
from bench_filter import _FixedModel, _time_steps
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion
n, lam, steps = {n}, {lam}, {steps}
four = np.random.default_rng(0).standard_normal((4, n))  # the rows cycled (the model ignores them but for rows[0])
rows = [four[k % 4] for k in range(steps + 10)]
g = PlaceGraph.chain(n)
def make():
    kw = dict(jump_graduation=lam) if lam < 1 else dict()
    return Localizer(g, _FixedModel(-rows[0]), 2000, motion=VelocityMotion(), seed=0, **kw)
_time_steps(make(), rows[:12])  # compiled, warm
load = os.getloadavg()[0]
loc = make()
loc.reset()
for r in rows[:10]:
    loc.step(r)
cpu = time.process_time()  # the process's own processor time: what other processes' load leaves out
start = time.perf_counter()
for r in rows[10:]:
    loc.step(r)
t = (time.perf_counter() - start) / (len(rows) - 10)
cpu = (time.process_time() - cpu) / (len(rows) - 10)
print(json.dumps({{"ms": 1e3 * t, "cpu_ms": 1e3 * cpu, "load": load}}))
"""

_COMPILE = """
import json, sys, time
import numpy as np
t0 = time.perf_counter()
from catgraph._jump_kernels import block_starts, jump_lost, jump_step, line_segments, segment_edges
from catgraph.grid import _bin_moves, route_neighbours
from catgraph.graph import PlaceGraph
from catgraph.motion import VelocityMotion
m = VelocityMotion(); g = PlaceGraph.chain(50); m.supports_marginal(g)
fwd, bwd = route_neighbours(g)[:2]; seg = line_segments(fwd, bwd)
whole, frac, sign, _ = _bin_moves(m._v); nb = len(m._v)
s = np.random.default_rng(0).random((nb, 50))
t1 = time.perf_counter()
jump_lost(s, seg, segment_edges(seg, 4), *m._columns, whole, frac, sign)
starts = block_starts(seg, 3)
k = len(starts) - 1
out = [np.empty((nb, 50)), np.empty(50), np.empty(50), np.empty((k, nb)), np.empty(k)]
for threads in (1, 2):
    jump_step(s, out[0], seg, *m._columns, whole, frac, sign, 3, 0.005, 0.9, 1e-3, np.full(nb, 1 / nb),
              np.ones(50), 1.0, starts, *out[1:], threads=threads)
t2 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "compile_s": t2 - t1}}))
"""


def jump_timing(before: str | None, places=(10_000, 100_000), rounds: int = 5, steps: int = 50,
                compile_time: bool = True) -> dict:
    """The step with and without the jump grid, each timing in a fresh process, the
    configurations (and, with ``before``, the two checkouts) alternated round by round;
    then (``compile_time``) the jump kernels' cold compile time (an empty numba cache)."""
    import os
    import subprocess
    import tempfile

    here = str(Path(__file__).resolve().parents[1])
    codes = [("this checkout", here)] + ([("before", str(Path(before).resolve()))] if before else [])
    out = {"rounds": rounds, "steps": steps, "codes": {k: _commit(v) for k, v in codes}, "rows": []}
    for n in places:
        cells = {(code, lam): [] for code, _ in codes for lam in (1.0, 0.2)}
        for r in range(rounds):
            for (code, path) in codes:
                for lam in (1.0, 0.2):
                    script = _ONE_TIMING.format(bench=str(Path(path) / "benchmarks"), n=n, lam=lam, steps=steps)
                    env = {**os.environ, "PYTHONPATH": path}
                    res = subprocess.run([sys.executable, "-c", script], env=env, cwd=path, capture_output=True,
                                         text=True, check=True)
                    cells[code, lam].append(json.loads(res.stdout.strip().splitlines()[-1]))
                    print(n, code, lam, cells[code, lam][-1], flush=True)
        for (code, lam), ts in cells.items():
            ms = [t["ms"] for t in ts]
            row = {"places": n, "code": code, "jump_graduation": lam, "ms_median": statistics.median(ms), "ms": ms,
                   "load": [t["load"] for t in ts]}
            if all("cpu_ms" in t for t in ts):
                row["cpu_ms"] = [t["cpu_ms"] for t in ts]
                row["cpu_ms_median"] = statistics.median(row["cpu_ms"])
            out["rows"].append(row)
    compile_runs = []
    for _ in range(2 if compile_time else 0):
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "PYTHONPATH": here, "NUMBA_CACHE_DIR": cache}
            res = subprocess.run([sys.executable, "-c", _COMPILE.format()], env=env, cwd=here, capture_output=True,
                                 text=True, check=True)
            compile_runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
    out["compile"] = compile_runs
    return out


def _commit(path: str) -> str:
    import subprocess

    res = subprocess.run(["git", "-C", path, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", path, "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                           text=True).stdout.strip()
    return res.stdout.strip() + (" (with uncommitted changes)" if dirty else "")


def _jump_timing_markdown(t: dict, flag: str = "--jump-timing",
                          title: str = "The particle filter's step with and without its jump grid") -> str:
    codes = t["codes"]
    parts = [f"# {title}\n\n",
             f"Generated by `benchmarks/bench_particles.py {flag}" + (" --before PATH" if len(codes) > 1 else "") +
             "`: one step, observation excluded (a fixed log-ratio vector), a chain of places, 2,000 particles, "
             f"`VelocityMotion`; each timing the mean of {t['steps']} steps in a fresh process (after 12 warm steps), "
             f"the configurations alternated over {t['rounds']} rounds; median of the rounds, the one-minute load "
             "average over them beside it. Code: " + "; ".join(f"{k} {v}" for k, v in codes.items()) + ". "
             f"{describe_machine()}, numpy {np.__version__}.\n\n",
             "| places | code | without (`jump_graduation` 1) | with (0.2) | with ÷ without | load |\n"
             "|---|---|---|---|---|---|\n"]
    rows = t["rows"]
    if rows and "cpu_ms_median" in rows[0]:
        parts[1] += ("Beside the wall time, the process's own processor time per step (`time.process_time`), "
                     "which leaves out the time other processes hold the cores (on one thread it is the step's "
                     "own time; it still includes their contention for caches and memory).\n\n")
        parts[2] = ("| places | code | without (`jump_graduation` 1) | with (0.2) | with ÷ without | "
                    "processor time without | with | with ÷ without | load |\n|---|---|---|---|---|---|---|---|---|\n")
    for n in dict.fromkeys(r["places"] for r in rows):
        for code in codes:
            a = next(r for r in rows if r["places"] == n and r["code"] == code and r["jump_graduation"] == 1.0)
            b = next(r for r in rows if r["places"] == n and r["code"] == code and r["jump_graduation"] == 0.2)
            loads = a["load"] + b["load"]
            cpu = ""
            if "cpu_ms_median" in a:
                cpu = (f" {a['cpu_ms_median']:.2f} ms | {b['cpu_ms_median']:.2f} ms | "
                       f"{b['cpu_ms_median'] / a['cpu_ms_median']:.2f} |")
            parts.append(f"| {n:,} | {code} ({codes[code]}) | {a['ms_median']:.2f} ms | {b['ms_median']:.2f} ms | "
                         f"{b['ms_median'] / a['ms_median']:.2f} |{cpu} {min(loads):.1f}–{max(loads):.1f} |\n")
    c = t["compile"]
    if not c:
        return "".join(parts)
    parts.append("\nCompile time of the jump kernels (`jump_lost`, `jump_step` on one thread and on two: "
                 "`_jump_blocks`, `_cumulate_blocks`) in a process with an empty numba cache: " +
                 ", ".join(f"{r['compile_s']:.2f} s" for r in c) + " (the package's own imports before it: " +
                 ", ".join(f"{r['import_s']:.2f} s" for r in c) + "); a cached process loads them from disk.\n")
    return "".join(parts)


def compare_markdown(without: dict, with_: dict, labels=("without", "with")) -> str:
    """Per cell, two runs of :func:`accuracy` side by side (the same grid column): mean AUC,
    spread over the filter seeds, the largest spread of one case; per dataset the means, the
    largest fall of a cell's mean and of one case's mean (a UJI month), and the cells whose
    spread is at most 0.02."""
    a_rows = {(r["dataset"], r["condition"]): r for r in without["rows"]}
    b_rows = {(r["dataset"], r["condition"]): r for r in with_["rows"]}
    keys = [k for k in a_rows if k in b_rows]
    w, v = labels
    parts = [f"| dataset | condition | grid | mean AUC {w} | {v} | change | spread {w} | {v} | largest spread of one "
             f"case {w} | {v} | largest fall of one case's mean |\n|---|---|---|---|---|---|---|---|---|---|---|\n"]
    summary = []
    for ds in dict.fromkeys(k[0] for k in keys):
        sub = [(a_rows[k], b_rows[k]) for k in keys if k[0] == ds]
        for a, b in sub:
            case_a = np.mean(a["particles"]["auc_by_case"], axis=0)
            case_b = np.mean(b["particles"]["auc_by_case"], axis=0)
            parts.append(f"| {ds} | {a['condition']} | {a['grid']['auc']:.3f} | {a['auc_mean']:.3f} | "
                         f"{b['auc_mean']:.3f} | {b['auc_mean'] - a['auc_mean']:+.3f} | {a['auc_spread']:.3f} | "
                         f"{b['auc_spread']:.3f} | {a['case_spread']:.3f} | {b['case_spread']:.3f} | "
                         f"{min(0.0, float(np.min(case_b - case_a))):+.3f} |\n")
        changes = [b["auc_mean"] - a["auc_mean"] for a, b in sub]
        case_falls = [float(np.min(np.mean(b["particles"]["auc_by_case"], 0) - np.mean(a["particles"]["auc_by_case"], 0)))
                      for a, b in sub]
        summary.append(f"| **{ds}** | all {len(sub)} conditions | mean {np.mean([a['grid']['auc'] for a, _ in sub]):.3f} "
                       f"| mean {np.mean([a['auc_mean'] for a, _ in sub]):.3f} | {np.mean([b['auc_mean'] for _, b in sub]):.3f} "
                       f"| smallest {min(changes):+.3f} | worst {max(a['auc_spread'] for a, _ in sub):.3f} | "
                       f"{max(b['auc_spread'] for _, b in sub):.3f} | worst {max(a['case_spread'] for a, _ in sub):.3f} "
                       f"| {max(b['case_spread'] for _, b in sub):.3f} | {min(0.0, min(case_falls)):+.3f} |\n")
        summary.append(f"| | cells with spread ≤ 0.02 | | {sum(a['auc_spread'] <= 0.02 for a, _ in sub)} of {len(sub)} | "
                       f"{sum(b['auc_spread'] <= 0.02 for _, b in sub)} of {len(sub)} | | | | | | |\n")
    return "".join(parts + summary)


def convergence(seeds=range(3)) -> list[dict]:
    """Mean (over frames and seeds) total-variation distance between the particle
    filter's and the grid filter's place posteriors on the synthetic world, in order,
    with the same fixed-temperature whole-image model."""
    from catgraph.grid import GridLocalizer
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion
    from catgraph.observation import TemperedObservation

    p = prepare_kept(Experiment(query="synthetic:0", reference="synthetic:0"))
    g = p.graph()
    d = p.differences[:400]

    def model():
        return TemperedObservation(temperature=0.5)

    exact = GridLocalizer(g, model()).run(d, return_posterior=True).posterior
    exact = exact / exact.sum(1, keepdims=True)
    out = []
    for n in (500, 2000, 8000, 32000):
        tv = []
        for s in seeds:
            post = Localizer(g, model(), n, motion=VelocityMotion(), new_place_prior=0.0, seed=s).run(
                d, return_posterior=True).posterior
            tv.append(float(0.5 * np.abs(post / post.sum(1, keepdims=True) - exact).sum(1).mean()))
        out.append({"n_particles": n, "tv_mean": float(np.mean(tv)), "tv_by_seed": tv})
        print(f"convergence N={n}: TV {np.mean(tv):.3f}", flush=True)
    return out


def _markdown(rows, times, conv, params, seeds, quick) -> str:
    parts = ["# The particle filter beside the exact grid filter\n\n",
             "Generated by `benchmarks/bench_particles.py" + (" --quick" if quick else "") + "`. Both through the "
             "registry (`filter`, `mode` grid / particles, registry defaults" +
             (f", particles with {json.dumps(params)}" if params else "") + f"); particle filter seeds "
             f"{', '.join(map(str, seeds))}. Each cell: grid AUC | particles mean AUC | spread (max − min over "
             "seeds) | particles' worst seed. UJI: means over months 02–06. Ground truth ±2 frames (Nordland), 3 m "
             "(UJI), the synthetic world's own tolerance.\n"]
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        parts.append(f"\n## {ds}\n\n| condition | grid | particles (mean) | spread | worst seed | "
                     "largest spread of one case | s/frame grid | s/frame particles |\n|---|---|---|---|---|---|---|---|\n")
        for r in (r for r in rows if r["dataset"] == ds):
            pt = r["particles"]
            parts.append(f"| {r['condition']} | {r['grid']['auc']:.3f} | {r['auc_mean']:.3f} | {r['auc_spread']:.3f} "
                         f"| {min(pt['auc']):.3f} | {r.get('case_spread', r['auc_spread']):.3f} | "
                         f"{r['grid']['seconds_per_frame'] * 1e3:.2f} ms | "
                         f"{statistics.median(pt['seconds_per_frame']) * 1e3:.2f} ms |\n")
        sub = [r for r in rows if r["dataset"] == ds]
        parts.append(f"| **all conditions** | mean {np.mean([r['grid']['auc'] for r in sub]):.3f} | mean "
                     f"{np.mean([r['auc_mean'] for r in sub]):.3f} | worst {max(r['auc_spread'] for r in sub):.3f} | "
                     f"| worst {max(r.get('case_spread', r['auc_spread']) for r in sub):.3f} | | |\n")
    if times:
        parts.append("\n## Step time, observation excluded\n\n3,576-place chain, a fixed log-ratio vector; medians "
                     "of 7 runs of 100 steps, particle filter (`VelocityMotion`) and grid filter alternating in the "
                     f"same run. {describe_machine()}, numpy {np.__version__}.\n\n| filter | step (ms) | ÷ grid |\n"
                     "|---|---|---|\n")
        for t in times:
            parts.append(f"| {t['filter']} | {t['ms']:.3f} | {t['ratio_to_grid']:.2f} |\n")
    if conv:
        parts.append("\n## Convergence to the grid filter\n\nSynthetic world, first 400 frames in order, "
                     "`TemperedObservation(temperature=0.5)` for both filters (same motion, same recovery, no new "
                     "place): total-variation distance between the place posteriors, mean over frames and seeds "
                     "0–2.\n\n| particles | TV |\n|---|---|\n")
        for c in conv:
            parts.append(f"| {c['n_particles']:,} | {c['tv_mean']:.3f} |\n")
    return "".join(parts)


def _localizer_default(name: str, value) -> None:
    """Make every ``Localizer`` built from here on default to ``name=value`` (for the
    parameters the registry does not expose)."""
    import functools

    from catgraph import localizer

    init = localizer.Localizer.__init__

    @functools.wraps(init)
    def changed(self, *args, **kwargs):
        kwargs.setdefault(name, value)
        init(self, *args, **kwargs)

    localizer.Localizer.__init__ = changed


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--datasets", default="nordland,uji,synthetic")
    ap.add_argument("--params", default="{}", help="particle-filter parameters (JSON) on top of the registry's")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--out", default="particles", help="results file stem under benchmarks/results")
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--diagnose", action="store_true", help="print where the seeds differ (see above) and stop")
    ap.add_argument("--sampled-velocity", action="store_true",
                    help="the particle filter as before its velocity was marginalised (Localizer(marginal_velocity="
                         "False): one sampled velocity bin per particle), for a before/after in one code state")
    ap.add_argument("--unsmoothed-feedback", action="store_true",
                    help="the particle filter as before its feedback was smoothed (Localizer(smooth_feedback=False): "
                         "the posterior at single places), for a before/after in one code state")
    ap.add_argument("--jump-graduation", type=float, default=None,
                    help="the particle filter with its jump grid (filter method jump_graduation=X, X in (0, 1)): the "
                         "recovery share kept exactly over (place, velocity bin), a share X of it born each step")
    ap.add_argument("--jump-timing", action="store_true",
                    help="the step with and without the jump grid at 10^4 and 10^5 places (fresh processes, "
                         "alternated) and the jump kernels' compile time; writes particles_jump_grid_speed.md")
    ap.add_argument("--large-timing", action="store_true",
                    help="the step with and without the jump grid at 3,576, 10^5 and 10^6 places (fresh "
                         "processes, alternated); writes particles_step_speed.md")
    ap.add_argument("--before", default=None,
                    help="with --jump-timing or --large-timing: a second checkout, alternated with this one")
    ap.add_argument("--compare", nargs=2, metavar=("WITHOUT", "WITH"), default=None,
                    help="print the cells of two results files (stems under benchmarks/results) side by side")
    args = ap.parse_args(argv)
    if args.compare:
        runs = [json.loads((RESULTS / f"{stem}.json").read_text()) for stem in args.compare]
        print(compare_markdown(*runs, labels=tuple(args.compare)))
        return
    if args.jump_timing:
        t = jump_timing(args.before)
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "particles_jump_grid_speed.json").write_text(json.dumps({"machine": describe_machine(), **t},
                                                                           indent=1))
        (RESULTS / "particles_jump_grid_speed.md").write_text(_jump_timing_markdown(t))
        return
    if args.large_timing:
        t = jump_timing(args.before, places=(3_576, 100_000, 1_000_000), steps=30, compile_time=False)
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "particles_step_speed.json").write_text(json.dumps({"machine": describe_machine(), **t}, indent=1))
        (RESULTS / "particles_step_speed.md").write_text(_jump_timing_markdown(
            t, "--large-timing", "The particle filter's step on large maps, with and without its jump grid"))
        return
    if args.sampled_velocity:
        _localizer_default("marginal_velocity", False)
    if args.unsmoothed_feedback:
        _localizer_default("smooth_feedback", False)
    params = json.loads(args.params)
    if args.jump_graduation is not None:  # a registry parameter of the filter method
        params["jump_graduation"] = args.jump_graduation
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.diagnose:
        diagnose(params, seeds)
        return
    conditions = benchmark_conditions(args.quick)
    rows = accuracy(prepared_datasets(args.datasets.split(",")), conditions, params, seeds)
    times = None if args.no_timing else step_times()
    conv = None if args.no_timing else convergence()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps({"machine": describe_machine(), "params": params,
                                                          "seeds": seeds, "rows": rows, "step_times": times,
                                                          "convergence": conv}, indent=1))
    (RESULTS / f"{args.out}.md").write_text(_markdown(rows, times, conv, params, seeds, args.quick))


if __name__ == "__main__":
    main()
