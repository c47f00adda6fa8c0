"""Live localisation at scale: time per frame, peak memory, cold start.

Random 512-value float32 reference descriptors (a 32×16 image map), N = 10⁴, 10⁵, 10⁶
places; query frames are random 16×32 images through the map's front-end. Every
case runs in its own process (peak RSS: its own ``VmHWM``), one after another, and
measures its own *floor* in the same process: the time to read the reference once
with every core (a parallel sum over its bytes) — the least any difference row can
cost — so ratios survive a busy machine. Writes ``benchmarks/results/live.md`` (and
``live.json``).

    python benchmarks/bench_live.py [--sizes 10000 100000 1000000] [--frames 200]
    python benchmarks/bench_live.py --cold-start
    python benchmarks/bench_live.py --profile --sizes 10000 100000   # the step's pieces (live_profile.md)
    python benchmarks/bench_live.py --profile-rest --sizes 100000    # the rest's pieces (live_profile_rest.md)
    python benchmarks/bench_live.py --write-batch-inputs DIR && \
        python benchmarks/bench_live.py --batch DIR/map.npz DIR/query.npy     # every batch command's peak

Cases (per N):

``row``        :meth:`PreparedReference.row` with normalisation (SAD), all cores
``row-u8``     the same on the compact layout (``layout="uint8"``: one byte per value),
               beside its own floor (one parallel read of the uint8 codes)
``row-1t``     the same on one thread
``cosine-raw`` :func:`difference_row` on the raw reference, cosine, as a user without a
               prepared map calls it (validates and recomputes norms every call)
``cosine``     the prepared cosine row
``matcher``    :meth:`SequenceMatcher.step`, adaptive, ``l_max`` 500, on normalised rows
``matcher-1t`` the same on one thread
``grid``       :meth:`GridLocalizer.step` alone on a line graph (a precomputed observation, as
               ``bench_filter.py speed``), beside that benchmark's reference (one ``np.add``
               over ``8 × N`` float64); ``grid-1t``: one thread
``live``       :meth:`LiveLocalizer.step`, combined model, the registry's filter (the grid up
               to 10⁵ places, 2000 particles above): front-end +
               difference + matcher + filter, the full per-frame path
``live-u8``    the same on a ``LiveMap(..., layout="uint8")``
``live-u8-repeats`` the same, every query frame stepped twice (a slower query, a sensor that
               sends a scan again): the filter keeps its twin, the reading of a query
               that stood still, while frames come again

``--cold-start`` also records which kernels compile in the cold run and for how long
(numba's compile events; callees are counted inside their callers).

``matcher`` and ``live`` first fill the matcher's ring buffer with ``l_max + 1``
untimed rows (``live``: one live step, then the model's matcher stepped directly), so
memory and cost are those of the steady state (``numpy.zeros`` pages count only once
written).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from machine_info import describe_machine
from process_memory import peak_rss_mb as _peak_rss_mb
from process_memory import reset_peak as _reset_peak
from process_memory import status_mb as _status_mb

RESULTS = Path(__file__).resolve().parent / "results"
DIM = 512


def _arrays(obj, seen: set, depth: int = 0):
    """Every distinct ndarray reachable through attributes, lists and dicts (owners of
    their memory only, so a view is not counted twice)."""
    if isinstance(obj, np.ndarray):
        base = obj
        while isinstance(base.base, np.ndarray):
            base = base.base
        if id(base) not in seen:
            seen.add(id(base))
            yield base
        return
    if id(obj) in seen or depth > 8:
        return
    seen.add(id(obj))
    if isinstance(obj, (list, tuple)):
        children = obj
    elif isinstance(obj, dict):
        children = obj.values()
    else:  # attributes, those held in slots too (the frame pools)
        slots = []
        for cls in type(obj).__mro__:
            names = getattr(cls, "__slots__", ())
            slots += [names] if isinstance(names, str) else list(names)
        children = [*getattr(obj, "__dict__", {}).values(), *(getattr(obj, name, None) for name in slots)]
    for child in children:
        yield from _arrays(child, seen, depth + 1)


def _floor_ms(reference: np.ndarray, repeats: int = 7) -> float:
    """Median time to read every byte of the reference once, all cores."""
    import numba

    @numba.njit(parallel=True, fastmath=True, cache=False)
    def read_all(x):  # pragma: no cover - compiled
        total = 0.0
        for j in numba.prange(x.shape[0]):
            acc = np.float32(0.0)
            for k in range(x.shape[1]):
                acc += x[j, k]
            total += acc
        return total

    read_all(reference[:8])
    return _median_ms(lambda: read_all(reference), repeats)[0]


def _floor_codes_ms(n: int, repeats: int = 7) -> float:
    """:func:`_floor_ms` for the compact layout: one parallel read of ``N × d`` bytes."""
    codes = np.random.default_rng(0).integers(0, 256, size=(n, DIM), dtype=np.uint8)
    return _floor_ms(codes, repeats)


def _floor_numpy_codes_ms(n: int, repeats: int = 15) -> float:
    """A plain memory read of ``N × d`` bytes: numpy's sum of the codes viewed as uint64
    (one thread, streaming; no arithmetic on the bytes)."""
    codes = np.random.default_rng(0).integers(0, 256, size=(n, DIM), dtype=np.uint8).reshape(-1).view(np.uint64)
    codes.sum()
    return _median_ms(codes.sum, repeats)[0]


class _FixedModel:
    """An observation model that returns the same log-ratio every step (the filter alone)."""

    def __init__(self, log_ratio):
        from catgraph.observation import Observation

        self._obs = Observation(log_ratio, -1.0, True)

    def reset(self):
        pass

    def observe(self, row):
        return self._obs


def _step_floor_ms(live, matcher, repeats: int = 15) -> dict:
    """Plain memory passes over what one live step must touch, one thread each (numpy,
    streaming; no arithmetic worth the name), measured in the same process: the map
    as the kernels read it (viewed as uint64 and summed) and the matcher's running
    sums (``V × G × N`` integers, read and written once: ``sums += 0`` in place; their
    values do not change). Their sum is the least the step's two memory-bound parts
    can cost on one thread; a second core helps only as far as memory bandwidth does."""
    codes = live.live_map.reference.descriptors
    flat = codes.reshape(-1)
    flat = flat[: flat.size - flat.size % (8 // flat.itemsize)].view(np.uint64)
    flat.sum()
    sums = matcher._sums
    np.add(sums, 0, out=sums)
    read_ms = _median_ms(flat.sum, repeats)[0]
    sums_ms = _median_ms(lambda: np.add(sums, 0, out=sums), repeats)[0]
    return {"floor_map_read_ms": read_ms, "floor_sums_rw_ms": sums_ms, "floor_step_ms": read_ms + sums_ms}


def _timed(fn, seconds: list):
    """``fn`` that appends the seconds of every call to ``seconds``."""

    def timed(*args):
        t = time.perf_counter()
        result = fn(*args)
        seconds.append(time.perf_counter() - t)
        return result

    return timed


def _median_ms(fn, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    ms = 1000.0 * np.asarray(times)
    return float(np.median(ms)), float(np.percentile(ms, 99))


def _reference(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    out = np.empty((n, DIM), dtype=np.float32)
    for start in range(0, n, 100_000):  # written in place: no scratch beside the map
        rng.standard_normal(dtype=np.float32, out=out[start : start + 100_000])
    return out


def _commit() -> str:
    """The commit of the checkout the imported catgraph comes from (``+`` if its files
    differ from it)."""
    import catgraph

    folder = Path(catgraph.__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "-C", str(folder), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(folder), "status", "--porcelain", "--", "."], capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+" if dirty else "")


def _particles(n: int) -> dict:
    """The live step's filter options: 2,000 particles where the registry runs the particle
    filter (above ``GRID_MAX_PLACES``); none where it runs the grid, which refuses them."""
    from catgraph.methods import GRID_MAX_PLACES

    return {"n_particles": 2000} if n > GRID_MAX_PLACES else {}


def run_case(case: str, n: int, frames: int, l_max: int, anchor_rows: int) -> dict:
    """One measurement, in this process."""
    from catgraph.differences import PreparedReference, difference_row

    out: dict = {"case": case, "n": n, "frames": frames, "commit": _commit(), "load_start": os.getloadavg()[0]}
    rng = np.random.default_rng(1)
    if case in ("grid", "grid-1t"):  # the grid filter's step alone (a fixed observation), all cores or one
        from catgraph import grid
        from catgraph.graph import PlaceGraph

        if case == "grid-1t":
            grid.LINE_WORK_PER_THREAD = 1 << 62
        rows = rng.standard_normal((8, n))
        loc = grid.GridLocalizer(PlaceGraph.chain(n), _FixedModel(-rows[0])).reset()
        for k in range(5):
            loc.step(rows[k % 8])
        times = []
        for k in range(frames):
            start = time.perf_counter()
            loc.step(rows[k % 8])
            times.append(time.perf_counter() - start)
        ms = 1000.0 * np.asarray(times)
        a, b, c = (np.ones((8, n)) for _ in range(3))  # bench_filter.py speed's reference: 8 x N float64
        out.update(median_ms=float(np.median(ms)), p99_ms=float(np.percentile(ms, 99)),
                   floor_ms=_median_ms(lambda: np.add(a, b, out=c), 15)[0], peak_rss_mb=_peak_rss_mb())
        return out
    if case in ("matcher", "matcher-1t"):
        from catgraph.sequence import SequenceMatcher

        if case == "matcher-1t":
            import numba

            numba.set_num_threads(1)

        rows = rng.standard_normal((8, n))
        matcher = SequenceMatcher(window="adaptive", l_max=l_max)
        for k in range(l_max + 1):  # fill the ring buffer: steady-state memory and cost
            matcher.step(rows[k % 8])
        times = []
        for k in range(frames):
            start = time.perf_counter()
            matcher.step(rows[k % 8])
            times.append(time.perf_counter() - start)
        ms = 1000.0 * np.asarray(times)
        out.update(median_ms=float(np.median(ms)), p99_ms=float(np.percentile(ms, 99)),
                   floor_ms=float("nan"), peak_rss_mb=_peak_rss_mb(), l_max=l_max)
        return out
    compact = case in ("live-u8", "live-u8-repeats")
    if case in ("live", "live-u8", "live-u8-repeats"):
        # the process before any map: Python, numpy, numba, the live kernels loaded
        import gc

        from catgraph.live import WARM_UP_PLACES, warm_up

        # the kernels of this map's size regime loaded (or compiled) before the streaming window
        warm_up(models=("combined",), layouts=("uint8" if compact else "float32",), steps=2,
                places=tuple(p for p in WARM_UP_PLACES if p <= n))
        gc.collect()
        out["baseline_mb"] = _status_mb("VmRSS")
        out["baseline_file_mb"] = _status_mb("RssFile")  # of it, pages of files: the shared libraries' code
    reference = _reference(n)
    if not compact:  # the compact live step's floors are measured after its streaming window
        out["floor_ms"] = _floor_ms(reference)
    query = rng.standard_normal((frames, DIM), dtype=np.float32)
    if case == "row-u8":
        out["floor_u8_ms"] = _floor_codes_ms(n)
        out["floor_np_u8_ms"] = _floor_numpy_codes_ms(n)
    if case in ("row", "row-1t", "cosine", "row-u8"):
        if case == "row-1t":
            import catgraph.differences

            catgraph.differences.WORK_PER_THREAD = 1 << 62  # every call on one thread
        prepared = PreparedReference(reference, "cosine" if case == "cosine" else "sad",
                                     layout="uint8" if case == "row-u8" else "float32")
        if case == "row-u8":
            del reference  # the live process keeps the codes only
            out["map_mb"] = prepared.nbytes / 2**20
        buf = np.empty(n)
        prepared.row(query[0], normalise=True, out=buf)
        it = iter(range(10**9))
        out["median_ms"], out["p99_ms"] = _median_ms(lambda: prepared.row(query[next(it) % frames], normalise=True,
                                                                           out=buf), frames)
    elif case == "cosine-raw":
        difference_row(query[0], reference, "cosine")
        it = iter(range(10**9))
        out["median_ms"], out["p99_ms"] = _median_ms(lambda: difference_row(query[next(it) % frames], reference,
                                                                            "cosine", normalise=True),
                                                     max(3, frames // 4))
    elif case in ("live", "live-u8", "live-u8-repeats"):
        from catgraph.graph import PlaceGraph
        from catgraph.io import CatgraphMap
        from catgraph.live import LiveLocalizer, LiveMap

        layout = "uint8" if compact else "float32"
        the_map = CatgraphMap(reference, "sad", {"size": None, "patch": 4, "metric": None, "normalise": True},
                              PlaceGraph.chain(n), meta={"kind": "images"})
        del reference
        start = time.perf_counter()
        live_map = LiveMap(the_map, layout=layout)
        del the_map  # the compact map keeps only its codes; the float32 map is its own kernel array
        gc.collect()
        live = LiveLocalizer(live_map, model="combined", l_max=l_max, anchor_rows=anchor_rows, **_particles(n))
        out["prepare_s"] = time.perf_counter() - start
        out["prepare_peak_rss_mb"] = _status_mb("VmHWM")  # float map, codes, bootstrap blocks
        out["streaming_window"] = _reset_peak()  # from here: the streaming peak
        images = rng.uniform(0, 255, (frames + 1, 16, 32)).astype(np.float32)
        live.step(images[0])
        matcher = live._sequence.matcher_  # fill its ring buffer: steady-state memory and cost
        fill = np.empty(n)  # one row at a time: no buffer of rows in the streaming peak
        for k in range(l_max):
            matcher.step(rng.standard_normal(out=fill))
        del fill
        matcher_seconds, observe_seconds = [], []
        import catgraph.observation as observation

        on_second_thread = []  # frames whose whole-image part observed on the second thread (the load decides)
        beside = observation._observe_and_prepare
        observation._observe_and_prepare = lambda m, r: (on_second_thread.append(1), beside(m, r))[1]
        matcher.step = _timed(matcher.step, matcher_seconds)  # the matcher's share of the model time
        model = live.localizer_.model
        model.observe = _timed(model.observe, observe_seconds)  # the observation model's share (matcher inside)
        parts = {"frontend": [], "difference": [], "model": []}
        times = []
        for k in range(frames):
            start = time.perf_counter()
            est = live.step(images[k // 2 + 1] if case == "live-u8-repeats" else images[k + 1])
            times.append(time.perf_counter() - start)
            for key in parts:
                parts[key].append(est.seconds[key])
        ms = 1000.0 * np.asarray(times)
        out["streaming_peak_rss_mb"] = _status_mb("VmHWM")
        out["streaming_rss_file_mb"] = _status_mb("RssFile")  # at the window's end: pages of files (libraries)
        out["streaming_rss_anon_mb"] = _status_mb("RssAnon")  # and the process's own memory
        observation._observe_and_prepare = beside
        out["frames_two_threads"] = len(on_second_thread)
        del matcher.step
        del model.observe
        # what the step holds, by component (array bytes reachable from each)
        seen: set = set()
        ring = sum(a.nbytes for name, a in vars(matcher).items() if isinstance(a, np.ndarray) and "ring" in name)
        sums = sum(a.nbytes for name, a in vars(matcher).items() if isinstance(a, np.ndarray) and "sums" in name)
        held = {"map_mb": sum(a.nbytes for a in _arrays(live_map.reference, seen)),
                "matcher_mb": sum(a.nbytes for a in _arrays(matcher, seen)),
                "graph_mb": sum(a.nbytes for a in _arrays(live_map.graph, seen)),
                "filter_mb": sum(a.nbytes for a in _arrays(live.localizer_, seen)),
                "other_mb": sum(a.nbytes for a in _arrays(live, seen))}
        out.update({k: v / 2**20 for k, v in held.items()}, ring_mb=ring / 2**20, sums_mb=sums / 2**20,
                   ring_dtype=str(getattr(matcher, "_ring", np.empty(0)).dtype))
        out.update(median_ms=float(np.median(ms)), p99_ms=float(np.percentile(ms, 99)), l_max=l_max,
                   anchor_rows=anchor_rows, filter=type(live.localizer_).__name__,
                   matcher_ms=1000.0 * float(np.median(matcher_seconds)),
                   **{f"{k}_ms": 1000.0 * float(np.median(v)) for k, v in parts.items()})
        out["model_rest_ms"] = 1000.0 * float(np.median(np.asarray(parts["model"]) - np.asarray(matcher_seconds)))
        out["row_matcher_ms"] = 1000.0 * float(np.median(np.asarray(parts["difference"]) + np.asarray(matcher_seconds)))
        if case == "live-u8-repeats":  # the new frames (the twin steps too) and their repeats (the row reused)
            out["new_median_ms"] = float(np.median(ms[0::2]))
            out["repeat_median_ms"] = float(np.median(ms[1::2]))
        out["observe_rest_ms"] = 1000.0 * float(np.median(np.asarray(observe_seconds) - np.asarray(matcher_seconds)))
        out["filter_ms"] = 1000.0 * float(np.median(np.asarray(parts["model"]) - np.asarray(observe_seconds)))
        # floors last (their scratch arrays must not count in the streaming peak)
        if compact:
            out["floor_u8_ms"] = _floor_codes_ms(n)
            out["floor_np_u8_ms"] = _floor_numpy_codes_ms(n)
        out.update(_step_floor_ms(live, matcher))
        out["peak_rss_mb"] = max(out["prepare_peak_rss_mb"], _peak_rss_mb())
    else:
        raise SystemExit(f"unknown case {case!r}")
    out.setdefault("peak_rss_mb", _peak_rss_mb())
    out["load_end"] = os.getloadavg()[0]
    return out


def profile_step(n: int, rounds: int = 41, l_max: int = 500) -> dict:
    """What each piece of the live step's matcher and difference row costs at ``N = n``.

    One process; every piece is timed once per round, the pieces in turn (so a busy
    spell of the shared machine falls on all of them alike), and the floors in the same
    rounds: a plain read of the compact map (numba, one thread, vectorised; numpy's
    integer sum is slower than the memory) and a read and write of the matcher's
    running sums (``np.add(sums, 0, out=sums)``, one thread). Wall-clock medians and
    CPU-time medians of the calling thread (the latter is the work itself where a piece
    runs on one thread, and less than it where a second thread shares the work).
    """
    import numba

    from catgraph import _diff_kernels as dk
    from catgraph import _sequence_kernels as sk
    from catgraph._validation import check_array
    from catgraph._window_rule import _decide
    from catgraph.differences import PreparedReference
    from catgraph.sequence import DEFAULT_LINE_RULE, SequenceMatcher

    rng = np.random.default_rng(1)
    rows = rng.standard_normal((8, n))
    # the live step's matcher: the combined model's sequence part, whose window rule reads the
    # matcher's statistics alone (the standalone default, "tracked", runs a filter beside it)
    matcher = SequenceMatcher(window="adaptive", rule=DEFAULT_LINE_RULE, l_max=l_max)
    for k in range(l_max + 1):  # the ring filled: steady state
        matcher.step(rows[k % 8])
    cfg, st, buffers = matcher._cfg, matcher._stats, matcher._buffers
    sums, ring, mring, state = matcher._sums, matcher._ring, matcher._mring, matcher._state

    def frame():
        return matcher.n_steps_

    def step():
        matcher.step(rows[frame() % 8])

    def run_batch():
        i = frame()
        sk.run_batch(rows[i % 8][None, :], i, sums, ring, mring, state, cfg.velocities, cfg.grid, cfg.approx_code,
                     10, 1, cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights, st.locs,
                     st.scales, st.sub, *buffers)
        matcher.n_steps_ = i + 1

    def kernel_one_thread():
        saved = sk.WORK_PER_THREAD
        sk.WORK_PER_THREAD = 1 << 62  # every velocity on the calling thread: the step's own kernels, one thread
        try:
            run_batch()
        finally:
            sk.WORK_PER_THREAD = saved

    def store_row():
        i = frame() - 1  # the latest row stored again: the state does not change
        sk.store_rows(rows[i % 8][None, :], 0, 1, i, ring, mring, state)

    def decide():
        i = frame() - 1
        _decide(st, cfg, np.array([i]), False, rows[i % 8][None, :], matcher._record)

    def validate():
        np.ascontiguousarray(check_array(rows[0], "difference row", ndim=1))

    def sums_floor():
        np.add(sums, 0, out=sums)

    reference = PreparedReference(_reference(n), "sad", layout="uint8")
    codes = reference.descriptors
    flat = codes.reshape(-1)[: codes.size - codes.size % 8].view(np.uint64)
    query = rng.standard_normal((8, DIM), dtype=np.float32)
    out = np.empty(n)
    view = out.reshape(1, -1)
    q = reference.prepare_query(query[0], single=True)

    @numba.njit(nogil=True, cache=False)
    def plain_read(x):  # pragma: no cover - compiled
        total = np.uint64(0)
        for k in range(x.shape[0]):
            total += x[k]
        return total

    def row():
        reference.row(query[frame() % 8], normalise=True, out=out)

    def prepare():
        reference.prepare_query(query[0], single=True)

    def pair_one_thread():
        dk.pair_block_codes(q, codes, 0, n, dk.SAD, float(reference.step), view)

    def pair_threads():
        reference._raw(q, view)

    def normalise():
        dk.normalise_row(out, out)

    pieces = {
        "matcher: SequenceMatcher.step (everything)": step,
        "matcher: run_batch (store + kernel, threads)": run_batch,
        "matcher: store + kernel, all velocities, one thread": kernel_one_thread,
        "matcher: store_rows (one row)": store_row,
        "matcher: window rule (_decide, Python + numpy)": decide,
        "matcher: validating the row (check_array)": validate,
        "floor: read + write the running sums (numpy, one thread)": sums_floor,
        "row: PreparedReference.row, normalised (everything)": row,
        "row: prepare_query (encode the descriptor)": prepare,
        "row: pair_block_codes, one thread": pair_one_thread,
        "row: pair_block_codes, threads (_raw)": pair_threads,
        "row: normalise_row": normalise,
        "floor: plain read of the compact map (numba, one thread)": lambda: plain_read(flat),
        "floor: numpy sum of the compact map as uint64 (as live.md)": flat.sum,
    }
    for fn in pieces.values():  # compiled and warm
        fn()
    wall = {k: [] for k in pieces}
    cpu = {k: [] for k in pieces}
    load = [os.getloadavg()[0]]
    for _ in range(rounds):
        for key, fn in pieces.items():
            c, t = time.thread_time(), time.perf_counter()
            fn()
            wall[key].append(time.perf_counter() - t)
            cpu[key].append(time.thread_time() - c)
    load.append(os.getloadavg()[0])
    return {"n": n, "rounds": rounds, "commit": _commit(), "threads": numba.get_num_threads(), "load": load,
            "pieces": {k: {"wall_ms": 1000 * float(np.median(wall[k])), "cpu_ms": 1000 * float(np.median(cpu[k])),
                           "wall_min_ms": 1000 * float(np.min(wall[k]))} for k in pieces}}


#: What ``--profile-rest`` times: (module, owner or None, name) of the observation's and
#: the grid filter's functions, each wrapped in the running process.
REST_PIECES = (
    [("catgraph.grid", "GridLocalizer", name) for name in ("step", "_exp_ratio", "_predict", "_update", "_summarise",
                                                           "_feedback")]
    + [("catgraph.grid", None, name) for name in ("_line_predict", "_line_setup", "_line_blocks", "_evidence_sums",
                                                  "_posterior_pass", "_inside_outside")]
    + [("catgraph.localizer", None, "_smoothed"), ("catgraph.sequence", "SequenceMatcher", "step"),
       ("catgraph.sequence", "SequenceMatcher", "window_scores")]
    + [("catgraph.observation", "CombinedObservation", name) for name in ("observe", "feedback")]
    + [("catgraph.observation", "SequenceObservation", "observe")]
    + [("catgraph.observation", "TemperedObservation", name) for name in ("observe", "feedback", "_hub", "_novelty",
                                                                          "_tempered", "_observe_standardised",
                                                                          "_prepare_levels", "_add_to_levels")]
    + [("catgraph.observation", None, "_observe_parts"), ("catgraph.observation", "_NearMedian", "median"),
       ("catgraph.observation", None, "_median")]
    # the particle filter (the registry's above GRID_MAX_PLACES places)
    + [("catgraph.localizer", "Localizer", name) for name in ("step", "_evidence", "_move", "_inject",
                                                              "_predicted_mass", "_predict_jumps", "_reweight",
                                                              "_resample_if_degenerate", "_summarise", "_feedback")]
    + [("catgraph.localizer", None, name) for name in ("_check_observation", "_likelihood_cumulative",
                                                       "_birth_kernel", "_reweight_kernel", "_resample_pool")]
    + [("catgraph.observation", "RecentSupport", "_support")]
)


def profile_rest(n: int, frames: int = 60, l_max: int = 500) -> dict:
    """What each function of the live step's rest (the whole-image model, the
    combination, the grid filter) costs at ``N = n``: the compact live step (combined
    model), ring filled, every function of :data:`REST_PIECES` and every compiled pass of
    :mod:`catgraph._observation_kernels` wrapped, ``frames`` frames; per piece the median
    CPU ms of the calling thread (the work itself, not the waits for a busy core) and wall
    ms, and how often it runs per frame. A wrapped piece includes the pieces it calls."""
    import importlib

    from catgraph.graph import PlaceGraph
    from catgraph.io import CatgraphMap
    from catgraph.live import LiveLocalizer, LiveMap

    rng = np.random.default_rng(1)
    the_map = CatgraphMap(_reference(n), "sad", {"size": None, "patch": 4, "metric": None, "normalise": True},
                          PlaceGraph.chain(n), meta={"kind": "images"})
    live = LiveLocalizer(LiveMap(the_map, layout="uint8"), model="combined", l_max=l_max, **_particles(n))
    del the_map
    images = rng.uniform(0, 255, (frames + 4, 16, 32)).astype(np.float32)
    live.step(images[0])
    matcher = live._sequence.matcher_
    fill = np.empty(n)
    for _ in range(l_max):  # the ring filled: steady state
        matcher.step(rng.standard_normal(out=fill))
    cpu: dict = {}
    wall: dict = {}
    counting = [False]

    def wrap(owner, name, label):
        fn = getattr(owner, name)

        def timed(*args, **kwargs):
            c, t = time.thread_time(), time.perf_counter()
            out = fn(*args, **kwargs)
            if counting[0]:
                wall.setdefault(label, []).append(time.perf_counter() - t)
                cpu.setdefault(label, []).append(time.thread_time() - c)
            return out

        setattr(owner, name, timed)

    for k in range(3):  # every kernel of the path compiled before any is wrapped
        live.step(images[1 + k])
    for module, owner, name in REST_PIECES:
        mod = importlib.import_module(module)
        wrap(getattr(mod, owner) if owner else mod, name, f"{owner or module.split('.')[-1]}.{name}")
    kernels = importlib.import_module("catgraph._observation_kernels")
    called_by_kernels = {"block_starts", "pairwise_sum"}  # globals of other kernels: left as they are
    for name in [k for k in vars(kernels) if not k.startswith("_") and k not in called_by_kernels
                 and hasattr(getattr(kernels, k), "py_func")]:
        wrap(kernels, name, f"_observation_kernels.{name}")
    load = [os.getloadavg()[0]]
    counting[0] = True
    for k in range(frames):
        live.step(images[4 + k] if 4 + k < len(images) else images[-1])
    counting[0] = False
    load.append(os.getloadavg()[0])
    per = {k: len(v) / frames for k, v in cpu.items()}
    out = {k: {"cpu_ms": 1e3 * float(np.median(v)), "wall_ms": 1e3 * float(np.median(wall[k])), "per_frame": per[k]}
           for k, v in cpu.items()}
    step_key = "GridLocalizer.step" if "GridLocalizer.step" in cpu else "Localizer.step"
    step, match, observe = (np.asarray(cpu[k]) for k in (step_key, "SequenceMatcher.step",
                                                        "CombinedObservation.observe"))
    totals = {"rest (filter step less the matcher)": 1e3 * float(np.median(step - match)),
              "observation less the matcher": 1e3 * float(np.median(observe - match)),
              "filter (step less the observation)": 1e3 * float(np.median(step - observe))}
    return {"n": n, "frames": frames, "commit": _commit(), "load": load, "pieces": out, "totals_cpu_ms": totals,
            "filter": type(live.localizer_).__name__,
            "package": str(Path(importlib.import_module("catgraph").__file__).parent)}


def write_profile_rest(results: list[dict], path: Path) -> None:
    """``live_profile_rest.md``: the rest's pieces, most time per frame first."""
    lines = ["# The live step's rest, piece by piece", "",
             "Generated by `benchmarks/bench_live.py --profile-rest`: the compact live step (combined model, the "
             "registry's filter: the grid filter up to 10⁵ places, the particle filter with 2000 particles above), the "
             "matcher's ring filled, every function of the whole-image model, the combination and the filter wrapped "
             "in the running process; per piece the median over the frames of the CPU time of "
             "the calling thread (the work itself, not the waits for a busy core) and of the wall clock, and the "
             "calls per frame. A piece includes the pieces it calls. 2 cores shared with other work.", ""]
    for r in results:
        lines += [f"## N = {r['n']:,} (commit {r['commit']}, {r.get('filter', 'GridLocalizer')}, {r['frames']} frames, "
                  f"load {r['load'][0]:.2f} -> {r['load'][1]:.2f})", "", "| CPU ms of the calling thread, median per frame | |", "|---|---|"]
        lines += [f"| {k} | {v:.3f} |" for k, v in r["totals_cpu_ms"].items()]
        lines += ["", "| piece | CPU ms per call | wall ms per call | calls per frame |", "|---|---|---|---|"]
        for k, v in sorted(r["pieces"].items(), key=lambda kv: -kv[1]["cpu_ms"] * kv[1]["per_frame"]):
            lines.append(f"| `{k}` | {v['cpu_ms']:.3f} | {v['wall_ms']:.3f} | {v['per_frame']:.0f} |")
        lines.append("")
    path.write_text("\n".join(lines))


