"""Tests for the window rule "punctuated": rule "spanning" with the spread test read only on
sub-windows that span half the query's decorrelation horizon or hold a break of its rows,
against a plain loop over frames.

The reference below recomputes every window score of every velocity by a double loop over
the line's frames, the horizon by the plain loop of ``tests/test_window_rule_decorrelated.py``,
and the breaks of the rows by a loop over frames and lags on the whole standardised rows (a
frame breaks where its mean standardised difference at the best places of each of the three
rows before it, over that at its own best places, is below the decorrelation level). It
admits the windows whose recent sub-windows pass the midpoint and rival tests of "spanning"
and whose sub-windows that span half the horizon, or hold the latest break, pass the spread
test; it takes the most significant admitted window and re-chooses the velocity where the
window spans the horizon. The matcher must make the same choices and give the same
confidences, in the batch and the streaming form.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import log_ndtr

from catgraph._window_rule import (BREAK_LAGS, DECORRELATION_LEVEL, DECORRELATION_PLACES, EVIDENT_SPREADS,
                                   JUMP_ODDS, RIVAL_SPREADS, SPANNING_MARGIN, SPREAD_HORIZON_FRACTION,
                                   WEAK_LINE_SPREADS, _Breaks)
from catgraph.sequence import match_sequences, window_grid
from tests.test_sequence_velocity import slow_line_scores
from tests.test_window_rule import on_grid
from tests.test_window_rule_decorrelated import slow_horizons, smooth_route
from tests.test_window_rule_predictive import assert_streaming_equals_batch
from tests.test_window_rule_spanning import varying_route

VELOCITIES = (1.0, 2.0)


def slow_since_breaks(d: np.ndarray, lags: int = BREAK_LAGS, level: float = DECORRELATION_LEVEL,
                      places: int = DECORRELATION_PLACES) -> np.ndarray:
    """``(n_q,)`` frames since the latest break of the rows (0 at a break; more than any
    window before the first), by loops over frames and lags on whole standardised rows."""
    z = [(row - row.mean()) / row.std() if row.std() > 0 else None for row in d]
    best = [None if r is None else np.argsort(r, kind="stable")[:places] for r in z]
    last = -(10 ** 9)
    out = np.empty(d.shape[0], dtype=int)
    for i in range(d.shape[0]):
        broke = False
        if z[i] is not None and i >= lags:
            own = np.mean(z[i][best[i]])
            if own < 0 and all(best[i - k] is not None for k in range(1, lags + 1)):
                broke = all(np.mean(z[i][best[i - k]]) / own < level for k in range(1, lags + 1))
        if broke:
            last = i
        out[i] = i - last
    return out


def slow_punctuated(d: np.ndarray, grid: np.ndarray, velocities, fraction: float = 0.05, radius: int = 10,
                    rule: str = "punctuated"):
    """Per frame: match, effective window, velocity and confidence "posterior" of rule
    "punctuated" (or, ``rule="gated"``, of rule "gated": the spread test read on the
    sub-windows that span the horizon, and on shorter ones where the window's own score lies
    less than ``WEAK_LINE_SPREADS`` spreads below the mean at the sub-window's length); and the
    number of frames whose chosen window the spread test on every shorter sub-window (rule
    "spanning") would have rejected."""
    n_q, n = d.shape
    horizons = slow_horizons(d)
    since = slow_since_breaks(d)
    scores = {(int(L), v): slow_line_scores(d, int(L), v) for L in grid for v in velocities}
    out = {k: [] for k in ("match", "length", "velocity", "confidence")}
    spared = 0
    for i in range(n_q):
        rows = [[scores[int(L), v][i] for L in grid] for v in velocities]  # [v][g] -> (N,)
        spread = [max(rows[a][g].std() for a in range(len(velocities))) for g in range(len(grid))]
        best_j = [[int(np.argmin(r)) for r in rv] for rv in rows]
        log_p = [[float(log_ndtr((r.min() - r.mean()) / spread[g])) for g, r in enumerate(rv)] for rv in rows]

        def admitted(a, gated=True):
            keep = []
            for g in range(len(grid)):
                ok = True
                for h in range(g):  # every shorter length
                    sub, own = rows[a][h][best_j[a][g]], rows[a][g][best_j[a][g]]
                    recent = grid[h] >= fraction * grid[g]
                    if recent and sub > 0.5 * (own + rows[a][h].mean()):
                        ok = False
                    if rule == "gated":
                        weak = (rows[a][h].mean() - own) / (spread[h] if spread[h] > 0 else 1.0) < WEAK_LINE_SPREADS
                        read = grid[h] >= horizons[i] or weak or not gated
                    else:
                        read = grid[h] >= SPREAD_HORIZON_FRACTION * horizons[i] or since[i] < grid[h] or not gated
                    if read and sub > rows[a][h].mean() - EVIDENT_SPREADS * spread[h]:
                        ok = False
                    if (recent and grid[h] >= horizons[i] and log_p[a][h] < -np.log(n) - SPANNING_MARGIN
                            and sub > rows[a][h].min() + RIVAL_SPREADS * spread[h]):
                        ok = False
                if ok or g == 0:
                    keep.append(g)
            return keep

        a0 = min(range(len(velocities)), key=lambda a: (sum(log_p[a]), a))
        g = min(admitted(a0), key=lambda k: (log_p[a0][k], k))
        spared += int(g not in admitted(a0, gated=False))
        a = a0
        if grid[g] >= horizons[i]:
            a = min(range(len(velocities)), key=lambda b: (log_p[b][g], b))
        match = best_j[a][g]
        support = 0.0
        for k in set(admitted(a)) | {g}:
            if abs(best_j[a][k] - match) <= radius:
                far = np.abs(np.arange(n) - best_j[a][k]) > radius
                support += (rows[a][k][far].min() - rows[a][k].min()) / spread[k]
        z = (d[i, match] - d[i].mean()) / d[i].std()
        mu = (rows[a][g][match] - d[i].mean()) / d[i].std()
        log_ratio = (z * z - (z - mu) ** 2) / 2.0  # on the line against a random place
        out["match"].append(match)
        out["length"].append(min(int(grid[g]), i + 1))
        out["velocity"].append(velocities[a])
        out["confidence"].append(support / (1.0 + JUMP_ODDS * np.exp(-log_ratio)))
    return {k: np.array(v) for k, v in out.items()}, spared


def scene_route(seed: int, width: int, strength: float, n_ref: int = 60) -> np.ndarray:
    """Rows alike for about ``width`` frames along a planted line; at frame 24 the scene
    changes (the rows of another smooth route: a break) and the line moves to the reference's
    second half; frames 36-41 are a hard stretch (the line's dip removed), so a correct long
    line's latest frames are no better than random places there."""
    a = smooth_route(24, n_ref, seed, width, strength)
    b = smooth_route(24, n_ref, seed + 10, width, strength, jump_at=0)
    d = np.concatenate([a, b])
    f = np.arange(36, 42)
    d[f, (f - 24 + n_ref // 2) % n_ref] += strength
    return on_grid(d)


def routes():
    """A route of white rows at a varying speed with a jump (horizon about 1), and routes whose
    rows stay alike for 7-13 frames, with a change of scene and a hard stretch."""
    yield varying_route(0)
    for seed, width, strength in ((0, 16, 2.0), (1, 24, 2.5), (2, 24, 2.5)):
        yield scene_route(seed, width, strength)


@pytest.mark.parametrize("k", range(4))
def test_punctuated_rule_matches_slow_reference(k):
    d = list(routes())[k]
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="punctuated", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _ = slow_punctuated(d, grid, VELOCITIES)
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_punctuated_reference_exercises_the_gate():
    """On these routes the rows break, and the gated spread test admits windows that the test
    on every shorter sub-window rejects, so the comparison above checks the gate."""
    grid = window_grid(3, 24, 6)
    spared = 0
    breaks = 0
    for d in routes():
        spared += slow_punctuated(d, grid, VELOCITIES)[1]
        breaks += int(np.sum(slow_since_breaks(d) == 0))
    assert spared > 0
    assert breaks > 0


def test_breaks_clock_matches_slow_loop():
    """The clock's frames since the latest break equal the plain loop's, on rows alike for
    several frames with changes of scene, a flat row and rows shown twice."""
    d = np.concatenate([scene_route(0, 16, 2.0), scene_route(1, 24, 2.5),
                        np.repeat(scene_route(2, 12, 2.0), 2, axis=0)])
    d[30] = 0.5  # a flat row: no break, and no break in the three frames after it
    clock = _Breaks()
    since = []
    for i, row in enumerate(d):
        clock.update(row, i, row.std())
        since.append(clock.since)
    expected = slow_since_breaks(d)
    np.testing.assert_array_equal(since, expected)
    assert np.sum(expected == 0) >= 2


@pytest.mark.parametrize("confidence", ["posterior", "changepoint", "gap"])
def test_punctuated_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames (the clock and
    its latest break travel from block to block)."""
    d = np.concatenate([scene_route(1, 24, 2.5), scene_route(3, 16, 2.0)[:12]])
    kwargs = dict(rule="punctuated", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)


def strong_line_route(seed: int = 2, width: int = 12, strength: float = 3.0, hard: int = 3) -> np.ndarray:
    """Rows alike for about ``width`` frames along a strong planted line whose dip is removed
    for ``hard`` frames from frame 40: a strong line with a weak recent stretch shorter than
    the horizon, which rule "gated" keeps and the spread test on every sub-window rejects."""
    d = smooth_route(48, 60, seed, width, strength)
    f = np.arange(40, 40 + hard)
    d[f, (f + 5) % 60] += strength
    return on_grid(d)


def gated_routes():
    """The routes of rule "punctuated" and one whose strong line the gate keeps."""
    yield from routes()
    yield strong_line_route()


@pytest.mark.parametrize("k", range(5))
def test_gated_rule_matches_slow_reference(k):
    d = list(gated_routes())[k]
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="gated", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _ = slow_punctuated(d, grid, VELOCITIES, rule="gated")
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_gated_reference_exercises_the_gate():
    """On these routes the gate admits windows that the spread test on every shorter
    sub-window rejects, and the answers differ from rule "punctuated"'s somewhere."""
    grid = window_grid(3, 24, 6)
    spared = 0
    differ = 0
    for d in gated_routes():
        gated, n_spared = slow_punctuated(d, grid, VELOCITIES, rule="gated")
        spared += n_spared
        punctuated, _ = slow_punctuated(d, grid, VELOCITIES)
        differ += int(np.sum(gated["length"] != punctuated["length"]))
    assert spared > 0
    assert differ > 0


@pytest.mark.parametrize("confidence", ["posterior", "changepoint"])
def test_gated_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames."""
    d = np.concatenate([scene_route(1, 24, 2.5), scene_route(3, 16, 2.0)[:12]])
    kwargs = dict(rule="gated", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)
