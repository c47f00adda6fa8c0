"""Benchmark: the combined model's weights, the plain sum against weights learned online.

The registry's ``filter`` method with ``model="combined"`` (grid filter; the tempered
whole-image model plus the adaptive sequence part, :func:`catgraph.methods.observation_model`)
runs on every condition of the condition table (``catgraph.conditions.condition_table``:
in order; shuffled 2–20 % and 0.5–3 %, seeds 0–4; reversed; speed 2; speed 0.5) of
Nordland 32×16 summer → winter (±2 frames), UJI months 02–06 against 01 (3 m; means of
the five months) and the synthetic world (seed 0), through the experiment layer, once
per variant of the combination:

* ``sum``: ``CombinedObservation(weights=None)``, the parts' log-ratios added;
* ``predictive``: ``CombinedObservation(weights="predictive")``, the sequence part's
  exponent chosen each frame among :data:`catgraph.observation.DEFAULT_PART_WEIGHTS` by
  the filter's discounted predictive score;
* ``w<x>`` (e.g. ``w0.5``): the sequence part's exponent fixed at ``x`` (``w0``: the
  tempered part alone inside the combined model).

Everything else is the registry's default. Beside each cell the table shows the filter's
default model (``filter (default)``) and the best standalone method (single-frame, the
fixed windows of ``sequence.md``, adaptive), read from the committed
``benchmarks/results/conditions.json`` and ``sequence.json``, and, for the learned
weights, how often each sequence weight was in use.

Writes ``benchmarks/results/combined.md`` and ``combined.json``. Run from the repository root::

    python benchmarks/bench_combined.py [--quick] [--datasets nordland,uji,synthetic]
        [--variants sum,predictive,w0.5] [--conditions 0,6,12] [--merge]

``--merge``: keep the saved rows of the (dataset, variant) pairs not run this time.

``--held-out``: instead, the registry's combined model on the held-out synthetic worlds
of ``bench_generalisation.py`` (its six worlds, five quick conditions), the sequence part
at each temperature of ``--temperatures`` (default ``window,longest``: ``1 / L_k``
against one over the longest window so far), beside the default filter; writes
``benchmarks/results/combined_heldout.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_filter import _stamped  # noqa: E402  (the commit a table was measured at, under its title)
from datasets import benchmark_conditions, prepared_datasets  # noqa: E402

import catgraph.methods as methods  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402
from catgraph.observation import CombinedObservation  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
VARIANTS = {"sum": None, "predictive": "predictive"}


def variant_weights(variant: str):
    """``weights`` of a variant: ``sum``, ``predictive``, or ``w<x>``: the sequence part fixed at ``x``."""
    if variant in VARIANTS:
        return VARIANTS[variant]
    if variant.startswith("w"):
        return [1.0, float(variant[1:])]
    raise SystemExit(f"unknown variant {variant!r}; choose from {list(VARIANTS)} or w<weight> (e.g. w0.5)")
DATASET_ORDER = ("Nordland", "UJI 02-06", "synthetic")


class _Recorded:
    """The registry's combined model with its weights set, recording the weights in use."""

    def __init__(self, weights) -> None:
        self.weights, self.used, self._original = weights, [], methods.observation_model

    def __enter__(self):
        def build(params, n_places, bootstrap_samples):
            model = self._original(params, n_places, bootstrap_samples)
            assert isinstance(model, CombinedObservation)
            model.weights = self.weights
            if isinstance(self.weights, str):
                feedback = model.feedback

                def recorded(fb):
                    self.used.append(float(model.weights_[-1]))  # the weight this frame was combined with
                    feedback(fb)

                model.feedback = recorded
            return model

        methods.observation_model = build
        return self

    def __exit__(self, *exc) -> None:
        methods.observation_model = self._original


