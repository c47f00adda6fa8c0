"""Diagnosis: where the long fixed windows beat the combined filter, frame by frame.

Reads the ground truth (diagnosis only: the methods never see it) to find, on Nordland
in order and reversed and on UJI months 02–06 in order and reversed, which frames the
registry's ``filter + combined`` answers wrong where the ``sequence`` method at L = 500
answers right, how the confidences rank them, what the grid filter's posterior held on
the hard stretch, and what each setting of the filter does to it
(``docs/particle_filter.md``, "Eighth round"). Prints tables; writes nothing. Run from
the repository root::

    python benchmarks/diagnose_filter_misses.py ranks      # AUC, accuracy, wrong frames, best-ranked wrong
    python benchmarks/diagnose_filter_misses.py uji        # UJI's wrong frames: start-up / point change / other
    python benchmarks/diagnose_filter_misses.py posterior  # Nordland reversed, frames 700-850 of the grid filter
    python benchmarks/diagnose_filter_misses.py settings   # the filter's settings on Nordland's hard stretch
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import rankdata

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import prepared_datasets  # noqa: E402

from catgraph import methods  # noqa: E402
from catgraph.conditions import Condition  # noqa: E402
from catgraph.experiment import run_method  # noqa: E402
from catgraph.grid import GridLocalizer  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402
from catgraph.observation import TemperedObservation  # noqa: E402

CONDITIONS = {"in order": Condition(), "reversed": Condition("reverse")}
RUNS = {"combined": ("filter", {"model": "combined"}), "filter (default)": ("filter", {}),
        "fixed L=500": ("sequence", {"window": 500}), "fixed L=200": ("sequence", {"window": 200})}
#: the hard stretch of Nordland (processing frames) where the combined model loses the track
STRETCH = {"in order": (2817, 2868), "reversed": (765, 838)}


def _run(prepared, method, params):
    r = run_method(method, params, prepared)
    ev = r.evaluate(prepared.ground_truth)
    return r, ev


def _start_up(correct: np.ndarray, run: int = 30) -> int:
    """The frames before the first run of ``run`` correct answers."""
    held = 0
    for i, ok in enumerate(correct):
        held = held + 1 if ok else 0
        if held >= run:
            return i - run + 1
    return len(correct)


def ranks() -> None:
    print("| cell | method | AUC | accuracy | wrong frames | best-ranked wrong frame |\n|---|---|---|---|---|---|")
    for ds, cases in prepared_datasets(["nordland", "uji"]).items():
        for cn, c in CONDITIONS.items():
            for k, p in enumerate(cases):
                q = p.under(c)
                for label, (m, params) in RUNS.items():
                    r, ev = _run(q, m, params)
                    wrong = ~ev.correct
                    rank = rankdata(-r.confidence) / len(wrong)
                    best = f"{rank[wrong].min():.3f}" if wrong.any() else "—"
                    print(f"| {ds} {k if len(cases) > 1 else ''} {cn} | {label} | {ev.metrics.auc:.4f} | "
                          f"{ev.correct.mean():.4f} | {wrong.sum()} | {best} |", flush=True)


def uji() -> None:
    print("| cell | month | method | AUC | wrong: start-up (ends at) / point change / other |\n|---|---|---|---|---|")
    for cn, c in CONDITIONS.items():
        for k, p in enumerate(prepared_datasets(["uji"])["UJI 02-06"]):
            q = p.under(c)
            pos = np.asarray(q.query.positions)[:, :2]
            same = np.all(pos[1:] == pos[:-1], axis=1)
            boundary = ~np.r_[False, same] | ~np.r_[same, False]  # the first or last scan at its point
            for label in ("combined", "fixed L=500"):
                r, ev = _run(q, *RUNS[label])
                wrong = np.nonzero(~ev.correct)[0]
                su = _start_up(ev.correct)
                late = wrong[wrong >= su]
                other = [int(i) for i in late if not boundary[i]]
                print(f"| {cn} | 0{k + 2} | {label} | {ev.metrics.auc:.3f} | {(wrong < su).sum()} ({su}) / "
                      f"{boundary[late].sum()} / {len(other)} {other[:8] if other else ''} |", flush=True)


def _combined_filter(q, scale: float | None = None, **grid):
    params = methods.resolve_params("filter", {"model": "combined"})
    obs = methods.observation_model(params, q.map.n_places, q.bootstrap_samples)
    if scale is not None:
        obs.models[0] = TemperedObservation(temperature_scale=scale)
    return GridLocalizer(q.graph(), obs, **grid)


def posterior(lo: int = 700, hi: int = 850, every: int = 4) -> None:
    q = prepared_datasets(["nordland"])["Nordland"][0].under(CONDITIONS["reversed"])
    loc = _combined_filter(q)
    loc.reset()
    gt, qi, n_places = q.ground_truth, q.query.index, q.graph().n_places
    velocities = list(loc.velocities)
    print("| frame | answer − truth | log-odds | ε | mass ±2 of the truth | ±50 | truth's rank in the frame | "
          "velocity marginal " + str(velocities) + " |\n|---|---|---|---|---|---|---|---|")
    for k in range(hi):
        est = loc.step(q.differences[k])
        if k < lo or (k - lo) % every:
            continue
        ok = gt.correct(np.full(n_places, qi[k]), np.arange(n_places))
        centre = int(np.median(np.nonzero(ok)[0]))
        post = loc.place_posterior_
        e = loc._e  # the frame's e^{r − top}
        print(f"| {k} | {est.place - qi[k]} | {est.log_odds:.2f} | {loc.recovery_:.4f} | {post[ok].sum():.3f} | "
              f"{post[max(0, centre - 50):centre + 51].sum():.3f} | {int((e > e[ok].max()).sum())} | "
              f"{np.round(loc.state_.sum(0), 2).tolist()} |", flush=True)


def settings() -> None:
    p = prepared_datasets(["nordland"])["Nordland"][0]
    variants = {"none (registry)": ({}, None),
                "jump rate fixed at 0.001": ({"recovery": 0.001, "learn_recovery": False}, None),
                "jump rate fixed at 0.0001": ({"recovery": 0.0001, "learn_recovery": False}, None),
                "whole-image temperature halved (scale 2)": ({}, 2.0),
                "blur 0": ({"blur": 0.0}, None),
                "velocity_stay 0.999": ({"velocity_stay": 0.999}, None)}
    print("| change | " + " | ".join(f"{cn}: AUC / wrong in {STRETCH[cn][0]}–{STRETCH[cn][1] - 1}" for cn in CONDITIONS)
          + " |\n|---|---|---|")
    for label, (grid, scale) in variants.items():
        cells = []
        for cn, c in CONDITIONS.items():
            q = p.under(c)
            r = _combined_filter(q, scale, **grid).run(q.differences, query_index=q.query.index)
            ev = evaluate(q.query.index, r.place, r.score, q.ground_truth)
            lo, hi = STRETCH[cn]
            cells.append(f"{ev.metrics.auc:.4f} / {(~ev.correct[lo:hi]).sum()}")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "ranks"
    {"ranks": ranks, "uji": uji, "posterior": posterior, "settings": settings}[what]()
