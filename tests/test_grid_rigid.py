"""The grid filter's motion averaged with a rigid line (``GridLocalizer(rigid_prior=p)``),
and its velocity prior with odds on the reference's own speed (``home_speed_odds``),
against a plain dense-matrix Bayes filter over (motion model, place, velocity) on a tiny
route."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import (RECOVERY_MEMORY, RECOVERY_PRIOR_FRAMES, RIGID_JUMP_RATE, VARYING_VELOCITY_STAY, GridLocalizer,
                           learn_jump_rate)
from catgraph.observation import Observation

from .test_grid_hazard import SETTINGS, VELOCITIES, _Float64, _motion, _Ratios, _rows
from .test_grid_jump_velocity import _General

PRIOR = 0.2
RECOVERY = 0.1


def _reference(rows, learn, jump_velocity, home_speed_odds=1.0, change=None, varying=0.0, stay=None, rigid=True,
               with_evidence=False):
    """Two filters as vectors over (place, velocity), each with its motion as one matrix:
    the settings' (``velocity_stay``, ``reverse_probability``, ``blur``, jump rate
    ``RECOVERY``, learned from its own evidence when ``learn``) and the rigid line's
    (velocity kept, no blur, ``RIGID_JUMP_RATE``); each jump uniform over places with the
    mixture's jump velocity (``"current"``: half the previous posterior velocity marginal
    and half the velocity prior; ``"long-run"``: the discounted mean of the posterior
    marginals so far and the velocity prior, written out as a weighted mean); the two
    weighed by their evidence (Bayes' rule), starting at ``1 − PRIOR`` and ``PRIOR``. The
    velocity prior (the start, the landing's prior part) gives each of ``±1``
    ``home_speed_odds`` times each other velocity's weight (1: uniform). ``change``: per
    frame, the likelihood ratio ``λ`` of the frame's change (jump against step), which
    multiplies each filter's landing mass before anything is normalised (the jump
    transitions' likelihood). ``varying``: a third filter between the two, of this prior
    weight (the settings' first less it), its velocity kept with ``VARYING_VELOCITY_STAY``,
    the settings' blur and turning, and the first filter's jump rate (as learned). Returns
    per frame the place posterior, ``P(new)`` and the weights (and, with ``with_evidence``, the
    frame's log evidence ``log(P(new)' e^{r_new} + (1 − P(new)') Σ prior e^r)``, ``P(new)'``
    the new place's prior for the frame). ``stay``: the first filter's ``velocity_stay``
    instead of the settings'. ``rigid=False``: the first filter alone."""
    n = rows.shape[1]
    nb = len(VELOCITIES)
    stay = SETTINGS["velocity_stay"] if stay is None else stay
    motion = [_motion(n, VELOCITIES, stay, SETTINGS["reverse_probability"], SETTINGS["blur"]),
              _motion(n, VELOCITIES, 1.0, 0.0, 0.0)]
    eps = [RECOVERY, RIGID_JUMP_RATE]
    w = [1.0 - PRIOR, PRIOR]
    if not rigid:
        motion, eps, w = motion[:1], eps[:1], [1.0]
    if varying:
        motion.insert(1, _motion(n, VELOCITIES, VARYING_VELOCITY_STAY, SETTINGS["reverse_probability"],
                                 SETTINGS["blur"]))
        eps.insert(1, RECOVERY)
        w = [1.0 - PRIOR - varying, varying, PRIOR]
    k = len(motion)
    w = np.array(w)
    jumps, frames = 0.0, 0.0
    vprior = np.array([home_speed_odds if abs(v) == 1.0 else 1.0 for v in VELOCITIES])
    vprior /= vprior.sum()
    x = [np.tile(vprior / n, n) for _ in range(k)]
    marginals = []
    p_new = 0.0
    out = []
    for t, row in enumerate(rows):
        like = np.repeat(np.exp(-row), nb)
        if t == 0:
            pred = [xi.copy() for xi in x]
        else:
            if jump_velocity == "current":
                land_v = 0.5 * marginals[-1] + 0.5 * vprior
            else:
                age = np.arange(len(marginals))[::-1]
                weight = 0.5 ** (age / RECOVERY_MEMORY)
                land_v = ((weight[:, None] * np.array(marginals)).sum(0) + RECOVERY_PRIOR_FRAMES * vprior) / (
                    weight.sum() + RECOVERY_PRIOR_FRAMES)
            land = np.tile(land_v / n, n)
            moved = [motion[i] @ x[i] for i in range(k)]
            lam = 1.0 if change is None else change[t]
            pred = [(1 - eps[i]) * moved[i] / moved[i].sum() + eps[i] * lam * land for i in range(k)]
        evidence = [float((pred[i] * like).sum()) for i in range(k)]  # each component's Σ prior e^r
        if t > 0 and learn:
            # the posterior probability of a jump: ε λ mean e^r over the evidence
            jumps, frames, eps[0] = learn_jump_rate(jumps, frames, RECOVERY, eps[0] * lam,
                                                    float(np.exp(-row).mean()) / evidence[0])
            if varying:
                eps[1] = eps[0]
        z = [w[i] * pred[i] * like for i in range(k)]
        total = sum(zi.sum() for zi in z)
        w = np.array([zi.sum() for zi in z]) / total
        x = [zi / zi.sum() for zi in z]
        mass = sum(zi.reshape(n, nb).sum(1) for zi in z) / total
        marginals.append(sum(zi.reshape(n, nb).sum(0) for zi in z) / total)
        prior = SETTINGS["new_place_stay"] * p_new + SETTINGS["new_place_prior"] * (1 - p_new)
        a_new = math.log(prior) - 1.0
        a_map = math.log1p(-prior) + math.log(total)
        p_new = math.exp(a_new - np.logaddexp(a_new, a_map))
        out.append(((1 - p_new) * mass, p_new, w) + ((float(np.logaddexp(a_new, a_map)),) if with_evidence else ()))
    return out


@pytest.mark.parametrize("jump_velocity", ["long-run", "current"])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_rigid_line_equals_dense_reference(kind, learn, jump_velocity):
    n = 11
    rows = _rows(n, 17, seed=5)  # a track, a turn, a faster run
    loc = kind(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, recovery=RECOVERY, learn_recovery=learn,
               jump_velocity=jump_velocity, **SETTINGS).reset()
    for row, (mass, p_new, w) in zip(rows, _reference(rows, learn, jump_velocity)):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-9, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(loc.rate_weights_, w, rtol=1e-9, atol=1e-15)
        assert est.place == int(np.argmax(mass))


@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_varying_speed_equals_dense_reference(kind, learn):
    """A third motion model whose velocity changes ten times as often
    (``varying_prior``), beside the filter's own and the rigid line, sharing the own
    one's learned jump rate, with jump evidence: the dense Bayes filter over three models."""
    n = 11
    rows = _rows(n, 17, seed=5)
    lam = np.exp(np.random.default_rng(3).uniform(0.0, 1.0, len(rows)))
    settings = {**SETTINGS, "velocity_stay": 0.97}  # the own velocity stickier than the varying one's
    assert VARYING_VELOCITY_STAY < 0.97
    loc = kind(PlaceGraph.chain(n), _Changing(np.log(lam)), rigid_prior=PRIOR, varying_prior=0.3, recovery=RECOVERY,
               learn_recovery=learn, jump_velocity="long-run", **settings).reset()
    reference = _reference(rows, learn, "long-run", change=lam, varying=0.3, stay=0.97)
    assert len(reference[-1][2]) == 3
    for row, (mass, p_new, w) in zip(rows, reference):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-9, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(loc.rate_weights_, w, rtol=1e-9, atol=1e-15)
        assert est.place == int(np.argmax(mass))


def test_varying_speed_without_the_rigid_line():
    """Two motion models, the own one and the varying speed's: weights that sum to one, and
    a filter unlike the one without it."""
    n = 11
    rows = _rows(n, 17, seed=5)
    settings = {**SETTINGS, "velocity_stay": 0.97}  # the own velocity stickier than the varying one's
    both = GridLocalizer(PlaceGraph.chain(n), _Ratios(), varying_prior=0.5, **settings).reset()
    plain = GridLocalizer(PlaceGraph.chain(n), _Ratios(), **settings).reset()
    differ = False
    for row in rows:
        a, b = both.step(row), plain.step(row)
        assert both.rate_weights_.shape == (2,) and both.rate_weights_.sum() == pytest.approx(1.0)
        differ |= not np.allclose(both.place_posterior_, plain.place_posterior_, rtol=1e-6)
    assert differ


@pytest.mark.parametrize("rigid, varying, needle", [(0.5, 0.5, "below 1"), (0.0, -0.1, "varying_prior"),
                                                    (0.0, 1.0, "varying_prior"), (0.2, float("nan"), "varying_prior")])
def test_varying_prior_validated(rigid, varying, needle):
    with pytest.raises(InvalidParameterError, match=needle):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), rigid_prior=rigid, varying_prior=varying).reset()


def test_varying_prior_and_jump_rates_exclusive():
    with pytest.raises(InvalidParameterError, match="varying_prior"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), varying_prior=0.2, jump_rates=(0.1, 0.01)).reset()


class _Changing(_Ratios):
    """The negated rows with a given jump evidence per frame (``Observation.jump_evidence``)."""

    def __init__(self, evidence):
        self.evidence, self.t = evidence, 0

    def reset(self):
        self.t = 0

    def observe(self, row):
        obs = super().observe(row)
        self.t += 1
        return Observation(obs.log_ratio, obs.new_place_log_ratio, True, jump_evidence=float(self.evidence[self.t - 1]))


@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_jump_evidence_equals_dense_reference(kind, learn):
    """A frame's jump evidence ``log λ`` multiplies each motion model's landing mass by
    ``λ`` before the models are weighed: the frame's rate and the models' change factors
    of the grid filter are that Bayes filter (rates below the cap)."""
    n = 11
    rows = _rows(n, 17, seed=5)
    lam = np.exp(np.random.default_rng(2).uniform(0.0, 1.5, len(rows)))
    lam[[3, 8]] = 1.0  # frames without evidence
    loc = kind(PlaceGraph.chain(n), _Changing(np.log(lam)), rigid_prior=PRIOR, recovery=RECOVERY,
               learn_recovery=learn, jump_velocity="long-run", **SETTINGS).reset()
    reference = _reference(rows, learn, "long-run", change=lam)
    plain = _reference(rows, learn, "long-run")
    assert not np.allclose(reference[-1][2], plain[-1][2], rtol=1e-3, atol=0)  # the evidence moves the weights
    for row, (mass, p_new, w) in zip(rows, reference):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(loc.rate_weights_, w, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("jump_velocity", ["long-run", "current"])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_home_speed_odds_equal_dense_reference(kind, jump_velocity):
    n = 11
    rows = _rows(n, 17, seed=8)
    loc = kind(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, recovery=RECOVERY, jump_velocity=jump_velocity,
               home_speed_odds=4.0, **SETTINGS).reset()
    reference = _reference(rows, True, jump_velocity, home_speed_odds=4.0)
    plain = _reference(rows, True, jump_velocity)
    # the case is what it claims: the odds move the posterior
    assert not np.allclose(reference[1][0], plain[1][0], rtol=1e-6, atol=0)
    for row, (mass, p_new, w) in zip(rows, reference):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-9, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(loc.rate_weights_, w, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("odds", [1.0, 3.0, 0.25])
def test_home_speed_odds_set_the_velocity_prior(odds):
    """Before the first frame the velocity marginal is the prior: each of ``±1`` ``odds``
    times each other velocity (``±0.5`` share theirs between two phases)."""
    from catgraph.grid import DEFAULT_VELOCITIES

    loc = GridLocalizer(PlaceGraph.chain(50), _Ratios(), home_speed_odds=odds).reset()
    per_velocity = loc.state_.sum(0)
    assert per_velocity.shape == (len(DEFAULT_VELOCITIES),)
    home = np.abs(np.abs(np.asarray(DEFAULT_VELOCITIES)) - 1.0) < 1e-12
    assert home.sum() == 2
    np.testing.assert_allclose(per_velocity.sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(per_velocity[home] / per_velocity[~home][0], odds, rtol=1e-6)
    np.testing.assert_allclose(per_velocity[~home], per_velocity[~home][0], rtol=1e-6)


@pytest.mark.parametrize("bad", [0.0, -2.0, float("nan"), "3", True])
def test_home_speed_odds_validated(bad):
    with pytest.raises(InvalidParameterError, match="home_speed_odds"):
        GridLocalizer(PlaceGraph.chain(10), _Ratios(), home_speed_odds=bad).reset()


def test_registry_filter_passes_the_home_speed_odds():
    from catgraph.methods import HOME_SPEED_ODDS, HOME_SPEED_SHARE, make_filter, observation_model, resolve_params

    for given, expected in (({}, 34.0), ({"home_speed_odds": 1.0}, 1.0)):
        params = resolve_params("filter", {"mode": "grid", **given})
        loc = make_filter(params, PlaceGraph.chain(40), observation_model(params, 40, None))
        assert loc.home_speed_odds == expected
    # the default odds give ±1 half the prior, whatever the velocity bins: the dense ones on a
    # small map, the eight of the class default above DENSE_VELOCITY_MAX_PLACES, or the user's
    for given, n in (({}, 40), ({"velocity_bins": [-2.0, -1.0, 1.0, 2.0, 3.0]}, 40), ({}, 20_000)):
        params = resolve_params("filter", {"mode": "grid", **given})
        loc = make_filter(params, PlaceGraph.chain(n), observation_model(params, n, None)).reset()
        home = np.abs(np.abs(loc._v[loc._owner]) - 1.0) < 1e-12
        assert loc._velocity_prior[home].sum() == pytest.approx(HOME_SPEED_SHARE, abs=1e-12)
        assert loc._velocity_prior.sum() == pytest.approx(1.0, abs=1e-12)
    assert loc.home_speed_odds == HOME_SPEED_ODDS
    with pytest.raises(InvalidParameterError, match="home_speed_odds"):
        resolve_params("filter", {"mode": "particles", "home_speed_odds": 2.0})


def test_registry_filter_velocity_bins_by_map_size():
    from catgraph.grid import DEFAULT_VELOCITIES, DENSE_VELOCITIES
    from catgraph.methods import (DENSE_VELOCITY_MAX_PLACES, concrete_params, make_filter, observation_model,
                                  resolve_params)

    assert len(DENSE_VELOCITIES) == 70 and min(np.abs(DENSE_VELOCITIES)) == 0.5 and max(DENSE_VELOCITIES) == 4.0
    for n, expected in ((DENSE_VELOCITY_MAX_PLACES, DENSE_VELOCITIES), (DENSE_VELOCITY_MAX_PLACES + 1,
                                                                        DEFAULT_VELOCITIES)):
        assert concrete_params(resolve_params("filter", {}), n)["velocity_bins"] == list(expected)
    params = resolve_params("filter", {"mode": "grid", "velocity_bins": [-1, 1, 1.5]})
    loc = make_filter(params, PlaceGraph.chain(30), observation_model(params, 30, None))
    assert loc.velocities == (-1.0, 1.0, 1.5)
    with pytest.raises(InvalidParameterError, match="velocity_bins"):
        resolve_params("filter", {"velocity_bins": [1.0, float("nan")]})
    with pytest.raises(InvalidParameterError, match="'velocity_bins' .* distinct numbers"):
        resolve_params("filter", {"mode": "grid", "velocity_bins": [1.0, 1.0]})
    with pytest.raises(InvalidParameterError, match="'velocities' .* distinct"):  # and the filter itself
        GridLocalizer(PlaceGraph.chain(30), observation_model(params, 30, None), velocities=(1.0, 1.0)).reset()


def test_float32_line_path_agrees_with_float64():
    n = 40
    rows = _rows(n, 17, seed=6)
    fast = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, **SETTINGS).reset()
    exact = _Float64(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, **SETTINGS).reset()
    assert fast._state.dtype == np.float32
    for row in rows:
        fast.step(row), exact.step(row)
        np.testing.assert_allclose(fast.place_posterior_, exact.place_posterior_, rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(fast.state_, exact.state_, rtol=1e-5, atol=1e-9)


def test_the_parameters_are_left_as_given():
    """The components swap their motion in and out: the filter's own settings stand after a run."""
    n = 30
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, **SETTINGS)
    loc.run(_rows(n, 17, seed=7))
    assert loc.blur == SETTINGS["blur"] and loc.velocity_stay == SETTINGS["velocity_stay"]
    np.testing.assert_array_equal(loc._transition, loc._motions[0][0])


def test_same_input_same_output():
    n = 30
    rows = _rows(n, 17, seed=8)
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR)
    a, b = loc.run(rows), loc.run(rows)
    np.testing.assert_array_equal(a.place, b.place)
    np.testing.assert_array_equal(a.log_odds, b.log_odds)


def _track(rng, n, frames, start, stretch=None):
    truth = start + np.arange(frames)
    rows = rng.uniform(0.0, 1.0, (frames, n))
    rows[np.arange(frames), truth] -= 1.0
    if stretch is not None:  # frames where a wrong track far away looks better than the truth
        first, length, where, gain = stretch
        rows[first + np.arange(length), truth[first:first + length]] += 1.0  # the truth looks like nothing
        rows[first + np.arange(length), where + np.arange(length)] -= gain
    return truth, rows


def test_an_unbroken_line_outlasts_a_misleading_stretch():
    """A track held for 400 frames (the rigid line's log-odds grow by what the flexible
    motion pays each frame, about 0.03 nats, to 13), then 25 frames where the truth looks
    like nothing and another track far away looks better by 1 a frame (more than a single
    learned jump rate lets a track keep): the rigid line keeps the track on every frame,
    the filter's motion alone leaves it."""
    n, held = 1000, 400
    truth, rows = _track(np.random.default_rng(9), n, held + 60, 20, (held, 25, 700, 1.0))
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=0.05).reset()
    places = []
    for k, row in enumerate(rows):
        places.append(loc.step(row).place)
        if k == held - 1:
            assert loc.rate_weights_[1] > 0.9999
    plain = GridLocalizer(PlaceGraph.chain(n), _Ratios()).run(rows)
    assert np.mean(np.abs(np.asarray(places) - truth)[held:] <= 2) == 1.0
    assert np.mean(np.abs(plain.place - truth)[held:] <= 2) < 0.8


def test_a_jump_refutes_the_rigid_line():
    """A query that jumps after 120 frames of an unbroken line: the rigid line, which held
    most of the weight, loses it within 30 frames of the jump (below 1e-5 after that), and
    from then on the filter answers as the plain filter, right on every frame (it follows
    the jump 7 frames later than the plain filter: the rigid line's lead is spent first)."""
    rng = np.random.default_rng(10)
    n = 400
    truth_a, rows_a = _track(rng, n, 120, 20)
    truth_b, rows_b = _track(rng, n, 80, 250)
    rows, truth = np.r_[rows_a, rows_b], np.r_[truth_a, truth_b]
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=0.05).reset()
    weights, places = [], []
    for row in rows:
        places.append(loc.step(row).place)
        weights.append(loc.rate_weights_[1])
    places = np.asarray(places)
    assert weights[119] > 0.9  # an unbroken line so far: the rigid line holds most of the weight
    assert max(weights[150:]) < 1e-5
    plain = GridLocalizer(PlaceGraph.chain(n), _Ratios()).run(rows)
    np.testing.assert_array_equal(places[140:], plain.place[140:])
    assert np.all(np.abs(places - truth)[140:] <= 2)


@pytest.mark.parametrize("bad", [-0.1, 1.0, "half"])
def test_rigid_prior_validated(bad):
    with pytest.raises(InvalidParameterError, match="rigid_prior"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), rigid_prior=bad).reset()


