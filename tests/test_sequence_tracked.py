"""Rule "tracked": the window chosen by a grid filter's place posterior (catgraph._window_rule._Tracker)."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.hubs import hub_offsets
from catgraph.observation import TemperedObservation
from catgraph.sequence import (DEFAULT_CONFIDENCE, DEFAULT_LINE_RULE, DEFAULT_RULE, SequenceMatcher,
                               match_sequences, window_grid)

TRACK_PLACES = 1  # the rule's neighbourhood, stated here again as the reference reads it


def _route(seed: int = 0, n_places: int = 120, n_query: int = 70, jump_at: int = 40):
    """A query along the reference at +1 place a frame that jumps once, with noise."""
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(n_places, 16))
    places = np.r_[np.arange(10, 10 + jump_at), np.arange(80, 80 + n_query - jump_at)]
    query = ref[places] + 0.8 * rng.normal(size=(n_query, 16))
    d = np.abs(query[:, None, :] - ref[None, :, :]).sum(axis=2)
    d = (d - d.mean(axis=1, keepdims=True)) / d.std(axis=1, keepdims=True)
    return d, ref


def _reference_rule(d: np.ndarray, l_min: int, l_max: int, grid):
    """The rule from its definition, one velocity (+1): each candidate length's best place
    from the library's fixed-window matcher; an independent filter's posterior summed near
    each; the longest length of the largest mass; confidence its log-odds."""
    lengths = window_grid(l_min, l_max, grid)
    best = np.stack([match_sequences(d, window=int(L), velocities=(1.0,)).match for L in lengths], axis=1)
    # the registry's default filter method, as the grid: its model, the long-run jump velocity, the
    # velocity prior's odds on ±1 (half the prior) and, on a map this small (at most 10,000 places),
    # the rigid line beside its motion, and outlier frames at 1 %; its velocity bins the matcher's
    # velocities (here +1 alone, so the prior has no other velocity to favour ±1 against)
    filt = GridLocalizer(PlaceGraph.chain(d.shape[1]), TemperedObservation(), velocities=(1.0,),
                         jump_velocity="long-run", rigid_prior=0.05, home_speed_odds=1.0, outlier_probability=0.01)
    match, conf, length = [], [], []
    for t, row in enumerate(d):
        filt.step(row)
        post = filt.place_posterior_
        mass = np.array([post[max(j - TRACK_PLACES, 0):j + TRACK_PLACES + 1].sum() for j in best[t]])
        g = max(k for k in range(len(lengths)) if mass[k] == mass.max())
        match.append(best[t, g])
        conf.append(np.log(mass[g]) - np.log1p(-mass[g]))
        length.append(min(int(lengths[g]), t + 1))
    return np.array(match), np.array(conf), np.array(length)


def test_tracked_is_the_default_rule():
    assert DEFAULT_RULE == "tracked"


def test_tracked_filter_has_the_matchers_velocities_as_its_bins():
    from catgraph.grid import DEFAULT_VELOCITIES
    from catgraph.methods import HOME_SPEED_ODDS

    d, _ = _route()
    for velocities in (None, (-1.0, 1.0, 1.5)):
        m = SequenceMatcher(window="adaptive", rule="tracked", l_min=3, l_max=40, grid=6,
                            **({} if velocities is None else {"velocities": velocities}))
        for row in d[:3]:
            m.step(row)
        filt = m._record.tracker.filter
        assert filt.velocities == tuple(DEFAULT_VELOCITIES if velocities is None else velocities)
    assert match_sequences(d[:5], rule="tracked", l_min=3, l_max=40, grid=6) is not None
    assert HOME_SPEED_ODDS == 3.0  # the eight velocities' odds: ±1 half the prior


def test_tracked_rule_matches_its_definition():
    d, _ = _route()
    kw = dict(l_min=3, l_max=40, grid=6)
    r = match_sequences(d, rule="tracked", velocities=(1.0,), **kw)
    match, conf, length = _reference_rule(d, **kw)
    np.testing.assert_array_equal(r.match, match)
    np.testing.assert_array_equal(r.window_length, length)
    np.testing.assert_allclose(r.confidence, conf, rtol=1e-9, atol=1e-9)
    # after the jump the filter moves the window to the new stretch: late frames answer right
    truth = np.r_[np.arange(10, 50), np.arange(80, 110)]
    assert np.mean(np.abs(r.match[50:] - truth[50:]) <= 2) > 0.9


@pytest.mark.parametrize("threaded", [False, True])
def test_tracked_streaming_is_batch_bit_for_bit(monkeypatch, threaded):
    if threaded:  # the kernels on two threads, the filter stepped beside them on the calling one
        from catgraph import _sequence_kernels

        monkeypatch.setattr(_sequence_kernels, "WORK_PER_THREAD", 1)
    d, ref = _route(seed=1)
    offsets = hub_offsets(np.abs(ref[:, None, :] - ref[None, :, :]).sum(axis=2))
    kw = dict(rule="tracked", l_min=3, l_max=40, grid=8, hub_offsets=offsets)
    batch = match_sequences(d, **kw)
    matcher = SequenceMatcher(**kw)
    steps = [matcher.step(row) for row in d]
    np.testing.assert_array_equal(batch.match, [s.match for s in steps])
    np.testing.assert_array_equal(batch.confidence, [s.confidence for s in steps])
    np.testing.assert_array_equal(batch.window_length, [s.window_length for s in steps])
    np.testing.assert_array_equal(batch.velocity, [s.velocity for s in steps])
    # a reset starts a new filter: the same answers again
    matcher.reset()
    again = [matcher.step(row) for row in d]
    np.testing.assert_array_equal([s.confidence for s in again], [s.confidence for s in steps])


def test_tracked_confidence_is_finite_and_rises_on_the_track():
    d, _ = _route(seed=2)
    r = match_sequences(d, rule="tracked", l_min=3, l_max=40)
    assert np.all(np.isfinite(r.confidence))
    assert np.median(r.confidence[25:38]) > np.median(r.confidence[:3])


def test_confidence_left_unset_is_the_rules_own():
    d, _ = _route(seed=3)
    kw = dict(l_min=3, l_max=40, grid=6)
    line = match_sequences(d, rule=DEFAULT_LINE_RULE, **kw)
    named = match_sequences(d, rule=DEFAULT_LINE_RULE, confidence=DEFAULT_CONFIDENCE, **kw)
    np.testing.assert_array_equal(line.confidence, named.confidence)
    default = match_sequences(d, **kw)  # rule "tracked"
    np.testing.assert_array_equal(match_sequences(d, rule="tracked", confidence="tracked", **kw).confidence,
                                  default.confidence)
    assert not np.array_equal(default.confidence, line.confidence)


@pytest.mark.parametrize("kwargs", [dict(rule="tracked", confidence="gap"), dict(rule="challenged", confidence="tracked"),
                                    dict(confidence="changepoint"), dict(rule="tracked", confidence="tracked", window=5)])
def test_tracked_rule_and_confidence_go_together(kwargs):
    d, _ = _route()
    with pytest.raises(InvalidParameterError, match="tracked"):
        match_sequences(d, **kwargs)
    with pytest.raises(InvalidParameterError, match="tracked"):
        SequenceMatcher(**kwargs).step(d[0])
