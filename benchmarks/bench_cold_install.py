"""Cold start as a user meets it: install, then the first run against the next ones.

Each round makes a fresh virtual environment per command, installs this tree into it
exactly as README.md says (``pip install .``; the build compiles and caches the kernels
into the wheel, ``setup.py``), then runs the command three times in fresh processes from a
neutral folder: the first run after the install, then twice warm. Commands: ``demo``
(``catgraph demo --particles 500 --quiet``) and ``live`` (the short live run of
``bench_live.py --cold-start``).
Each run counts numba's compile events (top level; callees inside their callers).
``--without-build-cache`` installs with ``CATGRAPH_BUILD_KERNEL_CACHE=0`` as well
(the build without the step: the kernels compile in the first run), alternated with the
default install round by round, so both are measured in the same session.

    python benchmarks/bench_cold_install.py [--rounds 2] [--without-build-cache] [--commands demo,live]

Writes ``benchmarks/results/cold_install.md`` and ``cold_install.json``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

#: One timed demo run: the command's seconds and the compile events' seconds per kernel.
_RUN = """
import json, sys, tempfile, time
from collections import defaultdict
from numba.core import event

compiled, stack = defaultdict(float), []


class Compiles(event.Listener):
    def on_start(self, ev):
        stack.append(time.perf_counter())

    def on_end(self, ev):
        seconds = time.perf_counter() - stack.pop()
        if not stack:
            f = ev.data["dispatcher"].py_func
            compiled[f"{f.__module__}.{f.__qualname__}"] += seconds


event.register("numba:compile", Compiles())
t0 = time.perf_counter()
from catgraph.cli.main import main
code = main(["demo", "--particles", "500", "--quiet", "--out", tempfile.mkdtemp()])
t1 = time.perf_counter()
import catgraph
print(json.dumps({"code": code, "command_s": t1 - t0, "compiled_s": dict(compiled),
                  "package": catgraph.__path__[0]}))
"""


#: The short live run of ``bench_live.py --cold-start``: import, a 288-place image map, the
#: first difference row, 20 steps of the combined model.
_LIVE = _RUN.split("t0 = time.perf_counter()")[0] + """
t0 = time.perf_counter()
from catgraph.datasets.synthetic import make_world
from catgraph.live import LiveMap, LiveLocalizer
world = make_world(seed=1, blocks=(2, 2), as_images=True)
live_map = LiveMap(world.reference, layout="uint8")
live_map.reference.row(live_map.describe(world.query.frames[0]), normalise=True)
live = LiveLocalizer(live_map, model="combined", n_particles=500)
for f in world.query.frames[:20]:
    live.step(f)