def run_cell(prepared: list, weights) -> dict:
    metrics, seconds, used = [], 0.0, []
    for p in prepared:
        with _Recorded(weights) as rec:
            result = run_method("filter", {"model": "combined"}, p)
        metrics.append(result.evaluate(p.ground_truth).metrics.as_dict())
        seconds += result.seconds
        used += rec.used
    row = {k: float(np.mean([m[k] for m in metrics])) for k in ("auc", "recall_at_100p", "mtl")}
    row["seconds"] = seconds
    if used:
        u = np.array(used)
        row["weight_share"] = {f"{w:g}": float(np.mean(u == w)) for w in np.unique(u)}
    return row


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--datasets", default="nordland,uji,synthetic")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--conditions", default=None, help="indices into the condition table (default: all)")
    ap.add_argument("--merge", action="store_true")
    ap.add_argument("--render", action="store_true", help="only rewrite the .md from the saved .json")
    ap.add_argument("--held-out", action="store_true", help="the held-out worlds of bench_generalisation.py")
    ap.add_argument("--temperatures", default="window,longest", help="sequence-part temperatures (--held-out)")
    args = ap.parse_args(argv)
    if args.held_out:
        held_out([t.strip() for t in args.temperatures.split(",")])
        return
    if args.render:
        out = RESULTS / ("combined_quick.json" if args.quick else "combined.json")
        conditions = benchmark_conditions(args.quick)
        out.with_suffix(".md").write_text(markdown(json.loads(out.read_text())["rows"], conditions, args.quick))
        return
    variants = [v.strip() for v in args.variants.split(",")]
    for v in variants:
        variant_weights(v)
    conditions = benchmark_conditions(args.quick)
    if args.conditions:
        conditions = [conditions[int(i)] for i in args.conditions.split(",")]
    rows = []
    for ds, cases in prepared_datasets(args.datasets.split(",")).items():
        for condition in conditions:
            prepared = [case.under(condition) if condition.kind != "in-order" else case for case in cases]
            for variant in variants:
                row = {"dataset": ds, "condition": condition.label, "condition_spec": condition.as_dict(),
                       "variant": variant, **run_cell(prepared, variant_weights(variant))}
                rows.append(row)
                print(f"{ds:10s} {condition.label:28s} {variant:10s} AUC {row['auc']:.3f} R@100P "
                      f"{row['recall_at_100p']:.3f} MTL {row['mtl']:.0f} {row.get('weight_share', '')} "
                      f"{time.strftime('%X')}", flush=True)
    out = RESULTS / ("combined_quick.json" if args.quick else "combined.json")
    if args.merge and out.is_file():
        done = {(r["dataset"], r["variant"]) for r in rows}
        rows = [r for r in json.loads(out.read_text())["rows"] if (r["dataset"], r["variant"]) not in done] + rows
        rows.sort(key=lambda r: DATASET_ORDER.index(r["dataset"]))
    RESULTS.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.platform(), "rows": rows}, indent=1))
    out.with_suffix(".md").write_text(_stamped(markdown(rows, conditions, args.quick)))


class _Temperature:
    """The registry's combined model with its sequence part at another temperature."""

    def __init__(self, temperature) -> None:
        self.temperature, self._original = temperature, methods.observation_model

    def __enter__(self):
        def build(params, n_places, bootstrap_samples):
            model = self._original(params, n_places, bootstrap_samples)
            assert isinstance(model, CombinedObservation)
            model.models[1].temperature = self.temperature
            return model

        methods.observation_model = build
        return self

    def __exit__(self, *exc) -> None:
        methods.observation_model = self._original


