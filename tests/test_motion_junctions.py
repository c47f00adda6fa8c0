"""The particle filter's velocity motion at junctions is the grid filter's prediction.

:class:`~catgraph.motion.VelocityMotion` moves particles one sample at a time;
:func:`catgraph.grid.predict` moves the exact distribution (the slow, obviously correct
reference, ``_shift_frames`` and ``_shift_distance``). With many particles the particles'
joint (place, velocity bin) histogram must be the grid's prediction, step after step:
junctions taken at the grid's rate, to a smaller index as to a larger one, then half on
in each direction; and with odometry, never a junction."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer, predict, route_neighbours, velocity_transition
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion
from catgraph.particles import ParticleSet

from .conftest import FixedLogRatio as _Fixed

N_PARTICLES = 200_000


def _junction_graph(n, junctions, spacing=1.0):
    """A two-way chain of ``n`` places with junction edges both ways between the pairs."""
    i = np.arange(n - 1)
    pairs = np.asarray(junctions, dtype=np.int64).reshape(-1, 2)
    edges = np.concatenate([np.stack([i, i + 1], 1), np.stack([i + 1, i], 1), pairs, pairs[:, ::-1]])
    kinds = np.concatenate([np.zeros(n - 1, int), np.ones(n - 1, int), np.full(2 * len(pairs), 2)])
    lengths = np.concatenate([np.full(2 * (n - 1), spacing), np.full(2 * len(pairs), 0.1 * spacing)])
    return PlaceGraph.from_edges(n, edges, lengths, kinds)


def _particles_at(graph, place, bin_, n, edge=None):
    """``n`` particles at ``place`` (on its first out-edge, or on ``edge``), all in ``bin_``."""
    e = graph.out_ptr[place] if edge is None else edge
    return ParticleSet(np.full(n, e, dtype=np.int64), np.zeros(n), np.full(n, -np.log(n)),
                       np.full(n, bin_, dtype=np.int64))


def _histogram(particles, graph, n_bins):
    """The particles' normalised joint (place, bin) histogram (those that left: weight 0)."""
    w = np.exp(particles.log_weight)
    h = np.zeros((graph.n_places, n_bins))
    np.add.at(h, (particles.places(graph), particles.velocity), w)
    return h / h.sum()


def _tv(a, b):
    return 0.5 * float(np.abs(a - b).sum())


CASES = {
    # graph, velocities, start place, start bin, steps
    "forwards onto a junction to a larger index": (_junction_graph(15, [(4, 10)]), (-1.0, 1.0), 3, 1, 3),
    "forwards onto a junction to a smaller index": (_junction_graph(15, [(4, 10)]), (-1.0, 1.0), 9, 1, 3),
    "backwards, half on each way": (_junction_graph(15, [(4, 10)]), (-1.0, 1.0), 11, 0, 4),
    "two junctions at one place, several hops a step": (_junction_graph(20, [(6, 2), (6, 15)]),
                                                         (-2.0, -1.0, 1.0, 2.0), 3, 3, 3),
    "no -v bin: both halves keep v": (_junction_graph(20, [(6, 2), (6, 15)]), (0.5, 1.0, 2.0), 4, 1, 3),
    "a junction at a route end": (_junction_graph(12, [(11, 3)]), (-1.0, 1.0, 2.0), 8, 2, 4),
}


@pytest.mark.parametrize("case", list(CASES))
def test_velocity_motion_is_the_grid_prediction_at_junctions(case):
    graph, velocities, start, bin_, steps = CASES[case]
    v = np.asarray(velocities)
    stay, reverse, blur, jp = 0.9, 0.02, 0.05, 0.15
    motion = VelocityMotion(velocities=velocities, velocity_stay=stay, reverse_probability=reverse, blur=blur,
                            junction_probability=jp)
    particles = _particles_at(graph, start, bin_, N_PARTICLES)
    state = np.zeros((graph.n_places, len(v)))
    state[start, bin_] = 1.0
    rng = np.random.default_rng(1)
    transition, neighbours = velocity_transition(v, stay, reverse), route_neighbours(graph)
    for step in range(steps):
        motion.move(particles, graph, rng)
        state = predict(state, transition, v, neighbours, blur, 0.0, np.full(len(v), 1 / len(v)), jp)
        # 2e5 particles over at most 80 cells: a sampling error of about 0.01 at most
        assert _tv(_histogram(particles, graph, len(v)), state) < 0.015, f"step {step + 1}"


