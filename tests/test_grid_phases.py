"""The grid filter's phase bins: a fractional speed driven as a fixed cycle of whole moves,
checked against a plainly written prediction, and a half-speed track kept sharp."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import (GridLocalizer, _bin_moves, phase_bins, phase_transition, predict, route_neighbours,
                           velocity_transition)
from catgraph.observation import TemperedObservation


def _fixed(tau=1.0):
    return TemperedObservation(likelihood="linear", hub=None, temperature=tau, novelty=False)


@pytest.mark.parametrize("speed, moves", [(0.5, [0, 1]), (1 / 3, [0, 0, 1]), (1.5, [1, 2]), (2.25, [2, 2, 2, 3]),
                                         (-0.5, [0, 1]), (2.0 / 3.0, [0, 1, 1])])
def test_a_fractional_speed_is_a_cycle_of_whole_moves(speed, moves):
    owner, whole, frac, sign, mirror, successor = phase_bins([speed], 4)
    assert list(owner) == [0] * len(moves) and list(whole) == moves and np.all(frac == 0.0)
    assert np.all(sign == (1 if speed > 0 else -1))
    assert sum(moves) == pytest.approx(abs(speed) * len(moves))  # one cycle covers q · |v| places
    assert list(successor) == [(i + 1) % len(moves) for i in range(len(moves))]


def test_whole_and_unrepresentable_speeds_keep_one_bin_and_the_linear_split():
    v = np.array([-2.0, 0.3, 1.0, 0.5])
    owner, whole, frac, sign, mirror, successor = phase_bins(v, 4)
    assert list(owner) == [0, 1, 2, 3, 3]  # 0.3 = 3/10 needs ten phases: one bin
    np.testing.assert_allclose(frac[:3], [0.0, 0.3, 0.0])
    one = phase_bins(v, 1)  # no phases at all: the plain bins
    w, f, s, m = _bin_moves(v)
    assert list(one[0]) == [0, 1, 2, 3]
    for got, want in zip(one[1:5], (w, f, s, m)):
        np.testing.assert_array_equal(got, want)


def test_mirror_keeps_the_phase():
    owner, whole, frac, sign, mirror, successor = phase_bins([-1.0, -0.5, 0.5, 1.0], 4)
    assert list(owner) == [0, 1, 1, 2, 2, 3]
    assert list(mirror) == [5, 3, 4, 1, 2, 0]


def _slow_phase_transition(t, owner, successor):
    """Element by element, from the definition."""
    nb = len(owner)
    out = np.zeros((nb, nb))
    for a in range(nb):
        for c in range(nb):
            if owner[a] == owner[c]:
                out[a, c] = t[owner[a], owner[a]] if c == successor[a] else 0.0
            else:
                out[a, c] = t[owner[a], owner[c]] / np.count_nonzero(owner == owner[c])
    return out


def test_phase_transition_against_its_definition():
    v = np.array([-3.0, -1.0, -0.5, 0.5, 1.0, 1.5, 3.0])
    t = velocity_transition(v, 0.9, 0.02)
    owner, _, _, _, _, successor = phase_bins(v, 4)
    got = phase_transition(t, owner, successor)
    np.testing.assert_allclose(got, _slow_phase_transition(t, owner, successor), atol=1e-15)
    np.testing.assert_allclose(got.sum(1), 1.0)
    plain = phase_bins(v, 1)
    np.testing.assert_array_equal(phase_transition(t, plain[0], plain[5]), t)  # no phases: unchanged


def _slow_predict(state, v, stay, reverse, blur, recovery, prior, n):
    """One prediction over phase bins on a chain of ``n`` places, from the definition."""
    owner, whole, _, sign, _, successor = phase_bins(v, 4)
    t = velocity_transition(v, stay, reverse)
    nb = len(owner)
    moved = np.zeros((n, nb))
    for j in range(n):
        for a in range(nb):
            for c in range(nb):
                if owner[a] == owner[c]:
                    w = t[owner[a], owner[a]] if c == successor[a] else 0.0
                else:
                    w = t[owner[a], owner[c]] / np.count_nonzero(owner == owner[c])
                k = j + sign[c] * whole[c]
                if 0 <= k < n:  # past a route end the mass leaves the map
                    moved[k, c] += w * state[j, a]
    out = (1 - 2 * blur) * moved
    for j in range(n):
        out[min(j + 1, n - 1)] += blur * moved[j]
        out[max(j - 1, 0)] += blur * moved[j]
    out /= out.sum()
    return (1 - recovery) * out + recovery * prior[None, :] / n


def test_predict_over_phase_bins_matches_slow_reference():
    rng = np.random.default_rng(0)
    n = 16
    v = np.array([-2.0, -0.5, 0.5, 1.0, 1.5])
    owner, whole, frac, sign, mirror, successor = phase_bins(v, 4)
    state = rng.random((n, len(owner)))
    state /= state.sum()
    prior = rng.random(len(owner))
    prior /= prior.sum()
    g = PlaceGraph.chain(n)
    got = predict(state, phase_transition(velocity_transition(v, 0.8, 0.05), owner, successor), v,
                  route_neighbours(g), 0.1, 0.02, prior, 0.0, moves=(whole, frac, sign, mirror))
    np.testing.assert_allclose(got, _slow_predict(state, v, 0.8, 0.05, 0.1, 0.02, prior, n), atol=1e-13)


@pytest.mark.parametrize("line", [True, False])
def test_a_point_mass_at_half_speed_stays_a_point(line):
    """Motion alone (no likelihood, no blur, no jumps): a point mass at v = 0.5 moves one
    place every second frame and never spreads; with one bin per speed it spreads."""
    n = 80
    rows = np.zeros((41, n))
    rows[0, 10] = -50.0  # the first frame pins the place; the rest say nothing
    kw = dict(velocities=(0.5, 1.0), velocity_stay=1.0, reverse_probability=0.0, blur=0.0, recovery=0.0,
              learn_recovery=False, new_place_prior=0.0)
    sharp = GridLocalizer(PlaceGraph.chain(n), _fixed(), **kw).reset()
    blurred = GridLocalizer(PlaceGraph.chain(n), _fixed(), max_phases=1, **kw).reset()
    for loc in (sharp, blurred):
        loc._line = line
        if not line:
            loc._state = loc._state.astype(np.float64)
    half = []
    for k, row in enumerate(rows):
        sharp.step(row)
        blurred.step(row)
        half.append(sharp.state_[:, 0])
    # the v = 0.5 mass after 40 more frames: at place 30 (both phases), or one ahead
    m = half[-1] / half[-1].sum()
    assert set(np.flatnonzero(m > 1e-6)) <= {30, 31}
    spread = blurred.state_[:, 0] / blurred.state_[:, 0].sum()
    assert spread.max() < 0.3  # binomial spread of forty half-steps
    assert sharp.state_.shape == (n, 2) and sharp.state_.sum() == pytest.approx(1.0)


def test_half_speed_track_with_repeated_frames_is_held_more_confidently():
    rng = np.random.default_rng(3)
    n = 300
    places = 40 + np.arange(120) // 2  # every frame shown twice: half the reference's speed
    rows = rng.standard_normal((len(places), n))
    rows[np.arange(len(places)), places] -= 1.5
    rows[1::2] = rows[::2]
    conf = {}
    for phases in (1, 4):
        res = GridLocalizer(PlaceGraph.chain(n), _fixed(0.5), max_phases=phases).run(rows)
        assert np.mean(np.abs(res.place[40:] - places[40:]) <= 2) > 0.9
        conf[phases] = float(np.mean(res.confidence[40:]))
    assert conf[4] > conf[1] + 0.05


def test_max_phases_validated():
    with pytest.raises(InvalidParameterError, match="max_phases"):
        GridLocalizer(PlaceGraph.chain(5), _fixed(), max_phases=0).reset()
