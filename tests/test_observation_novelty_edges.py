"""The whole-image model's novelty weight and hub levels at their edges: blank frames,
maps of two places, rows of extreme scale, the levels prepared ahead of the feedback,
and combination weights given as an array."""

import numpy as np
import pytest

from catgraph.observation import CombinedObservation, FilterFeedback, TemperedObservation


def _rows(n_frames=30, n_places=200, seed=0):
    """Normalised rows of a query driving the map one place per frame, with a few hubs."""
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(n_frames, n_places))
    rows[np.arange(n_frames), 10 + np.arange(n_frames)] -= 3.0
    rows[:, 150:154] -= 1.0
    return (rows - rows.mean(1, keepdims=True)) / rows.std(1, keepdims=True)


def _run(model, rows):
    """Every frame observed and fed back (posterior: the frame's own softmax); the
    log-ratios, new-place ratios and novelty weights per frame."""
    out = []
    for row in rows:
        o = model.observe(row)
        out.append((o.log_ratio.copy(), o.new_place_log_ratio, model.novelty_))
        p = np.exp(o.log_ratio - o.log_ratio.max())
        p /= p.sum()
        model.feedback(FilterFeedback(p, p, slice(0, 1)))
    return out


@pytest.mark.parametrize("kwargs", [{}, {"likelihood": "histogram"}, {"temperature": 0.7, "hub": None}],
                         ids=["default", "histogram", "fixed"])
def test_a_blank_frame_adds_nothing_and_leaves_the_next_frame_its_evidence(kwargs):
    """A blank frame (an all-zero normalised row) gives zero ratios; every other frame gets
    exactly what it gets without the blank frame (the next one was compared with the blank
    row, a correlation of 0/0 taken for a repeat: its evidence was wiped out)."""
    rows = _rows()
    blank = np.insert(rows, 6, 0.0, axis=0)
    plain = _run(TemperedObservation(**kwargs), rows)
    with_blank = _run(TemperedObservation(**kwargs), blank)
    assert np.all(with_blank[6][0] == 0.0) and with_blank[6][2] == 0.0
    for k, (a, b) in enumerate(zip(plain, with_blank[:6] + with_blank[7:])):
        np.testing.assert_array_equal(a[0], b[0], err_msg=f"frame {k}")
        assert a[1] == b[1] and a[2] == b[2]
    assert with_blank[7][2] > 0.5  # the frame after the blank one keeps its weight


def test_a_blank_first_frame_and_constant_rows():
    rows = _rows()
    model = TemperedObservation()
    out = _run(model, np.concatenate([np.full((2, rows.shape[1]), 3.25), rows]))
    assert out[0][2] == 0.0 and out[1][2] == 0.0
    assert out[2][2] == 1.0  # the first frame that holds a measurement
    np.testing.assert_array_equal(out[3][0], _run(TemperedObservation(), rows)[1][0])


def test_two_places_keep_their_evidence():
    """Any two frames of a two-place map correlate ±1: the weight is 1 there, not 0."""
    rng = np.random.default_rng(1)
    rows = np.stack([[-1.0, 1.0]] * 6) + 0.2 * rng.normal(size=(6, 2))
    out = _run(TemperedObservation(hub=None), rows)
    assert all(novelty == 1.0 for _, _, novelty in out)
    assert all(r[0] > r[1] for r, _, _ in out)


@pytest.mark.parametrize("scale", [1e-170, 1e-90, 1e80, 1e160])
def test_the_novelty_weight_does_not_depend_on_the_rows_scale(scale):
    """A correlation is scale-free; sums of squares that under- or overflow made the
    weight 0, 1 or NaN (from finite rows)."""
    rows = _rows(10)
    ref = [novelty for _, _, novelty in _run(TemperedObservation(hub=None, temperature=1.0), rows)]
    out = _run(TemperedObservation(hub=None, temperature=1.0), rows * scale)
    np.testing.assert_allclose([novelty for _, _, novelty in out], ref, rtol=1e-12)
    assert all(np.all(np.isfinite(r)) and np.isfinite(new) for r, new, _ in out)


def test_histogram_hub_levels_prepared_ahead_of_the_feedback_give_the_same_floats():
    """The combined model prepares a part's next hub levels on its second thread before
    the feedback (maps of 65,536 places or more, where a core is free); the histogram
    likelihood's feedback read the overwritten levels, so its answers depended on the load."""
    rows = _rows(25)

    def run(prepare):
        model, out = TemperedObservation(likelihood="histogram"), []
        for row in rows:
            o = model.observe(row)
            out.append(o.log_ratio.copy())
            if prepare:
                model._prepare_levels()
            p = np.exp(o.log_ratio - o.log_ratio.max())
            p /= p.sum()
            model.feedback(FilterFeedback(p, p, slice(0, 1)))
        return np.array(out)

    np.testing.assert_array_equal(run(True), run(False))


def test_combination_weights_may_be_an_array():
    rows = _rows(5)
    a = CombinedObservation([TemperedObservation(), TemperedObservation(hub=None)], weights=np.array([1.0, 0.5]))
    b = CombinedObservation([TemperedObservation(), TemperedObservation(hub=None)], weights=(1.0, 0.5))
    for row in rows:
        np.testing.assert_array_equal(a.observe(row).log_ratio, b.observe(row).log_ratio)


def test_combined_feedback_counts_one_answer_per_frame_and_reads_slices_as_numpy():
    rows = _rows(12)

    def run(twice, near):
        model = CombinedObservation([TemperedObservation(), TemperedObservation(hub=None)])
        for k, row in enumerate(rows):
            o = model.observe(row)
            p = np.exp(o.log_ratio - o.log_ratio.max())
            p /= p.sum()
            for _ in range(2 if twice else 1):
                model.feedback(FilterFeedback(p, p, near(k)))
        return model.reliability_

    around = lambda k: slice(8 + k, 13 + k)  # noqa: E731  (the true place is 10 + k)
    np.testing.assert_array_equal(run(True, around), run(False, around))
    # None and negative bounds as numpy reads them: the same places, the same answer
    np.testing.assert_array_equal(run(False, lambda k: slice(None, 13 + k)), run(False, lambda k: slice(0, 13 + k)))
    np.testing.assert_array_equal(run(False, lambda k: slice(8 + k - 200, None)), run(False, lambda k: slice(8 + k, 200)))


def test_parameter_errors_name_the_parameter_and_come_first():
    from catgraph.exceptions import InvalidParameterError, ShapeMismatchError
    from catgraph.observation import HistogramObservation

    row = _rows(1)[0]
    with pytest.raises(ShapeMismatchError, match="'hub' levels of TemperedObservation hold 5 values"):
        TemperedObservation(hub=np.zeros(5)).observe(row)
    for bad in (0, -3, 2.5):
        with pytest.raises(InvalidParameterError, match="'new_place_samples' parameter of HistogramObservation"):
            HistogramObservation(new_place_samples=bad).observe(row)  # the first frame, not after n_init
    with pytest.raises(InvalidParameterError, match="novelty_cap"):
        TemperedObservation(novelty_cap=0).observe(row)  # it silenced every frame after the first
