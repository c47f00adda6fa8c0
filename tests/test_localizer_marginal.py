"""The particle filter with the velocity marginalised (Rao–Blackwellised): each piece
against a slow, obviously correct reference — the grid filter's own prediction."""

import numpy as np
import pytest

from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer, predict, route_neighbours
from catgraph.localizer import Localizer
from catgraph.motion import PlacesWritten, VelocityMotion, _marginal_kernel
from catgraph.traverse import Traverse

from .conftest import FixedLogRatio as _Fixed
from .conftest import survey_graph as _survey_graph


def _grid_prediction(graph, motion, place, p):
    """The grid filter's prediction (``catgraph.grid.predict``, general path, no recovery)
    of a state with all its mass at ``place`` and distribution ``p`` over the grid's state
    bins (its own phase bins and transition, from a grid filter of the same motion)."""
    phases = {} if motion.max_phases is None else {"max_phases": motion.max_phases}
    grid = GridLocalizer(graph, _Fixed(1.0), velocities=motion._v, blur=motion._blur, **phases).reset()
    assert len(grid._owner) == len(p)
    state = np.zeros((graph.n_places, len(p)))
    state[place] = p
    return predict(state, grid._transition, None, route_neighbours(graph), grid.blur, 0.0,
                   np.full(len(p), 1.0 / len(p)), 0.1, moves=grid._moves)


@pytest.mark.parametrize("graph", [PlaceGraph.chain(30), _survey_graph(12)], ids=["chain", "survey"])
def test_one_particle_predicts_as_the_grid_predicts_a_point_mass(graph):
    """The marginalised transition of one particle, at every place (route ends
    included) and for a velocity distribution of every kind, is the grid filter's
    prediction of a state with all its mass there (which renormalises what runs off
    the route; the particle keeps that loss for its weight)."""
    motion = VelocityMotion()
    assert motion.supports_marginal(graph)
    rng = np.random.default_rng(0)
    nb = len(motion._owner)
    for place in range(graph.n_places):
        for p in (np.full(nb, 1.0 / nb), np.eye(nb)[place % nb], rng.dirichlet(np.ones(nb))):
            ours = motion.marginal_transition(graph, place, p)
            assert ours.sum() <= 1.0 + 1e-12
            if ours.sum() == 0.0:
                continue
            np.testing.assert_allclose(ours / ours.sum(), _grid_prediction(graph, motion, place, p), atol=1e-12)


def test_junction_graphs_take_the_sampled_motion():
    g = PlaceGraph.from_traverse(Traverse(np.zeros((20, 2)), positions=np.stack([np.arange(20.0), np.zeros(20)], 1)),
                                 junctions=[(2, 15)])
    assert not VelocityMotion().supports_marginal(g)
    loc = Localizer(g, _Fixed(1.0), n_particles=50, motion=VelocityMotion(), seed=0).reset()
    assert not loc._marginal
    rows = np.abs(np.arange(20)[None, :] - np.arange(5)[:, None]).astype(float)
    assert len(loc.run(rows).place) == 5


def _kernel_reference(graph, motion, places, spread, log_weight, like, log_keep):
    """Slow reading of what the kernel must give: the particles on one place are one
    mixture (weights summed, velocity distributions averaged by weight), each place's
    prediction is ``marginal_transition``; the masses before the draw, the family's
    predictive likelihood, the normalisation to ``log_keep``."""
    w = np.exp(log_weight - np.logaddexp.reduce(log_weight))
    prior = np.zeros(graph.n_places)
    posterior = np.zeros(graph.n_places)
    evidence, moved = {}, {}
    for j in np.unique(places):
        on = places == j
        weight = w[on].sum()
        p = (w[on, None] * spread[on]).sum(0) / weight
        t = motion.marginal_transition(graph, j, p)
        moved[j] = t
        prior += weight * t.sum(1)
        posterior += weight * t.sum(1) * like
        evidence[j] = (t.sum(1) * like).sum()
    kept = prior.sum()
    scale = np.exp(log_keep) / kept
    return prior * scale, posterior * scale, evidence, moved, kept, w, scale


