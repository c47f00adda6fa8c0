"""Benchmark: an upper bound for the grid filter on short shuffles, and the best hazard.

A query shuffled in segments of 0.5–3 % of its length jumps every 18–107 frames on
Nordland (3–17 on UJI). How much of what the filter misses there is the jump model's
fault, and how much the observation model's? This benchmark answers with two runs of
the registry's ``filter`` method (the exact grid filter, the default tempered
whole-image model), changed only in what the filter knows about jumps:

``oracle``
    The filter is *told every jump time*: at the first frame of each segment its state
    is re-seeded uniform over places (the velocity uniform too, or kept: ``velocity
    kept``) before the frame's prediction; the observation model, its temperature and hub
    levels carry on as they are. Between two jumps the filter runs with its jump rate as
    registered (learned), or with none at all (``no jumps``: it knows no jump comes).
    Its AUC is what a filter that detected every jump at once, with no false alarm,
    would reach with this observation model; its accuracy (the share of frames answered
    right) bounds the AUC of any ranking of those answers.
``hazard``
    The filter told nothing, with a fixed jump rate ``ε`` (not learned), with the
    registry's learned rate, and with the ``jump_rates`` mixture; the best of them is
    the best hazard found.

For the oracle it also counts, per segment, the frames after the jump until the first
right answer and until the answer is right for good (to the end of the segment), as
medians per dataset. Ground truth and the shuffle's jump times are read here, for the
bound only: the registry's method never sees them.

Run from the repository root::

    python benchmarks/bench_filter_oracle.py [--datasets nordland,uji] [--seeds 0,1,2,3,4]
        [--rates 0.005,0.01,0.02,0.05,0.1,0.2] [--out DIR]

Writes ``filter_oracle.md`` and ``filter_oracle.json`` under ``--out`` (default
``benchmarks/results``).
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
from datasets import prepared_datasets  # noqa: E402

import catgraph.grid as grid  # noqa: E402
from catgraph.conditions import Condition  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SHORT = (0.005, 0.03)
_REGISTERED = grid.GridLocalizer


def jump_frames(condition: Condition, n: int) -> np.ndarray:
    """Processing frames that start a new segment (the first frame excluded)."""
    order = condition.order(n)
    return np.flatnonzero(np.diff(order) != 1) + 1


class OracleGrid(_REGISTERED):
    """The registry's grid filter, re-seeded uniform over places at every frame of
    ``jumps`` (processing frames) before that frame's prediction."""

    jumps: frozenset = frozenset()
    keep_velocity: bool = False

    def step(self, observation, odometry=None):
        if self.n_steps_ > 0 and self.n_steps_ in self.jumps:
            self._reseed()
        return super().step(observation, odometry)

    def _reseed(self) -> None:
        n = self.graph.n_places
        velocity = self._velocity if self.keep_velocity else self._velocity_prior
        velocity = velocity / velocity.sum()
        for b, p in enumerate(velocity / n):
            self._state[b] = p
        self._like = self._ones
        self._summed = None
        self._velocity = velocity.copy()
        self.prior_ = self._state.sum(0, dtype=np.float64)
        self._mass = self.prior_.copy()


def _factory(base, **fixed):
    class Configured(base):
        def __init__(self, *args, **kwargs):
            kwargs.update(fixed)
            super().__init__(*args, **kwargs)

    return Configured


def run(prepared, cls) -> tuple[dict, np.ndarray]:
    grid.GridLocalizer = cls  # methods.make_filter imports it at call time
    try:
        result = run_method("filter", {"mode": "grid"}, prepared)
    finally:
        grid.GridLocalizer = _REGISTERED
    ev = result.evaluate(prepared.ground_truth)
    m = ev.metrics.as_dict()
    return {"auc": float(m["auc"]), "recall_at_100p": float(m["recall_at_100p"]),
            "accuracy": float(np.mean(ev.correct))}, np.asarray(ev.correct, dtype=bool)


def settle(correct: np.ndarray, jumps: np.ndarray) -> tuple[list, list]:
    """Per segment: frames after its start to the first right answer, and to the start
    of the right answers that last to the segment's end (``None``: never)."""
    starts = np.r_[0, jumps]
    stops = np.r_[jumps, len(correct)]
    first, held = [], []
    for a, b in zip(starts, stops):
        c = correct[a:b]
        hit = np.flatnonzero(c)
        first.append(int(hit[0]) if len(hit) else None)
        miss = np.flatnonzero(~c)
        held.append(0 if not len(miss) else (int(miss[-1]) + 1 if miss[-1] + 1 < len(c) else None))
    return first, held


