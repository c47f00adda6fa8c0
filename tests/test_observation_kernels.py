"""The observation models' compiled passes give numpy's floats, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from catgraph import _observation_kernels as kernels
from catgraph.observation import _median, _NearMedian


@pytest.mark.parametrize("n", [1, 2, 7, 8, 129, 1000, 1001])
def test_fused_passes_are_the_numpy_formulas(n):
    rng = np.random.default_rng(n)
    x, h = rng.standard_normal(n) * 3.0, rng.standard_normal(n)
    centre, factor = float(rng.standard_normal()), 0.37
    out = np.empty(n)
    kernels.negated_difference(x, h, out)
    assert np.array_equal(out, np.negative(np.subtract(x, h)))
    kernels.absolute_deviations(x, centre, out)
    assert np.array_equal(out, np.abs(np.subtract(x, centre)))
    square = np.empty(n)
    kernels.centred_squared(x, x.mean(), out, square)
    centred = np.subtract(x, x.mean())
    assert np.array_equal(out, centred) and np.array_equal(square, np.multiply(centred, centred))
    for threshold in (-1.0, centre, 10.0):
        assert kernels.centred_count(x, x.mean(), threshold, out) == np.count_nonzero(x < threshold)
        assert np.array_equal(out, centred)
    base, r = np.empty(n), np.empty(n)
    for corrected in (True, False):
        top, best = kernels.tempered_ratios(x, h, corrected, factor, base, r)
        expected = np.negative(np.subtract(x, h)) if corrected else np.negative(x)
        assert np.array_equal(base, expected) and np.array_equal(r, np.multiply(factor, expected))
        assert top == r.max() and best == np.argmax(expected)
    ties = np.zeros(n)  # the first of equal largest values, as np.argmax
    ties[1::2] = -1.0
    assert kernels.tempered_ratios(ties, ties, False, factor, base, r)[1] == np.argmax(-ties) == min(1, n - 1)


@pytest.mark.parametrize("n", [1, 2, 7, 8, 129, 1000, 1001, 100_003])
def test_accumulated_levels_are_numpy_add_divide_and_sum(n):
    rng = np.random.default_rng(n)
    total, row = rng.standard_normal(n) * 50.0, rng.standard_normal(n)
    want_total = total + row
    want_level = np.divide(want_total, 7)
    level = np.empty(n)
    before, new_total, other_level = total.copy(), np.empty(n), np.empty(n)
    assert kernels.accumulated_levels(total, row, 7.0, new_total, other_level) == want_level.sum()
    assert np.array_equal(total, before) and np.array_equal(new_total, want_total)  # into another array
    level_sum = kernels.accumulated_levels(total, row, 7.0, total, level)  # in place
    assert np.array_equal(total, want_total) and np.array_equal(level, want_level)
    assert np.array_equal(other_level, want_level)
    assert level_sum == want_level.sum() and level_sum / n == want_level.mean()


def _brute_bracket(v, mid, radius):
    d = v - mid
    return int(np.count_nonzero(d < -radius)), np.sort(v[np.abs(d) <= radius])


@pytest.mark.parametrize("absolute", [False, True])
def test_bracket_splits_the_values_like_a_sort(absolute):
    rng = np.random.default_rng(3)
    x = np.round(rng.standard_normal(500), 2)  # ties
    centre = 0.1
    v = np.abs(x - centre) if absolute else x
    work = np.empty_like(x)
    for mid, radius in ((0.0, 0.1), (0.5, 0.0), (v[7], 0.05), (-5.0, 1.0), (0.0, 100.0)):
        want_below, want_inside = _brute_bracket(v, mid, radius)
        for k in (0, len(x) // 2, want_below, want_below + len(want_inside) - 1, want_below + len(want_inside)):
            work[:] = np.nan
            below, inside = kernels.bracket(x, centre, absolute, mid, radius, k, work)
            assert (below, inside) == (want_below, len(want_inside))
            # the values inside, in their order (the same floats whether or not the k-th is among them)
            assert np.array_equal(work[:inside], v[np.abs(v - mid) <= radius])
            assert np.array_equal(np.sort(work[:inside]), want_inside)
        same = x.copy()  # the values' own array as the work array: each written over one already read
        below, inside = kernels.bracket(same, centre, absolute, mid, radius, 0, same)
        assert (below, inside) == (want_below, len(want_inside))
        assert np.array_equal(same[:inside], v[np.abs(v - mid) <= radius])
        lower = v[v - mid < -radius]
        assert kernels.largest_below(x, centre, absolute, mid, radius) == (lower.max() if len(lower) else -np.inf)


@pytest.mark.parametrize("n", [1, 2, 3, 10, 101, 1000, 1001])
@pytest.mark.parametrize("seed", [0, 1])
def test_near_median_is_numpys_median_as_the_values_drift(n, seed):
    """A slowly moving array (running means, as the hub levels), a jump, ties, exact
    repeats: every call gives ``np.median``'s float, whether the bracket hits or not."""
    rng = np.random.default_rng(seed)
    near, spread = _NearMedian(), _NearMedian()
    total = np.zeros(n)
    work = np.empty(n)
    hits = 0
    for k in range(1, 40):
        total += rng.standard_normal(n)
        level = total / k
        if k == 20:
            level = level + 3.0  # the median leaves its bracket
        if k in (25, 26):
            level = np.round(level, 1)  # many ties, repeated
        width = near.width
        med = near.median(level, work)
        assert med == float(np.median(level))
        mad = spread.median(level, work, centre=med)
        assert mad == float(np.median(np.abs(level - med)))
        if near.width == 0.0 and mad > 0:
            near.width = spread.width = 0.02 * mad
        hits += 0.0 < near.width <= width  # a miss widens the bracket fourfold
    if n >= 100:
        assert hits >= 10  # the bracket was used, not only the full selection