def held_out(temperatures: list[str]) -> None:
    """The combined model on bench_generalisation's held-out worlds, per sequence-part
    temperature, beside the default filter (AUC / R@100P / MTL per cell)."""
    from bench_generalisation import WORLDS, world_case

    conditions = benchmark_conditions(True)
    rows = []
    for label, spec in WORLDS.items():
        case = world_case(spec)
        for condition in conditions:
            prepared = case.under(condition) if condition.kind != "in-order" else case
            row = {"world": label, "condition": condition.label}
            for t in temperatures:
                with _Temperature(t):
                    result = run_method("filter", {"model": "combined"}, prepared)
                row[t] = result.evaluate(prepared.ground_truth).metrics.as_dict()
            row["filter (default)"] = run_method("filter", {}, prepared).evaluate(prepared.ground_truth).metrics.as_dict()
            rows.append(row)
            print(label, condition.label, " ".join(f"{k}: {row[k]['auc']:.3f}" for k in (*temperatures, "filter (default)")),
                  flush=True)
    columns = [*temperatures, "filter (default)"]
    lines = ["# The combined model on the held-out worlds\n\n",
             "Generated by `benchmarks/bench_combined.py --held-out`. The registry's `filter` with `model=\"combined\"` "
             "(grid filter; tempered whole-image model + adaptive sequence part) on the synthetic worlds of "
             "`bench_generalisation.py`, its sequence part at each temperature (`window`: `1 / L_k`; `longest`: one over "
             "the longest window the matcher has chosen so far), beside the default filter. Each cell: AUC / R@100P / "
             "MTL; ground truth each world's own (10 m).\n\n",
             "| world | condition | " + " | ".join(f"combined, {t}" if t != "filter (default)" else t for t in columns)
             + " |\n|---|---|" + "---|" * len(columns) + "\n"]
    for r in rows:
        lines.append(f"| {r['world']} | {r['condition']} | " + " | ".join(_cell(r[c]) for c in columns) + " |\n")
    lines.append(f"| **mean AUC of {len(rows)} cells** | | "
                 + " | ".join(f"{np.mean([r[c]['auc'] for r in rows]):.3f}" for c in columns) + " |\n")
    out = RESULTS / "combined_heldout.json"
    out.write_text(json.dumps({"machine": platform.platform(), "rows": rows}, indent=1))
    out.with_suffix(".md").write_text(_stamped("".join(lines)))


#: sequence.json's dataset names → this table's
_SEQUENCE_DATASETS = {"Nordland": "Nordland", "UJI Wi-Fi (months 02–06)": "UJI 02-06", "synthetic (seed 0)": "synthetic"}


def _standalone(label: str) -> bool:
    """Single-frame matching, every fixed window (velocity search or the SeqSLAM diagonal), the adaptive default."""
    return (label in ("single-frame", "single frame", "adaptive", "adaptive (default)")
            or label.startswith(("fixed L=", "SeqSLAM L=")))


def reference_rows() -> dict:
    """(dataset, condition) → {"default": row, "best": (label, row)} from the committed
    ``conditions.json`` (the filter's default model; standalone methods) and
    ``sequence.json`` (every fixed window)."""
    out: dict = {}

    def offer(ds, condition, label, r):
        cell = out.setdefault((ds, condition), {})
        if label == "filter (default)":
            cell["default"] = r
        elif label == "filter + combined":
            cell["sum"] = r
        elif _standalone(label) and ("best" not in cell or r["auc"] > cell["best"][1]["auc"]):
            cell["best"] = (label, r)

    path = RESULTS / "conditions.json"
    if path.is_file():
        for r in json.loads(path.read_text())["rows"]:
            offer(r["dataset"], r["condition"], r["method"], r)
    path = RESULTS / "sequence.json"
    if path.is_file():
        for name, table in json.loads(path.read_text())["table"].items():
            for c in table["conditions"]:
                for label, r in c["methods"].items():
                    offer(_SEQUENCE_DATASETS.get(name, name), c["label"], label, r)
    return out


def _cell(r) -> str:
    return "—" if r is None else f"{r['auc']:.3f} / {r['recall_at_100p']:.2f} / {r['mtl']:.0f}"