def configurations(rates) -> dict:
    out = {"registry (learned ε)": _REGISTERED,
           "oracle": None, "oracle, velocity kept": None, "oracle, no jumps": None,
           "oracle, no jumps, velocity kept": None,
           "jump_rates (0.1, 0.01, 0.001, 0.0001)": _factory(_REGISTERED, jump_rates=(0.1, 0.01, 0.001, 0.0001)),
           "jump_rates (0.2, 0.1, 0.05, 0.02)": _factory(_REGISTERED, jump_rates=(0.2, 0.1, 0.05, 0.02))}
    for r in rates:
        out[f"fixed ε = {r:g}"] = _factory(_REGISTERED, recovery=r, learn_recovery=False)
    return out


def _oracle(name: str, jumps: np.ndarray):
    kw = {}
    if "no jumps" in name:
        kw = {"recovery": 0.0, "learn_recovery": False}
    cls = _factory(OracleGrid, **kw)
    cls.jumps = frozenset(int(j) for j in jumps)
    cls.keep_velocity = "velocity kept" in name
    return cls


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default="nordland,uji")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--rates", default="0.005,0.01,0.02,0.05,0.1,0.2")
    ap.add_argument("--only", default="", help="comma-separated configuration names (default: all)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = configurations(rates)
    if args.only:
        keep = set(args.only.split(";"))
        configs = {k: v for k, v in configs.items() if k in keep}
    rows = []
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for ds, cases in prepared_datasets(args.datasets.split(",")).items():
        for seed in seeds:
            condition = Condition("shuffle", seed=seed, segment_range=SHORT)
            prepared = [c.under(condition) for c in cases]
            for name, cls in configs.items():
                each, first, held = [], [], []
                for p in prepared:
                    jumps = jump_frames(condition, len(p.query))
                    m, correct = run(p, cls if cls is not None else _oracle(name, jumps))
                    each.append(m)
                    f, h = settle(correct, jumps)
                    first += f
                    held += h
                cell = {"dataset": ds, "seed": seed, "config": name,
                        **{k: float(np.mean([m[k] for m in each])) for k in each[0]},
                        "auc_each": [m["auc"] for m in each], "first_right": first, "right_for_good": held}
                rows.append(cell)
                print(f"{ds:10s} seed {seed} {name:40s} AUC {cell['auc']:.4f} acc {cell['accuracy']:.4f} "
                      f"R@100P {cell['recall_at_100p']:.2f} {time.strftime('%X')}", flush=True)
                (out / "filter_oracle.json").write_text(json.dumps(
                    {"machine": platform.platform(), "rows": rows}, indent=1))
    (out / "filter_oracle.md").write_text(markdown(rows))


def _median(values) -> str:
    got = [v for v in values if v is not None]
    never = len(values) - len(got)
    return f"{np.median(got):.0f}" + (f" ({never} of {len(values)} never)" if never else "")


def markdown(rows) -> str:
    parts = ["# The grid filter on the 0.5–3 % shuffles: an oracle told every jump, and the best hazard\n\n",
             "Generated by `benchmarks/bench_filter_oracle.py` (module docstring: what each row is). AUC / "
             "accuracy / R@100P per seed; UJI: means over months 02–06. `first right`, `right for good`: frames "
             "after a segment's start (median over all segments of the five seeds; `never`: segments where it "
             "does not happen).\n"]
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        group = [r for r in rows if r["dataset"] == ds]
        seeds = list(dict.fromkeys(r["seed"] for r in group))
        head = " | ".join(f"seed {s}" for s in seeds)
        parts.append(f"\n## {ds}\n\n| configuration | {head} | mean AUC | first right | right for good |\n"
                     f"|---|{'---|' * len(seeds)}---|---|---|\n")
        for name in dict.fromkeys(r["config"] for r in group):
            cells = {r["seed"]: r for r in group if r["config"] == name}
            vals = " | ".join(f"{cells[s]['auc']:.3f} / {cells[s]['accuracy']:.3f} / {cells[s]['recall_at_100p']:.2f}"
                              if s in cells else "" for s in seeds)
            first = sum((cells[s]["first_right"] for s in cells), [])
            held = sum((cells[s]["right_for_good"] for s in cells), [])
            mean = np.mean([cells[s]["auc"] for s in cells])
            parts.append(f"| {name} | {vals} | {mean:.3f} | {_median(first)} | {_median(held)} |\n")
    return "".join(parts)


if __name__ == "__main__":
    main()
