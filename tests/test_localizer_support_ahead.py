"""The particle filter's joint confidence score reads the recent support at the answer's
places; on a large map its scores and moments are formed on a worker thread while the
particles move. The same floats either way, and the worker is done before the matcher
steps again."""

import threading

import numpy as np
import pytest

import catgraph.grid as grid
import catgraph.localizer as localizer
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer
from catgraph.observation import CombinedObservation, RecentSupport, SequenceObservation, TemperedObservation


def _rows(n_places, frames, seed):
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((frames, n_places))
    rows[np.arange(frames), (40 + np.arange(frames)) % n_places] -= 3.0  # a track at one place per frame
    return rows


def _run(n_places, rows, model):
    loc = Localizer(PlaceGraph.chain(n_places), model(), n_particles=300, seed=3)
    return [(e.place, e.confidence, e.log_odds, e.score, e.new_place_probability) for e in map(loc.step, rows)]


@pytest.mark.parametrize("model", [
    lambda: SequenceObservation(),
    lambda: CombinedObservation([TemperedObservation(), SequenceObservation()]),
])
def test_support_formed_ahead_gives_the_same_floats(monkeypatch, model):
    n_places = 700
    rows = _rows(n_places, 30, 1)
    monkeypatch.setattr(localizer, "SUPPORT_AHEAD_PLACES", 1 << 40)
    where_read = _run(n_places, rows, model)

    threads = []
    form = RecentSupport.form

    def noting(self):
        threads.append(threading.current_thread().name)
        return form(self)

    monkeypatch.setattr(RecentSupport, "form", noting)
    monkeypatch.setattr(localizer, "SUPPORT_AHEAD_PLACES", 1)
    monkeypatch.setattr(grid, "_cores_free", lambda cores: 2)
    ahead = _run(n_places, rows, model)
    assert ahead == where_read
    assert any(t.startswith("catgraph-support") for t in threads)  # the worker did form them

    threads.clear()
    monkeypatch.setattr(grid, "_cores_free", lambda cores: 1)  # no core free: formed where read
    assert _run(n_places, rows, model) == where_read
    assert threads and not any(t.startswith("catgraph-support") for t in threads)


def test_an_error_of_the_worker_reaches_the_caller(monkeypatch):
    monkeypatch.setattr(localizer, "SUPPORT_AHEAD_PLACES", 1)
    monkeypatch.setattr(grid, "_cores_free", lambda cores: 2)

    def failing(self):
        raise RuntimeError("support failed")

    monkeypatch.setattr(RecentSupport, "form", failing)
    loc = Localizer(PlaceGraph.chain(200), SequenceObservation(), n_particles=100, seed=0)
    rows = _rows(200, 30, 2)
    with pytest.raises(RuntimeError, match="support failed"):
        for r in rows:
            loc.step(r)
