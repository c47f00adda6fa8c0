"""Whole-Nordland timing of the adaptive matcher: the default rule against rule "spanning" (or
the rule named by ``--against``).

The two rules differ only in the window rule's share (rule "punctuated" also reads the
breaks of the rows from the horizon's clock and gates the spread test), so they are timed
alternately in one process on the same hub-corrected rows (``match_sequences`` with every
default but the rule), medians of ``--repeats`` runs each, wall and CPU time, and their
ratio: on a shared machine the ratio of runs taken side by side is the figure to read, not
the seconds. The matches of the two are compared too (they differ only where the gate
admits a longer window). Prints a markdown table. Run from the repository root::

    python benchmarks/bench_sequence_rule_timing.py [--repeats 3] [--against gated]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import nordland  # noqa: E402
from catgraph.hubs import hub_offsets  # noqa: E402
from catgraph.pipeline import differences  # noqa: E402
from catgraph.sequence import DEFAULT_RULE, match_sequences  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--against", default="spanning", help="the rule timed beside the default")
    args = parser.parse_args()
    case = nordland()
    start = time.perf_counter()
    d = differences(case.reference, case.query)
    diff_s = time.perf_counter() - start
    offsets = hub_offsets(differences(case.reference, case.reference))
    rules = (DEFAULT_RULE, args.against)
    match_sequences(d[:50], hub_offsets=offsets)  # compile
    wall = {r: [] for r in rules}
    cpu = {r: [] for r in rules}
    out = {}
    load = os.getloadavg()[0]
    for _ in range(args.repeats):
        for rule in rules:
            w0, c0 = time.perf_counter(), time.process_time()
            out[rule] = match_sequences(d, hub_offsets=offsets, rule=rule)
            wall[rule].append(time.perf_counter() - w0)
            cpu[rule].append(time.process_time() - c0)
    print(f"load average at the start {load:.1f}; difference matrix {diff_s:.2f} s; medians of {args.repeats} "
          f"alternated runs\n")
    print(f"| rule | matcher wall | matcher CPU | wall / {args.against}'s |")
    print("|---|---|---|---|")
    base = float(np.median(wall[args.against]))
    for rule in rules:
        print(f"| {rule} | {np.median(wall[rule]):.2f} s | {np.median(cpu[rule]):.2f} s | "
              f"{np.median(wall[rule]) / base:.3f} |")
    a, b = out[rules[0]], out[args.against]
    print(f"\nframes with another window: {int(np.sum(a.window_length != b.window_length))}, another match: "
          f"{int(np.sum(a.match != b.match))} of {d.shape[0]}")


if __name__ == "__main__":
    main()