def test_near_median_takes_the_lower_middle_from_below_the_bracket():
    """Even length, the bracket starting exactly at the upper middle value: the lower
    middle value is the largest of those below the bracket."""
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    near = _NearMedian()
    near.guess, near.width = 3.25, 0.25  # holds 3.0 (the upper middle) only
    assert near.median(x, np.empty(6)) == float(np.median(x)) == _median(x, np.empty(6))


def _same(a, b) -> bool:
    """The same float64 bits (``-0.0`` is not ``0.0``)."""
    return np.float64(a).tobytes() == np.float64(b).tobytes()


def _lengths():
    """Every length through a few of numpy's tree levels, and long ones with odd tails."""
    return [*range(0, 300), 1023, 1024, 1025, 4097, 65_543, 200_003]


def test_pairwise_sum_is_numpys_sum_on_every_length():
    """The replayed tree gives ``np.sum``'s float: values of very different sizes (so
    that the order of the additions shows), signed zeros, and every length up to a few
    hundred (every shape of block) and long arrays."""
    rng = np.random.default_rng(11)
    for n in _lengths():
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6, n)
        assert _same(kernels.pairwise_sum(x), x.sum()), n
        starts = kernels.block_starts(n)
        assert starts[0] == 0 and starts[-1] == n and np.all(np.diff(starts) <= 128)
    for zeros in (np.full(3, -0.0), np.full(200, -0.0), np.zeros(0)):
        assert _same(kernels.pairwise_sum(zeros), zeros.sum())


def test_product_sum_is_numpys_sum_of_the_products_on_every_length():
    """product_sum: numpy's ``(x * y).sum()``, every bit, on every length (the jump
    evidence's correlation with its kept frame, taken on the calling thread)."""
    rng = np.random.default_rng(13)
    for n in _lengths():
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6, n)
        y = rng.standard_normal(n)
        assert _same(kernels.product_sum(x, y), np.multiply(x, y).sum()), n


def test_the_jump_evidence_takes_no_blas_product(monkeypatch):
    """The jump evidence's correlation with its kept frame is numpy's sum of the products,
    taken without ``np.dot`` (whose BLAS threads spin on the live step's cores after a long
    product), on contiguous and on strided rows alike."""
    from catgraph import jumps

    monkeypatch.setattr(jumps.np, "dot", None)  # any np.dot in the module would fail
    rng = np.random.default_rng(14)
    rows = rng.standard_normal((120, 2 * 501))
    for view in (lambda r: r[:501].copy(), lambda r: r[::2]):  # contiguous; strided
        ev = jumps.JumpEvidence(apart=5)
        for r in rows:
            c = view(r) - view(r).mean()
            ev.observe(0.5, c, float((c * c).sum()))
        assert ev.jump_counts_.sum() > ev.prior_frames  # the kept frame was compared