def write_profile(results: list[dict], path: Path) -> None:
    """``live_profile.md``: the pieces side by side for each ``N``."""
    sizes = [r["n"] for r in results]
    lines = ["# The live step's matcher and difference row, piece by piece", "",
             "Generated by `benchmarks/bench_live.py --profile`: one process per N; every piece timed once per "
             "round, the pieces in turn, the floors in the same rounds. Wall = median wall-clock ms (min in "
             "brackets); CPU = median CPU ms of the calling thread (the work itself for one-thread pieces; less "
             "than the work where a second thread shares it). 2 cores shared with other work: compare each "
             "piece with the floors of its own column.", "",
             "| piece | " + " | ".join(f"N = {n:,}: wall (min) | CPU" for n in sizes) + " |",
             "|---|" + "---|---|" * len(sizes)]
    for key in results[0]["pieces"]:
        cells = []
        for r in results:
            p = r["pieces"][key]
            cells.append(f"{p['wall_ms']:.2f} ({p['wall_min_ms']:.2f}) | {p['cpu_ms']:.2f}")
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    lines += ["", "Commit, rounds, threads and the 1-minute load average before and after: " + "; ".join(
        f"N = {r['n']:,}: {r['commit']}, {r['rounds']} rounds, {r['threads']} threads, load {r['load'][0]:.2f} -> "
        f"{r['load'][1]:.2f}" for r in results) + ".", ""]
    path.write_text("\n".join(lines))


