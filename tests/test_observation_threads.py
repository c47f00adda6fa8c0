"""When the combined model's second thread runs: the load of other processes, not the step's own.

``grid._free_of_others`` subtracts this process's own CPU use (averaged over the
load average's minute) from the load average; the second thread runs where that leaves
two cores, or where ``grid._free_cores`` does.
"""

import math

import numpy as np
import pytest

import catgraph.grid as grid
import catgraph.observation as observation


class _Clock:
    """Wall and CPU seconds that advance as the test says."""

    def __init__(self):
        self.wall = 100.0
        self.cpu = 10.0

    def run(self, seconds, cores_busy):
        self.wall += seconds
        self.cpu += seconds * cores_busy


@pytest.fixture
def clock(monkeypatch):
    c = _Clock()
    monkeypatch.setattr(grid.time, "monotonic", lambda: c.wall)
    monkeypatch.setattr(grid.time, "process_time", lambda: c.cpu)
    monkeypatch.setattr(grid, "_OWN", [math.nan, 0.0, 0.0])
    monkeypatch.setattr(grid, "_own_use_since_start", lambda cpu: 0.0)
    return c


def _load(monkeypatch, value):
    monkeypatch.setattr(grid.os, "getloadavg", lambda: (value, value, value))


def test_own_use_is_averaged_over_the_minute(clock, monkeypatch):
    _load(monkeypatch, 1.8)
    assert grid._free_of_others(2) == 1  # no interval yet: the use since the start (none here)
    for _ in range(300):  # five minutes of frames keeping 1.8 cores busy
        clock.run(1.0, 1.8)
        grid._free_of_others(2)
    assert grid._OWN[2] == pytest.approx(1.8 * (1.0 - math.exp(-300.0 / grid.OWN_LOAD_SECONDS)), rel=1e-9)
    assert grid._free_of_others(2) == 2  # the load is the process's own: both cores free of others


@pytest.mark.parametrize("load, free", [(1.9, 2), (2.2, 2), (2.4, 1), (3.8, 1), (0.0, 2)])
def test_cores_left_by_other_processes(clock, monkeypatch, load, free):
    _load(monkeypatch, load)
    for _ in range(300):
        clock.run(1.0, 1.8)
        grid._free_of_others(2)
    assert grid._free_of_others(2) == free
    assert grid._free_of_others(1) == 1


def test_an_idle_process_under_others_load_keeps_one_core(clock, monkeypatch):
    _load(monkeypatch, 1.2)
    for _ in range(300):
        clock.run(1.0, 0.0)
        grid._free_of_others(2)
    assert grid._free_of_others(2) == 1  # 1.2 cores of other processes: half a core of margin gone


def test_the_second_thread_runs_where_other_processes_leave_a_core(clock, monkeypatch):
    """The grid filter's rule says one core (load 2.0), the process's own use explains the
    load: the whole-image part observes on the second thread, the same floats."""
    import threading

    from catgraph.observation import CombinedObservation, SequenceObservation, TemperedObservation

    monkeypatch.setattr(observation, "PARALLEL_PARTS_PLACES", 1)
    monkeypatch.setattr(grid, "_free_cores", lambda cores: 1)
    rng = np.random.default_rng(4)
    rows = rng.standard_normal((12, 400))

    def run():
        model = CombinedObservation([TemperedObservation(), SequenceObservation()], reliability=None)
        return [(o.log_ratio.tobytes(), o.new_place_log_ratio) for o in (model.observe(r) for r in rows)]

    threads = []
    observe = TemperedObservation.observe

    def noting(self, row):
        threads.append(threading.current_thread().name)
        return observe(self, row)

    monkeypatch.setattr(TemperedObservation, "observe", noting)
    _load(monkeypatch, 3.0)  # other processes hold the second core
    in_turn = run()
    assert threads and not any(t.startswith("catgraph-parts") for t in threads)
    threads.clear()
    _load(monkeypatch, 2.0)
    for _ in range(300):
        clock.run(1.0, 1.8)
        grid._free_of_others(2)
    assert run() == in_turn
    assert all(t.startswith("catgraph-parts") for t in threads)


def test_own_use_since_start_is_the_process_cpu_per_second_of_its_life():
    import time

    cpu = time.process_time()
    use = grid._own_use_since_start(cpu)
    assert 0.0 <= use <= 64.0
    assert grid._own_use_since_start(0.0) == 0.0
    if use > 0.0:  # /proc readable: twice the CPU seconds, twice the use
        assert grid._own_use_since_start(2 * cpu) == pytest.approx(2 * use, rel=0.05)


def test_every_threaded_pass_asks_one_rule(clock, monkeypatch):
    """The load average says one core, the process's own use explains the load: the jump
    grid gets two threads, as the combined model's second part does; with other
    processes holding the load, one. The line kernel and the particle filter's exp terms
    ask the same rule."""
    import catgraph.differences as differences
    from catgraph import _jump_kernels, localizer

    monkeypatch.setattr(grid, "_free_cores", lambda cores: 1)
    monkeypatch.setattr(differences, "_threads_available", lambda: 2)
    _load(monkeypatch, 3.0)  # other processes hold the second core
    for _ in range(300):
        clock.run(1.0, 0.0)
        grid._free_of_others(2)
    assert grid._cores_free(2) == 1
    assert _jump_kernels.jump_threads(1 << 24) == 1
    _load(monkeypatch, 2.0)  # the process's own two threads
    for _ in range(300):
        clock.run(1.0, 1.8)
        grid._free_of_others(2)
    assert grid._cores_free(2) == 2
    assert _jump_kernels.jump_threads(1 << 24) == 2
    monkeypatch.setattr(grid, "_free_cores", lambda cores: cores)
    assert grid._cores_free(2) == 2 and grid._cores_free(1) == 1

    asked = []
    monkeypatch.setattr(grid, "_cores_free", lambda cores: asked.append(cores) or 1)
    r = np.random.default_rng(0).standard_normal(4 * localizer.EXP_WORK_PER_THREAD)
    out = np.empty_like(r)
    localizer.likelihood_cumulative(r, out)
    assert asked == [2]
    asked.clear()
    from catgraph.graph import PlaceGraph
    from catgraph.grid import GridLocalizer
    from catgraph.observation import TemperedObservation

    monkeypatch.setattr(grid, "LINE_WORK_PER_THREAD", 1)
    monkeypatch.setattr(grid, "_LINE_BLOCK", 64)
    loc = GridLocalizer(PlaceGraph.chain(600), TemperedObservation(likelihood="linear", hub=None)).reset()
    for row in np.random.default_rng(2).random((3, 600)):
        loc.step(row)
    assert asked and all(c == 2 for c in asked)  # the line kernel asked the same rule
