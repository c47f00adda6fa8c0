"""Benchmark: sequence matching under every traversal condition (fixed vs adaptive window).

Datasets (``benchmarks/datasets.py``): Nordland 32×16 summer → winter (±2 frames) and the
UJI library Wi-Fi, month 01 ``trn01`` against months 02–06 ``tst01`` (3 m, same floor;
figures are means over the five months, MTL also as the worst month); the synthetic
world (seed 0, its own tolerance; not in ``--quick``). Conditions
(``catgraph.conditions.condition_table``): in order; shuffled in segments of 2–20 % and of
0.5–3 % (seeds 0–4 each: mean and worst seed); reversed; speed 2; speed 0.5.

Every method sees the same difference rows: the project's front-end, normalised per
query, with the map's hub offsets (``catgraph.hubs``, computed from the reference alone)
applied. Methods:

* single frame (window 1);
* every fixed window L ∈ {5, 10, 20, 50, 100, 200, 500}, with the default velocity search;
* the classic SeqSLAM fixed windows (the same lengths, forward diagonal v = 1 only, the
  same hub-corrected rows), so that "the best fixed window" is the better of the two;
* the default adaptive matcher (``match_sequences`` defaults: rule "tracked", the window
  chosen by a grid filter's place posterior, with its confidence "tracked");
* the same matches ranked by confidence "support" (the default before "posterior");
* the adaptive matcher with rule "evident" (the default before the rival test);
* the adaptive matcher with rule "consistent" and every shorter sub-window tested (the
  0.2 draft default, for comparison);
* the adaptive matcher with rule "predictive" (each window length judged by how well its
  line has been predicting later frames; ``catgraph.sequence``), compared per condition
  with the default and the best fixed window in a table of its own;
* the adaptive matcher with rule "decorrelated" (the same record, scored at the query's own
  decorrelation time instead of a constant horizon), in a table of its own too;
* the adaptive matcher with rule "spanning" and confidence "posterior" (the default until the
  confidence "changepoint": the tests of rule "unrivalled", with the velocity re-chosen at the
  chosen window and a rival test that only lines spanning the query's decorrelation time may
  make), in a table of its own against rule "unrivalled";
* the adaptive matcher with rule "spanning" and confidence "changepoint" (the default until rule
  "punctuated": the spread test read on every shorter sub-window);
* the adaptive matcher with rule "unrivalled" (the default before "spanning"), the reference
  of the rule tables (the rule rows, "support" apart, with confidence "posterior");
* the adaptive matcher with rule "challenged" and confidence "changepoint" (the default
  before "tracked"), with a goal table of its own;
* for reference, the previous default (rule "sustained", forward diagonal only, L in
  [10, 500] on 32 lengths, sub-windows from L/8, no hub offsets).

The goal checked per condition: adaptive AUC ≥ the best fixed window's AUC − 0.01 and
adaptive MTL ≤ the best fixed window's MTL (best fixed chosen per condition, with
hindsight, over both the velocity-search and the classic fixed windows; for shuffles,
per seed).

Writes ``benchmarks/results/sequence.md`` and ``sequence.json`` and the figure
``docs/figures/sequence_conditions.png`` (``--quick`` prints its table and writes nothing). Run from the repository root::

    python benchmarks/bench_sequence.py [--quick] [--no-timing] [--only METHOD ...]

``--only`` re-measures the named methods and keeps every other row from the committed
``sequence.json`` (rows it lacks are measured): after a change to the default, only the
adaptive rows need measuring again.

``--quick`` (a smoke run, under two minutes): seed 0 only, fixed windows {10, 50, 200},
Nordland's first 600 query frames, no synthetic world, no rule-"consistent" or
previous-default reference, no timing.

``--ranking`` (an analysis of the confidence, prints a table and writes nothing): the
default adaptive matcher once per dataset and condition, its matches ranked (a) by
confidence "support" (the default until "posterior"), (b) by an oracle that puts every correct match first (the best AUC and
R@100P any confidence can give at these matches; its AUC equals the accuracy), (c) by
"support" with the first 5 or 10 frames after every jump of the query set to zero
(a jump detector that knows the ground truth: how much the frames right after a jump
cost), and (d) by the online candidate ``support_sum x P(on line)``: the current frame's
likelihood ratio between "on the chosen line" (a normal of unit spread around the
line's mean standardised difference ``mu``, the window score of the match) and "a random
place" (a standard normal), ``P = sigmoid((z^2 - (z - mu)^2) / 2 - ln w)`` for prior odds
``w`` of a jump (``w = 0.3`` is confidence "posterior", the default before "changepoint"). (b) and (c) read the
ground truth and are no method; they bound what a confidence can gain.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from machine_info import describe_machine  # noqa: E402

from benchmarks.datasets import DATA, conditioned, nordland, synthetic, uji_months  # noqa: E402
from catgraph.conditions import condition_table  # noqa: E402
from catgraph.hubs import hub_offsets  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402
from catgraph.pipeline import differences  # noqa: E402
from catgraph.sequence import DEFAULT_VELOCITIES, match_sequences  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
FIGURES = ROOT / "docs" / "figures"
FIXED = (5, 10, 20, 50, 100, 200, 500)
QUICK_FIXED = (10, 50, 200)
ADAPTIVE = "adaptive (default)"
SUPPORT = "adaptive, confidence support"
CONSISTENT = "adaptive, rule consistent"
EVIDENT = "adaptive, rule evident"
PREDICTIVE = "adaptive, rule predictive"
DECORRELATED = "adaptive, rule decorrelated"
SPANNING = "adaptive, rule spanning"
SPANNING_CP = "adaptive, rule spanning, confidence changepoint"
PUNCTUATED = "adaptive, rule punctuated"
GATED = "adaptive, rule gated"
CONTESTED = "adaptive, rule contested"
PERSISTENT = "adaptive, rule persistent"
UNRIVALLED = "adaptive, rule unrivalled"
CHALLENGED = "adaptive, rule challenged"
PREVIOUS = "previous default"
SINGLE = "single frame"
PREVIOUS_KWARGS = dict(rule="sustained", velocities=(1.0,), l_min=10, l_max=500, grid=32, recent_fraction=0.125,
                       confidence="gap")
# the rule rows keep the confidence they were measured with ("posterior", the default until
# "changepoint"), so that a change of the default confidence re-measures the default row only
CONSISTENT_KWARGS = dict(rule="consistent", recent_fraction=0.0, confidence="posterior")
EVIDENT_KWARGS = dict(rule="evident", confidence="posterior")
PREDICTIVE_KWARGS = dict(rule="predictive", confidence="posterior")
DECORRELATED_KWARGS = dict(rule="decorrelated", confidence="posterior")
SPANNING_KWARGS = dict(rule="spanning", confidence="posterior")
# the default before rule "punctuated" (rule "spanning", confidence "changepoint")
SPANNING_CP_KWARGS = dict(rule="spanning", confidence="changepoint")
# the default before rule "gated"
PUNCTUATED_KWARGS = dict(rule="punctuated", confidence="changepoint")
# the default before rule "contested"
GATED_KWARGS = dict(rule="gated", confidence="changepoint")
# the default before rule "persistent"
CONTESTED_KWARGS = dict(rule="contested", confidence="changepoint")
# the default before rule "challenged"
PERSISTENT_KWARGS = dict(rule="persistent", confidence="changepoint")
UNRIVALLED_KWARGS = dict(rule="unrivalled", confidence="posterior")
# the default before rule "tracked"
CHALLENGED_KWARGS = dict(rule="challenged", confidence="changepoint")
GROUPS = ("in order", "shuffled 2–20 %", "shuffled 0.5–3 %", "reversed", "speed 2", "speed 0.5")


def _group(condition) -> str:
    if condition.kind == "shuffle":
        return "shuffled 2–20 %" if condition.segment_range[1] > 0.1 else "shuffled 0.5–3 %"
    return condition.label


def _methods(quick: bool):
    yield SINGLE, dict(window=1, velocities=(1.0,)), True
    for length in QUICK_FIXED if quick else FIXED:
        yield f"fixed L={length}", dict(window=length), True
    for length in QUICK_FIXED if quick else FIXED:
        yield f"SeqSLAM L={length}", dict(window=length, velocities=(1.0,)), True
    yield ADAPTIVE, {}, True
    yield UNRIVALLED, UNRIVALLED_KWARGS, True
    yield PREDICTIVE, PREDICTIVE_KWARGS, True
    yield DECORRELATED, DECORRELATED_KWARGS, True
    yield SPANNING, SPANNING_KWARGS, True
    yield SPANNING_CP, SPANNING_CP_KWARGS, True
    yield PUNCTUATED, PUNCTUATED_KWARGS, True
    yield GATED, GATED_KWARGS, True
    yield CONTESTED, CONTESTED_KWARGS, True
    yield PERSISTENT, PERSISTENT_KWARGS, True
    yield CHALLENGED, CHALLENGED_KWARGS, True
    if not quick:
        yield SUPPORT, dict(confidence="support"), True
        yield EVIDENT, EVIDENT_KWARGS, True
        yield CONSISTENT, CONSISTENT_KWARGS, True
        yield PREVIOUS, PREVIOUS_KWARGS, False  # no hub offsets


def _cases(quick: bool):
    """[(dataset name, [case, ...], hub offsets)]; several cases = averaged (UJI months)."""
    nord = nordland()
    if quick:
        keep = np.arange(600)
        nord = replace(nord, query=nord.query.take(keep), differences=nord.differences[keep])
    out = [("Nordland", [nord], hub_offsets(differences(nord.reference, nord.reference)))]
    months = uji_months()
    out.append(("UJI Wi-Fi (months 02–06)", months, hub_offsets(differences(months[0].reference, months[0].reference))))
    if not quick:
        world = synthetic(0)
        out.append(("synthetic (seed 0)", [world], hub_offsets(differences(world.reference, world.reference))))
    return out


def _run(cases, condition, kwargs, offsets):
    per = []
    seconds = 0.0
    for case in cases:
        c = conditioned(case, condition)
        start = time.perf_counter()
        res = match_sequences(c.differences, hub_offsets=offsets, **kwargs)
        seconds += time.perf_counter() - start
        m = evaluate(c.query.index, res.match, res.confidence, c.ground_truth).metrics
        per.append({"auc": m.auc, "recall_at_100p": m.recall_at_100p, "mtl": m.mtl, "accuracy": m.accuracy,
                    "median_window": float(np.median(res.window_length)),
                    "velocity_share": {f"{v:g}": float(np.mean(res.velocity == v)) for v in np.unique(res.velocity)}})
    keys = ("auc", "recall_at_100p", "mtl", "accuracy", "median_window")
    out = {k: float(np.mean([p[k] for p in per])) for k in keys}
    out["mtl_max"] = int(max(p["mtl"] for p in per))
    out["seconds"] = seconds
    out["per_case"] = per
    return out


def measure(quick: bool, only=None, kept: dict | None = None) -> dict:
    """The table; with ``only``, the other methods' rows are taken from ``kept`` (the
    committed results) where it has them, and measured where it does not."""
    conditions = condition_table(seeds=[0] if quick else range(5))
    table = {}
    for name, cases, offsets in _cases(quick):
        table[name] = {"hub_frames": int(np.count_nonzero(offsets)), "conditions": []}
        old_rows = {r["label"]: r["methods"] for r in (kept or {}).get(name, {}).get("conditions", [])}
        for condition in conditions:
            row = {"condition": condition.as_dict(), "label": condition.label, "group": _group(condition),
                   "methods": {}}
            old = old_rows.get(condition.label, {})
            for method, kwargs, with_hubs in _methods(quick):
                if only is not None and method not in only and method in old:
                    row["methods"][method] = old[method]
                    continue
                row["methods"][method] = _run(cases, condition, kwargs, offsets if with_hubs else None)
            table[name]["conditions"].append(row)
            r = row["methods"][ADAPTIVE]
            print(f"{name} | {condition.label}: adaptive AUC {r['auc']:.3f} MTL {r['mtl']:.0f} ({r['seconds']:.1f} s)",
                  flush=True)
    return table


def _check(row, method: str = ADAPTIVE) -> dict:
    fixed = {m: r for m, r in row["methods"].items() if m.startswith(("fixed", "SeqSLAM"))}
    best_auc_method = max(fixed, key=lambda m: fixed[m]["auc"])
    best_auc = fixed[best_auc_method]["auc"]
    best_mtl = min(r["mtl"] for r in fixed.values())
    a = row["methods"][method]
    return {"best_fixed": best_auc_method, "best_auc": best_auc, "best_mtl": best_mtl,
            "auc_margin": a["auc"] - best_auc, "mtl_margin": a["mtl"] - best_mtl,
            "auc_ok": a["auc"] >= best_auc - 0.01, "mtl_ok": a["mtl"] <= best_mtl}


def _matcher_memory(d: np.ndarray) -> dict:
    """The streaming matcher's buffers on these rows, read from a matcher that took one row."""
    from catgraph.sequence import SequenceMatcher

    m = SequenceMatcher()
    m.step(d[0])
    return {"ring_MiB": (m._ring.nbytes + m._mring.nbytes) / 2**20, "ring_dtype": str(m._ring.dtype),
            "sums_MiB": m._sums.nbytes / 2**20, "sums_dtype": str(m._sums.dtype), "lengths": int(m._sums.shape[1])}


