"""Frames that come again (``GridLocalizer(repeat_prior=q)``): from the first frame equal
to the one before, the filter runs a twin that stands still through every such run (it
advances on new frames only) beside itself, which moves on, and answers with the mixture
of the two, each weighed by its evidence frame by frame from the prior ``q``. Checked as
two plain filters composed by Bayes' rule — the query as it comes, and the query without
its repeats — whose frame evidence is checked against the dense-matrix Bayes filter of
``test_grid_rigid``."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer

from .test_grid_hazard import SETTINGS, _Float64, _Ratios, _rows
from .test_grid_jump_velocity import _General
from .test_grid_rigid import PRIOR, RECOVERY, _reference

RUNS = [0, 0, 3, 0, 1, 0, 0, 0, 2, 0, 0, 4, 0, 0, 0, 0, 1]


def _with_repeats(rows, runs):
    """``rows`` with row ``k`` shown ``1 + runs[k]`` times (in order)."""
    return np.repeat(rows, 1 + np.asarray(runs), axis=0)


def composed_by_bayes(loc, moved, still, rows, q):
    """Step ``loc`` (``repeat_prior = q``) and two plain filters through ``rows`` — ``moved``
    on every frame, ``still`` on the frames that are not repeats — checking, frame by frame,
    that ``loc`` answers with their mixture weighed by ``q`` and then by each frame's evidence
    where both advanced (from the first repeat on; before it, ``moved``'s answer). Yields
    ``(repeat, forked)`` after each frame's checks."""
    log_odds = math.log(q / (1 - q)) if q < 1 else math.inf
    forked = False
    for t, row in enumerate(rows):
        repeat = t > 0 and np.array_equal(row, rows[t - 1])
        forked |= repeat
        est = loc.step(row)
        moved.step(row)
        if not repeat:
            still.step(row)
            log_odds += still.frame_log_evidence_ - moved.frame_log_evidence_
        if not forked:
            posterior, p_new = moved.place_posterior_, moved.new_place_probability_
        else:
            w = 1.0 if log_odds == math.inf else 1.0 / (1.0 + math.exp(-log_odds))
            posterior = w * still.place_posterior_ + (1 - w) * moved.place_posterior_
            p_new = w * still.new_place_probability_ + (1 - w) * moved.new_place_probability_
            assert loc.repeat_log_odds_ == pytest.approx(log_odds, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(loc.place_posterior_, posterior, rtol=1e-9, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-9, abs=1e-15)
        assert est.place == int(np.argmax(posterior))
        yield repeat, forked
    assert forked


def answers_as_without_repeats(held, plain, base, runs=(0, 2, 0, 0, 5, 0, 1, 0, 0, 0, 3, 0, 0, 0, 0, 0, 2)):
    """Check that ``held`` (``repeat_prior = 1``), given ``base`` with row ``k`` shown
    ``1 + runs[k]`` times, answers every frame as ``plain`` answers its row on ``base``."""
    answers = [plain.step(row) for row in base]
    for i, row in enumerate(base):
        for _ in range(1 + runs[i]):
            est = held.step(row)
            assert est.place == answers[i].place
            assert est.confidence == pytest.approx(answers[i].confidence, rel=1e-9, abs=1e-15)
            assert est.new_place_probability == pytest.approx(answers[i].new_place_probability, rel=1e-9, abs=1e-15)


def _filter(kind, q, learn, rigid=True, n=11, jump_velocity="current"):
    extra = {"rigid_prior": PRIOR} if rigid else {}
    return kind(PlaceGraph.chain(n), _Ratios(), recovery=RECOVERY, learn_recovery=learn, jump_velocity=jump_velocity,
                repeat_prior=q, **extra, **SETTINGS).reset()


@pytest.mark.parametrize("rigid", [True, False])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_frame_evidence_equals_dense_reference(kind, learn, rigid):
    rows = _rows(11, 17, seed=5)
    loc = _filter(kind, 0.0, learn, rigid)
    for row, (*_, evidence) in zip(rows, _reference(rows, learn, "current", rigid=rigid, with_evidence=True)):
        loc.step(row)
        assert loc.frame_log_evidence_ == pytest.approx(evidence, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("jump_velocity", ["current", "long-run"])
@pytest.mark.parametrize("rigid", [True, False])
@pytest.mark.parametrize("q", [0.5, 0.2, 0.9, 1.0])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_repeats_are_two_filters_weighed_by_their_evidence(kind, learn, q, rigid, jump_velocity, monkeypatch):
    """The filter with ``repeat_prior = q`` against two plain filters: one on the frames as
    they come (the robot moved on), one on the frames without their repeats (it stood
    still), each repeat answered by the latter with its run's first frame's posterior;
    from the first repeat on the answer is their mixture, weighed by ``q`` and then by each
    frame's evidence where both advanced (the twin kept throughout: never agreeing)."""
    monkeypatch.setattr(GridLocalizer, "TWIN_AGREEMENT", -1.0)
    base = _rows(11, 17, seed=5)
    rows = _with_repeats(base, RUNS)
    loc = _filter(kind, q, learn, rigid, jump_velocity=jump_velocity)
    moved = _filter(kind, 0.0, learn, rigid, jump_velocity=jump_velocity)
    still = _filter(kind, 0.0, learn, rigid, jump_velocity=jump_velocity)
    for _ in composed_by_bayes(loc, moved, still, rows, q):
        pass


@pytest.mark.parametrize("kind", [_Float64, _General])
def test_standing_still_for_certain_is_the_query_without_its_repeats(kind):
    """``q = 1``: the robot stood still through every run, so the answers are the filter's
    on the frames without their repeats, each repeat answered as its run's first frame."""
    answers_as_without_repeats(_filter(kind, 1.0, True), _filter(kind, 0.0, True), _rows(11, 17, seed=7))


@pytest.mark.parametrize("kind", [_Float64, _General])
def test_the_twin_goes_once_the_two_agree_and_comes_back_at_the_next_repeat(kind, monkeypatch):
    """Frames that place the robot beyond doubt make the two posteriors one: the twin is
    dropped (the answers those of the filter that keeps it, to round-off), its evidence
    kept in the log-odds, and the next repeat forks it anew."""
    n = 200
    rows = np.full((n, n), 30.0)
    rows[np.arange(n), np.arange(n)] = 0.0  # each frame is one place, beyond doubt
    runs = np.zeros(n, dtype=int)
    runs[[1, 180]] = (2, 1)
    rows = _with_repeats(rows, runs)
    monkeypatch.setattr(GridLocalizer, "TWIN_AGREEMENT", -1.0)
    kept = _filter(kind, 0.5, False, rigid=False, n=n)
    keeping = [kept.step(row) for row in rows]
    monkeypatch.undo()
    loc = _filter(kind, 0.5, False, rigid=False, n=n)
    twins = []
    for row, other in zip(rows, keeping):
        est = loc.step(row)
        twins.append(loc._twin is not None)
        assert est.place == other.place
        assert est.confidence == pytest.approx(other.confidence, rel=1e-9, abs=1e-12)
    assert twins[2] and not twins[150] and twins[183] and not twins[1]  # forked, dropped, forked again
    assert loc.repeat_log_odds_ == pytest.approx(kept.repeat_log_odds_, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("rigid", [True, False])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("q", [1e-15, 1.0 - 1e-15])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_a_reading_whose_weight_makes_it_negligible_goes(kind, q, learn, rigid, monkeypatch):
    """Two readings whose posteriors still differ become one once the lighter one's part of
    the mixture is negligible (weight × distance ≤ ``TWIN_AGREEMENT``): a prior of 10⁻¹⁵
    leaves the twin no say, so it goes at the first new frame after each run; one of
    1 − 10⁻¹⁵ leaves the filter's own reading none, so the filter takes the twin's. Either
    way the twin comes back at the next run, and the answers are those of the filter that
    keeps both, to round-off."""
    rows = _with_repeats(_rows(11, 17, seed=5), RUNS)
    monkeypatch.setattr(GridLocalizer, "TWIN_AGREEMENT", -1.0)
    kept = _filter(kind, q, learn, rigid)
    keeping, apart = [], []
    for row in rows:
        keeping.append((kept.step(row), kept.place_posterior_.copy()))
        own = kept._mass * (1.0 - kept.new_place_probability_) if kept._twin is not None else None
        apart.append(0.0 if own is None else float(np.abs(own - kept._twin.place_posterior_).sum()))
    monkeypatch.undo()
    loc = _filter(kind, q, learn, rigid)
    twins = []
    for row, (other, posterior) in zip(rows, keeping):
        est = loc.step(row)
        twins.append(loc._twin is not None)
        assert est.place == other.place
        np.testing.assert_allclose(loc.place_posterior_, posterior, rtol=0, atol=1e-12)
        assert est.confidence == pytest.approx(other.confidence, rel=1e-9, abs=1e-12)
        assert est.new_place_probability == pytest.approx(other.new_place_probability, rel=1e-9, abs=1e-12)
    settled = [t for t in range(1, len(rows)) if twins[t - 1] and not twins[t]]
    assert len(settled) >= 2
    assert all(apart[t] > 1e-6 for t in settled)  # the two posteriors had not agreed: the weight settled it
    odds = math.log(1e-12)  # the lighter reading negligible throughout
    assert max(loc.repeat_log_odds_, kept.repeat_log_odds_) < odds if q < 0.5 else \
        min(loc.repeat_log_odds_, kept.repeat_log_odds_) > -odds


def test_off_by_default_and_left_to_odometry():
    """``repeat_prior = 0`` (the class's default): the filter moves on through a run as it
    always did; with ``q > 0`` the runs change the answers; where odometry says whether the
    robot moved, the filter keeps no twin and is the filter without it."""
    rows = _with_repeats(_rows(11, 17, seed=5), [0, 0, 3, 0, 1, 0, 0, 0, 2, 0, 0, 4, 0, 0, 0, 0, 1])
    make = lambda **kw: GridLocalizer(PlaceGraph.chain(11), _Ratios(), rigid_prior=PRIOR, **SETTINGS, **kw).reset()  # noqa: E731
    plain, mixed = make(), make(repeat_prior=0.5)
    assert plain.repeat_prior == 0.0
    with_odometry, plain_odometry = make(repeat_prior=0.5), make()
    differ = False
    for row in rows:
        a, b = plain.step(row), mixed.step(row)
        differ |= a.place != b.place or not math.isclose(a.confidence, b.confidence, rel_tol=1e-12)
        c, d = with_odometry.step(row, odometry=1.0), plain_odometry.step(row, odometry=1.0)
        assert with_odometry._twin is None
        assert (c.place, c.confidence, c.new_place_probability) == (d.place, d.confidence, d.new_place_probability)
    assert differ


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "half"])
def test_repeat_prior_is_checked(bad):
    with pytest.raises(InvalidParameterError, match="repeat_prior"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), repeat_prior=bad).reset()


@pytest.mark.parametrize("kind", [_Float64, _General])
def test_the_twin_shares_the_arrays_neither_reading_writes(kind):
    """The twin shares the filter's read-only arrays (``_FORK_SHARED``: the likelihood of
    ones among them) instead of copying them, and the ones stay ones through the frames."""
    n = 60
    rows = np.full((n, n), 30.0)
    rows[np.arange(n), np.arange(n)] = 0.0
    rows[:, 40:] += np.linspace(0.0, 5.0, n)[:, None]  # not beyond doubt everywhere: the twin lives a while
    runs = np.zeros(n, dtype=int)
    runs[[3, 20, 41]] = (2, 1, 3)
    loc = _filter(kind, 0.5, True, rigid=True, n=n)
    shared = 0
    for row in _with_repeats(rows, runs):
        loc.step(row)
        if loc._twin is not None:
            shared += 1
            for name in loc._FORK_SHARED:
                if loc.__dict__.get(name) is not None:
                    assert loc._twin.__dict__[name] is loc.__dict__[name], name
            assert loc._twin._ones is loc._ones
    assert shared > 0
    np.testing.assert_array_equal(loc._ones, np.ones(n))


@pytest.mark.parametrize("kind", [_Float64, _General])
def test_the_filter_and_its_twin_write_their_predictions_into_one_spare_buffer(kind):
    """Each reading's states (one per component) are its own arrays, never shared, and the
    filter, its components and its twin write their predictions into buffers from one pool:
    while the twin first lives, one buffer beyond the states they hold, not one each."""
    n = 60
    rows = np.full((n, n), 30.0)
    rows[np.arange(n), np.arange(n)] = 0.0
    rows[:, 40:] += np.linspace(0.0, 5.0, n)[:, None]
    runs = np.zeros(n, dtype=int)
    runs[[3, 20, 41]] = (2, 1, 3)
    loc = _filter(kind, 0.5, True, rigid=True, n=n)

    def states(f):
        return [f._state] if f._components is None else [c["_state"] for c in f._components]

    lived = settled = 0
    for row in _with_repeats(rows, runs):
        twin_before = loc._twin
        loc.step(row)
        if twin_before is not None and loc._twin is None:
            settled += 1
        held = states(loc) + ([] if loc._twin is None else states(loc._twin))
        assert len({id(s) for s in held}) == len(held)  # no two states share a buffer
        if loc._twin is not None:
            assert loc._twin._state_pool is loc._state_pool
            if not settled:
                lived += 1
                spare = {id(a) for a in loc._state_pool._arrays} - {id(s) for s in held}
                assert len(spare) <= 1
        del held  # a reference kept through the next step would keep its buffer from the pool
    assert lived > 0