def test_rigid_prior_and_jump_rates_exclusive():
    with pytest.raises(InvalidParameterError, match="cannot be combined"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), rigid_prior=0.05, jump_rates=(0.1, 0.01)).reset()


def test_off_is_the_plain_filter():
    n = 30
    rows = _rows(n, 17, seed=11)
    a = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=0.0).run(rows)
    b = GridLocalizer(PlaceGraph.chain(n), _Ratios()).run(rows)
    np.testing.assert_array_equal(a.place, b.place)
    np.testing.assert_array_equal(a.log_odds, b.log_odds)


def test_odometry_takes_the_general_path():
    """With odometry both motion models shift by it (the rigid line keeps no blur): the
    posterior stays normalised and follows the driven track."""
    n = 30
    rows = _rows(n, 17, seed=12)
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), rigid_prior=PRIOR, **SETTINGS)
    result = loc.run(rows, odometry=np.ones(len(rows)))
    assert loc.place_posterior_.sum() + loc.new_place_probability_ == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(result.place[:7], np.arange(1, 8))


def test_registry_filter_passes_the_rigid_prior():
    from catgraph import methods

    graph = PlaceGraph.chain(5)
    params = methods.resolve_params("filter", {"mode": "grid"})
    assert params["rigid_prior"] is None  # unset: on by default on small maps
    assert methods.make_filter(params, graph, _Ratios()).rigid_prior == methods.RIGID_PRIOR == 0.05
    assert methods.rigid_prior(params, methods.RIGID_MAX_PLACES) == 0.05
    assert methods.rigid_prior(params, methods.RIGID_MAX_PLACES + 1) == 0.0  # off on large maps
    params = methods.resolve_params("filter", {"mode": "grid", "rigid_prior": 0.0})
    assert methods.make_filter(params, graph, _Ratios()).rigid_prior == 0.0
    assert methods.rigid_prior(methods.resolve_params("filter", {"rigid_prior": 0.01}), 10**6) == 0.01
    params = methods.resolve_params("filter", {"mode": "grid", "rigid_prior": PRIOR})
    assert methods.make_filter(params, graph, _Ratios()).rigid_prior == PRIOR
    with pytest.raises(InvalidParameterError, match="particle filter has none"):
        methods.resolve_params("filter", {"mode": "particles", "rigid_prior": PRIOR})


