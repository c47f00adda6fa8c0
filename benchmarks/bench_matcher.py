"""The sequence matcher's kernels: time per streaming step, peak memory, whole-Nordland
time and compile time, each beside a floor or a reference measured in the same run.

Cases, each in its own process, one after another (peak RSS from ``getrusage``):

``stream N``    :meth:`SequenceMatcher.step` at ``N`` places, adaptive, ``l_max`` 500,
                the 8 default velocities and 13 lengths, on random normalised-looking
                rows. The matcher takes one real step, then its ring is filled with
                ``l_max`` more rows by the matcher's own store kernel (no statistics),
                so every timed step runs the steady-state path (every window full,
                every page of the ring written) without 500 untimed steps. Floor: one
                parallel pass adding a row to every running sum (the ``V G N`` float64
                values a step must read and write), same threads, same process.
``alternate N`` with ``--before`` and ``--current``: both packages' streaming steps in one
                process, alternated step by step (the same load for both).
``nordland``    the whole Nordland 32×16 summer → winter run, adaptive with velocity
                search (8 velocities) and with ``v = 1`` alone as the in-run reference;
                the difference matrix timed separately; medians of ``--runs`` runs.
``compile``     the kernels' first calls with an empty ``NUMBA_CACHE_DIR`` (cold), then
                again in a second process on the filled cache (warm); ``--runs`` such pairs,
                the packages in turn, medians.

``--before REV`` runs every case also on the package as committed at ``REV`` (extracted
with ``git archive`` into a temporary folder as ``catgraph_before``), so the
before/after comparison shares the machine's load. ``--current REV`` measures the
package as committed at ``REV`` instead of the working tree (``catgraph_current``), so
that uncommitted edits elsewhere in the package do not enter the comparison.
Writes ``benchmarks/results/matcher.md`` and ``matcher.json`` (``--out NAME``: ``NAME.md``
and ``NAME.json``)::

    python benchmarks/bench_matcher.py [--sizes 10000 100000 1000000] [--before REV] [--current REV] [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
L_MAX = 500


def _rss_mb() -> float:
    from process_memory import peak_rss_mb  # the case's own peak (VmHWM), not its parent's

    return peak_rss_mb()


def _pkg(name: str):
    import importlib

    return importlib.import_module(name)


# ---------------------------------------------------------------------------------------
# cases (run in child processes)


def case_stream(package: str, n: int, frames: int) -> dict:
    import numba

    k = _pkg(package + "._sequence_kernels")
    SequenceMatcher = _pkg(package + ".sequence").SequenceMatcher

    @numba.njit(parallel=True)
    def floor_pass(sums, row):
        v_count, g_count, m = sums.shape
        for q in numba.prange(v_count * g_count):
            out = sums[q // g_count, q % g_count]
            for j in range(m):
                out[j] += row[j]

    rng = np.random.default_rng(0)
    rows = rng.normal(size=(3, n))  # a few rows, used in turn (the values do not change the work)
    warm = SequenceMatcher(l_max=L_MAX)
    for r in rows[:3, :64]:
        warm.step(r)  # compile (or load) the kernels on a tiny reference
    floor_pass(np.zeros((1, 1, 4), dtype=warm._sums.dtype), np.zeros(4, dtype=warm._ring.dtype))
    rss_start = _rss_mb()
    m = SequenceMatcher(l_max=L_MAX)
    m.step(rows[0])
    for i in range(1, L_MAX + 1):
        k.advance(m._ring, m._mring, m._state, i, rows[i % 3])
    m.n_steps_ = L_MAX + 1
    times, cpu = [], []
    for t in range(frames):
        row = rows[t % 3]
        t0, c0 = time.perf_counter(), time.process_time()
        m.step(row)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)  # every thread of the process: the work, less sensitive to the load
    floors = []
    for t in range(max(5, min(frames, 20))):
        t0 = time.perf_counter()
        floor_pass(m._sums, m._ring[t % m._ring.shape[0]])  # a stored row into every running sum
        floors.append(time.perf_counter() - t0)
    v_count, g_count = m._sums.shape[:2]
    return {
        "package": package, "n": n, "frames": frames, "velocities": int(v_count), "lengths": int(g_count),
        "step_ms_median": 1e3 * float(np.median(times)), "step_ms_p99": 1e3 * float(np.percentile(times, 99)),
        "step_cpu_ms_median": 1e3 * float(np.median(cpu)), "load": os.getloadavg()[0],
        "floor_ms_median": 1e3 * float(np.median(floors)),
        "rss_start_mb": rss_start, "rss_peak_mb": _rss_mb(),
        "ring_mb": m._ring.nbytes / 1e6, "sums_mb": m._sums.nbytes / 1e6,
        "ring_dtype": str(m._ring.dtype), "sums_dtype": str(m._sums.dtype),
        "scratch_mb": sum(b.nbytes for b in m._buffers) / 1e6,
        "bytes_per_velocity": int((m._sums.nbytes + m._buffers[0].nbytes) // v_count),
        "threads": numba.get_num_threads(),
    }


def case_alternate(n: int, steps: int) -> dict:
    """Both packages' :meth:`SequenceMatcher.step` in one process, the steps alternated
    (``catgraph_before``, ``catgraph_current``, then the other way round), so that both
    meet the same load: the wall and CPU time per step of each, as ``stream`` fills the
    ring."""
    rows = np.random.default_rng(0).standard_normal((8, n))
    matchers = {}
    for pkg in ("catgraph_before", "catgraph_current"):
        seq, k = _pkg(pkg + ".sequence"), _pkg(pkg + "._sequence_kernels")
        warm = seq.SequenceMatcher(l_max=L_MAX)
        for r in rows[:3, :64]:
            warm.step(r)  # compile (or load) the kernels on a tiny reference
        m = seq.SequenceMatcher(l_max=L_MAX)
        m.step(rows[0])
        for i in range(1, L_MAX + 1):
            k.advance(m._ring, m._mring, m._state, i, rows[i % 8])
        m.n_steps_ = L_MAX + 1
        for t in range(3):
            m.step(rows[t % 8])
        matchers[pkg] = m
    wall = {pkg: [] for pkg in matchers}
    cpu = {pkg: [] for pkg in matchers}
    load = [os.getloadavg()[0]]
    for t in range(steps):
        for pkg in (("catgraph_before", "catgraph_current") if t % 2 else ("catgraph_current", "catgraph_before")):
            w0, c0 = time.perf_counter(), time.process_time()
            matchers[pkg].step(rows[t % 8])
            wall[pkg].append(time.perf_counter() - w0)
            cpu[pkg].append(time.process_time() - c0)
    load.append(os.getloadavg()[0])
    return {"n": n, "steps": steps, "load": load, **{
        pkg: {"wall_ms_median": 1e3 * float(np.median(wall[pkg])), "wall_ms_p10": 1e3 * float(np.percentile(wall[pkg], 10)),
              "cpu_ms_median": 1e3 * float(np.median(cpu[pkg]))} for pkg in matchers}}


def _nordland_differences():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from datasets import DATA

    from catgraph.datasets import load_traverse
    from catgraph.pipeline import differences

    ref = load_traverse(DATA / "nordland" / "32x16" / "summer")
    query = load_traverse(DATA / "nordland" / "32x16" / "winter")
    return ref, query, differences


def case_nordland(package: str, runs: int) -> dict:
    ref, query, differences = _nordland_differences()
    diff_times = []
    for _ in range(runs if package != "catgraph_before" else 1):
        t0 = time.perf_counter()
        d = differences(ref, query)
        diff_times.append(time.perf_counter() - t0)
    d = np.ascontiguousarray(d)
    match_sequences = _pkg(package + ".sequence").match_sequences
    match_sequences(d[:60])  # compile or load
    out = {"package": package, "shape": list(d.shape), "differences_s": diff_times}
    for name, kwargs in (("v1", {"velocities": (1.0,)}), ("all", {})):
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            res = match_sequences(d, **kwargs)
            times.append(time.perf_counter() - t0)
        out[name + "_s"] = times
        out[name + "_match"] = res.match.tolist()
    return out


def case_compile(package: str) -> dict:
    out = {}

    def timed(label, fn):
        w, c = time.perf_counter(), time.process_time()
        fn()
        out[label] = {"wall_s": time.perf_counter() - w, "cpu_s": time.process_time() - c}

    seq = {}
    timed("import", lambda: seq.setdefault("m", _pkg(package + ".sequence")))
    s = seq["m"]
    d = np.random.default_rng(0).normal(size=(30, 50))
    timed("batch, gaussian (the default)", lambda: s.match_sequences(d))

    def stream():
        m = s.SequenceMatcher()
        m.step(d[0])

    timed("streaming step, gaussian (after the batch)", stream)
    timed("batch, gmm2", lambda: s.match_sequences(d, approximation="gmm2"))
    timed("batch, robust", lambda: s.match_sequences(d, approximation="robust"))
    return out


# ---------------------------------------------------------------------------------------
# driver


def _child(args: list[str], env: dict | None = None, timeout: int = 3600) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _extract_before(rev: str, folder: Path, repo: Path, name: str = "catgraph_before") -> None:
    archive = subprocess.run(["git", "archive", rev, "catgraph"], cwd=repo, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    (folder / "catgraph").rename(folder / name)


def _env(extra_path: Path | None = None, cache: str | None = None) -> dict:
    env = dict(os.environ)
    paths = [str(ROOT)] + ([str(extra_path)] if extra_path else [])
    env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")])
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def _med(values) -> float:
    return float(np.median(values))


def _median_cells(runs: list[dict]) -> dict:
    """Per first call, the median wall and CPU seconds over several processes' runs."""
    return {label: {t: _med([r[label][t] for r in runs]) for t in ("wall_s", "cpu_s")} | {"runs": len(runs)}
            for label in runs[0]}


