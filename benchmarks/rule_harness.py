"""A harness for window rules: per-frame statistics computed once, rules applied afterwards.

The adaptive matcher (:mod:`catgraph.sequence`) has two stages: compiled kernels that
summarise, per query frame, velocity and candidate length, the window scores over the
reference (a ``_Stats``), and the window rule (:mod:`catgraph._window_rule`) that turns
those statistics into a match and a confidence. The first stage dominates the cost; the
second is cheap. To compare many rules on the whole condition table this harness runs
the first stage once per dataset, condition and seed (the same rows, hub correction and
kernels as :func:`catgraph.sequence.match_sequences`), caches the statistics on disk
(outside the repository: ``$CATGRAPH_RULE_CACHE``, default ``/tmp/catgraph_rule_cache``),
and applies any rule to them. It reuses nothing but the library: the rule under test is a
function ``rule(stats, rows, cfg) -> (match, confidence)``; the library's own rules run
through ``catgraph._window_rule._decide`` and reproduce ``match_sequences`` exactly.

Cells:

* ``table``: Nordland, UJI months 02–06 (averaged per cell) and the synthetic world of
  seed 0 under all 14 conditions (:func:`catgraph.conditions.condition_table`), rows as
  ``benchmarks/bench_sequence.py`` builds them; the margin of a rule is its AUC minus the
  best fixed window's AUC of the committed ``benchmarks/results/sequence.json`` (the better
  of the velocity-search and the SeqSLAM windows, chosen per cell with hindsight);
* ``heldout``: the six worlds and five quick conditions of
  ``benchmarks/bench_generalisation.py`` (through the experiment layer, as there); the
  margin is against the best fixed window of the committed ``generalisation.json``.

Ground truth is read only to score a rule, never by it. Run from the repository root::

    python benchmarks/rule_harness.py [--sets table,heldout] [--rules a,b] [--write]

which prints the margins of the default rule (a check that the harness reproduces the
committed benchmarks) and of every candidate of ``benchmarks/rule_candidates.py``; with
``--write`` the library's rules "unrivalled", "decorrelated" and "spanning", the parts of
"spanning" and the candidates around it that docs/sequence.md reports, and rule "spanning"
with the library's confidence "changepoint", written to
``benchmarks/results/window_rules.md`` and ``.json`` (``--round N``: one round of the search
beside "spanning"; ``--dump``: every cell's AUC per rule as JSON; ``--add``: only the
library's confidences, added as columns to the committed files).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from catgraph import _window_rule as wr  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402
from catgraph.sequence import (DEFAULT_VELOCITIES, EM_ITERATIONS, _config, _em_stride, _kernels,  # noqa: E402
                               _prepare_rows, _state)

RESULTS = ROOT / "benchmarks" / "results"
CACHE = Path(os.environ.get("CATGRAPH_RULE_CACHE", "/tmp/catgraph_rule_cache"))
FIELDS = ("best_j", "best_s", "second_s", "mean", "std", "weights", "locs", "scales", "sub")


def config(rule: str = "unrivalled", **kwargs):
    """The matcher's configuration with the registry defaults (``match_sequences``'s)."""
    args = dict(window="adaptive", approximation="gaussian", rule=rule, confidence="posterior", l_min=5, l_max=500,
                grid=13, radius=10, recent_fraction=0.05, velocities=DEFAULT_VELOCITIES, hub_offsets=None)
    args.update(kwargs)
    return _config("harness", *(args[k] for k in ("window", "approximation", "rule", "confidence", "l_min", "l_max",
                                                  "grid", "radius", "recent_fraction", "velocities", "hub_offsets")))


def compute_stats(d: np.ndarray, offsets: np.ndarray | None) -> tuple[wr._Stats, np.ndarray]:
    """Every per-frame statistic of the default adaptive matcher (sub-windows included)
    for the rows ``d`` (processing order), and the rows as the kernels see them."""
    cfg = config(hub_offsets=offsets)
    d = _prepare_rows(np.ascontiguousarray(d, dtype=np.float64), cfg)
    n_q, n = d.shape
    run = _kernels().matcher_kernel(cfg.approx_code)
    g, v_count = cfg.grid.shape[0], cfg.velocities.shape[0]
    sums, ring, mring, state, scratch = _state(cfg, n, max(1, min(64, (1 << 24) // n)))
    st = wr._Stats(n_q, v_count, g, cfg.n_components, True)
    block = max(1, min(n_q, 4_000_000 // (v_count * g * g)))
    for start in range(0, n_q, block):
        stop = min(n_q, start + block)
        part = wr._Stats(stop - start, v_count, g, cfg.n_components, True)
        run(d[start:stop], start, sums, ring, mring, state, cfg.velocities, cfg.grid, cfg.approx_code,
            EM_ITERATIONS, _em_stride(n), cfg.radius, part.best_j, part.best_s, part.second_s, part.mean, part.std,
            part.weights, part.locs, part.scales, part.sub, *scratch)
        for f in FIELDS:
            getattr(st, f)[start:stop] = getattr(part, f)
    return st, d


def cached_stats(key: str, d: np.ndarray, offsets: np.ndarray | None) -> tuple[wr._Stats, np.ndarray]:
    """:func:`compute_stats`, cached on disk under a hash of the rows and offsets."""
    h = hashlib.sha1(np.ascontiguousarray(d).tobytes())
    if offsets is not None:
        h.update(np.ascontiguousarray(offsets).tobytes())
    path = CACHE / f"{key.replace(' ', '_').replace('/', '-')}_{h.hexdigest()[:12]}.npz"
    if path.exists():
        z = np.load(path)
        n, v, g, k = z["weights"].shape
        st = wr._Stats(n, v, g, k, True)
        for f in FIELDS:
            setattr(st, f, z[f])
        return st, z["rows"]
    st, rows = compute_stats(d, offsets)
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, rows=rows, **{f: getattr(st, f) for f in FIELDS})
    return st, rows


class Cell:
    """One cell: one or more cases (UJI: the five months), each with cached statistics."""

    def __init__(self, dataset: str, label: str, best_fixed: float, parts: list):
        self.dataset, self.label, self.best_fixed = dataset, label, best_fixed
        self.parts = parts  # [(key, rows_raw, offsets, query_index, ground_truth)]

    def each(self):
        for key, d, offsets, index, truth in self.parts:
            st, rows = cached_stats(key, d, offsets)
            yield st, rows, index, truth


def library_rule(rule: str, **kwargs):
    """A rule of the library, as ``match_sequences`` applies it."""

    def apply(st, rows, cfg):
        c = config(rule, **kwargs)
        match, _, conf, length, vel, _ = wr._decide(st, c, np.arange(rows.shape[0]), False, rows, wr._new_record(c))
        return match, conf
    return apply


#: the library's confidences and rules beside the harness's candidates (``--add``: only these,
#: added as columns to the committed ``window_rules.json``; a column already there is measured again)
LIBRARY_CONFIDENCES = {"spanning, confidence changepoint (library)": library_rule("spanning", confidence="changepoint"),
                       "punctuated, confidence changepoint (library)": library_rule("punctuated",
                                                                                    confidence="changepoint"),
                       "gated, confidence changepoint (library)": library_rule("gated", confidence="changepoint"),
                       "contested, confidence changepoint (library)": library_rule("contested",
                                                                                   confidence="changepoint"),
                       "persistent, confidence changepoint (library)": library_rule("persistent",
                                                                                    confidence="changepoint"),
                       "challenged, confidence changepoint (library)": library_rule("challenged",
                                                                                    confidence="changepoint")}


def add_columns(cells: list[Cell], new: dict) -> None:
    """Add the rules ``new`` (name → AUC per cell, in the order of ``cells``) to the committed
    ``window_rules.json`` (the same cells) and write both files again."""
    data = json.loads((RESULTS / "window_rules.json").read_text())
    keys = [(c["dataset"], c["condition"]) for c in data["cells"]]
    if keys != [(c.dataset, c.label) for c in cells]:
        raise SystemExit("--add needs every cell of the committed window_rules.json (--sets table,heldout)")
    results = {r: [c["auc"][r] for c in data["cells"]] for r in data["cells"][0]["auc"]}
    results.update(new)
    write_results(cells, results)


def score(cell: Cell, rule) -> float:
    """Mean AUC of ``rule`` over the cell's cases."""
    return score_all(cell, [rule])[0]


