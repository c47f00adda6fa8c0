"""The jump grid's compiled pass (``catgraph._jump_kernels``) against the slow, obviously
correct reference, the grid filter's own prediction (``catgraph.grid.predict``), and the
particle filter with it against the same filter predicting its jump grid through that
reference."""

import numpy as np
import pytest

from catgraph._jump_kernels import JUMP_BLOCK, block_starts, jump_lost, jump_step, line_segments, segment_edges
from catgraph.graph import PlaceGraph
from catgraph.grid import _bin_moves, _shift_walk, predict, route_neighbours
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion

from .conftest import FixedLogRatio as _Fixed


def _route(n, breaks=()):
    """A route by place index, cut (no edge either way) after each place in ``breaks``."""
    edges, kinds = [], []
    for j in range(n - 1):
        if j in breaks:
            continue
        edges += [(j, j + 1), (j + 1, j)]
        kinds += ["chain", "reverse"]
    return PlaceGraph.from_edges(n, np.array(edges, dtype=np.int64).reshape(-1, 2), kinds=kinds)


def _reversed_route(n):
    """The same line, its route running from the last place to the first."""
    edges = [(j + 1, j) for j in range(n - 1)] + [(j, j + 1) for j in range(n - 1)]
    return PlaceGraph.from_edges(n, np.array(edges), kinds=["chain"] * (n - 1) + ["reverse"] * (n - 1))


def _reference(state, motion, nbrs, eps, mass, jv, e):
    """The jump grid's step as the filter first wrote it: ``grid.predict`` of the
    normalised grid, its lost mass given back, the new jump mass, the frame."""
    n = state.shape[0]
    if mass > 0:
        moved = predict(state / state.sum(), motion._transition, None, nbrs, motion._blur, 0.0, jv, 0.0,
                        moves=motion._bin_moves)
        moved *= (1.0 - eps) * mass / moved.sum()
    else:
        moved = np.zeros_like(state)
    moved += eps / n * jv[None, :]
    jumps = moved * e[:, None]
    return moved.sum(1), jumps, np.cumsum(jumps.sum(1)), jumps.sum(0)


def _kernel(state, motion, graph, eps, mass, jv, e, unit=1.0, threads=1, block=JUMP_BLOCK):
    """The compiled pass on the same inputs (velocity-major), its scale from ``jump_lost``
    as the filter sets it."""
    n, nb = state.shape
    fwd, bwd = route_neighbours(graph)[:2]
    seg = line_segments(fwd, bwd)
    whole, frac, sign, _ = motion._bin_moves
    hops = int((whole + (frac > 0)).max())
    s = np.ascontiguousarray(state.T)
    lost = jump_lost(s, seg, segment_edges(seg, hops), *motion._columns, whole, frac, sign)
    c = (1.0 - eps) * mass / (s.sum() - lost) if mass > 0 else 0.0
    starts = block_starts(seg, int(whole.max()), block)
    out, predicted, like = np.empty((nb, n)), np.empty(n), np.empty(n)
    bins, totals = np.empty((len(starts) - 1, nb)), np.empty(len(starts) - 1)
    jump_step(s, out, seg, *motion._columns, whole, frac, sign, int(whole.max()), motion._blur, c, eps / n, jv, e,
              unit, starts, predicted, like, bins, totals, threads=threads)
    return predicted, out.T / unit, like, bins.sum(0)


