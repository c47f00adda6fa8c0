"""Velocity search in catgraph.sequence: lines of slope v, against slow loops."""

from __future__ import annotations

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.sequence import DEFAULT_VELOCITIES, SequenceMatcher, fixed_window_scores, match_sequences


def on_grid(d: np.ndarray) -> np.ndarray:
    """Values the matcher stores exactly (see test_sequence.on_grid)."""
    q = np.rint(np.asarray(d, dtype=np.float64) * 256.0)
    q[:, -1] -= np.mod(q.sum(axis=1), q.shape[1])
    assert np.abs(q[0]).max() < 16 * 256
    return q / 256.0


def stored_values(d: np.ndarray):
    """The documented storage: integer codes ``rint(d / u)`` of the quantum
    ``u = 2**(e - 12)`` (``max|d_0j| < 2**e``), saturated at ±32767; each row's mean
    code rounded to an integer. Returns the stored values ``code * u``, the fills
    ``mean code * u`` and ``u``."""
    _, e = np.frexp(np.abs(d[0]).max())
    u = 2.0 ** (int(e) - 12)
    codes = np.clip(np.rint(d / u), -32767, 32767)
    return codes * u, np.rint(codes.mean(axis=1)) * u, u


def slow_line_scores(d: np.ndarray, length: int, v: float) -> np.ndarray:
    """s_ij(L, v) by a triple loop: the line through (i, j) visits place
    j - (pos(i) - pos(i - t)) at frame i - t, pos(i) = floor(v i + 1/2); min(L, i + 1)
    terms; a place outside the reference contributes its row's mean difference."""
    n_q, n = d.shape

    def pos(i):
        return int(np.floor(v * i + 0.5))

    out = np.empty((n_q, n))
    for i in range(n_q):
        eff = min(length, i + 1)
        for j in range(n):
            total = 0.0
            for t in range(eff):
                k = j - (pos(i) - pos(i - t))
                total += d[i - t, k] if 0 <= k < n else d[i - t].mean()
            out[i, j] = total / eff
    return out


@pytest.mark.parametrize("v", [1.0, -1.0, 0.5, -0.5, 2.0, -3.0, 1.5, 0.0, 9.0])
@pytest.mark.parametrize("length", [1, 4, 11])
def test_line_scores_match_triple_loop(v, length):
    d = on_grid(np.random.default_rng(int(10 * abs(v)) + length).normal(size=(26, 17)))
    np.testing.assert_allclose(fixed_window_scores(d, length, v), slow_line_scores(d, length, v), rtol=1e-12,
                               atol=1e-12)