def _markdown(res: dict) -> str:
    lines = ["# Sequence matcher kernels: step time, memory, whole Nordland, compile time", "",
             f"Generated by `benchmarks/bench_matcher.py` on {res['machine']} ({os.cpu_count()} cores, shared with "
             "other jobs while it ran: compare each figure with the floor or reference measured in the "
             "same process or run). Adaptive matcher, `l_max` 500, 13 candidate lengths, 8 velocities "
             "(±0.5, ±1, ±2, ±3) unless stated.", ""] + [f"Note: {note}" for note in res.get("notes", [])] \
        + ([""] if res.get("notes") else [])
    st = res.get("stream", [])
    if st:
        lines += ["## Streaming step and memory", "",
                  "One process per N. Floor: one parallel pass adding a stored row to every running sum (the V·G·N "
                  "values each step must read and write, in the package's own types), same process, same threads. "
                  "RSS at start: after imports and loading the kernels from the cache a first process filled, "
                  "before the matcher allocates.", "",
                  "Step CPU: the process's CPU time per step (every thread), the median; the work itself, "
                  "less sensitive to the machine's load than the wall time. Load: the 1-minute load average "
                  "at the end of the process.", "",
                  "| N | package | step median | step p99 | step CPU | load | floor (same process) | step / floor "
                  "| peak RSS | RSS at start | ring (shared) | running sums | bytes per velocity |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in st:
            cpu = f"{r['step_cpu_ms_median']:.2f} ms" if "step_cpu_ms_median" in r else "–"
            load = f"{r['load']:.1f}" if "load" in r else "–"
            label = r.get("label", "current") + (f" (round {r['round']})" if "round" in r else "")
            lines.append(
                f"| {r['n']:,} | {label} | {r['step_ms_median']:.2f} ms | {r['step_ms_p99']:.1f} ms "
                f"({r['frames']} steps) | {cpu} | {load} "
                f"| {r['floor_ms_median']:.1f} ms | ×{r['step_ms_median'] / r['floor_ms_median']:.1f} "
                f"| {r['rss_peak_mb']:.0f} MiB | {r['rss_start_mb']:.0f} MiB | {r['ring_mb']:.0f} MB "
                f"({r.get('ring_dtype', 'float32')}) | {r['sums_mb']:.0f} MB ({r.get('sums_dtype', 'float64')}) "
                f"| {r['bytes_per_velocity'] / 1e6:.2f} MB ({r['bytes_per_velocity'] / r['n']:.0f} B per place) |")
        lines += ["", "Memory layout (current): one int16 ring of the codes of the last `l_max + 1` rows shared by "
                  "all velocities (2·501 = 1002 B per place), plus per velocity 13 int32 running sums (4·13 = 52 B "
                  "per place per velocity; 416 B per place for 8 velocities): 1418 B per place in all, 142 MB at "
                  "N = 10⁵, 1.42 GB at N = 10⁶. The float32 ring with float64 sums before it: 4·501 + 8·13·8 = "
                  "2836 B per place. Before that: one float64 prefix ring per velocity, 8·N·501 B = 4008 B per "
                  "place per velocity (3237 MB peak at N = 10⁵ in `benchmarks/results/live.md`; 10⁶ not "
                  "runnable).", ""]
    alt = res.get("alternate", [])
    if alt:
        lines += ["## Streaming step, both packages in one process", "",
                  "`--current` and `--before` imported side by side in one process per row, each with its "
                  "own matcher (ring filled as above); their steps alternated (the order swapped every "
                  "step), so that both meet the same load. Wall: median (10th percentile); CPU: the "
                  "process's CPU time per step, every thread, median. Load: the 1-minute load average at the "
                  "start and the end.", "",
                  "| N | steps each | before: wall | before: CPU | current: wall | current: CPU | current / before (CPU) "
                  "| load |", "|---|---|---|---|---|---|---|---|"]
        for r in alt:
            b, c = r["catgraph_before"], r["catgraph_current"]
            lines.append(f"| {r['n']:,} | {r['steps']} | {b['wall_ms_median']:.2f} ms ({b['wall_ms_p10']:.2f}) "
                         f"| {b['cpu_ms_median']:.2f} ms | {c['wall_ms_median']:.2f} ms ({c['wall_ms_p10']:.2f}) "
                         f"| {c['cpu_ms_median']:.2f} ms | ×{c['cpu_ms_median'] / b['cpu_ms_median']:.2f} "
                         f"| {r['load'][0]:.1f}–{r['load'][1]:.1f} |")
        lines.append("")
    nl = res.get("nordland", {})
    if nl:
        lines += ["## Whole Nordland (3576 × 3576), adaptive", "",
                  f"Medians of {res['runs']} runs, one process per run, the packages in turn; the compile is "
                  "excluded (a warm-up call first). `v = 1 alone` is the in-run reference.", "",
                  "| package | difference matrix | matcher, v = 1 alone | matcher, 8 velocities | 8 velocities / v = 1 "
                  "| total (difference + 8 velocities) |", "|---|---|---|---|---|---|"]
        for key, r in nl.items():
            dif = _med(r["differences_s"])
            lines.append(f"| {key} | {dif:.2f} s | {_med(r['v1_s']):.2f} s | {_med(r['all_s']):.2f} s "
                         f"| ×{_med(r['all_s']) / _med(r['v1_s']):.1f} | {dif + _med(r['all_s']):.2f} s |")
        if "match_identical" in res:
            same = res["match_identical"]
            lines += ["", f"Matches, 8 velocities, current vs before: {100 * same:.1f} % of frames identical."]
        lines.append("")
    cp = res.get("compile", {})
    if cp:
        lines += ["## Compile time (numba)", "",
                  "Each cell: wall / CPU seconds of the first call in a fresh process, the median over "
                  f"{next(iter(next(iter(cp.values()))['cold'].values())).get('runs', 1)} processes (the packages "
                  "in turn); cold = empty `NUMBA_CACHE_DIR`, warm = a second process on the cache the cold one "
                  "filled. On a shared machine compare the CPU seconds of the packages within the table.", ""]
        keys = list(next(iter(cp.values()))["cold"].keys())
        cols = [f"{pkg} {kind}" for pkg in cp for kind in ("cold", "warm")]
        lines += ["| first call | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for key in keys:
            cells = []
            for pkg in cp:
                for kind in ("cold", "warm"):
                    v = cp[pkg][kind].get(key)
                    cells.append(f"{v['wall_s']:.2f} / {v['cpu_s']:.2f}" if v else "–")
            lines.append(f"| {key} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += _goals(res)
    return "\n".join(lines)


def _goals(res: dict) -> list[str]:
    """The goals beside the measured figures."""
    out = ["## Goals", "", "| goal | measured | met |", "|---|---|---|"]
    by_n = {r["n"]: r for r in res.get("stream", []) if r.get("label", "current") == "current"}
    for n, limit in ((100_000, 400), (1_000_000, 3000)):
        if n in by_n:
            r = by_n[n]
            peak = r["rss_peak_mb"] * 1.048576  # MiB to MB
            out.append(f"| streaming peak RSS ≤ {limit} MB at N = {n:,} | {peak:.0f} MB = {r['rss_peak_mb']:.0f} MiB "
                       f"(the process before the matcher: {r['rss_start_mb']:.0f} MiB; ring {r['ring_mb']:.0f} MB + "
                       f"sums {r['sums_mb']:.0f} MB + scratch {r['scratch_mb']:.0f} MB) "
                       f"| {'yes' if peak <= limit else 'no'} |")
    for n, limit in ((100_000, 10), (1_000_000, 100)):
        if n in by_n:
            step = by_n[n]["step_ms_median"]
            out.append(f"| full live step ≤ {limit} ms at N = {n:,} (the matcher's step alone, a part of it) "
                       f"| {step:.1f} ms (floor {by_n[n]['floor_ms_median']:.1f} ms) | {'no' if step > limit else 'not alone'} |")
    nl = res.get("nordland", {}).get("current")
    if nl:
        total = _med(nl["differences_s"]) + _med(nl["all_s"])
        out.append(f"| whole Nordland adaptive with velocity search ≤ 5 s on 2 cores, difference matrix included "
                   f"| {total:.2f} s (on 2 cores shared with other jobs) | {'yes' if total <= 5 else 'no'} |")
    cp = res.get("compile", {})
    if "current" in cp and "before" in cp:
        key = "batch, gaussian (the default)"
        step = "streaming step, gaussian (after the batch)"
        now = cp["current"]["cold"][key]["cpu_s"] + cp["current"]["cold"][step]["cpu_s"]
        then = cp["before"]["cold"][key]["cpu_s"] + cp["before"]["cold"][step]["cpu_s"]
        out.append(f"| cut the cold compile (batch + streaming, CPU seconds) | {then:.1f} s → {now:.1f} s | "
                   f"{'yes' if now < then else 'no'} |")
    out.append("")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--frames", type=int, nargs="*", default=None, help="timed steps per size")
    ap.add_argument("--before", default=None, help="also measure the package at this git revision")
    ap.add_argument("--current", default=None, help="measure the package at this git revision, not the working tree")
    ap.add_argument("--repo", default=str(ROOT), help="the git checkout --before is taken from")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--note", action="append", default=[], help="a note for the results (the machine's load)")
    ap.add_argument("--skip", default="", help="comma-separated: stream,alternate,nordland,compile")
    ap.add_argument("--stream-rounds", type=int, default=1, help="processes per package and N in the stream case")
    ap.add_argument("--out", default="matcher", help="results file name (NAME.md and NAME.json)")
    ap.add_argument("--render", action="store_true", help="only rewrite NAME.md from NAME.json")
    ap.add_argument("--child", nargs="*", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.render:
        (RESULTS / f"{args.out}.md").write_text(_markdown(json.loads((RESULTS / f"{args.out}.json").read_text())))
        return
    if args.child is not None:
        kind = args.child[0]
        if kind == "stream":
            out = case_stream(args.child[1], int(args.child[2]), int(args.child[3]))
        elif kind == "nordland":
            out = case_nordland(args.child[1], int(args.child[2]))
        elif kind == "alternate":
            out = case_alternate(int(args.child[1]), int(args.child[2]))
        else:
            out = case_compile(args.child[1])
        print(json.dumps(out))
        return
    skip = set(filter(None, args.skip.split(",")))
    res = {"machine": platform.platform(), "runs": args.runs, "notes": args.note}
    frames = args.frames or [{10_000: 60, 100_000: 30}.get(n, 8) for n in args.sizes]
    with tempfile.TemporaryDirectory() as tmp:
        before_path = None
        if args.before or args.current:
            before_path = Path(tmp) / "before"
            before_path.mkdir()
        if args.before:
            _extract_before(args.before, before_path, Path(args.repo))
        if args.current:
            _extract_before(args.current, before_path, Path(args.repo), "catgraph_current")
        packages = [("current", "catgraph_current" if args.current else "catgraph")] \
            + ([("before", "catgraph_before")] if args.before else [])
        if "compile" not in skip:
            # --runs cold/warm pairs per package, the packages in turn (a change in the
            # machine's load spreads over both); each cell is the median over the pairs
            runs = {key: {"cold": [], "warm": []} for key, _ in packages}
            for _ in range(args.runs):
                for key, pkg in packages:
                    cache = tempfile.mkdtemp(dir=tmp)
                    runs[key]["cold"].append(_child(["compile", pkg], _env(before_path, cache)))
                    runs[key]["warm"].append(_child(["compile", pkg], _env(before_path, cache)))
                    print("compile", key, runs[key]["cold"][-1], runs[key]["warm"][-1], flush=True)
            res["compile"] = {key: {kind: _median_cells(r[kind]) for kind in r} for key, r in runs.items()}
        if "stream" not in skip:
            for key, pkg in packages:  # compile into the package's cache first: RSS at start without the compiler
                _child(["stream", pkg, "1000", "2"], _env(before_path))
            res["stream"] = []
            # --stream-rounds processes per package and N, the packages in turn
            for round_ in range(args.stream_rounds):
                for n, f in zip(args.sizes, frames):
                    for key, pkg in packages:
                        res["stream"].append(dict(_child(["stream", pkg, str(n), str(f)], _env(before_path)), label=key,
                                                  round=round_ + 1))
                        print("stream", res["stream"][-1], flush=True)
        if "alternate" not in skip and args.before and args.current:
            # both packages in one process, their steps alternated: the same load for both
            res["alternate"] = []
            for _ in range(args.stream_rounds):
                for n, f in zip(args.sizes, frames):
                    res["alternate"].append(_child(["alternate", str(n), str(2 * f)], _env(before_path)))
                    print("alternate", res["alternate"][-1], flush=True)
        if "nordland" not in skip:
            res["nordland"] = {}
            # one run per process, the packages in turn: a change in the machine's load between
            # the packages' runs spreads over both
            for _ in range(args.runs):
                for key, pkg in packages:
                    r = _child(["nordland", pkg, "1"], _env(before_path))
                    if key not in res["nordland"]:
                        res["nordland"][key] = r
                    else:
                        for name in ("differences_s", "v1_s", "all_s"):
                            res["nordland"][key][name] += r[name]
                    print("nordland", key, {k: v for k, v in r.items() if not k.endswith("match")}, flush=True)
    if args.before:
        res["before"] = args.before
    if args.current:
        res["current"] = args.current
    nl = res.get("nordland", {})
    if "before" in nl and "current" in nl:
        same = np.array(nl["before"]["all_match"]) == np.array(nl["current"]["all_match"])
        res["match_identical"] = float(np.mean(same))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(
        {k: v if k != "nordland" else {p: {a: b for a, b in r.items() if not a.endswith("match")}
                                       for p, r in v.items()} for k, v in res.items()}, indent=1))
    (RESULTS / f"{args.out}.md").write_text(_markdown(res))


if __name__ == "__main__":
    main()
