"""Per-frame diagnosis of a window rule on one held-out world (docs/sequence.md, section
"0.2: why the adaptive window loses to a 5-frame window on unseen worlds").

On a world of ``benchmarks/bench_generalisation.py`` (default: seed 1, in order) this takes
the statistics the kernels hand to the window rule (cached by ``rule_harness.py``) and
takes the rule apart frame by frame: which length and velocity it chooses, whether the
chosen match is correct, whether the 5-frame window's is (ground truth is read here only to
label frames, never by a rule), how the velocity summed over the lengths compares with each
length's own, how significant the right and the wrong best lines and the best place beyond
the exclusion radius are at every length, and what the rival test of rule "unrivalled" sees
on the frames it gets wrong. Run from the repository root::

    python benchmarks/rule_diagnosis.py [--world "seed 1"] [--condition "in order"] [--rule unrivalled]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import rule_harness as H  # noqa: E402
import rule_candidates as C  # noqa: E402

from catgraph import _window_rule as wr  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402


def main(argv=None) -> None:
    from bench_generalisation import WORLDS, world_case
    from datasets import benchmark_conditions

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="seed 1")
    ap.add_argument("--condition", default="in order")
    ap.add_argument("--rule", default="unrivalled", help="a rule without a record (not predictive, decorrelated)")
    args = ap.parse_args(argv)
    case = world_case(WORLDS[args.world])
    condition = next(c for c in benchmark_conditions(True) if c.label == args.condition)
    prepared = case.under(condition) if condition.kind != "in-order" else case
    cell = H.Cell("held-out", f"{args.world}, {condition.label}", float("nan"),
                  [(f"world {args.world} {condition.label}", prepared.differences, prepared.hub_offsets(),
                    prepared.query.index, prepared.ground_truth)])
    st, rows, index, truth = next(cell.each())
    cfg = H.config(args.rule)
    n, _, g_count = st.best_s.shape
    r = np.arange(n)
    grid, vel = cfg.grid, cfg.velocities
    log_n = np.log(rows.shape[1])

    def correct(match):
        return evaluate(index, match, np.zeros(n), truth).correct.astype(bool)

    match, _, conf, _, _, _ = wr._decide(st, cfg, r, False, rows, wr._new_record(cfg))
    log_p = wr._log_p(st)
    v_sum = np.argmin(log_p.sum(axis=2), axis=1)
    # the chosen length, as the rule chooses it at the summed velocity (rules without a record)
    horizon = None
    if args.rule == "spanning":
        clock = wr._Horizon()
        horizon = np.array([clock.update(row, i, row.std()) for i, row in enumerate(rows)])
    admitted = wr._admissible(st, cfg, log_p, rows.shape[1], horizon)[r, v_sum]
    g = np.argmin(np.where(admitted, log_p[r, v_sum], np.inf), axis=1)
    ok = correct(match)
    v_own = np.argmin(log_p, axis=1)  # (n, G)
    print(f"{args.world}, {condition.label}: {n} frames, {rows.shape[1]} places, hub offsets "
          f"{np.count_nonzero(prepared.hub_offsets())}; rule {args.rule}: AUC "
          f"{evaluate(index, match, conf, truth).metrics.auc:.3f}, accuracy {ok.mean():.3f}")
    print("\nL | chosen on | correct when chosen | correct at the summed velocity | at its own velocity | "
          "median log p (summed velocity)")
    for k in range(g_count):
        at_sum = correct(st.best_j[r, v_sum, k]).mean()
        at_own = correct(st.best_j[r, v_own[:, k], k]).mean()
        when = ok[g == k].mean() if np.any(g == k) else float("nan")
        print(f"{grid[k]:4d} | {np.mean(g == k):.3f} | {when:.3f} | {at_sum:.3f} | {at_own:.3f} | "
              f"{np.median(log_p[r, v_sum, k]):.1f}")
    c5_own = correct(st.best_j[r, v_own[:, 0], 0])
    c5_sum = correct(st.best_j[r, v_sum, 0])
    bad = ~ok & c5_own
    print(f"\nwrong while the 5-frame window (own velocity) is right: {bad.sum()} (the other way: "
          f"{np.sum(ok & ~c5_own)}); the 5-frame window at the summed velocity also wrong (velocity): "
          f"{np.sum(bad & ~c5_sum)}, right (window): {np.sum(bad & c5_sum)}")
    print("velocity share, summed:", {float(x): round(float(np.mean(vel[v_sum] == x)), 3) for x in vel})
    print("velocity share, own at 5 frames:", {float(x): round(float(np.mean(vel[v_own[:, 0]] == x)), 3) for x in vel})
    second = C.log_p_at(st, st.second_s)
    print("\nL | median log p of the best place beyond the radius | of wrong best lines | of right best lines"
          f"   (-ln N = {-log_n:.1f})")
    for k in range(g_count):
        ck = correct(st.best_j[r, v_sum, k])
        a = log_p[r, v_sum, k]
        print(f"{grid[k]:4d} | {np.median(second[r, v_sum, k]):.1f} | {np.median(a[~ck]):.1f} | {np.median(a[ck]):.1f}")
    common = wr._common_std(st)[:, 0, :]
    line5 = (st.mean[r, v_sum, 0] - st.sub[r, v_sum, g, 0]) / common[:, 0]
    best5 = (st.mean[r, v_sum, 0] - st.best_s[r, v_sum, 0]) / common[:, 0]
    sig5 = log_p[r, v_sum, 0] + log_n
    long_bad = (g > 0) & ~ok & c5_sum
    print(f"\nlonger window wrong, 5-frame line at the same velocity right: {long_bad.sum()} frames; medians: the "
          f"chosen line's last 5 frames {np.median(line5[long_bad]):.2f} spreads better than random, trailing the "
          f"best 5-frame line by {np.median((best5 - line5)[long_bad]):.2f} spreads; that line's log p + ln N "
          f"{np.median(sig5[long_bad]):.1f}")
    for margin in (10, 5, 3, 0):
        caught = (g > 0) & (best5 - line5 > wr.RIVAL_SPREADS) & (sig5 < -margin)
        print(f"  a 5-frame rival at margin {margin}: rejects {np.sum(caught & long_bad)} of them, and "
              f"{np.sum(caught & ok & ~c5_sum)} frames where the longer window was right and the 5-frame line wrong")


if __name__ == "__main__":
    main()
