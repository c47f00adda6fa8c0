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

``rigid-line``
    Bayesian model averaging over two motion models (one posterior over (place, velocity)
    each, weighted by its evidence frame by frame, as ``jump_rates`` with scope
    ``"query"``): the registry's (``velocity_stay``, ``blur``, the learned jump rate) and
    a *rigid line* — the velocity never changes (``velocity_stay`` 1), no blur, a jump
    rate of ``RIGID_JUMP_RATE`` (1e-12) — with prior weight ``RIGID_PRIOR`` (0.05): the
    prior probability that the query is one unbroken line driven at one speed, which is
    what a long fixed window assumes. A query that jumps or changes speed refutes the
    rigid component within a few frames of doing so and the registry's carries on; a
    query that does neither hands it the weight, and a jump then costs ``log(N / 1e-12)``
    nats and a speed change more, so a hard stretch no longer moves the answer
    (``docs/particle_filter.md``, eleventh round). The library has it as an option,
    ``GridLocalizer(rigid_prior=0.05)`` (the same answers and scores, bit for bit).

``home-speed``
    A velocity prior with odds ``methods.HOME_SPEED_ODDS`` (3) on the reference's own
    speed, one place per frame forwards or backwards, against each other velocity, where the
    registry's was uniform: the start-up and every jump's landing read it. Now the registry's default
    (``methods.HOME_SPEED_ODDS``, ``GridLocalizer(home_speed_odds=...)``); the candidate's
    "before" is the same filter with a uniform prior (``home_speed_odds=1``), so the table
    is reproduced as it was measured.

Run from the repository root::

    python benchmarks/bench_filter_candidates.py CANDIDATE [--quick] [--datasets nordland,uji,synthetic,heldout]
        [--models default,combined] [--out DIR]

Writes ``filter_candidate_<name>.md|json`` under ``--out`` (default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import json
import math
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
from catgraph.methods import HOME_SPEED_ODDS  # noqa: E402

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


#: The rigid line's jump rate and prior weight (``rigid-line``).
RIGID_JUMP_RATE = 1e-12
RIGID_PRIOR = 0.05


class RigidLine(_REGISTERED):
    """Bayesian model averaging over the registry's motion model and a rigid line (module
    docstring): the ``jump_rates`` machinery's components, each with its own velocity
    transition, blur and jump rate (the registry's learned as the single-rate filter
    learns it)."""

    def __init__(self, *args, **kwargs):
        kwargs["jump_rates"] = (0.5, 0.25)  # two components (their rates are set below)
        kwargs["jump_rate_scope"] = "query"
        super().__init__(*args, **kwargs)

    def reset(self):
        super().reset()
        owner, _, _, _, _, successor = grid.phase_bins(self._v, self.max_phases)
        self._motion = []
        for stay, reverse, blur, rate in ((self.velocity_stay, self.reverse_probability, self.blur, None),
                                          (1.0, 0.0, 0.0, RIGID_JUMP_RATE)):
            t = grid.phase_transition(grid.velocity_transition(self._v, stay, reverse), owner, successor)
            nz = t.T != 0
            sparse = (np.concatenate([[0], np.cumsum(nz.sum(1))]).astype(np.int64), np.nonzero(nz)[1].astype(np.int64),
                      np.ascontiguousarray(t.T[nz], dtype=np.float64))
            self._motion.append({"transition": t, "sparse": sparse, "blur": float(blur), "learned": rate is None,
                                 "rate": float(self.recovery if rate is None else rate), "jumps": 0.0, "frames": 0.0})
        self.rate_weights_ = np.array([1.0 - RIGID_PRIOR, RIGID_PRIOR])
        self._own_motion = (self.blur, self._transition, self._t_sparse)
        return self

    def _hazard_step(self, odometry, ratio):
        w, velocity = self.rate_weights_, self._velocity
        totals, means = np.zeros(len(w)), np.zeros(len(w))
        for k, (component, m) in enumerate(zip(self._components, self._motion)):
            for f in self._COMPONENT_FIELDS:
                setattr(self, f, component[f])
            self._velocity = velocity  # every component's jump lands with the mixture's velocity
            self.blur, self._transition, self._t_sparse = m["blur"], m["transition"], m["sparse"]
            self.recovery_ = m["rate"]
            self._predict(odometry, ratio)
            if ratio is not None:
                totals[k], means[k] = self._likelihood(ratio[0])
            for f in self._COMPONENT_FIELDS:
                component[f] = getattr(self, f)
        self.blur, self._transition, self._t_sparse = self._own_motion
        self.recovery_ = float(w @ [m["rate"] for m in self._motion])
        self._pool = self._own_pool
        components = self._components
        self.prior_ = grid._weighted_sum(w, [c["prior_"] for c in components], self._pool.take(self.graph.n_places))
        evidence = w * totals
        total = float(evidence.sum())
        if ratio is None or not total > 0.0:
            self._mass = grid._weighted_sum(w, [c["_mass"] for c in components], self._pool.take(self.graph.n_places))
            self._velocity = velocity
            return
        if self.n_steps_ > 0 and self.learn_recovery:
            for k, m in enumerate(self._motion):
                if m["learned"] and totals[k] > 0.0:
                    m["jumps"], m["frames"], m["rate"] = grid.learn_jump_rate(
                        m["jumps"], m["frames"], float(self.recovery), m["rate"], means[k] / totals[k])
        self.rate_weights_ = evidence / total
        self._mass = grid._weighted_sum(self.rate_weights_, [c["_mass"] for c in components],
                                        self._pool.take(self.graph.n_places))
        self._velocity = grid._weighted_sum(self.rate_weights_, [c["_velocity"] for c in components],
                                            np.empty(len(self._owner)))
        self._new_place(math.log(total) + ratio[1], ratio[2])


def _speed_odds(odds: float):
    """The registered grid filter with ``home_speed_odds`` set to ``odds`` whatever the method passes."""

    class SpeedOdds(_REGISTERED):
        def __init__(self, *args, **kwargs):
            kwargs["home_speed_odds"] = odds
            super().__init__(*args, **kwargs)

    return SpeedOdds


#: candidate → its grid filter, or (the "before" filter, the candidate's)
CANDIDATES = {"jump-velocity-mean": JumpVelocityMean, "jump-velocity-mean-half": JumpVelocityMeanHalf,
              "rigid-line": RigidLine, "home-speed": (_speed_odds(1.0), _speed_odds(HOME_SPEED_ODDS))}


def _run(params, prepared, cls):
    grid.GridLocalizer = cls  # methods.make_filter imports it at call time
    try:
        result = run_method("filter", dict(params, mode="grid"), prepared)
    finally:
        grid.GridLocalizer = _REGISTERED
    m = result.evaluate(prepared.ground_truth).metrics.as_dict()
    return float(m["auc"]), float(m["recall_at_100p"]), float(m["mtl"]), result.seconds


def conditions(args) -> list[dict]:
    before, cls = (CANDIDATES[args.candidate] if isinstance(CANDIDATES[args.candidate], tuple)
                   else (_REGISTERED, CANDIDATES[args.candidate]))
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
                for name, c in (("before", before), ("after", cls)):
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
