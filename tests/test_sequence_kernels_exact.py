"""The matcher's faster kernels against the kernels they replace, bit for bit.

:func:`catgraph._sequence_kernels._update_stats_exact` (int32 lanes, the moments in the
compiler's order, checked exact, else added again in the order of :func:`_update_stats`)
against :func:`_update_stats` itself; :func:`encode_scaled` (a multiplication by the
quantum's reciprocal) against :func:`encode`; :func:`smallest_places` (blocks passed over
whole) against a stable sort."""

import numpy as np
import pytest

from catgraph import _sequence_kernels as k


def _both(d, v, length, dtype=np.int32):
    """Every frame's sums, block minima and moments from the two update kernels, side by side."""
    n_q, n = d.shape
    ring = np.zeros((length + 1, n), dtype=np.int16)
    mring = np.zeros(length + 1, dtype=np.int16)
    state = np.zeros(1)
    slow = np.zeros(n, dtype=dtype)
    fast = np.zeros(n, dtype=dtype)
    b_slow = np.empty((n + k.CHUNK - 1) // k.CHUNK, dtype=np.int64)
    b_fast = np.empty_like(b_slow)
    out = []
    for i in range(n_q):
        k.advance(ring, mring, state, i, d[i])
        shift = np.int64(slow[0])
        m_slow = k._update_stats(slow, ring, mring, i, v, length, shift, b_slow)
        *m_fast, exact = k._update_stats_exact(fast, ring, mring, i, v, length, shift, b_fast)
        # the fallback alone: the moments added again from the updated sums in the slow order
        e_lo, e_hi = _entering(v, i, n)
        m_replay = k._replay_moments(slow, i, v, length, shift, e_lo, e_hi, np.zeros(n, dtype=np.int16))
        out.append((m_slow, tuple(m_fast), slow.copy(), fast.copy(), b_slow.copy(), b_fast.copy(), m_replay, exact))
    return out


def _entering(v, i, n):
    """The places whose line enters the reference at frame ``i`` (as the kernels find them)."""
    if i == 0:
        return 0, n
    delta = int(k.position(v, i) - k.position(v, i - 1))
    if abs(delta) >= n:
        return 0, n
    if delta > 0:
        return 0, delta
    if delta < 0:
        return n + delta, n
    return 0, 0


def _assert_same(out):
    for m_slow, m_fast, slow, fast, b_slow, b_fast, m_replay, exact in out:
        np.testing.assert_array_equal(fast, slow)
        np.testing.assert_array_equal(b_fast, b_slow)
        if exact:  # the moments' bits; where not exact, the fallback's
            assert np.array(m_fast).tobytes() == np.array(m_slow).tobytes()
        assert np.array(m_replay).tobytes() == np.array(m_slow).tobytes()
        assert exact == (m_slow[1] < 2.0 ** 53)


@pytest.mark.parametrize("v", [1.0, -2.0, 0.5, 3.0])
@pytest.mark.parametrize("n", [40, 2048, 5000])
def test_exact_update_equals_the_update_on_random_rows(v, n):
    d = np.random.default_rng(n).normal(size=(30, n))
    _assert_same(_both(d, v, 7))


@pytest.mark.parametrize("v", [1.0, -1.0, 2.0])
def test_exact_update_equals_the_update_where_the_moments_round(v):
    """Rows of one pattern moving one place per frame at 20 times the first row's scale:
    window sums of millions whose squared deviations add up beyond 2^53, so that the float64
    moments round and only the order of :func:`_update_stats` gives its bits (the kernel adds
    them again in that order)."""
    rng = np.random.default_rng(1)
    n, n_q = 5000, 160
    base = rng.normal(size=n)
    d = np.stack([np.roll(base, i) for i in range(n_q)]) + 0.1 * rng.normal(size=(n_q, n))
    d[0] *= 0.05
    out = _both(d, v, 150)
    _assert_same(out)
    if v == 1.0:  # the case is what it claims: the pattern's own velocity, sums of squares beyond 2^53
        last_slow = out[-1][2].astype(np.int64)
        assert sum(int(y) ** 2 for y in last_slow - last_slow[0]) > 2 ** 53
        assert not out[-1][-1]  # and the exact update says so


def test_run_batch_settles_the_windows_whose_moments_round():
    """The whole kernel driver on rows whose long windows' moments round: the outputs of the
    exact update with the settled windows equal those of the update it replaces
    (:func:`run_velocities_gaussian`), on one thread and on two, and some window was settled."""
    from catgraph import sequence as seq

    rng = np.random.default_rng(2)
    n, n_q = 3000, 140
    base = rng.normal(size=n)
    d = np.stack([np.roll(base, i) for i in range(n_q)]) + 0.1 * rng.normal(size=(n_q, n))
    d[0] *= 0.05
    cfg = seq._config("test", "adaptive", "gaussian", seq.DEFAULT_LINE_RULE, "posterior", 5, 130, 6, 10, 0.05,
                      seq.DEFAULT_VELOCITIES, None)
    v_count, g = cfg.velocities.shape[0], cfg.grid.shape[0]

    def run(driver, rows_per_call):
        sums, ring, mring, state, scratch = seq._state(cfg, n, rows_per_call)
        outs = []
        for start in range(0, n_q, rows_per_call):
            block = d[start:start + rows_per_call]
            st = seq._Stats(block.shape[0], v_count, g, 1, True)
            driver(block, start, sums, ring, mring, state, st, scratch)
            outs += [st.best_j, st.best_s, st.second_s, st.mean, st.std, st.locs, st.scales, st.sub]
        return outs + [sums]

    def reference(block, start, sums, ring, mring, state, st, scratch):
        every = k._velocity_sets(v_count)[-1]
        k.store_rows(block, 0, block.shape[0], start, ring, mring, state)
        k.run_velocities_gaussian(every, 0, block.shape[0], start, sums, ring, mring, state, cfg.velocities, cfg.grid,
                                  cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights, st.locs,
                                  st.scales, st.sub, scratch[0])

    def exact(block, start, sums, ring, mring, state, st, scratch):
        k.run_batch(block, start, sums, ring, mring, state, cfg.velocities, cfg.grid, cfg.approx_code, 10, 1,
                    cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights, st.locs, st.scales,
                    st.sub, *scratch)

    settled = []
    original = k._settle_window

    def counting(*args):
        settled.append(args[1])
        return original(*args)

    k._settle_window = counting
    try:
        for rows_per_call in (1, 7):
            want = run(reference, rows_per_call)
            got = run(exact, rows_per_call)
            for a, b in zip(got, want):
                assert a.tobytes() == b.tobytes()
        old_work = k.WORK_PER_THREAD
        k.WORK_PER_THREAD = 1  # both threads, one velocity at a time
        try:
            got = run(exact, 7)
        finally:
            k.WORK_PER_THREAD = old_work
        for a, b in zip(got, want):
            assert a.tobytes() == b.tobytes()
    finally:
        k._settle_window = original
    assert settled  # the case is what it claims: some windows were settled


def test_exact_update_with_int64_sums():
    d = np.random.default_rng(3).normal(size=(25, 3000))
    _assert_same(_both(d, 1.0, 6, dtype=np.int64))


def test_scaled_encoding_is_the_encoding():
    rng = np.random.default_rng(0)
    for e in (-1000, -300, -40, -12, 0, 1, 12, 60, 900, 1020):
        unit = np.ldexp(1.0, e)
        with np.errstate(over="ignore"):
            x = np.concatenate([rng.normal(size=4000) * unit * 10.0 ** rng.uniform(-2, 5, size=4000),
                                (np.arange(-40, 40) + 0.5) * unit, [0.0, -0.0, 32767.5 * unit, -32767.5 * unit]])
        x = x[np.isfinite(x)]
        for value in x:
            assert k.encode_scaled(value, 1.0 / unit) == k.encode(value, unit)


def test_advance_stores_the_codes_of_the_division():
    rng = np.random.default_rng(4)
    for scale in (1e-310, 1e-300, 1e-5, 1.0, 3e4, 1e300):  # 1e-310: subnormal rows, 1 / unit beyond float64
        d = rng.normal(size=(3, 777)) * scale
        ring = np.zeros((3, 777), dtype=np.int16)
        mring = np.zeros(3, dtype=np.int16)
        state = np.zeros(1)
        for i in range(3):
            k.advance(ring, mring, state, i, d[i])
            codes = np.array([k.encode(x, state[0]) for x in d[i]])
            np.testing.assert_array_equal(ring[i], codes)
            assert mring[i] == np.int64(np.rint(codes.sum() / codes.size))


def _scan_one_by_one(row, kept):
    """The value-by-value scan the blocks replace (Python): each value against the kept list."""
    idx, val = [], []
    for j, x in enumerate(row):
        if len(val) == kept:
            if not x < val[-1]:
                continue
            idx.pop()
            val.pop()
        p = len(val)
        while p > 0 and val[p - 1] > x:
            p -= 1
        idx.insert(p, j)
        val.insert(p, x)
    return np.array(idx), np.array(val)


@pytest.mark.parametrize("seed", range(4))
def test_smallest_places_over_blocks_is_the_scan_one_by_one(seed):
    """Rows longer than a few blocks, with ties, runs of equal values and NaN; on finite rows
    also a stable sort's prefix."""
    rng = np.random.default_rng(seed)
    for trial in range(40):
        n = int(rng.integers(1, 3000))
        kept = int(rng.integers(1, min(n, 30) + 1))
        row = rng.integers(0, 40, n).astype(float) if trial % 2 else rng.normal(size=n)
        if trial % 3 == 0:
            row[rng.integers(0, n, 1 + trial % 7)] = np.nan
        idx, val = np.empty(kept, dtype=np.int64), np.empty(kept)
        k.smallest_places(row, idx, val)
        ref_idx, ref_val = _scan_one_by_one(row, kept)
        np.testing.assert_array_equal(idx, ref_idx)
        np.testing.assert_array_equal(val, ref_val)
        if np.all(np.isfinite(row)):
            order = np.lexsort((np.arange(n), row))[:kept]
            np.testing.assert_array_equal(idx, order)


#: ``match_sequences`` on the rows below (l_max 130, 6 lengths, with the curves), recorded from
#: the matcher before the exact update (9539438): matches, scores, confidences, lengths,
#: velocities and curves
_ROUNDING_DIGESTS = {"robust": "3eacb37524bfce08", "gmm2": "797b2fd6a2df2125", "gmm3": "04fc25ef3ac7aed9",
                     "gaussian": "8fc5e3da960de34a"}
#: the same on processors that round otherwise, recorded on them (Zen 4 at f19e3aa; Zen 3 at
#: 8cb4901, the digests the matcher of 9539438 gives there)
_OWN_ROUNDING_DIGESTS = {"znver4": {"robust": "e14f0bae91dbe420", "gmm2": "6c4b709041589328",
                                    "gmm3": "b25eb8f52a6a7596", "gaussian": "0b40d94350322d0a"},
                         "znver3": {"robust": "725ff3947af326fa", "gmm2": "d2a6fe2240d9464c",
                                    "gmm3": "c83d93c245395951", "gaussian": "8936927d0e781501"}}


@pytest.mark.parametrize("approximation", ["robust", "gmm2", "gmm3", "gaussian"])
def test_every_approximation_where_the_moments_round_gives_the_answers_before(approximation):
    """Every approximation on rows whose long windows' moments round: the settled windows' mean
    and spread (and the mixture fitted again from them) give the answers of the matcher before
    the exact update, and some window was settled."""
    from catgraph import sequence as seq

    from .conftest import array_digest, assert_recorded

    rng = np.random.default_rng(2)
    n, n_q = 3000, 140
    base = rng.normal(size=n)
    d = np.stack([np.roll(base, i) for i in range(n_q)]) + 0.1 * rng.normal(size=(n_q, n))
    d[0] *= 0.05
    settled = []
    original = k._settle_window

    def counting(*args):
        settled.append(args[1])
        return original(*args)

    k._settle_window = counting
    try:
        r = seq.match_sequences(d, approximation=approximation, l_max=130, grid=6, return_curves=True,
                                rule=seq.DEFAULT_LINE_RULE)
    finally:
        k._settle_window = original
    assert_recorded(array_digest([r.match, r.score, r.confidence, r.window_length, r.velocity, r.log_p]),
                    _ROUNDING_DIGESTS, _OWN_ROUNDING_DIGESTS, approximation)
    assert settled
