"""Tests for the window rule "spanning": the tests of rule "unrivalled" with a rival and a
velocity re-choice that only lines spanning the query's decorrelation time may make,
against a plain loop over frames.

The reference below recomputes every window score of every velocity by a double loop over
the line's frames (a term off the reference is its row's mean), widens each length's spread
to the widest over the velocities, chooses the velocity by the significance summed over the
lengths, admits the windows whose recent sub-windows pass the midpoint, spread and rival
tests (a rival only from the frame's horizon on, the horizon from the plain loop of
``tests/test_window_rule_decorrelated.py``), takes the most significant admitted window, and
re-chooses the velocity at that length when the length spans the horizon. The matcher must
make the same choices (and give the same confidences) in the batch and the streaming form.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import log_ndtr

from catgraph._window_rule import EVIDENT_SPREADS, JUMP_ODDS, RIVAL_SPREADS, SPANNING_MARGIN
from catgraph.sequence import match_sequences, window_grid
from tests.test_window_rule import on_grid
from tests.test_sequence_velocity import slow_line_scores
from tests.test_window_rule_decorrelated import slow_horizons
from tests.test_window_rule_predictive import assert_streaming_equals_batch


def slow_spanning(d: np.ndarray, grid: np.ndarray, velocities, fraction: float = 0.05, radius: int = 10):
    """Per frame: match, effective window, velocity and confidence "posterior" of rule
    "spanning"; and the number of frames where the velocity was re-chosen and where a rival
    rejected a window (so that a test can check that both were exercised)."""
    n_q, n = d.shape
    horizons = slow_horizons(d)
    scores = {(int(L), v): slow_line_scores(d, int(L), v) for L in grid for v in velocities}
    out = {k: [] for k in ("match", "length", "velocity", "confidence")}
    rechosen = rivals = 0
    for i in range(n_q):
        rows = [[scores[int(L), v][i] for L in grid] for v in velocities]  # [v][g] -> (N,)
        spread = [max(rows[a][g].std() for a in range(len(velocities))) for g in range(len(grid))]
        best_j = [[int(np.argmin(r)) for r in rv] for rv in rows]
        log_p = [[float(log_ndtr((r.min() - r.mean()) / spread[g])) for g, r in enumerate(rv)] for rv in rows]

        def admitted(a):
            keep = []
            for g in range(len(grid)):
                ok = True
                for h in range(g):  # every shorter length
                    sub, own = rows[a][h][best_j[a][g]], rows[a][g][best_j[a][g]]
                    recent = grid[h] >= fraction * grid[g]
                    if recent and sub > 0.5 * (own + rows[a][h].mean()):
                        ok = False
                    if sub > rows[a][h].mean() - EVIDENT_SPREADS * spread[h]:
                        ok = False
                    if (recent and grid[h] >= horizons[i] and log_p[a][h] < -np.log(n) - SPANNING_MARGIN
                            and sub > rows[a][h].min() + RIVAL_SPREADS * spread[h]):
                        ok = False
                        nonlocal rivals
                        rivals += 1
                if ok or g == 0:
                    keep.append(g)
            return keep

        a0 = min(range(len(velocities)), key=lambda a: (sum(log_p[a]), a))
        g = min(admitted(a0), key=lambda k: (log_p[a0][k], k))
        a = a0
        if grid[g] >= horizons[i]:
            a = min(range(len(velocities)), key=lambda b: (log_p[b][g], b))
            rechosen += int(a != a0)
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
    return {k: np.array(v) for k, v in out.items()}, rechosen, rivals


def varying_route(seed: int, n_q: int = 44, n_ref: int = 70) -> np.ndarray:
    """White rows with a planted route: one place per frame, then two per frame (a faster
    stretch), then a jump to another part of the reference; a weaker echo of the first
    stretch elsewhere, so that long windows have a wrong line to choose."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    truth = np.empty(n_q, dtype=int)
    truth[:16] = 3 + np.arange(16)
    truth[16:30] = truth[15] + 2 * np.arange(1, 15)
    truth[30:] = 5 + np.arange(n_q - 30)
    d[np.arange(n_q), truth] -= 3.0
    d[np.arange(16), 40 + np.arange(16)] -= 1.5
    return on_grid(0.4 * d)  # below 4 everywhere: the matcher stores these values exactly


VELOCITIES = (1.0, 2.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_spanning_rule_matches_slow_reference(seed):
    d = varying_route(seed)
    grid = window_grid(3, 24, 6)
    result = match_sequences(d, "adaptive", rule="spanning", grid=6, l_min=3, l_max=24, velocities=VELOCITIES,
                             confidence="posterior")
    slow, _, _ = slow_spanning(d, grid, VELOCITIES)
    np.testing.assert_array_equal(result.match, slow["match"])
    np.testing.assert_array_equal(result.window_length, slow["length"])
    np.testing.assert_array_equal(result.velocity, slow["velocity"])
    np.testing.assert_allclose(result.confidence, slow["confidence"], rtol=1e-9, atol=1e-9)


def test_spanning_reference_exercises_both_tests():
    """On these routes the reference re-chooses the velocity on some frames and a rival
    rejects some windows, so the comparison above checks both."""
    rechosen = rivals = 0
    for seed in (0, 1, 2):
        _, r, k = slow_spanning(varying_route(seed), window_grid(3, 24, 6), VELOCITIES)
        rechosen, rivals = rechosen + r, rivals + k
    assert rechosen > 0
    assert rivals > 0


@pytest.mark.parametrize("confidence", ["posterior", "support", "gap"])
def test_spanning_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames (the horizon's
    state travels from block to block)."""
    d = varying_route(3, n_q=60)
    kwargs = dict(rule="spanning", l_min=3, l_max=30, grid=6, confidence=confidence, velocities=VELOCITIES)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)