#: How a case's process starts: this module imported, not run by path. CPython keeps the
#: syntax tree of a script run by path until the script ends (``python bench_live.py``:
#: 3.4 MB of this 1,200-line file in every worker's memory, measured on the process before
#: the map, 176.8 against 173.3 MB), a cost of the benchmark, not of what it measures.
_WORKER = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r}); "
           "import bench_live; bench_live.main()")


def _subprocess(args: list[str], env: dict | None = None) -> dict:
    proc = subprocess.run([sys.executable, "-c", _WORKER, *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})})
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}",
                "args": args}
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------
# cold start

_COLD_SCRIPT = """
import time, json, numpy as np
from collections import defaultdict
from numba.core import event

compiled, stack = defaultdict(float), []


class Compiles(event.Listener):
    def on_start(self, ev):
        stack.append(time.perf_counter())

    def on_end(self, ev):
        seconds = time.perf_counter() - stack.pop()
        if not stack:  # top level only: callees compile inside their callers
            f = ev.data["dispatcher"].py_func
            compiled[f"{f.__module__}.{f.__qualname__}"] += seconds


event.register("numba:compile", Compiles())
t0 = time.perf_counter()
from catgraph.datasets.synthetic import make_world
from catgraph.live import LiveMap, LiveLocalizer
world = make_world(seed=1, blocks=(2, 2), as_images=True)
live_map = LiveMap(world.reference, layout=LAYOUT)
t1 = time.perf_counter()
live_map.reference.row(live_map.describe(world.query.frames[0]), normalise=True)
t2 = time.perf_counter()
live = LiveLocalizer(live_map, model="combined")
for f in world.query.frames[:20]:
    live.step(f)
t3 = time.perf_counter()
import catgraph
print(json.dumps({"import_and_map_s": t1 - t0, "first_row_s": t2 - t1, "twenty_combined_steps_s": t3 - t2,
                  "total_s": t3 - t0, "compiled_s": dict(sorted(compiled.items(), key=lambda kv: -kv[1])),
                  "package": catgraph.__path__[0]}))
"""