def timing(repeats: int = 3) -> dict:
    """Whole Nordland: difference matrix + default adaptive matcher (hub offsets apart)."""
    from catgraph.datasets import load_traverse

    ref = load_traverse(DATA / "nordland" / "32x16" / "summer")
    query = load_traverse(DATA / "nordland" / "32x16" / "winter")
    start = time.perf_counter()
    offsets = hub_offsets(differences(ref, ref))
    hub_s = time.perf_counter() - start
    match_sequences(np.random.default_rng(0).normal(size=(20, 50)))  # compile / load the kernels
    diff_s, match_s, cpu_s = [], [], []
    for _ in range(repeats):
        start = time.perf_counter()
        d = differences(ref, query)
        mid = time.perf_counter()
        cpu = time.process_time()
        match_sequences(d, hub_offsets=offsets)
        cpu_s.append(time.process_time() - cpu)
        diff_s.append(mid - start)
        match_s.append(time.perf_counter() - mid)
    one_s = []
    for _ in range(repeats):  # the same matcher with the forward diagonal only: what the velocity search costs
        start = time.perf_counter()
        match_sequences(d, hub_offsets=offsets, velocities=(1.0,))
        one_s.append(time.perf_counter() - start)
    n = d.shape[1]
    import numba

    return {"difference_s": float(np.median(diff_s)), "adaptive_s": float(np.median(match_s)),
            "total_s": float(np.median(np.add(diff_s, match_s))), "hub_offsets_s": hub_s, "repeats": repeats,
            "adaptive_cpu_s": float(np.median(cpu_s)), "adaptive_one_velocity_s": float(np.median(one_s)),
            "threads": numba.get_num_threads(), "velocities": len(DEFAULT_VELOCITIES),
            **_matcher_memory(d),
            "load_average": os.getloadavg()[0],
            "machine": describe_machine()}


