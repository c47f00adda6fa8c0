"""The grid filter's step on a large line map, piece by piece, against a memory floor.

Usage (from the project root)::

    python benchmarks/bench_grid_speed.py                       # -> results/grid_speed.md (+ .json)
    python benchmarks/bench_grid_speed.py --trees OLD NEW ...   # -> results/grid_speed_trees.md: several trees
    python benchmarks/bench_grid_speed.py --rigid 0.05          # -> results/grid_speed_rigid.md: with a rigid line

One step of :class:`catgraph.grid.GridLocalizer` (the default 8 velocities in 10 state
bins, line graph: the fast path) at 100,000 places, the observation precomputed (a
fixed log-ratio vector, as ``bench_filter.py speed``), timed as the median over several
runs of 20 steps each; beside every run, in the same process, one ``np.add`` over an
array of the state's size (8 × places float64), the floor the step is reported against
(the machine is shared, so absolute times move with its load). The profile times every
compiled kernel and Python piece of the step on its own (the median of its calls), so
that what the step is made of can be read off.

``--trees`` runs the step in one fresh process per tree and run (``PYTHONPATH`` set to
the tree), the trees alternated run after run, so that the load falls on each alike:
the before/after comparison of a change. The load average is recorded with every run.

``--rigid P`` runs the step without and with the rigid line beside the motion
(``GridLocalizer(rigid_prior=P)``; the registry's ``filter`` method holds 0.05 on maps of
at most 10,000 places), one fresh
process each, alternated.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

N_PLACES = 100_000
N_ROWS = 30
N_WARM = 10

from bench_filter import _FixedModel  # noqa: E402  (observation precomputed)
from bench_filter import _memory_reference as _floor  # noqa: E402  (one np.add, the floor)


def _localizer(n: int = N_PLACES, rigid_prior: float = 0.0):
    from catgraph.graph import PlaceGraph
    from catgraph.grid import GridLocalizer

    rows = np.random.default_rng(0).standard_normal((N_ROWS, n))
    loc = GridLocalizer(PlaceGraph.chain(n), _FixedModel(-rows[0]), rigid_prior=rigid_prior).reset()
    return loc, rows


def _one_run(loc, rows, cpu: list | None = None) -> float:
    """Seconds per step over the rows after ``N_WARM`` warm-up steps (wall clock;
    ``cpu`` given: the process's CPU seconds per step appended to it, every thread's
    work counted, the time spent waiting for a core not)."""
    loc.reset()
    for r in rows[:N_WARM]:
        loc.step(r)
    start, start_cpu = time.perf_counter(), time.process_time()
    for r in rows[N_WARM:]:
        loc.step(r)
    if cpu is not None:
        cpu.append((time.process_time() - start_cpu) / (len(rows) - N_WARM))
    return (time.perf_counter() - start) / (len(rows) - N_WARM)


def measure(runs: int = 7, rigid_prior: float = 0.0) -> dict:
    """Step and floor, ``runs`` times alternated; medians in milliseconds."""
    loc, rows = _localizer(rigid_prior=rigid_prior)
    _one_run(loc, rows)  # compile, fault the buffers in
    step, floor, cpu = [], [], []
    for _ in range(runs):
        step.append(_one_run(loc, rows, cpu))
        floor.append(_floor(8 * N_PLACES))
    return {"step_ms": 1e3 * statistics.median(step), "floor_ms": 1e3 * statistics.median(floor),
            "cpu_ms": 1e3 * statistics.median(cpu),
            "ratio": statistics.median(s / f for s, f in zip(step, floor)), "runs": runs,
            "load": os.getloadavg()[0], "package": str(Path(__import__("catgraph").__file__).parent)}


def profile(rounds: int = 5) -> dict:
    """Median milliseconds of each piece of the step (its own calls timed, the step
    otherwise unchanged)."""
    import catgraph.grid as grid
    import catgraph.localizer as localizer

    loc, rows = _localizer()
    _one_run(loc, rows)
    times: dict = {}
    counting = [False]

    def timed(owner, name, label):
        f = getattr(owner, name)

        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            out = f(*args, **kwargs)
            if counting[0]:
                times.setdefault(label, []).append(time.perf_counter() - start)
            return out

        setattr(owner, name, wrapper)
        return f

    pieces = [(grid, name, f"grid.{name}") for name in
              ("_line_setup", "_line_blocks", "_line_sums", "_line_predict", "_evidence_sums", "_posterior_pass",
               "_likelihood", "_inside_outside") if hasattr(grid, name)]
    pieces += [(localizer, "_smoothed", "localizer._smoothed")]
    pieces += [(grid.GridLocalizer, name, f"GridLocalizer.{name}") for name in
               ("_exp_ratio", "_predict", "_update", "_summarise", "_feedback")]
    saved = [(owner, name, timed(owner, name, label)) for owner, name, label in pieces]
    try:
        steps = []
        for _ in range(rounds):
            loc.reset()
            for r in rows[:N_WARM]:
                loc.step(r)
            counting[0] = True
            for r in rows[N_WARM:]:
                start = time.perf_counter()
                loc.step(r)
                steps.append(time.perf_counter() - start)
            counting[0] = False
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
    out = {label: 1e3 * statistics.median(v) for label, v in times.items()}
    out["step (profiled)"] = 1e3 * statistics.median(steps)
    out["np.add floor"] = 1e3 * _floor(8 * N_PLACES)
    return out


def threads(runs: int = 9) -> dict:
    """The step on one thread, on two (the load left out of the choice), and with the
    default choice, alternated; per setting the median ms, and the load averages."""
    import catgraph.grid as grid

    loc, rows = _localizer()
    _one_run(loc, rows)
    work, free = grid.LINE_WORK_PER_THREAD, grid._free_cores
    settings = {"one thread": (1 << 62, free), "two threads": (1, lambda cores: cores),
                "default (the load decides)": (work, free)}
    times: dict = {k: [] for k in settings}
    loads = []
    try:
        for _ in range(runs):
            for name, (w, f) in settings.items():
                grid.LINE_WORK_PER_THREAD, grid._free_cores = w, f
                times[name].append(1e3 * _one_run(loc, rows))
            loads.append(os.getloadavg()[0])
    finally:
        grid.LINE_WORK_PER_THREAD, grid._free_cores = work, free
    return {"ms": {k: statistics.median(v) for k, v in times.items()}, "load": [min(loads), max(loads)],
            "floor_ms": 1e3 * _floor(8 * N_PLACES)}


def compare(trees: list[str], runs: int = 5, priors: tuple = (0.0,)) -> dict:
    """One fresh process per tree (and rigid prior) and run, alternated; per tree the runs'
    results (several priors: keyed ``tree, rigid_prior=P``)."""
    keys = {(tree, p): tree if len(priors) == 1 else f"{tree}, rigid_prior={p:g}" for tree in trees for p in priors}
    results: dict = {k: [] for k in keys.values()}
    for _ in range(runs):
        for (tree, p), key in keys.items():
            env = dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
            out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--one", str(p)], env=env,
                                 check=True, capture_output=True, text=True, cwd=str(Path(tree).resolve())).stdout
            results[key].append(json.loads(out.strip().splitlines()[-1]))
            print(key, results[key][-1], flush=True)
    return results


def _table(results: dict) -> str:
    lines = ["| tree | step (ms), median of runs | np.add floor (ms) | step / np.add | CPU ms per step (all threads) "
             "| load (1 min) |", "|---|---|---|---|---|---|"]
    for tree, runs in results.items():
        step = statistics.median(r["step_ms"] for r in runs)
        floor = statistics.median(r["floor_ms"] for r in runs)
        ratio = statistics.median(r["ratio"] for r in runs)
        cpu = statistics.median(r["cpu_ms"] for r in runs)
        loads = [r["load"] for r in runs]
        lines.append(f"| `{tree}` | {step:.3f} | {floor:.3f} | {ratio:.2f} | {cpu:.3f} | "
                     f"{min(loads):.1f}–{max(loads):.1f} |")
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    if argv and argv[0] == "--one":
        print(json.dumps(measure(rigid_prior=float(argv[1]) if len(argv) > 1 else 0.0)))
        return
    if argv and argv[0] == "--rigid":
        results = compare([str(ROOT)], priors=(0.0, float(argv[1])))
        text = ["# Grid filter step at 100,000 places: without and with the rigid line", "",
                f"`python benchmarks/bench_grid_speed.py --rigid {argv[1]}`: one fresh process per setting and run, "
                "alternated; in each process the step (8 velocities in 10 state bins, line graph, observation "
                f"precomputed) as the median of 7 runs of {N_ROWS - N_WARM} steps beside one `np.add` over 8 × "
                "places float64; the table gives the medians over the processes.", "", _table(results)]
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "grid_speed_rigid.md").write_text("\n".join(text) + "\n")
        (RESULTS / "grid_speed_rigid.json").write_text(json.dumps(results, indent=1) + "\n")
        print("\n".join(text))
        return
    if argv and argv[0] == "--trees":
        results = compare(argv[1:])
        text = ["# Grid filter step at 100,000 places: source trees compared", "",
                "`python benchmarks/bench_grid_speed.py --trees " + " ".join(argv[1:]) + "`: one fresh process per "
                "tree and run, the trees alternated; in each process the step (8 velocities in 10 state bins, line "
                f"graph, observation precomputed) as the median of 7 runs of {N_ROWS - N_WARM} steps beside one "
                "`np.add` over 8 × places float64; the table gives the medians over the processes.", "",
                _table(results)]
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "grid_speed_trees.md").write_text("\n".join(text) + "\n")
        (RESULTS / "grid_speed_trees.json").write_text(json.dumps(results, indent=1) + "\n")
        print("\n".join(text))
        return
    m = measure()
    p = profile()
    text = ["# Grid filter step at 100,000 places", "",
            "`python benchmarks/bench_grid_speed.py`: one step of `GridLocalizer` (8 velocities in 10 state bins, "
            "line graph: the fast path), observation precomputed; medians of "
            f"{m['runs']} runs of {N_ROWS - N_WARM} steps, each beside one `np.add` over 8 × places float64 in "
            f"the same process. Load average {m['load']:.1f}.", "",
            "| step (ms) | np.add (ms) | step / np.add |", "|---|---|---|",
            f"| {m['step_ms']:.3f} | {m['floor_ms']:.3f} | {m['ratio']:.2f} |", "",
            f"CPU time per step (the process, every thread): {m['cpu_ms']:.3f} ms.", "",
            "Pieces (median ms per call; a piece inside another is counted in both; `_line_blocks` once per "
            "block range, of which a threaded step has several):", "", "| piece | ms |", "|---|---|"]
    text += [f"| `{k}` | {v:.3f} |" for k, v in p.items()]
    t = threads()
    text += ["", f"Threads (the line kernel's block ranges; medians of alternated runs, load average "
             f"{t['load'][0]:.1f}–{t['load'][1]:.1f}, np.add {t['floor_ms']:.3f} ms):", "",
             "| threads | step (ms) |", "|---|---|"]
    text += [f"| {k} | {v:.3f} |" for k, v in t["ms"].items()]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "grid_speed.md").write_text("\n".join(text) + "\n")
    (RESULTS / "grid_speed.json").write_text(json.dumps({"step": m, "profile": p, "threads": t}, indent=1) + "\n")
    print("\n".join(text))


if __name__ == "__main__":
    main(sys.argv[1:])
