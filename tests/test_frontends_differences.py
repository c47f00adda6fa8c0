import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.distance import cdist

from catgraph.differences import difference_matrix, difference_row, iter_difference_blocks, normalise_rows
from catgraph.exceptions import DataError, InvalidParameterError, ShapeMismatchError
from catgraph.frontends import patch_normalise, seqslam_preprocess, wifi_vectors


def test_patch_normalise_matches_hand_computation_and_flat_patch_is_zero():
    img = np.zeros((1, 4, 8))
    img[0, :, 4:] = np.arange(16).reshape(4, 4)
    out = patch_normalise(img, patch=4)
    assert np.all(out[0, :, :4] == 0)  # flat patch: zeros, not NaN
    block = np.arange(16.0).reshape(4, 4)
    np.testing.assert_allclose(out[0, :, 4:], (block - block.mean()) / block.std(), rtol=1e-6)


def test_patch_normalise_uneven_edges_finite():
    out = patch_normalise(np.random.default_rng(0).random((2, 5, 7)), patch=4)
    assert out.shape == (2, 5, 7) and np.all(np.isfinite(out))


def test_seqslam_preprocess_shapes_and_constant_images():
    imgs = np.full((3, 16, 32, 3), 200, dtype=np.uint8)
    d = seqslam_preprocess(imgs, size=(16, 8))
    assert d.shape == (3, 128) and d.dtype == np.float32 and np.all(d == 0)


def test_wifi_not_detected_is_weak_not_strong():
    v = wifi_vectors(np.array([[100, -40, -104, -110]]))
    np.testing.assert_allclose(v, [[0, 65, 1, 0]])
    with pytest.raises(DataError, match="dBm"):
        wifi_vectors(np.array([[5, -40]]))


@pytest.mark.parametrize("metric, reference", [("sad", "cityblock"), ("ssd", "sqeuclidean"), ("cosine", "cosine")])
def test_difference_matrix_against_scipy(metric, reference, rng):
    q, r = rng.random((23, 17)), rng.random((31, 17))
    expected = cdist(q, r, reference)
    np.testing.assert_allclose(difference_matrix(q, r, metric, block_rows=5), expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(difference_row(q[3], r, metric), expected[3], rtol=1e-5, atol=1e-5)


def test_hamming_bool_and_packed(rng):
    q, r = rng.random((4, 16)) > 0.5, rng.random((6, 16)) > 0.5
    expected = cdist(q, r, "hamming") * 16
    np.testing.assert_allclose(difference_matrix(q, r, "hamming"), expected)
    np.testing.assert_allclose(difference_matrix(np.packbits(q, axis=1), np.packbits(r, axis=1), "hamming"), expected)


def test_blocks_are_bounded_and_cover_everything(rng):
    q, r = rng.random((10, 3)), rng.random((7, 3))
    blocks = list(iter_difference_blocks(q, r, "sad", block_rows=4))
    assert [s for s, _ in blocks] == [0, 4, 8]
    assert max(b.shape[0] for _, b in blocks) <= 4


def test_mismatched_sizes_unknown_metric_and_nan():
    with pytest.raises(ShapeMismatchError, match="same front-end"):
        difference_matrix(np.zeros((2, 3)), np.zeros((2, 4)))
    with pytest.raises(InvalidParameterError, match="metric"):
        difference_matrix(np.zeros((2, 3)), np.zeros((2, 3)), "l7")
    with pytest.raises(DataError, match="NaN"):
        difference_matrix(np.array([[np.nan, 1.0]]), np.zeros((2, 2)))


def test_cosine_zero_vector_is_finite():
    d = difference_matrix(np.zeros((1, 3)), np.ones((2, 3)), "cosine")
    np.testing.assert_allclose(d, 1.0)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 5), st.integers(1, 9)),
              elements=st.floats(-1e3, 1e3, allow_nan=False)))
def test_normalise_rows_finite_zero_mean_unit_std(d):
    out = normalise_rows(d)
    assert np.all(np.isfinite(out))
    for row, src in zip(out, d):
        if np.ptp(src) > 1e-6 * max(1.0, np.abs(src).max()):
            assert abs(row.mean()) < 1e-6 and abs(row.std() - 1) < 1e-6
        else:
            assert np.all(np.abs(row) < 1e3)
