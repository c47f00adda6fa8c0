"""What the particle filter tells its observation model (``FilterFeedback``).

The posterior handed to the model is each place's mean mass over its confidence
neighbourhood (``smooth_feedback``): checked against a slow reference that asks the
filter's own summary for the neighbourhood of an answer at every place, against the
grid filter's posterior smoothed the same way as the particles grow, and for a lower
variance over seeds than the posterior at single places on a fixed query."""

import numpy as np
import pytest

from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer, neighbourhood_means
from catgraph.motion import VelocityMotion
from catgraph.observation import FilterFeedback, Observation

from .conftest import survey_graph as _survey_graph


class _Recorder:
    """``−τ d`` with a feedback step that keeps every feedback it is given."""

    def __init__(self, tau=0.8):
        self.tau = tau

    def reset(self):
        self.seen = []

    def observe(self, row):
        return Observation(-self.tau * np.asarray(row, dtype=float), 0.0)

    def feedback(self, feedback: FilterFeedback) -> None:
        self.seen.append(np.array(feedback.posterior, dtype=float))


def _slow_means(loc, mass):
    """Each place's neighbourhood from the filter's own summary of an answer there (a
    one-hot mass), its mean mass, rescaled to the total."""
    n = loc.graph.n_places
    out = np.empty(n)
    for j in range(n):
        one_hot = np.zeros(n)
        one_hot[j] = 1.0
        near = loc._summarise(one_hot, 1.0, False)[1]
        out[j] = mass[near].mean()
    return out * mass.sum() / out.sum()


@pytest.mark.parametrize("kind", ["chain", "survey", "metric"])
def test_neighbourhood_means_match_the_summary_neighbourhoods(kind):
    graph = PlaceGraph.chain(40) if kind == "chain" else _survey_graph(12)
    kw = {"confidence_radius_m": 7.0} if kind == "metric" else {"confidence_radius": 2}
    loc = Localizer(graph, _Recorder(), 50, **kw).reset()
    mass = np.random.default_rng(1).random(graph.n_places) ** 4 * 0.9
    slow = _slow_means(loc, mass)
    np.testing.assert_allclose(neighbourhood_means(mass, *loc._neighbourhoods), slow, rtol=0, atol=1e-14 * slow.max())
    if kind == "survey":  # a surveyed point's scans all share one mean
        ours = neighbourhood_means(mass, *loc._neighbourhoods)
        assert np.ptp(ours[:3]) < 1e-15 and ours[0] != ours[3]


def test_running_window_sums_keep_tiny_masses_beside_large_ones():
    """The compiled running sum stays exact to round-off of the largest mass, and never
    goes negative, where masses 30 orders of magnitude apart follow each other."""
    loc = Localizer(PlaceGraph.chain(300), _Recorder(), 50, confidence_radius=3).reset()
    mass = np.full(300, 1e-30)
    mass[::37] = 1.0
    ours = neighbourhood_means(mass, *loc._neighbourhoods)
    slow = _slow_means(loc, mass)
    assert (ours >= 0).all()
    np.testing.assert_allclose(ours, slow, rtol=0, atol=1e-15)


def test_feedback_is_the_smoothed_posterior_and_radius_zero_is_the_posterior():
    rows = np.abs(np.arange(30)[None, :] - np.arange(3, 13)[:, None]) / 3.0
    for radius in (0, 2):
        model = _Recorder()
        loc = Localizer(PlaceGraph.chain(30), model, 200, motion=VelocityMotion(), confidence_radius=radius,
                        seed=0).reset()
        for r in rows:
            loc.step(r)
            expected = (loc.place_posterior_ if radius == 0 else
                        neighbourhood_means(loc.place_posterior_, *loc._neighbourhoods))
            np.testing.assert_array_equal(model.seen[-1], expected)
        assert model.seen[-1].sum() == pytest.approx(loc.place_posterior_.sum())
    off = Localizer(PlaceGraph.chain(30), _Recorder(), 200, motion=VelocityMotion(), smooth_feedback=False).reset()
    assert off._neighbourhoods is None


def _query(graph, seed=3):
    """Drive one place per frame, then jump to the other end (the recovery decides)."""
    n = graph.n_places
    j = np.arange(n)
    path = list(range(3, 21)) + list(range(n - 18, n - 3))
    rng = np.random.default_rng(seed)
    return np.array([2.0 * np.minimum(np.abs(j - p), 6) / 6.0 + 0.4 * rng.standard_normal(n) for p in path])