def _fmt(r, wifi):
    mtl = f"{r['mtl']:.1f} ({r['mtl_max']})" if wifi else f"{r['mtl']:.0f}"
    return f"{r['auc']:.3f} / {r['recall_at_100p']:.2f} / {mtl}"


def markdown(table: dict, timing_: dict | None, quick: bool) -> str:
    lines = ["# Sequence matching under every traversal condition", "",
             "Generated by `benchmarks/bench_sequence.py`" + (" `--quick` (seed 0, Nordland's first 600 query frames)"
                                                               if quick else "") + ". "
             "Cells: AUC / R@100P / MTL (UJI: mean over months 02–06, worst month's MTL in brackets). Every method "
             "uses the same rows (per-query normalised, the map's hub offsets applied) except the previous default. "
             "\"fixed\" windows use the default velocity search, \"SeqSLAM\" windows the forward diagonal only; "
             "the best fixed window of the goal check is the best of both. Shuffled rows: mean over the seeds, and the worst "
             "seed's AUC.", ""]
    for name, data in table.items():
        wifi = "UJI" in name
        rows = data["conditions"]
        methods = list(rows[0]["methods"])
        lines += [f"## {name}", "", f"Hub frames corrected in the map: {data['hub_frames']}.", ""]
        lines += ["| method | " + " | ".join(GROUPS) + " |", "|---" * (len(GROUPS) + 1) + "|"]
        for method in methods:
            cells = []
            for group in GROUPS:
                rs = [r["methods"][method] for r in rows if r["group"] == group]
                if not rs:
                    cells.append("–")
                    continue
                mean = {k: float(np.mean([r[k] for r in rs])) for k in ("auc", "recall_at_100p", "mtl")}
                mean["mtl_max"] = max(r["mtl_max"] for r in rs)
                cell = _fmt(mean, wifi)
                if len(rs) > 1:
                    cell += f" (worst AUC {min(r['auc'] for r in rs):.3f})"
                cells.append(cell)
            lines.append(f"| {method} | " + " | ".join(cells) + " |")
        lines += _goal_lines(rows, ADAPTIVE, "Goal per condition (adaptive AUC ≥ best fixed − 0.01; adaptive MTL ≤ "
                             "best fixed MTL):")
        if CHALLENGED in rows[0]["methods"]:
            lines += _goal_lines(rows, CHALLENGED, "The same goal for rule \"challenged\" (the default before "
                                 "\"tracked\"):")
        for method, rule in ((PREDICTIVE, "predictive"), (DECORRELATED, "decorrelated"), (SPANNING, "spanning")):
            if method in rows[0]["methods"]:
                lines += _predictive_lines(rows, wifi, method, rule)
    if timing_:
        t = timing_
        lines += ["## Timing", "",
                  f"{t['machine']}; numba threads {t['threads']}; load average at the start {t['load_average']:.1f} "
                  f"(the machine is shared); medians of {t['repeats']} runs.", "",
                  "| what | time |", "|---|---|",
                  f"| Nordland 3,576 × 3,576 difference matrix | {t['difference_s']:.2f} s |",
                  f"| Nordland adaptive matcher, {t['velocities']} velocities, 13 window lengths | "
                  f"{t['adaptive_s']:.2f} s (CPU time, all threads: {t['adaptive_cpu_s']:.1f} s) |",
                  f"| **Nordland total (difference matrix + adaptive)** | **{t['total_s']:.2f} s** |",
                  f"| the same adaptive matcher, forward diagonal only (v = 1) | {t['adaptive_one_velocity_s']:.2f} s |",
                  f"| each further velocity (difference of the two, / {t['velocities'] - 1}) | "
                  f"{(t['adaptive_s'] - t['adaptive_one_velocity_s']) / (t['velocities'] - 1):.2f} s |",
                  f"| hub offsets from the map (once per map) | {t['hub_offsets_s']:.2f} s |",
                  f"| the matcher's ring of the last l_max + 1 rows, shared by every velocity "
                  f"({t['ring_dtype']}) | {t['ring_MiB']:.1f} MiB |",
                  f"| its running sums ({t['velocities']} velocities × {t['lengths']} lengths, {t['sums_dtype']}) "
                  f"| {t['sums_MiB']:.1f} MiB |",
                  ""]
    return "\n".join(lines)