def score_all(cell: Cell, rules: list) -> list[float]:
    """Mean AUC of each rule over the cell's cases (the statistics loaded once)."""
    aucs = np.zeros((len(rules), len(cell.parts)))
    for k, (st, rows, index, truth) in enumerate(cell.each()):
        for r, rule in enumerate(rules):
            match, conf = rule(st, rows, config())
            aucs[r, k] = evaluate(index, match, conf, truth).metrics.auc
    return [float(a) for a in aucs.mean(axis=1)]


# ------------------------------------------------------------------------------------------
# the cells

def _best_fixed_table() -> dict:
    table = json.loads((RESULTS / "sequence.json").read_text())["table"]
    out = {}
    for name, data in table.items():
        for row in data["conditions"]:
            fixed = [r["auc"] for m, r in row["methods"].items() if m.startswith(("fixed", "SeqSLAM"))]
            out[(name, row["label"])] = max(fixed)
    return out


def dataset_groups(datasets=("Nordland", "UJI", "synthetic")) -> list[tuple[str, list]]:
    """``[(name, cases)]`` of the table's datasets (UJI: its five months, one cell each
    condition)."""
    from datasets import nordland, synthetic, uji_months

    groups = []
    if "Nordland" in datasets:
        groups.append(("Nordland", [nordland()]))
    if "UJI" in datasets:
        groups.append(("UJI Wi-Fi (months 02–06)", uji_months()))
    if "synthetic" in datasets:
        groups.append(("synthetic (seed 0)", [synthetic(0)]))
    return groups


