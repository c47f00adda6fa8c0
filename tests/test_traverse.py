import numpy as np
import pytest

from catgraph.exceptions import DataError, ShapeMismatchError
from catgraph.traverse import ExplicitGroundTruth, FrameTolerance, MetricTolerance, Traverse, shuffle_segments


def test_shuffle_is_seeded_and_a_permutation_of_contiguous_segments():
    t = Traverse(np.arange(200, dtype=float)[:, None], positions=np.c_[np.arange(200.0), np.zeros(200)])
    a, b = shuffle_segments(t, seed=3), shuffle_segments(t, seed=3)
    np.testing.assert_array_equal(a.index, b.index)
    assert not np.array_equal(a.index, np.arange(200))
    np.testing.assert_array_equal(np.sort(a.index), np.arange(200))
    # frames and positions travel with their index
    np.testing.assert_array_equal(a.frames[:, 0], a.index)
    np.testing.assert_array_equal(a.positions[:, 0], a.index)
    lengths = [stop - start for start, stop in a.meta["segments"]]
    assert sum(lengths) == 200
    assert all(1 <= n <= 40 for n in lengths)  # at most 20 %
    assert max(lengths[:-1] + [0]) >= 4 or len(lengths) < 50
    for start, stop in a.meta["segments"]:
        assert stop > start
    assert not np.array_equal(shuffle_segments(t, seed=4).index, a.index)


def test_traverse_rejects_nan_and_mismatched_metadata():
    with pytest.raises(DataError, match="NaN"):
        Traverse(np.array([[0.0, np.nan]]))
    with pytest.raises(ShapeMismatchError, match="positions"):
        Traverse(np.zeros((3, 2)), positions=np.zeros((2, 2)))
    with pytest.raises(DataError, match="empty"):
        Traverse(np.zeros((0, 4)))


def test_frame_tolerance_edges():
    gt = FrameTolerance(n_reference=5, tolerance=1)
    np.testing.assert_array_equal(gt.correct(np.array([0, 4, 4, 2]), np.array([1, 5, -1, 0])),
                                  [True, False, False, False])
    np.testing.assert_array_equal(gt.has_true_match(np.array([0, 5, 6])), [True, True, False])


def test_metric_tolerance_uses_floors_and_loaded_order():
    ref = Traverse(np.zeros((3, 1)), positions=[[0, 0], [10, 0], [20, 0]], floors=[0, 0, 1])
    qry = Traverse(np.zeros((3, 1)), positions=[[1, 0], [20, 0], [50, 0]], floors=[0, 0, 0])
    gt = MetricTolerance.between(shuffle_segments(qry, seed=1, min_fraction=0.3, max_fraction=0.4), ref, 2.0)
    np.testing.assert_array_equal(gt.correct(np.array([0, 0, 1]), np.array([0, 1, 2])), [True, False, False])
    np.testing.assert_array_equal(gt.has_true_match(np.array([0, 1, 2])), [True, False, False])


def test_explicit_soft_matrix_threshold():
    soft = np.array([[0.9, 0.2], [0.0, 0.6]])
    gt = ExplicitGroundTruth(soft, threshold=0.5)
    np.testing.assert_array_equal(gt.correct(np.array([0, 0, 1]), np.array([0, 1, 1])), [True, False, True])
    with pytest.raises(DataError, match="pairs"):
        ExplicitGroundTruth.from_pairs([[0, 9]], 2, 2)