_COLD_CLI_SCRIPT = _COLD_SCRIPT.split("t0 = time.perf_counter()")[0] + """
t0 = time.perf_counter()
from catgraph.cli.main import main
code = main(ARGV)
t1 = time.perf_counter()
assert code == 0, code
import catgraph
print(json.dumps({"command_s": t1 - t0, "compiled_s": dict(sorted(compiled.items(), key=lambda kv: -kv[1])),
                  "package": catgraph.__path__[0]}))
"""

#: The command line the CLI cold start runs (the demo's three methods on a small world).
COLD_CLI_ARGV = ["demo", "--particles", "500", "--quiet", "--out", "OUT"]


def cold_start(layout: str = "uint8", tree: str | None = None, warm_up: bool = False, cli: bool = False) -> dict:
    """The same short live run three times in fresh processes with an empty numba cache
    directory (cold, then warm twice). ``tree``: import catgraph from that checkout
    (a frozen copy, so no file changes between the runs and invalidates the cache).
    ``warm_up``: first run :func:`catgraph.live.warm_up` in its own process (what an
    install step would do) and time it; the three runs come after it."""
    runs = []
    env = dict(os.environ)
    if tree:
        env["PYTHONPATH"] = tree + os.pathsep + env.get("PYTHONPATH", "")
    script = _COLD_SCRIPT.replace("LAYOUT", repr(layout))
    warm_up_s = None
    with tempfile.TemporaryDirectory() as cache:
        if cli:
            argv = [cache + "/demo" if a == "OUT" else a for a in COLD_CLI_ARGV]
            script = _COLD_CLI_SCRIPT.replace("ARGV", repr(argv))
        if warm_up:  # the install step: `catgraph warm-up` (live paths and batch methods)
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", "from catgraph.cli.main import main; main(['warm-up', '-q'])"],
                           check=True, env={**env, "NUMBA_CACHE_DIR": cache}, cwd=cache)
            warm_up_s = time.perf_counter() - start
        for label in ("first after warm-up" if warm_up else "cold", "warm", "warm"):
            start = time.perf_counter()
            # run in the cache folder: ``python -c`` puts its working directory first on
            # the path, which would import the working tree's package instead of ``tree``
            proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                                  env={**env, "NUMBA_CACHE_DIR": cache}, cwd=cache)
            wall = time.perf_counter() - start
            if proc.returncode != 0:
                raise SystemExit(proc.stderr)
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            row.update(label=label, process_s=wall, load=os.getloadavg()[0])
            if tree and not row.get("package", "").startswith(str(Path(tree).resolve())):
                raise SystemExit(f"the run imported catgraph from {row.get('package')!r}, not from {tree!r}")
            runs.append(row)
    return {"runs": runs, "layout": layout, "tree": tree, "warm_up_s": warm_up_s,
            "argv": COLD_CLI_ARGV if cli else None}


