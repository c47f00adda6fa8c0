"""The live step's kernels made faster give the floats of their one-pass references.

:func:`catgraph._diff_kernels.chunk_sums` and :func:`~catgraph._diff_kernels.normalise_row`
sum whole chunks side by side: each is checked here against the plain loop it replaced
(kept below as the reference), bit for bit, on lengths around the chunk and group sizes
and on rows with no spread."""

import numpy as np
import pytest

from catgraph import _diff_kernels as dk
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


def _bits(x):
    return np.asarray(x, dtype=np.float64).tobytes()


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