def markdown(rows, conditions, quick) -> str:
    ref = reference_rows()
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    if "sum" not in variants:  # the plain sum is the registry's combined: its committed condition-table rows
        rows = rows + [{**cell["sum"], "dataset": ds, "condition": c, "variant": "sum"}
                       for (ds, c), cell in ref.items() if "sum" in cell]
        variants = ["sum"] + variants
    parts = ["# The combined model: plain sum against weights learned online\n\n",
             "Generated by `benchmarks/bench_combined.py" + (" --quick" if quick else "") + "`. Grid filter, "
             "registry defaults, `model=\"combined\"` (tempered whole-image model + adaptive sequence part); "
             "`sum`: the parts' log-ratios added (`weights=None`); `predictive`: the sequence part's weight chosen "
             "each frame among 0, 0.25, 0.5, 1, 2 by the filter's discounted predictive score "
             "(`weights=\"predictive\"`). Each cell: AUC / R@100P / MTL (UJI: means over months 02–06). "
             "`filter (default)` and the best standalone method (single-frame, fixed windows, adaptive; its "
             "label in brackets) are read from the committed `conditions.json` / `sequence.json`, and so is the "
             "`sum` column where this run did not measure it (`conditions.json`'s `filter + combined`: the "
             "same model and code path). "
             "`weights in use`: share of frames combined with each sequence weight (learned weights).\n"]
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        parts.append(f"\n## {ds}\n\n| condition | " + " | ".join(f"combined, {v}" for v in variants)
                     + " | filter (default) | best standalone | weights in use |\n|---|"
                     + "---|" * (len(variants) + 3) + "\n")
        for c in conditions:
            cells = []
            for v in variants:
                r = next((r for r in rows if r["dataset"] == ds and r["condition"] == c.label
                          and r["variant"] == v), None)
                cells.append(_cell(r))
            cell = ref.get((ds, c.label), {})
            best = cell.get("best")
            learned = next((r for r in rows if r["dataset"] == ds and r["condition"] == c.label
                            and "weight_share" in r), None)
            share = "—" if learned is None else ", ".join(
                f"{w}: {s:.3f}" for w, s in sorted(learned["weight_share"].items(), key=lambda x: -x[1]) if s >= 5e-4)
            cells += [_cell(cell.get("default")), "—" if best is None else f"{_cell(best[1])} ({best[0]})", share]
            parts.append(f"| {c.label} | " + " | ".join(cells) + " |\n")
        for rng, name in (((0.02, 0.2), "shuffled 2–20 %"), ((0.005, 0.03), "shuffled 0.5–3 %")):
            group = [r for r in rows if r["dataset"] == ds and r["condition_spec"].get("segment_range") == list(rng)]
            if len({r["condition"] for r in group}) > 1:
                cells = []
                for v in variants:
                    aucs = [r["auc"] for r in group if r["variant"] == v]
                    cells.append(f"mean {np.mean(aucs):.3f}, worst {min(aucs):.3f}" if aucs else "—")
                labels = {r["condition"] for r in group}
                d = [ref.get((ds, lab), {}).get("default") for lab in labels]
                b = [ref.get((ds, lab), {}).get("best") for lab in labels]
                cells.append(f"mean {np.mean([x['auc'] for x in d]):.3f}, worst {min(x['auc'] for x in d):.3f}"
                             if all(d) else "—")
                cells.append(f"mean {np.mean([x[1]['auc'] for x in b]):.3f}, worst {min(x[1]['auc'] for x in b):.3f}"
                             if all(b) else "—")
                cells.append("")
                parts.append(f"| **{name}, all seeds** | " + " | ".join(cells) + " |\n")
        means = []
        for v in variants:
            aucs = [r["auc"] for r in rows if r["dataset"] == ds and r["variant"] == v]
            means.append(f"{np.mean(aucs):.3f}" if aucs else "—")
        d = [ref.get((ds, c.label), {}).get("default") for c in conditions]
        b = [ref.get((ds, c.label), {}).get("best") for c in conditions]
        parts.append(f"| **mean AUC of the {len(conditions)} conditions** | " + " | ".join(means)
                     + f" | {np.mean([x['auc'] for x in d]):.3f} | " if all(d) else " | — | ")
        parts[-1] += (f"{np.mean([x[1]['auc'] for x in b]):.3f} (best per cell) | |\n" if all(b) else "— | |\n")
    return "".join(parts)


if __name__ == "__main__":
    main()