def table_cells(datasets=("Nordland", "UJI", "synthetic")) -> list[Cell]:
    from datasets import conditioned

    from catgraph.conditions import condition_table
    from catgraph.hubs import hub_offsets
    from catgraph.pipeline import differences

    best = _best_fixed_table()
    cells = []
    for name, cases in dataset_groups(datasets):
        offsets = hub_offsets(differences(cases[0].reference, cases[0].reference))
        for condition in condition_table(seeds=range(5)):
            parts = []
            for case in cases:
                c = conditioned(case, condition)
                parts.append((f"{case.name} {condition.label}", c.differences, offsets, c.query.index,
                              c.ground_truth))
            cells.append(Cell(name, condition.label, best[(name, condition.label)], parts))
    return cells


def heldout_cells() -> list[Cell]:
    from bench_generalisation import WORLDS, world_case
    from datasets import benchmark_conditions

    rows = json.loads((RESULTS / "generalisation.json").read_text())["rows"]
    cells = []
    for name, spec in WORLDS.items():
        case = world_case(spec)
        for condition in benchmark_conditions(True):
            prepared = case.under(condition) if condition.kind != "in-order" else case
            best = max(r["auc"] for r in rows if r["world"] == name and r["condition"] == condition.label
                       and r["method"].startswith("fixed"))
            cells.append(Cell("held-out", f"{name}, {condition.label}", best,
                              [(f"world {name} {condition.label}", prepared.differences, prepared.hub_offsets(),
                                prepared.query.index, prepared.ground_truth)]))
    return cells


def summary(cells: list[Cell], aucs: list[float]) -> dict:
    """Margins to the best fixed window (mean, worst, cells within 0.01, cells): per
    dataset, over the condition table's cells ("table") and over the held-out cells."""
    out = {}
    names = list(dict.fromkeys(c.dataset for c in cells))
    groups = {ds: [ds] for ds in names}
    table = [ds for ds in names if ds != "held-out"]
    if len(table) > 1:
        groups["table"] = table
    for key, members in groups.items():
        m = np.array([a - c.best_fixed for c, a in zip(cells, aucs) if c.dataset in members])
        out[key] = (float(m.mean()), float(m.min()), int(np.sum(m >= -0.01)), int(m.size))
    return out


def fmt(s) -> str:
    return f"{s[0]:+.3f} / {s[1]:+.3f} / {s[2]}"


def candidates(write: bool = False) -> dict:
    """Rules compared by ``main`` (name → rule function). With ``write``: the library's rules
    "unrivalled", "decorrelated" and "spanning" (the default), the parts of "spanning"
    (``rule_candidates.ABLATIONS``) and the candidates around it that the documentation reports
    (``rule_candidates.REPORTED``); else the default and every candidate of the search
    (``rule_candidates.CANDIDATES``)."""
    import rule_candidates

    if write:
        return {"unrivalled": library_rule("unrivalled"), "decorrelated": library_rule("decorrelated"),
                "spanning": library_rule("spanning"), **rule_candidates.ABLATIONS, **rule_candidates.REPORTED,
                **LIBRARY_CONFIDENCES}
    return {"unrivalled": library_rule("unrivalled"), **rule_candidates.CANDIDATES}