def test_fused_sums_are_the_numpy_formulas_they_replace():
    """centred_sums: ``x − m`` with numpy's ``((x − m)²).sum()`` and ``((x − m) · o).sum()``;
    mean_std: ``(x.mean(), x.std())``: every bit, on every length."""
    rng = np.random.default_rng(12)
    nothing = np.empty(0)
    for n in _lengths()[1:]:
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n) + 5.0
        other = rng.standard_normal(n)
        mean = x.mean()
        out = np.empty(n)
        squares, products = kernels.centred_sums(x, mean, other, out)
        centred = np.subtract(x, mean)
        assert np.array_equal(out, centred)
        assert _same(squares, np.multiply(centred, centred).sum()) and _same(products, np.multiply(centred, other).sum())
        assert kernels.centred_sums(x, mean, nothing, out) == (squares, 0.0)
        kept = out.copy()
        assert kernels.centred_sums(x, mean, nothing, nothing) == (squares, 0.0)  # nothing stored
        assert np.array_equal(out, kept)
        m, sd = kernels.mean_std(x)
        assert _same(m, x.mean()) and _same(sd, x.std()), n


@pytest.mark.parametrize("n", [2, 7, 8, 129, 1000, 1001])
def test_standardised_ratios_sum_max_and_all_finite_are_the_numpy_passes(n):
    rng = np.random.default_rng(n)
    s = rng.standard_normal(n) * 4.0
    centred = s - s.mean()
    sd, scale, tau = float(s.std()), 0.83, 1.0 / 7.0
    z, r = np.empty(n), np.empty(n)
    top, best, finite = kernels.standardised_ratios(s, s.mean(), sd, scale, tau, r)
    want_z = centred / sd  # the model's numpy passes: centre, divide
    want_r = np.multiply(np.multiply(scale, np.negative(want_z)), tau)  # ratio, then the window's factor
    assert finite and np.array_equal(r, want_r)
    assert top == want_r.max() and best == np.argmax(np.negative(want_z))
    bad = s.copy()
    bad[n // 2] = np.inf
    assert not kernels.standardised_ratios(bad, s.mean(), sd, scale, tau, r)[2]
    a, b, out = rng.standard_normal(n), rng.standard_normal(n), np.empty(n)
    assert kernels.sum_max(a, b, out) == np.add(a, b).max() and np.array_equal(out, np.add(a, b))
    assert kernels.all_finite(a)
    for value in (np.nan, np.inf, -np.inf):
        a[-1] = value
        assert not kernels.all_finite(a)


def _running_max(values):
    """The slow reference of the compiled maxima: ``top = max(top, v)`` in order (numba's
    ``max``: a NaN ``v`` is skipped, of equal values the first is kept)."""
    top = -np.inf
    for v in values:
        top = v if v > top else top
    return top


@pytest.mark.parametrize("n", [1, 3, 7, 8, 9, 16, 17, 129, 1000, 100_003])
def test_sum_max_is_the_running_maximum_in_order(n):
    rng = np.random.default_rng(n)
    a, b, out = rng.standard_normal(n), rng.standard_normal(n), np.empty(n)
    cases = [(a, b)]
    nan = a.copy()
    nan[:: 3] = np.nan  # NaN skipped
    cases.append((nan, b))
    cases.append((np.full(n, np.nan), b))  # every value NaN: -inf
    neg = -np.abs(a) - 1.0
    for first in (0.0, -0.0):  # a largest 0 keeps the sign of the first zero
        z = neg.copy()
        z[n // 2] = first
        z[-1] = -first
        cases.append((z, np.zeros(n)))
    cases.append((np.full(n, -np.inf), np.zeros(n)))
    for x, y in cases:
        top = kernels.sum_max(x, y, out)
        want = _running_max(np.add(x, y))
        assert np.array_equal(out, np.add(x, y), equal_nan=True)
        assert np.array_equal(np.array([top]), np.array([want])) and np.signbit(top) == np.signbit(want), (n, top, want)


@pytest.mark.parametrize("n", [1, 8, 129, 1001])
def test_hub_tempered_ratios_are_the_formed_correction_then_tempered_ratios(n):
    rng = np.random.default_rng(n)
    row, level = rng.standard_normal(n), rng.standard_normal(n) * 2.0 + 1.0
    mean = float(level.mean())
    assert kernels.count_below(level, 0.3) == np.count_nonzero(level < 0.3)
    for shrink in (1.0, 0.37, 0.0):
        h = np.subtract(level, mean)
        if shrink != 1.0:
            h *= shrink
        base, r = np.empty(n), np.empty(n)
        want = kernels.tempered_ratios(row, h, True, 0.61, base, r)
        for keep in (True, False):
            got_base, got_r = np.full(n, np.nan), np.empty(n)
            got = kernels.hub_tempered_ratios(row, level, mean, shrink, 0.61, keep, got_base, got_r)
            assert got == want and np.array_equal(got_r, r)
            assert np.array_equal(got_base, base) if keep else np.all(np.isnan(got_base))
