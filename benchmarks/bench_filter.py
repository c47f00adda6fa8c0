"""Filter benchmarks: step time, and the filters on every traversal condition.

Usage (from the project root)::

    python benchmarks/bench_filter.py speed                 # -> results/filter_speed.md
    python benchmarks/bench_filter.py conditions [--quick]  # -> results/filter_compare.md (+ .json)
    python benchmarks/bench_filter.py seeds                 # particle-filter seed spread -> results/filter_seeds.md
    python benchmarks/bench_filter.py threshold             # one global threshold -> results/filter_threshold.md
    python benchmarks/bench_filter.py jumps                 # oracle jumps, accuracy after a jump -> results/filter_jumps.md

``speed`` times one step of the particle filter (2,000 particles, observation
precomputed) on Nordland's graph size and one step of the grid filter at 3,576 and
100,000 places (observation excluded), medians of repeated runs.

``conditions`` runs, with the library defaults and nothing tuned per dataset,

* single-frame matching (best place of each row; confidence: the margin to the best
  place outside ± 10 reference frames),
* the grid filter (:class:`catgraph.grid.GridLocalizer`) with the tempered whole-image
  model (:class:`catgraph.observation.TemperedObservation`),
* the particle filter (:class:`catgraph.localizer.Localizer`, 2,000 particles,
  :class:`catgraph.motion.VelocityMotion`) with the same model,

on the 14 conditions of :func:`catgraph.conditions.condition_table` for Nordland 32×16
summer→winter, UJI months 02–06 and the synthetic world (``benchmarks/datasets.py``),
and writes one table per condition. ``--quick`` runs the first condition of each kind.
Datasets under ``../shared/data`` are skipped where absent. Timings are reported,
never asserted.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT / "benchmarks"))
from machine_info import describe_machine  # noqa: E402


class _FixedModel:
    """Observation precomputed: returns the same log-ratio every step."""

    def __init__(self, log_ratio, new_place_log_ratio=-1.0):
        from catgraph.observation import Observation

        self._obs = Observation(log_ratio, new_place_log_ratio, True)

    def reset(self):
        pass

    def observe(self, row):
        return self._obs

    def feedback(self, feedback):
        pass


def _time_steps(loc, rows, n_warm=10):
    loc.reset()
    for r in rows[:n_warm]:
        loc.step(r)
    start = time.perf_counter()
    for r in rows[n_warm:]:
        loc.step(r)
    return (time.perf_counter() - start) / (len(rows) - n_warm)


def _median_ms(fn, repeats: int = 5) -> float:
    return 1e3 * statistics.median(fn() for _ in range(repeats))


def _memory_reference(n_values: int, repeats: int = 20) -> float:
    """Seconds of one ``np.add`` over two arrays of ``n_values`` float64 (a measure of the
    machine's memory bandwidth at this moment, taken beside each filter timing)."""
    a, b = np.random.default_rng(1).random((2, n_values))
    c = np.empty_like(a)
    t = []
    for _ in range(repeats):
        start = time.perf_counter()
        np.add(a, b, out=c)
        t.append(time.perf_counter() - start)
    return statistics.median(t)


def speed() -> str:
    from catgraph.graph import PlaceGraph
    from catgraph.grid import DEFAULT_VELOCITIES, GridLocalizer
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion

    rng = np.random.default_rng(0)
    nb = len(DEFAULT_VELOCITIES)
    lines = ["# Filter step time", "", f"`python benchmarks/bench_filter.py speed`. {describe_machine()}, "
             f"numpy {np.__version__}; medians of 5 runs (the grid filter's configurations interleaved); observation precomputed (a fixed log-ratio vector). The "
             "machine is shared, so each row also gives, measured in the same run, one `np.add` over an array of the "
             f"grid's size ({nb} × places float64) and the step as a multiple of it.", "",
             "| filter | places | step (ms) | np.add of the state (ms) | step / np.add |", "|---|---|---|---|---|"]
    n = 3576
    rows = rng.standard_normal((60, n))
    g = PlaceGraph.chain(n)
    t = _median_ms(lambda: _time_steps(Localizer(g, _FixedModel(-rows[0]), 2000, motion=VelocityMotion(), seed=0),
                                        rows))
    ref = 1e3 * _memory_reference(2000 * 4)
    lines.append(f"| particle filter, 2,000 particles, VelocityMotion | {n:,} | {t:.3f} | {ref:.3f} | {t / ref:.1f} |")
    for n in (3576, 100_000):
        rows = rng.standard_normal((30, n))
        # the default (phase bins for the fractional speeds) and, beside it in the same
        # run, one bin per speed (max_phases=1): what the phase bins cost
        configs = (("line graph (fast path)", True, 4), ("line graph, one bin per speed", True, 1),
                   ("general path (the reference)", False, 4))
        g = PlaceGraph.chain(n)

        def one(line, phases):
            loc = GridLocalizer(g, _FixedModel(-rows[0]), max_phases=phases).reset()
            loc._line = line
            loc.reset = lambda: loc  # keep the path chosen above
            return _time_steps(loc, rows)

        times: dict = {c: [] for c in configs}
        for _ in range(5):  # the configurations interleaved, so that the machine's load falls on each alike
            for c in configs:
                times[c].append(one(c[1], c[2]))
        for c in configs:
            label, _, phases = c
            t = 1e3 * statistics.median(times[c])
            ref = 1e3 * _memory_reference(nb * n)
            bins = len(GridLocalizer(g, _FixedModel(-rows[0]), max_phases=phases).reset()._owner)
            lines.append(f"| grid filter, {nb} velocities in {bins} state bins, {label} | {n:,} | {t:.3f} | "
                         f"{ref:.3f} | {t / ref:.1f} |")
            print(lines[-1], flush=True)
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- conditions
def _single_frame(d: np.ndarray, exclusion: int = 10):
    best = np.argmin(d, 1)
    n = d.shape[1]
    idx = np.arange(n)
    margin = np.empty(len(d))
    for k, row in enumerate(d):
        far = np.abs(idx - best[k]) > exclusion
        margin[k] = (row[far].min() if far.any() else row.max()) - row[best[k]]
    return best, margin


def _graph(case):
    from catgraph.graph import PlaceGraph

    if case.name.startswith("synthetic"):
        from catgraph.datasets.synthetic import make_world

        return PlaceGraph.from_traverse(case.reference, junctions=make_world(seed=0).reference_junctions())
    from catgraph.io import place_graph

    return place_graph(case.reference)  # the registry's map graph (route distances of the survey)


def _methods():
    from catgraph.grid import GridLocalizer
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion
    from catgraph.observation import TemperedObservation

    def grid(case, graph):
        res = GridLocalizer(graph, TemperedObservation()).run(
            case.differences, odometry=case.query.odometry, query_index=case.query.index)
        return res.place, res.score, res.seconds_per_frame

    def particles(case, graph, seed=0):
        res = Localizer(graph, TemperedObservation(), n_particles=2000, motion=VelocityMotion(), seed=seed).run(
            case.differences, odometry=case.query.odometry, query_index=case.query.index)
        return res.place, res.score, res.seconds_per_frame

    def single(case, graph):
        t = time.perf_counter()
        m, c = _single_frame(case.differences)
        return m, c, (time.perf_counter() - t) / len(m)

    def registry(case, graph):
        # the registry's filter method as a user gets it on these maps: the grid with its defaults
        # (the long-run jump velocity, the rigid line on maps of at most 10,000 places, outlier frames)
        from catgraph.methods import make_filter, observation_model, resolve_params

        params = resolve_params("filter", {"mode": "grid"})
        loc = make_filter(params, graph, observation_model(params, graph.n_places, None))
        odometry = case.query.odometry if params["use_odometry"] and graph.unit == "m" else None
        res = loc.run(case.differences, odometry=odometry, query_index=case.query.index)
        return res.place, res.score, res.seconds_per_frame

    return {"single frame": single, "grid filter": grid, "particle filter": particles,
            "filter method (registry defaults, grid)": registry}


def _evaluate(case, match, confidence):
    from catgraph.metrics import evaluate

    m = evaluate(case.query.index, match, confidence, case.ground_truth).metrics
    return {"auc": float(m.auc), "r100": float(m.recall_at_100p), "r99": float(m.recall_at_99p),
            "r90": float(m.recall_at_90p), "mtl": int(m.mtl)}


def _cases():
    import datasets as ds

    out = [ds.synthetic(0)]
    if ds.have_data():
        out = [ds.nordland()] + ds.uji_months() + out
    return out


def conditions(quick: bool = False) -> tuple[str, dict]:
    import datasets as ds

    table = ds.condition_table()
    if quick:
        seen, keep = set(), []
        for c in table:
            if c.kind not in seen:
                seen.add(c.kind)
                keep.append(c)
        table = keep
    methods = _methods()
    results: dict = {}
    start = time.perf_counter()
    for case in _cases():
        graph = _graph(case)
        for cond in table:
            c = ds.conditioned(case, cond)
            for name, fn in methods.items():
                match, conf, sec = fn(c, graph)
                r = _evaluate(c, match, conf)
                r["ms_per_frame"] = 1e3 * sec
                results.setdefault(cond.label, {}).setdefault(case.name, {})[name] = r
            print(f"{case.name:12s} {cond.label:28s} " + "  ".join(
                f"{k}: {v['auc']:.3f}" for k, v in results[cond.label][case.name].items())
                + f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    return _markdown(results), results


def _markdown(results: dict) -> str:
    lines = ["# Filters on every traversal condition", "",
             "`python benchmarks/bench_filter.py conditions`. Library defaults everywhere, nothing tuned per dataset "
             "or condition: grid filter = `GridLocalizer(graph, TemperedObservation())`; particle filter = "
             "`Localizer(graph, TemperedObservation(), n_particles=2000, motion=VelocityMotion(), seed=0)`; "
             "filter method (registry defaults, grid) = the `filter` method as `catgraph localize` runs it on "
             "these maps (`methods.make_filter`: the grid, the long-run jump velocity, the rigid line on maps of "
             "at most 10,000 places, the varying speed's motion and the dense velocity bins there, outlier frames at 1 %, "
             "the twin that stands still through frames that come again at prior 0.1; the goals of the filter are "
             "read on this row); "
             "single frame = best place per row, confidence = margin to the best place outside ±10 frames. "
             "Filters are ranked by their score (`LocalizationResult.score`): the posterior log-odds of the "
             "answer's neighbourhood (±2 mean spacings along the route), for the grid filter less 1 nat until it "
             "first converges (`catgraph.grid`). Graphs: the registry's map graph (`catgraph.io.place_graph`); the "
             "synthetic world's with its junctions. "
             "Tolerance: Nordland ±2 frames, UJI 3 m (same floor), synthetic world its own.", ""]
    for label, per_case in results.items():
        lines += [f"## {label}", "", "| dataset | method | AUC | R@100P | R@99P | R@90P | MTL | ms/frame |",
                  "|---|---|---|---|---|---|---|---|"]
        for case, per_method in per_case.items():
            for name, r in per_method.items():
                lines.append(f"| {case} | {name} | {r['auc']:.3f} | {r['r100']:.3f} | {r['r99']:.3f} | "
                             f"{r['r90']:.3f} | {r['mtl']} | {r['ms_per_frame']:.2f} |")
        lines.append("")
    return "\n".join(lines)


def seeds() -> str:
    import datasets as ds
    from catgraph.conditions import Condition

    methods = _methods()
    lines = ["# Particle filter: AUC over seeds 0–4", "", "| dataset | condition | AUC per seed | spread |",
             "|---|---|---|---|"]
    for case in _cases():
        graph = _graph(case)
        for cond in (Condition(), Condition("shuffle", seed=0)):
            c = ds.conditioned(case, cond)
            aucs = [_evaluate(c, *methods["particle filter"](c, graph, seed=s)[:2])["auc"] for s in range(5)]
            lines.append(f"| {case.name} | {cond.label} | {' '.join(f'{a:.3f}' for a in aucs)} | "
                         f"{max(aucs) - min(aucs):.3f} |")
            print(lines[-1], flush=True)
    return "\n".join(lines) + "\n"


def _global_threshold(pooled: list[tuple[np.ndarray, np.ndarray, np.ndarray]], precision: float) -> float:
    """The lowest threshold whose pooled precision is at least ``precision``."""
    score = np.concatenate([p[0] for p in pooled])
    correct = np.concatenate([p[1] for p in pooled])
    order = np.argsort(-score, kind="stable")
    hits = np.cumsum(correct[order])
    prec = hits / np.arange(1, len(order) + 1)
    ok = np.flatnonzero(prec >= precision)
    return float(score[order][ok[-1]]) if len(ok) else float("inf")


def threshold() -> str:
    """Paper 2's claim at the filter level: one global threshold for every traverse."""
    import datasets as ds
    from catgraph.grid import GridLocalizer
    from catgraph.metrics import evaluate
    from catgraph.observation import TemperedObservation

    from catgraph.sequence import match_sequences

    from catgraph.io import place_graph

    cases = [c for c in _cases() if not c.name.startswith("synthetic")]
    sequences = {"sequence score, fixed L=50": 50, "sequence score, fixed L=100": 100,
                 "sequence score, adaptive": "adaptive"}
    registry = _methods()["filter method (registry defaults, grid)"]
    runs: dict[str, list] = {"filter method (registry defaults, grid): its score": [],
                             "grid filter score (the filter method's ranking)": [],
                             "grid filter posterior log-odds": [], "raw difference (−d_min)": [],
                             "single-frame margin": [], **{k: [] for k in sequences}}
    names = []
    for case in cases:
        graph = place_graph(case.reference)  # the registry's map graph (route distances of the survey)
        conds = ds.condition_table() if case.name == "Nordland" else [ds.condition_table()[0]]
        for cond in conds:
            c = ds.conditioned(case, cond)
            names.append(f"{case.name} {cond.label}")
            res = GridLocalizer(graph, TemperedObservation()).run(c.differences, query_index=c.query.index)
            best, margin = _single_frame(c.differences)
            place, score, _ = registry(c, graph)
            scored = [("filter method (registry defaults, grid): its score", place, score),
                      ("grid filter score (the filter method's ranking)", res.place, res.score),
                      ("grid filter posterior log-odds", res.place, res.log_odds),
                      ("raw difference (−d_min)", best, -c.differences.min(1)),
                      ("single-frame margin", best, margin)]
            for key, window in sequences.items():  # the matcher's defaults (velocity search included)
                seq = match_sequences(c.differences, window=window)
                scored.append((key, seq.match, seq.confidence))
            for key, match, score in scored:
                ev = evaluate(c.query.index, match, score, c.ground_truth)
                runs[key].append((np.asarray(score, dtype=float), ev.correct.astype(bool), ev.has_true_match))
            print(names[-1], flush=True)
    lines = ["# One global threshold for every traverse (paper 2's claim, at the filter level)", "",
             "`python benchmarks/bench_filter.py threshold`. Traverses: UJI months 02–06 in order and Nordland in "
             f"all 14 conditions ({len(names)} traverses). For each score, the one threshold that holds the pooled "
             "precision at P is applied to every traverse; the table gives the worst and the mean per-traverse "
             "recall (recall = correct frames above the threshold / frames with a true match). The filter method is "
             "the registry's `filter` as `catgraph localize` runs it (`bench_filter.py conditions`' row of that name: "
             "the grid, the long-run jump velocity, the rigid line, the varying speed's motion and the dense velocity "
             "bins on these maps, outlier frames at 1 %, the twin that stands still through frames that come again at "
             "prior 0.1); the grid "
             "filter is "
             "`GridLocalizer(graph, TemperedObservation())`, its own defaults. Both run on the registry's map graph "
             "(`catgraph.io.place_graph`); their score is the log-odds less the unconverged penalty "
             "(`GridLocalizer`, module docstring).", "",
             "| score | P | threshold | worst recall | mean recall |", "|---|---|---|---|---|"]
    for key, pooled in runs.items():
        for precision in (1.0, 0.99, 0.9):
            t = _global_threshold(pooled, precision)
            rec = [float(((s >= t) & c).sum()) / max(int(h.sum()), 1) for s, c, h in pooled]
            lines.append(f"| {key} | {precision:.0%} | {t:.3g} | {min(rec):.3f} | {np.mean(rec):.3f} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- jumps
#: frames-since-jump bins of the accuracy curves (lower edges; the last is open)
_SINCE = (0, 1, 2, 3, 5, 10, 20, 50, 100)


def _true_jumps(index: np.ndarray) -> np.ndarray:
    """Frames that begin a new segment: more than three frames (as loaded) from the
    previous one. Ground truth of the benchmark, never shown to the method."""
    jumps = np.zeros(len(index), dtype=bool)
    jumps[1:] = np.abs(np.diff(index)) > 3
    return jumps


def _since(jumps: np.ndarray) -> np.ndarray:
    """Frames since the last jump, the traverse's start counting as one (the filter
    starts from the same uniform state it resets to)."""
    start = np.where(jumps, np.arange(len(jumps)), 0)
    return np.arange(len(jumps)) - np.maximum.accumulate(start)


def _run_grid(case, graph, oracle: np.ndarray | None = None):
    """The default grid filter; with ``oracle`` (a bool per frame), its state is reset to
    the recovery prior (uniform over places × the velocity prior) before every frame the
    oracle marks, the model's learned state kept. Benchmark only: the method never sees it."""
    from catgraph.grid import GridLocalizer
    from catgraph.observation import CheckedRow, TemperedObservation

    loc = GridLocalizer(graph, TemperedObservation()).reset()
    rows = case.differences.view(CheckedRow)
    n = len(rows)
    place, score = np.empty(n, dtype=np.int64), np.empty(n)
    for k in range(n):
        if oracle is not None and oracle[k] and k > 0:
            loc._state[...] = (loc._velocity_prior[:, None] / graph.n_places).astype(loc._state.dtype)
            loc._like = loc._ones
            loc.prior_ = loc._state.sum(0, dtype=np.float64)
            loc._mass = loc.prior_
        est = loc.step(rows[k], None if case.query.odometry is None or k == 0 else float(case.query.odometry[k]))
        place[k], score[k] = est.place, est.score
    return place, score


def jumps() -> tuple[str, dict]:
    """What limits the filter on short shuffles: finding the jump, or relocalising after it."""
    import datasets as ds
    from catgraph.conditions import Condition
    from catgraph.metrics import evaluate

    conds = [Condition("shuffle", seed=s, segment_range=(0.005, 0.03)) for s in range(5)] + \
        [Condition("shuffle", seed=s) for s in range(5)]
    results: dict = {}
    groups: dict = {}
    for case in _cases():
        group = "UJI 02-06" if case.name.startswith("UJI") else case.name.split(" ")[0]
        graph = _graph(case)
        for cond in conds:
            c = ds.conditioned(case, cond)
            truth = _true_jumps(c.query.index)
            since = _since(truth)
            for variant, oracle in (("default", None), ("oracle jumps", truth)):
                place, score = _run_grid(c, graph, oracle)
                ev = evaluate(c.query.index, place, score, c.ground_truth)
                m = ev.metrics
                key = f"{group}|{cond.label}|{variant}"
                r = results.setdefault(key, {"auc": [], "r100": [], "mtl": [], "correct": [], "since": []})
                r["auc"].append(float(m.auc))
                r["r100"].append(float(m.recall_at_100p))
                r["mtl"].append(int(m.mtl))
                r["correct"].append(ev.correct.astype(bool))
                r["since"].append(since)
            groups[group] = True
            print(f"{case.name:12s} {cond.label:28s} " + "  ".join(
                f"{v}: {results[f'{group}|{cond.label}|{v}']['auc'][-1]:.3f}" for v in ("default", "oracle jumps")),
                flush=True)
    summary: dict = {}
    for key, r in results.items():
        correct, since = np.concatenate(r["correct"]), np.concatenate(r["since"])
        curve = []
        for lo, hi in zip(_SINCE, _SINCE[1:] + (10 ** 9,)):
            sel = (since >= lo) & (since < hi)
            curve.append(float(correct[sel].mean()) if sel.any() else None)
        summary[key] = {"auc": float(np.mean(r["auc"])), "r100": float(np.mean(r["r100"])),
                        "mtl": float(np.mean(r["mtl"])), "accuracy_since_jump": curve,
                        "frames_since_jump_bins": list(_SINCE)}
    return _jumps_markdown(summary), summary


def _jumps_markdown(summary: dict) -> str:
    lines = ["# Short shuffles: finding the jump, or relocalising after it", "",
             "`python benchmarks/bench_filter.py jumps`. The default grid filter "
             "(`GridLocalizer(graph, TemperedObservation())`, the registry's map graph) against an *oracle-jump* "
             "variant of it that is told, by the benchmark, the frames where the shuffled query jumps (a frame more "
             "than 3 frames, as loaded, from its predecessor) and resets its state there to its recovery prior "
             "(uniform over places × the velocity prior; the observation model's learned state kept). The oracle "
             "removes jump *detection*; what it still loses is relocalisation: the evidence a few frames give. "
             "UJI: means over months 02–06.", "",
             "## AUC / R@100P / MTL", "", "| dataset | condition | default | oracle jumps |", "|---|---|---|---|"]
    keys = sorted({k.rsplit("|", 1)[0] for k in summary}, key=lambda k: list(summary).index(k + "|default"))
    for k in keys:
        a, b = summary[k + "|default"], summary[k + "|oracle jumps"]
        group, label = k.split("|")
        lines.append(f"| {group} | {label} | {a['auc']:.3f} / {a['r100']:.2f} / {a['mtl']:.0f} | "
                     f"{b['auc']:.3f} / {b['r100']:.2f} / {b['mtl']:.0f} |")
    bins = [f"{lo}–{hi - 1}" if hi - lo > 1 else f"{lo}" for lo, hi in zip(_SINCE, _SINCE[1:])] + [f"≥{_SINCE[-1]}"]
    lines += ["", "## Accuracy (share of frames whose answer is right) against frames since the last jump", "",
              "Pooled over the five seeds of each segment range (UJI: and months). Frame 0 of a segment is the jump "
              "itself.", "", "| dataset | shuffle | variant | " + " | ".join(bins) + " |",
              "|---|---|---|" + "---|" * len(bins)]
    pooled: dict = {}
    for key, r in summary.items():
        group, label, variant = key.split("|")
        rng = label.split(" (")[0]
        pooled.setdefault((group, rng, variant), []).append(r["accuracy_since_jump"])
    for (group, rng, variant), curves in pooled.items():
        arr = np.array([[np.nan if v is None else v for v in c] for c in curves], dtype=float)
        with np.errstate(all="ignore"):
            mean = np.array([np.nanmean(col) if np.isfinite(col).any() else np.nan for col in arr.T])
        lines.append(f"| {group} | {rng} | {variant} | " + " | ".join("–" if np.isnan(v) else f"{v:.2f}" for v in mean)
                     + " |")
    return "\n".join(lines) + "\n"


def _stamped(text: str) -> str:
    """``text`` with the commit it was measured at under its title (``+ changes`` where
    the working tree differs from it in the package or the benchmarks)."""
    import subprocess

    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "catgraph", "benchmarks/bench_filter.py",
                                "benchmarks/datasets.py"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return text
    title, _, rest = text.partition("\n")
    return f"{title}\n\nMeasured at commit `{head}`{' + changes' if dirty else ''}.\n{rest}"


def main(argv: list[str]) -> None:
    what = argv[0] if argv else "speed"
    RESULTS.mkdir(parents=True, exist_ok=True)
    if what == "speed":
        (RESULTS / "filter_speed.md").write_text(_stamped(speed()))
    elif what == "conditions":
        text, results = conditions(quick="--quick" in argv)
        (RESULTS / "filter_compare.md").write_text(_stamped(text))
        (RESULTS / "filter_compare.json").write_text(json.dumps(results, indent=1))
    elif what == "threshold":
        (RESULTS / "filter_threshold.md").write_text(_stamped(threshold()))
    elif what == "seeds":
        (RESULTS / "filter_seeds.md").write_text(seeds())
    elif what == "jumps":
        text, results = jumps()
        (RESULTS / "filter_jumps.md").write_text(_stamped(text))
        (RESULTS / "filter_jumps.json").write_text(json.dumps(results, indent=1))
    else:
        raise SystemExit(f"unknown benchmark {what!r}; use speed, conditions, threshold, seeds or jumps.")


if __name__ == "__main__":
    main(sys.argv[1:])