t1 = time.perf_counter()
import catgraph
print(json.dumps({"code": 0, "command_s": t1 - t0, "compiled_s": dict(compiled), "package": catgraph.__path__[0]}))
"""

#: What each round runs: the README's demo and the short live run, each in its own fresh environment.
COMMANDS = {"demo": _RUN, "live": _LIVE}


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _load() -> float:
    return os.getloadavg()[0]


def one_round(build_cache: bool, command: str = "demo") -> dict:
    """A fresh environment, the install, then the first run of ``command`` and two warm ones."""
    with tempfile.TemporaryDirectory(prefix="catgraph-cold-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
        if not build_cache:
            env["CATGRAPH_BUILD_KERNEL_CACHE"] = "0"
        start = time.perf_counter()
        subprocess.run([str(venv / "bin" / "pip"), "install", "--quiet", str(ROOT)], check=True, env=env,
                       stdout=subprocess.DEVNULL)
        install_s = time.perf_counter() - start
        runs = []
        for _ in range(3):
            load = _load()
            start = time.perf_counter()
            proc = subprocess.run([str(venv / "bin" / "python"), "-c", COMMANDS[command]], cwd=tmp,
                                  capture_output=True, text=True, env=env)
            wall = time.perf_counter() - start
            if proc.returncode != 0:
                raise SystemExit(f"the {command} run failed:\n{proc.stderr[-2000:]}")
            run = json.loads(proc.stdout.strip().splitlines()[-1])
            run.update(process_s=wall, load=[load, _load()])
            runs.append(run)
    if not runs[0]["package"].startswith(str(venv)):
        raise SystemExit(f"the run imported catgraph from {runs[0]['package']}, not from the fresh environment")
    return {"command": command, "build_cache": build_cache, "install_s": install_s, "runs": runs,
            "first_over_warm": runs[0]["process_s"] / float(np.median([r["process_s"] for r in runs[1:]]))}


def write(results: list[dict], commit: str) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "cold_install.json").write_text(json.dumps({"commit": commit, "rounds": results}, indent=1))
    lines = ["# Cold start after `pip install .`", "",
             f"Generated by `benchmarks/bench_cold_install.py` at commit `{commit}`. Each round and command: a fresh "
             "virtual environment, `pip install .` of this tree (as README.md says), then the command three times "
             "in fresh processes (the first run after the install, then twice warm); process wall seconds, and the "
             "seconds numba spent compiling (its compile events, top level). `demo`: `catgraph demo --particles "
             "500 --quiet`; `live`: the short live run of `bench_live.py --cold-start` (import, a 288-place image "
             "map, the first row, 20 combined steps). 'build cache off': the same install with "
             "`CATGRAPH_BUILD_KERNEL_CACHE=0` (the build does not compile the kernels, so the first run does). "
             "2 cores shared with other work.", "",
             "| round | command | build cache | install s | first run s (compiling s) | warm runs s | first / warm | "
             "load (1 min) |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        first, warm = r["runs"][0], r["runs"][1:]
        loads = [x for run in r["runs"] for x in run["load"]]
        lines.append(f"| {r['round']} | {r['command']} | "
                     f"{'on' if r['build_cache'] else 'off'} | {r['install_s']:.1f} | {first['process_s']:.2f} "
                     f"({sum(first['compiled_s'].values()):.2f}) | "
                     f"{', '.join(format(w['process_s'], '.2f') for w in warm)} | ×{r['first_over_warm']:.2f} | "
                     f"{min(loads):.2f}–{max(loads):.2f} |")
    for command in dict.fromkeys(r["command"] for r in results):
        for on in (True, False):
            group = [r["first_over_warm"] for r in results if r["build_cache"] == on and r["command"] == command]
            if group:
                lines.append("")
                lines.append(f"`{command}`, build cache {'on' if on else 'off'}: first run / warm, median over "
                             f"{len(group)} round{'s' if len(group) > 1 else ''}: **×{np.median(group):.2f}** "
                             "(goal ×1.5).")
        compiled: dict[str, list[float]] = {}
        for r in results:
            if r["build_cache"] and r["command"] == command:
                for name, s in r["runs"][0]["compiled_s"].items():
                    compiled.setdefault(name, []).append(s)
        lines += ["", f"Kernels the first `{command}` run compiled with the build cache on (seconds, each round): " +
                  (", ".join(f"`{n}` {' / '.join(f'{s:.2f}' for s in v)}" for n, v in sorted(compiled.items()))
                   if compiled else "none")]
    lines.append("")
    (RESULTS / "cold_install.md").write_text("\n".join(lines))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--commands", default=",".join(COMMANDS), help=f"comma-separated, of {list(COMMANDS)}")
    ap.add_argument("--without-build-cache", action="store_true",
                    help="also install with CATGRAPH_BUILD_KERNEL_CACHE=0, alternated with the default")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        raise SystemExit("--rounds must be at least 1")
    commands = [c.strip() for c in args.commands.split(",")]
    unknown = [c for c in commands if c not in COMMANDS]
    if unknown:
        raise SystemExit(f"unknown commands {unknown}; choose from {list(COMMANDS)}")
    results = []
    for k in range(args.rounds):
        for command, on in itertools.product(commands, (True, False) if args.without_build_cache else (True,)):
            r = one_round(on, command)
            r["round"] = k + 1
            results.append(r)
            print(f"round {k + 1}, {command}, build cache {'on' if on else 'off'}: install {r['install_s']:.1f} s, first "
                  f"{r['runs'][0]['process_s']:.2f} s, warm {r['runs'][1]['process_s']:.2f} / "
                  f"{r['runs'][2]['process_s']:.2f} s: x{r['first_over_warm']:.2f}", flush=True)
    write(results, _commit())


if __name__ == "__main__":
    main()
