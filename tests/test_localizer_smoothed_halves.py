"""The smoothed posterior of the particle filter's feedback on a large map: the window
means in two halves (the second on the worker thread), the total continued in place
order, the rescaling and the maximum in one pass — the floats of the one-thread pass."""

import numpy as np
import pytest

import catgraph.grid as grid
import catgraph.localizer as localizer
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer, _smoothed
from catgraph.observation import CombinedObservation, SequenceObservation, TemperedObservation


def _ends(n, radius):
    j = np.arange(n)
    return np.maximum(0, j - radius).astype(np.int32), np.minimum(n, j + radius + 1).astype(np.int32)


def _both(monkeypatch, mass, lo, hi):
    monkeypatch.setattr(localizer, "SMOOTH_THREAD_PLACES", 1 << 40)
    one, top_one = _smoothed(mass, lo, hi, False)
    monkeypatch.setattr(localizer, "SMOOTH_THREAD_PLACES", 1)
    monkeypatch.setattr(grid, "_cores_free", lambda cores: 2)
    two, top_two = _smoothed(mass, lo, hi, False)
    return (one, top_one), (two, top_two)


@pytest.mark.parametrize("n, radius, seed", [(1000, 2, 0), (777, 5, 1), (130, 0, 2), (64 * 9 + 1, 30, 3)])
def test_halves_give_the_floats_of_one_pass(monkeypatch, n, radius, seed):
    rng = np.random.default_rng(seed)
    mass = rng.random(n) ** 8  # a few large masses among small ones
    mass[rng.integers(0, n, 5)] += 50.0
    mass /= mass.sum()
    lo, hi = _ends(n, radius)
    (one, top_one), (two, top_two) = _both(monkeypatch, mass, lo, hi)
    assert np.array_equal(one, two) and top_one == top_two
    assert top_one == one.max()


def test_halves_keep_numpys_rules_for_zero_and_nan(monkeypatch):
    lo, hi = _ends(500, 2)
    (one, top_one), (two, top_two) = _both(monkeypatch, np.zeros(500), lo, hi)  # no mass: not rescaled
    assert np.array_equal(one, two) and top_one == top_two == 0.0
    mass = np.full(500, 1 / 500)
    mass[321] = np.nan
    (one, top_one), (two, top_two) = _both(monkeypatch, mass, lo, hi)
    assert np.array_equal(one, two, equal_nan=True) and np.isnan(top_one) and np.isnan(top_two)


def test_a_filter_with_halves_gives_the_same_estimates(monkeypatch):
    n = 900
    rng = np.random.default_rng(5)
    rows = rng.standard_normal((25, n))
    rows[np.arange(25), 100 + np.arange(25)] -= 3.0

    def run():
        model = CombinedObservation([TemperedObservation(), SequenceObservation()])
        loc = Localizer(PlaceGraph.chain(n), model, n_particles=300, seed=1)
        return [(e.place, e.confidence, e.score, e.new_place_probability) for e in map(loc.step, rows)]

    monkeypatch.setattr(localizer, "SMOOTH_THREAD_PLACES", 1 << 40)
    one = run()
    monkeypatch.setattr(localizer, "SMOOTH_THREAD_PLACES", 1)
    monkeypatch.setattr(grid, "_cores_free", lambda cores: 2)
    halves = []
    sum_on = localizer._sum_on
    monkeypatch.setattr(localizer, "_sum_on", lambda *a: halves.append(1) or sum_on(*a))
    assert run() == one
    assert len(halves) >= 20  # the halves did run, once a frame
