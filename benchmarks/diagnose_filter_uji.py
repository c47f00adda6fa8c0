"""Diagnosis: which frames the registry's grid filter answers wrong on UJI months 02–06 in order.

Reads the ground truth (diagnosis only: the method never sees it or its tolerance). For each
month runs ``GridLocalizer(graph, TemperedObservation())`` on the registry's map graph frame by
frame and prints, per run of wrong frames: the frames, the truth and the answer (reference
index), the score and its rank in the traverse, the posterior's mass on the places the
tolerance accepts, P(new place), the learned jump rate, the velocity of largest mass, the
temperature and hub weight the model has chosen, and whether the query's position lies
within the tolerance of any reference place at all, and on the floor of the answer
(``docs/particle_filter.md``, "UJI 06 in order"). Prints; writes nothing. Run from the
repository root::

    python benchmarks/diagnose_filter_uji.py            # months 02-06, summary + runs
    python benchmarks/diagnose_filter_uji.py 6          # one month
    python benchmarks/diagnose_filter_uji.py 6 recovery=0.03   # with a grid filter setting changed
    python benchmarks/diagnose_filter_uji.py candidate [RATE [FRAMES [JUMP_VELOCITY]]]  # the start-up jump rate

``candidate`` runs the prototype :class:`StartUpJumps` (a lower jump rate before the
filter first converges) against the defaults on the condition table of Nordland, UJI
02–06 and the synthetic world, and on the held-out worlds of ``bench_generalisation.py``
(all fourteen conditions), with the grid filter's defaults or with ``jump_velocity`` as
given (the registry's ``filter`` method: ``long-run``), and prints per dataset the mean AUC before → after, the cells
that fall by more than 0.005, and the worst and best cell (several minutes).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.stats import rankdata

sys.path.insert(0, str(Path(__file__).resolve().parent))
import datasets as ds  # noqa: E402

from catgraph.grid import RECOVERY_PRIOR_FRAMES, GridLocalizer  # noqa: E402
from catgraph.io import place_graph  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402
from catgraph.observation import TemperedObservation  # noqa: E402
from diagnose_filter_misses import _start_up  # noqa: E402  (one definition of the start-up)


def _runs(idx: np.ndarray) -> list[tuple[int, int]]:
    out = []
    for i in idx:
        if out and i == out[-1][1] + 1:
            out[-1] = (out[-1][0], int(i))
        else:
            out.append((int(i), int(i)))
    return out


def month(case, **grid) -> None:
    graph = place_graph(case.reference)
    obs = TemperedObservation()
    loc = GridLocalizer(graph, obs, **grid)
    loc.reset()
    n, n_places = len(case.differences), graph.n_places
    qi = case.query.index
    rows = []
    for k in range(n):
        est = loc.step(case.differences[k])
        ok = case.ground_truth.correct(np.full(n_places, qi[k]), np.arange(n_places))
        vel = loc.state_.sum(1) if loc.state_.shape[0] == len(loc.velocities) else loc.state_.sum(0)
        rows.append(dict(place=est.place, score=est.score, mass=float(loc.place_posterior_[ok].sum()),
                         covered=bool(ok.any()), new=float(est.new_place_probability), jump=float(loc.recovery_),
                         v=float(np.asarray(loc.velocities)[int(np.argmax(vel))]), vmass=float(vel.max() / vel.sum()),
                         temp=float(np.atleast_1d(obs.temperature_)[0]), hub=float(obs.hub_weight_),
                         best=int(np.argmin(case.differences[k])), best_ok=bool(ok[int(np.argmin(case.differences[k]))])))
    place = np.array([r["place"] for r in rows])
    score = np.array([r["score"] for r in rows])
    ev = evaluate(qi, place, score, case.ground_truth)
    wrong = np.nonzero(~ev.correct)[0]
    rank = rankdata(-score) / n  # 0 = ranked first
    qpos = np.asarray(case.query.positions)
    rpos = np.asarray(case.reference.positions)
    su = _start_up(ev.correct)
    print(f"\n## {case.name}: AUC {ev.metrics.auc:.3f}, R@100P {ev.metrics.recall_at_100p:.3f}, accuracy "
          f"{ev.correct.mean():.3f}, {len(wrong)} wrong of {n}; start-up (before 30 correct in a row) ends at "
          f"frame {su}; uncovered frames (no reference place within tolerance) {sum(not r['covered'] for r in rows)}; "
          f"best-ranked wrong frame at rank {rank[wrong].min() if len(wrong) else float('nan'):.3f}; "
          f"frames ranked above it that are right {int((score > score[wrong].max()).sum()) if len(wrong) else n}")
    print("| frames | truth (query index) | answer | single frame best / right | score (rank) | mass on truth | "
          "P(new) | jump rate | velocity (mass) | temperature / hub | answer − truth (m, floor) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for a, b in _runs(wrong):
        for k in (range(a, b + 1) if b - a < 4 else (a, b)):
            r = rows[k]
            d = qpos[k] - rpos[r["place"]]
            fl = f"{d[2]:+.0f}" if len(d) > 2 else ""
            print(f"| {a}–{b} | {k}: {qi[k]} | {r['place']} | {r['best']} / {'y' if r['best_ok'] else 'n'} | "
                  f"{r['score']:.2f} ({rank[k]:.3f}) | {r['mass']:.3f} | {r['new']:.3f} | {r['jump']:.4f} | "
                  f"{r['v']:+.2f} ({r['vmass']:.2f}) | {r['temp']:.3f} / {r['hub']:.2f} | "
                  f"{np.hypot(*d[:2]):.1f} {fl} |")
    late = wrong[wrong >= su]
    print(f"after the start-up: {len(late)} wrong; AUC of frames {su}..: "
          f"{evaluate(qi[su:], place[su:], score[su:], case.ground_truth).metrics.auc:.3f}")


class StartUpJumps(GridLocalizer):
    """Prototype (not in the library): until the filter first converges
    (``converged_``), and for at most ``start_frames`` frames, the prediction's jump rate is
    ``min(learned rate, start_rate)``; the learned rate itself is left as it is. Before a
    track has formed there is none to jump from, and the jump's uniform re-spread only
    slows the forming tracks."""

    start_rate = 0.01
    start_frames = int(RECOVERY_PRIOR_FRAMES)

    def _predict(self, odometry, ratio=None):
        rate = self.recovery_
        if not self.converged_ and (self.start_frames is None or self.n_steps_ < self.start_frames):
            self.recovery_ = min(rate, self.start_rate)
        try:
            super()._predict(odometry, ratio)
        finally:
            self.recovery_ = rate


def candidate(rate: float = 0.01, frames: int | None = int(RECOVERY_PRIOR_FRAMES), jump_velocity: str = "current") -> None:
    from bench_filter import _graph
    from bench_generalisation import WORLDS, world_case

    def runs():
        cases = ([ds.nordland()] + ds.uji_months() if ds.have_data() else []) + [ds.synthetic(0)]
        for case in cases:
            graph = _graph(case)
            group = "UJI 02-06" if case.name.startswith("UJI") else case.name
            for cond in ds.condition_table():
                c = ds.conditioned(case, cond)
                yield group, f"{case.name}, {cond.label}", graph, c.differences, c.query, c.ground_truth
        for name, spec in WORLDS.items():
            world = world_case(spec)
            for cond in ds.condition_table():
                q = world.under(cond) if cond.kind != "in-order" else world
                yield f"held-out {name}", f"{name}, {cond.label}", q.graph(), q.differences, q.query, q.ground_truth

    table: dict = {}
    for group, cell, graph, d, query, gt in runs():
        aucs = []
        for loc in (GridLocalizer(graph, TemperedObservation(), jump_velocity=jump_velocity),
                    StartUpJumps(graph, TemperedObservation(), jump_velocity=jump_velocity)):
            if isinstance(loc, StartUpJumps):
                loc.start_rate, loc.start_frames = rate, frames
            r = loc.run(d, odometry=query.odometry, query_index=query.index)
            aucs.append(evaluate(query.index, r.place, r.score, gt).metrics.auc)
        table.setdefault(group, []).append((aucs[1] - aucs[0], aucs[0], aucs[1], cell))
        print(f"{cell:60s} {aucs[0]:.4f} -> {aucs[1]:.4f}", flush=True)
    print("\n| dataset | cells | mean AUC (defaults) | mean AUC (candidate) | cells falling > 0.005 | falling / rising "
          "| worst cell | best cell |\n|---|---|---|---|---|---|---|---|")
    for group, rows in table.items():
        rows.sort()
        print(f"| {group} | {len(rows)} | {np.mean([r[1] for r in rows]):.4f} | {np.mean([r[2] for r in rows]):.4f} | "
              f"{sum(r[0] < -0.005 for r in rows)} | {sum(r[0] < 0 for r in rows)} / {sum(r[0] > 0 for r in rows)} | "
              f"{rows[0][0]:+.4f} ({rows[0][3]}) | {rows[-1][0]:+.4f} ({rows[-1][3]}) |")


def main(argv) -> None:
    if argv and argv[0] == "candidate":
        rest = argv[1:]
        candidate(float(rest[0]) if rest else 0.01,
                  (None if rest[1] == "none" else int(rest[1])) if len(rest) > 1 else int(RECOVERY_PRIOR_FRAMES),
                  rest[2] if len(rest) > 2 else "current")
        return
    months = [int(a) for a in argv if "=" not in a] or list(range(2, 7))
    grid = {k: float(v) for k, v in (a.split("=", 1) for a in argv if "=" in a)}
    for case in ds.uji_months(months):
        month(case, **grid)


if __name__ == "__main__":
    main(sys.argv[1:])
