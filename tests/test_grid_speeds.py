"""The grid filter follows a query driven at any speed from 0.9 to four times the
reference's, and at a half, two thirds and three quarters of it (the registry's dense
velocity bins), where the eight bins of the class default lose every speed between theirs."""

import numpy as np
import pytest

from catgraph.graph import PlaceGraph
from catgraph.grid import DEFAULT_VELOCITIES, DENSE_VELOCITIES
from catgraph.methods import make_filter, observation_model, resolve_params

FRAMES, SETTLE = 300, 50


def _rows(speed: float, seed: int, noise: float = 0.8):
    """Difference rows of a query at ``speed`` places per frame on a map just long enough: a
    dip one place wide at the true place under noise that single frames cannot see through
    (the filter must carry the track), and the true place of each frame."""
    rng = np.random.default_rng(seed)
    pos = 20.0 + speed * np.arange(FRAMES)
    n_places = int(pos[-1]) + 40
    offset = np.arange(n_places)[None, :] - pos[:, None]
    d = -np.exp(-offset ** 2 / 2.0) + noise * rng.standard_normal((FRAMES, n_places))
    return d, np.floor(pos + 0.5).astype(np.int64)


def _accuracy(speed: float, seed: int, bins=None) -> float:
    d, truth = _rows(speed, seed)
    # the eight bins as on a large map: no varying speed's motion, which hops between them
    given = {} if bins is None else {"velocity_bins": list(bins), "varying_prior": 0.0}
    params = resolve_params("filter", {"mode": "grid", **given})
    n = d.shape[1]
    loc = make_filter(params, PlaceGraph.chain(n), observation_model(params, n, None)).reset()
    places = np.array([loc.step(row).place for row in d])
    return float(np.mean(np.abs(places - truth)[SETTLE:] <= 2))


def test_single_frames_cannot_see_the_track():
    d, truth = _rows(1.5, 0)
    assert np.mean(np.abs(np.argmin(d, axis=1) - truth) <= 2) < 0.2


@pytest.mark.parametrize("speed", [1.0, 1.5, 0.75, 2 / 3, 2.5, 1.1, 3.7, 0.95])
def test_the_registry_filter_follows_speeds_between_the_eight_bins(speed):
    assert _accuracy(speed, seed=0) >= 0.95


@pytest.mark.parametrize("speed", [1.5, 2.5])
def test_the_eight_bins_lose_a_speed_between_theirs(speed):
    assert _accuracy(speed, seed=0, bins=DEFAULT_VELOCITIES) < 0.5
    assert _accuracy(1.0, seed=0, bins=DEFAULT_VELOCITIES) >= 0.95  # and hold their own


def test_dense_bins_cover_half_to_four_times_the_speed_both_ways():
    v = np.asarray(DENSE_VELOCITIES)
    assert np.array_equal(v, -v[::-1]) and np.all(np.diff(v) > 0)
    speeds = v[v > 0]
    assert speeds[:4] == pytest.approx([1 / 2, 2 / 3, 3 / 4, 0.9]) and speeds[-1] == 4.0
    assert np.max(np.diff(speeds[3:])) == pytest.approx(0.1)  # every tenth from 0.9


def _varying_rows(seed: int, noise: float = 0.8, profile=(1.0, 2.0, 0.7, 1.6)):
    """Rows as :func:`_rows`, the speed moving linearly through ``profile`` over the frames
    (1 → 2 → 0.7 → 1.6 places per frame: every frame between the bins' speeds or leaving them)."""
    rng = np.random.default_rng(seed)
    speed = np.interp(np.arange(FRAMES), np.linspace(0, FRAMES, len(profile)), profile)
    pos = 20.0 + np.concatenate([[0.0], np.cumsum(speed[:-1])])
    n_places = int(pos[-1]) + 40
    offset = np.arange(n_places)[None, :] - pos[:, None]
    d = -np.exp(-offset ** 2 / 2.0) + noise * rng.standard_normal((FRAMES, n_places))
    return d, np.floor(pos + 0.5).astype(np.int64)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_registry_filter_follows_a_speed_that_changes_all_the_time(seed):
    """The varying speed's motion (``varying_prior``, on by default on small maps) follows a
    query whose speed never settles; the filter's own sticky velocity alone loses it."""
    d, truth = _varying_rows(seed)
    accuracy = {}
    for label, given in (("default", {}), ("without", {"varying_prior": 0.0})):
        params = resolve_params("filter", {"mode": "grid", **given})
        n = d.shape[1]
        loc = make_filter(params, PlaceGraph.chain(n), observation_model(params, n, None)).reset()
        places = np.array([loc.step(row).place for row in d])
        accuracy[label] = float(np.mean(np.abs(places - truth)[SETTLE:] <= 2))
    assert accuracy["default"] >= 0.9 and accuracy["without"] < 0.85
