"""Diagnosis: what the long fixed window keeps on Nordland's hard stretch, and the rigid line.

The registry's ``filter + combined`` loses Nordland reversed's hard stretch (processing
frames 765–837, query frames 2,810–2,738) where the fixed window L = 500 holds it. This
script reads, frame by frame, what the grid filter held there (the mass near the truth,
the velocity marginal, the adaptive window's length, each part's ratio at the truth),
which changes of the motion model hold the stretch, and how the rigid line
(``GridLocalizer(rigid_prior=0.05)``) holds it and what it costs on a shuffled query
(``docs/particle_filter.md``, eleventh round). Ground truth is read for the diagnosis
only. Prints tables; writes nothing. Run from the repository root::

    python benchmarks/diagnose_filter_rigid.py stretch    # reversed, frames 700-850, registry
    python benchmarks/diagnose_filter_rigid.py settings   # motion settings on the stretch
    python benchmarks/diagnose_filter_rigid.py leads      # the rigid line's log-odds: reversed; at each jump of a shuffle
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import prepared_datasets  # noqa: E402

import catgraph.grid as grid  # noqa: E402
from catgraph.conditions import Condition  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402

REGISTERED = grid.GridLocalizer
#: the hard stretch, processing frames (eighth round)
STRETCH = {"in order": (2817, 2868), "reversed": (765, 838)}
CONDITIONS = {"in order": Condition(), "reversed": Condition("reverse")}


def _with(settings: dict, log: dict | None = None):
    """The registry's grid filter with ``settings``; ``log``: per frame, the mass within
    ±2 places of ``log["truth"]``, the velocity marginal, the rigid line's weight, and
    the combined model's parts (their ratios, the window length)."""

    class Variant(REGISTERED):
        def __init__(self, *args, **kwargs):
            kwargs.update(settings)
            super().__init__(*args, **kwargs)

        def step(self, observation, odometry=None):
            if log is not None and not log.get("wrapped") and hasattr(self.model, "models"):
                log["wrapped"] = True
                for i, part in enumerate(self.model.models):
                    def observe(row, _observe=part.observe, i=i, part=part):
                        o = _observe(row)
                        t = int(log["truth"][len(log[f"part{i}"])])
                        r = np.asarray(o.log_ratio)
                        log[f"part{i}"].append((float(r[max(0, t - 2):t + 3].max() - r.max()),
                                                float(r[max(0, t - 2):t + 3].max() - np.median(r))))
                        if hasattr(part, "last_match_"):
                            log["window"].append(int(part.last_match_.window_length))
                        return o
                    part.observe = observe
            est = super().step(observation, odometry)
            if log is not None:
                t = int(log["truth"][self.n_steps_ - 1])
                log["near"].append(float(self.place_posterior_[max(0, t - 2):t + 3].sum()))
                log["velocity"].append(np.asarray(self.state_.sum(0)))
                log["rigid"].append(float(self.rate_weights_[1]) if self.rigid_prior > 0 else np.nan)
            return est

    return Variant


def run(q, settings=None, model="combined", record=False):
    log = None
    if record:
        log = {"truth": np.asarray(q.query.index), "near": [], "velocity": [], "rigid": [], "part0": [],
               "part1": [], "window": []}
    grid.GridLocalizer = _with(settings or {}, log)
    try:
        r = run_method("filter", {"mode": "grid"} | ({"model": model} if model != "default" else {}), q)
    finally:
        grid.GridLocalizer = REGISTERED
    return r, r.evaluate(q.ground_truth), log