# ---------------------------------------------------------------------------------------
# batch commands on a large saved map

def _batch_commands() -> tuple:
    """``(label, arguments after the map and query)`` of :func:`batch_commands`: the
    matcher's fixed and adaptive windows, then ``localize`` with every observation model
    the filter takes (``catgraph.methods.FILTER_MODELS``, the names the CLI offers)."""
    from catgraph.methods import FILTER_MODELS

    return (("match --window 50", ["match", "--window", "50"]),
            ("match --window adaptive", ["match", "--window", "adaptive"]),
            *((f"localize --model {m}", ["localize", "--model", m]) for m in FILTER_MODELS))


def write_batch_inputs(folder: str, n: int = 100_000, n_query: int = 1000) -> tuple[Path, Path]:
    """The inputs of ``--batch`` in ``folder``: a saved map of ``n`` places (a random walk,
    cosine; ``map.npz``) and a query of ``n_query`` frames along it (``query.npy``), as
    ``bench_cluster_map.py`` writes its own."""
    from bench_cluster_map import write_inputs

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    map_path, query_path, _ = write_inputs(out, n, n_query, metric="cosine", map_name="map.npz")
    return map_path, query_path


def batch_commands(map_file: str, query_file: str, tree: str | None = None) -> dict:
    """Peak RSS (``VmHWM`` of the child) and wall time of each batch command on a
    saved map, one fresh process each, one after the other. The processes start in a
    scratch folder: ``python -c`` puts its working directory first on the module path, so
    from a checkout they would import that checkout's package instead of ``tree``'s."""
    map_file, query_file = str(Path(map_file).resolve()), str(Path(query_file).resolve())
    env = dict(os.environ)
    if tree:
        env["PYTHONPATH"] = tree + os.pathsep + env.get("PYTHONPATH", "")
    rows = []
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        for label, args in _batch_commands():
            script = ("import sys, time; from catgraph.cli.main import main; t = time.perf_counter(); "
                      f"code = main({[args[0], '--map', map_file, query_file, *args[1:], '-q', '-o', folder + '/out.json']!r}); "
                      "hwm = next(l for l in open('/proc/self/status') if l.startswith('VmHWM:')); "
                      "print(code, time.perf_counter() - t, int(hwm.split()[1]) / 1024)")
            proc = subprocess.run([sys.executable, "-c", script + "; import catgraph; print(catgraph.__file__)"],
                                  capture_output=True, text=True, env=env, cwd=folder)
            if proc.returncode != 0:
                rows.append({"label": label, "error": proc.stderr.strip().splitlines()[-1]})
                continue
            *_, last, package = proc.stdout.strip().splitlines()
            code, seconds, peak = last.split()
            n_query = len(json.loads(Path(folder, "out.json").read_text())["frames"]["match"])
            rows.append({"label": label, "exit": int(code), "seconds": float(seconds), "peak_rss_mb": float(peak),
                         "ms_per_frame": 1000.0 * float(seconds) / n_query, "package": str(Path(package).parent)})
            print(f"  {rows[-1]}", file=sys.stderr, flush=True)
    from catgraph.io import load_map

    places, dim = load_map(map_file, descriptors="stream", graph=False).descriptors.shape
    frames = np.load(query_file, mmap_mode="r").shape[0]
    source = f"catgraph from `{tree}`" if tree else f"at `{_commit()}`"  # _commit: this process's catgraph
    note = (f"a map of {places:,} places × {dim} values and a query of {frames:,} frames, {source}, "
            f"load {load[0]:.1f}–{os.getloadavg()[0]:.1f}")
    return {"map": map_file, "query": query_file, "rows": rows, "peak": "VmHWM", "note": note}


# ---------------------------------------------------------------------------------------
# Dask shards


def dask_shards(shard_places: int = 1 << 18, n_shards: int = 2, block_rows: int = 32, window: int = 50,
                n_query: int = 96, layout: str = "float32") -> dict:
    """Per-shard figures of :func:`catgraph.distributed.match_fixed_window` on a local
    cluster of ``n_shards`` one-thread worker processes (one shard each)."""
    import distributed

    from catgraph import distributed as dd

    reference = _reference(shard_places * n_shards)
    rng = np.random.default_rng(2)
    start_place = shard_places - 40  # a route stretch that crosses the shard edge
    query = reference[start_place : start_place + n_query] + 0.3 * rng.standard_normal((n_query, DIM),
                                                                                        dtype=np.float32)

    def counters(dask_worker):
        import psutil

        return {"rss": psutil.Process().memory_info().rss,
                "out": getattr(dask_worker, "transfer_outgoing_bytes_total", 0)}

    with distributed.LocalCluster(n_workers=n_shards, threads_per_worker=1, processes=True,
                                  dashboard_address=None, memory_limit=None) as cluster, \
            distributed.Client(cluster) as client:
        t0 = time.perf_counter()
        ref = dd.shard_reference(reference, "sad", client, shard_places=shard_places, layout=layout)
        client.gather(ref.shards)
        prepare_s = time.perf_counter() - t0
        before = client.run(counters)
        dd.match_fixed_window(query[:block_rows], ref, window, block_rows=block_rows)  # warm the kernels
        t1 = time.perf_counter()
        res = dd.match_fixed_window(query, ref, window, block_rows=block_rows)
        seconds = time.perf_counter() - t1
        after = client.run(counters)
    correct = float(np.mean(np.abs(res.match[window:] - (start_place + np.arange(window, n_query))) <= 1))
    return {"layout": layout, "shard_places": shard_places, "n_shards": n_shards, "block_rows": block_rows, "window": window,
            "n_query": n_query, "prepare_s": prepare_s, "ms_per_frame": 1000 * seconds / n_query,
            "worker_rss_mb": [a["rss"] / 2**20 for a in after.values()],
            "bytes_out_per_frame": [(a["out"] - b["out"]) / n_query for a, b in zip(after.values(), before.values())],
            "correct_after_window": correct}


# ---------------------------------------------------------------------------------------
# report


def _fmt(v, digits=1):
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{digits}f}"


