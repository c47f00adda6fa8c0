"""The sequence part's ``temperature="longest"``: each frame's ratios scaled by one over the
longest window the matcher has chosen so far, checked against a plain reference built
from a twin model at temperature 1 and the windows it chose."""

from __future__ import annotations

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.observation import SequenceObservation


def _rows(n_frames: int, n_places: int, seed: int) -> np.ndarray:
    """A query that follows the route for a while, jumps, and follows it again: the
    adaptive window grows, shrinks after the jump and grows again."""
    rng = np.random.default_rng(seed)
    truth = np.concatenate([np.arange(10, 10 + n_frames // 2), np.arange(200, 200 + n_frames - n_frames // 2)])
    d = rng.normal(size=(n_frames, n_places))
    d[np.arange(n_frames), truth] -= 2.5
    return (d - d.mean(1, keepdims=True)) / d.std(1, keepdims=True)


def _model(temperature, calibration="agreement"):
    return SequenceObservation(window="adaptive", matcher_params={"l_min": 2, "l_max": 40},
                               calibration=calibration, temperature=temperature, agreement_scale=1.0)


@pytest.mark.parametrize("calibration", ["agreement", "online"])
def test_longest_is_one_over_the_running_maximum_of_the_window(calibration):
    d = _rows(120, 300, 0)
    fast, plain = _model("longest", calibration), _model(1.0, calibration)
    longest, lengths, grew_then_shrank = 0, [], False
    for row in d:
        a, b = fast.observe(row), plain.observe(row)
        length = int(plain.last_match_.window_length)
        assert int(fast.last_match_.window_length) == length  # the temperature does not steer the matcher
        lengths.append(length)
        longest = max(longest, length)
        grew_then_shrank |= length < longest
        assert a.informative == b.informative
        if not b.informative:
            continue
        want = np.asarray(b.log_ratio) / longest
        np.testing.assert_allclose(a.log_ratio, want, rtol=1e-12, atol=1e-15)
        # agreement: the new place is a place drawn from the map (log mean e^r of the scaled
        # ratios); online: the histograms' ratio, scaled like every other
        new = (np.log(np.mean(np.exp(want))) if calibration == "agreement"
               else b.new_place_log_ratio / longest)
        np.testing.assert_allclose(a.new_place_log_ratio, new, rtol=1e-9, atol=1e-12)
    # the case "longest" is for: the window shortened after having been longer
    assert grew_then_shrank and len(set(lengths)) > 2


def test_longest_differs_from_window_where_the_window_shrinks_and_resets():
    d = _rows(120, 300, 1)
    model, window = _model("longest"), _model("window")
    differ = 0
    for row in d:
        a, b = model.observe(row), window.observe(row)
        differ += not np.allclose(a.log_ratio, b.log_ratio)
    assert differ > 0
    model.reset()  # the running maximum starts afresh: the values of a fresh model
    again = [model.observe(row).log_ratio.copy() for row in d[:5]]
    fresh = _model("longest")
    for row, y in zip(d[:5], again):
        np.testing.assert_array_equal(fresh.observe(row).log_ratio, y)


def test_same_input_same_output():
    d = _rows(60, 300, 2)
    runs = []
    for _ in range(2):
        model = _model("longest")
        runs.append([model.observe(row).log_ratio.copy() for row in d])
    for x, y in zip(*runs):
        np.testing.assert_array_equal(x, y)


def test_unknown_temperature_is_refused():
    with pytest.raises(InvalidParameterError, match="temperature"):
        _model("shortest").observe(np.zeros(50))
