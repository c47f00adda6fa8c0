"""Tests for catgraph.sequence: compiled kernels against slow, obviously-correct loops."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import log_ndtr, logsumexp, ndtr

from catgraph.exceptions import InvalidParameterError, ShapeMismatchError
from catgraph.sequence import (
    APPROXIMATIONS,
    SequenceMatcher,
    fixed_window_scores,
    match_sequences,
    window_grid,
)

# ------------------------------------------------------------------ slow references

V1 = (1.0,)  # the classic diagonal only: the slow references below score it


def on_grid(d: np.ndarray) -> np.ndarray:
    """``d`` rounded to multiples of 2**-8, each row's last value nudged so that the row's
    mean is one too: values the matcher stores exactly (integer multiples of its quantum
    ``u = 2**(e - 12) <= 2**-8`` while the first row lies below ``2**4`` in magnitude), so
    its scores equal the float64 loops below to rounding. The rounding of other input is
    tested against its bound in test_sequence_velocity.py."""
    q = np.rint(np.asarray(d, dtype=np.float64) * 256.0)
    q[:, -1] -= np.mod(q.sum(axis=1), q.shape[1])
    assert np.abs(q[0]).max() < 16 * 256
    return q / 256.0


def slow_scores(d: np.ndarray, length: int) -> np.ndarray:
    """s_ij(L) by a double loop. Edge policy: ``min(L, i + 1)`` terms; a term before
    the reference's start is its query row's mean difference."""
    n_q, n = d.shape
    out = np.empty((n_q, n))
    for i in range(n_q):
        eff = min(length, i + 1)
        for j in range(n):
            terms = [d[i - k, j - k] if j - k >= 0 else d[i - k].mean() for k in range(eff)]
            out[i, j] = sum(terms) / eff
    return out


def slow_em(x: np.ndarray, k: int, n_iter: int = 10, start=None):
    """Textbook EM for a 1-D mixture, started like the kernel (numpy, no tricks)."""
    mean, std = (x.mean(), x.std()) if start is None else start
    w = np.full(k, 1.0 / k)
    mu = mean + std * np.linspace(-1.0, 1.0, k) if k > 1 else np.array([mean])
    sd = np.full(k, std)
    for _ in range(n_iter):
        logr = np.log(w)[:, None] - np.log(sd)[:, None] - 0.5 * ((x[None, :] - mu[:, None]) / sd[:, None]) ** 2
        r = np.exp(logr - logr.max(axis=0))
        r /= r.sum(axis=0)
        nk = r.sum(axis=1)
        mu = (r * x).sum(axis=1) / nk
        var = (r * (x[None, :] - mu[:, None]) ** 2).sum(axis=1) / nk
        sd = np.sqrt(np.maximum(var, 1e-6 * std**2))
        w = nk / x.size
        w /= w.sum()
    return w, mu, sd


def slow_log_p(s: np.ndarray, approximation: str) -> float:
    best = s.min()
    if approximation == "gaussian":
        return float(log_ndtr((best - s.mean()) / s.std()))
    if approximation == "robust":
        med = np.median(s)
        return float(log_ndtr((best - med) / (1.4826 * np.median(np.abs(s - med)))))
    w, mu, sd = slow_em(s, {"gmm2": 2, "gmm3": 3}[approximation])
    return float(logsumexp(np.log(w) + log_ndtr((best - mu) / sd)))


def slow_literal(d: np.ndarray, grid: np.ndarray, approximation: str):
    """Literal adaptive rule: argmin_L p_i(L); returns match, effective L, log p curves."""
    n_q = d.shape[0]
    scores = {int(L): slow_scores(d, int(L)) for L in grid}
    match = np.empty(n_q, dtype=int)
    length = np.empty(n_q, dtype=int)
    curves = np.empty((n_q, len(grid)))
    for i in range(n_q):
        for g, L in enumerate(grid):
            curves[i, g] = slow_log_p(scores[int(L)][i], approximation)
        g = int(np.argmin(curves[i]))
        match[i] = int(np.argmin(scores[int(grid[g])][i]))
        length[i] = min(int(grid[g]), i + 1)
    return match, length, curves


def planted(n_q=120, n_ref=150, seed=0):
    """Normalised-looking differences with a planted diagonal (query i ~ reference i + 20)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    for i in range(n_q):
        if i + 20 < n_ref:
            d[i, i + 20] -= 2.5
    return on_grid(d)


# ------------------------------------------------------------------ fixed windows