def planted_line(v: float, n_q: int = 90, n_ref: int = 200, start: int = 60, seed: int = 0, strength: float = 2.0):
    """Query frame i resembles reference place start + pos(i) (a route driven at speed v)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    truth = np.array([start + int(np.floor(v * i + 0.5)) for i in range(n_q)])
    ok = (truth >= 0) & (truth < n_ref)
    d[np.flatnonzero(ok), truth[ok]] -= strength
    return on_grid(d), truth


@pytest.mark.parametrize("v", [-1.0, 2.0, 0.5, -2.0, 3.0])
def test_velocity_search_recovers_planted_line(v):
    d, truth = planted_line(v, n_q=60, n_ref=400, start=200)
    searched = match_sequences(d, window=20)
    forward = match_sequences(d, window=20, velocities=(1.0,))
    late = slice(20, None)
    assert np.mean(np.abs(searched.match[late] - truth[late]) <= 1) > 0.9
    assert np.all(searched.velocity[late] == v)
    assert np.mean(np.abs(forward.match[late] - truth[late]) <= 1) < 0.5


def test_adaptive_recovers_reversed_route_and_chooses_long_windows():
    d, truth = planted_line(-1.0, n_q=120, n_ref=300, start=250, strength=1.5)
    result = match_sequences(d, l_min=3, l_max=60)
    forward = match_sequences(d, l_min=3, l_max=60, velocities=(1.0,))
    late = slice(40, None)
    assert np.mean(np.abs(result.match[late] - truth[late]) <= 1) >= 0.85
    assert np.mean(np.abs(forward.match[late] - truth[late]) <= 1) < 0.2
    assert np.median(result.window_length[late]) >= 30


def slow_common_log_p(d, grid, velocities):
    """log p on the common spread: per length the widest velocity spread (Gaussian)."""
    from scipy.special import log_ndtr

    scores = {(L, v): slow_line_scores(d, int(L), v) for L in grid for v in velocities}
    n_q = d.shape[0]
    out = np.empty((n_q, len(velocities), len(grid)))
    best = np.empty((n_q, len(velocities), len(grid)), dtype=int)
    for i in range(n_q):
        for g, L in enumerate(grid):
            common = max(scores[(L, v)][i].std() for v in velocities)
            for k, v in enumerate(velocities):
                s = scores[(L, v)][i]
                out[i, k, g] = log_ndtr((s.min() - s.mean()) / common)
                best[i, k, g] = int(np.argmin(s))
    return out, best


def test_literal_rule_with_velocities_matches_slow_reference():
    d, _ = planted_line(2.0, n_q=30, n_ref=70, start=5, strength=1.0)
    grid = np.array([2, 5, 9])
    vel = (-1.0, 0.5, 2.0)
    result = match_sequences(d, "adaptive", rule="literal", grid=list(grid), l_min=2, l_max=9, velocities=vel,
                             return_curves=True)
    lp, best = slow_common_log_p(d, grid, vel)
    for i in range(d.shape[0]):
        k = int(np.argmin(lp[i].sum(axis=1)))  # the velocity most significant over every length
        g = int(np.argmin(lp[i, k]))
        assert result.velocity[i] == vel[k]
        assert result.match[i] == best[i, k, g]
        np.testing.assert_allclose(result.log_p[i], lp[i, k], rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("rule", ["consistent", "sustained", "literal"])
def test_streaming_equals_batch_with_velocities(rule):
    d, _ = planted_line(-1.0, n_q=50, n_ref=60, start=55)
    kwargs = dict(rule=rule, l_min=2, l_max=20, grid=6, velocities=(-1.0, 0.5, 1.0, 2.0))
    batch = match_sequences(d, return_curves=True, **kwargs)
    matcher = SequenceMatcher(**kwargs)
    steps = [matcher.step(row, return_curve=True) for row in d]
    np.testing.assert_array_equal(batch.match, [s.match for s in steps])
    np.testing.assert_array_equal(batch.confidence, [s.confidence for s in steps])
    np.testing.assert_array_equal(batch.velocity, [s.velocity for s in steps])
    np.testing.assert_array_equal(batch.window_length, [s.window_length for s in steps])
    np.testing.assert_array_equal(batch.log_p, np.array([s.log_p for s in steps]))
    assert matcher._ring.shape == (21, 60)  # one ring of l_max + 1 rows for every velocity


def test_window_scores_per_velocity_and_hub_offsets():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(25, 30))
    m = SequenceMatcher(l_min=2, l_max=8)
    for row in d:
        m.step(row)
    np.testing.assert_allclose(m.window_scores(5, velocity=-1.0), fixed_window_scores(d, 5, -1.0)[-1], atol=1e-12)
    np.testing.assert_allclose(m.window_scores(5), fixed_window_scores(d, 5, 1.0)[-1], atol=1e-12)
    with pytest.raises(InvalidParameterError, match="velocity"):
        m.window_scores(5, velocity=1.25)
    offsets = np.zeros(30)
    offsets[4] = -3.0
    from catgraph.hubs import apply_hub_offsets

    direct = match_sequences(apply_hub_offsets(d, offsets), window=4)
    via = match_sequences(d, window=4, hub_offsets=offsets)
    np.testing.assert_array_equal(direct.match, via.match)
    np.testing.assert_array_equal(direct.confidence, via.confidence)


def test_default_velocities_and_validation():
    assert -1.0 in DEFAULT_VELOCITIES and 0.5 in DEFAULT_VELOCITIES and 3.0 in DEFAULT_VELOCITIES
    with pytest.raises(InvalidParameterError, match="velocities"):
        match_sequences(np.zeros((3, 4)), velocities=())
    with pytest.raises(InvalidParameterError, match="velocities"):
        match_sequences(np.zeros((3, 4)), velocities=(1.0, 1.0))
    with pytest.raises(InvalidParameterError, match="velocities"):
        match_sequences(np.zeros((3, 4)), velocities=(np.nan,))


# ------------------------------------------------------------------ precision and threads


def vectorised_line_scores(d: np.ndarray, length: int, v: float, means=None) -> np.ndarray:
    """The triple loop of :func:`slow_line_scores`, vectorised over frames and places
    (each window summed afresh: no running sums); ``means`` the fill per row."""
    n_q, n = d.shape
    pos = np.floor(v * np.arange(n_q) + 0.5).astype(np.int64)
    means = d.mean(axis=1) if means is None else means
    total = np.zeros((n_q, n))
    count = np.minimum(length, np.arange(n_q) + 1)
    j = np.arange(n)
    for t in range(length):
        rows = np.arange(t, n_q)  # frames i with a term t frames back
        k = j[None, :] - (pos[rows] - pos[rows - t])[:, None]
        inside = (k >= 0) & (k < n)
        term = np.where(inside, d[rows - t][np.arange(rows.size)[:, None], np.clip(k, 0, n - 1)], means[rows - t, None])
        total[rows] += term
    return total / count[:, None]


@pytest.mark.parametrize("v", [1.0, -0.5, 2.0])
def test_stored_value_error_is_within_its_bound(v):
    """Every term is the difference rounded once to a multiple of the quantum ``u`` (at
    most ``u / 2`` off; a fill, the rounded mean of rounded values, at most ``u``), so a
    window mean differs from the float64 score by at most ``u`` (``u / 2`` where the
    window lies inside the reference), while no value saturates."""
    rng = np.random.default_rng(11)
    d = rng.normal(size=(60, 45)) * 7.0 + 3.0
    d[5:9] *= 1e-7  # values far below the quantum's scale
    d[20] *= 6.0  # below the saturation (8 times the first row's largest)
    length = 9
    exact = slow_line_scores(d, length, v)
    err = np.abs(fixed_window_scores(d, length, v) - exact)
    _, _, u = stored_values(d)
    assert np.abs(d).max() < 32767 * u  # nothing saturates
    assert err.max() <= u * (1 + 1e-9)
    assert err.max() > 0.05 * u  # the rounding is there: a wrong bound would show
    # the lines that stay inside the reference over the window: terms alone, u / 2
    inside = np.ones_like(exact)
    if v > 0:
        reach = int(np.ceil(v * (length - 1))) + 1
        inside[:, :reach] = 0
    else:
        reach = int(np.ceil(-v * (length - 1))) + 1
        inside[:, d.shape[1] - reach:] = 0
    inside[: length - 1] = 0
    assert err[inside > 0].max() <= 0.5 * u * (1 + 1e-9)


def test_values_beyond_the_headroom_saturate_and_never_wrap():
    """Codes are int16: a later row ten times larger than the first stores ±32767 u (the
    largest code), never a wrapped-around value of the opposite sign; the window sums
    stay exact over the saturated values."""
    rng = np.random.default_rng(14)
    d = rng.normal(size=(30, 40))
    d[0, 0] = 3.0  # first row's largest: 3 < 2**2, so u = 2**-10 and 32767 u < 32
    d[10] = np.abs(d[10]) * 10.0 + 40.0  # every value beyond the int16 range, positive
    d[11] = -np.abs(d[11]) * 10.0 - 40.0  # and negative
    values, means, u = stored_values(d)
    assert u == 2.0**-10
    np.testing.assert_array_equal(values[10], 32767 * u)
    np.testing.assert_array_equal(values[11], -32767 * u)
    for v in (1.0, -2.0):
        got = fixed_window_scores(d, 4, v)
        np.testing.assert_array_equal(got, vectorised_line_scores(values, 4, v, means))
        single = fixed_window_scores(d, 1, v)
        np.testing.assert_array_equal(single[10], 32767 * u)  # saturated, not wrapped
        np.testing.assert_array_equal(single[11], -32767 * u)
    matcher = SequenceMatcher(window=4, velocities=(1.0,))
    for row in d[:12]:
        matcher.step(row)
    r = matcher._ring.shape[0]  # row t in ring[t % r]
    assert matcher._ring[10 % r].min() == 32767 and matcher._ring[11 % r].max() == -32767


@pytest.mark.parametrize("v", [1.0, -0.5, 3.0])
def test_long_stream_is_exact(v):
    """5,000 frames of running sums (an addition and a subtraction per frame) equal, bit for
    bit, every window summed afresh from the stored values: integer codes add exactly,
    so nothing drifts (and exact ties stay ties)."""
    rng = np.random.default_rng(12)
    d = rng.normal(size=(5000, 23)) * 4.0 + 1.0
    length = 40
    got = fixed_window_scores(d, length, v)
    values, means, _ = stored_values(d)
    np.testing.assert_array_equal(got, vectorised_line_scores(values, length, v, means))
    # the vectorised reference itself is the triple loop
    small = on_grid(d[:30])
    np.testing.assert_allclose(vectorised_line_scores(small, length, v), slow_line_scores(small, length, v), rtol=0,
                               atol=1e-12)
    matcher = SequenceMatcher(window=length, velocities=(v,))
    for row in d:
        matcher.step(row)
    np.testing.assert_array_equal(matcher.window_scores(length, velocity=v), got[-1])


def test_wide_reference_across_chunks_is_exact_and_streams_as_batch():
    """A reference wider than two chunks of the update (slots wrapping, lines entering
    and leaving inside chunks): window sums equal the vectorised reference bit for bit,
    and streaming equals batch at every default velocity."""
    from catgraph import _sequence_kernels as k

    rng = np.random.default_rng(15)
    n = 2 * k.CHUNK + 301
    d = rng.normal(size=(45, n))
    values, means, _ = stored_values(d)
    for v in (3.0, -0.5):
        np.testing.assert_array_equal(fixed_window_scores(d, 12, v), vectorised_line_scores(values, 12, v, means))
    kwargs = dict(l_min=2, l_max=20, grid=4)
    batch = match_sequences(d, return_curves=True, **kwargs)
    matcher = SequenceMatcher(**kwargs)
    steps = [matcher.step(row, return_curve=True) for row in d]
    np.testing.assert_array_equal(batch.match, [s.match for s in steps])
    np.testing.assert_array_equal(batch.confidence, [s.confidence for s in steps])
    np.testing.assert_array_equal(batch.velocity, [s.velocity for s in steps])
    np.testing.assert_array_equal(batch.log_p, np.array([s.log_p for s in steps]))


def test_results_do_not_depend_on_the_thread_count(monkeypatch):
    import numba

    from catgraph import _sequence_kernels

    monkeypatch.setattr(_sequence_kernels, "WORK_PER_THREAD", 1)  # threads even for this small matrix

    d, _ = planted_line(2.0, n_q=70, n_ref=90, start=3)
    kwargs = dict(l_min=2, l_max=30, grid=7, return_curves=True)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = match_sequences(d, **kwargs)
    finally:
        numba.set_num_threads(before)
    many = match_sequences(d, **kwargs)
    np.testing.assert_array_equal(one.match, many.match)
    np.testing.assert_array_equal(one.log_p, many.log_p)
    np.testing.assert_array_equal(one.confidence, many.confidence)


def test_window_scores_of_lengths_outside_the_grid_sum_the_ring():
    d, _ = planted_line(-0.5, n_q=40, n_ref=35, start=30)
    m = SequenceMatcher(l_min=2, l_max=12, grid=3, velocities=(-0.5, 1.0))
    for row in d:
        m.step(row)
    assert 7 not in m.window_grid_
    np.testing.assert_allclose(m.window_scores(7, velocity=-0.5), slow_line_scores(d, 7, -0.5)[-1], rtol=0,
                               atol=1e-12)


def test_exact_ties_keep_the_first_place():
    """A repeated stretch of the reference (a stop: places 10-19 identical) makes windows
    tie exactly; the exact sums keep the tie, and the first place wins, at any velocity."""
    rng = np.random.default_rng(13)
    d = rng.normal(size=(40, 60)) * 0.3 + 1.0
    d[:, 10:20] = (rng.normal(size=(40, 1)) * 0.1 - 2.0) / 3.0  # the same arbitrary value in every column
    scores = fixed_window_scores(d, 3, 1.0)
    for i in range(2, 40):
        assert np.all(scores[i, 12:20] == scores[i, 12])  # lines wholly inside the stop
    result = match_sequences(d, window=3, velocities=(1.0, -1.0))
    # the first place whose whole window lies in the stop: 12 along v = 1, 10 along v = -1
    expected = np.where(result.velocity == 1.0, 12, 10)
    np.testing.assert_array_equal(result.match[2:], expected[2:])


@pytest.mark.parametrize("approximation", ["gaussian", "robust"])
def test_streaming_step_on_threads_equals_the_serial_step(approximation, monkeypatch):
    """The velocities taken by whichever thread is free (the streaming step) against one
    thread taking them in order: every statistic of every window, the running sums and
    the ring, step by step, bit for bit."""
    import numba

    from catgraph import _sequence_kernels

    monkeypatch.setattr(_sequence_kernels, "WORK_PER_THREAD", 1)  # threads even for this small map

    d, _ = planted_line(-2.0, n_q=45, n_ref=300, start=250)
    kwargs = dict(l_min=2, l_max=20, grid=5, approximation=approximation)
    before = numba.get_num_threads()
    runs = []
    for threads in (1, before):
        numba.set_num_threads(threads)
        try:
            m = SequenceMatcher(**kwargs)
            steps = []
            for row in d:
                out = m.step(row, return_curve=True)
                st = m._stats
                steps.append((out, [a.copy() for a in (st.best_j, st.best_s, st.second_s, st.mean, st.std,
                                                       st.weights, st.locs, st.scales, st.sub)]))
            runs.append((steps, m._sums.copy(), m._ring.copy(), m._mring.copy()))
        finally:
            numba.set_num_threads(before)
    (steps_a, *state_a), (steps_b, *state_b) = runs
    for (out_a, stats_a), (out_b, stats_b) in zip(steps_a, steps_b):
        assert (out_a.match, out_a.score, out_a.confidence, out_a.window_length, out_a.velocity) == \
            (out_b.match, out_b.score, out_b.confidence, out_b.window_length, out_b.velocity)
        assert np.array_equal(out_a.log_p, out_b.log_p)
        assert all(np.array_equal(a, b) for a, b in zip(stats_a, stats_b))
    assert all(np.array_equal(a, b) for a, b in zip(state_a, state_b))