def _goal_lines(rows, method: str, title: str) -> list[str]:
    """The goal per condition for one adaptive row, and the conditions that meet it."""
    lines = ["", title, "",
             "| condition | best fixed (AUC) | adaptive AUC | AUC margin | best fixed MTL | adaptive MTL | goal |",
             "|---|---|---|---|---|---|---|"]
    met = 0
    for row in rows:
        c = _check(row, method)
        a = row["methods"][method]
        met += c["auc_ok"] and c["mtl_ok"]
        ok = "✓" if c["auc_ok"] and c["mtl_ok"] else ("AUC ✗" if not c["auc_ok"] else "") + (
            " MTL ✗" if not c["mtl_ok"] else "")
        lines.append(f"| {row['label']} | {c['best_fixed']} ({c['best_auc']:.3f}) | {a['auc']:.3f} | "
                     f"{c['auc_margin']:+.3f} | {c['best_mtl']:.1f} | {a['mtl']:.1f} | {ok.strip()} |")
    auc_met = sum(_check(row, method)["auc_ok"] for row in rows)
    return lines + ["", f"Met in {met} of {len(rows)} conditions (AUC alone: {auc_met}).", ""]


def _predictive_lines(rows, wifi: bool, method: str = PREDICTIVE, rule: str = "predictive") -> list[str]:
    """A rule (row ``method``) against the default rule and the best fixed window, per
    condition, and a summary of the AUC margins to the best fixed window over every condition."""
    lines = [f"Rule \"{rule}\" against rule \"unrivalled\" (the default before \"spanning\") and the best fixed window (AUC / R@100P / "
             "MTL; goal as above):", "",
             f"| condition | best fixed (AUC, MTL) | unrivalled | {rule} | {rule} margin | goal |",
             "|---|---|---|---|---|---|"]
    margins = {UNRIVALLED: [], method: []}
    for row in rows:
        c = _check(row, method)
        for method in margins:
            margins[method].append(_check(row, method)["auc_margin"])
        ok = "✓" if c["auc_ok"] and c["mtl_ok"] else ("AUC ✗" if not c["auc_ok"] else "") + (
            " MTL ✗" if not c["mtl_ok"] else "")
        lines.append(f"| {row['label']} | {c['best_fixed']} ({c['best_auc']:.3f}, {c['best_mtl']:.1f}) | "
                     f"{_fmt(row['methods'][UNRIVALLED], wifi)} | {_fmt(row['methods'][method], wifi)} | "
                     f"{c['auc_margin']:+.3f} | {ok.strip()} |")
    lines += ["", "| rule | mean AUC margin to the best fixed window | worst | conditions within 0.01 |", "|---|---|---|---|"]
    for key, name in ((UNRIVALLED, "unrivalled"), (method, rule)):
        m = np.array(margins[key])
        lines.append(f"| {name} | {m.mean():+.3f} | {m.min():+.3f} | {int(np.sum(m >= -0.01))} / {m.size} |")
    return lines + [""]


