"""The particle filter's jump grid (``Localizer(jump_graduation < 1)``): the recent jumps'
mass kept exactly over (place, velocity bin), the births drawn from it. Checked against
the slow, obviously correct reference, the grid filter, and against the filter without it."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.grid import GridLocalizer
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion

from .conftest import FixedLogRatio as _Fixed
from .conftest import survey_graph as _survey_graph


def _rows_with_a_jump(g, seed=3):
    j = np.arange(g.n_places)
    path = list(range(3, 21)) + list(range(g.n_places - 18, g.n_places - 3))
    rng = np.random.default_rng(seed)
    return np.array([2.0 * np.minimum(np.abs(j - p), 6) / 6.0 + 0.4 * rng.standard_normal(g.n_places) for p in path])


def _tv(post, exact):
    return 0.5 * np.abs(post / post.sum(1, keepdims=True) - exact / exact.sum(1, keepdims=True)).sum(1).mean()


def test_graduation_one_is_the_filter_without_the_grid():
    g = _survey_graph(15)
    rows = _rows_with_a_jump(g)
    a = Localizer(g, _Fixed(0.8), n_particles=300, motion=VelocityMotion(), seed=1).run(rows, return_posterior=True)
    b = Localizer(g, _Fixed(0.8), n_particles=300, motion=VelocityMotion(), jump_graduation=1.0,
                  seed=1).run(rows, return_posterior=True)
    np.testing.assert_array_equal(a.place, b.place)
    np.testing.assert_array_equal(a.score, b.score)
    np.testing.assert_array_equal(a.posterior, b.posterior)


def test_jump_grid_converges_to_the_grid_filter_and_is_closer_than_births_alone():
    """Same particles, same seeds: with the jump grid the posterior is closer to the grid
    filter's than with births drawn from the frame alone, and as the particles grow its
    error stays no larger than theirs (both about 0.002–0.003 at 16,000 particles): the
    jump grid adds no error of its own."""
    g = _survey_graph(15)
    rows = _rows_with_a_jump(g)
    exact = GridLocalizer(g, _Fixed(0.8), recovery=0.05).run(rows, return_posterior=True).posterior

    def tv(n, graduation):
        return float(np.mean([_tv(Localizer(g, _Fixed(0.8), n_particles=n, recovery=0.05, motion=VelocityMotion(),
                                            jump_graduation=graduation, seed=s).run(rows, return_posterior=True)
                                  .posterior, exact) for s in range(3)]))

    small, large = tv(250, 0.2), tv(4000, 0.2)
    assert small < 0.75 * tv(250, 1.0)
    assert large < small / 2 and large < 0.02
    assert large < tv(4000, 1.0) + 0.003


def test_mass_is_conserved_between_particles_and_grid():
    """The prediction the model is told sums to 1 and keeps at least the recovery share
    at every place; the posterior over places and the new place sums to 1."""

    class Recording(_Fixed):
        def reset(self):
            self.priors = []

        def feedback(self, fb):
            self.priors.append(fb.prior.copy())

    g = _survey_graph(15)
    rows = _rows_with_a_jump(g, seed=5)
    model = Recording(0.8)
    loc = Localizer(g, model, n_particles=400, motion=VelocityMotion(), learn_recovery=False, jump_graduation=0.3,
                    seed=0)
    loc.reset()
    for row in rows:
        loc.step(row)
        assert loc._jumps_mass > 0.0 or loc.n_steps_ == 1
        np.testing.assert_allclose(loc.place_posterior_.sum() + loc.new_place_probability_, 1.0, atol=1e-9)
        merged = np.zeros(loc.n_particles, dtype=bool)  # the generation just resampled: its slots are free
        merged[slice(*loc._generation(loc.n_steps_ - 1))] = True
        np.testing.assert_allclose(loc._weight[~merged].sum() + loc._jumps_mass, 1.0, atol=1e-9)
    np.testing.assert_allclose([p.sum() for p in model.priors], 1.0, atol=1e-9)
    assert min(p.min() for p in model.priors[1:]) >= 0.05 / g.n_places - 1e-12


def test_jump_grid_parameters_are_checked():
    g = _survey_graph(15)
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(InvalidParameterError, match="jump_graduation"):
            Localizer(g, _Fixed(0.8), motion=VelocityMotion(), jump_graduation=bad).reset()
    with pytest.raises(InvalidParameterError, match="proposal='likelihood'"):
        Localizer(g, _Fixed(0.8), motion=VelocityMotion(), jump_graduation=0.5, proposal="best").reset()


def test_registry_filter_passes_the_jump_graduation():
    from catgraph import methods
    from catgraph.graph import PlaceGraph

    graph = PlaceGraph.chain(5)
    params = methods.resolve_params("filter", {"mode": "particles"})
    assert params["jump_graduation"] is None  # unset: the map's size decides
    assert methods.make_filter(params, graph, _Fixed(1.0)).jump_graduation == methods.JUMP_GRADUATION == 0.2
    assert methods.jump_graduation(params, methods.JUMP_GRID_MAX_PLACES) == 0.2
    assert methods.jump_graduation(params, methods.JUMP_GRID_MAX_PLACES + 1) == 1.0  # above: no jump grid
    best = methods.resolve_params("filter", {"mode": "particles", "proposal": "best"})
    assert methods.make_filter(best, graph, _Fixed(1.0)).jump_graduation == 1.0  # the grid needs 'likelihood'
    params = methods.resolve_params("filter", {"mode": "particles", "jump_graduation": 1.0})
    assert methods.make_filter(params, graph, _Fixed(1.0)).jump_graduation == 1.0
    assert methods.jump_graduation(params, 10) == 1.0  # set: kept at any size
    params = methods.resolve_params("filter", {"mode": "particles", "jump_graduation": 0.2})
    assert methods.make_filter(params, graph, _Fixed(1.0)).jump_graduation == 0.2
    with pytest.raises(InvalidParameterError, match="jump_graduation"):
        methods.resolve_params("filter", {"mode": "grid", "jump_graduation": 0.2})
