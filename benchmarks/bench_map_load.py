"""A compact live map from a saved map file: read whole, or coded as it is read.

Usage (from the project root)::

    python benchmarks/bench_map_load.py                 # -> results/map_load.md (+ .json)
    python benchmarks/bench_map_load.py --sizes 100000  # a quicker run

A map of ``N`` places × 512 float32 values (a random walk, so that deflating it is not
trivial) is saved twice in a scratch folder, its members stored and deflated
(``save_map(..., compress=False | True)``). In a fresh process per case and round, the
rounds alternating the cases, a compact live map is made from it in two ways: the map
read whole, then coded (``LiveMap(load_map(path), layout="uint8")``), and the map file
given to ``LiveMap`` (``LiveMap(path, layout="uint8")``: the descriptors read in row
blocks, checked and coded as they are read, ``catgraph.io.StoredDescriptors``).
Reported: the median wall time over the rounds, the growth of the process's peak RSS
(``VmHWM`` after, less ``VmRSS`` before) and of its RSS once the loaded map is dropped.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DIM = 512

_CHILD = r"""
import gc, json, sys, time
from catgraph.io import load_map
from catgraph.live import LiveMap

def status_mb(key):
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) / 1024 for l in f if l.startswith(key))

path, how = sys.argv[1], sys.argv[2]
before = status_mb("VmRSS")
start = time.perf_counter()
live = LiveMap(load_map(path), layout="uint8") if how == "whole" else LiveMap(path, layout="uint8")
seconds = time.perf_counter() - start
gc.collect()
print(json.dumps({"seconds": seconds, "peak_growth_mb": status_mb("VmHWM") - before,
                  "rss_growth_mb": status_mb("VmRSS") - before, "codes_mb": live.reference.nbytes / 2**20}))
"""

_MAKE = r"""
import sys
import numpy as np
from catgraph.graph import PlaceGraph
from catgraph.io import CatgraphMap, save_map

n, folder = int(sys.argv[1]), sys.argv[2]
rng = np.random.default_rng(0)
values = np.empty((n, 512), dtype=np.float32)
level = np.zeros(512, dtype=np.float32)
for a in range(0, n, 65536):  # a random walk, a block at a time
    block = np.cumsum(rng.standard_normal((min(65536, n - a), 512), dtype=np.float32), axis=0, dtype=np.float32)
    values[a : a + len(block)] = level + 0.01 * block
    level = values[a + len(block) - 1]
the_map = CatgraphMap(values, "sad", {"size": None, "patch": 4, "metric": None, "normalise": True},
                      PlaceGraph.chain(n), meta={"kind": "images"})
for name, compress in (("stored", False), ("deflated", True)):
    save_map(f"{folder}/{name}-{n}.npz", the_map, compress=compress)
"""


def _run(code: str, *args: str) -> str:
    return subprocess.run([sys.executable, "-c", code, *args], cwd="/tmp", check=True, capture_output=True,
                          text=True, env=dict(os.environ, PYTHONPATH=str(ROOT))).stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default="map_load", help="results file stem")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from machine_info import describe_machine

    cases = [(n, f, how) for n in args.sizes for f in ("stored", "deflated") for how in ("whole", "streamed")]
    runs: dict = {c: [] for c in cases}
    with tempfile.TemporaryDirectory(prefix="catgraph-map-load-") as folder:
        for n in args.sizes:
            _run(_MAKE, str(n), folder)
        for r in range(args.rounds):
            for c in cases:
                n, f, how = c
                out = json.loads(_run(_CHILD, f"{folder}/{f}-{n}.npz", how))
                runs[c].append({**out, "load": os.getloadavg()[0]})
                print(f"round {r}: {c} {runs[c][-1]}", flush=True)
    loads = [x["load"] for v in runs.values() for x in v]
    lines = [f"# A compact live map from a map file ({describe_machine()})", "",
             f"`benchmarks/bench_map_load.py` {' '.join(sys.argv[1:])}: {DIM} float32 values per place; median over "
             f"{args.rounds} rounds, a fresh process per case and round (cases alternated); load average "
             f"{min(loads):.1f}–{max(loads):.1f}. Peak and RSS: growth of the process's, from before the map.", "",
             "| places | members | map read whole, then coded: time, peak, RSS after | coded as read "
             "(`LiveMap(path)`) | peak ratio |", "|---|---|---|---|---|"]
    for n in args.sizes:
        for f in ("stored", "deflated"):
            cell = {}
            for how in ("whole", "streamed"):
                v = runs[(n, f, how)]
                cell[how] = tuple(statistics.median(x[k] for x in v) for k in ("seconds", "peak_growth_mb",
                                                                               "rss_growth_mb"))
            text = {h: f"{t:.2f} s, {p:.0f} MB, {m:.0f} MB" for h, (t, p, m) in cell.items()}
            lines.append(f"| {n:,} | {f} | {text['whole']} | {text['streamed']} | "
                         f"×{cell['whole'][1] / cell['streamed'][1]:.1f} |")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    (RESULTS / f"{args.out}.json").write_text(json.dumps({"|".join(map(str, k)): v for k, v in runs.items()},
                                                        indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
