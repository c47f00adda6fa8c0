"""Tests for the confidence "changepoint": the posterior of no jump off the chosen line over
the latest ``T`` frames, against a plain loop over frames and jump times.

The reference reads the batch matcher's own matches, scores and velocities (the choice of
the window is tested elsewhere), walks each frame's line back over its latest ``T`` frames
on the rows themselves, adds the log likelihood ratio of "on the line" against "a random
place" one frame at a time for every jump time, and forms the posterior of "no jump"; the
windows' agreeing gaps come from confidence "support" (the same sum, weighted by the
current frame's ``Phi(-z)``). The matcher must give the same confidences in the batch form,
in blocks shorter than ``T`` and step by step, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from catgraph import _window_rule, sequence
from catgraph._window_rule import CHANGE_POINT_FRAMES, JUMP_ODDS
from catgraph.sequence import SequenceMatcher, match_sequences
from tests.test_window_rule_predictive import assert_streaming_equals_batch
from tests.test_window_rule import on_grid
from tests.test_window_rule_spanning import VELOCITIES, varying_route


def position(v: float, i: int) -> int:
    return int(np.floor(v * i + 0.5))


def slow_changepoint(d: np.ndarray, match, score, velocity, frames: int = CHANGE_POINT_FRAMES) -> np.ndarray:
    """Per frame ``i``: ``1 / (1 + JUMP_ODDS * sum_t exp(-LLR_t))`` over the jump times
    ``t = 1 .. min(T, i + 1)``, ``LLR_t`` the sum over the latest ``t`` frames of
    ``(z^2 - (z - mu)^2) / 2`` at the line's places (nothing where the place is off the
    reference or the row is flat)."""
    n_q, n = d.shape
    out = np.empty(n_q)
    for i in range(n_q):
        spread_i = d[i].std()
        mu = (score[i] - d[i].mean()) / spread_i if spread_i > 0 else 0.0
        v = float(velocity[i])
        llr, odds_sum = 0.0, 0.0
        for t in range(1, min(frames, i + 1) + 1):
            k = i - (t - 1)  # the frame the jump time t adds
            place = int(match[i]) - (position(v, i) - position(v, k))
            spread = d[k].std()
            if 0 <= place < n and spread > 0:
                z = (d[k, place] - d[k].mean()) / spread
                llr += (z * z - (z - mu) ** 2) / 2.0
            odds_sum += JUMP_ODDS * np.exp(-llr)
        out[i] = 1.0 / (1.0 + odds_sum)
    return out


def route_with_jumps(seed: int, n_q: int = 56, n_ref: int = 70) -> np.ndarray:
    """White rows with a planted route: one place per frame, two per frame (a faster
    stretch), a jump to the reference's first place (so that the lines of the next frames
    reach off the reference), then driven backwards; a weaker echo of the first stretch
    elsewhere, and a flat row (no information)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    truth = np.empty(n_q, dtype=int)
    truth[:16] = 3 + np.arange(16)
    truth[16:30] = truth[15] + 2 * np.arange(1, 15)
    truth[30:44] = np.arange(14)
    truth[44:] = 60 - np.arange(n_q - 44)
    d[np.arange(n_q), truth] -= 3.0
    d[np.arange(16), 40 + np.arange(16)] -= 1.5
    d[20] = 0.0
    return on_grid(0.4 * d)


KW = dict(rule="spanning", l_min=3, l_max=24, grid=6, velocities=(1.0, 2.0, -1.0))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_changepoint_matches_slow_reference(seed):
    d = route_with_jumps(seed)
    cp = match_sequences(d, confidence="changepoint", **KW)
    support = match_sequences(d, confidence="support", **KW)
    np.testing.assert_array_equal(cp.match, support.match)
    z = np.array([(d[i, m] - d[i].mean()) / d[i].std() if d[i].std() > 0 else 0.0 for i, m in enumerate(cp.match)])
    gaps = support.confidence / ndtr(-z)
    expected = gaps * slow_changepoint(d, cp.match, cp.score, cp.velocity)
    np.testing.assert_allclose(cp.confidence, expected, rtol=1e-9, atol=1e-12)
    # the reference was exercised where it matters: lines off the reference and a flat row
    places = [cp.match[i] - (position(v, i) - position(v, i - 4)) for i, v in enumerate(cp.velocity) if i >= 4]
    assert min(places) < 0 or max(places) >= d.shape[1]


def test_changepoint_with_one_frame_is_posterior(monkeypatch):
    """``T = 1`` weighs the current frame alone: confidence "posterior"."""
    d = route_with_jumps(0)
    posterior = match_sequences(d, confidence="posterior", **KW)
    monkeypatch.setattr(_window_rule, "CHANGE_POINT_FRAMES", 1)
    one = match_sequences(d, confidence="changepoint", **KW)
    np.testing.assert_array_equal(one.match, posterior.match)
    np.testing.assert_allclose(one.confidence, posterior.confidence, rtol=1e-12, atol=1e-15)


def test_changepoint_lowers_the_frames_after_a_jump():
    """Right after the planted jump (frame 30) the line still held by the long windows is
    trusted less than with the current frame alone, at the same matches."""
    d = varying_route(0, n_q=56)
    cp = match_sequences(d, confidence="changepoint", **KW)
    posterior = match_sequences(d, confidence="posterior", **KW)
    ratio = cp.confidence / np.where(posterior.confidence > 0, posterior.confidence, np.inf)
    assert np.all(ratio <= 1.0 + 1e-12)  # more hypotheses of a jump, never fewer
    assert ratio[30:33].min() < 0.999 * ratio[10:16].max()


@pytest.mark.parametrize("rule", ["spanning", "punctuated", "gated", "unrivalled", "predictive",
                                  "decorrelated"])
def test_changepoint_streaming_equals_batch(rule, monkeypatch):
    """Same numbers step by step, in one batch, and in batches cut into blocks of 7 and of
    2 frames (fewer than ``T``: the latest rows travel from block to block)."""
    d = route_with_jumps(3)
    kwargs = dict(KW, rule=rule, confidence="changepoint")
    assert_streaming_equals_batch(d, kwargs, monkeypatch)
    whole = match_sequences(d, **kwargs)
    monkeypatch.setattr(sequence, "_BLOCK_VALUES", 2 * 3 * 6 * 6)
    tiny = match_sequences(d, **kwargs)
    np.testing.assert_array_equal(tiny.match, whole.match)
    np.testing.assert_array_equal(tiny.confidence, whole.confidence)


def test_changepoint_does_not_keep_the_callers_rows():
    """The streaming matcher copies the rows it keeps: a caller that reuses its buffer does
    not change later confidences."""
    d = route_with_jumps(1)
    kwargs = dict(KW, confidence="changepoint")
    matcher = SequenceMatcher(**kwargs)
    buffer = np.empty(d.shape[1])
    reused = []
    for row in d:
        buffer[:] = row
        reused.append(matcher.step(buffer).confidence)
    np.testing.assert_array_equal(reused, match_sequences(d, **kwargs).confidence)


def test_changepoint_fixed_window_is_the_gap():
    """With a fixed window the confidence is SeqSLAM's gap, as for "posterior"."""
    d = route_with_jumps(2)
    a = match_sequences(d, window=5, confidence="changepoint", velocities=VELOCITIES)
    b = match_sequences(d, window=5, confidence="gap", velocities=VELOCITIES)
    np.testing.assert_array_equal(a.confidence, b.confidence)
