"""The combined model's weights learned online: every candidate combination scored by
how well the filter's prediction explains the frame, the best one used next.

The fast scores (a few exponentials per place, candidates as products of their powers)
are checked against the plain formula, one candidate at a time; the model's choice is
checked against a plain re-implementation stepped beside it."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catgraph.exceptions import InvalidParameterError
from catgraph.observation import (
    DEFAULT_PART_WEIGHTS,
    CombinedObservation,
    FilterFeedback,
    Observation,
    _combination_scores,
    _WeightPlan,
    predictive_weight_grid,
)


def plain_scores(parts, grid, prior):
    """``log Σ_j π_j e^{r_j} − log mean_j e^{r_j}`` of each candidate ``r = Σ_m w_m r_m``:
    a loop over the candidates, the formula as written (``π`` normalised)."""
    p = np.asarray(prior, dtype=float) / np.sum(prior)
    out = []
    for w in grid:
        r = np.zeros(len(p))
        for wm, rm in zip(w, parts):
            r = r + wm * rm
        t = r.max()
        e = np.exp(r - t)
        out.append(np.log(np.sum(p * e) + 1e-300) - np.log(np.mean(e)))
    return np.array(out)


def fast_scores(parts, grid, prior):
    grid = np.asarray(grid, dtype=float)
    plan = _WeightPlan(grid)
    return _combination_scores(parts, grid, np.asarray(prior, dtype=float), plan,
                               np.empty((plan.n_rows + 1, len(prior))))


GRIDS = [
    predictive_weight_grid(2),
    np.array([[0.3, 0.7], [1.0, 0.1], [0.0, 0.0]]),  # no common step: one exponential per weight
    np.array([[1.0, 3.0], [2.0, 5.0]]),  # a lattice part beside one without
    np.array([[1.0, 0.0, 0.0], [1.0, 0.5, 3.0], [0.0, 1.5, 1.0], [2.0, 2.0, 2.0]]),  # three parts, odd powers
    np.array([[0.0, 0.0], [3.0, 5.0], [1.0, 16.0]]),
]


@pytest.mark.parametrize("g", range(len(GRIDS)))
@pytest.mark.parametrize("n", [1, 2, 7, 1000, 20_000])
def test_fast_scores_are_the_plain_formula(g, n):
    grid = GRIDS[g]
    rng = np.random.default_rng(10 * g + n)
    parts = [rng.standard_normal(n) * s for s in (3.0, 10.0, 0.5)[: grid.shape[1]]]
    prior = rng.random(n)
    np.testing.assert_allclose(fast_scores(parts, grid, prior), plain_scores(parts, grid, prior), rtol=0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 400), st.integers(0, 2**31), st.sampled_from([1e-3, 1.0, 30.0, 1e3]),
       st.lists(st.sampled_from([0.0, 0.125, 0.25, 0.3, 0.5, 1.0, 1.5, 2.0, 4.0]), min_size=2, max_size=12))
def test_fast_scores_match_on_any_grid_and_scale(n, seed, scale, flat):
    """Peaks hundreds of nats apart (the shifted sums underflow: the plain formula takes
    over), priors with zeros, any weights."""
    rng = np.random.default_rng(seed)
    grid = np.array(flat[: len(flat) // 2 * 2]).reshape(-1, 2)
    parts = [rng.standard_normal(n) * scale, -rng.standard_normal(n) * scale]
    prior = rng.random(n) * (rng.random(n) > 0.3)
    if prior.sum() == 0:
        prior[0] = 1.0
    np.testing.assert_allclose(fast_scores(parts, grid, prior), plain_scores(parts, grid, prior), rtol=0, atol=1e-12)


def test_scores_ignore_constant_shifts_and_the_priors_scale():
    rng = np.random.default_rng(3)
    parts = [rng.standard_normal(300), rng.standard_normal(300)]
    prior = rng.random(300)
    grid = predictive_weight_grid(2)
    base = fast_scores(parts, grid, prior)
    shifted = fast_scores([parts[0] + 7.0, parts[1] - 3.0], grid, 5.0 * prior)
    np.testing.assert_allclose(shifted, base, atol=1e-12)
    # a uniform prediction explains no frame better than the uniform guess: every score 0
    np.testing.assert_allclose(fast_scores(parts, grid, np.ones(300)), 0.0, atol=1e-12)


def test_default_grid_and_plan():
    grid = predictive_weight_grid(2)
    assert grid.tolist() == [[1.0, w] for w in DEFAULT_PART_WEIGHTS]
    plan = _WeightPlan(grid)
    # one exponential per part, three squarings, each candidate at most two rows
    assert len(plan.exponentials) == 2 and len(plan.steps) == 3 and max(map(len, plan.rows)) == 2
    assert predictive_weight_grid(3, (0.0, 1.0)).shape == (4, 3)


class Fixed:
    """A part whose ratios are given per frame."""

    def __init__(self, frames, new=0.0):
        self.frames, self.new, self.k = frames, new, 0

    def reset(self):
        self.k = 0

    def observe(self, row):
        r = self.frames[self.k]
        self.k += 1
        return Observation(r.copy(), self.new, True)


def test_predictive_weights_follow_the_plain_choice_frame_by_frame():
    rng = np.random.default_rng(4)
    n, frames, memory = 60, 40, 5.0
    a, b = rng.standard_normal((frames, n)), 2.0 * rng.standard_normal((frames, n))
    priors = rng.random((frames, n))
    model = CombinedObservation([Fixed(a, 0.5), Fixed(b, -1.0)], weights="predictive", reliability=None,
                                memory=memory)
    grid = predictive_weight_grid(2)
    decay = 0.5 ** (1.0 / memory)
    score = np.zeros(len(grid))
    w = np.array([1.0, 1.0])  # before any frame: the plain sum
    for k in range(frames):
        obs = model.observe(np.zeros(n))
        np.testing.assert_allclose(obs.log_ratio, w[0] * a[k] + w[1] * b[k], atol=1e-14)
        assert obs.new_place_log_ratio == pytest.approx(w[0] * 0.5 - w[1] * 1.0)
        model.feedback(FilterFeedback(priors[k], priors[k], slice(0, 1)))
        score = decay * score + plain_scores([a[k], b[k]], grid, priors[k])
        w = grid[np.argmax(score)]
        np.testing.assert_allclose(model.weight_scores_, score, atol=1e-11)
        assert np.array_equal(model.weights_, w)
    model.reset()
    assert not hasattr(model, "weights_") and not hasattr(model, "weight_scores_")


def test_a_part_that_points_away_from_the_prediction_is_switched_off():
    """Part a peaks where the filter predicted the place; part b at a random place: the
    learned weight of b falls to 0, and a part that agrees with a is kept."""
    rng = np.random.default_rng(5)
    n, frames = 80, 30
    truth = np.arange(10, 10 + frames)
    prior = np.full((frames, n), 0.01)
    prior[np.arange(frames), truth] = 1.0
    a = np.array([-0.3 * np.abs(np.arange(n) - t) for t in truth])
    b = np.array([-0.3 * np.abs(np.arange(n) - rng.integers(n)) for _ in truth])
    for other, expected in ((b, 0.0), (a, 2.0)):
        model = CombinedObservation([Fixed(a), Fixed(other)], weights="predictive", reliability=None)
        for k in range(frames):
            model.observe(np.zeros(n))
            model.feedback(FilterFeedback(prior[k], prior[k], slice(0, 1)))
        assert model.weights_.tolist() == [1.0, expected]


def test_predictive_weights_run_under_the_grid_filter():
    from catgraph.graph import PlaceGraph
    from catgraph.grid import GridLocalizer
    from catgraph.observation import TemperedObservation

    rng = np.random.default_rng(6)
    n = 120
    rows = rng.standard_normal((50, n))
    rows[np.arange(50), np.arange(20, 70)] -= 3.0
    model = CombinedObservation([TemperedObservation(hub=None), TemperedObservation(hub=None, novelty=False)],
                                weights="predictive", reliability=None)
    res = GridLocalizer(PlaceGraph.chain(n), model).run(rows)
    assert model.weight_scores_.shape == (len(DEFAULT_PART_WEIGHTS),) and np.all(np.isfinite(model.weight_scores_))
    assert np.mean(np.abs(res.place[10:] - np.arange(30, 70)) <= 2) > 0.9


def test_weight_errors_name_the_problem():
    part = Fixed(np.zeros((1, 3)))
    with pytest.raises(InvalidParameterError, match="'weights'.*'predictive'"):
        CombinedObservation([part], weights="learned").observe(np.zeros(3))
    with pytest.raises(InvalidParameterError, match="weight_grid.*\\(n_candidates, 2\\)"):
        CombinedObservation([part, Fixed(np.zeros((1, 3)))], weights="predictive", weight_grid=[[1.0, 2.0, 3.0]]).observe(np.zeros(3))
    with pytest.raises(InvalidParameterError, match="weight_grid"):
        CombinedObservation([part, Fixed(np.zeros((1, 3)))], weights="predictive", weight_grid=[[1.0, -1.0]]).observe(np.zeros(3))
    with pytest.raises(InvalidParameterError, match="memory"):
        CombinedObservation([part], weights="predictive", memory=0.5).observe(np.zeros(3))
    with pytest.raises(InvalidParameterError, match="at least one model"):
        CombinedObservation([]).observe(np.zeros(3))
