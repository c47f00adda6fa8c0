"""Tests for the window rule "contested": rule "gated" where a weak window line also yields to a
rival that spans two decorrelation horizons and is significant beyond the random lines searched,
against a plain loop over frames.

The reference below recomputes every window score of every velocity by a double loop over the
line's frames and the horizon by the plain loop of ``tests/test_window_rule_decorrelated.py``.
It admits the windows of rule "gated" (the midpoint test on the recent sub-windows, the spread
test on the sub-windows that span the horizon or where the window's own line is weak, the
rival that spans the horizon and is significant by ``SPANNING_MARGIN`` nats beyond chance) and
rejects, in addition, a window whose line, over a recent sub-window where that line is weaker
than ``CONTEST_LINE_SPREADS`` common spreads below the random places' mean, trails the best
line of the sub-window's length by more than ``RIVAL_SPREADS`` spreads while that best line
spans ``CONTEST_SPANS`` horizons and is significant beyond the best of the ``N V`` random lines
searched by ``CONTEST_MARGIN`` nats (``log p < -ln(N V) - CONTEST_MARGIN``). It takes
the most significant admitted window and re-chooses the velocity where the window spans the
horizon. The matcher must make the same choices and give the same confidences, in the batch and
the streaming form, and on the cluster (``tests/test_distributed_rules.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import log_ndtr

from catgraph._window_rule import (CONTEST_LINE_SPREADS, CONTEST_MARGIN, CONTEST_SPANS, EVIDENT_SPREADS, JUMP_ODDS,
                                   PROVEN_MARGIN, RIVAL_SPREADS, SPANNING_MARGIN, WEAK_LINE_SPREADS)
from catgraph.sequence import match_sequences, window_grid
from tests.test_sequence_velocity import slow_line_scores
from tests.test_window_rule import on_grid
from tests.test_window_rule_decorrelated import slow_horizons
from tests.test_window_rule_predictive import assert_streaming_equals_batch
from tests.test_window_rule_punctuated import gated_routes, scene_route, slow_since_breaks
from tests.test_window_rule_spanning import varying_route

VELOCITIES = (1.0, 2.0)


def slow_contested(d: np.ndarray, grid: np.ndarray, velocities, fraction: float = 0.05, radius: int = 10,
                   contested: bool = True, persistent: bool = False, challenged: bool = False):
    """Per frame: match, effective window, velocity and confidence "posterior" of rule
    "contested" (``contested=False``: of rule "gated"; ``persistent=True``: of rule "persistent",
    whose midpoint test is read only on the sub-windows that span the horizon, where the window's
    line is weaker than ``CONTEST_LINE_SPREADS`` or that hold the latest break of the rows;
    ``challenged=True`` with it: of rule "challenged", whose weak-line rival counts beyond
    ``-ln N`` without a margin where the window's own line is not significant beyond
    ``-ln(N V) - PROVEN_MARGIN`` at its full length), and
    the number of frames where the contested rival rejected the window that rule "gated" would
    have chosen."""
    n_q, n = d.shape
    horizons = slow_horizons(d)
    since = slow_since_breaks(d)
    scores = {(int(L), v): slow_line_scores(d, int(L), v) for L in grid for v in velocities}
    out = {k: [] for k in ("match", "length", "velocity", "confidence")}
    contests = 0
    for i in range(n_q):
        rows = [[scores[int(L), v][i] for L in grid] for v in velocities]  # [v][g] -> (N,)
        spread = [max(rows[a][g].std() for a in range(len(velocities))) for g in range(len(grid))]
        best_j = [[int(np.argmin(r)) for r in rv] for rv in rows]
        log_p = [[float(log_ndtr((r.min() - r.mean()) / spread[g])) for g, r in enumerate(rv)] for rv in rows]

        def admitted(a, with_contest):
            keep = []
            for g in range(len(grid)):
                ok = True
                for h in range(g):  # every shorter length
                    sub, own = rows[a][h][best_j[a][g]], rows[a][g][best_j[a][g]]
                    recent = grid[h] >= fraction * grid[g]
                    level = (rows[a][h].mean() - own) / (spread[h] if spread[h] > 0 else 1.0)
                    mid_read = recent and (not persistent or grid[h] >= horizons[i] or level < CONTEST_LINE_SPREADS
                                           or since[i] < grid[h])
                    if mid_read and sub > 0.5 * (own + rows[a][h].mean()):
                        ok = False
                    read = grid[h] >= horizons[i] or level < WEAK_LINE_SPREADS
                    if read and sub > rows[a][h].mean() - EVIDENT_SPREADS * spread[h]:
                        ok = False
                    beaten = sub > rows[a][h].min() + RIVAL_SPREADS * spread[h]
                    if (recent and grid[h] >= horizons[i] and log_p[a][h] < -np.log(n) - SPANNING_MARGIN
                            and beaten):
                        ok = False
                    if challenged:
                        contender = (log_p[a][h] < -np.log(n)
                                     and log_p[a][g] >= -np.log(n * len(velocities)) - PROVEN_MARGIN)
                    else:
                        contender = log_p[a][h] < -np.log(n * len(velocities)) - CONTEST_MARGIN
                    if (with_contest and recent and beaten and level < CONTEST_LINE_SPREADS
                            and grid[h] >= CONTEST_SPANS * horizons[i] and contender):
                        ok = False
                if ok or g == 0:
                    keep.append(g)
            return keep

        a0 = min(range(len(velocities)), key=lambda a: (sum(log_p[a]), a))
        g = min(admitted(a0, contested), key=lambda k: (log_p[a0][k], k))
        contests += int(g != min(admitted(a0, False), key=lambda k: (log_p[a0][k], k)))
        a = a0
        if grid[g] >= horizons[i]:
            a = min(range(len(velocities)), key=lambda b: (log_p[b][g], b))
        match = best_j[a][g]
        support = 0.0
        for k in set(admitted(a, contested)) | {g}:
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
    return {k: np.array(v) for k, v in out.items()}, contests


def repeated_route(seed: int, n_q: int = 48, n_ref: int = 80) -> np.ndarray:
    """White rows (the rows decorrelate within a frame or two) along a route driven at a
    speed that changes every few frames, past a weaker copy of an earlier stretch (repeated
    scenery): a long straight line through the copy is weak but longer than the true one."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    steps = rng.choice([1, 1, 2], size=n_q)
    truth = 4 + np.cumsum(steps) - steps[0]
    truth = np.minimum(truth, n_ref - 1)
    d[np.arange(n_q), truth] -= 2.5
    d[np.arange(n_q), (truth[0] + 30 + np.arange(n_q)) % n_ref] -= 1.2
    return on_grid(0.4 * d)  # below 4 everywhere: the matcher stores these values exactly