def cold_start_compare(trees: list[str], rounds: int = 3) -> dict:
    """:func:`cold_start` of ``catgraph demo`` (``cli``) for each frozen tree, the trees
    alternated round after round (each round: an empty cache, cold, warm, warm), so that
    the machine's load falls on each alike."""
    runs: dict = {tree: [] for tree in trees}
    for _ in range(rounds):
        for tree in trees:
            runs[tree].append(cold_start(tree=tree, cli=True))
            r = runs[tree][-1]["runs"]
            print(tree, [(x["label"], round(x["process_s"], 2), round(x["load"], 2)) for x in r], file=sys.stderr,
                  flush=True)
    return {"trees": trees, "rounds": rounds, "runs": runs, "argv": COLD_CLI_ARGV}


def _compare_lines(compare: dict) -> list[str]:
    """The cold/warm table of :func:`cold_start_compare`."""
    lines = ["", "### `catgraph " + " ".join(compare["argv"]) + "`, empty cache: the trees alternated", "",
             f"{compare['rounds']} rounds, each tree in its own empty `NUMBA_CACHE_DIR` per round (cold, warm, warm; "
             "fresh processes); medians over the rounds, the ratio per round (cold over the round's median warm) "
             "and its median:", "",
             "| tree | cold s | warm s | cold / warm per round | median | compiled s (cold) | load (1 min) |",
             "|---|---|---|---|---|---|---|"]
    for tree, rounds in compare["runs"].items():
        cold = [r["runs"][0]["process_s"] for r in rounds]
        warm = [float(np.median([x["process_s"] for x in r["runs"][1:]])) for r in rounds]
        ratio = [c / w for c, w in zip(cold, warm)]
        compiled = [sum(r["runs"][0]["compiled_s"].values()) for r in rounds]
        loads = [x["load"] for r in rounds for x in r["runs"]]
        lines.append(f"| `{tree}` | {np.median(cold):.2f} | {np.median(warm):.2f} | "
                     f"{', '.join(f'×{x:.2f}' for x in ratio)} | ×{np.median(ratio):.2f} | {np.median(compiled):.2f} | "
                     f"{min(loads):.1f}–{max(loads):.1f} |")
    lines += ["", "Kernels compiled by the cold run (numba compile events, top level; seconds, median over the "
              "rounds; blank: not compiled):", "", "| kernel | " + " | ".join(f"`{t}`" for t in compare["runs"]) + " |",
              "|---|" + "---|" * len(compare["runs"])]
    names: dict = {}
    for rounds in compare["runs"].values():
        for r in rounds:
            for k, v in r["runs"][0]["compiled_s"].items():
                names[k] = max(names.get(k, 0.0), v)
    for name in sorted(names, key=lambda k: -names[k]):
        cells = []
        for rounds in compare["runs"].values():
            got = [r["runs"][0]["compiled_s"].get(name) for r in rounds]
            got = [g for g in got if g is not None]
            cells.append(f"{np.median(got):.2f}" if got else "")
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return lines


