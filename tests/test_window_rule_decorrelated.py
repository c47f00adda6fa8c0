"""Tests for the window rule "decorrelated": the predictive record of rule "predictive" with a
horizon read from the query's own rows, against plain loops over frames.

The reference below measures, for every frame and lag, how well the best places of the row
``k`` frames back still match the current row (their mean standardised difference over
that of the row's own best places, the best places found by a full sort), averages each
lag's ratio over the frames with the rule's half-life, takes the first lag whose average
is below the level as the frame's horizon, recomputes every window score by a double loop,
follows each length's best line that many frames ahead and keeps the discounted mean of
the losses per length. The matcher must make the same choices in the batch and the
streaming form, and carry the horizon's state across the batch form's blocks.
"""

from __future__ import annotations

import numpy as np
import pytest

from catgraph._window_rule import (DECORRELATION_HALF_LIFE, DECORRELATION_LEVEL, DECORRELATION_PLACES, HORIZON_MAX,
                                   _Horizon)
from catgraph.sequence import match_sequences, window_grid
from tests.test_window_rule import V1, on_grid
from tests.test_window_rule_predictive import assert_streaming_equals_batch, slow_predictive


def slow_horizons(d: np.ndarray, places: int = DECORRELATION_PLACES, level: float = DECORRELATION_LEVEL,
                  half_life: float = DECORRELATION_HALF_LIFE, capacity: int = HORIZON_MAX) -> np.ndarray:
    """``(n_q,)`` the horizon of every frame, by loops over frames and lags."""
    z = [(row - row.mean()) / row.std() for row in d]
    best = [np.argsort(r, kind="stable")[:places] for r in z]
    decay = 2.0 ** (-1.0 / half_life)
    out = np.empty(d.shape[0], dtype=int)
    for i in range(d.shape[0]):
        horizon = capacity
        for k in range(1, capacity + 1):
            total = weight = 0.0
            for s in range(k, i + 1):  # every frame so far that has a frame k back
                ratio = np.mean(z[s][best[s - k]]) / np.mean(z[s][best[s]])
                total += decay ** (i - s) * ratio
                weight += decay ** (i - s)
            if weight > 0 and total / weight < level:
                horizon = k
                break
        out[i] = horizon
    return out


def slow_decorrelated(d: np.ndarray, grid: np.ndarray, **horizon_kwargs):
    """Per frame (forward diagonal only): the match, the effective window and the horizon."""
    horizons = slow_horizons(d, **horizon_kwargs)
    match, length = slow_predictive(d, grid, horizons)
    return match, length, horizons


def smooth_route(n_q: int, n_ref: int, seed: int, width: int, strength: float, jump_at: int | None = None,
                 repeat: int = 1) -> np.ndarray:
    """Rows that stay alike for about ``width`` frames (a moving sum of noise rows, each
    shifted one place per frame like a route seen from a moving vehicle), a diagonal of lower
    differences (a jump to another place at ``jump_at``), each frame shown ``repeat`` times."""
    rng = np.random.default_rng(seed)
    frames = -(-n_q // repeat)
    noise = rng.normal(size=(frames + width, n_ref + frames + width))
    d = np.empty((frames, n_ref))
    for i in range(frames):
        d[i] = sum(noise[i + w, i + w: i + w + n_ref] for w in range(width)) / np.sqrt(width)
    truth = np.arange(frames) + 5
    if jump_at is not None:
        truth[jump_at:] = np.arange(frames - jump_at) + n_ref // 2
    d[np.arange(frames), truth % n_ref] -= strength
    return on_grid(np.repeat(d, repeat, axis=0)[:n_q])


def test_horizon_follows_the_rows():
    """White rows decorrelate at once; rows alike for ``w`` frames take longer; the same rows
    each shown twice (half the speed) take twice as long."""
    def final_horizon(d):
        clock = _Horizon()
        for i, row in enumerate(d):
            k = clock.update(row, i, row.std())
        return k

    white = final_horizon(smooth_route(200, 300, 0, 1, 0.0))
    smooth = final_horizon(smooth_route(200, 300, 0, 8, 0.0))
    slow = final_horizon(smooth_route(400, 300, 0, 8, 0.0, repeat=2))
    assert white == 1
    assert 2 <= smooth <= 8
    assert 2 * smooth - 1 <= slow <= 2 * smooth + 1


@pytest.mark.parametrize("seed, width, strength, repeat", [(0, 4, 3.0, 1), (1, 6, 4.0, 1), (2, 3, 3.0, 2)])
def test_decorrelated_rule_matches_slow_reference(seed, width, strength, repeat):
    d = smooth_route(48, 40, seed, width, strength, jump_at=24 // repeat, repeat=repeat)
    grid = window_grid(3, 24, 7)
    result = match_sequences(d, "adaptive", rule="decorrelated", grid=7, l_min=3, l_max=24, velocities=V1)
    match, length, horizons = slow_decorrelated(d, grid)
    assert horizons[10:].max() > 1  # the horizon is not trivially one frame
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_array_equal(result.window_length, length)


def test_decorrelated_rule_changes_its_horizon():
    """On these routes the reference's horizon varies, so the test above checks a horizon that moves."""
    _, _, horizons = slow_decorrelated(smooth_route(48, 40, 2, 3, 3.0, jump_at=12, repeat=2), window_grid(3, 24, 7))
    assert len(np.unique(horizons)) > 2


@pytest.mark.parametrize("confidence", ["posterior", "support"])
def test_decorrelated_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames (the record and
    the horizon's state travel from block to block)."""
    d = smooth_route(60, 50, 4, 4, 3.0, jump_at=30)
    kwargs = dict(rule="decorrelated", l_min=3, l_max=30, grid=6, confidence=confidence)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)


def test_decorrelated_rule_recovers_after_a_jump(jump_route):
    """White rows give the horizon 1 at once; after the jump the record turns to the lines that
    re-lock, and most frames on both sides of it are matched."""
    d, truth = jump_route  # a jump at frame 100
    res = match_sequences(d, rule="decorrelated", l_min=5, l_max=100, grid=16, velocities=V1)
    assert np.mean(res.match[120:] == truth[120:]) >= 0.75
    assert np.mean(res.match[:100] == truth[:100]) >= 0.9


def test_flat_rows_add_nothing_to_the_horizon():
    """A flat row (a frame without information) has no best places: neither its own frame
    nor any later frame whose lag reaches back to it adds a ratio, and the matcher stays finite."""
    flat = smooth_route(80, 60, 6, 5, 0.0)
    flat[30] = 0.0
    clock = _Horizon()
    for i, row in enumerate(flat):
        clock.update(row, i, row.std())
    assert np.all(np.isfinite(clock.total))
    n = len(flat)
    for k in (1, 5, 20):  # the discounted count of frames that added a ratio at lag k
        frames = [s for s in range(k, n) if s != 30 and s - k != 30]
        assert clock.weight[k - 1] == pytest.approx(sum(clock.decay ** (n - 1 - s) for s in frames), rel=1e-12)
    res = match_sequences(flat, rule="decorrelated", l_min=3, l_max=30, grid=6, velocities=V1)
    assert np.all(np.isfinite(res.confidence))