RANKING_ODDS = (0.3, 3.0)


def _since_jump(query_index: np.ndarray) -> np.ndarray:
    """Frames since the query last jumped (processing order; a step of more than 2 frames)."""
    jump = np.r_[True, np.abs(np.diff(query_index)) > 2]
    start = np.maximum.accumulate(np.where(jump, np.arange(query_index.size), 0))
    return np.arange(query_index.size) - start


def _ranked(c, match, confidence) -> tuple[float, float]:
    m = evaluate(c.query.index, match, confidence, c.ground_truth).metrics
    return m.auc, m.recall_at_100p


def ranking() -> dict:
    """Per dataset and condition (means over the UJI months): AUC and R@100P of the default
    adaptive matches under each ranking of the module docstring's ``--ranking``."""
    from scipy.special import expit, ndtr

    from catgraph.hubs import apply_hub_offsets

    conditions = condition_table(seeds=range(5))
    out = {}
    for name, cases, offsets in _cases(False):
        rows_out = []
        for condition in conditions:
            per = []
            for case in cases:
                c = conditioned(case, condition)
                res = match_sequences(c.differences, hub_offsets=offsets, confidence="support")
                d = np.asarray(apply_hub_offsets(c.differences, offsets))
                t = np.arange(d.shape[0])
                mean, std = d.mean(axis=1), d.std(axis=1)
                z = np.where(std > 0, (d[t, res.match] - mean) / np.where(std > 0, std, 1.0), 0.0)
                mu = np.where(std > 0, (res.score - mean) / np.where(std > 0, std, 1.0), 0.0)
                ev = evaluate(c.query.index, res.match, res.confidence, c.ground_truth)
                since = _since_jump(np.asarray(c.query.index))
                support_sum = res.confidence / ndtr(-z)
                cell = {"accuracy": ev.metrics.accuracy,
                        "support": (ev.metrics.auc, ev.metrics.recall_at_100p),
                        "oracle": _ranked(c, res.match, ev.correct + 1e-6 * res.confidence / (1.0 + res.confidence.max())),
                        "masked 5": _ranked(c, res.match, np.where(since < 5, 0.0, res.confidence)),
                        "masked 10": _ranked(c, res.match, np.where(since < 10, 0.0, res.confidence))}
                for w in RANKING_ODDS:
                    on_line = expit((z ** 2 - (z - mu) ** 2) / 2.0 - np.log(w))
                    cell[f"candidate w={w:g}"] = _ranked(c, res.match, support_sum * on_line)
                per.append(cell)
            row = {"label": condition.label, "group": _group(condition),
                   "accuracy": float(np.mean([p["accuracy"] for p in per]))}
            for key in per[0]:
                if key != "accuracy":
                    row[key] = tuple(float(np.mean([p[key][k] for p in per])) for k in range(2))
            rows_out.append(row)
            print(f"{name} | {condition.label}: support {row['support'][0]:.3f} oracle {row['oracle'][0]:.3f}",
                  flush=True)
        out[name] = rows_out
    return out


