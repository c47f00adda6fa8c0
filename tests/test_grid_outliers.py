"""Outlier frames in the grid filter (``GridLocalizer(outlier_probability=p)``): each frame
shows no place of the map with probability ``p``, its likelihood at every place then the
new-place hypothesis's. Checked against the same filter without outliers fed the mixed
likelihood written out from the definition, ``log((1 − p) e^{r_j} + p e^{r_new})``."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.methods import OUTLIER_PROBABILITY, concrete_params, make_filter, resolve_params
from catgraph.observation import Observation, TemperedObservation



class _General(GridLocalizer):
    """The general path (a walk along the graph's edges, float64) on a line graph."""

    _line_dtype = np.float64

    def reset(self):
        super().reset()
        self._line = False
        for c in [self.__dict__] + (self._components or []):
            c["_state"] = c["_state"].astype(np.float64)
        return self


class _Given:
    """Log-ratios and a new-place ratio given per frame (``rows[k]``, ``new[k]``)."""

    def __init__(self, rows, new, mixed: float = 0.0):
        self.rows, self.new, self.mixed = rows, new, mixed

    def reset(self):
        self.k = 0

    def observe(self, row):
        r, n = np.asarray(self.rows[self.k], dtype=np.float64), float(self.new[self.k])
        self.k += 1
        if self.mixed > 0.0:  # the definition, in log space, place by place
            p = self.mixed
            r = np.array([math.log((1.0 - p) * math.exp(x) + p * math.exp(n)) for x in r])
        return Observation(r, n, True)


def _frames(n_places=40, n_frames=30, seed=0, glitch=(12, 13)):
    """A query along the route at +1 place a frame with noisy ratios, and glitch frames
    that score the true place far below every other and a place half the route away far
    above."""
    rng = np.random.default_rng(seed)
    rows = rng.normal(scale=1.0, size=(n_frames, n_places))
    truth = (5 + np.arange(n_frames)) % n_places
    rows[np.arange(n_frames), truth] += 3.0
    for k in glitch:
        rows[k] = rng.normal(scale=1.0, size=n_places)
        rows[k, truth[k]] = -6.0
        rows[k, (truth[k] + n_places // 2) % n_places] = 6.0
    new = np.log(np.exp(rows).mean(axis=1))  # the tempered model's form: log mean e^r
    return rows, new, truth


@pytest.mark.parametrize("p", [0.01, 0.2])
@pytest.mark.parametrize("kind", ["line", "general", "rigid"])
def test_outliers_equal_the_mixed_likelihood_written_out(p, kind):
    rows, new, _ = _frames()
    cls = _General if kind == "general" else GridLocalizer
    extra = {"rigid_prior": 0.1} if kind == "rigid" else {}
    graph = PlaceGraph.chain(rows.shape[1])
    fast = cls(graph, _Given(rows, new), outlier_probability=p, **extra).reset()
    slow = cls(graph, _Given(rows, new, mixed=p), **extra).reset()
    for k in range(len(rows)):
        a, b = fast.step(np.zeros(rows.shape[1])), slow.step(np.zeros(rows.shape[1]))
        np.testing.assert_allclose(fast.place_posterior_, slow.place_posterior_, rtol=1e-6, atol=1e-12)
        assert fast.new_place_probability_ == pytest.approx(slow.new_place_probability_, rel=1e-6, abs=1e-12)
        assert fast.recovery_ == pytest.approx(slow.recovery_, rel=1e-6)
        assert a.place == b.place
        assert a.log_odds == pytest.approx(b.log_odds, rel=1e-6, abs=1e-9)


def test_zero_leaves_the_filter_as_it_was():
    rows, new, _ = _frames()
    graph = PlaceGraph.chain(rows.shape[1])
    off = GridLocalizer(graph, _Given(rows, new), outlier_probability=0.0).reset()
    plain = GridLocalizer(graph, _Given(rows, new)).reset()
    for _ in range(len(rows)):
        off.step(np.zeros(rows.shape[1]))
        plain.step(np.zeros(rows.shape[1]))
        np.testing.assert_array_equal(off.place_posterior_, plain.place_posterior_)


def test_a_glitch_frame_does_not_pull_the_track_away():
    """A frame that scores the true place far below the rest and a place half the route
    away far above: without outliers the track keeps 2 % of the mass and the answer stays
    away for a second frame; with them the track keeps about 11 % and the next frame's
    answer is back on the route."""
    rows, new, truth = _frames(glitch=(20,))
    graph = PlaceGraph.chain(rows.shape[1])
    answers, near = {}, {}
    for p in (0.0, 0.01):
        loc = GridLocalizer(graph, _Given(rows, new), outlier_probability=p, recovery=0.02,
                            learn_recovery=False).reset()
        answers[p], near[p] = [], []
        for k in range(len(rows)):
            answers[p].append(loc.step(np.zeros(rows.shape[1])).place - truth[k])
            near[p].append(loc.place_posterior_[truth[k] - 1:truth[k] + 2].sum())
    assert answers[0.0][20] == answers[0.0][21] == -20  # the glitch moves the plain filter for two frames
    assert near[0.0][20] < 0.05 and near[0.01][20] > 0.1
    assert all(abs(a) <= 1 for a in answers[0.01][21:])
    assert all(abs(a) <= 1 for p in (0.0, 0.01) for a in answers[p][:20])


@pytest.mark.parametrize("bad", [-0.1, 1.0, 1.5, float("nan"), "0.01"])
def test_outlier_probability_validated(bad):
    with pytest.raises(InvalidParameterError, match="outlier_probability"):
        GridLocalizer(PlaceGraph.chain(10), TemperedObservation(), outlier_probability=bad).reset()


def test_registry_filter_passes_the_outlier_probability():
    for given, expected in (({}, OUTLIER_PROBABILITY), ({"outlier_probability": 0.0}, 0.0),
                            ({"outlier_probability": 0.2}, 0.2)):
        params = concrete_params(resolve_params("filter", given), 100)
        assert params["outlier_probability"] == expected
        loc = make_filter(params, PlaceGraph.chain(100), TemperedObservation())
        assert loc.outlier_probability == expected
    assert OUTLIER_PROBABILITY == 0.01
