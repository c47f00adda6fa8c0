"""Row normalisation: the one-call row kernel and the threaded passes give the same floats.

:func:`catgraph.differences._normalise_into` runs each row's passes in one compiled call
(:func:`catgraph._diff_kernels.normalise_row`) where the work fits one thread, and the
chunk-sum and scale passes split over threads otherwise; both must give the same floats,
bit for bit, for any rows (large offsets, zero and tiny spread, negative zeros)."""

import numpy as np

import catgraph.differences as differences
from catgraph import _diff_kernels as k


def _rows(rng):
    d = rng.normal(size=(9, 3 * k.SUM_CHUNK + 123)) * rng.uniform(0.01, 1e4, size=(9, 1))
    d[1] += 1e9  # a large offset: the centred second pass matters
    d[2] = 7.25  # no spread: zeros
    d[3] = 0.0
    d[3, ::2] = -0.0
    d[4] = 1e6 + rng.normal(size=d.shape[1]) * 1e-9  # spread below the zero-spread threshold
    return d


def test_one_long_row_split_into_chunk_runs_equals_the_row_kernel(monkeypatch):
    """A single row too long for one thread takes the chunk-sum and scale passes, split
    into runs of whole chunks: the row kernel's floats."""
    rng = np.random.default_rng(12)
    d = _rows(rng)
    for i in (0, 1, 2, 4):
        row = d[i:i + 1].copy()
        monkeypatch.setattr(differences, "NORMALISE_PER_THREAD", 1)
        monkeypatch.setattr(differences, "_threads_available", lambda: 3)
        pieces = differences._split(*row.shape, k.SUM_CHUNK)
        assert len(pieces) == 3 and pieces[0][3] < row.shape[1]  # runs of chunks of the one row
        split = differences._normalise_into(row, np.empty_like(row))
        one = np.empty_like(row[0])
        k.normalise_row(row[0], one)
        assert np.array_equal(split[0], one)


def test_row_kernel_path_equals_the_threaded_passes(monkeypatch):
    rng = np.random.default_rng(11)
    d = _rows(rng)
    monkeypatch.setattr(differences, "NORMALISE_PER_THREAD", 1)  # the passes, split over threads
    monkeypatch.setattr(differences, "_threads_available", lambda: 3)
    assert len(differences._split(*d.shape, k.SUM_CHUNK)) > 1
    split = differences._normalise_into(d.copy(), np.empty_like(d))
    monkeypatch.setattr(differences, "NORMALISE_PER_THREAD", 1 << 60)  # one piece: the row kernel
    assert len(differences._split(*d.shape, k.SUM_CHUNK)) == 1
    one = differences._normalise_into(d.copy(), np.empty_like(d))
    in_place = d.copy()
    differences._normalise_into(in_place, in_place)
    assert np.array_equal(one, split) and np.array_equal(in_place, split)
    assert np.all(one[2] == 0.0) and np.all(one[3] == 0.0) and np.all(one[4] == 0.0)
    # against the statistics the passes compute, row by row
    mean, std = differences.row_statistics(d)
    for i in (0, 1, 5):
        assert np.array_equal(one[i], (d[i] - mean[i]) / std[i])


def test_column_blocks_in_one_block_equal_the_matrix_bit_for_bit():
    """A map that fits one column block is normalised row by row as a whole (the row
    kernel): the floats of the batch matrix and of the same map cut into several blocks
    (the chunk-sum passes across blocks)."""
    from catgraph.differences import PreparedReference, difference_matrix, iter_difference_columns

    rng = np.random.default_rng(5)
    r = rng.normal(size=(9000, 24)).astype(np.float32)
    q = r[::97] + 0.1
    for metric in ("sad", "cosine"):
        ref = PreparedReference(r, metric)
        full = difference_matrix(q, ref, metric, normalise=True)
        one = list(iter_difference_columns(q, ref, metric, normalise=True))
        several = list(iter_difference_columns(q, ref, metric, block_places=4096, normalise=True))
        assert len(one) == 1 and len(several) == 3
        assert np.array_equal(one[0][1], full)
        assert np.array_equal(np.concatenate([b for _, b in several], axis=1), full)


def test_rows_of_huge_values_normalise_as_their_scaled_copies():
    """Rows beyond 1e100 (their squared deviations overflow) normalise as the same rows
    scaled down, where they became zeros; other rows keep their floats."""
    rng = np.random.default_rng(0)
    rows = rng.random((3, 7))
    huge = rows * 1e200
    huge[1] = rows[1]  # one ordinary row among them
    normalise_rows = differences.normalise_rows
    out = normalise_rows(huge)
    np.testing.assert_allclose(out, normalise_rows(rows), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(out[1], normalise_rows(rows)[1])
    np.testing.assert_allclose(normalise_rows([1e200, 0.0]), [1.0, -1.0])