@pytest.mark.parametrize("graph", [PlaceGraph.chain(25), _survey_graph(12)], ids=["chain", "survey"])
def test_marginal_kernel_matches_a_slow_reference(graph):
    """Families (the particles on one place) predict once, as one particle of their
    weight and mean velocity distribution; the masses before the draw, the weights
    (the family's predictive likelihood, shared by its members), the members' velocity
    distributions (the prediction's at the place each one drew) and the places drawn
    (where the prediction times the likelihood is positive) are the slow reference's."""
    motion = VelocityMotion()
    motion._check()
    rng = np.random.default_rng(1)
    n, nb = 40, len(motion._owner)
    fwd, bwd, first_in, _ = motion._route(graph)
    places = rng.integers(0, graph.n_places, n)
    places[:10] = places[0]  # one large family
    places[-3:] = graph.n_places - 1  # and one at the route's end
    has_out = graph.out_ptr[places + 1] > graph.out_ptr[places]
    edge = np.where(has_out, graph.out_ptr[places], first_in[places]).astype(np.int64)
    fraction = np.where(has_out, 0.0, 1.0)
    spread = rng.dirichlet(np.ones(nb), n)
    log_weight = np.log(rng.random(n)) - 3.0
    like = np.exp(-rng.random(graph.n_places) * 3)
    log_keep = np.log(0.9)
    skip = (30, 34)  # slots about to take new particles: left alone
    keep = np.r_[0:30, 34:n]
    prior_ref, post_ref, evidence, moved, kept_ref, w, scale = _kernel_reference(
        graph, motion, places[keep], spread[keep], log_weight[keep], like, log_keep)
    e, f, lw, v = edge.copy(), fraction.copy(), log_weight.copy(), spread.copy()
    post, prior = np.empty(graph.n_places), np.empty(graph.n_places)
    family = np.full(graph.n_places, -1, dtype=np.int64)
    whole, frac, sign = motion._moves
    kept = _marginal_kernel(e, f, lw, v, *skip, log_keep, rng.random(n), like, motion._transition, whole, frac, sign,
                            motion._blur, fwd, bwd, graph.source, graph.target, graph.out_ptr, first_in, motion._reach,
                            post, prior, family, np.empty(n, dtype=np.int64), motion._interior_rows,
                            motion._interior_column, *_written(graph, n, motion))
    assert np.all(family == -1)  # left as it came
    assert kept == pytest.approx(kept_ref, rel=1e-12)
    np.testing.assert_allclose(prior, prior_ref, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(post, post_ref, rtol=1e-10, atol=1e-15)
    np.testing.assert_array_equal(e[30:34], edge[30:34])
    np.testing.assert_array_equal(lw[30:34], log_weight[30:34])
    for j in np.unique(places[keep]):
        members = keep[places[keep] == j]
        weight = w[places[keep] == j].sum()
        np.testing.assert_allclose(np.exp(lw[members]), weight * evidence[j] / len(members) * scale, rtol=1e-10)
        for i in members:
            landed = graph.source[e[i]] if f[i] < 0.5 else graph.target[e[i]]
            column = moved[j][landed]
            assert column.sum() * like[landed] > 0
            np.testing.assert_allclose(v[i], column / column.sum(), rtol=1e-10, atol=1e-15)
    # the weights carry the share log_keep of the whole prediction times the evidence
    assert np.exp(np.logaddexp.reduce(lw[keep])) == pytest.approx(post.sum(), rel=1e-10)


def _written(graph, n, motion):
    """A new record of the places written (the kernel clears every place first)."""
    w = PlacesWritten(graph.n_places, n * (2 * motion._reach + 1))
    return w.places, w.count, w.marks


def test_a_family_splits_in_proportion_over_its_destinations():
    """k copies of one particle land on the places of its posterior at the systematic
    positions: every place gets ⌊k q⌋ or ⌈k q⌉ of them."""
    g = PlaceGraph.chain(40)
    motion = VelocityMotion()
    motion._check()
    fwd, bwd, first_in, _ = motion._route(g)
    k, nb = 200, len(motion._owner)
    edge = np.full(k, g.out_ptr[20], dtype=np.int64)
    spread = np.tile(np.full(nb, 1.0 / nb), (k, 1))
    like = np.ones(g.n_places)
    post, prior = np.empty(g.n_places), np.empty(g.n_places)
    e = edge.copy()
    f = np.zeros(k)
    whole, frac, sign = motion._moves
    _marginal_kernel(e, f, np.zeros(k), spread, 0, 0, 0.0, np.full(k, 0.37), like, motion._transition, whole, frac,
                     sign, motion._blur, fwd, bwd, g.source, g.target, g.out_ptr, first_in, motion._reach, post, prior,
                     np.full(g.n_places, -1, dtype=np.int64), np.empty(k, dtype=np.int64), motion._interior_rows,
                     motion._interior_column, *_written(g, k, motion))
    counts = np.bincount(g.source[e], minlength=g.n_places)
    q = post / post.sum()
    assert np.all(counts >= np.floor(k * q) - 1e-9) and np.all(counts <= np.ceil(k * q) + 1e-9)


def test_first_frame_posterior_is_exact():
    """The first frame is drawn from its own posterior and its place masses are the
    exact posterior ``∝ e^{r_j}`` (no Monte Carlo error), as the grid filter's."""
    g = PlaceGraph.chain(300)
    rng = np.random.default_rng(3)
    row = rng.random(300) * 4
    loc = Localizer(g, _Fixed(1.0), n_particles=100, motion=VelocityMotion(), new_place_prior=0.0, seed=0)
    loc.reset()
    loc.step(row)
    exact = np.exp(-row - (-row).max())
    np.testing.assert_allclose(loc.place_posterior_, exact / exact.sum(), rtol=1e-10)


def test_marginal_filter_is_closer_to_the_grid_than_the_sampled_one():
    """Same particles, same seeds: the Rao–Blackwellised filter's posterior is closer to
    the grid filter's than one sampled velocity per particle gives, and still converges."""
    from catgraph.grid import GridLocalizer

    g = _survey_graph(15)
    j = np.arange(g.n_places)
    path = list(range(3, 21)) + list(range(g.n_places - 18, g.n_places - 3))
    rng = np.random.default_rng(3)
    rows = np.array([2.0 * np.minimum(np.abs(j - p), 6) / 6.0 + 0.4 * rng.standard_normal(g.n_places) for p in path])
    exact = GridLocalizer(g, _Fixed(0.8), recovery=0.05).run(rows, return_posterior=True).posterior

    def tv(n, marginal):
        out = []
        for s in range(3):
            post = Localizer(g, _Fixed(0.8), n_particles=n, recovery=0.05, motion=VelocityMotion(),
                             marginal_velocity=marginal, seed=s).run(rows, return_posterior=True).posterior
            out.append(0.5 * np.abs(post / post.sum(1, keepdims=True) - exact / exact.sum(1, keepdims=True)).sum(1).mean())
        return float(np.mean(out))

    small, large = tv(250, True), tv(4000, True)
    assert small < tv(250, False) / 2
    assert large < small / 3 and large < 0.02


def test_odometry_steps_take_the_sampled_motion_and_back():
    """A frame with odometry moves one sampled bin per particle (drawn from its velocity
    distribution); the next frame without odometry carries on marginalised."""
    g = _survey_graph(12)
    rows = np.abs(np.arange(g.n_places)[None, :] - 3 * np.arange(6)[:, None]).astype(float)
    loc = Localizer(g, _Fixed(1.0), n_particles=300, motion=VelocityMotion(), seed=0).reset()
    for k, row in enumerate(rows):
        loc.step(row, odometry=5.0 if k == 3 else None)
        np.testing.assert_allclose(loc._spread.sum(1), 1.0)
        assert np.isfinite(loc.place_posterior_).all()
        assert loc.place_posterior_.sum() + loc.new_place_probability_ == pytest.approx(1.0)
