"""Benchmark: every method's defaults on every traversal condition and dataset.

The condition table (``catgraph.conditions.condition_table``): in order; shuffled in
segments of 2–20 % and of 0.5–3 % (seeds 0–4 each); reversed; speed 2; speed 0.5 — on
Nordland 32×16 summer → winter (±2 frames), UJI Wi-Fi month 01 ``trn01`` → months 02–06
``tst01`` (3 m; means over the five months) and the synthetic world (seed 0, 10 m).
Every method runs with its registry defaults through the experiment layer
(:func:`catgraph.experiment.run_method` on :meth:`Prepared.under` inputs), so the table
shows exactly what a user gets without tuning.

Writes ``benchmarks/results/conditions.md`` and ``conditions.json``. Run from the
repository root::

    python benchmarks/bench_conditions.py [--quick] [--methods single-frame,adaptive,...]
        [--datasets nordland,uji,synthetic] [--merge]

``--merge``: keep the committed rows of the methods and datasets not run this time, so one
method can be re-measured after its defaults change without re-running the others.

``--quick``: in order, shuffled 2–20 % seed 0, shuffled 0.5–3 % seed 0, reversed, speed 2.

``--check [--tolerance T]``: run the methods, datasets and conditions asked for and compare
every cell with the committed ``conditions.json`` (AUC, R@100P and MTL; float for float,
or within ``T``: the compiled kernels that sum with ``fastmath`` round per target CPU, so on
another processor a cell may differ in its last digits, unless ``NUMBA_CPU_NAME`` names the
CPU the table was compiled for, its ``compiled_for``: ``docs/evaluation.md``); writes
nothing, prints the cells that differ or are missing, exits 1 if any does — the table
reproduced on another checkout or machine with one command.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import benchmark_conditions, prepared_datasets  # noqa: E402
from machine_info import describe_machine  # noqa: E402

from catgraph.environment import compile_target  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

#: label → (method, params): the registry defaults a user gets
METHODS = {
    "single-frame": ("single-frame", {}),
    "fixed L=10": ("sequence", {"window": 10}),
    "fixed L=50": ("sequence", {"window": 50}),
    "fixed L=100": ("sequence", {"window": 100}),
    "adaptive": ("sequence", {"window": "adaptive"}),
    "histogram (online)": ("histogram", {}),
    "filter (default)": ("filter", {}),
    "particle filter": ("filter", {"mode": "particles"}),
    "filter + histogram": ("filter", {"model": "histogram"}),
    "filter + combined": ("filter", {"model": "combined"}),
}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--methods", default=None,
                    help="comma-separated labels (default: every method; with --check, the committed table's)")
    ap.add_argument("--datasets", default="nordland,uji,synthetic")
    ap.add_argument("--merge", action="store_true",
                    help="keep the saved rows of every other method and dataset (full table only)")
    ap.add_argument("--check", action="store_true",
                    help="compare every cell run with the committed conditions.json; write nothing; exit 1 on a "
                         "difference")
    ap.add_argument("--tolerance", type=float, default=0.0,
                    help="with --check: the largest difference a cell may have (default 0: float for float)")
    args = ap.parse_args(argv)
    if args.merge and args.quick:
        raise SystemExit("--merge keeps rows of the full table; it cannot be combined with --quick")
    if args.merge and args.check:
        raise SystemExit("--check writes nothing; it cannot be combined with --merge")
    if not args.tolerance >= 0.0:
        raise SystemExit(f"--tolerance must be a difference of 0 or more; got {args.tolerance}")
    if args.methods is None and args.check and (RESULTS / "conditions.json").is_file():
        present = {r["method"] for r in json.loads((RESULTS / "conditions.json").read_text())["rows"]}
        args.methods = ",".join(m for m in METHODS if m in present)
    labels = [m.strip() for m in (args.methods or ",".join(METHODS)).split(",")]
    unknown = [m for m in labels if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}; choose from {list(METHODS)}")
    conditions = benchmark_conditions(args.quick)
    datasets = prepared_datasets(args.datasets.split(","))
    rows = []
    for ds, cases in datasets.items():
        for condition in conditions:
            prepared = [case.under(condition) if condition.kind != "in-order" else case for case in cases]
            for label in labels:
                method, params = METHODS[label]
                metrics, seconds = [], 0.0
                for p in prepared:
                    result = run_method(method, params, p)
                    metrics.append(result.evaluate(p.ground_truth).metrics.as_dict())
                    seconds += result.seconds
                row = {"dataset": ds, "condition": condition.label, "condition_spec": condition.as_dict(),
                       "method": label, "auc": float(np.mean([m["auc"] for m in metrics])),
                       "recall_at_100p": float(np.mean([m["recall_at_100p"] for m in metrics])),
                       "mtl": float(np.mean([m["mtl"] for m in metrics])),
                       "mtl_max": int(max(m["mtl"] for m in metrics)), "seconds": seconds}
                rows.append(row)
                print(f"{ds:10s} {condition.label:28s} {label:22s} AUC {row['auc']:.3f} R@100P "
                      f"{row['recall_at_100p']:.3f} MTL {row['mtl']:.0f}  {time.strftime('%X')}", flush=True)
    if args.check:
        raise SystemExit(_check(rows, RESULTS / "conditions.json", args.tolerance))
    if args.merge and (RESULTS / "conditions.json").is_file():
        done = {(r["dataset"], r["method"]) for r in rows}
        kept = [r for r in json.loads((RESULTS / "conditions.json").read_text())["rows"]
                if (r["dataset"], r["method"]) not in done]
        rows = kept + rows
        present = {r["method"] for r in rows}
        labels = [m for m in METHODS if m in present]
        rows.sort(key=lambda r: ("Nordland", "UJI 02-06", "synthetic").index(r["dataset"]))
    RESULTS.mkdir(parents=True, exist_ok=True)
    table = {"machine": describe_machine(), "compiled_for": compile_target(), "rows": rows}
    (RESULTS / "conditions.json").write_text(json.dumps(table, indent=1))
    (RESULTS / "conditions.md").write_text(_markdown(rows, labels, conditions, args.quick))


#: What a row of the table records of a method's result (compared by ``--check``).
CHECKED = ("auc", "recall_at_100p", "mtl", "mtl_max")


def _check(rows: list[dict], committed_path: Path, tolerance: float = 0.0) -> int:
    """Compare ``rows`` with the committed table cell by cell; 0 where every value is the
    same, float for float (JSON keeps a float's every bit), or within ``tolerance``; else 1."""
    if not committed_path.is_file():
        print(f"no committed table at {committed_path}: nothing to check against")
        return 1
    table = json.loads(committed_path.read_text())
    committed = {(r["dataset"], r["condition"], r["method"]): r for r in table["rows"]}
    # the compiled sums round per processor: say where the table was made and where it is checked
    print(f"committed table measured on: {table.get('machine', 'not recorded')}\nchecked on: {describe_machine()}")
    differ = 0
    for row in rows:
        key = (row["dataset"], row["condition"], row["method"])
        old = committed.get(key)
        if old is None:
            print(f"not in the committed table: {' / '.join(key)}")
            differ += 1
            continue
        changed = [f"{f} {old.get(f)!r} -> {row[f]!r}" for f in CHECKED
                   if old.get(f) is None or not abs(old[f] - row[f]) <= tolerance]
        if changed:
            print(f"differs: {' / '.join(key)}: " + "; ".join(changed))
            differ += 1
    print(f"{len(rows) - differ} of {len(rows)} cells as committed" + ("" if differ else ": the table reproduces"))
    made_for, here = table.get("compiled_for"), compile_target()
    if differ and made_for and made_for != here:
        print(f"the table's kernels were compiled for {made_for}, these for {here}: the kernels that sum with "
              f"fastmath round per target CPU; NUMBA_CPU_NAME={made_for} compiles for the table's (docs/evaluation.md)")
    return 1 if differ else 0


def _markdown(rows, labels, conditions, quick) -> str:
    parts = ["# Every method's defaults under every traversal condition\n",
             "Generated by `benchmarks/bench_conditions.py" + (" --quick" if quick else "") + "`. Each cell: AUC / "
             "R@100P / MTL (UJI: means over months 02–06). Registry defaults, no tuning; ground truth ±2 frames "
             "(Nordland), 3 m (UJI), 10 m (synthetic). Shuffled rows are summarised as mean and worst AUC over "
             "their seeds below each table.\n"]
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        parts.append(f"\n## {ds}\n\n| condition | " + " | ".join(labels) + " |\n|---|" + "---|" * len(labels) + "\n")
        for c in conditions:
            cells = []
            for label in labels:
                r = next((r for r in rows if r["dataset"] == ds and r["condition"] == c.label
                          and r["method"] == label), None)
                cells.append("—" if r is None else f"{r['auc']:.3f} / {r['recall_at_100p']:.2f} / {r['mtl']:.0f}")
            parts.append(f"| {c.label} | " + " | ".join(cells) + " |\n")
        for rng, name in (((0.02, 0.2), "shuffled 2–20 %"), ((0.005, 0.03), "shuffled 0.5–3 %")):
            group = [r for r in rows if r["dataset"] == ds and r["condition_spec"].get("segment_range") == list(rng)]
            if len({r["condition"] for r in group}) > 1:
                cells = []
                for label in labels:
                    aucs = [r["auc"] for r in group if r["method"] == label]
                    cells.append(f"mean {np.mean(aucs):.3f}, worst {min(aucs):.3f}" if aucs else "—")
                parts.append(f"| **{name}, all seeds** | " + " | ".join(cells) + " |\n")
    return "".join(parts)


if __name__ == "__main__":
    main()
