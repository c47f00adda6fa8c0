"""Particles, log-weights and resampling (against filterpy and against N·w)."""

import numpy as np
import pytest
from filterpy.monte_carlo import resampling as fp

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.particles import (
    RESAMPLERS,
    ParticleSet,
    effective_sample_size,
    get_resampler,
    log_sum_exp,
    normalise_log_weights,
)


class _Replay:
    """Stand-in for ``numpy.random.random`` that returns prepared uniforms."""

    def __init__(self, values):
        self.values = list(values)

    def __call__(self, size=None):
        if size is None:
            return self.values.pop(0)
        out = np.array(self.values[:size])
        del self.values[:size]
        return out


@pytest.mark.parametrize("name,filterpy_fn,n_uniforms", [
    ("systematic", fp.systematic_resample, lambda n: 1),
    ("stratified", fp.stratified_resample, lambda n: n),
    ("multinomial", fp.multinomial_resample, lambda n: n),
])
def test_same_indices_as_filterpy_for_the_same_uniforms(monkeypatch, name, filterpy_fn, n_uniforms):
    rng = np.random.default_rng(3)
    for n in (1, 7, 500):
        w = rng.gamma(0.3, size=n)
        w /= w.sum()
        ours = RESAMPLERS[name](w, np.random.default_rng(11))
        uniforms = np.random.default_rng(11).random(n_uniforms(n))
        if n_uniforms(n) == 1:
            uniforms = [float(uniforms[0])]
        monkeypatch.setattr(fp, "random", _Replay(uniforms))
        np.testing.assert_array_equal(ours, filterpy_fn(w))


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_expected_counts_are_n_times_weight(name):
    rng = np.random.default_rng(0)
    n = 200
    w = rng.gamma(0.5, size=n)
    w /= w.sum()
    counts = np.zeros(n)
    trials = 400
    for _ in range(trials):
        idx = RESAMPLERS[name](w, rng)
        assert len(idx) == n and idx.min() >= 0 and idx.max() < n
        counts += np.bincount(idx, minlength=n)
    mean = counts / trials
    # the standard error of a multinomial count is sqrt(N w (1-w) / trials)
    se = np.sqrt(n * w * (1 - w) / trials) + 1e-9
    assert np.all(np.abs(mean - n * w) < 5 * se + 0.05)
    if name in ("systematic", "stratified", "residual"):
        # low-variance schemes: each count within one of N·w (systematic, residual floor)
        idx = RESAMPLERS[name](w, rng)
        c = np.bincount(idx, minlength=n)
        if name != "stratified":
            assert np.all(np.abs(c - n * w) < 1 + 1e-9) or name == "residual"
        if name == "residual":
            assert np.all(c >= np.floor(n * w))


def test_zero_weight_particles_are_never_drawn():
    w = np.array([0.0, 0.5, 0.0, 0.5, 0.0])
    for name, fn in RESAMPLERS.items():
        for seed in range(20):
            idx = fn(w, np.random.default_rng(seed))
            assert set(idx.tolist()) <= {1, 3}, name


def test_same_seed_same_indices():
    w = np.random.default_rng(0).random(100)
    for fn in RESAMPLERS.values():
        np.testing.assert_array_equal(fn(w, np.random.default_rng(4)), fn(w, np.random.default_rng(4)))


def test_log_weight_helpers_are_shift_invariant():
    lw = np.random.default_rng(2).normal(size=30) * 10
    for shift in (-1e3, 0.0, 750.0):
        np.testing.assert_allclose(normalise_log_weights(lw + shift), normalise_log_weights(lw), atol=1e-12)
        assert effective_sample_size(lw + shift) == pytest.approx(effective_sample_size(lw))
    assert log_sum_exp(np.array([np.log(2), np.log(3)])) == pytest.approx(np.log(5))
    np.testing.assert_allclose(np.exp(normalise_log_weights(np.full(4, -np.inf))), 0.25)
    assert effective_sample_size(np.zeros(10)) == pytest.approx(10)
    assert effective_sample_size(np.array([0.0, -np.inf, -np.inf])) == pytest.approx(1)


def test_particle_set_uniform_take_and_places():
    g = PlaceGraph.chain(10, bidirectional=False)
    rng = np.random.default_rng(0)
    p = ParticleSet.uniform(g, 1000, rng)
    assert len(p) == 1000
    assert np.all((p.edge >= 0) & (p.edge < g.n_edges))
    # the last place has no out-edge: it sits at the end of its in-edge
    at_end = p.fraction == 1.0
    assert np.all(g.target[p.edge[at_end]] == 9)
    places = p.places(g)
    assert set(np.unique(places)) == set(range(10))
    np.testing.assert_allclose(p.weights.sum(), 1)
    q = p.take(np.array([3, 3, 5]))
    assert len(q) == 3 and q.edge[0] == p.edge[3]
    np.testing.assert_allclose(np.exp(q.log_weight), 1 / 3)


def test_unknown_resampler_names_the_choices():
    with pytest.raises(InvalidParameterError, match="systematic"):
        get_resampler("bogus")
