"""Diagnosis: why weighing jump rates by the evidence holds Nordland in order, not reversed.

``GridLocalizer(jump_rates=(0.1, 0.01, 0.001, 0.0001))`` lifts Nordland in order from
0.966 to 0.983 and leaves it reversed at 0.966, although the long fixed window is better
reversed (0.981) than in order (0.965). This script runs the grid filter with the
default model (``TemperedObservation``), with and without ``jump_rates``, on Nordland in
order and reversed, records per frame what the filter held (the answer, the mass near
the truth, the jump-rate weights, the velocity marginal, the model's temperature and
the truth's whole-image ratio against the frame's best) and compares the two directions
*at the same places*: a query frame is the same place whichever way it is driven (on
Nordland, query frame ``q`` is reference place ``q``). Ground truth is read for the
diagnosis only. Prints tables (``docs/particle_filter.md``, "Tenth round"); writes
nothing. Run from the repository root::

    python benchmarks/diagnose_filter_reversed.py places   # wrong one way, right the other, by place
    python benchmarks/diagnose_filter_reversed.py stretch  # the hard stretch in each direction
    python benchmarks/diagnose_filter_reversed.py age      # the stretch reached early / late, and warm weights
    python benchmarks/diagnose_filter_reversed.py temperature  # each half of the stretch; τ swapped
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import prepared_datasets  # noqa: E402

from catgraph.conditions import Condition  # noqa: E402
from catgraph.grid import GridLocalizer  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402
from catgraph.observation import TemperedObservation  # noqa: E402
from diagnose_filter_misses import _start_up  # noqa: E402  (one definition of the start-up)

RATES = (0.1, 0.01, 0.001, 0.0001)
CONDITIONS = {"in order": Condition(), "reversed": Condition("reverse")}
#: the hard stretch of the route (query frames = places), eighth round
STRETCH = (2738, 2871)


class Recorder(GridLocalizer):
    """The grid filter, recording per frame what it held (``truth``: the true place of
    each processing frame, set before the run)."""

    truth: np.ndarray = np.empty(0, dtype=np.int64)
    initial_weights = None

    def reset(self):
        super().reset()
        if self.initial_weights is not None and self.jump_rates is not None:
            self.rate_weights_ = np.asarray(self.initial_weights, dtype=np.float64).copy()
        self.log = {k: [] for k in ("near", "weights", "velocity", "tau", "deficit", "rank", "eps")}
        return self

    def _exp_ratio(self, obs):
        k = self.n_steps_
        if obs.informative and k < len(self.truth):
            r = np.asarray(obs.log_ratio, dtype=np.float64)
            t = int(self.truth[k])
            lo, hi = max(0, t - 2), t + 3
            self.log["deficit"].append(float(r.max() - r[lo:hi].max()))
            self.log["rank"].append(int((r > r[lo:hi].max()).sum()))
        else:
            self.log["deficit"].append(np.nan)
            self.log["rank"].append(-1)
        return super()._exp_ratio(obs)

    def step(self, observation, odometry=None):
        est = super().step(observation, odometry)
        t = int(self.truth[self.n_steps_ - 1])
        self.log["near"].append(float(self.place_posterior_[max(0, t - 2):t + 3].sum()))
        if self.jump_rates is not None:
            self.log["weights"].append(self.rate_weights_.copy())
        self.log["velocity"].append(np.asarray(self.state_.sum(0)))
        self.log["tau"].append(float(getattr(self.model, "temperature_", np.nan)))
        self.log["eps"].append(float(self.recovery_))
        return est


def run(q, rates=None, rows=None, weights=None, scale=4.0):
    """One run of the grid filter with the default model on ``q`` (rows: a slice of the
    processing frames; ``scale``: the model's temperature scale); returns (the
    evaluation per processing frame, truth, the recorder)."""
    d = q.differences if rows is None else q.differences[rows]
    qi = np.asarray(q.query.index) if rows is None else np.asarray(q.query.index)[rows]
    loc = Recorder(q.graph(), TemperedObservation(temperature_scale=scale), jump_rates=rates)
    loc.truth = qi
    loc.initial_weights = weights
    r = loc.run(d, query_index=qi)
    ev = evaluate(qi, r.place, r.score, q.ground_truth)
    return ev, qi, loc


def _runs(values: np.ndarray) -> str:
    """``a–b`` runs of consecutive integers."""
    if not len(values):
        return "—"
    values = np.sort(values)
    cut = np.flatnonzero(np.diff(values) != 1) + 1
    return ", ".join(f"{g[0]}–{g[-1]}" if len(g) > 1 else f"{g[0]}" for g in np.split(values, cut))


def _all():
    p = prepared_datasets(["nordland"])["Nordland"][0]
    out = {}
    for cn, c in CONDITIONS.items():
        q = p.under(c)
        for label, rates in (("registry", None), ("jump_rates", RATES)):
            ev, qi, loc = run(q, rates)
            out[cn, label] = (ev, qi, loc)
    return p, out


def places() -> None:
    p, out = _all()
    n = len(p.query)
    print("| method | direction | AUC | wrong | start-up (processing frames) | wrong places (query frames) |\n"
          "|---|---|---|---|---|---|")
    by_place = {}
    for (cn, label), (ev, qi, loc) in out.items():
        ok = np.zeros(n, dtype=bool)
        ok[qi] = ev.correct
        by_place[cn, label] = ok
        su = _start_up(ev.correct)
        print(f"| {label} | {cn} | {ev.metrics.auc:.4f} | {(~ev.correct).sum()} | {su} | "
              f"{_runs(np.flatnonzero(~ok))} |")
    print("\n| method | wrong reversed, right in order (places) | count | wrong in order, right reversed | count |\n"
          "|---|---|---|---|---|")
    for label in ("registry", "jump_rates"):
        a, b = by_place["in order", label], by_place["reversed", label]
        rev_only, in_only = np.flatnonzero(a & ~b), np.flatnonzero(b & ~a)
        print(f"| {label} | {_runs(rev_only)} | {len(rev_only)} | {_runs(in_only)} | {len(in_only)} |")


def stretch() -> None:
    p, out = _all()
    lo, hi = STRETCH
    print(f"The stretch: query frames {lo}–{hi - 1} (places).\n")
    print("| method | direction | processing frames | wrong in it | first wrong (place) | rate weights at entry "
          f"{RATES} | ε at entry | τ in it (median) | truth's deficit in it: median / sum (nats, tempered) | "
          "truth's rank (median) | correct velocity's mass at entry / at the first wrong |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")
    for (cn, label), (ev, qi, loc) in out.items():
        inside = np.flatnonzero((qi >= lo) & (qi < hi))
        k0 = int(inside.min())
        wrong = inside[~ev.correct[inside]]
        first = int(wrong.min()) if len(wrong) else None
        w = np.round(loc.log["weights"][k0], 3).tolist() if loc.log["weights"] else "—"
        deficit = np.asarray(loc.log["deficit"])[inside]
        rank = np.asarray(loc.log["rank"])[inside]
        tau = np.asarray(loc.log["tau"])[inside]
        v = list(loc.velocities)
        true_v = v.index(1.0 if cn == "in order" else -1.0)
        vel = np.asarray(loc.log["velocity"])
        at_first = f"{vel[first][true_v]:.2f}" if first is not None else "—"
        print(f"| {label} | {cn} | {inside.min()}–{inside.max()} | {len(wrong)} | "
              f"{qi[first] if first is not None else '—'} | {w} | {loc.log['eps'][k0]:.4f} | {np.median(tau):.2f} | "
              f"{np.nanmedian(deficit):.2f} / {np.nansum(deficit):.1f} | {np.median(rank):.0f} | "
              f"{vel[k0][true_v]:.2f} / {at_first} |")
    # the same places, frame by frame, every 8 places
    print("\n| place | in order: near truth / τ / deficit | reversed: near truth / τ / deficit "
          "(jump_rates) |\n|---|---|---|")
    for place in range(lo, hi, 8):
        cells = []
        for cn in CONDITIONS:
            ev, qi, loc = out[cn, "jump_rates"]
            k = int(np.flatnonzero(qi == place)[0])
            cells.append(f"{loc.log['near'][k]:.2f} / {loc.log['tau'][k]:.2f} / {loc.log['deficit'][k]:.2f}")
        print(f"| {place} | " + " | ".join(cells) + " |")


def age() -> None:
    """The stretch reached after few or many frames: in order from place 2040 (the
    stretch ~700 frames in, as reversed), and reversed with the rate weights the in-order
    run held on entering the stretch."""
    p = prepared_datasets(["nordland"])["Nordland"][0]
    lo, hi = STRETCH
    rows = []
    q_in = p.under(CONDITIONS["in order"])
    q_rev = p.under(CONDITIONS["reversed"])
    ev, qi, loc = run(q_in, RATES)
    k0 = int(np.flatnonzero(qi == lo)[0])
    warm = loc.log["weights"][k0]
    for label, q, sl, weights in (("in order, whole query", q_in, None, None),
                                  ("in order, from place 2040", q_in, slice(2040, None), None),
                                  ("in order, from place 2540", q_in, slice(2540, None), None),
                                  ("reversed, whole query", q_rev, None, None),
                                  ("reversed, rate weights of the in-order run at the stretch", q_rev, None, warm),
                                  ("reversed, all weight on 0.0001", q_rev, None, (0.0, 0.0, 0.0, 1.0))):
        ev, qi, loc = run(q, RATES, sl, weights)
        inside = np.flatnonzero((qi >= lo) & (qi < hi))
        k0 = int(inside.min())
        rows.append(f"| {label} | {k0} | {np.round(loc.log['weights'][k0], 3).tolist()} | "
                    f"{(~ev.correct[inside]).sum()} of {len(inside)} | {ev.metrics.auc:.4f} |")
    print(f"| run (jump_rates {RATES}) | stretch entered at processing frame | rate weights there | wrong in the "
          "stretch | AUC of the run |\n|---|---|---|---|---|")
    print("\n".join(rows))


def temperature() -> None:
    """The stretch's two halves in each direction, the truth's deficit untempered
    (``deficit / τ``), and the temperature scale set so that each direction's ``τ`` in the
    stretch is the other's."""
    p = prepared_datasets(["nordland"])["Nordland"][0]
    lo, hi = STRETCH
    mid = 2809
    print("| run (jump_rates) | temperature scale | τ in the stretch (median) | untempered deficit, places "
          f"{lo}–{mid - 1}: median / sum | places {mid}–{hi - 1}: median / sum | wrong in {lo}–{mid - 1} / "
          f"{mid}–{hi - 1} | AUC |\n|---|---|---|---|---|---|---|")
    for cn, scale in (("in order", 4.0), ("reversed", 4.0), ("reversed", 3.0), ("in order", 5.4)):
        q = p.under(CONDITIONS[cn])
        ev, qi, loc = run(q, RATES, scale=scale)
        tau = np.asarray(loc.log["tau"])
        raw = np.asarray(loc.log["deficit"]) / tau
        a = np.flatnonzero((qi >= lo) & (qi < mid))
        b = np.flatnonzero((qi >= mid) & (qi < hi))
        inside = np.r_[a, b]
        print(f"| {cn} | {scale} | {np.median(tau[inside]):.2f} | {np.nanmedian(raw[a]):.2f} / {np.nansum(raw[a]):.0f} | "
              f"{np.nanmedian(raw[b]):.2f} / {np.nansum(raw[b]):.0f} | {(~ev.correct[a]).sum()} / "
              f"{(~ev.correct[b]).sum()} | {ev.metrics.auc:.4f} |", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "places"
    {"places": places, "stretch": stretch, "age": age, "temperature": temperature}[what]()
