"""Tests for catgraph.likelihood: histogram model, online samples, recogniser."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catgraph.exceptions import DataError, InvalidParameterError, NotFittedError, ShapeMismatchError
from catgraph.likelihood import (
    HistogramLikelihood,
    HistogramPlaceRecogniser,
    labelled_samples,
    online_samples,
    reference_samples,
)
from catgraph.traverse import FrameTolerance

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


# ---------------------------------------------------------------- slow references
def reference_log_tables(d_same, d_diff, edges, eps, prior=None):
    """Obviously-correct per-bin log P(b|L), log P(b|¬L), log P(b), by explicit loops."""
    s = len(edges) - 1

    def which(v):
        for b in range(s):
            if v < edges[b + 1]:
                return max(b, 0) if v >= edges[b] or b == 0 else b
        return s - 1

    def probs(values):
        counts = [0] * s
        for v in values:
            counts[which(v)] += 1
        n = len(values)
        return [1.0 / s if n == 0 else (1 - eps) * c / n + eps / s for c in counts]

    ps, pd = probs(list(d_same)), probs(list(d_diff))
    p_l = len(d_same) / (len(d_same) + len(d_diff)) if prior is None else prior
    pm = [a * p_l + b * (1 - p_l) for a, b in zip(ps, pd)]
    return np.log(ps), np.log(pd), np.log(pm), which


def test_hand_computed_fixed_range_with_empty_bins():
    # 4 bins over [0, 4): same = {0.5, 0.7} (bin 0), different = {2.5, 3.5, 3.6} (bins 2, 3, 3)
    eps = 0.2
    m = HistogramLikelihood(n_bins=4, range=(0.0, 4.0), smoothing=eps).fit([0.5, 0.7], [2.5, 3.5, 3.6])
    np.testing.assert_array_equal(m.counts_same_, [2, 0, 0, 0])
    np.testing.assert_array_equal(m.counts_different_, [0, 0, 1, 2])
    np.testing.assert_allclose(m.bin_edges_, [0, 1, 2, 3, 4])
    assert m.prior_same_ == pytest.approx(2 / 5)
    # bin 0: P(b|L) = 0.8 * 1 + 0.05 = 0.85 ; P(b|¬L) = 0.05 ; P(b) = 0.4*0.85 + 0.6*0.05
    assert m.log_prob_same(0.1) == pytest.approx(math.log(0.85))
    assert m.log_prob_different(0.1) == pytest.approx(math.log(0.05))
    assert m.log_likelihood_ratio(0.1) == pytest.approx(math.log(0.85 / (0.4 * 0.85 + 0.6 * 0.05)))
    # bin 1 is empty in both: no evidence either way
    assert m.log_likelihood_ratio(1.5) == pytest.approx(0.0, abs=1e-12)
    # bin 3: P(b|¬L) = 0.8 * 2/3 + 0.05
    p_d = 0.8 * 2 / 3 + 0.05
    assert m.log_likelihood_ratio(3.9) == pytest.approx(math.log(0.05 / (0.4 * 0.05 + 0.6 * p_d)))
    assert m.prob_same_given(0.1) == pytest.approx(0.4 * 0.85 / (0.4 * 0.85 + 0.6 * 0.05))
    # densities divide by the bin width 1 here; with width 0.5 they double
    m2 = HistogramLikelihood(n_bins=4, range=(0.0, 2.0), smoothing=eps).fit([0.1], [1.9])
    assert m2.log_prob_same(0.1) == pytest.approx(math.log((0.8 + 0.05) / 0.5))


def test_against_slow_reference_fixed_range():
    rng = np.random.default_rng(1)
    same, diff = rng.normal(1, 0.5, 40), rng.normal(3, 1, 300)
    edges = np.linspace(0.0, 5.0, 11)
    m = HistogramLikelihood(n_bins=10, range=(0.0, 5.0), smoothing=0.05, monotone=False).fit(same, diff)
    ls, ld, lm, which = reference_log_tables(same, diff, edges, 0.05)
    query = rng.uniform(-2, 7, 50)
    # evaluation clips into the range of the samples seen
    both = np.concatenate([same, diff])
    b = np.array([which(v) for v in np.clip(query, both.min(), both.max())])
    np.testing.assert_allclose(m.log_likelihood_ratio(query), ls[b] - lm[b])
    np.testing.assert_allclose(m.log_prob(query), lm[b] - np.log(0.5))


def slow_monotone(f, g):
    """Brute force: the non-increasing ratio fit by repeatedly merging the first violating pair of blocks."""
    blocks = [[b] for b in range(len(f))]
    ratio = lambda blk: sum(f[b] for b in blk) / sum(g[b] for b in blk)  # noqa: E731
    changed = True
    while changed:
        changed = False
        for k in range(len(blocks) - 1):
            if ratio(blocks[k]) < ratio(blocks[k + 1]):
                blocks[k:k + 2] = [blocks[k] + blocks[k + 1]]
                changed = True
                break
    fs, gs = np.empty(len(f)), np.empty(len(f))
    for blk in blocks:
        r = ratio(blk)
        for b in blk:
            m = f[b] + g[b]
            fs[b], gs[b] = m * r / (1 + r), m / (1 + r)
    return fs, gs


def test_monotone_ratio_against_slow_reference():
    rng = np.random.default_rng(3)
    same, diff = rng.normal(1, 0.7, 60), rng.normal(2.5, 1, 200)
    plain = HistogramLikelihood(n_bins=12, range=(-1.0, 5.0), monotone=False).fit(same, diff)
    mono = HistogramLikelihood(n_bins=12, range=(-1.0, 5.0)).fit(same, diff)
    ls, ld, _, _ = plain._log_tables()
    f, g = slow_monotone(np.exp(ls), np.exp(ld))
    ms, md, _, _ = mono._log_tables()
    np.testing.assert_allclose(np.exp(ms), f, rtol=1e-10)
    np.testing.assert_allclose(np.exp(md), g, rtol=1e-10)
    assert np.all(np.diff(ms - md) <= 1e-12)  # non-increasing ratio
    assert np.exp(ms).sum() == pytest.approx(1.0) and np.exp(md).sum() == pytest.approx(1.0)
    assert np.any(np.diff(ls - ld) > 0)  # the plain histograms did violate it
    # the hand-computed example already has a non-increasing ratio: unchanged
    a = HistogramLikelihood(n_bins=4, range=(0.0, 4.0), smoothing=0.2).fit([0.5, 0.7], [2.5, 3.5, 3.6])
    b = HistogramLikelihood(n_bins=4, range=(0.0, 4.0), smoothing=0.2, monotone=False).fit([0.5, 0.7], [2.5, 3.5, 3.6])
    np.testing.assert_allclose(a._log_tables()[0], b._log_tables()[0])


def test_out_of_range_values_are_clipped_into_edge_bins():
    m = HistogramLikelihood(n_bins=5, range=(0.0, 1.0)).fit([-10.0, 0.1], [5.0, 0.95, np.float64(1e300)])
    np.testing.assert_array_equal(m.counts_same_, [2, 0, 0, 0, 0])
    np.testing.assert_array_equal(m.counts_different_, [0, 0, 0, 0, 3])
    assert m.log_likelihood_ratio(-1e9) == m.log_likelihood_ratio(0.0)
    assert m.log_likelihood_ratio(1e9) == m.log_likelihood_ratio(0.99)


def test_adaptive_range_grows_and_keeps_all_data():
    m = HistogramLikelihood(n_bins=8).partial_fit([0.1, 0.2], [0.3])
    first = m.bin_edges_.copy()
    assert first[0] <= 0.1 and first[-1] > 0.3
    m.partial_fit(None, [100.0, -50.0])
    assert m.bin_edges_[0] <= -50.0 and m.bin_edges_[-1] > 100.0
    assert m.counts_same_.sum() == 2 and m.counts_different_.sum() == 3
    widths = np.diff(m.bin_edges_)
    assert np.allclose(widths, widths[0]) and math.log2(widths[0]).is_integer()


def test_constant_input_no_nan():
    m = HistogramLikelihood().fit(np.full(50, 3.7), np.full(20, 3.7))
    values = [m.log_likelihood_ratio(v) for v in (3.7, -1e6, 1e6)]
    assert np.all(np.isfinite(values))
    assert np.isfinite(m.new_place_log_likelihood())
    lp, ln = m.log_posterior(np.full(10, 3.7), new_place_prior=0.1)
    assert m.prior_same_ == pytest.approx(50 / 70)
    assert np.all(np.isfinite(lp)) and np.isfinite(ln)
    np.testing.assert_allclose(np.exp(lp), 0.09)  # all places equal; new place keeps its prior
    # a single class only, all-identical
    m1 = HistogramLikelihood(range=(0.0, 1.0)).fit([], np.zeros(5))
    assert np.isfinite(m1.log_likelihood_ratio(0.0))


def chunks_strategy():
    values = st.lists(st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False), min_size=0, max_size=40)
    return st.tuples(values, values, st.integers(1, 5), st.integers(2, 30))


@settings(max_examples=60, deadline=None)
@given(chunks_strategy())
def test_partial_fit_in_chunks_equals_one_fit(args):
    same, diff, n_chunks, n_bins = args
    full = HistogramLikelihood(n_bins=n_bins).fit(same, diff)
    part = HistogramLikelihood(n_bins=n_bins)
    cs, cd = np.array_split(np.asarray(same), n_chunks), np.array_split(np.asarray(diff), n_chunks)
    for a, b in zip(cs, cd):
        part.partial_fit(a, b)
    np.testing.assert_array_equal(full.counts_same_, part.counts_same_)
    np.testing.assert_array_equal(full.counts_different_, part.counts_different_)
    np.testing.assert_array_equal(full.bin_edges_, part.bin_edges_)
    q = np.linspace(-1100, 1100, 17)
    np.testing.assert_array_equal(full.log_likelihood_ratio(q), part.log_likelihood_ratio(q))


def test_partial_fit_chunks_fixed_range():
    rng = np.random.default_rng(3)
    same, diff = rng.normal(0, 1, 100), rng.normal(2, 2, 1000)
    full = HistogramLikelihood(range=(-1.0, 4.0)).fit(same, diff)
    part = HistogramLikelihood(range=(-1.0, 4.0))
    for i in range(10):
        part.partial_fit(same[i * 10 : (i + 1) * 10], diff[i * 100 : (i + 1) * 100])
    np.testing.assert_array_equal(full.counts_same_, part.counts_same_)
    np.testing.assert_array_equal(full.counts_different_, part.counts_different_)


def test_adaptive_bins_match_slow_reference():
    rng = np.random.default_rng(2)
    same, diff = rng.normal(-3, 1, 200), rng.normal(0, 1, 2000)
    m = HistogramLikelihood(n_bins=50, smoothing=0.02, monotone=False).fit(same, diff)
    ls, ld, lm, which = reference_log_tables(same, diff, m.bin_edges_, 0.02)
    inside = rng.uniform(m.bin_edges_[0], m.bin_edges_[-1], 100)
    both = np.concatenate([same, diff])
    b = np.array([which(v) for v in np.clip(inside, both.min(), both.max())])
    np.testing.assert_allclose(m.log_likelihood_ratio(inside), ls[b] - lm[b])
    np.testing.assert_array_equal(m.counts_same_, np.histogram(same, m.bin_edges_)[0])


def test_vectorised_over_any_shape():
    m = HistogramLikelihood().fit([0.0, 0.1], [1.0, 2.0])
    d = np.random.default_rng(0).uniform(-1, 3, (2, 3, 4))
    out = m.log_likelihood_ratio(d)
    assert out.shape == d.shape
    np.testing.assert_array_equal(out.ravel(), [m.log_likelihood_ratio(v) for v in d.ravel()])
    assert isinstance(m.log_likelihood_ratio(0.5), float)


def test_prior_same_and_ratio_bound():
    m = HistogramLikelihood(prior_same=0.01).fit(np.zeros(10), np.ones(1000))
    assert m.prior_same_ == 0.01
    assert m.log_likelihood_ratio(0.0) <= -math.log(0.01) + 1e-12
    assert m.log_likelihood_ratio(0.0) > 4.0


def test_new_place_likelihood_exact_and_sampled():
    rng = np.random.default_rng(5)
    m = HistogramLikelihood(n_bins=20).fit(rng.normal(-2, 1, 300), rng.normal(1, 1, 3000))
    exact = m.new_place_log_likelihood()
    ls, ld, lm, _ = m._log_tables()
    assert exact == pytest.approx(math.log(np.sum(np.exp(ld) * np.exp(ls - lm))))
    sampled = m.new_place_log_likelihood(n_samples=20000, rng=0)
    assert sampled == pytest.approx(exact, abs=0.05)
    assert m.new_place_log_likelihood(n_samples=50, rng=1) == m.new_place_log_likelihood(n_samples=50, rng=1)


def test_log_posterior_eq2():
    m = HistogramLikelihood(n_bins=10, range=(0.0, 10.0), prior_same=0.1).fit([0.5, 1.5], [5.5, 6.5, 7.5, 8.5])
    d = np.array([0.5, 5.5, 9.5])
    prior = np.log([0.2, 0.5, 0.3])
    lp, ln = m.log_posterior(d, log_prior=prior)
    w = np.exp(m.log_likelihood_ratio(d)) * np.exp(prior)
    np.testing.assert_allclose(np.exp(lp), w / w.sum())
    assert ln == -np.inf
    lp2, ln2 = m.log_posterior(d, log_prior=prior, new_place_prior=0.2)
    wn = 0.2 * np.exp(m.new_place_log_likelihood())
    total = 0.8 * w.sum() + wn
    np.testing.assert_allclose(np.exp(lp2), 0.8 * w / total)
    assert math.exp(ln2) == pytest.approx(wn / total)
    # batched rows
    lpb, lnb = m.log_posterior(np.stack([d, d[::-1]]), new_place_prior=0.2)
    assert lpb.shape == (2, 3) and lnb.shape == (2,)
    np.testing.assert_allclose(np.exp(lpb).sum(1) + np.exp(lnb), 1.0)


def test_errors():
    with pytest.raises(NotFittedError, match="fit"):
        HistogramLikelihood().log_likelihood_ratio(0.0)
    with pytest.raises(InvalidParameterError, match="The 'n_bins' parameter of HistogramLikelihood must be an int"):
        HistogramLikelihood(n_bins=1).fit([0.0], [1.0])
    with pytest.raises(InvalidParameterError, match="'smoothing'"):
        HistogramLikelihood(smoothing=0.0).fit([0.0], [1.0])
    with pytest.raises(InvalidParameterError, match="'range'"):
        HistogramLikelihood(range=(1.0, 0.0)).fit([0.0], [1.0])
    with pytest.raises(InvalidParameterError, match="'prior_same'"):
        HistogramLikelihood(prior_same=1.0).fit([0.0], [1.0])
    with pytest.raises(DataError, match="NaN"):
        HistogramLikelihood().fit([np.nan], [1.0])
    m = HistogramLikelihood().fit([0.0], [1.0])
    with pytest.raises(ShapeMismatchError):
        m.log_posterior([0.0, 1.0], log_prior=[0.0])


def test_constructor_only_stores_params():
    m = HistogramLikelihood(n_bins=-3, smoothing="bad")
    assert m.n_bins == -3 and not hasattr(m, "counts_same_")
    assert "n_bins=-3" in repr(m)


# ---------------------------------------------------------------- online samples
def test_online_samples_excludes_neighbourhood():
    d = np.array([5.0, 4.0, 1.0, 0.5, 0.9, 3.0, 2.0, 6.0])
    s = online_samples(d, exclusion_radius=1)
    assert (s.best, s.d_min, s.d_other) == (3, 0.5, 2.0)
    s0 = online_samples(d, exclusion_radius=0)
    assert s0.d_other == 0.9
    assert math.isnan(online_samples(d[:3], exclusion_radius=5).d_other)


# ---------------------------------------------------------------- recogniser
def synthetic_differences(n_query=300, n_ref=200, seed=0, unseen=()):
    """Rows: N(0,1) noise, the true place (query i ↔ reference i mod n_ref) 5 lower."""
    rng = np.random.default_rng(seed)
    d = rng.normal(0.0, 1.0, (n_query, n_ref))
    truth = np.arange(n_query) % n_ref
    for i in range(n_query):
        if i not in unseen:
            d[i, truth[i]] -= 5.0
    return d, truth


def test_recogniser_online_follows_the_paper():
    d, truth = synthetic_differences()
    rec = HistogramPlaceRecogniser(n_init=50, exclusion_radius=2, n_random_different=0)
    out = rec.run(d)
    assert out.initialising[:50].all() and not out.initialising[50:].any()
    assert np.all(out.confidence[:50] == 0)
    model = rec.model_
    # initialisation: one ¬L sample per frame; afterwards one L and one ¬L per frame
    assert model.n_same_ == 250 and model.n_different_ == 300
    assert (model.counts_same_ > 0).any()
    good = out.match[50:] == truth[50:]
    # right matches are given far more confidence than wrong ones
    conf = out.confidence[50:]
    assert conf[good].mean() > 2 * conf[~good].mean()
    assert good[conf >= np.quantile(conf, 0.5)].mean() > 0.98
    assert np.all((out.confidence >= 0) & (out.confidence <= 1))
    assert np.all((out.new_place_probability >= 0) & (out.new_place_probability <= 1))


def test_recogniser_step_equals_run_and_update_matches():
    d, _ = synthetic_differences(60, 40)
    a = HistogramPlaceRecogniser(n_init=10).run(d)
    rec = HistogramPlaceRecogniser(n_init=10)
    steps = [rec.step(row) for row in d]
    np.testing.assert_array_equal(a.confidence, [s.confidence for s in steps])
    # update() alone learns the same histograms as step()
    learner = HistogramPlaceRecogniser(n_init=10)
    for row in d:
        learner.update(row)
    np.testing.assert_array_equal(learner.model_.counts_same_, rec.model_.counts_same_)
    np.testing.assert_array_equal(learner.model_.counts_different_, rec.model_.counts_different_)


def test_recogniser_new_place_probability_higher_for_unseen_places():
    unseen = set(range(200, 260))
    d, _ = synthetic_differences(300, 200, seed=1, unseen=unseen)
    out = HistogramPlaceRecogniser(n_init=50).run(d)
    idx = np.arange(300)
    seen = (idx >= 50) & ~np.isin(idx, list(unseen))
    unseen = list(unseen)
    assert out.new_place_probability[unseen].mean() > 2 * out.new_place_probability[seen].mean()
    assert out.confidence[unseen].mean() < 0.5 * out.confidence[seen].mean()


def test_recogniser_trained_and_bootstrap_modes():
    d, truth = synthetic_differences(200, 200, seed=2)
    gt = FrameTolerance(200, tolerance=0)
    d_same, d_diff = labelled_samples(d, gt, max_different=5000, seed=0)
    assert d_same.size == 200 and d_diff.size == 5000
    trained = HistogramLikelihood().fit(d_same, d_diff)
    fixed = HistogramPlaceRecogniser(trained, n_init=0, learn=False)
    out = fixed.run(d)
    assert not out.initialising.any()
    np.testing.assert_array_equal(fixed.model_.counts_same_, trained.counts_same_)  # not modified
    assert (out.match == truth)[out.confidence > 0.9].mean() > 0.95
    # bootstrap: ¬L from reference pairs far apart
    r = np.random.default_rng(4).normal(0, 1, (200, 200))
    s, nd = reference_samples(r, gap=10, max_different=3000, seed=0)
    assert s.size == 0 and nd.size == 3000
    s2, _ = reference_samples(r, gap=10, max_different=10, same_radius=2)
    assert s2.size == 2 * (199 + 198)
    boot = HistogramPlaceRecogniser(HistogramLikelihood().fit(s, nd), n_init=0)
    out_b = boot.run(d)
    assert out_b.confidence[0] > 0 and boot.model_.n_same_ == 200
    assert boot.model_.prior_same == pytest.approx(1 / 200)  # "per-place" default
    model_prior = HistogramPlaceRecogniser(HistogramLikelihood(prior_same=0.3).fit(s, nd), n_init=0, prior_same="model")
    model_prior.step(d[0])
    assert model_prior.model_.prior_same_ == 0.3


def test_reference_samples_respect_gap():
    n = 30
    r = np.abs(np.subtract.outer(np.arange(n), np.arange(n))).astype(float)  # d = |j − j'|
    _, nd = reference_samples(r, gap=7, max_different=2000, seed=1)
    assert nd.min() > 7 and nd.max() <= n - 1
    # all offsets are used, more often the short ones (more pairs)
    counts = np.bincount(nd.astype(int), minlength=n)
    assert counts[8] > counts[n - 1] > 0


def test_recogniser_errors():
    with pytest.raises(InvalidParameterError, match="n_init"):
        HistogramPlaceRecogniser(n_init=-1).step(np.zeros(5))
    with pytest.raises(InvalidParameterError, match="learn=False"):
        HistogramPlaceRecogniser(learn=False).step(np.zeros(5))
    with pytest.raises(NotFittedError):
        HistogramPlaceRecogniser(n_init=0, learn=False).step(np.zeros(5))
    with pytest.raises(InvalidParameterError, match="prior_same"):
        HistogramPlaceRecogniser(prior_same="often").step(np.zeros(5))
    rec = HistogramPlaceRecogniser(n_init=1)
    rec.step(np.zeros(5))
    with pytest.raises(ShapeMismatchError):
        rec.step(np.zeros(6))
    with pytest.raises(DataError):
        rec.step(np.array([0.0, np.inf]))


def test_recogniser_random_different_samples_and_positions():
    d, truth = synthetic_differences(120, 60, seed=5)
    rec = HistogramPlaceRecogniser(n_init=20, exclusion_radius=2, n_random_different=3, random_state=1)
    rec.run(d)
    assert rec.model_.n_same_ == 100 and rec.model_.n_different_ == 20 + 100 * 4
    again = HistogramPlaceRecogniser(n_init=20, exclusion_radius=2, n_random_different=3, random_state=1)
    again.run(d)
    np.testing.assert_array_equal(rec.model_.counts_different_, again.model_.counts_different_)  # seeded
    # a route that comes back: place j and place 59 - j share a position
    x = np.minimum(np.arange(60), 59 - np.arange(60)).astype(float)
    positions = np.column_stack([x, np.zeros(60)])
    rec_p = HistogramPlaceRecogniser(n_init=0, reference_positions=positions, confidence_distance=0.5)
    rec_i = HistogramPlaceRecogniser(n_init=0, confidence_radius=0)
    row = np.full(60, 3.0)
    row[[10, 49]] = -2.0  # the same position seen twice: both visits are near the match
    for r in (rec_p, rec_i):
        for k in range(30):
            r.update(d[k])
    assert rec_p.step(row).confidence > 1.5 * rec_i.step(row).confidence
    with pytest.raises(InvalidParameterError, match="confidence_distance"):
        HistogramPlaceRecogniser(reference_positions=positions).step(row)
    # bootstrap pairs closer than min_distance are never ¬L
    r = np.abs(np.subtract.outer(x, x))
    _, nd = reference_samples(r, gap=2, max_different=300, seed=0, reference_positions=positions, min_distance=3.0)
    assert nd.size == 300 and nd.min() > 3.0


# ---------------------------------------------------------------------- split modules, map samples
def test_likelihood_names_still_importable_from_one_place():
    import catgraph.histogram
    import catgraph.recogniser
    import catgraph.samples
    from catgraph import likelihood

    assert likelihood.HistogramLikelihood is catgraph.histogram.HistogramLikelihood
    assert likelihood.HistogramPlaceRecogniser is catgraph.recogniser.HistogramPlaceRecogniser
    assert likelihood.reference_samples is catgraph.samples.reference_samples
    for name in likelihood.__all__:
        assert hasattr(likelihood, name)


# ---------------------------------------------------------------------- tempered whole-image model
def test_predictive_scores_kernel_matches_numpy():
    from catgraph._grid_kernels import predictive_scores

    rng = np.random.default_rng(2)
    b = rng.standard_normal(50)
    prior = rng.random(50)
    prior /= prior.sum()
    taus = np.array([0.1, 0.5, 2.0])
    want = [np.log(np.sum(prior * np.exp(t * b))) - np.log(np.mean(np.exp(t * b))) for t in taus]
    np.testing.assert_allclose(predictive_scores(b, np.log(prior), taus), want, rtol=1e-10)


def test_tempered_hub_correction_only_where_the_map_has_hubs():
    from catgraph.observation import TemperedObservation

    rng = np.random.default_rng(3)
    level = rng.uniform(-0.5, 0.5, 500)
    m = TemperedObservation(hub=level, temperature=1.0)
    r = m.observe(rng.standard_normal(500)).log_ratio
    assert m.n_hubs_ == 0 and m.hub_shrinkage_ == 0.0
    level[:20] = -5.0  # 4 % hubs
    m = TemperedObservation(hub=level, temperature=1.0)
    row = rng.standard_normal(500)
    r = m.observe(row).log_ratio
    assert m.n_hubs_ == 20 and m.hub_shrinkage_ == 1.0
    np.testing.assert_allclose(r, -(row - (level - level.mean())))


def test_tempered_temperature_follows_agreement():
    from catgraph.observation import FilterFeedback, TemperedObservation

    rng = np.random.default_rng(4)
    n = 100
    agree, disagree = TemperedObservation(hub=None), TemperedObservation(hub=None)
    for k in range(50):
        row = rng.standard_normal(n)
        best = int(np.argmin(row))
        for model, place in ((agree, best), (disagree, (best + 50) % n)):
            model.observe(row)
            post = np.full(n, 1e-4)
            post[place] = 1.0
            model.feedback(FilterFeedback(np.full(n, 1 / n), post / post.sum(), slice(place, place + 1)))
    assert agree.temperature_ > 2.5 > 0.5 > disagree.temperature_
    assert agree.agreement_ == pytest.approx(agree.temperature_ / agree.temperature_scale)


def test_tempered_validates_and_resets():
    from catgraph.observation import TemperedObservation

    with pytest.raises(InvalidParameterError, match="likelihood"):
        TemperedObservation(likelihood="nope").observe(np.zeros(5))
    with pytest.raises(InvalidParameterError, match="temperature"):
        TemperedObservation(temperature=-1.0).observe(np.zeros(5))
    with pytest.raises(ShapeMismatchError):
        TemperedObservation(hub=np.zeros(4)).observe(np.zeros(5))
    m = TemperedObservation()
    m.observe(np.arange(5.0))
    with pytest.raises(ShapeMismatchError):
        m.observe(np.zeros(6))
    m.reset()
    m.observe(np.zeros(6))


def test_tempered_histogram_learns_from_the_filter():
    from catgraph.observation import FilterFeedback, TemperedObservation

    rng = np.random.default_rng(5)
    n = 200
    m = TemperedObservation(likelihood="histogram", hub=None, temperature=1.0, prior_strength=1.0)
    for k in range(60):
        row = rng.standard_normal(n)
        row[k] -= 3.0  # the true place is clearly lower
        m.observe(row)
        post = np.zeros(n)
        post[k] = 1.0
        m.feedback(FilterFeedback(np.full(n, 1 / n), post, slice(k, k + 1)))
    row = np.linspace(-4, 2, n)
    r = m.observe(row).log_ratio
    assert np.all(np.diff(r) <= 1e-12)  # non-increasing in d
    assert r[0] - r[-1] > 3.0


def test_tempered_repeated_frame_adds_no_evidence():
    from catgraph.observation import TemperedObservation

    rng = np.random.default_rng(6)
    m = TemperedObservation(hub=None, temperature=1.0)
    rows = rng.standard_normal((3, 50))
    first = m.observe(rows[0]).log_ratio
    np.testing.assert_allclose(first, -rows[0])  # the first frame: novelty 1
    m.observe(rows[1])
    again = m.observe(rows[1]).log_ratio  # the same frame twice
    assert m.novelty_ == 0.0 and np.all(again == 0.0)
    m.reset()
    np.testing.assert_allclose(m.observe(rows[1]).log_ratio, -rows[1])  # reset forgets the previous row
    off = TemperedObservation(hub=None, temperature=1.0, novelty=False)
    off.observe(rows[1])
    np.testing.assert_allclose(off.observe(rows[1]).log_ratio, -rows[1])


def test_sequence_observation_window_temperature_counts_each_frame_once():
    from catgraph.observation import SequenceObservation

    rows = np.random.default_rng(3).standard_normal((40, 30))
    plain = SequenceObservation(window=8, n_init=5)
    once = SequenceObservation(window=8, n_init=5, temperature="window")
    for row in rows:
        a, b = plain.observe(row), once.observe(row)
        assert a.informative == b.informative
        if a.informative:
            length = once.last_match_.window_length
            np.testing.assert_allclose(b.log_ratio, a.log_ratio / length, rtol=1e-12, atol=1e-15)
            assert b.new_place_log_ratio == pytest.approx(a.new_place_log_ratio / length)
    with pytest.raises(InvalidParameterError):
        SequenceObservation(temperature="hot").observe(rows[0])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from([-2.0, -0.0, 0.0, 0.5, 1e-300, 3.0, -1e300, 7.25]), min_size=1, max_size=40),
       st.integers(0, 2**31))
def test_median_from_one_selection_is_numpys_float(values, seed):
    from catgraph.observation import _median

    x = np.array(values) + np.random.default_rng(seed).integers(0, 2, len(values)) * 0.1
    work = np.empty(len(x))
    got = _median(x, work)
    assert got == float(np.median(x)) and math.copysign(1, got) == math.copysign(1, float(np.median(x)))
    np.copyto(work, x)
    assert _median(work, work) == float(np.median(x))  # in place, the values already in the work array


class _SlowTempered:
    """The linear tempered model's per-frame formulas, written plainly (a fresh array
    for every intermediate, ``np.median`` for the hub statistic, the previous row kept)."""

    def __init__(self, threshold=3.0, cap=2.0, memory=200.0, scale=4.0):
        self.threshold, self.cap, self.decay, self.scale = threshold, cap, 0.5 ** (1 / memory), scale
        self.hub_sum, self.count, self.prev = None, 0, None
        self.rho_sum = self.rho_n = self.hits = self.trials = 0.0
        self.tau = scale * 0.5

    def observe(self, row):
        h = None
        if self.count > 1:
            level = self.hub_sum / self.count
            med = float(np.median(level))
            mad = 1.4826 * float(np.median(np.abs(level - med)))
            hubs = int(np.count_nonzero(level < med - self.threshold * mad))
            h = min(1.0, hubs / (0.01 * len(level))) * (level - level.mean())
        self.base = -row if h is None else -(row - 1.0 * h)
        nu = 1.0
        if self.prev is None:
            self.prev = row.astype(np.float64, copy=True)
        else:
            a, b = row - row.mean(), self.prev - self.prev.mean()
            den = float(np.sqrt((a * a).sum() * (b * b).sum()))
            rho = float((a * b).sum()) / den if den > 0 else 1.0
            self.prev[...] = row
            if 1.0 - rho > 1e-9:  # an exact repeat stays out of the mean
                self.rho_sum = self.decay * self.rho_sum + rho
                self.rho_n = self.decay * self.rho_n + 1.0
            mean = self.rho_sum / self.rho_n if self.rho_n > 0 else rho
            nu = float(np.clip((1.0 - rho) / max(1.0 - mean, 1e-6), 0.0, self.cap))
        r = self.tau * nu * self.base
        top = float(r.max())
        self.row = row
        return r, top + math.log(float(np.mean(np.exp(r - top))))

    def feedback(self, posterior):
        best = int(np.argmax(self.base))
        hit = float(posterior[best]) / float(posterior.max())
        self.hits = self.decay * self.hits + hit
        self.trials = self.decay * self.trials + 1.0
        self.tau = self.scale * (self.hits + 1.0) / (self.trials + 2.0)
        self.hub_sum = self.row.copy() if self.hub_sum is None else self.hub_sum + self.row
        self.count += 1


def step_both_tempered(fast, slow, row, rng, k):
    """One frame through the fast tempered model and its plain-formula twin, with the same
    random posterior fed back to both; their log-ratios must be the same floats."""
    from catgraph.observation import FilterFeedback

    n = len(row)
    obs = fast.observe(row)
    r, new = slow.observe(row)
    assert np.array_equal(obs.log_ratio, r) and obs.new_place_log_ratio == new, k
    post = rng.random(n)
    post /= post.sum()
    fast.feedback(FilterFeedback(np.full(n, 1 / n), post, slice(0, 3)))
    slow.feedback(post)


@pytest.mark.parametrize("strided", [False, True])
def test_tempered_is_bit_identical_to_the_plain_formulas(strided):
    from catgraph.observation import TemperedObservation

    rng = np.random.default_rng(11)
    n = 301  # odd: the median is one middle value; the MAD's too
    fast, slow = TemperedObservation(), _SlowTempered()
    hubs = np.zeros(n)
    hubs[:12] = -3.0  # a run of hub references (4 %): the correction is on
    for k in range(30):
        wide = rng.standard_normal((n, 2)) + hubs[:, None]
        wide[k % 7] = wide[(k + 1) % 7]  # repeated values, ties in the selections
        row = wide[:, 0] if strided else np.ascontiguousarray(wide[:, 0])
        step_both_tempered(fast, slow, row, rng, k)
        assert fast.temperature_ == slow.tau
    assert fast.n_hubs_ >= 12 and fast.hub_shrinkage_ == 1.0


def test_recent_support_reads_only_what_is_asked_with_the_same_floats():
    from scipy.special import log_ndtr

    from catgraph.observation import RecentSupport

    s = np.random.default_rng(12).standard_normal(1000) * 3.0
    s[5] = s.mean()
    z = (s.mean() - s) / s.std()
    want = -log_ndtr(-z)
    near = slice(3, 9)
    mask = np.zeros(1000, dtype=bool)
    mask[[0, 500, 999]] = True
    assert np.array_equal(RecentSupport(s.copy())[near], want[near])
    assert np.array_equal(RecentSupport(s.copy())[mask], want[mask])
    support = RecentSupport(s.copy())
    assert np.array_equal(np.asarray(support), want) and np.array_equal(support.copy(), want)
    assert np.array_equal(support[near], want[near]) and len(support) == 1000 and support.shape == (1000,)
    flat = RecentSupport(np.full(10, 2.0))  # no spread: every place as likely as any
    assert np.array_equal(flat[2:4], -log_ndtr(np.zeros(2))) and np.array_equal(np.asarray(flat), -log_ndtr(np.zeros(10)))


def test_combined_sum_without_reliability_is_the_parts_sum_in_a_fresh_array():
    from catgraph.observation import CombinedObservation, Observation

    class Fixed:
        def __init__(self, r, new, support=None):
            self.r, self.new, self.support = r, new, support

        def reset(self):
            pass

        def observe(self, row):
            return Observation(self.r, self.new, True, self.support)

    rng = np.random.default_rng(13)
    a, b = rng.standard_normal(50), rng.standard_normal(50)
    sa, sb = rng.random(50), rng.random(50)
    obs = CombinedObservation([Fixed(a, 0.5, sa), Fixed(b, -0.25, sb)], reliability=None).observe(np.zeros(50))
    assert np.array_equal(obs.log_ratio, a + b) and obs.new_place_log_ratio == 0.25
    assert np.array_equal(obs.support, np.maximum(sa, sb))
    weighted = CombinedObservation([Fixed(a, 0.5), Fixed(b, 1.0)], weights=[2.0, 0.5], reliability=None)
    obs = weighted.observe(np.zeros(50))
    assert np.array_equal(obs.log_ratio, 2.0 * (1.0 * a) + 0.5 * (1.0 * b)) and obs.new_place_log_ratio == 1.5
    one = CombinedObservation([Fixed(a, 0.5)], reliability=None).observe(np.zeros(50))
    assert np.array_equal(one.log_ratio, a) and one.log_ratio is not a  # the part's own array is never handed on
    online = CombinedObservation([Fixed(a, 0.5), Fixed(b, 1.0)])
    obs = online.observe(np.zeros(50))
    assert np.array_equal(obs.log_ratio, 0.5 * a + 0.5 * b)
    assert online._best == [int(np.argmax(a)), int(np.argmax(b))]


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 3000), st.integers(0, 2**31), st.sampled_from([1e-3, 1.0, 1e6]))
def test_standardised_scores_are_numpys_floats(n, seed, scale):
    from catgraph.observation import _standardised

    rng = np.random.default_rng(seed)
    s = rng.standard_normal(n) * scale + rng.integers(-5, 5)
    if n > 3:
        s[: n // 3] = s[0]  # ties
    sd = s.std()
    want = (s - s.mean()) / sd if sd > 0 else np.zeros_like(s)
    got = _standardised(s, np.empty(n), np.empty(n))
    assert np.array_equal(got, want)
    assert np.array_equal(_standardised(np.full(n, 2.5), np.empty(n), np.empty(n)), np.zeros(n))


def test_recent_support_as_an_array_is_numpys_array_protocol():
    from catgraph.observation import RecentSupport

    support = RecentSupport(np.arange(6.0))
    full = np.asarray(support)
    assert np.asarray(support) is full  # computed once
    copied = np.array(support, copy=True)
    assert copied is not full and np.array_equal(copied, full)
    assert np.asarray(support, dtype=np.float32).dtype == np.float32


def test_fitting_again_learns_the_new_data_not_the_tables_of_the_last_fit():
    """Same sample sizes and range, other data: the cached tables of the first fit were
    reused (the log-ratios kept their sign)."""
    from catgraph.histogram import HistogramLikelihood

    for kwargs in ({"n_bins": 10, "range": (0.0, 1.0), "monotone": False}, {"n_bins": 10}):
        m = HistogramLikelihood(**kwargs).fit([0.05, 0.1], [0.9, 0.95])
        m.log_likelihood_ratio(0.5)  # fills the cache
        m.fit([0.9, 0.95], [0.05, 0.1])
        fresh = HistogramLikelihood(**kwargs).fit([0.9, 0.95], [0.05, 0.1])
        np.testing.assert_array_equal(m.log_likelihood_ratio([0.05, 0.5, 0.95]),
                                      fresh.log_likelihood_ratio([0.05, 0.5, 0.95]))


def test_histogram_observation_is_paper_2s_scheme_with_no_random_samples_and_seeds_them_otherwise():
    from catgraph.observation import HistogramObservation

    rows = np.random.default_rng(3).uniform(0.0, 1.0, (12, 30))

    def learned(**kwargs):
        obs = HistogramObservation(n_init=2, **kwargs)
        for row in rows:
            obs.observe(row)
        return obs.recogniser_

    paper = learned(n_random_different=0)
    # paper 2: after T_init, one L sample (d_min) and one ¬L sample per frame; T_init frames add d_min to ¬L
    assert (paper.model_.n_same_, paper.model_.n_different_) == (10, 12)
    more = learned()
    assert (more.model_.n_same_, more.model_.n_different_) == (10, 12 + 5 * 10)
    np.testing.assert_array_equal(learned(seed=0).model_.counts_different_, more.model_.counts_different_)
    assert not np.array_equal(learned(seed=999).model_.counts_different_, more.model_.counts_different_)
    np.testing.assert_array_equal(learned(n_random_different=0, seed=999).model_.counts_different_,
                                  paper.model_.counts_different_)


def test_fixed_range_bins_are_read_by_their_edges():
    from catgraph.histogram import HistogramLikelihood

    for n_bins, lo, hi in ((3, 0.0, 0.3), (10, 0.0, 1.0), (7, -0.35, 0.9), (100, 0.0, 0.1)):
        m = HistogramLikelihood(n_bins=n_bins, range=(lo, hi)).fit([], [lo])
        edges = m.bin_edges_
        np.testing.assert_array_equal(m._bin_index(edges[:-1]), np.arange(n_bins))   # each edge opens its bin
        np.testing.assert_array_equal(m._bin_index(np.nextafter(edges[1:], -np.inf)), np.arange(n_bins))
        assert m._bin_index(np.array([lo - 1.0, hi, hi + 1.0])).tolist() == [0, n_bins - 1, n_bins - 1]


def test_one_default_bootstrap_gap_for_the_registry_the_live_map_and_the_api():
    from catgraph import methods
    from catgraph.samples import default_bootstrap_gap

    for n in (3, 4, 10, 60, 249, 250, 251, 3576, 100_000):
        registry = methods._bootstrap_gap({"gap": None}, n)
        assert registry == default_bootstrap_gap(n) == max(1, min(50, n // 5, n - 2))
    # the API's bootstrap without a gap is the registry's model
    from catgraph.observation import HistogramObservation

    rng = np.random.default_rng(2)
    r = rng.uniform(0, 1, (120, 120))
    a = HistogramObservation.bootstrap(r, max_different=500, seed=1).likelihood
    b = HistogramObservation.bootstrap(r, gap=methods._bootstrap_gap({"gap": None}, 120), max_different=500,
                                       seed=1).likelihood
    np.testing.assert_array_equal(a.counts_different_, b.counts_different_)