@pytest.mark.parametrize("length", [1, 3, 7, 40])
def test_fixed_window_scores_match_double_loop(length):
    d = on_grid(np.random.default_rng(length).normal(size=(25, 31)))
    np.testing.assert_allclose(fixed_window_scores(d, length), slow_scores(d, length), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("length", [1, 5, 12])
def test_fixed_window_batch_matches_reference(length):
    d = on_grid(np.random.default_rng(1).normal(size=(40, 60)))
    result = match_sequences(d, window=length, velocities=V1)
    expected = slow_scores(d, length)
    np.testing.assert_array_equal(result.match, expected.argmin(axis=1))
    np.testing.assert_allclose(result.score, expected.min(axis=1), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(result.window_length, np.minimum(length, np.arange(40) + 1))


def test_fixed_window_recovers_planted_diagonal():
    d = planted()
    result = match_sequences(d, window=10, velocities=V1)
    assert np.mean(result.match[10:] == np.arange(10, 120) + 20) > 0.95


def test_fixed_window_gap_confidence_matches_definition():
    d = on_grid(np.random.default_rng(2).normal(size=(30, 80)))
    result = match_sequences(d, window=4, radius=3, confidence="gap", velocities=V1)
    s = slow_scores(d, 4)
    for i in range(30):
        j = int(np.argmin(s[i]))
        far = np.abs(np.arange(80) - j) > 3
        assert result.confidence[i] == pytest.approx((s[i][far].min() - s[i, j]) / s[i].std(), rel=1e-9)


@pytest.mark.parametrize("v", [1.0, -2.0, 0.5])
def test_best_and_second_across_blocks_match_the_scores(v):
    """Best place (the first of exact ties) and gap over several blocks of the block
    minima, with the excluded radius straddling a block boundary, against the scores."""
    from catgraph import _sequence_kernels as k

    n = 3 * k.BLOCK + 50
    rng = np.random.default_rng(4)
    d = on_grid(rng.normal(size=(25, n)))
    edge = k.BLOCK  # plant a strong line that ends at the first block boundary
    for i in range(25):
        j = edge - (int(np.floor(v * 24 + 0.5)) - int(np.floor(v * i + 0.5)))
        if 0 <= j < n:
            d[i, j] -= 3.0
    d = on_grid(d)
    result = match_sequences(d, window=6, radius=5, confidence="gap", velocities=(v,))
    s = fixed_window_scores(d, 6, v)
    for i in range(25):
        j = int(np.argmin(s[i]))
        assert result.match[i] == j
        far = np.abs(np.arange(n) - j) > 5
        assert result.confidence[i] == pytest.approx((s[i][far].min() - s[i, j]) / s[i].std(), rel=1e-9)
    assert result.match[-1] == edge


def test_support_confidence_sums_the_agreeing_windows_gaps():
    # literal rule: every window is admitted, so support = sum of the gaps of the lengths
    # whose own best place lies within the radius of the match
    d = planted(50, 60, seed=5)
    grid = [2, 4, 8, 16]
    result = match_sequences(d, window="adaptive", rule="literal", grid=grid, radius=3, velocities=V1,
                             confidence="support")
    gaps, best = [], []
    for length in grid:
        s = slow_scores(d, length)
        j = np.argmin(s, axis=1)
        far = np.abs(np.arange(60)[None, :] - j[:, None]) > 3
        second = np.where(far, s, np.inf).min(axis=1)
        gaps.append((second - s[np.arange(50), j]) / s.std(axis=1))
        best.append(j)
    gaps, best = np.array(gaps), np.array(best)
    expected = np.where(np.abs(best - result.match[None, :]) <= 3, gaps, 0.0).sum(axis=0)
    rows = np.arange(50)
    current = (d[rows, result.match] - d.mean(axis=1)) / d.std(axis=1)
    expected = expected * ndtr(-current)
    np.testing.assert_allclose(result.confidence, expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("confidence", ["support", "posterior"])
def test_adaptive_confidences_are_the_gap_for_a_fixed_window(confidence):
    """A fixed window keeps SeqSLAM's confidence, whatever the adaptive default."""
    d = np.random.default_rng(6).normal(size=(40, 70))
    adaptive_kind = match_sequences(d, window=5, confidence=confidence)
    gap = match_sequences(d, window=5, confidence="gap")
    np.testing.assert_array_equal(adaptive_kind.match, gap.match)
    np.testing.assert_array_equal(adaptive_kind.confidence, gap.confidence)


def test_support_confidence_falls_when_the_current_frame_leaves_the_line():
    # a clean diagonal, then one frame whose difference at the continued line is poor:
    # the match may still follow the line, but its confidence must drop
    d = planted(60, 80, seed=7)
    clean = match_sequences(d, window="adaptive", l_min=3, l_max=30, grid=6, velocities=V1)
    broken = d.copy()
    j = clean.match[-1]
    broken[-1, j] = broken[-1].max()
    out = match_sequences(broken, window="adaptive", l_min=3, l_max=30, grid=6, velocities=V1)
    assert out.confidence[-1] < 0.1 * clean.confidence[-1]


# ------------------------------------------------------------------ streaming = batch


@pytest.mark.parametrize("window", [6, "adaptive"])
@pytest.mark.parametrize("approximation", APPROXIMATIONS)
@pytest.mark.parametrize("rule", ["literal", "consistent", "sustained"])
def test_streaming_equals_batch_exactly(window, approximation, rule):
    d = planted(60, 70, seed=3)
    kwargs = dict(window=window, approximation=approximation, rule=rule, l_min=3, l_max=30, grid=8)
    batch = match_sequences(d, return_curves=True, **kwargs)
    matcher = SequenceMatcher(**kwargs)
    steps = [matcher.step(row, return_curve=True) for row in d]
    np.testing.assert_array_equal(batch.match, [s.match for s in steps])
    np.testing.assert_array_equal(batch.score, [s.score for s in steps])
    np.testing.assert_array_equal(batch.confidence, [s.confidence for s in steps])
    np.testing.assert_array_equal(batch.window_length, [s.window_length for s in steps])
    np.testing.assert_array_equal(batch.log_p, np.array([s.log_p for s in steps]))
    assert matcher.n_steps_ == 60


def test_streaming_memory_is_one_int16_ring_and_int32_running_sums():
    matcher = SequenceMatcher(window="adaptive", l_min=2, l_max=9, grid="all")
    for row in np.random.default_rng(0).normal(size=(40, 13)):
        matcher.step(row)
    # one ring of l_max + 1 rows of int16 codes shared by every velocity, one int32 sum
    # per line, velocity and candidate length: 2 (l_max + 1) + 4 V G bytes per place
    assert matcher._ring.shape == (10, 13) and matcher._ring.dtype == np.int16
    assert matcher._mring.dtype == np.int16
    assert matcher._sums.shape == (len(matcher.velocities_), 8, 13) and matcher._sums.dtype == np.int32
    # windows so long that int32 could overflow keep int64 sums
    from catgraph import _sequence_kernels as k

    assert k.sums_dtype(65_538) == np.int32 and k.sums_dtype(65_539) == np.int64


def test_windows_beyond_the_int32_range_keep_int64_sums():
    """A window so long that int32 sums could overflow runs on int64 sums with the same
    results: while fewer frames than either window have been seen, both use them all."""
    d = np.random.default_rng(6).normal(size=(15, 7))
    long = SequenceMatcher(window=70_000, velocities=(1.0, -2.0))
    steps = [long.step(row) for row in d]
    assert long._sums.dtype == np.int64
    short = match_sequences(d, window=20, velocities=(1.0, -2.0))
    np.testing.assert_array_equal(short.match, [s.match for s in steps])
    np.testing.assert_array_equal(short.score, [s.score for s in steps])
    np.testing.assert_array_equal(short.confidence, [s.confidence for s in steps])


def test_streaming_reset_and_shape_check():
    matcher = SequenceMatcher(window=3)
    matcher.step(np.zeros(5))
    with pytest.raises(ShapeMismatchError, match="reset"):
        matcher.step(np.zeros(6))
    matcher.reset()
    assert matcher.step(np.arange(6.0)).match == 0


# ------------------------------------------------------------------ adaptive


@pytest.mark.parametrize("approximation", APPROXIMATIONS)
def test_literal_adaptive_matches_slow_reference(approximation):
    d = planted(45, 50, seed=4)
    grid = window_grid(3, 20, 6)
    result = match_sequences(d, "adaptive", approximation, rule="literal", l_min=3, l_max=20, grid=6, velocities=V1,
                             return_curves=True)
    match, length, curves = slow_literal(d, grid, approximation)
    np.testing.assert_allclose(result.log_p, curves, rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_array_equal(result.window_length, length)


def slow_rule(d: np.ndarray, grid: np.ndarray, rule: str, fraction: float = 0.125):
    """Gaussian adaptive choice by the consistent or sustained rule, from double-loop scores."""
    scores = {int(L): slow_scores(d, int(L)) for L in grid}
    match = np.empty(d.shape[0], dtype=int)
    for i in range(d.shape[0]):
        best_j = [int(np.argmin(scores[int(L)][i])) for L in grid]
        log_p = np.array([slow_log_p(scores[int(L)][i], "gaussian") for L in grid])
        admissible = np.ones(len(grid), dtype=bool)
        for g, L in enumerate(grid):
            own = scores[int(L)][i, best_j[g]]
            for h, length in enumerate(grid):
                if fraction * L <= length < L:
                    row = scores[int(length)][i]
                    if row[best_j[g]] > 0.5 * (own + row.mean()):
                        admissible[g] = False
        admissible[0] = True
        best = min(log_p[g] for g in range(len(grid)) if admissible[g])
        if rule == "consistent":
            g = next(g for g in range(len(grid)) if admissible[g] and log_p[g] == best)
        else:  # sustained: the longest admitted window with log p <= half the best
            g = max(g for g in range(len(grid)) if admissible[g] and log_p[g] <= 0.5 * best)
        match[i] = best_j[g]
    return match


@pytest.mark.parametrize("rule", ["consistent", "sustained"])
def test_consistent_and_sustained_rules_match_slow_reference(rule):
    d = planted(45, 50, seed=7)
    grid = window_grid(3, 24, 8)
    result = match_sequences(d, "adaptive", rule=rule, l_min=3, l_max=24, grid=8, velocities=V1, recent_fraction=0.125)
    np.testing.assert_array_equal(result.match, slow_rule(d, grid, rule))


def test_every_integer_grid():
    np.testing.assert_array_equal(window_grid(10, 15, "all"), np.arange(10, 16))
    g = window_grid(10, 500)
    assert g[0] == 10 and g[-1] == 500 and np.all(np.diff(g) > 0)


def test_consistent_rule_shortens_window_after_a_jump(jump_route):
    """After a jump to another part of the route the default rule drops the old alignment
    sooner than the literal rule does."""
    d, truth = jump_route  # a jump at frame 100
    common = dict(window="adaptive", l_min=5, l_max=100, grid=16, velocities=V1)
    literal = match_sequences(d, rule="literal", **common)
    after = slice(100, 200)

    def first_correct(res):
        return int(np.flatnonzero(res.match[after] == truth[after])[0])

    for rule in ("consistent", "sustained"):
        tested = match_sequences(d, rule=rule, **common)
        assert first_correct(tested) < first_correct(literal)
        assert np.mean(tested.match[after] == truth[after]) >= np.mean(literal.match[after] == truth[after])


def test_log_p_is_finite_for_very_strong_matches():
    d = np.random.default_rng(6).normal(size=(60, 80))
    d[np.arange(60), np.arange(60)] = -40.0
    result = match_sequences(d, "adaptive", l_min=5, l_max=50, return_curves=True)
    assert np.all(np.isfinite(result.log_p))
    assert result.log_p.min() < -40  # p below 1e-17, kept in log space


def test_constant_rows_do_not_produce_nan():
    d = np.zeros((20, 30))
    for approximation in APPROXIMATIONS:
        result = match_sequences(d, "adaptive", approximation, l_min=2, l_max=10, return_curves=True)
        assert np.all(np.isfinite(result.confidence)) and not np.any(np.isnan(result.log_p))


# ------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    "kwargs, text",
    [
        (dict(window=0), "'window'"),
        (dict(window="long"), "'window'"),
        (dict(approximation="gmm4"), "'approximation'"),
        (dict(rule="best"), "'rule'"),
        (dict(l_min=20, l_max=10), "'l_max'"),
        (dict(confidence="ratio"), "'confidence'"),
    ],
)
def test_bad_parameters_raise_typed_errors(kwargs, text):
    with pytest.raises(InvalidParameterError, match=text):
        match_sequences(np.zeros((3, 4)), **kwargs)


def test_blocked_batch_equals_single_block(monkeypatch):
    import catgraph.sequence as sequence

    d = planted(50, 60, seed=7)
    kwargs = dict(window="adaptive", l_min=3, l_max=25, grid=7, return_curves=True)
    whole = match_sequences(d, **kwargs)
    monkeypatch.setattr(sequence, "_BLOCK_VALUES", 7 * 7 * 3)  # blocks of 3 rows
    blocked = match_sequences(d, **kwargs)
    np.testing.assert_array_equal(whole.match, blocked.match)
    np.testing.assert_array_equal(whole.log_p, blocked.log_p)


def test_mixture_fit_uses_a_strided_subsample_for_large_references():
    """Above EM_MAX_POINTS scores the mixture is fitted to every stride-th score."""
    d = on_grid(np.random.default_rng(8).normal(size=(4, 2500)))
    result = match_sequences(d, window=3, approximation="gmm2", return_curves=True, velocities=V1)
    s = slow_scores(d[:, :], 3)[3 - 1]
    stride = 3  # ceil(2500 / 1024)
    w, mu, sd = slow_em(s[::stride], 2, start=(s.mean(), s.std()))
    expected = logsumexp(np.log(w) + log_ndtr((s.min() - mu) / sd))
    assert result.log_p[2, 0] == pytest.approx(expected, rel=1e-7)


def test_public_window_scores_equal_fixed_window_scores():
    from catgraph.exceptions import NotFittedError
    from catgraph.sequence import SequenceMatcher, fixed_window_scores

    rng = np.random.default_rng(5)
    d = rng.normal(size=(30, 40))
    m = SequenceMatcher(window="adaptive", l_min=2, l_max=16, velocities=V1)
    with pytest.raises(NotFittedError):
        m.window_scores(4)
    for row in d:
        m.step(row)
    for length in (1, 4, 16):
        np.testing.assert_allclose(m.window_scores(length), fixed_window_scores(d, length)[-1], atol=1e-12)
    with pytest.raises(ValueError, match="length"):
        m.window_scores(17)


@pytest.mark.parametrize("n", [150, 4500])
def test_block_minima_and_moments_of_the_fused_update_equal_numpy(n):
    """The fused update's moments and block minima (integer minima of the sums) against
    numpy on the sums it leaves, for every velocity kind, with negative values, zeros
    and blocks cut by the slot wrap, the entering lines and (n = 4500) the chunks of
    the update, on int32 and int64 sums."""
    from catgraph import _sequence_kernels as k

    assert 4500 > 2 * k.CHUNK
    rng = np.random.default_rng(3)
    length = 4
    d = rng.normal(size=(12, n))
    d[5, :40] = 0.0
    d[6, 40:80] = -0.0
    for v, dtype in ((1.0, np.int32), (0.5, np.int64), (-2.0, np.int32), (3.0, np.int32)):
        ring = np.zeros((length + 1, n), dtype=np.int16)
        mring = np.zeros(length + 1, dtype=np.int16)
        state = np.zeros(1)
        sums = np.zeros(n, dtype=dtype)
        bmin = np.empty((n + k.BLOCK - 1) // k.BLOCK, dtype=np.int64)
        for i in range(d.shape[0]):
            k.advance(ring, mring, state, i, d[i])
            shift = int(rng.integers(-5000, 5000))
            a, q = k._update_stats(sums, ring, mring, i, v, length, shift, bmin)
            sbase = k.position(v, i) % n
            in_place = np.roll(sums, sbase).astype(np.int64)  # place j sits in slot (j - sbase) mod n
            eff = min(length, i + 1)
            np.testing.assert_array_equal(in_place * state[0] / eff, k.fixed_scores(d[: i + 1], length, v)[i])
            expected = [in_place[b:b + k.BLOCK].min() for b in range(0, n, k.BLOCK)]
            np.testing.assert_array_equal(bmin, expected)
            y = in_place - shift
            assert a == float(y.sum())  # integers: exact in float64 at this size
            assert q == pytest.approx((y.astype(np.float64) ** 2).sum(), rel=1e-12)


def test_segment_minimum_of_integer_sums():
    from catgraph import _sequence_kernels as k

    rng = np.random.default_rng(5)
    for dtype in (np.int32, np.int64):
        info = np.iinfo(np.int32)
        x = np.array([35, 0, -1, info.min + 1, info.max - 1, -7, 7, -7, 2], dtype=dtype)
        for lo in range(len(x)):
            for hi in range(lo + 1, len(x) + 1):
                bmin = np.full(1, 1 << 62, dtype=np.int64)
                k._segment_min(x[lo:hi].copy(), 0, bmin)
                assert bmin[0] == x[lo:hi].min()
        # blocks: a segment starting inside a block folds into the existing minima
        b = k.BLOCK
        seg = rng.integers(-1000, 1000, size=3 * b + 7).astype(dtype)
        bmin = np.array([-5000, 1 << 62, 1 << 62, 1 << 62, 1 << 62], dtype=np.int64)
        k._segment_min(seg, 10, bmin)
        full = np.concatenate([np.full(10, 1 << 40), seg.astype(np.int64)])
        expected = [-5000] + [full[lo:lo + b].min() for lo in range(b, full.size, b)] + [1 << 62]
        np.testing.assert_array_equal(bmin, expected)
        bmin[:] = 1 << 62
        k._segment_min(seg, 10, bmin)
        assert bmin[0] == seg[:b - 10].min()
    bmin = np.full(1, 1 << 62, dtype=np.int64)
    k._segment_min(np.empty(0, dtype=np.int32), 0, bmin)
    assert bmin[0] == 1 << 62