def stretch() -> None:
    p = prepared_datasets(["nordland"])["Nordland"][0]
    q = p.under(CONDITIONS["reversed"])
    r, ev, log = run(q, record=True)
    qi = np.asarray(q.query.index)
    lo, hi = STRETCH["reversed"]
    inside, before = np.arange(lo, hi), np.arange(1000, 2000)
    window = np.asarray(log["window"])
    img, seq = np.asarray(log["part0"]), np.asarray(log["part1"])
    print(f"registry filter + combined, Nordland reversed: AUC {ev.metrics.auc:.4f}, wrong {(~ev.correct).sum()}, "
          f"wrong in {lo}–{hi - 1}: {(~ev.correct[lo:hi]).sum()}\n")
    print("| processing frame | query frame | answer − truth | mass within ±2 of the truth | velocity −1 / −0.5 / +0.5 |"
          "\n|---|---|---|---|---|")
    v = list(REGISTERED(None, None).velocities)
    for k in range(700, 850, 8):
        vel = log["velocity"][k]
        print(f"| {k} | {qi[k]} | {int(r.match[k]) - int(qi[k])} | {log['near'][k]:.3f} | "
              f"{vel[v.index(-1.0)]:.2f} / {vel[v.index(-0.5)]:.2f} / {vel[v.index(0.5)]:.2f} |")
    print(f"\nadaptive window in the stretch: median {np.median(window[inside]):.0f} (frames 1000–1999: "
          f"{np.median(window[before]):.0f})")
    print(f"sequence part at the truth above its median: stretch {np.median(seq[inside, 1]):.4f}, frames 1000–1999 "
          f"{np.median(seq[before, 1]):.4f} nats; the truth below the part's best, summed over the stretch: "
          f"{-seq[inside, 0].sum():.2f} nats")
    print(f"whole-image part: the truth below its best, summed over the stretch {-img[inside, 0].sum():.1f} nats "
          f"(median {-np.median(img[inside, 0]):.2f})")


SETTINGS = {
    "registry": {},
    "velocities (−1) only": {"velocities": (-1.0,)},
    "velocities (−1) only, blur 0": {"velocities": (-1.0,), "blur": 0.0},
    "negative velocities only": {"velocities": (-3.0, -2.0, -1.0, -0.5)},
    "jump rate fixed at 1e-8": {"recovery": 1e-8, "learn_recovery": False},
    "velocities (−1) only, blur 0, jump rate 1e-6": {"velocities": (-1.0,), "blur": 0.0, "recovery": 1e-6,
                                                     "learn_recovery": False},
    "velocities (−1) only, blur 0, jump rate 1e-12": {"velocities": (-1.0,), "blur": 0.0, "recovery": 1e-12,
                                                      "learn_recovery": False},
    "rigid line, prior 0.05 (rigid_prior)": {"rigid_prior": 0.05},
}


def settings() -> None:
    p = prepared_datasets(["nordland"])["Nordland"][0]
    q = p.under(CONDITIONS["reversed"])
    lo, hi = STRETCH["reversed"]
    print("| motion (the velocity sets are diagnosis: the query's velocity is not known to the method) | AUC | wrong | "
          f"wrong in {lo}–{hi - 1} |\n|---|---|---|---|")
    for name, s in SETTINGS.items():
        _, ev, _ = run(q, s)
        print(f"| {name} | {ev.metrics.auc:.4f} | {(~ev.correct).sum()} | {(~ev.correct[lo:hi]).sum()} |", flush=True)


def _log_odds(weights) -> np.ndarray:
    w = np.asarray(weights)
    return np.log(np.maximum(w, 1e-300)) - np.log1p(-np.minimum(w, 1.0 - 1e-16))


def leads() -> None:
    p = prepared_datasets(["nordland"])["Nordland"][0]
    q = p.under(CONDITIONS["reversed"])
    _, ev, log = run(q, {"rigid_prior": 0.05}, record=True)
    odds = _log_odds(log["rigid"])
    print("reversed, rigid line: its log-odds (nats) against the filter's own motion, every 10 frames 600–850:")
    print(" ".join(f"{k}:{odds[k]:.1f}" for k in range(600, 860, 10)))
    for seed in (3, 4):
        q = p.under(Condition("shuffle", seed=seed))
        _, ev, log = run(q, {"rigid_prior": 0.05}, record=True)
        _, ev0, _ = run(q)
        odds = _log_odds(log["rigid"])
        qi = np.asarray(q.query.index)
        jumps = np.flatnonzero(np.abs(np.diff(qi)) != 1) + 1
        print(f"\nshuffled 2–20 % seed {seed}: AUC {ev0.metrics.auc:.4f} → {ev.metrics.auc:.4f}\n"
              "| jump at (processing frame) | rigid line's log-odds before it | wrong in the 60 frames after: "
              "registry / rigid line |\n|---|---|---|")
        for j in jumps:
            print(f"| {j} | {odds[j - 1]:.1f} | {(~ev0.correct[j:j + 60]).sum()} / {(~ev.correct[j:j + 60]).sum()} |")


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "stretch"
    {"stretch": stretch, "settings": settings, "leads": leads}[what]()
