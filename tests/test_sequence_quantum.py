"""The matcher's quantum: blank leading frames leave it unfixed, and values clipped at the
largest code are reported (the precision policy of :mod:`catgraph.sequence`)."""

import warnings

import numpy as np
import pytest

from catgraph.exceptions import CatgraphWarning
from catgraph.sequence import SequenceMatcher, fixed_window_scores, match_sequences


def _rows(rng, n_frames=60, n_places=300, depth=10.0):
    """Normalised-looking rows whose true place (and a decoy) reach about −depth."""
    d = rng.normal(size=(n_frames, n_places))
    d[np.arange(n_frames), 20 + np.arange(n_frames)] -= depth
    d[np.arange(n_frames), 200 + np.arange(n_frames) % 50] -= depth - 0.5
    return d


def _slow_scores(d, window):
    """Window means along the diagonal in float64 (the row's mean where the line leaves the map)."""
    n_q, n = d.shape
    out = np.empty(d.shape)
    for i in range(n_q):
        eff = min(window, i + 1)
        total = np.zeros(n)
        for t in range(i - eff + 1, i + 1):
            col = np.arange(n) - (i - t)
            total += np.where(col >= 0, d[t, np.clip(col, 0, n - 1)], d[t].mean())
        out[i] = total / eff
    return out


@pytest.mark.parametrize("blank_frames", [0, 1, 3])
def test_blank_leading_frames_leave_the_quantum_to_the_first_informative_one(rng, blank_frames):
    """A blank first frame (zeros once normalised) fixed the quantum 2^-12: every later
    difference beyond ±8 saturated and the scores were off by more than 2."""
    d = _rows(rng)
    d[:blank_frames] = 0.0
    for window in (1, 5):
        got, want = fixed_window_scores(d, window), _slow_scores(d, window)
        u = 2.0 ** (int(np.frexp(np.abs(d[blank_frames]).max())[1]) - 12)
        assert np.abs(got - want).max() <= u
    with warnings.catch_warnings():
        warnings.simplefilter("error", CatgraphWarning)  # nothing clipped
        batch = match_sequences(d, window=5)
    stream = SequenceMatcher(window=5)
    steps = [stream.step(row) for row in d]
    assert np.array_equal(batch.match, [s.match for s in steps])
    assert np.array_equal(batch.score, [s.score for s in steps])
    assert np.all(batch.match[:blank_frames] == -1)
    # where the float64 scores leave no doubt, the matcher's best place is theirs
    want = _slow_scores(d, 5)[blank_frames:]
    top2 = np.sort(want, axis=1)[:, :2]
    clear = top2[:, 1] - top2[:, 0] > 2.0 ** -8
    assert clear.sum() > 40
    assert np.array_equal(batch.match[blank_frames:][clear], want.argmin(1)[clear])


def test_values_clipped_at_the_largest_code_are_reported(rng):
    """Rows not normalised per query, whose first is far smaller than the rest: later
    values saturate (the documented policy), now with a warning, once per query."""
    d = 100.0 + 20.0 * rng.normal(size=(40, 200))
    d[0] = 1e-3 * rng.normal(size=200)
    with pytest.warns(CatgraphWarning, match="clipped"):
        match_sequences(d, window=5)
    matcher = SequenceMatcher(window=5)
    with pytest.warns(CatgraphWarning, match="clipped") as record:
        for row in d:
            matcher.step(row)
    assert len([w for w in record if issubclass(w.category, CatgraphWarning)]) == 1
    matcher.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("error", CatgraphWarning)
        for row in d[1:]:  # a first row of the query's own scale: nothing clipped
            matcher.step(row)


def test_fixed_window_scores_take_the_matchers_velocity_range(rng):
    """A velocity beyond ±MAX_VELOCITY (the others' limit) overflowed the line positions."""
    from catgraph.exceptions import InvalidParameterError
    from catgraph.sequence import MAX_VELOCITY

    d = rng.normal(size=(5, 20))
    fixed_window_scores(d, 3, -MAX_VELOCITY)
    for v in (MAX_VELOCITY * 1.5, 5e18, -1e300):
        with pytest.raises(InvalidParameterError, match="velocity"):
            fixed_window_scores(d, 3, v)


def test_a_nan_in_one_row_is_named_by_its_index(rng):
    from catgraph.exceptions import DataError

    row = rng.normal(size=10)
    row[3] = np.nan
    with pytest.raises(DataError, match=r"holds 1 NaN or infinite values \(first at index 3\)"):
        SequenceMatcher(window=3).step(row)
