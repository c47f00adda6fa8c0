"""The tempered model's novelty weight on repeated frames: a frame shown twice is one
measurement, so a query with every frame repeated weighs its frames as the query shown once."""

import numpy as np
import pytest

from catgraph.observation import DUPLICATE_TOLERANCE, TemperedObservation
from tests.test_likelihood import _SlowTempered, step_both_tempered


def _weights(rows):
    m = TemperedObservation(hub=None, temperature=1.0)
    out = []
    for row in rows:
        m.observe(row)
        out.append(m.novelty_)
    return np.array(out)


def _correlated_rows(rng, n_frames, n_places, keep=0.8):
    rows = [rng.standard_normal(n_places)]
    for _ in range(n_frames - 1):
        rows.append(keep * rows[-1] + np.sqrt(1 - keep ** 2) * rng.standard_normal(n_places))
    return np.array(rows)


@pytest.mark.parametrize("repeat", [2, 3])
def test_repeated_frames_get_the_weights_of_the_query_shown_once(repeat):
    rng = np.random.default_rng(0)
    rows = _correlated_rows(rng, 60, 120)
    once = _weights(rows)
    slow = _weights(np.repeat(rows, repeat, axis=0))
    np.testing.assert_array_equal(slow[::repeat], once)  # the first showing of each frame: the same weight
    for r in range(1, repeat):
        assert np.all(slow[r::repeat] == 0.0)  # the repeats: none
    assert 0.5 < once[1:].mean() < 1.5  # the weights of new frames average about one


def test_near_repeats_still_count_in_the_typical_change():
    """Only exact repeats are left out: a frame that differs from its predecessor by more
    than the tolerance is a measurement, however similar."""
    rng = np.random.default_rng(1)
    rows = _correlated_rows(rng, 40, 100)
    near = rows.copy()
    near[1::2] = rows[::2] + 1e-3 * rng.standard_normal((20, 100))  # almost the previous frame
    w = _weights(near)
    assert np.all(w[1::2] > 0.0)
    assert 1.0 - DUPLICATE_TOLERANCE < 1.0


def test_fast_model_equals_plain_formulas_with_repeated_frames():
    rng = np.random.default_rng(2)
    n = 101
    fast, slow = TemperedObservation(), _SlowTempered()
    rows = np.repeat(_correlated_rows(rng, 15, n), 2, axis=0)
    rows[0] = rows[1] = rows[2]  # a repeat from the very start
    for k, row in enumerate(rows):
        step_both_tempered(fast, slow, row, rng, k)
