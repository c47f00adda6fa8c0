"""Soak test: a million steps of each streaming loop, memory sampled.

A navigation stack calls ``step()`` once per sensor frame for hours. Whatever a step
allocates must be released (or live in fixed-size buffers), so memory must stay flat
however long the run. This benchmark drives (``--only`` picks one)

* ``matcher``: :meth:`catgraph.sequence.SequenceMatcher.step` with the adaptive window and
  its default rule (which runs a tracking filter of its own),
* ``filter``: :meth:`catgraph.localizer.Localizer.step`, the particle filter, with the
  online histogram observation model (it learns from every frame, so its state is
  exercised too),
* ``grid``: the registry's ``filter`` method as ``catgraph localize`` builds it, defaults
  unchanged (the exact grid filter, the tempered whole-image model), and
* ``live``: :meth:`catgraph.live.LiveLocalizer.step` with its defaults (the combined model)
  on raw descriptors, front-end and difference row included — what a navigation stack
  embeds,

for ``--steps`` frames each (default 10⁶) along a synthetic route that loops over a
chain of places, with occasional kidnaps (a jump to a random place) and frames with no
information (constant rows; for ``live``, zero descriptors). The resident set size
(``VmRSS``) and the Python heap (``tracemalloc`` would slow the steps tenfold, so the heap
is counted with ``gc.get_objects`` instead) are sampled every ``--sample-every`` steps. After a warm-up
(the first 5 % of the steps: JIT compilation, buffers reaching their size) the largest
sample must stay within 1 % of the warm-up level.

Each loop's row is kept in ``results/soak.json`` (with the commit and command that measured
it) and ``results/soak.md`` is written from every row there, so one loop can be run again
alone.

Run::

    python benchmarks/bench_soak.py                       # every loop, 10^6 steps each
    python benchmarks/bench_soak.py --only live --steps 20000 --no-write   # a quick check
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shlex
import time
from pathlib import Path

import numpy as np

from bench_live import _commit as package_commit  # the commit of the catgraph imported
from machine_info import describe_machine  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "soak.md"
STORE = RESULTS.with_suffix(".json")
#: The loops, in the table's order: ``--only`` name, row name.
LOOPS = {
    "matcher": "SequenceMatcher.step (adaptive, default rule)",
    "filter": "Localizer.step (particles, histogram)",
    "grid": "registry filter step (grid, tempered: `catgraph localize` defaults)",
    "live": "LiveLocalizer.step (combined, raw descriptors in)",
}


def rss_bytes() -> int:
    """Resident set size of this process (Linux ``/proc/self/status``)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def route_rows(n_places: int, n_rows: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A pool of normalised difference rows along a looping route: a dip at the true
    place over noise; every 97th row a kidnap, every 89th a frame with no information."""
    rng = np.random.default_rng(seed)
    rows = np.empty((n_rows, n_places))
    truth = np.empty(n_rows, dtype=np.int64)
    place = 0
    cols = np.arange(n_places)
    for k in range(n_rows):
        place = int(rng.integers(n_places)) if k % 97 == 96 else (place + 1) % n_places
        truth[k] = place
        if k % 89 == 88:
            rows[k] = 0.0
            continue
        dist = np.minimum(np.abs(cols - place), n_places - np.abs(cols - place))
        row = rng.normal(size=n_places) - 2.5 * np.exp(-0.5 * (dist / 1.5) ** 2)
        rows[k] = (row - row.mean()) / row.std()
    return rows, truth


def soak(name: str, step, rows: np.ndarray, truth: np.ndarray, n_steps: int, sample_every: int,
         progress: bool = True) -> dict:
    """Run ``step(row)`` ``n_steps`` times cycling over ``rows``; sample memory."""
    warmup = max(sample_every, n_steps // 20)
    samples: list[tuple[int, int, int]] = []
    correct = 0
    gc.collect()
    start = time.perf_counter()
    for k in range(n_steps):
        j = k % len(rows)
        if step(rows[j]) == truth[j]:
            correct += 1
        if (k + 1) % sample_every == 0:
            samples.append((k + 1, rss_bytes(), len(gc.get_objects())))
            if progress:
                print(f"{name}: step {k + 1:,}, RSS {samples[-1][1] / 2**20:.2f} MiB, {samples[-1][2]:,} objects, "
                      f"{time.perf_counter() - start:.0f} s", flush=True)
    seconds = time.perf_counter() - start
    after = [s for s in samples if s[0] >= warmup]
    base_rss, base_obj = after[0][1], after[0][2]
    max_rss = max(s[1] for s in after)
    max_obj = max(s[2] for s in after)
    return {
        "name": name, "steps": n_steps, "seconds": seconds, "us_per_step": 1e6 * seconds / n_steps,
        "warmup_steps": after[0][0], "rss_warm_mib": base_rss / 2**20, "rss_max_mib": max_rss / 2**20,
        "rss_end_mib": after[-1][1] / 2**20, "rss_growth": (max_rss - base_rss) / base_rss,
        "objects_warm": base_obj, "objects_max": max_obj, "objects_growth": (max_obj - base_obj) / base_obj,
        "samples": len(after), "top1": correct / n_steps,
    }


def filter_step(n_places: int, n_particles: int, seed: int):
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.methods import observation_model, resolve_params

    model = observation_model(resolve_params("filter", {"model": "histogram"}), n_places, None)
    loc = Localizer(PlaceGraph.chain(n_places), model, n_particles=n_particles, seed=seed)
    return lambda row: loc.step(row).place


def matcher_step(l_max: int):
    from catgraph.sequence import SequenceMatcher

    matcher = SequenceMatcher(window="adaptive", l_min=5, l_max=l_max)
    return lambda row: matcher.step(row).match


def grid_step(n_places: int):
    """The registry's ``filter`` method with its defaults, on a chain of ``n_places``."""
    from catgraph.graph import PlaceGraph
    from catgraph.methods import concrete_params, make_filter, observation_model, resolve_params

    params = concrete_params(resolve_params("filter", {}), n_places)
    loc = make_filter(params, PlaceGraph.chain(n_places), observation_model(params, n_places, None))
    loc.reset()
    return lambda row: loc.step(row).place


def route_frames(n_places: int, n_frames: int, seed: int, dims: int = 64):
    """Raw descriptors for the live loop: a random reference of ``n_places`` × ``dims``
    and query frames along the same looping route as :func:`route_rows` (each its place's
    descriptor plus noise; every 97th a kidnap, every 89th a zero descriptor)."""
    rng = np.random.default_rng(seed)
    reference = rng.random((n_places, dims)).astype(np.float32)
    frames = np.empty((n_frames, dims), dtype=np.float32)
    truth = np.empty(n_frames, dtype=np.int64)
    place = 0
    for k in range(n_frames):
        place = int(rng.integers(n_places)) if k % 97 == 96 else (place + 1) % n_places
        truth[k] = place
        frames[k] = 0.0 if k % 89 == 88 else reference[place] + rng.normal(0.0, 0.15, dims)
    return reference, frames, truth


def live_step(reference: np.ndarray):
    from catgraph.live import LiveLocalizer, LiveMap
    from catgraph.traverse import Traverse

    live = LiveLocalizer(LiveMap(Traverse(reference, name="soak reference")))
    return lambda frame: live.step(frame).place


def markdown(rows: dict[str, dict]) -> str:
    """The table of every stored loop (``rows``: :data:`STORE`'s content), in :data:`LOOPS` order."""
    lines = [
        "# Soak: a long run of `step()` with memory sampled",
        "",
        f"Generated by `benchmarks/bench_soak.py` ({describe_machine()}, "
        "shared with other work). Route: a loop over a chain of places with a kidnap every 97 frames and a frame "
        "with no information every 89; the matcher and the filters read normalised difference rows (a dip at the "
        "true place over noise), the live loop raw 64-value descriptors (its reference random, each frame its "
        "place's descriptor plus noise, the frames with no information zero). Memory sampled every "
        "`--sample-every` steps; the warm-up is the first 5 % of the steps. Each row's commit and command below "
        "the table. *Top-1 right*: the share of steps whose answer is exactly the frame's place, a check that the "
        "loop keeps localising rather than a measure of accuracy (the rows' dip spans the neighbouring places too, "
        "so the filters often answer one place off).",
        "",
        "| loop | steps | µs/step | top-1 right | RSS after warm-up (MiB) | max RSS (MiB) | RSS at end (MiB) | "
        "RSS growth | Python objects after warm-up | max objects | object growth | flat within 1 % |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|",
    ]
    ordered = [rows[k] for k in LOOPS if k in rows]
    for r in ordered:
        flat = r["rss_growth"] <= 0.01 and r["objects_growth"] <= 0.01
        top1 = "" if r.get("top1") is None else f"{r['top1']:.3f}"
        lines.append(
            f"| {r['name']} | {r['steps']:,} | {r['us_per_step']:.1f} | {top1} | {r['rss_warm_mib']:.1f} | "
            f"{r['rss_max_mib']:.1f} | {r['rss_end_mib']:.1f} | {100 * r['rss_growth']:+.2f} % | "
            f"{r['objects_warm']:,} | {r['objects_max']:,} | {100 * r['objects_growth']:+.2f} % | "
            f"{'yes' if flat else '**no**'} |"
        )
    lines += ["", "Growth = (largest sample after the warm-up − first sample after it) / first sample. "
              "The RSS counts the whole process (numpy, numba, the row pool), so the bound is on what the "
              "steps add.", ""]
    lines += [f"- {r['name']}: commit `{r.get('commit', 'unknown')}`, load {r.get('load', '?')}, "
              f"`{r.get('command', '')}`" for r in ordered]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000, help="steps per loop (default 10^6)")
    parser.add_argument("--filter-steps", type=int, help="steps of the filter loop (default --steps)")
    parser.add_argument("--matcher-steps", type=int, help="steps of the matcher loop (default --steps)")
    parser.add_argument("--places", type=int, default=300, help="places in the map (default 300)")
    parser.add_argument("--particles", type=int, default=500, help="particles in the filter (default 500)")
    parser.add_argument("--l-max", type=int, default=100, help="longest window of the matcher (default 100)")
    parser.add_argument("--sample-every", type=int, default=10_000, help="steps between memory samples")
    parser.add_argument("--only", choices=tuple(LOOPS), help="run one loop only")
    parser.add_argument("--no-write", action="store_true", help="print the table, do not write results/soak.*")
    args = parser.parse_args(argv)
    steps = {k: args.steps for k in LOOPS}
    steps["filter"] = args.filter_steps or args.steps
    steps["matcher"] = args.matcher_steps or args.steps
    chosen = [args.only] if args.only else list(LOOPS)
    if min(steps[k] for k in chosen) < 2 * args.sample_every or args.sample_every < 1:
        parser.error("every loop needs at least twice --sample-every steps")
    rows, truth = route_rows(args.places, 2000, seed=0)
    stored = json.loads(STORE.read_text()) if STORE.exists() and not args.no_write else {}
    results = []
    for key in chosen:
        if key == "matcher":
            step, data, want = matcher_step(args.l_max), rows, truth
        elif key == "filter":
            step, data, want = filter_step(args.places, args.particles, 0), rows, truth
        elif key == "grid":
            step, data, want = grid_step(args.places), rows, truth
        else:
            reference, data, want = route_frames(args.places, 2000, seed=0)
            step = live_step(reference)
        load = f"{os.getloadavg()[0]:.2f}"
        r = soak(LOOPS[key], step, data, want, steps[key], args.sample_every)
        r.update(commit=package_commit(), load=f"{load}–{os.getloadavg()[0]:.2f}",
                 command="python benchmarks/bench_soak.py " + shlex.join(
                     ["--only", key, "--steps", str(steps[key]), "--places", str(args.places), "--particles",
                      str(args.particles), "--l-max", str(args.l_max), "--sample-every", str(args.sample_every)]))
        print(r, flush=True)
        results.append(r)
        stored[key] = r
        if not args.no_write:  # each loop kept as soon as it ends
            STORE.parent.mkdir(parents=True, exist_ok=True)
            STORE.write_text(json.dumps(stored, indent=1) + "\n")
            RESULTS.write_text(markdown(stored))
    print(markdown(stored if not args.no_write else {k: r for k, r in zip(chosen, results)}))
    return 0 if all(r["rss_growth"] <= 0.01 and r["objects_growth"] <= 0.01 for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
