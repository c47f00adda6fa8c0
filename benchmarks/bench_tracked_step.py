"""What rule "tracked" adds to the streaming matcher's step, at 10⁴–10⁶ places.

Rule "tracked" runs a grid filter (``GridLocalizer`` with the ``TemperedObservation``
model, on the chain of the reference's places) beside the matcher on every row. This
script times ``SequenceMatcher.step`` with rule "tracked" (the default) and with rule
"challenged" (the default before it) on the same random normalised rows (default
velocities and lengths, ``l_max`` 500), in fresh processes alternated over ``--rounds``
rounds, and reports the median step time of each and their ratio, with each process's
peak RSS. Rows are random: the filter's work per step does not depend on what the rows
hold, the step's time and memory are what is read here, not answers. Run from the
repository root::

    python benchmarks/bench_tracked_step.py [--places 10000,100000,1000000] [--rounds 3] [--steps 20]

Prints a markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _one(n_places: int, rule: str, steps: int) -> dict:
    """Child process: warm up, then time ``steps`` steps; peak RSS in MiB."""
    import resource

    sys.path.insert(0, str(ROOT))
    from catgraph.sequence import SequenceMatcher

    rng = np.random.default_rng(0)
    rows = rng.standard_normal((8, n_places))
    matcher = SequenceMatcher(rule=rule)
    for k in range(5):  # compile and fill the first buffers
        matcher.step(rows[k % 8])
    times = []
    for k in range(steps):
        row = rows[k % 8]
        start = time.perf_counter()
        matcher.step(row)
        times.append(time.perf_counter() - start)
    return {"ms": 1e3 * float(np.median(times)),
            "rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--places", default="10000,100000,1000000")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--child", nargs=2, metavar=("N", "RULE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_one(int(args.child[0]), args.child[1], args.steps)))
        return
    rules = ("tracked", "challenged")
    print(f"load average at the start: {os.getloadavg()[0]:.1f}; {os.cpu_count()} cpu; {args.rounds} rounds "
          f"alternated, {args.steps} steps each\n")
    print("| places | rule \"challenged\" (ms/step) | rule \"tracked\" (ms/step) | ratio | peak RSS challenged / tracked |")
    print("|---|---|---|---|---|")
    for n in (int(x) for x in args.places.split(",")):
        got = {r: [] for r in rules}
        for _ in range(args.rounds):
            for rule in rules:
                out = subprocess.run([sys.executable, __file__, "--steps", str(args.steps), "--child", str(n), rule],
                                     check=True, capture_output=True, text=True).stdout
                got[rule].append(json.loads(out.strip().splitlines()[-1]))
        ms = {r: float(np.median([g["ms"] for g in got[r]])) for r in rules}
        rss = {r: max(g["rss_mib"] for g in got[r]) for r in rules}
        print(f"| {n:,} | {ms['challenged']:.1f} | {ms['tracked']:.1f} | ×{ms['tracked'] / ms['challenged']:.2f} | "
              f"{rss['challenged']:.0f} / {rss['tracked']:.0f} MiB |", flush=True)


if __name__ == "__main__":
    main()
