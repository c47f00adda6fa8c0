"""The long-run velocity distribution a grid filter's jump lands with (catgraph.motion.LongRunVelocity)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catgraph.exceptions import InvalidParameterError
from catgraph.motion import LongRunVelocity


def _slow(prior, marginals, memory, prior_frames):
    """Reference: the weighted mean written out, frame k weighted 2^(−(K−1−k)/memory)."""
    K = len(marginals)
    w = np.array([0.5 ** ((K - 1 - k) / memory) for k in range(K)])
    total = sum(wk * m for wk, m in zip(w, marginals)) + prior_frames * prior
    return total / (w.sum() + prior_frames)


def _simplex(rng, n, k):
    x = rng.random((n, k))
    return x / x.sum(1, keepdims=True)


def test_matches_the_written_out_mean():
    rng = np.random.default_rng(0)
    prior = np.full(6, 1 / 6)
    marginals = _simplex(rng, 300, 6)
    v = LongRunVelocity(prior, memory=37.0, prior_frames=5.0)
    for k, m in enumerate(marginals):
        q = v.update(m)
        if k in (0, 1, 10, 299):
            np.testing.assert_allclose(q, _slow(prior, marginals[:k + 1], 37.0, 5.0), rtol=1e-12)


def test_prior_before_any_frame_and_follows_a_steady_query():
    prior = np.array([0.25, 0.25, 0.25, 0.25])
    v = LongRunVelocity(prior, memory=100.0, prior_frames=20.0)
    np.testing.assert_array_equal(v.distribution(), prior)
    steady = np.array([0.0, 0.0, 1.0, 0.0])
    for _ in range(2000):
        q = v.update(steady)
    # the discounted frames saturate at 1 / (1 − δ) ≈ 144.8: the prior keeps 20 / 164.8 of the mass
    delta = 0.5 ** (1 / 100)
    expected = (steady / (1 - delta) + 20 * prior) / (1 / (1 - delta) + 20)
    np.testing.assert_allclose(q, expected, rtol=1e-5)  # 2000 frames: 1 − 2^(−20) of saturation
    assert q[2] > 0.85


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 50), st.integers(2, 9), st.floats(1.0, 500.0), st.floats(0.0, 50.0), st.integers(0, 2 ** 31))
def test_a_distribution(frames, bins, memory, prior_frames, seed):
    rng = np.random.default_rng(seed)
    prior = _simplex(rng, 1, bins)[0]
    v = LongRunVelocity(prior, memory=memory, prior_frames=prior_frames)
    for m in _simplex(rng, frames, bins):
        q = v.update(m)
    assert np.all(q >= 0)
    assert q.sum() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("kw", [{"memory": 0.0}, {"memory": -1.0}, {"prior_frames": -1.0}, {"memory": True}])
def test_bad_parameters(kw):
    with pytest.raises(InvalidParameterError, match="LongRunVelocity"):
        LongRunVelocity(np.full(2, 0.5), **kw)
