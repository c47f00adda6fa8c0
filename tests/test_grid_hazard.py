"""The grid filter over several jump rates (``jump_rates``, both scopes) against a plain
dense-matrix Bayes filter over (rate, place, velocity) on a tiny route."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer, velocity_transition
from catgraph.observation import Observation

VELOCITIES = (-1.0, 1.0, 2.0)
RATES = (0.2, 0.02, 0.002)
SETTINGS = {"velocities": VELOCITIES, "velocity_stay": 0.9, "reverse_probability": 0.02, "blur": 0.05,
            "new_place_prior": 0.05, "new_place_stay": 0.8}


class _Ratios:
    """An observation model whose log-likelihood ratios are the negated difference row."""

    def reset(self):
        pass

    def observe(self, row):
        return Observation(-np.asarray(row, dtype=np.float64), -1.0, True)


class _Float64(GridLocalizer):
    """The line path with its prediction stored in float64."""

    _line_dtype = np.float64


class _General(_Float64):
    """The general path (a walk along the graph's edges) on a line graph."""

    def reset(self):
        super().reset()
        self._line = False
        for c in [self.__dict__] + self._components:
            c["_state"] = c["_state"].astype(np.float64)
        return self


def _motion(n, velocities, stay, reverse, blur):
    """Dense ``(n·B, n·B)`` motion matrix, column ``(j, b)`` → rows ``(j', b')``: the
    velocity transition, the shift by the new velocity (mass past a route end is lost),
    the blur one place either way (kept at a route end)."""
    t = velocity_transition(np.asarray(velocities), stay, reverse)
    nb = len(velocities)
    a = np.zeros((n * nb, n * nb))
    for j in range(n):
        for b in range(nb):
            for c in range(nb):
                target = j + int(velocities[c])
                if not 0 <= target < n:
                    continue
                left, right = max(target - 1, 0), min(target + 1, n - 1)
                for k, w in ((target, 1.0 - 2.0 * blur), (left, blur), (right, blur)):
                    a[k * nb + c, j * nb + b] += t[b, c] * w
    return a


def _reference(rows, rates, learn, scope):
    """The filter over (rate k, place j, velocity b) as vectors and one matrix: each
    rate's normalised motion and its jump rate; scope ``"query"``: rate ``k``'s jumps
    land in rate ``k``; ``"run"``: the jump mass ``J = Σ_k w_k ε_k`` lands in rate ``k``
    with probability ``π_k``, ``π`` the counted rates of ended runs (``learn``); every
    jump uniform over places with the mixture's jump velocity; Bayes' rule. Returns per
    frame the place posterior ``(1 − P(new)) Σ_k Σ_b``, ``P(new)`` and the rates'
    weights."""
    n = rows.shape[1]
    nb = len(VELOCITIES)
    eps = np.asarray(rates)
    k = len(eps)
    a = _motion(n, VELOCITIES, SETTINGS["velocity_stay"], SETTINGS["reverse_probability"], SETTINGS["blur"])
    vprior = np.full(nb, 1.0 / nb)
    x = [np.tile(vprior / n, n) for _ in range(k)]  # each rate's posterior, (place, velocity) flattened
    w = np.full(k, 1.0 / k)
    runs = np.ones(k)
    velocity = vprior.copy()
    p_new = 0.0
    out = []
    for t, row in enumerate(rows):
        r = -row
        like = np.repeat(np.exp(r), nb)
        if t == 0:
            y = [w[i] * x[i] for i in range(k)]
        else:
            pi = runs / runs.sum()
            jump = float(w @ eps)
            land = np.tile((0.5 * velocity + 0.5 * vprior) / n, n)
            moved = [a @ x[i] for i in range(k)]
            into = w * eps if scope == "query" else pi * jump  # the jump mass landing in each rate
            y = [w[i] * (1 - eps[i]) * moved[i] / moved[i].sum() + into[i] * land for i in range(k)]
        z = [yi * like for yi in y]
        total = sum(zi.sum() for zi in z)
        if t > 0 and learn and scope == "run":
            ended = min(1.0, jump * np.exp(r).mean() / total)
            runs = runs + ended * w * eps / jump
        w = np.array([zi.sum() for zi in z]) / total
        x = [zi / zi.sum() for zi in z]
        mass = sum(zi.reshape(n, nb).sum(1) for zi in z) / total
        velocity = sum(zi.reshape(n, nb).sum(0) for zi in z) / total
        prior = SETTINGS["new_place_stay"] * p_new + SETTINGS["new_place_prior"] * (1 - p_new)
        a_new = math.log(prior) - 1.0
        a_map = math.log1p(-prior) + math.log(total)
        p_new = math.exp(a_new - np.logaddexp(a_new, a_map))
        out.append(((1 - p_new) * mass, p_new, w.copy()))
    return out


def _rows(n, frames, seed):
    rng = np.random.default_rng(seed)
    rows = rng.uniform(0.0, 2.0, (frames, n))
    places = np.r_[np.arange(1, 8), np.arange(9, 4, -1), np.arange(0, 10, 2)][:frames]
    rows[np.arange(len(places)), places] -= 2.0  # a track, a turn, a faster run
    return rows


@pytest.mark.parametrize("scope", ["query", "run"])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_jump_rates_equal_dense_reference(kind, learn, scope):
    n = 11
    rows = _rows(n, 17, seed=1)
    loc = kind(PlaceGraph.chain(n), _Ratios(), jump_rates=RATES, jump_rate_scope=scope, learn_recovery=learn,
               **SETTINGS).reset()
    for row, (mass, p_new, w) in zip(rows, _reference(rows, RATES, learn, scope)):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-12, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-12, abs=1e-15)
        np.testing.assert_allclose(loc.rate_weights_, w, rtol=1e-12, atol=1e-15)
        assert est.place == int(np.argmax(mass))


