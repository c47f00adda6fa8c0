"""The decorrelation horizon of the default window rule "spanning": its cost per streaming
step, and the same horizons as the partition of the whole standardised row on real rows.

Every frame, rule "spanning" reads the query's difference row into a
:class:`catgraph._window_rule._Horizon`, which finds the row's ten best places and
compares the standardised values at the best places of the last ``HORIZON_MAX`` frames.
The clock finds the best places with one compiled pass over the raw row; the reference
(:class:`PartitionHorizon`, the clock as first written) standardises the whole row and
partitions it with ``np.argpartition``.

``timing``    per ``N``, in one process, frame by frame in turn: the reference clock's
              ``update`` and the clock's own on the same rows; and three streaming
              matchers (adaptive, ``l_max`` 500, 8 velocities; the ring filled with the
              store kernel as in ``bench_matcher.py``): rule "unrivalled" (no horizon),
              rule "spanning" with the reference clock, and rule "spanning" as it is.
              Medians of ``--frames`` steps each; the machine's load average beside.
``identity``  Nordland (summer -> winter), UJI months 02-06 (against 01) and the synthetic
              world (seed 0), under each of the 14 conditions of
              :func:`catgraph.conditions.condition_table`, each query's rows as they are
              and hub-corrected (with the map's own hub offsets): both clocks read the
              same rows; every frame's horizon and set of best places are compared, and the
              largest relative difference of the clocks' averaged ratios is reported.

Writes ``benchmarks/results/matcher_horizon.md`` and ``matcher_horizon.json``::

    python benchmarks/bench_horizon.py [--sizes 10000 100000 1000000] [--frames 40] [--skip timing,identity]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
L_MAX = 500

from catgraph._window_rule import _Horizon  # noqa: E402

sys.path.insert(0, str(ROOT))
from machine_info import describe_machine  # noqa: E402

#: the reference clock (the clock as first written), kept beside its test
from tests.test_live_horizon import _PartitionHorizon as PartitionHorizon  # noqa: E402


def _commit() -> str:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "catgraph"], cwd=ROOT, capture_output=True,
                               text=True).stdout
        return rev.strip() + (" (+ uncommitted changes in catgraph/)" if dirty.strip() else "")
    except OSError:
        return "unknown"


def _filled_matcher(rule: str, rows: np.ndarray, clock=None):
    from catgraph import _sequence_kernels as k
    from catgraph.sequence import SequenceMatcher

    m = SequenceMatcher(l_max=L_MAX, rule=rule)
    m.step(rows[0])
    if clock is not None:
        m._record.clock = clock
        clock.update(rows[0], 0, rows[0].std())
    for i in range(1, L_MAX + 1):
        k.advance(m._ring, m._mring, m._state, i, rows[i % len(rows)])
    m.n_steps_ = L_MAX + 1
    return m


def timing(n: int, frames: int) -> dict:
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(4, n))
    # the clocks alone, warmed past their capacity
    ref, new = PartitionHorizon(), _Horizon()
    for i in range(60):
        r = rows[i % 4]
        ref.update(r, i, r.std())
        new.update(r, i, r.std())
    clock_ms = {"partition": [], "selection": [], "row std": []}
    for t in range(frames):
        r = rows[t % 4]
        spread = r.std()
        for name, c in (("partition", ref), ("selection", new)):
            t0 = time.perf_counter()
            c.update(r, 60 + t, spread)
            clock_ms[name].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        r.std()
        clock_ms["row std"].append(time.perf_counter() - t0)
    tiny = rng.normal(size=(3, 64))
    for rule in ("unrivalled", "spanning"):  # compile or load the kernels first
        _filled_matcher(rule, tiny).step(tiny[0])
    matchers = {"unrivalled": _filled_matcher("unrivalled", rows),
                "spanning, partition clock": _filled_matcher("spanning", rows, PartitionHorizon()),
                "spanning": _filled_matcher("spanning", rows)}
    step_ms = {name: [] for name in matchers}
    for t in range(frames):
        for name, m in matchers.items():
            t0 = time.perf_counter()
            m.step(rows[t % 4])
            step_ms[name].append(time.perf_counter() - t0)
    med = {k: 1e3 * float(np.median(v)) for k, v in {**clock_ms, **step_ms}.items()}
    p90 = {k: 1e3 * float(np.percentile(v, 90)) for k, v in step_ms.items()}
    return {"n": n, "frames": frames, "median_ms": med, "p90_ms": p90, "load": os.getloadavg()}


def _cases():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from datasets import have_data, nordland, synthetic, uji_months

    out = [synthetic(0)]
    if have_data():
        out = [nordland(), *uji_months(), *out]
    return out


def _clock_pair(rows: np.ndarray) -> dict:
    ref, new = PartitionHorizon(), _Horizon()
    same_k = same_best = 0
    worst = 0.0
    for i, row in enumerate(rows):
        spread = row.std()
        k_ref, k_new = ref.update(row, i, spread), new.update(row, i, spread)
        same_k += k_ref == k_new
        slot = i % ref.capacity
        m = min(ref.places, row.shape[0])
        same_best += set(ref.best[slot, :m].tolist()) == set(new.best[slot, :m].tolist())
        scale = np.maximum(np.abs(ref.total), 1e-300)
        worst = max(worst, float(np.max(np.abs(ref.total - new.total) / scale)))
    return {"frames": int(rows.shape[0]), "same_horizon": int(same_k), "same_best": int(same_best),
            "max_rel_total": worst}


def identity() -> list[dict]:
    from catgraph.conditions import condition_table
    from catgraph.hubs import apply_hub_offsets, hub_offsets
    from catgraph.pipeline import differences

    out = []
    for case in _cases():
        hubs = hub_offsets(differences(case.reference, case.reference))
        for cond in condition_table():
            d = case.differences[cond.order(len(case.query))]
            for form, rows in (("as is", d), ("hub-corrected", np.ascontiguousarray(apply_hub_offsets(d, hubs)))):
                res = _clock_pair(np.ascontiguousarray(rows, dtype=np.float64))
                out.append({"case": case.name, "condition": cond.label,
                            "rows": form, **res})
                print(f"{case.name:12s} {out[-1]['condition']:28s} {form:13s} {res}", flush=True)
    return out


def _markdown(res: dict) -> str:
    lines = ["# The decorrelation horizon of rule \"spanning\": cost per step and identity", "",
             f"Generated by `benchmarks/bench_horizon.py`; the package measured: {res['commit']}; "
             f"{res['machine']}. Both clocks read the same rows in the same process.", ""]
    if res.get("timing"):
        sizes = [t["n"] for t in res["timing"]]
        lines += ["## Time per streaming step (medians; the partition clock is the reference)", "",
                  "| per frame | " + " | ".join(f"N = {n:,}" for n in sizes) + " |",
                  "|---|" + "---|" * len(sizes)]
        rows = [("row.std() (read by `_horizons` before the clock)", "row std"),
                ("`_Horizon.update`, partition of the standardised row (reference)", "partition"),
                ("`_Horizon.update`, one compiled pass for the best places", "selection"),
                ("`SequenceMatcher.step`, rule \"unrivalled\" (no horizon)", "unrivalled"),
                ("`SequenceMatcher.step`, rule \"spanning\", the partition clock", "spanning, partition clock"),
                ("`SequenceMatcher.step`, rule \"spanning\" as it is", "spanning")]
        for label, key in rows:
            cells = []
            for t in res["timing"]:
                cell = f"{t['median_ms'][key]:.3f} ms" if t["median_ms"][key] < 1 else f"{t['median_ms'][key]:.2f} ms"
                if key in t["p90_ms"]:
                    cell += f" (p90 {t['p90_ms'][key]:.1f})"
                cells.append(cell)
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        lines.append("| what rule \"spanning\" adds to the step, partition clock / as it is | " + " | ".join(
            f"{t['median_ms']['spanning, partition clock'] - t['median_ms']['unrivalled']:+.2f} / "
            f"{t['median_ms']['spanning'] - t['median_ms']['unrivalled']:+.2f} ms" for t in res["timing"]) + " |")
        lines.append("| the clock alone, partition / compiled pass | " + " | ".join(
            f"×{t['median_ms']['partition'] / t['median_ms']['selection']:.1f}" for t in res["timing"]) + " |")
        lines.append("| load average (1, 5, 15 min) at the end | " + " | ".join(
            ", ".join(f"{x:.2f}" for x in t["load"]) for t in res["timing"]) + " |")
        lines.append("")
    if res.get("identity"):
        ident = res["identity"]
        frames = sum(r["frames"] for r in ident)
        lines += ["## The same horizons on real rows", "",
                  f"{len(ident)} runs (each case × 14 conditions × rows as they are / hub-corrected), {frames:,} frames: "
                  f"horizon identical in {sum(r['same_horizon'] for r in ident):,}, best-place set identical in "
                  f"{sum(r['same_best'] for r in ident):,}; the clocks' averaged ratios differ by at most "
                  f"{max(r['max_rel_total'] for r in ident):.1e} (relative; the ten values summed in another order).",
                  "", "| case | rows | conditions | frames | same horizon | same best places | max relative difference |",
                  "|---|---|---|---|---|---|---|"]
        groups = {}
        for r in ident:
            groups.setdefault((r["case"], r["rows"]), []).append(r)
        for (case, form), rs in groups.items():
            lines.append(f"| {case} | {form} | {len(rs)} | {sum(r['frames'] for r in rs):,} | "
                         f"{sum(r['same_horizon'] for r in rs):,} | {sum(r['same_best'] for r in rs):,} | "
                         f"{max(r['max_rel_total'] for r in rs):.1e} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--skip", default="", help="comma-separated: timing,identity")
    ap.add_argument("--out", default="matcher_horizon")
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    res = {"commit": _commit(), "machine": f"{describe_machine()}, shared with other work"}
    if "timing" not in skip:
        res["timing"] = []
        for n in args.sizes:
            res["timing"].append(timing(n, args.frames))
            print(json.dumps(res["timing"][-1]), flush=True)
    if "identity" not in skip:
        res["identity"] = identity()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(res, indent=1) + "\n")
    (RESULTS / f"{args.out}.md").write_text(_markdown(res))
    print(_markdown(res))


if __name__ == "__main__":
    main()