def write_results(cells: list[Cell], results: dict) -> None:
    """``benchmarks/results/window_rules.md`` and ``.json``: every cell's AUC per rule and the
    summaries of the margins to the best fixed window."""
    rules = list(results)
    data = {"cells": [{"dataset": c.dataset, "condition": c.label, "best_fixed": c.best_fixed,
                       "auc": {r: results[r][k] for r in rules}} for k, c in enumerate(cells)],
            "summary": {r: summary(cells, results[r]) for r in rules}}
    (RESULTS / "window_rules.json").write_text(json.dumps(data, indent=1))
    lines = ["# Window rules on cached per-frame statistics", "",
             "Generated by `benchmarks/rule_harness.py --write`: the adaptive matcher's per-frame statistics "
             "computed once per dataset, condition and seed (the library's kernels, rows and hub offsets as "
             "`bench_sequence.py` and `bench_generalisation.py` build them), each rule applied afterwards. AUC per "
             "cell (UJI: mean of months 02–06); *best fixed*: the committed best fixed window of the cell "
             "(`sequence.json`, `generalisation.json`), chosen with hindsight. Held-out: the six worlds and five "
             "quick conditions of `bench_generalisation.py`.", "",
             "## Margin to the best fixed window (mean / worst / cells within 0.01)", "",
             "| rule | " + " | ".join(summary(cells, results[rules[0]])) + " |",
             "|---|" + "---|" * len(summary(cells, results[rules[0]]))]
    for r in rules:
        lines.append(f"| {r} | " + " | ".join(f"{v[0]:+.3f} / {v[1]:+.3f} / {v[2]} of {v[3]}"
                                               for v in summary(cells, results[r]).values()) + " |")
    lines += ["", "## Every cell (AUC)", "", "| dataset | condition | best fixed | " + " | ".join(rules) + " |",
              "|---|---|---|" + "---|" * len(rules)]
    for k, c in enumerate(cells):
        lines.append(f"| {c.dataset} | {c.label} | {c.best_fixed:.3f} | "
                     + " | ".join(f"{results[r][k]:.3f}" for r in rules) + " |")
    (RESULTS / "window_rules.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="table,heldout")
    ap.add_argument("--rules", default=None, help="comma-separated rule names (default: all)")
    ap.add_argument("--datasets", default="Nordland,UJI,synthetic")
    ap.add_argument("--round", default=None,
                    help="only the candidates of this round of rule_candidates.ROUNDS (its number), beside "
                         "the library's 'spanning'")
    ap.add_argument("--dump", default=None, help="write every cell's AUC per rule to this JSON file")
    ap.add_argument("--add", action="store_true",
                    help="only the library's confidences (LIBRARY_CONFIDENCES), added to the committed "
                         "results/window_rules.md|json as columns")
    ap.add_argument("--write", action="store_true",
                    help="the library's rules and the parts of 'spanning'; write results/window_rules.md|json")
    args = ap.parse_args(argv)
    cells = []
    if "table" in args.sets:
        cells += table_cells(tuple(args.datasets.split(",")))
    if "heldout" in args.sets:
        cells += heldout_cells()
    table = dict(LIBRARY_CONFIDENCES) if args.add else candidates(args.write)
    if args.round is not None:
        import rule_candidates

        chosen = next(v for k, v in rule_candidates.ROUNDS.items() if k.split(":")[0] == args.round)
        table = {"spanning": library_rule("spanning"), **chosen}
    rules = list(table) if args.rules is None else [r for r in args.rules.split(",") if r]
    results = {r: [] for r in rules}
    for cell in cells:
        start = time.perf_counter()
        line = []
        for r, auc in zip(rules, score_all(cell, [table[r] for r in rules])):
            results[r].append(auc)
            line.append(f"{r} {auc:.3f}")
        print(f"{cell.dataset:28s} {cell.label:28s} best fixed {cell.best_fixed:.3f} | " + " | ".join(line)
              + f"  ({time.perf_counter() - start:.0f} s)", flush=True)
    print("\nmargin to the best fixed window: mean / worst / cells within 0.01")
    for r in rules:
        s = summary(cells, results[r])
        print(f"{r:24s} " + " | ".join(f"{k}: {fmt(v)}" for k, v in s.items()))
    if args.dump:
        Path(args.dump).write_text(json.dumps({"cells": [[c.dataset, c.label, c.best_fixed] for c in cells],
                                               "auc": results}, indent=1))
    if args.write:
        write_results(cells, results)
    elif args.add:
        add_columns(cells, results)


if __name__ == "__main__":
    main()