def test_a_particle_born_on_a_junction_edge_moves_from_its_place():
    """Births put a particle on its place's first out-edge, which may be a junction edge: it
    stands at that place, and moves from there as the grid's mass does (it does not take
    the junction edge for granted)."""
    graph = _junction_graph(15, [(4, 10)])
    junction_edge = [e for e in graph.out_edges(4) if graph.kind[e] == 2][0]
    v = np.array([-1.0, 1.0])
    motion = VelocityMotion(velocities=v, velocity_stay=1.0, reverse_probability=0.0, blur=0.0,
                            junction_probability=0.1)
    particles = _particles_at(graph, 4, 1, N_PARTICLES, edge=junction_edge)
    assert np.all(particles.places(graph) == 4)
    motion.move(particles, graph, np.random.default_rng(0))
    state = np.zeros((15, 2))
    state[4, 1] = 1.0
    state = predict(state, velocity_transition(v, 1.0, 0.0), v, route_neighbours(graph), 0.0, 0.0,
                    np.array([0.5, 0.5]), 0.1)
    assert state[5].sum() == pytest.approx(0.9) and state[10].sum() == pytest.approx(0.1)
    assert _tv(_histogram(particles, graph, 2), state) < 0.01


def test_with_odometry_particles_follow_the_route_and_never_a_junction():
    """The grid walks the odometry along the route's edges (``_shift_distance``); so do the
    particles: on a junction graph, with whole edge lengths, the same distribution."""
    graph = _junction_graph(15, [(4, 10), (6, 1)], spacing=2.0)
    v = np.array([-1.0, 1.0])
    stay, reverse, blur, jp = 0.9, 0.05, 0.05, 0.2
    motion = VelocityMotion(velocities=v, velocity_stay=stay, reverse_probability=reverse, blur=blur,
                            junction_probability=jp)
    particles = _particles_at(graph, 3, 1, N_PARTICLES)
    state = np.zeros((15, 2))
    state[3, 1] = 1.0
    rng = np.random.default_rng(2)
    transition, neighbours = velocity_transition(v, stay, reverse), route_neighbours(graph)
    for step, odometry in enumerate((2.0, 4.0, 0.0, 2.0)):
        motion.move(particles, graph, rng, odometry=odometry)
        state = predict(state, transition, v, neighbours, blur, 0.0, np.array([0.5, 0.5]), jp, odometry=odometry)
        assert _tv(_histogram(particles, graph, 2), state) < 0.01, f"step {step + 1}"


def test_junction_probability_is_the_grid_filters_range():
    graph = _junction_graph(15, [(4, 10)])
    particles = _particles_at(graph, 3, 0, 4)
    with pytest.raises(InvalidParameterError, match="junction_probability"):
        VelocityMotion(junction_probability=0.6).move(particles, graph, np.random.default_rng(0))
    with pytest.raises(TypeError):
        VelocityMotion(straight_preference=0.3)  # the grid's junction rule has no such thing