def test_registry_filter_passes_the_varying_prior():
    from catgraph import methods

    graph = PlaceGraph.chain(5)
    params = methods.resolve_params("filter", {"mode": "grid"})
    assert params["varying_prior"] is None  # unset: half of what the rigid line leaves, on small maps
    assert methods.make_filter(params, graph, _Ratios()).varying_prior == pytest.approx(0.5 * (1 - 0.05))
    assert methods.varying_prior(params, methods.DENSE_VELOCITY_MAX_PLACES, 0.2) == pytest.approx(0.4)
    assert methods.varying_prior(params, methods.DENSE_VELOCITY_MAX_PLACES + 1, 0.0) == 0.0  # off on large maps
    given = methods.resolve_params("filter", {"mode": "grid", "varying_prior": 0.1, "rigid_prior": 0.3})
    loc = methods.make_filter(given, graph, _Ratios())
    assert (loc.varying_prior, loc.rigid_prior) == (0.1, 0.3)
    with pytest.raises(InvalidParameterError, match="particle filter has none"):
        methods.resolve_params("filter", {"mode": "particles", "varying_prior": 0.1})
    with pytest.raises(InvalidParameterError, match="below 1"):
        methods.make_filter(methods.resolve_params("filter", {"mode": "grid", "varying_prior": 0.6,
                                                              "rigid_prior": 0.5}), graph, _Ratios()).reset()


def test_varying_motion_turns_within_what_its_stay_leaves():
    """An own motion loose enough to turn more often than the varying motion's stay allows
    (``reverse_probability`` 0.3 beside ``velocity_stay`` 0.5): every motion's transition stays
    a probability matrix."""
    loc = GridLocalizer(PlaceGraph.chain(12), _Ratios(), velocities=VELOCITIES, velocity_stay=0.5,
                        reverse_probability=0.3, varying_prior=0.3, rigid_prior=0.1).reset()
    assert len(loc._motions) == 3
    for transition, _, _ in loc._motions:
        assert transition.min() >= 0.0
        np.testing.assert_allclose(transition.sum(axis=1), 1.0, rtol=1e-12)
    loc.run(_rows(12, 10, seed=1))
    assert np.isfinite(loc.place_posterior_).all() and loc.rate_weights_.sum() == pytest.approx(1.0)
