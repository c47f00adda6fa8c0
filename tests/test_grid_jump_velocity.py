"""The velocity a grid filter's jump lands with (``GridLocalizer(jump_velocity=...)``)
against a plain dense-matrix Bayes filter over (rate, place, velocity) on a tiny route."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import RECOVERY_MEMORY, RECOVERY_PRIOR_FRAMES, GridLocalizer

from .test_grid_hazard import SETTINGS, VELOCITIES, _Float64, _motion, _Ratios, _rows


class _General(_Float64):
    """The general path (a walk along the graph's edges) on a line graph, one rate or several."""

    def reset(self):
        super().reset()
        self._line = False
        for c in [self.__dict__] + (getattr(self, "_components", None) or []):
            c["_state"] = c["_state"].astype(np.float64)
        return self


def _reference(rows, rates, jump_velocity):
    """Each rate's filter as a vector over (place, velocity) and the motion as one
    matrix; every jump uniform over places with, for ``"current"``, half the previous
    posterior velocity marginal and half uniform, for ``"long-run"``, the discounted mean
    of the posterior marginals of the frames so far (half-life ``RECOVERY_MEMORY``) and
    the uniform prior worth ``RECOVERY_PRIOR_FRAMES`` frames, written out as a weighted
    mean; the rates weighed by their evidence (Bayes' rule). Returns per frame the place
    posterior and ``P(new)``."""
    n = rows.shape[1]
    nb = len(VELOCITIES)
    eps = np.asarray(rates)
    k = len(eps)
    a = _motion(n, VELOCITIES, SETTINGS["velocity_stay"], SETTINGS["reverse_probability"], SETTINGS["blur"])
    vprior = np.full(nb, 1.0 / nb)
    x = [np.tile(vprior / n, n) for _ in range(k)]
    w = np.full(k, 1.0 / k)
    marginals = []
    p_new = 0.0
    out = []
    for t, row in enumerate(rows):
        like = np.repeat(np.exp(-row), nb)
        if t == 0:
            y = [w[i] * x[i] for i in range(k)]
        else:
            if jump_velocity == "current":
                land_v = 0.5 * marginals[-1] + 0.5 * vprior
            else:
                age = np.arange(len(marginals))[::-1]  # frames since each marginal
                weight = 0.5 ** (age / RECOVERY_MEMORY)
                land_v = ((weight[:, None] * np.array(marginals)).sum(0) + RECOVERY_PRIOR_FRAMES * vprior) / (
                    weight.sum() + RECOVERY_PRIOR_FRAMES)
            land = np.tile(land_v / n, n)
            moved = [a @ x[i] for i in range(k)]
            y = [w[i] * ((1 - eps[i]) * moved[i] / moved[i].sum() + eps[i] * land) for i in range(k)]
        z = [yi * like for yi in y]
        total = sum(zi.sum() for zi in z)
        w = np.array([zi.sum() for zi in z]) / total
        x = [zi / zi.sum() for zi in z]
        mass = sum(zi.reshape(n, nb).sum(1) for zi in z) / total
        marginals.append(sum(zi.reshape(n, nb).sum(0) for zi in z) / total)
        prior = SETTINGS["new_place_stay"] * p_new + SETTINGS["new_place_prior"] * (1 - p_new)
        a_new = math.log(prior) - 1.0
        a_map = math.log1p(-prior) + math.log(total)
        p_new = math.exp(a_new - np.logaddexp(a_new, a_map))
        out.append(((1 - p_new) * mass, p_new))
    return out


@pytest.mark.parametrize("jump_velocity", ["long-run", "current"])
@pytest.mark.parametrize("rates", [None, (0.2, 0.02)])
@pytest.mark.parametrize("kind", [_Float64, _General])
def test_jump_velocity_equals_dense_reference(kind, rates, jump_velocity):
    n = 11
    rows = _rows(n, 17, seed=2)
    # one fixed rate: the single-rate filter; two: the mixture (its jumps land with the mixture's velocity)
    extra = {"recovery": 0.1, "learn_recovery": False} if rates is None else {"jump_rates": rates}
    loc = kind(PlaceGraph.chain(n), _Ratios(), jump_velocity=jump_velocity, **extra, **SETTINGS).reset()
    reference = _reference(rows, (0.1,) if rates is None else rates, jump_velocity)
    for row, (mass, p_new) in zip(rows, reference):
        est = loc.step(row)
        np.testing.assert_allclose(loc.place_posterior_, mass, rtol=1e-11, atol=1e-15)
        assert est.new_place_probability == pytest.approx(p_new, rel=1e-11, abs=1e-15)


def test_the_landing_is_taken_once_per_frame():
    """Reading the landing distribution again within a frame returns the same one (the
    mixture's components, and a caller, share it)."""
    n = 11
    loc = GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_velocity="long-run", **SETTINGS).reset()
    for row in _rows(n, 5, seed=3):
        loc.step(row)
    first = loc._jump_velocity().copy()
    np.testing.assert_array_equal(loc._jump_velocity(), first)


def test_same_seed_same_output():
    n = 11
    rows = _rows(n, 17, seed=4)
    runs = [GridLocalizer(PlaceGraph.chain(n), _Ratios(), jump_velocity="long-run", **SETTINGS).run(rows)
            for _ in range(2)]
    np.testing.assert_array_equal(runs[0].place, runs[1].place)
    np.testing.assert_array_equal(runs[0].score, runs[1].score)


def test_unknown_jump_velocity():
    with pytest.raises(InvalidParameterError, match="'jump_velocity' parameter of GridLocalizer"):
        GridLocalizer(PlaceGraph.chain(5), _Ratios(), jump_velocity="uniform").reset()


def test_registry_filter_lands_with_the_long_run_velocity():
    from catgraph import methods

    graph = PlaceGraph.chain(5)
    params = methods.resolve_params("filter", {"mode": "grid"})
    assert params["jump_velocity"] is None  # unset: the method's default where the grid runs
    assert methods.concrete_params(params, graph.n_places)["jump_velocity"] == methods.JUMP_VELOCITY == "long-run"
    assert methods.make_filter(params, graph, _Ratios()).jump_velocity == "long-run"
    params = methods.resolve_params("filter", {"mode": "grid", "jump_velocity": "current"})
    assert methods.make_filter(params, graph, _Ratios()).jump_velocity == "current"