def _case(rng, n, velocities, stay, blur, concentrated):
    motion = VelocityMotion(velocities=velocities, velocity_stay=stay, blur=blur)
    motion.supports_marginal(PlaceGraph.chain(2))  # resolves the motion's arrays
    nb = len(motion._owner)  # the state bins (a fractional speed's phases each)
    state = rng.random((n, nb)) ** 4
    if concentrated:  # most of the mass at a few places, some of them at the route's ends
        state *= 1e-6
        for j in {0, min(1, n - 1), n - 1, max(n - 2, 0), n // 2}:
            state[j] += rng.random(nb)
    jv = rng.random(nb)
    jv /= jv.sum()
    e = np.exp(-4.0 * rng.random(n))
    return motion, state, jv, e


@pytest.mark.parametrize("n", [1, 2, 5, 37, 2 * JUMP_BLOCK + 3, 5000])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jump_step_matches_grid_predict(n, seed):
    rng = np.random.default_rng(seed * 100 + n)
    velocities = [(-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), (-1.5, -0.25, 0.75, 1.0, 2.5),
                  (0.5, 1.0, 2.0, 3.0), (-2.0, -1.0, -0.5)][seed % 4 if n > 5 else seed % 2]
    for concentrated in (False, True):
        motion, state, jv, e = _case(rng, n, velocities, rng.uniform(0.9, 0.99), rng.uniform(0.0, 0.2), concentrated)
        eps, mass = rng.uniform(1e-4, 0.3), rng.uniform(1e-3, 1.0)
        g = PlaceGraph.chain(n) if n > 1 else _route(1)
        nbrs = route_neighbours(g)
        ref = _reference(state, motion, nbrs, eps, mass, jv, e)
        got = _kernel(state, motion, g, eps, mass, jv, e, unit=rng.uniform(0.5, 50.0))
        for a, b in zip(got, ref):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("breaks", [(0,), (10, 11, 40), (3, 2 * JUMP_BLOCK + 1)])
def test_jump_step_on_a_cut_route_matches_grid_predict(breaks):
    """Several stretches of route: mass that would cross a cut runs off its stretch's end,
    a stretch's end keeps its blur, as the reference does."""
    rng = np.random.default_rng(len(breaks))
    n = 2 * JUMP_BLOCK + 60 if max(breaks) > 100 else 97
    g = _route(n, set(breaks))
    assert line_segments(*route_neighbours(g)[:2]) is not None
    motion, state, jv, e = _case(rng, n, (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), 0.97, 0.05, True)
    for j in breaks:  # mass right at the cuts
        state[j] += 1.0
        state[j + 1] += 1.0
    ref = _reference(state, motion, route_neighbours(g), 0.01, 0.4, jv, e)
    got = _kernel(state, motion, g, 0.01, 0.4, jv, e)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-300)


def test_jump_step_without_the_old_mass_is_the_new_jump_mass_alone():
    rng = np.random.default_rng(5)
    motion, state, jv, e = _case(rng, 300, (-1.0, 0.5, 1.0, 2.0), 0.99, 0.01, False)
    state[:] = np.nan  # not read
    got = _kernel(state, motion, PlaceGraph.chain(300), 0.02, 0.0, jv, e)
    ref = _reference(np.zeros_like(state), motion, route_neighbours(PlaceGraph.chain(300)), 0.02, 0.0, jv, e)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_jump_step_floats_do_not_depend_on_the_threads():
    rng = np.random.default_rng(7)
    n = 9 * JUMP_BLOCK + 17
    motion, state, jv, e = _case(rng, n, (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), 0.99, 0.005, False)
    one = _kernel(state, motion, PlaceGraph.chain(n), 0.01, 0.5, jv, e, threads=1)
    two = _kernel(state, motion, PlaceGraph.chain(n), 0.01, 0.5, jv, e, threads=2)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("block", [7, 64, JUMP_BLOCK])
def test_jump_step_does_not_depend_on_the_blocks(block):
    """Small blocks (many of them plain, moving by index alone) against one block per
    stretch end and the default: the same masses to rounding."""
    rng = np.random.default_rng(block)
    n = 700
    g = _route(n, {250, 251, 600})
    motion, state, jv, e = _case(rng, n, (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), 0.97, 0.02, True)
    ref = _reference(state, motion, route_neighbours(g), 0.03, 0.7, jv, e)
    got = _kernel(state, motion, g, 0.03, 0.7, jv, e, block=block)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-300)


