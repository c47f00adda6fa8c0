"""The compact (uint8 codes) pair kernel against a plain integer reference.

:func:`catgraph._diff_kernels.pair_block_codes` sums 512-byte groups of vector steps
(one horizontal sum each), then 64-byte steps, then a scalar tail; every split of the
dimension, extreme codes included, must give the integer sums of the plain loop, bit
for bit, for both metrics, any block of places and any query row."""

import numpy as np
import pytest

from catgraph import _diff_kernels as k


def _slow(q, r, code, step):
    diff = q[:, None, :].astype(np.int64) - r[None, :, :].astype(np.int64)
    terms = np.abs(diff) if code == k.SAD else diff * diff
    return step * terms.sum(-1).astype(np.int64)


@pytest.mark.parametrize("code", [0, 1])
@pytest.mark.parametrize("dim", [448, 511, 512, 513, 576, 1024, 1089])
def test_grouped_code_kernel_equals_integer_loop(code, dim):
    rng = np.random.default_rng(dim + 7 * code)
    r = rng.integers(0, 256, size=(70, dim), dtype=np.uint8)
    r[0], r[1] = 0, 255  # the extremes both ways: every lane at its largest term
    q = rng.integers(0, 256, size=(3, dim), dtype=np.uint8)
    q[0], q[1] = 255, 0
    out = np.full((3, 70), np.nan)
    step = 0.375
    k.pair_block_codes(q, r, 0, 70, code, step, out)
    assert np.array_equal(out, _slow(q, r, code, step))
    top = 255 if code == k.SAD else 255 * 255
    assert out[0, 0] == step * dim * top and out[1, 1] == step * dim * top
    part = np.full((3, 70), -1.0)
    k.pair_block_codes(q, r, 13, 41, code, step, part)  # a range of places only
    assert np.array_equal(part[:, 13:41], out[:, 13:41]) and np.all(part[:, :13] == -1.0)
