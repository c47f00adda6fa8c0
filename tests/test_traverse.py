import numpy as np
import pytest

from catgraph.exceptions import DataError, InvalidParameterError, ShapeMismatchError
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


def test_metric_ground_truth_counts_a_pair_at_the_threshold_once_for_both_questions():
    """correct() and has_true_match() (the recall denominator) measure the same distance:
    a match exactly at the threshold is correct *and* its frame has a true match."""
    rng = np.random.default_rng(0)
    disagree = 0
    for _ in range(2000):
        a, b = rng.uniform(-100, 100, 2), rng.uniform(-100, 100, 2)
        metres = float(np.linalg.norm(a - b))
        gt = MetricTolerance([a], [b], metres)
        disagree += int(gt.correct(np.array([0]), np.array([0]))[0] != gt.has_true_match(np.array([0]))[0])
    assert disagree == 0


def test_metric_has_true_match_equals_a_brute_force_reference():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, r = rng.uniform(0, 50, (40, 2)), rng.uniform(0, 50, (60, 2))
        qf, rf = rng.integers(0, 2, 40), rng.integers(0, 2, 60)
        metres = float(rng.uniform(1, 8))
        gt = MetricTolerance(q, r, metres, qf, rf)
        slow = [any(np.linalg.norm(q[i] - r[j]) <= metres and qf[i] == rf[j] for j in range(60)) for i in range(40)]
        np.testing.assert_array_equal(gt.has_true_match(np.arange(40)), slow)


def test_metric_ground_truth_between_a_thinned_or_repeated_query_and_its_reference():
    """Frames keep their numbers as loaded: a query at twice the speed (every other frame)
    or a subsample has indices beyond its length; the reference is read by place (row)."""
    positions = np.stack([np.arange(10) * 10.0, np.zeros(10)], axis=1)
    ref = Traverse(np.zeros((10, 2)), positions=positions)
    qry = Traverse(np.zeros((10, 2)), positions=positions + [0.5, 0.0])
    thinned = qry.take(np.arange(0, 10, 2))                       # index 0, 2, 4, 6, 8
    gt = MetricTolerance.between(thinned, ref, 1.0)
    np.testing.assert_array_equal(gt.correct(thinned.index, thinned.index), np.ones(5, bool))
    assert gt.has_true_match(thinned.index).all()
    with pytest.raises(DataError, match="query_index 3 is not a frame"):   # frame 3 is not in the query
        gt.has_true_match(np.array([3]))
    with pytest.raises(DataError, match="query_index 10 is not a frame"):
        gt.correct(np.array([10]), np.array([0]))
    repeated = Traverse(np.zeros((4, 2)), positions=positions[[0, 0, 1, 2]])  # a reference with a frame twice
    gt = MetricTolerance.between(qry, repeated, 1.0)
    np.testing.assert_array_equal(gt.correct(np.array([0, 1, 2, 3]), np.array([1, 2, 3, 3])),
                                  [True, True, True, False])
    assert not gt.has_true_match(np.array([3]))[0]  # 30 m from every place of that reference


def test_explicit_ground_truth_refuses_a_threshold_every_entry_would_meet():
    for bad in (0, 0.0, -0.5):
        with pytest.raises(InvalidParameterError, match="threshold"):
            ExplicitGroundTruth(np.eye(3), threshold=bad)
    gt = ExplicitGroundTruth.from_pairs([[0, 0], [1, 1]], 2, 2)
    with pytest.raises(DataError, match="query_index 2 is not a frame"):
        gt.has_true_match(np.array([2]))
