"""What the client of a cluster run holds: `catgraph match --map FILE --scheduler ADDRESS`.

A map file of random-walk float32 descriptors (stored uncompressed, as `catgraph build-map
--no-compress` writes it) and a query along part of its route; a `LocalCluster` of one-thread
worker processes started here. Each run is a fresh client process of the command
(`catgraph.cli.main.main`, fixed window, the hub correction on, as by default), from each
given checkout in turn, alternated over the rounds; per run the client's peak resident
memory (`VmHWM`, the client process alone: the workers are other processes) and its wall
time. The answers of every run are compared with the first run's.

    python benchmarks/bench_cluster_map.py --trees OLD NEW [--places 200000] [--rounds 2]

Writes `benchmarks/results/cluster_map.{json,md}` (`--out` another name).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

DIM = 512
RESULTS = Path(__file__).parent / "results"

_CLIENT = """
import json, sys, time
sys.path.insert(0, sys.argv[1])
start = time.perf_counter()
from catgraph.cli.main import main
rc = main(["match", "--map", sys.argv[2], sys.argv[3], "--window", "20", "--ground-truth", sys.argv[6],
           "--scheduler", sys.argv[4], "-q", "-o", sys.argv[5]])
status = dict(line.split(":", 1) for line in open("/proc/self/status"))
# VmHWM, not getrusage's ru_maxrss: that keeps the peak of the process before its exec, i.e. of the
# benchmark process it was forked from
print(json.dumps({"rc": rc, "wall_s": time.perf_counter() - start, "peak_rss_mb": int(status["VmHWM"].split()[0]) / 1024}))
"""


def write_inputs(folder: Path, n: int, n_query: int, metric: str = "sad",
                 map_name: str = "walk.npz") -> tuple[Path, Path, Path]:
    """A map of ``n`` random-walk places × :data:`DIM` float32 values (places near each
    other alike; ``metric``), stored uncompressed as ``folder/map_name``, a query of
    ``n_query`` frames along a third of the way in with noise (``query.npy``) and its
    ground truth, ±2 places (``truth.csv``); written in place, no second copy of the map."""
    from catgraph.io import build_map, save_map
    from catgraph.pipeline import FrontEnd
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(0)
    values = np.empty((n, DIM), dtype=np.float32)
    for a in range(0, n, 50_000):  # a random walk, written in place
        rng.standard_normal(dtype=np.float32, out=values[a : a + 50_000])
    np.cumsum(values, axis=0, out=values)
    the_map = build_map(Traverse(values, meta={"kind": "descriptors"}, name="walk"), FrontEnd(metric=metric))
    map_path = save_map(folder / map_name, the_map, compress=False)
    first = n // 3
    query = values[first : first + n_query] + 0.5 * rng.standard_normal((n_query, DIM), dtype=np.float32)
    np.save(folder / "query.npy", query)
    # query frame i is place first + i (±2 places)
    pairs = [f"{i},{first + i + k}" for i in range(n_query) for k in range(-2, 3)]
    (folder / "truth.csv").write_text("query,reference\n" + "\n".join(pairs) + "\n")
    return map_path, folder / "query.npy", folder / "truth.csv"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", nargs="+", required=True, help="checkouts to import catgraph from, alternated")
    parser.add_argument("--places", type=int, default=200_000)
    parser.add_argument("--query", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="cluster_map", help="results file stem in benchmarks/results/")
    args = parser.parse_args()

    import distributed

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from machine_info import describe_machine

    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        map_path, query_path, truth_path = write_inputs(folder, args.places, args.query)
        cluster = distributed.LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                                           memory_limit=0, dashboard_address=None)
        try:
            first_frames = None
            for r in range(args.rounds):
                for tree in args.trees:
                    out = folder / f"out_{r}_{Path(tree).name}.json"
                    load = os.getloadavg()[0]
                    proc = subprocess.run([sys.executable, "-c", _CLIENT, str(Path(tree).resolve()), str(map_path),
                                           str(query_path), cluster.scheduler_address, str(out), str(truth_path)],
                                          capture_output=True, text=True, cwd=tmp)
                    if proc.returncode != 0:
                        raise SystemExit(f"{tree}: {proc.stderr[-3000:]}")
                    row = json.loads(proc.stdout.strip().splitlines()[-1])
                    frames = json.loads(out.read_text())["frames"]
                    if first_frames is None:
                        first_frames = frames
                    row.update(tree=str(tree), round=r, load=load,
                               same_answers=frames["match"] == first_frames["match"]
                               and frames["confidence"] == first_frames["confidence"],
                               auc=json.loads(out.read_text())["metrics"]["auc"])
                    runs.append(row)
                    print(json.dumps(row), flush=True)
        finally:
            cluster.close()
    info = {"places": args.places, "query": args.query, "workers": args.workers, "dim": DIM,
            "map_file_mb": args.places * DIM * 4 / 2**20, "machine": describe_machine(), "runs": runs}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.out}.json").write_text(json.dumps(info, indent=1))
    lines = [
        "# The client of a cluster run on a map file",
        "",
        f"`catgraph match --map FILE QUERY --window 20 --scheduler ADDRESS` (the hub correction on, as by default): "
        f"a map of {args.places:,} places × {DIM} float32 ({info['map_file_mb']:.0f} MiB of descriptors, stored "
        f"uncompressed), a query of {args.query} frames, a `LocalCluster` of {args.workers} one-thread worker "
        f"processes; `benchmarks/bench_cluster_map.py`, each checkout's client in a fresh process, alternated over "
        f"{args.rounds} rounds. Peak RSS: the client process alone (`VmHWM`). Machine: {info['machine']}.",
        "",
        "| checkout | round | client peak RSS | wall s | same answers as the first run | AUC | load (1 min) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in runs:
        lines.append(f"| `{row['tree']}` | {row['round']} | {row['peak_rss_mb']:.0f} MB | {row['wall_s']:.1f} | "
                     f"{'yes' if row['same_answers'] else 'no'} | {row['auc']:.3f} | {row['load']:.1f} |")
    for tree in args.trees:
        mine = [row for row in runs if row["tree"] == str(tree)]
        lines.append("")
        lines.append(f"`{tree}`: median client peak {np.median([r['peak_rss_mb'] for r in mine]):.0f} MB, "
                     f"median wall {np.median([r['wall_s'] for r in mine]):.1f} s.")
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
