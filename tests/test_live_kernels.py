"""The live step's kernels made faster give the floats of their one-pass references.

:func:`catgraph._diff_kernels.chunk_sums` and :func:`~catgraph._diff_kernels.normalise_row`
sum whole chunks side by side, :func:`catgraph._observation_kernels.first_max` finds a
running maximum from vectorised block maxima: each is checked here against the plain
loop it replaced (kept below as the reference), bit for bit, on values chosen to catch
the corner cases (ties, ``±0``, NaN, ``±inf``, lengths around the block sizes)."""

import numpy as np
import pytest

from catgraph import _diff_kernels as dk
from catgraph import _observation_kernels as ok
from catgraph._jit import njit


@njit
def _chunk_sums_reference(d, centre, power, out):
    m, n = d.shape
    n_chunks = out.shape[1]
    for t in range(m * n_chunks):
        i = t // n_chunks
        c = t - i * n_chunks
        lo = c * dk.SUM_CHUNK
        hi = min(n, lo + dk.SUM_CHUNK)
        mu = centre[i]
        s = 0.0
        if power == 1:
            for j in range(lo, hi):
                s += d[i, j] - mu
        else:
            for j in range(lo, hi):
                v = d[i, j] - mu
                s += v * v
        out[i, c] = s


@njit
def _normalise_row_reference(d, out):
    n = d.shape[0]
    n_chunks = (n + dk.SUM_CHUNK - 1) // dk.SUM_CHUNK
    mu = 0.0
    total = 0.0
    for c in range(n_chunks):
        s = 0.0
        for j in range(c * dk.SUM_CHUNK, min(n, c * dk.SUM_CHUNK + dk.SUM_CHUNK)):
            s += d[j] - mu
        total += s
    mean = total / n
    total = 0.0
    for c in range(n_chunks):
        s = 0.0
        for j in range(c * dk.SUM_CHUNK, min(n, c * dk.SUM_CHUNK + dk.SUM_CHUNK)):
            v = d[j] - mean
            s += v * v
        total += s
    std = np.sqrt(total / n)
    size = abs(mean)
    if not (std > 1e-12 * (size if size > 1.0 else 1.0)) or mean != mean:
        std = 0.0
    if std > 0.0:
        for j in range(n):
            out[j] = (d[j] - mean) / std
    else:
        for j in range(n):
            out[j] = 0.0
    return mean, std


@njit
def _first_max_reference(x, sign):
    top = -np.inf
    best = -1
    for i in range(x.shape[0]):
        v = sign * x[i]
        if v > top:
            top = v
            best = i
    return top, best


@njit
def _standardised_reference(centred, sd, scale, tau, z, r):
    top = -np.inf
    best = 0
    largest = -np.inf
    finite = True
    for i in range(centred.shape[0]):
        v = centred[i] / sd
        z[i] = v
        finite &= np.isfinite(v)
        b = -v
        w = (scale * b) * tau
        r[i] = w
        top = max(top, w)
        if b > largest:
            largest = b
            best = i
    return top, best, finite


@njit
def _sum_max_reference(a, b, out):
    top = -np.inf
    for i in range(a.shape[0]):
        v = a[i] + b[i]
        out[i] = v
        top = max(top, v)
    return top


def _bits(x):
    return np.asarray(x, dtype=np.float64).tobytes()


def _values(rng, n, kind):
    x = rng.standard_normal(n) * rng.uniform(0.1, 50) + rng.uniform(-20, 20)
    if kind == "ties":
        x = np.round(x / 10)
    elif kind == "signed zeros":
        x = np.zeros(n) * rng.choice([-1.0, 1.0], n)
    elif kind == "non-positive":
        x = -np.abs(np.round(x / 10))
        x[rng.random(n) < 0.5] = -0.0
    elif kind == "nan":
        x[rng.random(n) < 0.2] = np.nan
    elif kind == "all nan":
        x[:] = np.nan
    elif kind == "-inf":
        x[:] = -np.inf
        x[rng.random(n) < 0.1] = np.nan
    elif kind == "inf":
        x[rng.random(n) < 0.3] = -np.inf
        x[rng.random(n) < 0.05] = np.inf
    return x


KINDS = ("plain", "ties", "signed zeros", "non-positive", "nan", "all nan", "-inf", "inf")
LENGTHS = (0, 1, 2, 7, 8, 9, 255, 256, 257, 1000, 4097)


@pytest.mark.parametrize("n", [1, 2, 4095, 4096, 4097, 4 * 4096, 4 * 4096 + 1, 5 * 4096 - 3, 9 * 4096 + 17, 100_003])
def test_chunk_sums_and_normalise_row_are_the_plain_loops(n):
    rng = np.random.default_rng(n)
    d = rng.standard_normal((3, n)) * 37.0 + 5.0
    centre = d.mean(axis=1)
    n_chunks = -(-n // dk.SUM_CHUNK)
    for power in (1, 2):
        fast, slow = np.empty((3, n_chunks)), np.empty((3, n_chunks))
        dk.chunk_sums(d, centre, power, fast)
        _chunk_sums_reference(d, centre, power, slow)
        assert fast.tobytes() == slow.tobytes()
    for row in (d[0], np.full(n, 2.5), np.zeros(n)):
        fast, slow = np.empty(n), np.empty(n)
        assert _bits(dk.normalise_row(row, fast)) == _bits(_normalise_row_reference(row, slow))
        assert fast.tobytes() == slow.tobytes()


@pytest.mark.parametrize("kind", KINDS)
def test_first_max_is_the_running_maximum(kind):
    rng = np.random.default_rng(len(kind))
    for n in LENGTHS:
        for _ in range(4):
            x = _values(rng, n, kind)
            for sign in (1.0, -1.0):
                top, best = ok.first_max(x, sign)
                ref_top, ref_best = _first_max_reference(x, sign)
                assert best == ref_best and _bits(top) == _bits(ref_top), (n, sign)


@pytest.mark.parametrize("kind", KINDS)
def test_standardised_ratios_and_sum_max_are_their_one_pass_forms(kind):
    rng = np.random.default_rng(7 + len(kind))
    for n in LENGTHS:
        x, y = _values(rng, n, kind), _values(rng, n, KINDS[(KINDS.index(kind) + 1) % len(KINDS)])
        for sd in (1.3, -2.0, np.inf, 1e-300):
            for tau in (0.9, 0.0):
                a, b = x.copy(), x.copy()  # in place, as the model calls it
                ra, rb = np.empty(n), np.empty(n)
                with np.errstate(all="ignore"):
                    fast = ok.standardised_ratios(a, sd, 0.7, tau, a, ra)
                    slow = _standardised_reference(b, sd, 0.7, tau, b, rb)
                assert _bits(fast[0]) == _bits(slow[0]) and fast[1:] == slow[1:]
                assert a.tobytes() == b.tobytes() and ra.tobytes() == rb.tobytes()
        oa, ob = np.empty(n), np.empty(n)
        with np.errstate(all="ignore"):
            assert _bits(ok.sum_max(x, y, oa)) == _bits(_sum_max_reference(x, y, ob))
        assert oa.tobytes() == ob.tobytes()
