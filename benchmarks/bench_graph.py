"""Building a place graph: the CSR arrays and edge tables of a map of 10⁴–10⁶ places.

Usage (from the project root)::

    python benchmarks/bench_graph.py                      # -> results/graph_build.md (+ .json)
    python benchmarks/bench_graph.py --trees OLD NEW      # the same, one column per frozen checkout

Every map — a saved ``.npz`` map on load, ``LiveMap`` from a reference, ``build-map`` —
compiles its graph with :meth:`catgraph.graph.PlaceGraph.from_edges`. Measured per size:
``PlaceGraph.chain(N)`` (a route driven both ways: ``2 (N − 1)`` edges) and a route with
junctions (``from_edges`` on the chain's edges plus ``N / 100`` junction pairs both ways),
the ``reverse`` and ``straight`` edge tables included (formed on first use since
``PlaceGraph`` forms them lazily: the JSON keeps the time before them too), each in a
fresh process (``PYTHONPATH`` set to the tree), the trees alternated round by
round so that the shared machine's load falls on each alike. Reported: the median wall
time over the rounds and the growth of the process's peak RSS while building (``VmHWM``
after, less ``VmRSS`` before: what building needs beyond the graph it returns, and the graph).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SIZES = (10_000, 100_000, 1_000_000)
CASES = ("chain", "junctions")

_CHILD = r"""
import json, sys, time
import numpy as np
from catgraph.graph import PlaceGraph

def status_mb(key):
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) / 1024 for l in f if l.startswith(key))

case, n = sys.argv[1], int(sys.argv[2])
PlaceGraph.chain(100)  # imports and first calls outside the timing
rng = np.random.default_rng(0)
if case == "junctions":
    i = np.arange(n - 1)
    pairs = rng.integers(0, n, (n // 100, 2))
    pairs = pairs[np.abs(pairs[:, 0] - pairs[:, 1]) > 3]
    edges = np.concatenate([np.stack([i, i + 1], 1), np.stack([i + 1, i], 1), pairs, pairs[:, ::-1]])
    kinds = np.concatenate([np.zeros(n - 1, int), np.ones(n - 1, int), np.full(2 * len(pairs), 2)])
before = status_mb("VmRSS")
start = time.perf_counter()
g = PlaceGraph.chain(n) if case == "chain" else PlaceGraph.from_edges(n, edges, kinds=kinds)
arrays = time.perf_counter() - start
g.reverse  # the edge tables (formed on first use where they are not formed with the graph)
seconds = time.perf_counter() - start
graph_mb = sum(getattr(g, k).nbytes for k in ("source", "target", "length", "kind", "out_ptr", "reverse",
                                               "straight", "route_distance")) / 2**20
print(json.dumps({"seconds": seconds, "seconds_before_tables": arrays, "peak_growth_mb": status_mb("VmHWM") - before, "graph_mb": graph_mb,
                  "edges": int(len(g.source))}))
"""


def _one(tree: Path, case: str, n: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, "-c", _CHILD, case, str(n)], env=env, cwd="/tmp", check=True,
                         capture_output=True, text=True).stdout
    return {**json.loads(out), "load": os.getloadavg()[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trees", nargs="+", default=[str(ROOT)], help="checkouts to import catgraph from")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default="graph_build", help="results file stem")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from machine_info import describe_machine

    trees = [Path(t).resolve() for t in args.trees]
    runs = {(str(t), c, n): [] for t in trees for c in CASES for n in args.sizes}
    for r in range(args.rounds):
        for n in args.sizes:
            for c in CASES:
                for t in trees:
                    runs[(str(t), c, n)].append(_one(t, c, n))
                    print(f"round {r}, {c} N={n}, {t.name}: {runs[(str(t), c, n)][-1]}", flush=True)
    label = {str(t): (t.name if len(trees) > 1 else "this tree") for t in trees}
    loads = [x["load"] for v in runs.values() for x in v]
    lines = [f"# Building a place graph ({describe_machine()})", "",
             f"`benchmarks/bench_graph.py` {' '.join(sys.argv[1:])}: median over {args.rounds} rounds, one fresh "
             "process per tree, case, size and round (trees alternated); the peak's growth while building "
             "(VmHWM after − VmRSS before) includes the graph returned. "
             f"Load average {min(loads):.1f}–{max(loads):.1f}.",
             "", "| case | N | edges | " + " | ".join(f"{label[str(t)]}: seconds, peak growth" for t in trees)
             + (" | time ratio (first / last)" if len(trees) > 1 else "") + " |",
             "|---|---|---|" + "---|" * (len(trees) + (len(trees) > 1))]
    for c in CASES:
        for n in args.sizes:
            med = [statistics.median(x["seconds"] for x in runs[(str(t), c, n)]) for t in trees]
            grow = [statistics.median(x["peak_growth_mb"] for x in runs[(str(t), c, n)]) for t in trees]
            cells = [f"{s:.3f} s, {g:.0f} MB" for s, g in zip(med, grow)]
            ratio = [f"×{med[0] / med[-1]:.1f}"] if len(trees) > 1 else []
            edges = runs[(str(trees[0]), c, n)][0]["edges"]
            lines.append(f"| {c} | {n:,} | {edges:,} | " + " | ".join(cells + ratio) + " |")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    (RESULTS / f"{args.out}.json").write_text(json.dumps({"|".join(map(str, k)): v for k, v in runs.items()}, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
