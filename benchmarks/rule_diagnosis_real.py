"""Per-frame diagnosis of rule "spanning" on Nordland driven backwards and re-timed
(docs/sequence.md, section "0.2: the adaptive window on reversed and re-timed routes").

On Nordland reversed, at speed 2 and at speed 0.5 (and in order, for comparison) this takes
the statistics the kernels hand to the window rule (cached by ``rule_harness.py``) and
labels every frame: the length, velocity and decorrelation horizon rule "spanning" chooses,
whether its match is correct, whether the fixed window of 500 frames (at its own most
significant velocity: the best fixed window of these cells) and rule "decorrelated" are
correct there. Ground truth is read here only to label frames, never by a rule. The lost
frames (spanning wrong, the 500-frame window right) are split by cause, each frame counted
once, in this order:

* *start-up*: frame index below 500 (the 500-frame window is still the ``i + 1`` frames seen);
* *velocity re-choice*: the velocity was re-chosen away from the one summed over the lengths,
  and the chosen length at the summed velocity would be right;
* *window too short*: a longer window at the summed velocity is right; for these, which of
  the sub-window tests (midpoint, spread, rival) rejected the 500-frame line;
* *other*.

Beside them: how often each test rejects the 500-frame line where it is right and where it is
wrong, the share of frames at the condition's true velocity, and the AUC without the hub
correction (the statistics computed once more without it).

Run from the repository root::

    python benchmarks/rule_diagnosis_real.py [--conditions "reversed,speed 2,speed 0.5,in order"]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import rule_harness as H  # noqa: E402

from catgraph import _window_rule as wr  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402

TRUE_VELOCITY = {"in order": 1.0, "reversed": -1.0, "speed 2": 2.0, "speed 0.5": 0.5}


def tests(st, cfg, log_p, n_places, horizon):
    """The three sub-window tests of rule "spanning", separately: ``(n, V, G)`` booleans,
    True where the window passes that test."""
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    mid = 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])
    midpoint = np.all((st.sub <= mid) | ~recent, axis=3)
    common = wr._common_std(st)[:, :, None, :]
    spread = np.all((st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~shorter, axis=3)
    rival = (log_p < -np.log(n_places) - wr.SPANNING_MARGIN) & (lengths[None, None, :] >= horizon[:, None, None])
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * common
    unrivalled = np.all(~(beaten & rival[:, :, None, :]) | ~recent, axis=3)
    for a in (midpoint, spread, unrivalled):
        a[:, :, 0] = True
    return midpoint, spread, unrivalled


def diagnose(cell, label, offsets=True):
    """Per-frame labels and the counts of the lost frames of one cell (see the module docstring)."""
    st, rows, index, truth = next(cell.each()) if offsets else _without_offsets(cell)
    cfg = H.config("spanning")
    n, v_count, g_count = st.best_s.shape
    r = np.arange(n)
    grid, vel = cfg.grid, cfg.velocities

    def correct(match):
        return evaluate(index, match, np.zeros(n), truth).correct.astype(bool)

    match, _, conf, length, velocity, _ = wr._decide(st, cfg, r, False, rows, wr._new_record(cfg))
    auc = evaluate(index, match, conf, truth).metrics.auc
    log_p = wr._log_p(st)
    v_sum = np.argmin(log_p.sum(axis=2), axis=1)
    clock = wr._Horizon()
    horizon = np.array([clock.update(row, i, row.std()) for i, row in enumerate(rows)])
    midpoint, spread, unrivalled = tests(st, cfg, log_p, rows.shape[1], horizon)
    adm = (midpoint & spread & unrivalled)[r, v_sum]
    g = np.argmin(np.where(adm, log_p[r, v_sum], np.inf), axis=1)  # the chosen length (as the rule does)
    v_idx = np.searchsorted(vel, velocity)
    ok = correct(match)
    v_own = np.argmin(log_p, axis=1)  # (n, G)
    fixed = correct(st.best_j[r, v_own[:, -1], -1])  # the 500-frame window at its own velocity
    dcfg = H.config("decorrelated")
    dmatch = wr._decide(st, dcfg, r, False, rows, wr._new_record(dcfg))[0]
    dec = correct(dmatch)
    v_true = int(np.argmin(np.abs(vel - TRUE_VELOCITY[label])))
    right_k = np.stack([correct(st.best_j[r, v_sum, k]) for k in range(g_count)], axis=1)  # (n, G) at v_sum
    lost = ~ok & fixed
    startup = lost & (r < grid[-1])
    rechoice = lost & ~startup & (v_idx != v_sum) & right_k[r, g]
    longer = np.array([right_k[t, g[t] + 1:].any() for t in range(n)])
    short = lost & ~startup & ~rechoice & longer
    other = lost & ~startup & ~rechoice & ~short
    l500 = right_k[:, -1]
    out = {
        "label": label, "frames": n, "auc": auc, "accuracy": ok.mean(), "fixed500": fixed.mean(),
        "decorrelated": dec.mean(), "lost": int(lost.sum()), "gained": int((ok & ~fixed).sum()),
        "startup": int(startup.sum()), "rechoice": int(rechoice.sum()), "short": int(short.sum()),
        "other": int(other.sum()),
        "short_by": {name: int(np.sum(short & ~test[r, v_sum, -1] & l500))
                     for name, test in (("midpoint", midpoint), ("spread", spread), ("rival", unrivalled))},
        "l500_rejected": {name: (int(np.sum(~test[r, v_sum, -1] & l500)), int(np.sum(~test[r, v_sum, -1] & ~l500)))
                          for name, test in (("midpoint", midpoint), ("spread", spread), ("rival", unrivalled))},
        "horizon": np.percentile(horizon, [10, 50, 90]).tolist(),
        "horizon_lost": float(np.median(horizon[lost])) if lost.any() else float("nan"),
        "chosen_L_lost": float(np.median(grid[g][lost])) if lost.any() else float("nan"),
        "short_below_K": int(np.sum(short & (grid[g] < horizon))),
        "v_true_share": float(np.mean(v_idx == v_true)), "v_sum_true_share": float(np.mean(v_sum == v_true)),
        "v_sum_true_lost": int(np.sum(lost & (v_sum == v_true))),
        "rechosen_lost": int(np.sum(lost & (v_idx != v_sum))),
        "dec_right_on_lost": int((lost & dec).sum()),
        "lost_runs": runs(lost),
    }
    return out


def _without_offsets(cell):
    """The cell's first case with the statistics computed without the hub correction."""
    key, d, _, index, truth = cell.parts[0]
    st, rows = H.cached_stats(key + " no hubs", d, None)
    return st, rows, index, truth