def write_report(results: list[dict], cold: dict | None, path: Path, shards: dict | None = None,
                 after_warm_up: dict | None = None, shards_uint8: dict | None = None,
                 cli_cold: dict | None = None, batch: dict | None = None, cold_compare: dict | None = None) -> None:
    by = {(r.get("case"), r.get("n")): r for r in results if "error" not in r}
    sizes = sorted({r["n"] for r in results if "n" in r})
    lines = ["# Live localisation: time per frame, memory, cold start", "",
             f"Random {DIM}-value float32 reference descriptors; measured on "
             f"{'; '.join(sorted({r['machine'] for r in results if 'machine' in r})) or 'a machine not recorded'} "
             "(per row in `live.json`; rows of runs before machines were recorded name none), shared with other "
             "work (medians are noisy: compare each figure with the floor measured in the same process). "
             "Generated by `benchmarks/bench_live.py`; the package measured: commit " +
             ", ".join(sorted({r.get("commit", "unrecorded") for r in results if "error" not in r})) +
             " (per row in `live.json`).", "",
             "Floor = one parallel read of the reference (N × 2 KiB as float32, N × 512 B as uint8 codes), the "
             "least a difference row can cost; each figure is beside the floor measured in the same process.", ""]
    loads = {}
    for r in results:
        if "load_start" in r and "error" not in r:
            loads.setdefault(r["n"], []).extend([r["load_start"], r.get("load_end", r["load_start"])])
    if loads:
        lines += ["The machine's 1-minute load average at the start and end of the cases that recorded it (2 cores): " +
                  "; ".join(f"N = {n:,}: {min(v):.2f}–{max(v):.2f}" for n, v in sorted(loads.items())) + ".", ""]
    threaded = {r["n"]: (r["frames_two_threads"], r["frames"]) for r in results
                if r.get("case") == "live-u8" and "frames_two_threads" in r}
    if threaded:
        lines += ["Frames of the compact live step whose whole-image model observed on a second thread beside the "
                  "matcher (on where the load of other processes leaves a core free): " +
                  "; ".join(f"N = {n:,}: {k} of {f}" for n, (k, f) in sorted(threaded.items())) + ".", ""]
    lines += ["| per frame | " + " | ".join(f"N = {n:,}" for n in sizes) + " |",
              "|---|" + "---|" * len(sizes)]

    def row(label, case, key="median_ms", ratio=True, floor="floor_ms"):
        cells = []
        for n in sizes:
            r = by.get((case, n))
            if r is None:
                cells.append("not run")
                continue
            if key not in r:  # a row measured before this figure was recorded
                cells.append("not recorded")
                continue
            text = f"{_fmt(r[key])} ms"
            if key == "median_ms":
                text += f" (p99 {_fmt(r['p99_ms'])})"
            if ratio and np.isfinite(r.get(floor, float("nan"))):
                text += f", ×{r[key] / r[floor]:.1f} floor" + {"floor_u8_ms": " (uint8)",
                                                                "floor_np_u8_ms": " (numpy read)",
                                                                "floor_step_ms": " (step)"}.get(floor, "")
            cells.append(text)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")

    def floor_row(case="row", key="floor_ms", label="floor: read the float32 reference once, all cores"):
        cells = [f"{_fmt(by[(case, n)][key])} ms" if key in by.get((case, n), {}) else "—" for n in sizes]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")

    floor_row()
    floor_row("row-u8", "floor_u8_ms", "floor (uint8): read the compact reference (N × 512 bytes) once, all cores")
    floor_row("row-u8", "floor_np_u8_ms", "floor (uint8, plain memory read): numpy sum of the codes as uint64, "
              "one thread")
    row("difference row + normalisation (SAD, prepared map, all cores)", "row")
    row("**compact layout** (uint8 codes): row + normalisation, all cores", "row-u8", floor="floor_u8_ms")
    row("the same, against the plain memory read", "row-u8", floor="floor_np_u8_ms")
    row("the same, one thread", "row-1t")
    row("`difference_row`, cosine, raw reference (validates every call)", "cosine-raw")
    row("prepared cosine row + normalisation", "cosine")
    row("`SequenceMatcher.step` (adaptive, l_max 500, as it is)", "matcher", ratio=False)
    row("the same, one thread", "matcher-1t", ratio=False)
    row("grid filter step alone (line graph, 8 velocities in 10 bins, a precomputed observation), all cores, "
        "against one `np.add` over 8 × N float64 (`bench_filter.py speed`'s reference)", "grid")
    row("the same, one thread", "grid-1t")
    row("full live step, combined model (the grid up to 10⁵ places, 2000 particles above)", "live")
    row("… of which front-end", "live", "frontend_ms", ratio=False)
    row("… of which difference row", "live", "difference_ms", ratio=False)
    row("… of which models + filter", "live", "model_ms", ratio=False)
    row("… … of which the sequence matcher (`SequenceMatcher.step`)", "live", "matcher_ms", ratio=False)
    row("… … of which the rest (whole-image model, combination, filter)", "live", "model_rest_ms", ratio=False)
    row("**full live step on the compact map** (combined; the grid up to 10⁵ places, 2000 particles above)", "live-u8", floor="floor_u8_ms")
    row("… of which front-end", "live-u8", "frontend_ms", ratio=False)
    row("… of which difference row", "live-u8", "difference_ms", ratio=False)
    row("… of which models + filter", "live-u8", "model_ms", ratio=False)
    row("… … of which the sequence matcher (`SequenceMatcher.step`)", "live-u8", "matcher_ms", ratio=False)
    row("… … of which the rest (whole-image model, combination, filter)", "live-u8", "model_rest_ms", ratio=False)
    row("… … … of which the whole-image model and the combination (observation less matcher)", "live-u8",
        "observe_rest_ms", ratio=False)
    row("… … … of which the filter (predict, update, estimate, the model's feedback)", "live-u8", "filter_ms",
        ratio=False)
    row("full live step on the compact map, every frame twice (the filter's twin lives through the repeats)",
        "live-u8-repeats", floor="floor_u8_ms")
    row("… the frames new (the filter and its twin step)", "live-u8-repeats", "new_median_ms", ratio=False)
    row("… the frames repeated (the previous frame's row, the filter alone steps)", "live-u8-repeats",
        "repeat_median_ms", ratio=False)
    row("full live step on the compact map, against the plain memory read", "live-u8", floor="floor_np_u8_ms")
    floor_row("live-u8", "floor_map_read_ms", "floor: plain read of the map as the kernels read it (numpy, one thread)")
    floor_row("live-u8", "floor_sums_rw_ms", "floor: plain read + write of the matcher's running sums "
              "(V × G × N int32; numpy, one thread)")
    floor_row("live-u8", "floor_step_ms", "floor of the step: the two together")
    row("full live step on the compact map, against the floor of the step", "live-u8", floor="floor_step_ms")
    row("… of which difference row + matcher, against the same floor", "live-u8", "row_matcher_ms",
        floor="floor_step_ms")
    lines += ["", "Peak RSS of each process (reference, buffers, models; Python and numba ≈ 150–200 MB):", "",
              "| process | " + " | ".join(f"N = {n:,}" for n in sizes) + " |", "|---|" + "---|" * len(sizes)]
    for label, case in (("difference rows (SAD)", "row"), ("difference rows, compact layout (the peak includes the float map while it is coded; the codes are N × 512 B)", "row-u8"),
                        ("matcher alone (adaptive, l_max 500)", "matcher"),
                        ("full live step (combined), whole process (preparing included)", "live"),
                        ("full live step (combined), compact map, whole process (the float map while it is coded "
                         "included)", "live-u8")):
        cells = []
        for n in sizes:
            r = by.get((case, n))
            cells.append("not run" if r is None else f"{_fmt(r['peak_rss_mb'], 0)} MB")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")

    def mem_row(label, case, value):
        cells = []
        for n in sizes:
            r = by.get((case, n))
            cells.append("not run" if r is None or "streaming_peak_rss_mb" not in r else value(r))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")

    def floor_mb(r):
        return r["baseline_mb"] + r["map_mb"] + r["ring_mb"] + r["sums_mb"]

    for case, what in (("live-u8", "compact map (uint8 codes)"),
                       ("live-u8-repeats", "compact map, every frame twice (the filter's twin)"),
                       ("live", "float32 map")):
        if not any((case, n) in by and "streaming_peak_rss_mb" in by[(case, n)] for n in sizes):
            continue
        mem_row(f"**streaming peak, full live step, {what}** (after preparing; ring filled, frames stepped)", case,
                lambda r: f"{r['streaming_peak_rss_mb']:.0f} MB, ×{r['streaming_peak_rss_mb'] / floor_mb(r):.2f} floor")
        mem_row("… at the window's end: the process's own memory (`RssAnon`) + pages of files, the shared "
                "libraries' code most (`RssFile`: reclaimable, shared with other processes)", case,
                lambda r: (f"{r['streaming_rss_anon_mb']:.0f} + {r['streaming_rss_file_mb']:.0f} MB"
                           if "streaming_rss_file_mb" in r else "not recorded"))
        mem_row("… floor: the process before the map + the map + the matcher's ring and sums", case,
                lambda r: f"{floor_mb(r):.0f} MB")
        mem_row("… … the process before the map (Python, numpy, numba, live kernels loaded; of it, pages of files)",
                case, lambda r: f"{r['baseline_mb']:.0f} MB" + (f" ({r['baseline_file_mb']:.0f} MB)"
                                                               if "baseline_file_mb" in r else ""))
        mem_row("… … the map as the kernels read it", case, lambda r: f"{r['map_mb']:.0f} MB")
        mem_row("… … the matcher's ring of the last l_max + 1 rows", case,
                lambda r: f"{r['ring_mb']:.0f} MB ({r['ring_dtype']})")
        mem_row("… … the matcher's running sums", case, lambda r: f"{r['sums_mb']:.0f} MB")
        mem_row("… the rest of the matcher, the filter (state, particles), the place graph", case,
                lambda r: f"{r['matcher_mb'] - r['ring_mb'] - r['sums_mb']:.0f} + {r['filter_mb']:.0f} + "
                          f"{r['graph_mb']:.0f} MB ({r['filter']})")
        mem_row("… peak while preparing (float map, codes, bootstrap blocks)", case,
                lambda r: f"{r['prepare_peak_rss_mb']:.0f} MB")
    for case, what in (("live", "float32"), ("live-u8", "uint8 codes")):
        live = [by[(case, n)] for n in sizes if (case, n) in by]
        if live:
            lines += ["", f"Preparing the live map ({what}: validation, layout, bootstrap from sampled pairs): " +
                      ", ".join(f"N = {r['n']:,}: {r['prepare_s']:.1f} s (anchor rows {r['anchor_rows']})"
                                for r in live) + "."]
    # runs written by hand (other machines, alternated trees) live in their own file, which
    # this report does not rewrite
    lines += ["", "Runs recorded beside this table (other machines, frozen trees alternated, single cases): "
              "`live_notes.md`."]
    errors = [r for r in results if "error" in r]
    if errors:
        lines += ["", "Failed cases:", ""] + [f"- `{' '.join(e['args'])}`: {e['error']}" for e in errors]
    if cold:
        lines += ["", "## Cold start", "",
                  "The same short run (import, synthetic image map of 288 places, first difference row, 20 "
                  "combined live steps) in fresh processes sharing one empty `NUMBA_CACHE_DIR`:", "",
                  "| run | process wall s | import + map s | first row s | 20 combined steps s |", "|---|---|---|---|---|"]
        for r in cold["runs"]:
            lines.append(f"| {r['label']} | {r['process_s']:.2f} | {r['import_and_map_s']:.2f} | "
                         f"{r['first_row_s']:.2f} | {r['twenty_combined_steps_s']:.2f} |")
        warm = np.median([r["process_s"] for r in cold["runs"] if r["label"] == "warm"])
        lines += ["", f"Cold / warm: ×{cold['runs'][0]['process_s'] / warm:.2f}."]
        first = cold["runs"][0].get("compiled_s")
        if first is not None:
            lines += ["", "Kernels compiled in each run (numba compile events, top level; seconds):", "",
                      "| kernel | " + " | ".join(r["label"] for r in cold["runs"]) + " |",
                      "|---|" + "---|" * len(cold["runs"])]
            names = list(dict.fromkeys(k for r in cold["runs"] for k in r.get("compiled_s", {})))
            for name in names:
                cells = [f"{r['compiled_s'][name]:.2f}" if name in r.get("compiled_s", {}) else "cached"
                         for r in cold["runs"]]
                lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
            totals = [f"{sum(r.get('compiled_s', {}).values()):.2f}" for r in cold["runs"]]
            lines.append("| total | " + " | ".join(totals) + " |")
    if after_warm_up:
        runs = after_warm_up["runs"]
        warm = np.median([r["process_s"] for r in runs[1:]])
        lines += ["", f"After `catgraph warm-up` (live paths and batch methods) in its own process ({after_warm_up['warm_up_s']:.1f} s, "
                  "an install step), the same empty cache otherwise:", "",
                  "| run | process wall s | import + map s | first row s | 20 combined steps s | compiled s |",
                  "|---|---|---|---|---|---|"]
        for r in runs:
            lines.append(f"| {r['label']} | {r['process_s']:.2f} | {r['import_and_map_s']:.2f} | "
                         f"{r['first_row_s']:.2f} | {r['twenty_combined_steps_s']:.2f} | "
                         f"{sum(r.get('compiled_s', {}).values()):.2f} |")
        lines += ["", f"First run / warm: ×{runs[0]['process_s'] / warm:.2f}."]
    for key, c in (cli_cold or {}).items():
        runs = c["runs"]
        warm = np.median([r["process_s"] for r in runs[1:]])
        lines += ["", "### `catgraph " + " ".join(c["argv"]) + "`" +
                  (f", after `catgraph warm-up` ({c['warm_up_s']:.1f} s, an install step)" if c.get("warm_up_s")
                   else ", empty cache"), "",
                  "| run | process wall s | command s | compiled s | largest compilations |", "|---|---|---|---|---|"]
        for r in runs:
            top = ", ".join(f"`{k.split('.')[-1]}` {v:.1f}" for k, v in list(r["compiled_s"].items())[:4]) or "—"
            lines.append(f"| {r['label']} | {r['process_s']:.2f} | {r['command_s']:.2f} | "
                         f"{sum(r['compiled_s'].values()):.2f} | {top} |")
        lines += ["", f"First run / warm: ×{runs[0]['process_s'] / warm:.2f}."]
    if cold_compare:
        lines += _compare_lines(cold_compare)
    if batch:
        # a run of --batch, and (where recorded) the run of another tree it was compared with
        before = batch.get("before")
        lines += ["", "## The batch commands on a saved map", "",
                  f"`catgraph <command> --map {Path(batch['map']).name} {Path(batch['query']).name}`, one fresh process "
                  f"each, peak RSS of the process (`{batch.get('peak', 'getrusage')}`)"
                  + (f"; {batch['note']}" if batch.get("note") else "")
                  + ":", "",
                  "| command | peak RSS | ms / frame (the whole command over the frames) |"
                  + (f" before (`{before.get('commit', '?')}`): peak RSS, ms / frame |" if before else ""),
                  "|---|---|---|" + ("---|" if before else "")]
        cell = (lambda r: f"failed: {r['error']} |" if "error" in r else
                f"{r['peak_rss_mb']:.0f} MB | {r['ms_per_frame']:.1f} |")
        earlier = {r["label"]: r for r in before["rows"]} if before else {}
        for r in batch["rows"]:
            was = earlier.get(r["label"])
            lines.append(f"| `{r['label']}` | " + cell(r) + (
                "" if not before else " — |" if was is None else f" failed: {was['error']} |" if "error" in was
                else f" {was['peak_rss_mb']:.0f} MB, {was['ms_per_frame']:.1f} |"))
    for s in (shards, shards_uint8):
        if not s:
            continue
        compact = s.get("layout", "float32") == "uint8"
        per_shard_mb = s["shard_places"] * DIM * (1 if compact else 4) / 2**20
        lines += ["", "## Dask shards" + (", compact layout (uint8 codes)" if compact else ""), "",
                  f"`catgraph.distributed.match_fixed_window` on a `LocalCluster` of {s['n_shards']} one-thread worker "
                  f"processes, one shard of {s['shard_places']:,} places × {DIM} {'uint8 codes' if compact else 'float32'} "
                  f"({per_shard_mb:.0f} MiB) each, "
                  f"window {s['window']}, {s['n_query']} query frames in blocks of {s['block_rows']} (the route "
                  "crosses the shard edge):", "",
                  "| figure | measured |", "|---|---|",
                  f"| preparing the shards (send + validate) | {s['prepare_s']:.1f} s |",
                  f"| time per query frame (all shards, client rounds included) | {s['ms_per_frame']:.1f} ms |",
                  "| worker RSS after the run | " + ", ".join(f"{v:.0f} MB" for v in s["worker_rss_mb"]) + " |",
                  "| bytes a worker serves per frame (to its neighbour and to the client) | " +
                  ", ".join(f"{v:,.0f}" for v in s["bytes_out_per_frame"]) + " |",
                  f"| frames matched within ±1 place after the first window | {s['correct_after_window']:.2f} |"]
    path.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--cases", nargs="+", default=["row", "row-u8", "row-1t", "cosine-raw", "cosine", "matcher", "live",
                                                          "live-u8", "live-u8-repeats"])
    parser.add_argument("--frames", type=int, default=200,
                        help="timed frames per case (default 200: the jump evidence compares each frame with a kept "
                             "one in 50 of every 100 frames, catgraph.jumps.APART_FRAMES; fewer frames time one "
                             "phase of that cycle)")
    parser.add_argument("--l-max", type=int, default=500)
    parser.add_argument("--cold-start", action="store_true", help="measure only the cold start")
    parser.add_argument("--tree", help="with --cold-start: import catgraph from this checkout (a frozen copy)")
    parser.add_argument("--warm-up", action="store_true", help="with --cold-start: run catgraph.live.warm_up first")
    parser.add_argument("--cli", action="store_true", help="with --cold-start: time `catgraph demo` instead")
    parser.add_argument("--trees", nargs="+", help="with --cold-start --cli: these frozen checkouts, alternated")
    parser.add_argument("--rounds", type=int, default=3, help="with --trees: rounds of each tree")
    parser.add_argument("--batch", nargs=2, metavar=("MAP", "QUERY"),
                        help="measure only the batch commands on this saved map and query (.npy)")
    parser.add_argument("--write-batch-inputs", metavar="FOLDER",
                        help="write a 10^5-place map (map.npz) and a 1000-frame query (query.npy) for --batch, then stop")
    parser.add_argument("--dask", action="store_true", help="measure only the Dask shards")
    parser.add_argument("--layout", default="float32", help="with --dask: the shards' layout (float32 or uint8)")
    parser.add_argument("--profile", action="store_true",
                        help="measure only the matcher's and the row's pieces (live_profile.md)")
    parser.add_argument("--profile-rest", action="store_true",
                        help="time the whole-image model's, the combination's and the grid filter's pieces")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--anchor-rows", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:  # worker mode: one case, JSON on stdout
        if args.case == "profile":
            print(json.dumps(profile_step(args.n, l_max=args.l_max)))
            return
        if args.case == "profile-rest":
            print(json.dumps(profile_rest(args.n, args.frames, l_max=args.l_max)))
            return
        anchor = args.anchor_rows or (256 if args.n >= 1_000_000 else 1024)
        print(json.dumps(run_case(args.case, args.n, args.frames, args.l_max, anchor)))
        return
    if args.write_batch_inputs:
        for path in write_batch_inputs(args.write_batch_inputs):
            print(path)
        return
    if args.profile:
        sizes = [n for n in args.sizes if n <= 1_000_000]
        results = [_subprocess(["--case", "profile", "--n", str(n), "--l-max", str(args.l_max)]) for n in sizes]
        store = RESULTS / "live_profile.json"  # the other sizes' columns kept
        earlier = [r for r in (json.loads(store.read_text()) if store.exists() else []) if r["n"] not in sizes]
        results = sorted(earlier + results, key=lambda r: r["n"])
        store.write_text(json.dumps(results, indent=1))
        write_profile(results, RESULTS / "live_profile.md")
        print((RESULTS / "live_profile.md").read_text())
        return
    if args.profile_rest:
        results = [_subprocess(["--case", "profile-rest", "--n", str(n), "--frames", str(args.frames), "--l-max",
                                str(args.l_max)]) for n in args.sizes]
        store = RESULTS / "live_profile_rest.json"  # earlier runs kept, the new ones after them
        results = (json.loads(store.read_text()) if store.exists() else []) + results
        store.write_text(json.dumps(results, indent=1))
        write_profile_rest(results, RESULTS / "live_profile_rest.md")
        print((RESULTS / "live_profile_rest.md").read_text())
        return
    store = RESULTS / "live.json"
    previous = json.loads(store.read_text()) if store.exists() else {"results": [], "cold": None}
    if args.cold_start and args.trees:
        previous["cold_cli_compare"] = cold_start_compare(args.trees, args.rounds)
    elif args.cold_start:
        key = ("cold_cli" if args.cli else "cold") + ("_after_warm_up" if args.warm_up else "")
        previous[key] = cold_start(tree=args.tree, warm_up=args.warm_up, cli=args.cli)
    elif args.batch:
        previous["batch"] = batch_commands(*args.batch, tree=args.tree)
    elif args.dask:
        previous["shards" if args.layout == "float32" else f"shards_{args.layout}"] = dask_shards(layout=args.layout)
    else:
        keep = [r for r in previous["results"] if (r.get("case"), r.get("n")) not in
                {(c, n) for c in args.cases for n in args.sizes}]
        machine = describe_machine()
        for n in args.sizes:
            for case in args.cases:
                print(f"N = {n}: {case}", file=sys.stderr, flush=True)
                frames = args.frames if case != "cosine-raw" or n <= 100_000 else 8
                res = _subprocess(["--case", case, "--n", str(n), "--frames", str(frames), "--l-max", str(args.l_max)])
                res["machine"] = machine
                print(f"  {res}", file=sys.stderr, flush=True)
                keep.append(res)
        previous["results"] = keep
    store.write_text(json.dumps(previous, indent=1))
    write_report(previous["results"], previous.get("cold"), RESULTS / "live.md", previous.get("shards"),
                 previous.get("cold_after_warm_up"), previous.get("shards_uint8"),
                 {k: previous[k] for k in ("cold_cli", "cold_cli_after_warm_up") if previous.get(k)},
                 previous.get("batch"), previous.get("cold_cli_compare"))
    print((RESULTS / "live.md").read_text())


if __name__ == "__main__":
    main()
