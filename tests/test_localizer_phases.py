"""The particle filter's velocity-marginalised motion drives a fractional speed by the
grid filter's phase bins (``catgraph.grid.phase_bins``), so that it converges to the grid
filter with its default ``max_phases`` — the slow, exact reference — on a query driven at
half the reference's speed, where one bin per speed (a random extra hop) does not."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer, phase_bins
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion

from .conftest import FixedLogRatio as _Fixed


def _half_speed_rows(n: int, frames: int, seed: int) -> np.ndarray:
    """A chain driven at half speed (each place seen twice): eight informative frames set
    the track, the rest say nothing, so the motion alone must hold it."""
    rng = np.random.default_rng(seed)
    truth = 5 + np.arange(frames) // 2
    rows = np.zeros((frames, n))
    for t in range(8):
        rows[t] = rng.random(n)
        rows[t, truth[t]] -= 3.0
    return rows


def _mean_tv(a: np.ndarray, b: np.ndarray) -> float:
    return float(0.5 * np.abs(a - b).sum(1)[8:].mean())


def test_particles_at_half_speed_converge_to_the_grid_with_its_phase_bins():
    """Held by the motion alone, the grid's phase bins keep the half-speed track a point
    mass where one bin per speed spreads it as a random walk (the two grids differ by a
    mean total variation of about 0.4). The particles' default follows the phases: their
    distance to the default grid falls with the particles (0.08 at 250, 0.015 at 4,000),
    while particles with one bin per speed stay about 0.4 away at any number."""
    n, g = 60, PlaceGraph.chain(60)
    rows = _half_speed_rows(n, 40, 0)
    exact = GridLocalizer(g, _Fixed(2.0), recovery=0.01).run(rows, return_posterior=True).posterior
    split = GridLocalizer(g, _Fixed(2.0), recovery=0.01, max_phases=1).run(rows, return_posterior=True).posterior
    assert _mean_tv(exact, split) > 0.3  # the case separates the two representations

    def tv(k, **motion):
        return np.mean([_mean_tv(Localizer(g, _Fixed(2.0), k, recovery=0.01, motion=VelocityMotion(**motion),
                                           seed=s).run(rows, return_posterior=True).posterior, exact)
                        for s in range(3)])

    few, many = tv(250), tv(4000)
    assert many < few / 3 and many < 0.03
    assert tv(4000, max_phases=1) > 0.3
    # and with one bin per speed they converge to the grid with one bin per speed
    one_bin = np.mean([_mean_tv(Localizer(g, _Fixed(2.0), 4000, recovery=0.01, motion=VelocityMotion(max_phases=1),
                                          seed=s).run(rows, return_posterior=True).posterior, split)
                       for s in range(3)])
    assert one_bin < 0.03


@pytest.mark.parametrize("velocities, max_phases", [(None, None), ((-2.5, -1.0, 0.25, 1.0, 4 / 3), 4),
                                                    ((-1.5, 0.5, 1.0), 1)])
def test_the_marginal_motion_has_the_grid_filters_state_bins(velocities, max_phases):
    """Bins, their moves and the transition are those of a grid filter of the same motion;
    the particles' velocity distributions and their prior live on those bins (each speed
    uniform, shared evenly by its phases)."""
    kw = {} if velocities is None else {"velocities": velocities}
    if max_phases is not None:
        kw["max_phases"] = max_phases
    g = PlaceGraph.chain(30)
    motion = VelocityMotion(**kw)
    assert motion.supports_marginal(g)
    grid = GridLocalizer(g, _Fixed(1.0), **kw).reset()
    np.testing.assert_array_equal(motion._owner, grid._owner)
    for ours, theirs in zip(motion._bin_moves, grid._moves):
        np.testing.assert_array_equal(ours, theirs)
    np.testing.assert_array_equal(motion._transition, grid._transition)
    owner = phase_bins(grid._v, grid.max_phases)[0]
    loc = Localizer(g, _Fixed(1.0), 100, motion=motion, seed=0).reset()
    assert loc._spread.shape == (100, len(owner))
    prior = loc._velocity_prior
    np.testing.assert_allclose(np.bincount(owner, weights=prior), 1.0 / len(grid._v))
    for b in range(len(owner)):  # the phases of one speed alike
        assert prior[b] == prior[np.flatnonzero(owner == owner[b])[0]]


def test_odometry_frames_between_marginal_frames_draw_speeds_not_phase_bins():
    """A frame with odometry takes the sampled motion: each particle draws a bin from its
    distribution and drives at that bin's *speed* (an index into the velocities, never a
    phase bin's index), and comes back to the marginal motion with that speed's phases."""
    n = 40
    positions = np.stack([np.arange(n, dtype=float), np.zeros(n)], 1)
    from catgraph.traverse import Traverse

    g = PlaceGraph.from_traverse(Traverse(np.zeros((n, 2)), positions=positions))
    motion = VelocityMotion()
    loc = Localizer(g, _Fixed(1.0), 300, motion=motion, seed=0).reset()
    assert loc._marginal and len(motion._owner) > len(motion._v)  # phases: ±0.5 by default
    rng = np.random.default_rng(0)
    for t in range(12):
        row = rng.random(n)
        row[5 + t // 2] -= 3.0
        loc.step(row, odometry=1.0 if t in (4, 5, 9) else None)
        if t in (4, 5, 9):
            # a speed index, or a draw from the prior still to come (negative: the births)
            assert loc._velocity.max() < len(motion._v)
            moved = np.ones(300, dtype=bool)
            moved[loc._newborn[0]:loc._newborn[1]] = False
            moved &= loc._velocity >= 0
            assert moved.sum() > 200
            # each particle that drove: its speed's phases alike, nothing elsewhere
            np.testing.assert_array_equal(loc._spread[moved], motion._speed_bins[loc._velocity[moved]])
    np.testing.assert_allclose(loc._spread.sum(1), 1.0)


def test_max_phases_validated():
    g = PlaceGraph.chain(5)
    for bad in (0, 65, 1.5, "four"):
        with pytest.raises(InvalidParameterError, match="max_phases"):
            VelocityMotion(max_phases=bad).supports_marginal(g)