def runs(mask):
    """Number of runs of consecutive True frames, their median and longest length."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    starts = np.flatnonzero(np.diff(m) == 1)
    ends = np.flatnonzero(np.diff(m) == -1)
    lens = ends - starts
    return (int(lens.size), float(np.median(lens)) if lens.size else 0.0, int(lens.max()) if lens.size else 0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default="reversed,speed 2,speed 0.5,in order")
    ap.add_argument("--signals", action="store_true",
                    help="instead: the autocorrelation of the frames' standardised difference at the match, and "
                         "how far the correct chosen lines' sub-windows stand from random places (Nordland, UJI 02)")
    args = ap.parse_args(argv)
    if args.signals:
        signals()
        return
    wanted = args.conditions.split(",")
    cells = {c.label: c for c in H.table_cells(("Nordland",)) if c.label in wanted}
    rows = [diagnose(cells[label], label) for label in wanted]
    print("| | " + " | ".join(o["label"] for o in rows) + " |")
    print("|---|" + "---|" * len(rows))

    def line(name, f):
        print(f"| {name} | " + " | ".join(f(o) for o in rows) + " |")

    line("frames", lambda o: str(o["frames"]))
    line("AUC / accuracy, rule spanning", lambda o: f"{o['auc']:.3f} / {o['accuracy']:.3f}")
    line("accuracy, 500-frame window / rule decorrelated", lambda o: f"{o['fixed500']:.3f} / {o['decorrelated']:.3f}")
    line("horizon K (10th / median / 90th pct)", lambda o: "{:.0f} / {:.0f} / {:.0f}".format(*o["horizon"]))
    line("lost frames (spanning wrong, 500 right) / the other way", lambda o: f"{o['lost']} / {o['gained']}")
    line("  in runs: count / median / longest", lambda o: "{} / {:.0f} / {}".format(*o["lost_runs"]))
    line("  median chosen L / median K on them", lambda o: f"{o['chosen_L_lost']:.0f} / {o['horizon_lost']:.0f}")
    line("  start-up (frame < 500)", lambda o: str(o["startup"]))
    line("  velocity re-chosen at L >= K (summed velocity right there)", lambda o: str(o["rechoice"]))
    line("  window too short (a longer window right at the summed velocity)", lambda o: str(o["short"]))
    line("    of which chosen L < K", lambda o: str(o["short_below_K"]))
    line("    L = 500 right but rejected by midpoint / spread / rival",
         lambda o: "{midpoint} / {spread} / {rival}".format(**o["short_by"]))
    line("  other", lambda o: str(o["other"]))
    line("  velocity re-chosen away from the summed one (any cause above)", lambda o: str(o["rechosen_lost"]))
    line("  summed velocity the true one", lambda o: f"{o['v_sum_true_lost']} of {o['lost']}")
    line("  rule decorrelated right", lambda o: f"{o['dec_right_on_lost']} of {o['lost']}")
    line("all frames: L = 500 rejected by midpoint (right / wrong there)",
         lambda o: "{} / {}".format(*o["l500_rejected"]["midpoint"]))
    line("all frames: L = 500 rejected by spread (right / wrong there)",
         lambda o: "{} / {}".format(*o["l500_rejected"]["spread"]))
    line("all frames: L = 500 rejected by rival (right / wrong there)",
         lambda o: "{} / {}".format(*o["l500_rejected"]["rival"]))
    line("velocity: chosen / summed = the true one", lambda o: f"{o['v_true_share']:.3f} / {o['v_sum_true_share']:.3f}")
    hubs = [diagnose(cells[label], label, offsets=False) for label in wanted]
    print("| AUC without the hub correction | " + " | ".join(f"{o['auc']:.3f}" for o in hubs) + " |")


def signals() -> None:
    """Two candidate signals that could tell Nordland's hard stretches from UJI's dwelling
    (docs/sequence.md): per cell, the autocorrelation of each frame's standardised difference
    at rule "spanning"'s match, and, where the rule chose a window of 16 frames or more and was
    right, how many common spreads its line's 5-, 11- and 23-frame sub-windows lie below the
    random places' mean."""
    import rule_candidates as C

    cfg = H.config("spanning")
    for cell in H.table_cells(("Nordland", "UJI", "synthetic")):
        if cell.label not in ("in order", "shuffled 2–20 % (seed 4)", "reversed"):
            continue
        st, rows, index, truth = next(cell.each())
        n = rows.shape[0]
        r = np.arange(n)
        match, conf, g, v = C.decide_spanning(st, rows, cfg)
        e = wr._current_z(rows, match)
        e = e - e.mean()
        acf = [np.corrcoef(e[:-k], e[k:])[0, 1] for k in (1, 5, 20)]
        ok = evaluate(index, match, conf, truth).correct.astype(bool)
        z = (st.mean[r, v, :] - st.sub[r, v, g, :]) / wr._common_std(st)[:, 0, :]
        sel = ok & (g > 2)
        print(f"{cell.parts[0][0]}: autocorrelation at lags 1 / 5 / 20 " + " / ".join(f"{a:.2f}" for a in acf)
              + "; correct chosen line, spreads below random at 5 / 11 / 23 frames: median "
              + " / ".join(f"{x:.2f}" for x in np.median(z[sel][:, [0, 2, 4]], axis=0)) + ", 10th pct "
              + " / ".join(f"{x:.2f}" for x in np.percentile(z[sel][:, [0, 2, 4]], 10, axis=0)))


if __name__ == "__main__":
    main()