def test_particle_posterior_converges_to_the_grid_filter_on_a_junction_graph():
    """Whole filters on a map with junctions, a query that takes one: the particle
    posterior's distance to the exact one falls with the particles, towards 0."""
    n = 60
    graph = _junction_graph(n, [(15, 40), (30, 8)])
    rng = np.random.default_rng(3)
    path = list(range(5, 16)) + list(range(40, 55))  # forwards, across the junction 15 → 40, on
    rows = np.abs(np.arange(n)[None, :] - np.asarray(path, dtype=float)[:, None]) / 4 + 0.4 * rng.random((len(path), n))
    v = (-2.0, -1.0, 1.0, 2.0)
    common = dict(velocities=v, velocity_stay=0.95, reverse_probability=0.01, blur=0.02, junction_probability=0.1)
    exact = GridLocalizer(graph, _Fixed(0.8), recovery=0.0, learn_recovery=False, new_place_prior=0.0, **common).run(
        rows, return_posterior=True).posterior
    tv = {}
    for n_particles in (250, 4000):
        tv[n_particles] = np.mean([
            0.5 * np.abs(Localizer(graph, _Fixed(0.8), n_particles=n_particles, recovery=0.0, learn_recovery=False,
                                   redraw_fraction=0.0, new_place_prior=0.0, motion=VelocityMotion(**common),
                                   seed=s).run(rows, return_posterior=True).posterior - exact).sum(1).mean()
            for s in range(3)])
    assert tv[4000] < tv[250] / 3
    assert tv[4000] < 0.05


def test_the_marginal_kernel_stays_inside_its_buffers_at_a_route_end(monkeypatch):
    """Run as plain Python (numpy indexing raises where the compiled kernel read and wrote
    past its window: the extra hop of a whole speed, which carries no mass, blurred one
    place beyond it), a query driven to the end of a chain."""
    import catgraph.motion as motion

    from .conftest import FixedLogRatio

    monkeypatch.setattr(motion, "_marginal_kernel", motion._marginal_kernel.py_func)
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(30, 30))
    rows[np.arange(30), np.arange(30)] -= 2.0
    loc = Localizer(PlaceGraph.chain(30), FixedLogRatio(1.0), n_particles=60, motion=VelocityMotion(), seed=0)
    assert loc.run(rows).match[-1] >= 25


def test_an_impossible_place_next_to_a_particle_is_no_nan():
    """A place whose log-ratio is -inf (a model that rules it out): particles standing on
    its neighbour weighed it with a factor 0, and 0 · -inf made NaN posteriors (the default
    frame motion's particles sit on places)."""
    from catgraph.observation import Observation

    class RulesOutSeven:
        def reset(self):
            pass

        def observe(self, row):
            r = -np.asarray(row, dtype=float)
            r[7] = -np.inf
            return Observation(r, 0.0)

    rows = np.random.default_rng(0).random((40, 30))
    loc = Localizer(PlaceGraph.chain(30), RulesOutSeven(), n_particles=300, seed=0)
    for row in rows:
        est = loc.step(row)
        assert np.all(np.isfinite(loc.place_posterior_)) and np.isfinite(est.log_odds)
        assert loc.place_posterior_[7] == 0.0


@pytest.mark.parametrize("velocity_motion", [True, False], ids=["velocity", "frame"])
def test_a_frame_that_rules_out_every_place_leaves_the_prediction_standing(velocity_motion):
    """As the grid filter keeps its prediction: the velocity particles froze on such frames
    (the place they were at, confidence falling) and then lost the track."""
    from catgraph.observation import Observation

    class RulesOutAll:
        def reset(self):
            pass

        def observe(self, row):
            r = np.asarray(row, dtype=float).copy()
            if r[0] > 1e8:
                r[:] = -np.inf
            return Observation(r, 0.0)

    graph = PlaceGraph.chain(50)
    rng = np.random.default_rng(0)
    truth = np.arange(40) + 5
    rows = rng.normal(size=(40, 50))
    rows[np.arange(40), truth] += 3.0
    rows[20:23] = 1e9
    grid = GridLocalizer(graph, RulesOutAll())
    loc = Localizer(graph, RulesOutAll(), n_particles=2000, seed=0,
                    motion=VelocityMotion() if velocity_motion else None)
    for k, row in enumerate(rows[:26]):
        g, p = grid.step(row), loc.step(row)
        assert np.all(np.isfinite(loc.place_posterior_))
        if k >= 18:
            assert p.place == g.place == truth[k], k
