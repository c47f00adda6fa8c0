import numpy as np
import pytest

from catgraph.metrics import auc, evaluate, max_time_to_localisation, pr_curve, recall_at_precision
from catgraph.traverse import ExplicitGroundTruth, FrameTolerance


def test_pr_curve_hand_computed():
    # confidences 0.9 (correct), 0.8 (wrong), 0.7 (correct), no output, 4 positives
    correct = np.array([True, False, True, False])
    has_output = np.array([True, True, True, False])
    conf = np.array([0.9, 0.8, 0.7, np.nan])
    curve = pr_curve(correct, has_output, conf, n_positive=4)
    np.testing.assert_allclose(curve.thresholds, [0.9, 0.8, 0.7])
    np.testing.assert_allclose(curve.precision, [1.0, 0.5, 2 / 3])
    np.testing.assert_allclose(curve.recall, [0.25, 0.25, 0.5])
    # trapezoid from (0, 1): 0.25*1 + 0 + 0.25*(0.5+2/3)/2
    assert auc(curve) == pytest.approx(0.25 + 0.25 * (0.5 + 2 / 3) / 2)
    assert recall_at_precision(curve, 1.0) == 0.25
    assert recall_at_precision(curve, 0.6) == 0.5
    assert recall_at_precision(curve, 0.99) == 0.25


def test_ties_enter_together_whatever_the_order():
    correct = np.array([False, True, True])
    conf = np.array([0.5, 0.5, 0.2])
    a = pr_curve(correct, np.ones(3, bool), conf, 3)
    b = pr_curve(correct[[1, 0, 2]], np.ones(3, bool), conf[[1, 0, 2]], 3)
    np.testing.assert_allclose(a.precision, [0.5, 2 / 3])
    np.testing.assert_allclose(a.precision, b.precision)
    np.testing.assert_allclose(a.recall, b.recall)
    assert recall_at_precision(a, 1.0) == 0.0


def test_mtl_counts_frames_without_output_and_runs():
    assert max_time_to_localisation(np.array([True, False, False, True, False])) == 2
    assert max_time_to_localisation(np.array([False, False, False])) == 3
    assert max_time_to_localisation(np.array([True, True])) == 0
    assert max_time_to_localisation(np.array([], bool)) == 0
    assert max_time_to_localisation(np.array([False, True, False, False, False])) == 3


def test_evaluate_end_to_end_frame_tolerance():
    gt = FrameTolerance(n_reference=10, tolerance=1)
    q = np.array([0, 1, 2, 3, 4])
    match = np.array([1, 5, -1, 3, 9])  # correct, wrong, none, correct, wrong
    conf = np.array([0.9, 0.95, 0.0, 0.5, 0.1])
    ev = evaluate(q, match, conf, gt)
    np.testing.assert_array_equal(ev.correct, [True, False, False, True, False])
    m = ev.metrics
    assert m.n_queries == 5
    assert m.accuracy == pytest.approx(2 / 5)
    assert m.mtl == 2
    # sorted: .95 wrong, .9 right, .5 right, .1 wrong -> precision 0, .5, 2/3, .5 ; recall 0, .2, .4, .4
    np.testing.assert_allclose(ev.curve.precision, [0, 0.5, 2 / 3, 0.5])
    np.testing.assert_allclose(ev.curve.recall, [0, 0.2, 0.4, 0.4])
    assert m.recall_at_100p == 0.0
    assert m.recall_at_90p == 0.0
    assert m.auc == pytest.approx(0.2 * 0.25 + 0.2 * (0.5 + 2 / 3) / 2)


def test_recall_denominator_excludes_frames_without_true_match():
    gt = ExplicitGroundTruth.from_pairs([[0, 0], [1, 1]], n_query=3, n_reference=3)  # query 2 is a new place
    ev = evaluate(np.array([0, 1, 2]), np.array([0, 1, 2]), np.array([3.0, 2.0, 1.0]), gt)
    assert ev.metrics.accuracy == 1.0
    assert ev.metrics.recall_at_100p == 1.0
    assert ev.metrics.mtl == 1


def test_all_frames_without_output():
    ev = evaluate(np.arange(3), np.full(3, -1), np.zeros(3), FrameTolerance(3, 0))
    assert ev.metrics.auc == 0.0 and ev.metrics.mtl == 3 and ev.metrics.accuracy == 0.0


