"""Benchmark: the grid filter over several jump rates against its single learned jump rate.

:class:`catgraph.grid.GridLocalizer` has an option ``jump_rates`` (off by default): one
posterior over (place, velocity) per jump rate, weighted by its evidence — the query's
one rate averaged by Bayes' rule (``jump_rate_scope="query"``) or a rate per run between
two jumps, a run-length hazard (``"run"``) — so that the cost of leaving a track grows
with the evidence the frames have given the small rates (``docs/particle_filter.md``,
"Ninth round"). This benchmark runs the registry's
``filter`` method exactly as a user gets it — the default model (``filter (default)``) and
the combined model (``filter + combined``) — once as registered and once with the grid
filter given ``jump_rates``, on the condition table of Nordland, UJI 02–06 and the
synthetic world (``bench_conditions.py``'s cells) and on the held-out worlds
(``bench_generalisation.py``'s), and writes every cell before and after.

Run from the repository root::

    python benchmarks/bench_filter_hazard.py [--quick] [--datasets nordland,uji,synthetic,heldout]
        [--models default,combined] [--rates 0.1,0.01,0.001,0.0001] [--scope query|run] [--out DIR]

Writes ``filter_hazard.md`` and ``filter_hazard.json`` under ``--out`` (default
``benchmarks/results``). ``--quick``: in order, shuffled 2–20 % and 0.5–3 % (seed 0),
reversed, speed 2. The held-out worlds always run the five quick conditions (as
``bench_generalisation.py`` without ``--full``). ``speed`` instead times one step at
10⁵ places (median of repeated runs, against the single-rate filter in the same run).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import benchmark_conditions, prepared_datasets  # noqa: E402

import catgraph.grid as grid  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
RATES = (0.1, 0.01, 0.001, 0.0001)
MODELS = {"default": ("filter (default)", {}), "combined": ("filter + combined", {"model": "combined"})}
_REGISTERED = grid.GridLocalizer


def _with_rates(rates, scope="query"):
    """The grid filter the registry builds, with ``jump_rates`` (None: as registered)."""
    if rates is None:
        return _REGISTERED

    class Hazard(_REGISTERED):
        def __init__(self, *args, **kwargs):
            kwargs.setdefault("jump_rates", rates)
            kwargs.setdefault("jump_rate_scope", scope)
            super().__init__(*args, **kwargs)

    return Hazard


def _run(params, prepared, rates, scope="query"):
    grid.GridLocalizer = _with_rates(rates, scope)  # methods.make_filter imports it at call time
    try:
        result = run_method("filter", dict(params, mode="grid"), prepared)
    finally:
        grid.GridLocalizer = _REGISTERED
    m = result.evaluate(prepared.ground_truth).metrics.as_dict()
    return float(m["auc"]), float(m["recall_at_100p"]), result.seconds


def _cases(names):
    out = prepared_datasets([n for n in names if n != "heldout"])
    cases = {ds: (c, None) for ds, c in out.items()}
    if "heldout" in names:
        from bench_generalisation import WORLDS, world_case

        for label, spec in WORLDS.items():
            cases[f"held-out: {label}"] = ([world_case(spec)], benchmark_conditions(True))
    return cases


def conditions(args) -> list[dict]:
    rates = tuple(float(r) for r in args.rates.split(","))
    rows = []
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for ds, (cases, own) in _cases(args.datasets.split(",")).items():
        for condition in own or benchmark_conditions(args.quick):
            prepared = [c.under(condition) if condition.kind != "in-order" else c for c in cases]
            for key in args.models.split(","):
                label, params = MODELS[key]
                cell = {"dataset": ds, "condition": condition.label, "condition_spec": condition.as_dict(),
                        "method": label}
                for name, r in (("before", None), ("after", rates)):
                    runs = [_run(params, p, r, args.scope) for p in prepared]
                    cell[name] = {"auc": float(np.mean([x[0] for x in runs])),
                                  "recall_at_100p": float(np.mean([x[1] for x in runs])),
                                  "seconds": float(sum(x[2] for x in runs)),
                                  "auc_each": [x[0] for x in runs]}
                rows.append(cell)
                print(f"{ds:20s} {condition.label:28s} {label:18s} {cell['before']['auc']:.4f} -> "
                      f"{cell['after']['auc']:.4f} ({cell['after']['auc'] - cell['before']['auc']:+.4f}) "
                      f"{time.strftime('%X')}", flush=True)
                (out / "filter_hazard.json").write_text(json.dumps(
                    {"machine": platform.platform(), "rates": rates, "scope": args.scope, "rows": rows}, indent=1))
    (out / "filter_hazard.md").write_text(markdown(rows, rates, args.scope))
    return rows


def markdown(rows, rates, scope) -> str:
    header = (f"# The grid filter over several jump rates (`jump_rates={rates}`, `jump_rate_scope={scope!r}`)\n\n"
              "Generated by `benchmarks/bench_filter_hazard.py`. Each cell: AUC / R@100P before (the registry's "
              "filter, one learned jump rate) → after (the same method with the grid filter given `jump_rates`); "
              "UJI: means over months 02–06. Held-out worlds: `bench_generalisation.py`'s, quick conditions.\n")
    return header + before_after_tables(rows, run_time=True)


def before_after_tables(rows, run_time: bool = False) -> str:
    """One table per dataset: every cell's AUC / R@100P before → after, and each method's mean
    (with ``run_time``, also its summed seconds before → after)."""
    parts = []
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        parts.append(f"\n## {ds}\n\n| condition | method | before | after | Δ AUC |\n|---|---|---|---|---|\n")
        for r in (r for r in rows if r["dataset"] == ds):
            b, a = r["before"], r["after"]
            parts.append(f"| {r['condition']} | {r['method']} | {b['auc']:.4f} / {b['recall_at_100p']:.2f} | "
                         f"{a['auc']:.4f} / {a['recall_at_100p']:.2f} | {a['auc'] - b['auc']:+.4f} |\n")
        for method in dict.fromkeys(r["method"] for r in rows if r["dataset"] == ds):
            group = [r for r in rows if r["dataset"] == ds and r["method"] == method]
            b = np.mean([r["before"]["auc"] for r in group])
            a = np.mean([r["after"]["auc"] for r in group])
            parts.append(f"| **mean of {len(group)}** | {method} | {b:.4f} | {a:.4f} | {a - b:+.4f} |\n")
            if run_time:
                sb = sum(r["before"]["seconds"] for r in group)
                sa = sum(r["after"]["seconds"] for r in group)
                parts.append(f"| (run time, s) | {method} | {sb:.0f} | {sa:.0f} | ×{sa / max(sb, 1e-9):.2f} |\n")
    return "".join(parts)


def speed(args) -> str:
    """Step time at 10⁵ places: the single-rate filter and ``jump_rates``, alternated."""
    from catgraph.graph import PlaceGraph
    from bench_filter import _FixedModel

    rates = tuple(float(r) for r in args.rates.split(","))
    rng = np.random.default_rng(0)
    n = 100_000
    g = PlaceGraph.chain(n)
    model = _FixedModel(rng.standard_normal(n))
    rows = rng.standard_normal((40, n))
    times = {"single rate": [], "jump_rates": []}
    filters = {"single rate": _REGISTERED(g, model),
               "jump_rates": _REGISTERED(g, model, jump_rates=rates, jump_rate_scope=args.scope)}
    for _ in range(5):
        for name, f in filters.items():
            f.reset()
            for r in rows[:5]:
                f.step(r)
            t = time.perf_counter()
            for r in rows[5:]:
                f.step(r)
            times[name].append((time.perf_counter() - t) / (len(rows) - 5))
    one = statistics.median(times["single rate"])
    many = statistics.median(times["jump_rates"])
    text = (f"step at {n:,} places (observation precomputed, median of 5 alternated runs of 35 steps): "
            f"single rate {1e3 * one:.2f} ms, jump_rates={rates} {1e3 * many:.2f} ms (×{many / one:.2f})\n")
    print(text)
    return text


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", nargs="?", default="conditions", choices=("conditions", "speed"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--datasets", default="nordland,uji,synthetic,heldout")
    ap.add_argument("--models", default="default,combined")
    ap.add_argument("--rates", default=",".join(str(r) for r in RATES))
    ap.add_argument("--scope", default="query", choices=grid.JUMP_RATE_SCOPES)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    if args.what == "speed":
        speed(args)
    else:
        conditions(args)


if __name__ == "__main__":
    main()
