"""Benchmark: candidate changes to the grid filter's jump model, before → after, every cell.

Each candidate is a subclass of :class:`catgraph.grid.GridLocalizer` defined here (a
prototype: the library is changed only once a candidate has passed). The registry's
``filter`` method runs exactly as a user gets it — the default model (``filter
(default)``) and the combined model (``filter + combined``) — once as registered and once
with the candidate's grid filter, on the condition table of Nordland, UJI 02–06 and the
synthetic world and on the held-out worlds (``bench_generalisation.py``'s six, its five
quick conditions).

Candidates:

``jump-velocity-mean``
    A jump lands with the query's *long-run* velocity distribution: a discounted mean of
    the filter's posterior velocity marginal (half-life ``RECOVERY_MEMORY`` frames, the
    uniform prior worth ``RECOVERY_PRIOR_FRAMES`` frames: the jump rate's own constants)
    instead of half the current marginal and half uniform. A shuffled query keeps its
    speed across a jump (the oracle that keeps the velocity gains 0.02 on Nordland and
    0.09 on UJI, ``filter_oracle.md``), and a query whose speed varies along the route
    spreads the mean over the speeds it drives at.

``jump-velocity-mean-half``
    Half that long-run distribution, half uniform (the registry's mix, the long-run mean
    in place of the current marginal).

Run from the repository root::

    python benchmarks/bench_filter_candidates.py CANDIDATE [--quick] [--datasets nordland,uji,synthetic,heldout]
        [--models default,combined] [--out DIR]

Writes ``filter_candidate_<name>.md|json`` under ``--out`` (default ``benchmarks/results``).
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
from bench_filter_hazard import MODELS, _cases, before_after_tables  # noqa: E402
from datasets import benchmark_conditions  # noqa: E402

import catgraph.grid as grid  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
_REGISTERED = grid.GridLocalizer


class JumpVelocityMean(_REGISTERED):
    """A jump lands with the query's long-run velocity distribution (module docstring)."""

    def reset(self):
        super().reset()
        self._velocity_sum = np.zeros(len(self._velocity_prior))
        self._velocity_frames = 0.0
        return self

    def _jump_velocity(self) -> np.ndarray:
        decay = 0.5 ** (1.0 / grid.RECOVERY_MEMORY)
        self._velocity_sum = decay * self._velocity_sum + self._velocity
        self._velocity_frames = decay * self._velocity_frames + 1.0
        prior = grid.RECOVERY_PRIOR_FRAMES
        return (self._velocity_sum + prior * self._velocity_prior) / (self._velocity_frames + prior)


class JumpVelocityMeanHalf(JumpVelocityMean):
    """Half the long-run velocity distribution, half uniform (the registry's mix, with the
    long-run mean in place of the current marginal)."""

    def _jump_velocity(self) -> np.ndarray:
        return 0.5 * super()._jump_velocity() + 0.5 * self._velocity_prior


CANDIDATES = {"jump-velocity-mean": JumpVelocityMean, "jump-velocity-mean-half": JumpVelocityMeanHalf}


def _run(params, prepared, cls):
    grid.GridLocalizer = cls  # methods.make_filter imports it at call time
    try:
        result = run_method("filter", dict(params, mode="grid"), prepared)
    finally:
        grid.GridLocalizer = _REGISTERED
    m = result.evaluate(prepared.ground_truth).metrics.as_dict()
    return float(m["auc"]), float(m["recall_at_100p"]), float(m["mtl"]), result.seconds


def conditions(args) -> list[dict]:
    cls = CANDIDATES[args.candidate]
    rows = []
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"filter_candidate_{args.candidate}"
    for ds, (cases, own) in _cases(args.datasets.split(",")).items():
        for condition in own or benchmark_conditions(args.quick):
            prepared = [c.under(condition) if condition.kind != "in-order" else c for c in cases]
            for key in args.models.split(","):
                label, params = MODELS[key]
                cell = {"dataset": ds, "condition": condition.label, "condition_spec": condition.as_dict(),
                        "method": label}
                for name, c in (("before", _REGISTERED), ("after", cls)):
                    runs = [_run(params, p, c) for p in prepared]
                    cell[name] = {"auc": float(np.mean([x[0] for x in runs])),
                                  "recall_at_100p": float(np.mean([x[1] for x in runs])),
                                  "mtl": float(np.mean([x[2] for x in runs])),
                                  "seconds": float(sum(x[3] for x in runs)),
                                  "auc_each": [x[0] for x in runs]}
                rows.append(cell)
                print(f"{ds:20s} {condition.label:28s} {label:18s} {cell['before']['auc']:.4f} -> "
                      f"{cell['after']['auc']:.4f} ({cell['after']['auc'] - cell['before']['auc']:+.4f}) "
                      f"{time.strftime('%X')}", flush=True)
                (out / f"{stem}.json").write_text(json.dumps(
                    {"machine": platform.platform(), "candidate": args.candidate, "rows": rows}, indent=1))
    (out / f"{stem}.md").write_text(markdown(rows, args.candidate))
    return rows


def markdown(rows, candidate) -> str:
    header = (f"# Grid filter candidate `{candidate}`\n\n"
              "Generated by `benchmarks/bench_filter_candidates.py` (module docstring: the candidate). Each cell: "
              "AUC / R@100P before (the registry's filter) → after (the same method with the candidate's grid "
              "filter); UJI: means over months 02–06. Held-out worlds: `bench_generalisation.py`'s, quick "
              "conditions.\n")
    return header + before_after_tables(rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("candidate", choices=tuple(CANDIDATES))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--datasets", default="nordland,uji,synthetic,heldout")
    ap.add_argument("--models", default="default,combined")
    ap.add_argument("--out", default=str(RESULTS))
    conditions(ap.parse_args(argv))


if __name__ == "__main__":
    main()
