"""Motion on the place graph: distances, branches, dead ends, never leaving the graph."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catgraph.exceptions import DataError, InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.motion import FrameMotion, OdometryMotion, advance
from catgraph.particles import ParticleSet


def _at(graph, source, target, fraction, n):
    e = [k for k in graph.out_edges(source) if graph.target[k] == target][0]
    return ParticleSet(np.full(n, e, dtype=np.int64), np.full(n, float(fraction)), np.full(n, -np.log(n)))


def _slow_chain_position(start, distance, n_places, reflect):
    """Reference: position along a forward chain as a float place index."""
    x = start + distance
    if not reflect:
        return min(x, n_places - 1), +1
    period = 2 * (n_places - 1)
    x = x % period
    return (x, +1) if x <= n_places - 1 else (period - x, -1)


def _position(graph, p):
    a, b = graph.source[p.edge], graph.target[p.edge]
    return a + (b - a) * p.fraction


@pytest.mark.parametrize("reflect", [True, False])
def test_chain_travel_matches_reference(reflect):
    g = PlaceGraph.chain(8, bidirectional=True)
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 30, 200)
    p = _at(g, 2, 3, 0.25, 200)
    advance(p, g, d, rng, dead_end="reflect" if reflect else "stop")
    got = _position(g, p)
    for k in range(200):
        want, direction = _slow_chain_position(2.25, d[k], 8, reflect)
        assert got[k] == pytest.approx(want, abs=1e-9)
        if reflect and 0 < want < 7 and abs(want - round(want)) > 1e-9:
            assert np.sign(g.target[p.edge[k]] - g.source[p.edge[k]]) == direction


def test_one_way_chain_stops_at_the_end():
    g = PlaceGraph.chain(5, bidirectional=False)
    p = _at(g, 1, 2, 0.5, 10)
    advance(p, g, np.full(10, 100.0), np.random.default_rng(0))
    assert np.all(g.target[p.edge] == 4) and np.all(p.fraction == 1.0)
    advance(p, g, np.full(10, 3.0), np.random.default_rng(1))  # stays there
    assert np.all(g.target[p.edge] == 4) and np.all(p.fraction == 1.0)


def _t_junction():
    # 0-1-2-3-4 main road, 2 also joins a side road 5-6-7 (as a junction 2<->5)
    edges = [(0, 1), (1, 2), (2, 3), (3, 4), (5, 6), (6, 7)]
    e = np.array(edges + [(b, a) for a, b in edges] + [(2, 5), (5, 2)])
    kinds = ["chain"] * 6 + ["reverse"] * 6 + ["junction"] * 2
    lengths = np.ones(len(e))
    lengths[-2:] = 0.0
    return PlaceGraph.from_edges(8, e, lengths, kinds)


def test_branch_choice_is_uniform_or_prefers_straight():
    g = _t_junction()
    n = 20000
    for pref, want_straight in [(0.0, 0.5), (0.8, 0.8 + 0.2 * 0.5)]:
        p = _at(g, 1, 2, 0.5, n)
        advance(p, g, np.full(n, 1.0), np.random.default_rng(3), straight_preference=pref)
        # half an edge to node 2, then branch: to 3 (straight) or 5 (junction, length ~0) then 5->6
        on_main = g.target[p.edge] == 3
        on_side = (g.source[p.edge] == 5) & (g.target[p.edge] == 6)
        assert np.all(on_main | on_side)
        assert on_main.mean() == pytest.approx(want_straight, abs=0.015)


def test_no_u_turn_at_a_through_node():
    g = PlaceGraph.chain(6, bidirectional=True)
    p = _at(g, 1, 2, 0.0, 1000)
    advance(p, g, np.full(1000, 2.5), np.random.default_rng(0))
    np.testing.assert_allclose(_position(g, p), 3.5)
    assert np.all(g.target[p.edge] == 4)


def test_reverse_probability_turns_particles_round():
    g = PlaceGraph.chain(50, bidirectional=True)
    n = 4000
    p = _at(g, 20, 21, 0.5, n)
    advance(p, g, np.full(n, 2.0), np.random.default_rng(0), reverse_probability=0.25)
    pos = _position(g, p)
    assert np.mean(np.isclose(pos, 18.5)) == pytest.approx(0.25, abs=0.03)
    assert np.mean(np.isclose(pos, 22.5)) == pytest.approx(0.75, abs=0.03)


@settings(max_examples=40, deadline=None)
@given(
    n_places=st.integers(2, 30),
    n_junctions=st.integers(0, 6),
    bidirectional=st.booleans(),
    dead_end=st.sampled_from(["reflect", "stop"]),
    scale=st.floats(0.0, 50.0),
    seed=st.integers(0, 2**16),
)
def test_particles_never_leave_the_graph(n_places, n_junctions, bidirectional, dead_end, scale, seed):
    rng = np.random.default_rng(seed)
    g0 = PlaceGraph.chain(n_places, bidirectional=bidirectional)
    junctions = rng.integers(0, n_places, size=(n_junctions, 2))
    junctions = junctions[junctions[:, 0] != junctions[:, 1]]
    e = np.concatenate([np.stack([g0.source, g0.target], 1), junctions, junctions[:, ::-1]])
    kinds = np.concatenate([g0.kind, np.full(2 * len(junctions), 2)])
    lengths = np.concatenate([rng.uniform(0, 3, g0.n_edges), rng.uniform(0, 1, 2 * len(junctions))])
    g = PlaceGraph.from_edges(n_places, e, lengths, kinds)
    p = ParticleSet.uniform(g, 300, rng)
    motion = FrameMotion(speed=scale / 10, speed_noise=scale / 20, dead_end=dead_end,
                         straight_preference=0.3, reverse_probability=0.1 if bidirectional else 0.0)
    for _ in range(5):
        motion.move(p, g, rng)
        assert np.all((p.edge >= 0) & (p.edge < g.n_edges))
        assert np.all((p.fraction >= 0) & (p.fraction <= 1)) and np.all(np.isfinite(p.fraction))


def test_odometry_noise_statistics_and_errors():
    g = PlaceGraph.chain(10)
    m = OdometryMotion(relative_noise=0.1, absolute_noise=0.2)
    d = m.distances(100000, g, 5.0, np.random.default_rng(0))
    assert d.mean() == pytest.approx(5.0, abs=0.01)
    assert d.std() == pytest.approx(np.hypot(0.5, 0.2), rel=0.02)
    with pytest.raises(DataError, match="FrameMotion"):
        m.distances(3, g, None, np.random.default_rng(0))
    with pytest.raises(InvalidParameterError, match="dead_end"):
        FrameMotion(dead_end="bounce").move(ParticleSet.uniform(g, 3, np.random.default_rng(0)), g, np.random.default_rng(0))


def test_frame_motion_counts_places_whatever_the_spacing():
    g = PlaceGraph.chain(10, spacing=2.5)
    d = FrameMotion(speed=1.0, speed_noise=0.0).distances(4, g, None, np.random.default_rng(0))
    np.testing.assert_allclose(d, 1.0)
    p = _at(g, 2, 3, 0.0, 4)
    FrameMotion(speed=2.0, speed_noise=0.0).move(p, g, np.random.default_rng(0))
    np.testing.assert_allclose(_position(g, p), 4.0)


def test_same_seed_same_motion():
    g = _t_junction()
    out = []
    for _ in range(2):
        rng = np.random.default_rng(9)
        p = ParticleSet.uniform(g, 500, rng)
        for _ in range(4):
            FrameMotion(reverse_probability=0.1, straight_preference=0.2).move(p, g, rng)
        out.append((p.edge.copy(), p.fraction.copy()))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])


def _repeated_positions_graph():
    """A metric route like a Wi-Fi survey: several samples at each surveyed point, so
    most chain edges have zero length and a few are metres long."""
    from catgraph.traverse import Traverse

    points = np.stack([4.0 * np.arange(8), np.zeros(8)], 1)
    positions = np.repeat(points, 5, axis=0)
    ref = Traverse(np.zeros((len(positions), 4)), positions=positions)
    return PlaceGraph.from_traverse(ref)


@pytest.mark.parametrize("motion", ["velocity", "frame"])
def test_frame_based_motion_counts_places_on_a_metric_graph_with_repeated_positions(motion):
    from catgraph.motion import VelocityMotion

    g = _repeated_positions_graph()
    assert g.unit == "m" and np.sum(g.length[g.kind == 0] < 1e-3) > g.n_places // 2
    n, start = 200, 3
    p = _at(g, start, start + 1, 0.0, n)
    m = (VelocityMotion(velocities=(1.0,), blur=0.0, reverse_probability=0.0) if motion == "velocity"
         else FrameMotion(speed=1.0, speed_noise=0.0))
    rng = np.random.default_rng(0)
    for k in range(1, 25):
        m.move(p, g, rng)
        # one place per frame, as the grid filter moves its mass, whatever the metres between places
        np.testing.assert_array_equal(p.places(g), start + k)


def test_velocity_motion_defaults_are_the_grid_filters():
    import inspect

    from catgraph.grid import GridLocalizer, velocity_transition
    from catgraph.motion import VelocityMotion

    grid = {k: p.default for k, p in inspect.signature(GridLocalizer).parameters.items()}
    m = VelocityMotion()
    g = PlaceGraph.chain(10)
    rng = np.random.default_rng(0)
    m.move(ParticleSet.uniform(g, 4, rng), g, rng)
    want = np.cumsum(velocity_transition(np.asarray(grid["velocities"], dtype=float), grid["velocity_stay"],
                                         grid["reverse_probability"]), axis=1)
    np.testing.assert_allclose(m._cumulative[:, :-1], want[:, :-1])
    assert m._blur == grid["blur"] and m._junction == grid["junction_probability"]
    # an explicit value wins
    m2 = VelocityMotion(blur=0.2)
    m2.move(ParticleSet.uniform(g, 4, rng), g, rng)
    assert m2._blur == 0.2


@pytest.mark.parametrize("bad", [float("nan"), -1.0, float("inf"), "3", True])
def test_every_motion_model_refuses_odometry_that_is_not_a_distance(bad):
    """Called directly (not through a filter, which checks it too): NaN sent every particle to
    the route's end, -1 read as 'no odometry', '3' was taken as 3."""
    from catgraph.motion import VelocityMotion

    graph = PlaceGraph.chain(10, spacing=2.0)
    rng = np.random.default_rng(0)
    for model in (FrameMotion(), OdometryMotion(), VelocityMotion()):
        with pytest.raises(DataError, match="odometry must be a finite, non-negative distance"):
            model.move(_at(graph, 2, 3, 0.0, 20), graph, rng, odometry=bad)
