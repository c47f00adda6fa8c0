"""Diagnosis: leaving the rigid line sooner after a jump, and a finer front-end (measured, not adopted).

The registry's grid filter holds a rigid line beside its motion (``GridLocalizer(rigid_prior)``,
``docs/particle_filter.md``, "The rigid line by default"). After hundreds of frames in order the
rigid line holds all the weight (its log-odds grow without bound), so after the query's first
jump the answer stays on the old line until the frames have spent that lead. This script
measures, on Nordland 32×16 in every traversal condition (±2 frames; the registry's ``filter``
method, nothing else set), variants of the filter that cap or share that lead, each applied
to the committed code for the run only (a patch of ``GridLocalizer``, undone afterwards):

* ``share rate``: fixed share between the two motion models — before each step a share ``s``
  of the weights returns to their prior, ``w ← (1 − s) w + s π``, with ``s`` the filter's own
  learned jump rate (a query that jumps often also changes its motion often);
* ``share 1e-6``, ``share 1e-8``: the same with a constant share;
* ``run own``: the rigid line as a model of the run between two jumps — both components jump,
  at the filter's learned rate, and every jump's mass lands in each component by its prior
  (the hazard mixture's scope ``"run"``);
* ``run tiny``: the same, the rigid line itself never jumping (``RIGID_JUMP_RATE``) but every
  jump's mass landing in it by its prior, so that a rigid line can start again after a jump;
* ``confidence mean``: the filter unchanged, its confidence the mean of the two components'
  log-odds (the tracker's lead of ``docs/sequence.md``, "a rigid line beside the tracker");
* ``64x32``: the filter unchanged, the front-end at 64 × 32 pixels with 8-pixel patches
  (Nordland's ``64x32`` folder) instead of 32 × 16 with 4.

Writes ``benchmarks/results/rigid_exit.md`` and ``rigid_exit.json``. Run from the repository
root (about a minute and a half a variant on 2 cores; the whole run took about 10 minutes)::

    python benchmarks/diagnose_rigid_exit.py [--variants NAME,...]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import catgraph.grid as G  # noqa: E402
from catgraph.conditions import condition_table  # noqa: E402
from catgraph.experiment import Experiment, run_method  # noqa: E402
from catgraph.localizer import confidence_log_odds  # noqa: E402
from datasets import DATA, NORDLAND_FRAMES, prepare_kept  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def _shared_step(share):
    """``GridLocalizer._rigid_step`` with fixed share ``share`` (a float, or ``"rate"``)."""
    original = G.GridLocalizer._rigid_step

    def step(self, odometry, ratio):
        if self.n_steps_ > 0:
            s = float(self._rates[0]) if share == "rate" else float(share)
            w = (1.0 - s) * self.rate_weights_ + s * self._rate_prior
            self.rate_weights_ = w / w.sum()
        return original(self, odometry, ratio)

    return step


def _run_step(rigid_jumps: bool):
    """``GridLocalizer._rigid_step`` as a run model: each component's jump mass pooled and
    landing in every component by its prior (``_hazard_step``'s scope ``"run"``, with each
    component's own motion); the rigid line jumping at the learned rate or never."""

    def step(self, odometry, ratio):
        w, pi = self.rate_weights_, self._rate_prior
        rates = self._rates.copy()
        if rigid_jumps:
            rates[1] = rates[0]
        if self.n_steps_ > 0:
            jump = float(w @ rates)
            predicted = w * (1.0 - rates) + pi * jump
            share = pi * jump / predicted
        else:
            predicted, share = w.copy(), np.zeros(len(w))
        velocity = self._velocity  # the mixture's: every component's jump lands with it
        totals, means = self._step_components(odometry, ratio, velocity, share)
        components = self._components
        n = self.graph.n_places
        self.prior_ = G._weighted_sum(predicted, [c["prior_"] for c in components], self._pool.take(n))
        evidence = predicted * totals
        total = float(evidence.sum())
        current = float(w @ rates)
        self.recovery_ = current
        if ratio is None or not total > 0.0:
            self.rate_weights_ = predicted / predicted.sum()
            self._mass = G._weighted_sum(self.rate_weights_, [c["_mass"] for c in components], self._pool.take(n))
            self._velocity = velocity
            return
        if self.n_steps_ > 0 and self.learn_recovery and self.recovery > 0.0 and current > 0.0:
            # the E-step: the mixture's posterior share of the jump mass
            landed = float(np.sum(predicted * share * means)) / total
            jumps, frames, self._rates[0] = G.learn_jump_rate(*self._rigid_jumps, float(self.recovery), current,
                                                              landed / current)
            self._rigid_jumps = (jumps, frames)
        self.rate_weights_ = evidence / total
        self._mass = G._weighted_sum(self.rate_weights_, [c["_mass"] for c in components], self._pool.take(n))
        self._velocity = G._weighted_sum(self.rate_weights_, [c["_velocity"] for c in components],
                                         np.empty(len(self._owner)))
        self._new_place(math.log(total) + ratio[1], ratio[2])

    return step


def _mean_confidence():
    """``GridLocalizer._summarise`` whose log-odds (and score) are the mean of the two
    components' log-odds at the same answer."""
    original = G.GridLocalizer._summarise

    def summarise(self):
        estimate, near = original(self)
        if self._components is None or self._motions is None:
            return estimate, near
        odds = [confidence_log_odds(*G._inside_outside(c["_mass"], near), self._log_map, self._log_new)[1]
                for c in self._components]
        mean = 0.5 * (odds[0] + odds[1])
        return replace(estimate, log_odds=mean, score=mean + (estimate.score - estimate.log_odds)), near

    return summarise


VARIANTS = {
    "registry default": {},
    "share rate": {"_rigid_step": lambda: _shared_step("rate")},
    "share 1e-6": {"_rigid_step": lambda: _shared_step(1e-6)},
    "share 1e-8": {"_rigid_step": lambda: _shared_step(1e-8)},
    "run own": {"_rigid_step": lambda: _run_step(True)},
    "run tiny": {"_rigid_step": lambda: _run_step(False)},
    "confidence mean": {"_summarise": _mean_confidence},
    "64x32": {},
}


@contextmanager
def _patched(name: str):
    saved = {}
    try:
        for attr, make in VARIANTS[name].items():
            saved[attr] = getattr(G.GridLocalizer, attr)
            setattr(G.GridLocalizer, attr, make())
        yield
    finally:
        for attr, value in saved.items():
            setattr(G.GridLocalizer, attr, value)


def _prepared(size: str):
    d = DATA / "nordland" / size
    patch = 8 if size == "64x32" else 4
    return prepare_kept(Experiment(query=d / "winter", reference=d / "summer", tolerance=NORDLAND_FRAMES,
                                   frontend={"size": size, "patch": patch}))


def measure(names) -> dict:
    base = {}
    out = {}
    for name in names:
        size = "64x32" if name == "64x32" else "32x16"
        if size not in base:
            base[size] = _prepared(size)
        rows = []
        with _patched(name):
            for condition in condition_table():
                p = base[size].under(condition) if condition.kind != "in-order" else base[size]
                m = run_method("filter", {}, p).evaluate(p.ground_truth).metrics
                rows.append({"condition": condition.label, "auc": m.auc, "recall_at_100p": m.recall_at_100p,
                             "mtl": m.mtl, "accuracy": m.accuracy})
                print(f"{name:18s} {condition.label:28s} AUC {m.auc:.4f} R@100P {m.recall_at_100p:.3f} MTL {m.mtl}",
                      flush=True)
        out[name] = rows
    return out


def markdown(table: dict, commit: str) -> str:
    names = list(table)
    labels = [r["condition"] for r in table[names[0]]]
    lines = ["# Leaving the rigid line sooner, and a finer front-end (Nordland; measured, not adopted)", "",
             f"Generated by `benchmarks/diagnose_rigid_exit.py` at `{commit}` ({platform.machine()}, "
             f"{time.strftime('%Y-%m-%d')}): the registry's `filter` method on Nordland (±2 frames) in every "
             "traversal condition, each variant a patch of the committed filter for its run (the script's "
             "docstring). Cells: AUC / R@100P / MTL.", "",
             "| condition | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for i, label in enumerate(labels):
        cells = [f"{table[n][i]['auc']:.3f} / {table[n][i]['recall_at_100p']:.2f} / {table[n][i]['mtl']}"
                 for n in names]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    base = table[names[0]]
    lines += ["", f"Against `{names[0]}` (AUC):", "",
              "| variant | mean change | largest gain | largest fall | cells down by more than 0.005 | "
              "2–20 % R@100P per seed |", "|---|---|---|---|---|---|"]
    for n in names:
        d = np.array([r["auc"] - b["auc"] for r, b in zip(table[n], base)])
        worst = int(np.argmin(d))
        best = int(np.argmax(d))
        r100 = " / ".join(f"{r['recall_at_100p']:.2f}" for r in table[n] if r["condition"].startswith("shuffled 2"))
        lines.append(f"| {n} | {d.mean():+.4f} | {d[best]:+.4f} ({labels[best]}) | {d[worst]:+.4f} ({labels[worst]}) "
                     f"| {int(np.sum(d < -0.005))} | {r100} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, from {list(VARIANTS)}")
    args = ap.parse_args()
    names = [n.strip() for n in args.variants.split(",")]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    if not (DATA / "nordland").is_dir():
        raise SystemExit(f"Nordland is not at {DATA / 'nordland'}: this diagnosis needs it")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip() or "unknown"
    table = measure(names)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "rigid_exit.json").write_text(json.dumps({"commit": commit, "machine": platform.platform(),
                                                         "variants": table}, indent=1))
    (RESULTS / "rigid_exit.md").write_text(markdown(table, commit))


if __name__ == "__main__":
    main()
