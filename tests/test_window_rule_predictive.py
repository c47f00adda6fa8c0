"""Tests for the window rule "predictive": each candidate length's line is judged by how well
it predicted later frames, against a plain loop over frames.

The reference below recomputes every window score by a double loop, follows each length's
best line ``PREDICTION_HORIZON`` frames ahead, reads the standardised difference of the
later frame there, keeps the discounted mean of those losses per length, and takes the
length with the best record (ties: the longer). The matcher must make the same choices in
the batch and the streaming form, and carry the record across the batch form's blocks.
"""

from __future__ import annotations

import numpy as np
import pytest

import catgraph.sequence as sequence
from catgraph._window_rule import PREDICTION_HALF_LIFE, PREDICTION_HORIZON
from catgraph.sequence import SequenceMatcher, match_sequences, window_grid
from tests.test_window_rule import V1, on_grid, planted, slow_scores


def slow_predictive(d: np.ndarray, grid: np.ndarray, horizons=None) -> tuple[np.ndarray, np.ndarray]:
    """Per frame (forward diagonal only): the match and the effective window of rule
    "predictive" (horizon ``PREDICTION_HORIZON``), or of its record at the per-frame
    ``horizons`` (rule "decorrelated")."""
    scores = {int(L): slow_scores(d, int(L)) for L in grid}
    n_q, n = d.shape
    decay = 2.0 ** (-1.0 / PREDICTION_HALF_LIFE)
    if horizons is None:
        horizons = np.full(n_q, PREDICTION_HORIZON)
    best = np.array([[int(np.argmin(scores[int(L)][i])) for L in grid] for i in range(n_q)])
    total, weight = np.zeros(len(grid)), 0.0
    match = np.empty(n_q, dtype=int)
    length = np.empty(n_q, dtype=int)
    for i in range(n_q):
        k = horizons[i]
        if i >= k:
            row = d[i]
            loss = np.zeros(len(grid))
            for g in range(len(grid)):
                place = best[i - k, g] + k  # the line one place further per frame
                if 0 <= place < n:
                    loss[g] = (row[place] - row.mean()) / row.std()
            total = decay * total + loss
            weight = decay * weight + 1.0
        if weight == 0.0:
            g = len(grid) - 1
        else:
            record = total / weight
            g = max(range(len(grid)), key=lambda h: (-record[h], h))  # best record, then the longer
        match[i] = best[i, g]
        length[i] = min(int(grid[g]), i + 1)
    return match, length


@pytest.mark.parametrize("seed, strength, echo", [(0, 1.2, 0.0), (1, 2.0, 1.2), (3, 3.0, 1.8), (4, 1.5, 0.5)])
def test_predictive_rule_matches_slow_reference(seed, strength, echo):
    d = planted(48, 40, seed, jump_at=24, strength=strength, echo=echo)
    grid = window_grid(3, 24, 7)
    result = match_sequences(d, "adaptive", rule="predictive", grid=7, l_min=3, l_max=24, velocities=V1)
    match, length = slow_predictive(d, grid)
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_array_equal(result.window_length, length)


def test_predictive_rule_is_not_trivial():
    """The record must choose different lengths on a route with a jump (else the comparison
    with the reference above would not test the choice)."""
    d = planted(48, 40, 3, jump_at=24, strength=3.0, echo=1.8)
    _, length = slow_predictive(d, window_grid(3, 24, 7))
    assert len(np.unique(length[PREDICTION_HORIZON + 24:])) > 1


def assert_streaming_equals_batch(d, kwargs, monkeypatch):
    """The batch run, the batch cut into blocks of 7 frames, and the streaming matcher
    (also after a reset) give the same matches, windows, velocities and confidences."""
    whole = match_sequences(d, **kwargs)
    monkeypatch.setattr(sequence, "_BLOCK_VALUES", 7 * 8 * 6 * 6)
    blocks = match_sequences(d, **kwargs)
    matcher = SequenceMatcher(**kwargs)
    steps = [matcher.step(row) for row in d]
    for batch in (whole, blocks):
        np.testing.assert_array_equal(batch.match, [s.match for s in steps])
        np.testing.assert_array_equal(batch.window_length, [s.window_length for s in steps])
        np.testing.assert_array_equal(batch.velocity, [s.velocity for s in steps])
        np.testing.assert_array_equal(batch.confidence, [s.confidence for s in steps])
    matcher.reset()
    again = [matcher.step(row) for row in d]
    np.testing.assert_array_equal([s.match for s in again], [s.match for s in steps])


@pytest.mark.parametrize("confidence", ["posterior", "gap", "support"])
def test_predictive_streaming_equals_batch(confidence, monkeypatch):
    """Same numbers step by step, and in a batch cut into blocks of 7 frames (the record
    travels from block to block)."""
    d = planted(60, 50, 4, jump_at=30, strength=2.5, echo=1.5)
    kwargs = dict(rule="predictive", l_min=3, l_max=30, grid=6, confidence=confidence)
    assert_streaming_equals_batch(d, kwargs, monkeypatch)


def test_predictive_rule_drops_the_old_alignment_after_a_jump(jump_route):
    """After a jump every long line predicts badly; the record turns to the short lines that
    re-lock, within the horizon and a few frames, where the literal rule holds on to the old
    alignment for dozens of frames."""
    d, truth = jump_route  # a jump at frame 100
    common = dict(window="adaptive", l_min=5, l_max=100, grid=16, velocities=V1)
    predictive = match_sequences(d, rule="predictive", **common)
    literal = match_sequences(d, rule="literal", **common)
    after = slice(100, 200)

    def first_correct(res):
        return int(np.flatnonzero(res.match[after] == truth[after])[0])

    assert first_correct(predictive) <= PREDICTION_HORIZON + 5 < first_correct(literal)
    assert np.mean(predictive.match[after] == truth[after]) >= 0.75
    assert np.mean(predictive.match[:100] == truth[:100]) >= 0.9


def test_predictive_rule_keeps_the_longest_window_on_a_straight_route():
    """Where every length finds the same line its predictions tie exactly: the longest wins."""
    rng = np.random.default_rng(2)
    d = rng.normal(size=(120, 200))
    truth = np.arange(120) + 30
    d[np.arange(120), truth] -= 4.0
    res = match_sequences(on_grid(d), rule="predictive", l_min=5, l_max=60, grid=6, velocities=V1)
    assert np.all(res.match[60:] == truth[60:])
    assert np.all(res.window_length[60:] == 60)