def test_nan_confidence_with_output_is_an_error():
    with pytest.raises(ValueError, match="finite"):
        evaluate(np.arange(2), np.arange(2), np.array([np.nan, 1.0]), FrameTolerance(2, 0))


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="one length"):
        evaluate(np.arange(3), np.arange(2), np.zeros(3), FrameTolerance(3, 0))


def test_evaluate_checks_its_inputs():
    from catgraph.exceptions import DataError

    gt = FrameTolerance(5, tolerance=0)
    q = np.arange(4)
    ok = evaluate(q.astype(float), [0, 1, -1, 3], [0.9, 0.8, np.nan, 0.1], gt)
    assert ok.metrics.accuracy == 0.75  # whole-number floats are indices; no-output confidence is never read
    for match, message in (([0, 1, -2, 3], "below -1"), ([0, 1, 2, 5], "reference has 5")):
        with pytest.raises(DataError, match=message):
            evaluate(q, match, np.ones(4), gt)
    with pytest.raises(DataError, match="whole-number"):
        evaluate(q + 0.5, [0, 1, 2, 3], np.ones(4), gt)
    with pytest.raises(DataError, match="NaN or infinite confidence"):
        evaluate(q, [0, 1, 2, 3], [1.0, np.inf, 0.5, 0.2], gt)
    with pytest.raises(DataError, match="complex"):
        evaluate(q, [0, 1, 2, 3], np.ones(4, dtype=complex), gt)


def test_pr_curve_refuses_fewer_positives_than_correct_frames():
    from catgraph.exceptions import DataError

    with pytest.raises(DataError, match="n_positive"):
        pr_curve([True, True], [True, True], [0.5, 0.4], 1)


def test_every_ground_truth_refuses_a_match_past_the_reference():
    """A match past the reference's last place is an error for every kind of ground truth
    (it was refused by the frame tolerance and silently scored wrong by the others)."""
    from catgraph.exceptions import DataError
    from catgraph.traverse import MetricTolerance

    positions = np.array([[0.0, 0.0], [1.0, 0.0]])
    for gt in (FrameTolerance(2, 0), MetricTolerance(positions, positions, 0.5), ExplicitGroundTruth(np.eye(2, dtype=bool))):
        assert evaluate([0, 1], [0, 1], [1.0, 0.5], gt).metrics.accuracy == 1.0
        with pytest.raises(DataError, match="reference has 2 places"):
            evaluate([0, 1], [0, 7], [1.0, 0.5], gt)


def test_floors_of_the_wrong_length_are_refused():
    from catgraph.exceptions import ShapeMismatchError
    from catgraph.traverse import MetricTolerance

    qp, rp = np.zeros((1, 2)), np.zeros((2, 2))
    with pytest.raises(ShapeMismatchError, match="reference floors"):
        MetricTolerance(qp, rp, 5.0, query_floors=[3], reference_floors=[3])
    with pytest.raises(ShapeMismatchError, match="query floors"):
        MetricTolerance(qp, rp, 5.0, query_floors=[3, 3], reference_floors=[3, 3])
    assert MetricTolerance(qp, rp, 5.0, query_floors=[3], reference_floors=[3, 4]).correct([0], [0])[0]


def test_a_ground_truth_no_frame_matches_warns():
    """Every figure 0 because no frame has a true match (e.g. a slice of the query, which
    keeps its frame numbers, against a reference numbered from 0) is said, not silent."""
    import warnings

    from catgraph.exceptions import CatgraphWarning

    gt = FrameTolerance(300, 2)
    with pytest.warns(CatgraphWarning, match="none of the 3 query frames has a true match"):
        ev = evaluate([1000, 1001, 1002], [0, 1, 2], [1.0, 0.5, 0.2], gt)
    assert ev.metrics.auc == 0.0 and ev.metrics.mtl == 3
    with warnings.catch_warnings():
        warnings.simplefilter("error", CatgraphWarning)
        evaluate([0, 1, 2], [0, 1, 2], [1.0, 0.5, 0.2], gt)
        evaluate([], [], [], gt)  # nothing to evaluate: nothing to say


def test_precision_is_a_fraction():
    curve = pr_curve(np.array([True, False]), np.array([True, True]), np.array([1.0, 0.5]), 1)
    assert recall_at_precision(curve, 1.0) == 1.0 and recall_at_precision(curve, np.float32(0.9)) == 1.0
    from catgraph.exceptions import InvalidParameterError

    for bad in (99, 0.0, -0.5, float("nan"), True, "0.9"):
        with pytest.raises(InvalidParameterError, match="fraction"):
            recall_at_precision(curve, bad)