def test_block_starts_cut_each_stretch_at_its_ends():
    seg = np.repeat([0, 1, 2], [100, 5, 3000])
    starts = block_starts(seg, 3, 1000)
    assert starts[0] == 0 and starts[-1] == len(seg)
    assert np.all(np.diff(starts) > 0) and np.max(np.diff(starts)) <= 1000
    for a in (0, 100, 105):  # every stretch starts a block
        assert a in starts
    assert 6 in starts and 94 in starts and 105 + 6 in starts and 3105 - 6 in starts


def test_jump_lost_is_the_mass_the_shift_loses():
    rng = np.random.default_rng(11)
    for n, breaks in ((40, ()), (40, (5, 19)), (3, ())):
        g = _route(n, set(breaks))
        motion, state, _, _ = _case(rng, n, (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), 0.95, 0.0, True)
        fwd, bwd = route_neighbours(g)[:2]
        whole, frac, sign, _ = motion._bin_moves
        moved = np.empty_like(state)
        _shift_walk(state, moved, whole, frac, sign, fwd, bwd, *motion._columns)
        seg = line_segments(fwd, bwd)
        lost = jump_lost(np.ascontiguousarray(state.T), seg, segment_edges(seg, 4), *motion._columns, whole, frac,
                         sign)
        np.testing.assert_allclose(lost, state.sum() - moved.sum(), rtol=1e-12, atol=1e-15)


def test_line_segments_only_for_a_route_by_place_index():
    assert np.array_equal(line_segments(*route_neighbours(_route(6, {2}))[:2]), [0, 0, 0, 1, 1, 1])
    assert np.array_equal(line_segments(*route_neighbours(PlaceGraph.chain(4))[:2]), [0, 0, 0, 0])
    assert line_segments(*route_neighbours(_reversed_route(6))[:2]) is None


def _filter_pair(graph, rows, odometry, seed, lam=0.2):
    """The filter with its compiled jump grid, and the same filter with the reference."""
    runs = []
    for compiled in (True, False):
        loc = Localizer(graph, _Fixed(0.9), n_particles=300, motion=VelocityMotion(), jump_graduation=lam,
                        seed=seed).reset()
        if not compiled:
            loc._jumps_line = None  # catgraph.grid.predict
        out = []
        for k, r in enumerate(rows):
            est = loc.step(r, odometry[k])
            out.append(np.r_[loc.place_posterior_, est.confidence, loc.new_place_probability_])
        runs.append((np.array(out), loc))
    return runs


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("with_odometry", [False, True])
def test_filter_with_compiled_jump_grid_matches_the_reference(direction, with_odometry):
    """Forward and backward along the route, with and without odometry on some frames:
    the compiled jump grid and ``grid.predict`` give the same filter (the particles draw
    from the same floats up to rounding, so the posteriors agree closely)."""
    n = 180
    g = PlaceGraph.chain(n)
    rng = np.random.default_rng(3 if direction > 0 else 4)
    path = np.r_[np.arange(20, 60), np.arange(130, 170)] if direction > 0 else np.r_[np.arange(150, 110, -1),
                                                                                      np.arange(60, 20, -1)]
    j = np.arange(n)
    rows = np.array([2.0 * np.minimum(np.abs(j - p), 6) / 6.0 + 0.3 * rng.standard_normal(n) for p in path])
    odometry = [1.0 if with_odometry and k % 9 == 4 else None for k in range(len(rows))]
    (a, la), (b, lb) = _filter_pair(g, rows, odometry, seed=2)
    assert la._jumps_line is not None and lb._jumps_line is None
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(la.jump_state(), lb.jump_state(), rtol=1e-9, atol=1e-300)
    assert la._jumps_mass > 0.0


def test_filter_on_a_route_not_by_index_takes_the_reference():
    g = _reversed_route(60)
    rng = np.random.default_rng(9)
    rows = rng.standard_normal((25, 60))
    loc = Localizer(g, _Fixed(0.9), n_particles=200, motion=VelocityMotion(), jump_graduation=0.3, seed=0)
    loc.run(rows)
    assert loc._jumps_line is None and loc._jumps_mass > 0.0
