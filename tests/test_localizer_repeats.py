"""Frames that come again in the particle filter (``Localizer(repeat_prior=q)``): from the
first frame equal to the one before, the filter runs a twin that stands still through every
such run (it advances on new frames only) beside itself, which moves on, and answers with
the mixture of the two, each weighed by its evidence frame by frame from the prior ``q``
(:mod:`catgraph._twin`, shared with the grid filter). Checked as two plain particle filters
of the same seed composed by Bayes' rule — the query as it comes, and the query without its
repeats — and against the particles' own frame evidence, summed over the particles by hand."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion

from .test_grid_hazard import _Ratios, _rows
from .test_grid_repeats import RUNS, _with_repeats, answers_as_without_repeats, composed_by_bayes

N_PLACES = 11


def _filter(q, marginal=True, n_particles=300, seed=3, **kw):
    return Localizer(PlaceGraph.chain(N_PLACES), _Ratios(), n_particles=n_particles, motion=VelocityMotion(),
                     marginal_velocity=marginal, repeat_prior=q, seed=seed, **kw).reset()


@pytest.mark.parametrize("marginal", [True, False])
@pytest.mark.parametrize("q", [0.5, 0.2, 0.9, 1.0])
def test_repeats_are_two_particle_filters_weighed_by_their_evidence(q, marginal, monkeypatch):
    """The filter with ``repeat_prior = q`` against two plain filters of its seed: one on the
    frames as they come (the robot moved on), one on the frames without their repeats (it
    stood still; the twin is forked from the filter at the run's first frame, before that
    frame moves it, so it draws what the plain filter draws), each repeat answered by the
    latter as its run's first frame; from the first repeat on the answer is their mixture,
    weighed by ``q`` and then by each frame's evidence where both advanced (the twin kept
    throughout)."""
    monkeypatch.setattr(Localizer, "TWIN_PARTICLES", -1.0)
    rows = _with_repeats(_rows(N_PLACES, 17, seed=5), RUNS)
    loc, moved, still = _filter(q, marginal), _filter(0.0, marginal), _filter(0.0, marginal)
    for _, forked in composed_by_bayes(loc, moved, still, rows, q):
        np.testing.assert_array_equal(loc.particles_.edge, moved.particles_.edge)  # its own reading: the moved one
        if forked:
            np.testing.assert_array_equal(loc._twin.particles_.edge, still.particles_.edge)
        else:
            assert loc._twin is None


def test_frame_evidence_is_the_particles_predictive_likelihood():
    """``frame_log_evidence_`` is ``log(P(new)' e^{r_new} + (1 − P(new)') Σ_i w_i e^{ℓ_i})``,
    summed here by hand on the first frame (nothing moves yet, no births: the weights are
    the start's, uniform, and ``ℓ_i`` each particle's ratio interpolated along its edge);
    on every later frame it is finite and is what the twin's odds are made of."""
    loc = _filter(0.0, marginal=False, redraw_fraction=0.0, new_place_prior=0.05, new_place_stay=0.8)
    rows = _rows(N_PLACES, 17, seed=5)
    g = loc.graph
    w = np.exp(loc.particles_.log_weight)
    w = w / w.sum()
    loc.step(rows[0])
    e, f = loc.particles_.edge, loc.particles_.fraction
    r = -rows[0]
    ell = (1 - f) * r[g.source[e]] + f * r[g.target[e]]
    prior = 0.05  # P(new) starts at 0: the new place's prior for the first frame is new_place_prior
    expected = np.logaddexp(math.log(prior) - 1.0, math.log1p(-prior) + math.log(np.sum(w * np.exp(ell))))
    assert loc.frame_log_evidence_ == pytest.approx(float(expected), rel=1e-12)
    for row in rows[1:]:
        loc.step(row)
        assert math.isfinite(loc.frame_log_evidence_)