@pytest.mark.parametrize("scope", ["query", "run"])
def test_float32_line_path_agrees_with_float64(scope):
    n = 40
    rows = _rows(n, 17, seed=2)
    fast = GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_rates=RATES, jump_rate_scope=scope, **SETTINGS).reset()
    exact = _Float64(PlaceGraph.chain(n), _Ratios(), jump_rates=RATES, jump_rate_scope=scope, **SETTINGS).reset()
    assert fast._state.dtype == np.float32
    for row in rows:
        fast.step(row), exact.step(row)
        np.testing.assert_allclose(fast.place_posterior_, exact.place_posterior_, rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(fast.state_, exact.state_, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("scope", ["query", "run"])
def test_one_rate_is_the_fixed_rate_filter(scope):
    n = 30
    rows = _rows(n, 17, seed=3)
    for learn in (True, False):
        one = GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_rates=(0.03,), jump_rate_scope=scope,
                            learn_recovery=learn).run(rows)
        fixed = GridLocalizer(PlaceGraph.chain(n), _Ratios(), recovery=0.03, learn_recovery=False).run(rows)
        np.testing.assert_array_equal(one.place, fixed.place)
        np.testing.assert_allclose(one.log_odds, fixed.log_odds, rtol=1e-12, atol=1e-12)


def test_same_input_same_output():
    n = 30
    rows = _rows(n, 17, seed=4)
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_rates=RATES)
    a, b = loc.run(rows), loc.run(rows)
    np.testing.assert_array_equal(a.place, b.place)
    np.testing.assert_array_equal(a.log_odds, b.log_odds)


@pytest.mark.parametrize("scope", ["query", "run"])
def test_a_long_held_track_outlasts_a_misleading_stretch(scope):
    """A track held for 150 frames, then 12 frames where another track far away looks
    better by 1 a frame (12 nats in all, about ``log(n / ε)`` at the single learned rate):
    the hazard keeps the track on (nearly) every frame; the single rate leaves it."""
    rng = np.random.default_rng(6)
    n = 400
    frames = 200
    truth = 20 + np.arange(frames)
    rows = rng.uniform(0.0, 1.0, (frames, n))
    rows[np.arange(frames), truth] -= 1.0
    rows[150 + np.arange(12), 300 + np.arange(12)] -= 2.0  # a wrong track, better than the truth by 1 a frame
    hazard = GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_rates=(0.1, 0.01, 0.001, 0.0001),
                           jump_rate_scope=scope).run(rows)
    single = GridLocalizer(PlaceGraph.chain(n), _Ratios()).run(rows)
    assert np.mean(np.abs(hazard.place - truth)[150:] <= 2) >= 0.95
    assert np.mean(np.abs(single.place - truth)[150:] <= 2) < 0.9


@pytest.mark.parametrize("bad", [(), (0.1, 0.1), (0.0, 0.1), (1.0,), "fast", ((0.1,),)])
def test_jump_rates_validated(bad):
    with pytest.raises(InvalidParameterError, match="jump_rates"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), jump_rates=bad).reset()


def test_jump_rate_scope_validated():
    with pytest.raises(InvalidParameterError, match="jump_rate_scope"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), jump_rates=RATES, jump_rate_scope="frame").reset()
