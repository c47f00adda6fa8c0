"""Frames that come again (``GridLocalizer(repeat_prior=q)``): through a run of frames
equal to the one before, the filter keeps the posterior of the run's first frame, held,
beside the filter moved on, and merges the two with weights ``q`` and ``1 − q`` at the
first new frame. Checked against a plain dense-matrix Bayes filter over (motion model,
place, velocity) that does the same with whole vectors, and against the filter run on
the frames without their repeats (``q = 1``)."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import RIGID_JUMP_RATE, GridLocalizer, learn_jump_rate

from .test_grid_hazard import SETTINGS, VELOCITIES, _Float64, _motion, _Ratios, _rows
from .test_grid_jump_velocity import _General

PRIOR = 0.2
RECOVERY = 0.1


def _with_repeats(rows, runs):
    """``rows`` with row ``k`` shown ``1 + runs[k]`` times (in order)."""
    return np.repeat(rows, 1 + np.asarray(runs), axis=0)


def _reference(rows, q, learn, rigid=True):
    """The filter's motion (the settings', jump rate ``RECOVERY`` learned from its own
    evidence when ``learn``) and, with ``rigid``, the rigid line (velocity kept, no blur,
    ``RIGID_JUMP_RATE``), weighed by their evidence; each jump uniform over places with
    half the previous posterior velocity marginal and half the (uniform) velocity prior.
    A row equal to the previous one starts (or continues) a run: the posterior of the
    frame before the run is kept, and the answers are the mixture of it (weight ``q``)
    and the filter moved on (``1 − q``), over the map and the new place together; at the
    first new row the two are merged so, component by component, before that row is
    processed. Returns per frame the place posterior and ``P(new)``."""
    n = rows.shape[1]
    nb = len(VELOCITIES)
    motion = [_motion(n, VELOCITIES, SETTINGS["velocity_stay"], SETTINGS["reverse_probability"], SETTINGS["blur"])]
    eps, w = [RECOVERY], [1.0]
    if rigid:
        motion.append(_motion(n, VELOCITIES, 1.0, 0.0, 0.0))
        eps.append(RIGID_JUMP_RATE)
        w = [1.0 - PRIOR, PRIOR]
    k = len(motion)
    w = np.array(w)
    vprior = np.full(nb, 1.0 / nb)
    x = [np.tile(vprior / n, n) for _ in range(k)]
    jumps, frames, p_new = 0.0, 0.0, 0.0
    last_marginal = vprior
    standing = None
    out = []

    def mixture(xs, ws):
        return sum(wi * xi for wi, xi in zip(ws, xs))

    for t, row in enumerate(rows):
        repeated = t > 0 and np.array_equal(row, rows[t - 1])
        if not repeated and standing is not None:
            xh, wh, ph = standing
            a, b = q * (1 - ph), (1 - q) * (1 - p_new)
            a, b = a / (a + b), b / (a + b)
            joint = [a * wh[i] * xh[i] + b * w[i] * x[i] for i in range(k)]
            w = np.array([j.sum() for j in joint])
            x = [j / j.sum() for j in joint]
            p_new = q * ph + (1 - q) * p_new
            last_marginal = mixture(x, w).reshape(n, nb).sum(0)
            standing = None
        if repeated and standing is None:
            standing = ([xi.copy() for xi in x], w.copy(), p_new)
        like = np.repeat(np.exp(-row), nb)
        if t == 0:
            pred = [xi.copy() for xi in x]
        else:
            land = np.tile((0.5 * last_marginal + 0.5 * vprior) / n, n)
            moved = [motion[i] @ x[i] for i in range(k)]
            pred = [(1 - eps[i]) * moved[i] / moved[i].sum() + eps[i] * land for i in range(k)]
        evidence = [float((pred[i] * like).sum()) for i in range(k)]
        if t > 0 and learn:
            jumps, frames, eps[0] = learn_jump_rate(jumps, frames, RECOVERY, eps[0],
                                                    float(np.exp(-row).mean()) / evidence[0])
        z = [w[i] * pred[i] * like for i in range(k)]
        total = sum(zi.sum() for zi in z)
        w = np.array([zi.sum() for zi in z]) / total
        x = [zi / zi.sum() for zi in z]
        last_marginal = mixture(x, w).reshape(n, nb).sum(0)
        prior = SETTINGS["new_place_stay"] * p_new + SETTINGS["new_place_prior"] * (1 - p_new)
        a_new = math.log(prior) - 1.0
        a_map = math.log1p(-prior) + math.log(total)
        p_new = math.exp(a_new - np.logaddexp(a_new, a_map))
        posterior, p_out = (1 - p_new) * mixture(x, w).reshape(n, nb).sum(1), p_new
        if standing is not None:  # the answer of a run: the held posterior beside the moved one
            xh, wh, ph = standing
            posterior = q * (1 - ph) * mixture(xh, wh).reshape(n, nb).sum(1) + (1 - q) * posterior
            p_out = q * ph + (1 - q) * p_new
        out.append((posterior, p_out))
    return out


def _filter(kind, q, learn, rigid=True, **kwargs):
    extra = {"rigid_prior": PRIOR} if rigid else {}
    return kind(PlaceGraph.chain(11), _Ratios(), recovery=RECOVERY, learn_recovery=learn, jump_velocity="current",
                repeat_prior=q, **extra, **SETTINGS, **kwargs).reset()


@pytest.mark.parametrize("rigid", [True, False])
@pytest.mark.parametrize("q", [0.5, 0.2, 1.0])
@pytest.mark.parametrize("learn", [True, False])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_repeats_equal_dense_reference(kind, learn, q, rigid):
    rows = _with_repeats(_rows(11, 17, seed=5), [0, 0, 3, 0, 1, 0, 0, 0, 2, 0, 0, 4, 0, 0, 0, 0, 1])
    loc = _filter(kind, q, learn, rigid)
    for row, (posterior, p_new) in zip(rows, _reference(rows, q, learn, rigid)):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, posterior, rtol=1e-9, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-9, abs=1e-15)
        assert est.place == int(np.argmax(posterior))


@pytest.mark.parametrize("kind", [_Float64, _General])
def test_held_for_certain_is_the_query_without_its_repeats(kind):
    """``q = 1``: the robot stood still through every run, so the filter is the filter run
    on the frames without their repeats, and each repeat's answer its run's first frame's
    (with the jump rate fixed: its learning reads every frame, the repeats too)."""
    base = _rows(11, 17, seed=7)
    runs = [0, 2, 0, 0, 5, 0, 1, 0, 0, 0, 3, 0, 0, 0, 0, 0, 2]
    held, plain = _filter(kind, 1.0, False), _filter(kind, 0.0, False)
    answers = [plain.step(row) for row in base]
    k = 0
    for i, row in enumerate(base):
        for _ in range(1 + runs[i]):
            est = held.step(row)
            assert est.place == answers[i].place
            assert est.confidence == pytest.approx(answers[i].confidence, rel=1e-9, abs=1e-15)
            assert est.new_place_probability == pytest.approx(answers[i].new_place_probability, rel=1e-9, abs=1e-15)
            k += 1
    assert k == len(_with_repeats(base, runs))


def test_off_by_default_and_left_to_odometry():
    """``repeat_prior = 0`` (the class's default): the filter moves on through a run as it
    always did; with ``q > 0`` the runs change the answers; where odometry says whether the
    robot moved, the filter keeps no held posterior and is the filter without it."""
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
        assert with_odometry._standing is None
        assert (c.place, c.confidence, c.new_place_probability) == (d.place, d.confidence, d.new_place_probability)
    assert differ


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "half"])
def test_repeat_prior_is_checked(bad):
    with pytest.raises(InvalidParameterError, match="repeat_prior"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), repeat_prior=bad).reset()