@pytest.mark.parametrize("marginal", [True, False])
def test_standing_still_for_certain_is_the_query_without_its_repeats(marginal):
    """``q = 1``: the robot stood still through every run, so the answers are the filter's
    on the frames without their repeats (same seed), each repeat answered as its run's
    first frame."""
    answers_as_without_repeats(_filter(1.0, marginal), _filter(0.0, marginal), _rows(N_PLACES, 17, seed=7))


@pytest.mark.parametrize("q", [1e-15, 1.0 - 1e-15])
def test_a_reading_whose_weight_makes_it_negligible_goes(q, monkeypatch):
    """A prior of 10⁻¹⁵ leaves the twin no say, so it goes at the first new frame after each
    run (the answers those of the filter that keeps it, to round-off); one of 1 − 10⁻¹⁵
    leaves the filter's own reading none, so the filter takes the twin's particles. Either
    way the twin comes back at the next run."""
    rows = _with_repeats(_rows(N_PLACES, 17, seed=5), RUNS)
    monkeypatch.setattr(Localizer, "TWIN_PARTICLES", -1.0)
    kept = _filter(q)
    keeping = [kept.step(row) for row in rows]
    monkeypatch.undo()
    loc = _filter(q)
    alive = []
    for row, other in zip(rows, keeping):
        est = loc.step(row)
        alive.append(loc._twin is not None)
        assert est.place == other.place
        assert est.confidence == pytest.approx(other.confidence, rel=1e-9, abs=1e-12)
        assert est.new_place_probability == pytest.approx(other.new_place_probability, rel=1e-9, abs=1e-12)
    repeats = [t for t in range(1, len(rows)) if np.array_equal(rows[t], rows[t - 1])]
    assert all(alive[t] for t in repeats)  # forked at each run
    assert not alive[-1] or np.array_equal(rows[-1], rows[-2])
    if q > 0.5:  # the filter took the twin's reading at each run's end: the query's without its repeats
        plain = _filter(0.0)
        for t, row in enumerate(rows):
            if t == 0 or not np.array_equal(row, rows[t - 1]):
                plain.step(row)
        still = loc._twin if loc._twin is not None else loc  # (the query may end in a run)
        np.testing.assert_array_equal(still.particles_.edge, plain.particles_.edge)
        np.testing.assert_array_equal(still.particles_.log_weight, plain.particles_.log_weight)


def test_off_by_default_and_refused_outside_zero_to_one():
    loc = Localizer(PlaceGraph.chain(N_PLACES), _Ratios(), n_particles=50)
    assert loc.repeat_prior == 0.0
    rows = _with_repeats(_rows(N_PLACES, 5, seed=1), [0, 3, 0, 0, 0])
    for row in rows:
        loc.step(row)
        assert loc._twin is None
    with pytest.raises(InvalidParameterError, match="repeat_prior"):
        Localizer(PlaceGraph.chain(N_PLACES), _Ratios(), repeat_prior=1.5).reset()


def test_a_reading_lighter_than_one_particle_goes():
    """A twin whose weight is below one particle's share of the cloud (a prior of 10⁻⁴ on 300
    particles) goes at the first new frame after each run: the answers move by at most its
    weight (the place posteriors' L1 distance ≤ 2 w, ``w`` the weight the filter that keeps it
    gives it: the two filters' own readings are the same particles, and their mixtures differ
    only in the twin's part)."""
    rows = _with_repeats(_rows(N_PLACES, 17, seed=5), RUNS)
    q = 1e-4
    kept, loc = _filter(q), _filter(q)
    kept.TWIN_PARTICLES = -1.0  # (an instance attribute: this filter keeps its twin)
    for t, row in enumerate(rows):
        loc.step(row)
        kept.step(row)
        w = 1.0 / (1.0 + math.exp(-kept.repeat_log_odds_))  # the twin's weight in the kept mixture
        repeat = t > 0 and np.array_equal(row, rows[t - 1])
        if not repeat:
            assert loc._twin is None  # gone at the first new frame (or never forked)
        assert np.abs(loc.place_posterior_ - kept.place_posterior_).sum() <= 2.0 * max(w, 1e-300) + 1e-12
    assert kept._twin is not None