def test_feedback_converges_to_the_grid_filters_smoothed_posterior():
    """Same motion, recovery and model: as the particles grow, the feedback approaches
    the grid filter's posterior smoothed over the same neighbourhoods."""
    from catgraph.grid import GridLocalizer

    g = _survey_graph(15)
    rows = _query(g)
    grid = GridLocalizer(g, _Recorder(), recovery=0.05)
    exact = grid.run(rows, return_posterior=True).posterior.astype(float)

    def tv(n):
        out = []
        for s in range(3):
            model = _Recorder()
            loc = Localizer(g, model, n_particles=n, recovery=0.05, motion=VelocityMotion(), seed=s)
            loc.run(rows)
            ours = np.array(model.seen)
            ref = np.array([neighbourhood_means(p, *loc._neighbourhoods) for p in exact])
            out.append(0.5 * np.abs(ours / ours.sum(1, keepdims=True) - ref / ref.sum(1, keepdims=True)).sum(1).mean())
        return float(np.mean(out))

    small, large = tv(250), tv(4000)
    assert large < small / 3 and large < 0.02


def test_smoothed_feedback_varies_less_over_seeds():
    """On one query, the agreement the tempered model reads from the feedback
    (``posterior(best) / max posterior``) varies less from seed to seed when the
    posterior is smoothed over the neighbourhoods."""
    g = PlaceGraph.chain(120)
    rows = _query(g, seed=5)
    best = np.argmin(rows, axis=1)

    def agreement_variance(smooth):
        hits = []
        for s in range(12):
            model = _Recorder()
            Localizer(g, model, n_particles=200, recovery=0.05, motion=VelocityMotion(), smooth_feedback=smooth,
                      seed=s).run(rows)
            post = np.array(model.seen)
            hits.append(post[np.arange(len(best)), best] / post.max(1))
        return float(np.var(np.array(hits), axis=0).mean())

    assert agreement_variance(True) < 0.7 * agreement_variance(False)


@pytest.mark.parametrize("kind", ["chain", "survey", "metric"])
def test_grid_filter_feeds_back_its_posterior_smoothed_the_same_way(kind):
    """The grid filter hands its model the posterior smoothed over the neighbourhoods its
    own summary counts (checked per frame against the slow one-hot reference), and the
    plain posterior with ``smooth_feedback=False``; the answers do not change."""
    from catgraph.grid import GridLocalizer

    graph = PlaceGraph.chain(40) if kind == "chain" else _survey_graph(12)
    kw = {"confidence_radius_m": 7.0} if kind == "metric" else {"confidence_radius": 2}
    rows = _query(graph)
    runs = {}
    for smooth in (True, False):
        model = _Recorder()
        grid = GridLocalizer(graph, model, recovery=0.05, smooth_feedback=smooth, **kw).reset()
        posteriors, match = [], []
        for row in rows:
            match.append(grid.step(row).place)
            posteriors.append(grid.place_posterior_.copy())
        runs[smooth] = (np.array(model.seen), np.array(posteriors), np.array(match))
    seen, posterior, match = runs[True]
    plain_seen, plain_posterior, plain_match = runs[False]
    np.testing.assert_array_equal(match, plain_match)
    np.testing.assert_array_equal(posterior, plain_posterior)
    np.testing.assert_array_equal(plain_seen, plain_posterior)
    loc = GridLocalizer(graph, _Recorder(), recovery=0.05, **kw).reset()

    def slow(mass):
        n = graph.n_places
        out = np.empty(n)
        for j in range(n):
            one_hot = np.zeros(n)
            one_hot[j] = 1.0
            loc._mass = one_hot
            out[j] = mass[loc._summarise()[1]].mean()
        return out * mass.sum() / out.sum()

    for got, post in zip(seen, posterior):
        ref = slow(post)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * max(ref.max(), 1e-300))
    assert not np.allclose(seen, posterior)  # the smoothing did something


def test_grid_filter_checks_smooth_feedback():
    from catgraph.exceptions import InvalidParameterError
    from catgraph.grid import GridLocalizer

    with pytest.raises(InvalidParameterError, match="smooth_feedback"):
        GridLocalizer(PlaceGraph.chain(5), _Recorder(), smooth_feedback="yes").reset()
