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
                                           [--before CHECKOUT]

Prints a markdown table. ``--before``: a checkout of an earlier commit (``git worktree
add``) whose rule "tracked" is timed as a third column, alternated with the other two.
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
    """Child process: warm up, then time ``steps`` steps; peak RSS in MiB (its own ``VmHWM``)."""
    sys.path.insert(0, str(ROOT))
    from benchmarks.process_memory import peak_rss_mb
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
            "rss_mib": peak_rss_mb()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--places", default="10000,100000,1000000")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--before", default=None, help="a checkout of an earlier commit: its rule 'tracked' as well")
    ap.add_argument("--child", nargs=2, metavar=("N", "RULE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_one(int(args.child[0]), args.child[1], args.steps)))
        return
    runs = {"tracked": (__file__, "tracked"), "challenged": (__file__, "challenged")}
    if args.before:
        runs["tracked before"] = (str(Path(args.before).resolve() / "benchmarks" / "bench_tracked_step.py"), "tracked")
    print(f"load average at the start: {os.getloadavg()[0]:.1f}; {os.cpu_count()} cpu; {args.rounds} rounds "
          f"alternated, {args.steps} steps each\n")
    before = " | rule \"tracked\" before (ms/step) | ratio to it" if args.before else ""
    print(f"| places | rule \"challenged\" (ms/step) | rule \"tracked\" (ms/step) | ratio{before} | peak RSS challenged "
          f"/ tracked{' / before' if args.before else ''} |")
    print("|---|---|---|---|---|" + ("---|---|" if args.before else ""))
    for n in (int(x) for x in args.places.split(",")):
        got = {r: [] for r in runs}
        for _ in range(args.rounds):
            for label, (script, rule) in runs.items():
                out = subprocess.run([sys.executable, script, "--steps", str(args.steps), "--child", str(n), rule],
                                     check=True, capture_output=True, text=True).stdout
                got[label].append(json.loads(out.strip().splitlines()[-1]))
        ms = {r: float(np.median([g["ms"] for g in got[r]])) for r in runs}
        rss = {r: max(g["rss_mib"] for g in got[r]) for r in runs}
        extra = (f" {ms['tracked before']:.1f} | ×{ms['tracked'] / ms['tracked before']:.2f} |" if args.before else "")
        print(f"| {n:,} | {ms['challenged']:.1f} | {ms['tracked']:.1f} | ×{ms['tracked'] / ms['challenged']:.2f} |{extra} "
              f"{' / '.join(f'{rss[r]:.0f}' for r in ('challenged', 'tracked', 'tracked before') if r in rss)} MiB |", flush=True)


if __name__ == "__main__":
    main()