def ranking_markdown(result: dict) -> str:
    keys = ["support", "oracle", "masked 5", "masked 10"] + [f"candidate w={w:g}" for w in RANKING_ODDS]
    lines = []
    for name, rows in result.items():
        lines += [f"**{name}** (AUC / R@100P; shuffles: mean over seeds, worst AUC in brackets)", "",
                  "| condition | accuracy | " + " | ".join(keys) + " |", "|---" * (len(keys) + 2) + "|"]
        for group in GROUPS:
            rs = [r for r in rows if r["group"] == group]
            cells = [f"{np.mean([r['accuracy'] for r in rs]):.3f}"]
            for key in keys:
                auc = [r[key][0] for r in rs]
                cell = f"{np.mean(auc):.3f}" + (f" ({min(auc):.3f})" if len(rs) > 1 else "")
                cells.append(cell + f" / {np.mean([r[key][1] for r in rs]):.2f}")
            lines.append(f"| {group} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def figure(table: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(table), figsize=(7 * len(table), 4.2), squeeze=False)
    for ax, (name, data) in zip(axes[0], table.items()):
        rows = data["conditions"]
        methods = list(rows[0]["methods"])
        x = np.arange(len(GROUPS))
        for method in methods:
            ys = [np.mean([r["methods"][method]["auc"] for r in rows if r["group"] == g]) for g in GROUPS]
            style = dict(lw=2.5, color="tab:green", marker="o") if method == ADAPTIVE else \
                dict(lw=1.5, color="tab:purple", ls="-.", marker="^") if method == CONSISTENT else \
                dict(lw=1.5, color="tab:orange", ls="--", marker="s") if method == PREVIOUS else \
                dict(lw=1.0, color="0.3", ls=":", marker="x") if method == SINGLE else \
                dict(lw=0.7, ls="--", marker=".", alpha=0.6) if method.startswith("SeqSLAM") else dict(lw=0.9, marker=".")
            ax.plot(x, ys, label=method, **style)
        ax.set_xticks(x, GROUPS, rotation=20, fontsize=8)
        ax.set_ylim(0, 1.02)
        ax.set_ylabel("AUC (mean over seeds / months)")
        ax.set_title(name)
    handles, labels = axes[0][0].get_legend_handles_labels()  # beside the panels: it would cover one of them
    fig.legend(handles, labels, fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5), ncol=2 if len(labels) > 16 else 1)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="seed 0, three fixed windows, 600 Nordland frames")
    parser.add_argument("--no-timing", action="store_true")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", nargs="+", metavar="METHOD",
                        help="re-measure only these methods (e.g. 'adaptive (default)'); the other rows are kept "
                             "from the committed sequence.json where it has them")
    parser.add_argument("--ranking", action="store_true",
                        help="analyse the default's confidence (oracle, jump-masked, candidates); prints, writes nothing")
    args = parser.parse_args()
    if not DATA.exists():
        raise SystemExit(f"no data at {DATA}; this benchmark needs ../shared/data (see its README)")
    if args.ranking:
        print(ranking_markdown(ranking()))
        return
    start = time.perf_counter()
    kept, kept_timing = {}, None
    if args.only and (RESULTS / "sequence.json").exists():
        committed = json.loads((RESULTS / "sequence.json").read_text())
        kept, kept_timing = committed["table"], committed.get("timing")
    table = measure(args.quick, args.only, kept)
    timing_ = None if (args.quick or args.no_timing) else timing(args.repeats)
    timing_ = timing_ or (None if args.quick else kept_timing)
    if args.quick:  # a smoke run: print, keep the committed results
        print(markdown(table, timing_, args.quick))
    else:
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "sequence.json").write_text(json.dumps({"table": table, "timing": timing_}, indent=1))
        (RESULTS / "sequence.md").write_text(markdown(table, timing_, args.quick))
        figure(table, FIGURES / "sequence_conditions.png")
    print(f"done in {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