def routes():
    """Routes whose rows decorrelate within a few frames: varying speeds, a jump, repeated scenery."""
    for seed in range(3):
        yield varying_route(seed)
    for seed in range(3):
        yield repeated_route(seed)


@pytest.mark.parametrize("k", range(6))
def test_contested_rule_matches_slow_reference(k):
    d = list(routes())[k]
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="contested", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _ = slow_contested(d, grid, VELOCITIES)
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_contested_reference_exercises_the_contest():
    """On these routes the contested rival rejects windows that rule "gated" chooses, so the
    comparison above checks it; and the library's "gated" differs from its "contested" there."""
    grid = window_grid(3, 24, 6)
    contests = 0
    differ = 0
    for d in routes():
        contests += slow_contested(d, grid, VELOCITIES)[1]
        kwargs = dict(grid=6, l_min=3, l_max=24, velocities=VELOCITIES, confidence="posterior")
        a = match_sequences(d, "adaptive", rule="contested", **kwargs)
        b = match_sequences(d, "adaptive", rule="gated", **kwargs)
        differ += int(np.sum(a.window_length != b.window_length))
    assert contests > 0
    assert differ > 0


@pytest.mark.parametrize("confidence", ["posterior", "changepoint"])
def test_contested_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames."""
    d = np.concatenate([repeated_route(0, n_ref=70), varying_route(1)])
    kwargs = dict(rule="contested", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)


def persistent_routes():
    """The routes above, and the routes of rule "gated" (rows alike for 7-13 frames, a change of
    scene, hard stretches, a strong line with a weak recent stretch)."""
    yield from routes()
    yield from gated_routes()


@pytest.mark.parametrize("k", range(11))
def test_persistent_rule_matches_slow_reference(k):
    d = list(persistent_routes())[k]
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="persistent", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _ = slow_contested(d, grid, VELOCITIES, persistent=True)
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_persistent_reference_exercises_the_midpoint_gate():
    """On these routes the gated midpoint test admits windows that rule "contested" rejects."""
    grid = window_grid(3, 24, 6)
    differ = 0
    for d in persistent_routes():
        a, _ = slow_contested(d, grid, VELOCITIES, persistent=True)
        b, _ = slow_contested(d, grid, VELOCITIES)
        differ += int(np.sum(a["length"] != b["length"]))
    assert differ > 0


@pytest.mark.parametrize("confidence", ["posterior", "changepoint"])
def test_persistent_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames (the clock and its
    latest break travel from block to block)."""
    d = np.concatenate([scene_route(1, 24, 2.5), scene_route(3, 16, 2.0)[:12]])
    kwargs = dict(rule="persistent", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)


@pytest.mark.parametrize("k", range(11))
def test_challenged_rule_matches_slow_reference(k):
    d = list(persistent_routes())[k]
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="challenged", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _ = slow_contested(d, grid, VELOCITIES, persistent=True, challenged=True)
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_challenged_reference_exercises_the_unproven_rival():
    """On these routes the rival beyond chance rejects windows that rule "persistent" admits."""
    grid = window_grid(3, 24, 6)
    differ = 0
    for d in persistent_routes():
        a, _ = slow_contested(d, grid, VELOCITIES, persistent=True, challenged=True)
        b, _ = slow_contested(d, grid, VELOCITIES, persistent=True)
        differ += int(np.sum(a["length"] != b["length"]))
    assert differ > 0


@pytest.mark.parametrize("confidence", ["posterior", "changepoint"])
def test_challenged_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames."""
    d = np.concatenate([repeated_route(0, n_ref=70), varying_route(1)])
    kwargs = dict(rule="challenged", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)
