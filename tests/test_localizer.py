"""The particle filter: invariances, junction splits, kidnapping, new places, seeding."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError, ShapeMismatchError
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer
from catgraph.observation import CombinedObservation, Observation
from catgraph.particles import log_sum_exp
from catgraph.traverse import Traverse

from .conftest import FixedLogRatio as _Fixed
from .conftest import survey_graph as _survey_graph


class PeakModel:
    """Stand-in observation model: log-ratio ``-(d / scale)`` of the given row, so a row
    with a low difference at place j says "near j"; ``new`` for the new place."""

    def __init__(self, scale=1.0, new=-2.0, offset=0.0):
        self.scale, self.new, self.offset = scale, new, offset

    def reset(self):
        pass

    def observe(self, row):
        return Observation(-np.asarray(row) / self.scale + self.offset, self.new + self.offset, True)


def _rows_along(path, n_places, sharpness=3.0, noise=0.0, rng=None):
    """Difference rows for a query at places ``path`` (lower near the true place)."""
    j = np.arange(n_places)
    rows = []
    for k, p in enumerate(path):
        d = sharpness * np.minimum(np.abs(j - p), 6) / 6.0
        if noise:
            d = d + noise * rng.standard_normal(n_places)
        rows.append(d)
    return np.array(rows)


def test_reweighting_matches_a_slow_reference():
    g = PlaceGraph.chain(20)
    loc = Localizer(g, PeakModel(), n_particles=50, redraw_fraction=0.0, ess_threshold=0.0, new_place_prior=0.0,
                    seed=1).reset()
    before = loc.particles_.copy()
    row = np.random.default_rng(0).random(20)
    loc.n_steps_ = 0  # first frame: no motion
    loc.step(row)
    r = -row
    want = []
    for e, f, lw in zip(before.edge, before.fraction, before.log_weight):
        want.append(lw + (1 - f) * r[g.source[e]] + f * r[g.target[e]])
    want = np.array(want)
    np.testing.assert_allclose(loc.particles_.log_weight, want - log_sum_exp(want), atol=1e-12)


def test_shifting_log_ratios_by_a_constant_changes_nothing_but_p_new_consistently():
    g = PlaceGraph.chain(60)
    rows = _rows_along(range(10, 40), 60, noise=0.2, rng=np.random.default_rng(0))
    outs = []
    for offset in (0.0, 37.0, -500.0):
        loc = Localizer(g, PeakModel(offset=offset), n_particles=300, seed=3)
        res = loc.run(rows)
        outs.append(res)
    for res in outs[1:]:
        np.testing.assert_array_equal(res.place, outs[0].place)
        np.testing.assert_allclose(res.confidence, outs[0].confidence, atol=1e-9)
        np.testing.assert_allclose(res.new_place_probability, outs[0].new_place_probability, atol=1e-9)


def test_same_seed_same_output_and_different_seed_differs():
    g = PlaceGraph.chain(80)
    rows = _rows_along(list(range(5, 45)), 80, noise=0.5, rng=np.random.default_rng(1))
    a = Localizer(g, PeakModel(), n_particles=200, seed=7).run(rows)
    b = Localizer(g, PeakModel(), n_particles=200, seed=7).run(rows)
    c = Localizer(g, PeakModel(), n_particles=200, seed=8).run(rows)
    np.testing.assert_array_equal(a.place, b.place)
    np.testing.assert_array_equal(a.confidence, b.confidence)
    assert not np.array_equal(a.confidence, c.confidence)


def test_tracks_a_forward_drive_and_confidence_grows():
    g = PlaceGraph.chain(100)
    rng = np.random.default_rng(2)
    path = list(range(20, 80))
    res = Localizer(g, PeakModel(), n_particles=1000, seed=0).run(_rows_along(path, 100, noise=0.3, rng=rng))
    assert np.all(np.abs(res.place[10:] - np.array(path[10:])) <= 2)
    assert res.confidence[-10:].mean() > 0.8
    assert res.confidence[-10:].mean() > res.confidence[0]


def _y_graph():
    """Stem 0..9, then at 9 two branches: 10..19 (chain) and 20..29 (junction 9->20)."""
    n = 30
    e, kinds = [], []
    for a in list(range(0, 19)) + list(range(20, 29)):
        if a == 9:
            continue
        e.append((a, a + 1))
        kinds.append("chain")
    e += [(9, 10), (9, 20)]
    kinds += ["chain", "junction"]
    return PlaceGraph.from_edges(n, np.array(e), kinds=kinds), n


def test_posterior_splits_at_a_junction_and_reconverges():
    g, n = _y_graph()
    # both branches look alike for 3 frames after the junction, then branch B wins
    j = np.arange(n)
    rows = []
    for k in range(10):  # along the stem
        rows.append(3.0 * np.minimum(np.abs(j - k), 4) / 4)
    ambiguous = []
    for k in range(1, 4):
        d = np.full(n, 3.0)
        d[10 + k - 1] = d[20 + k - 1] = 0.0
        rows.append(d)
        ambiguous.append(len(rows) - 1)
    for k in range(4, 9):
        d = 3.0 * np.minimum(np.abs(j - (20 + k - 1)), 4) / 4
        d[:20] = 3.0
        rows.append(d)
    loc = Localizer(g, PeakModel(), n_particles=2000, redraw_fraction=0.0, new_place_prior=0.0, seed=0)
    loc.reset()
    split_seen = False
    for k, row in enumerate(rows):
        est = loc.step(row)
        w = np.exp(loc.particles_.log_weight)
        places = loc.particles_.places(g)
        mass_a = w[(places >= 10) & (places < 20)].sum()
        mass_b = w[places >= 20].sum()
        if k in ambiguous[1:]:
            assert 0.25 < mass_a / (mass_a + mass_b) < 0.75  # split
            split_seen = True
    assert split_seen
    assert est.place >= 24 and mass_b > 0.95  # re-converged on branch B


def test_kidnapped_robot_relocalises_on_the_synthetic_world():
    pytest.importorskip("catgraph.datasets.synthetic")
    from catgraph.datasets.synthetic import make_world
    from catgraph.observation import HistogramObservation
    from catgraph.pipeline import differences

    w = make_world(1, blocks=(3, 3), new_place_blocks=0, reverse_fraction=0.0)
    ref = w.reference
    g = PlaceGraph.from_traverse(ref, junctions=w.reference_junctions())
    # a query that follows the reference from place 40 for 60 frames, then is carried
    # away (kidnapped) to place 300 and drives on from there
    n_ref = len(ref)
    assert n_ref > 420
    path = np.r_[np.arange(40, 100), np.arange(300, 380)]
    noise = 1.0 * np.random.default_rng(0).standard_normal((len(path), ref.frames.shape[1]))
    query = Traverse(frames=(ref.frames[path] + noise).astype(np.float32))
    D = differences(ref, query)
    odo = np.r_[0.0, ref.odometry[path[1:]]]
    odo[60] = ref.odometry[301]  # the kidnap is not in the odometry
    model = HistogramObservation(n_init=20)
    res = Localizer(g, model, n_particles=2000, seed=0).run(D, odometry=odo)
    pos = ref.positions
    err = np.linalg.norm(pos[res.place] - pos[path], axis=1)
    assert np.median(err[30:60]) < w.tolerance_m  # localised before the kidnap
    relocalised = 60 + np.flatnonzero(err[60:] <= w.tolerance_m)
    assert len(relocalised) > 0
    first = relocalised[0] - 60
    assert first <= 25, f"took {first} frames to relocalise"
    assert np.mean(err[60 + first + 10:] <= w.tolerance_m) > 0.8


def test_new_place_probability_rises_in_unmapped_places():
    g = PlaceGraph.chain(100)
    rng = np.random.default_rng(4)
    in_map = _rows_along(range(10, 50), 100, noise=0.2, rng=rng)
    away = 3.0 + 0.2 * rng.standard_normal((15, 100))  # nothing in the map looks alike
    back = _rows_along(range(50, 70), 100, noise=0.2, rng=rng)
    rows = np.concatenate([in_map, away, back])
    res = Localizer(g, PeakModel(new=-1.5), n_particles=1000, new_place_prior=0.05, seed=0).run(rows)
    p = res.new_place_probability
    assert p[20:40].max() < 0.2
    assert p[45:55].min() > 0.8
    assert p[-5:].max() < 0.2


def test_new_place_on_the_synthetic_world():
    from catgraph.datasets.synthetic import make_world
    from catgraph.observation import HistogramObservation
    from catgraph.pipeline import differences

    w = make_world(0, reverse_fraction=0.0)
    g = PlaceGraph.from_traverse(w.reference, junctions=w.reference_junctions())
    from catgraph.differences import difference_matrix
    from catgraph.pipeline import describe

    D = differences(w.reference, w.query)
    r, metric = describe(w.reference)
    model = HistogramObservation.bootstrap(difference_matrix(r, r, metric, normalise=True))
    res = Localizer(g, model, n_particles=1000, new_place_prior=0.05, seed=0).run(D, odometry=w.query.odometry)
    new = np.asarray(w.query.meta["new_place"])
    assert new.sum() > 10
    later = np.arange(len(new)) >= 20
    p = res.new_place_probability
    assert p[new & later].mean() > p[~new & later].mean() + 0.3


def test_combined_model_sums_log_ratios():
    a, b = PeakModel(scale=1.0, new=-1.0), PeakModel(scale=2.0, new=-3.0)
    row = np.array([0.0, 1.0, 2.0])
    out = CombinedObservation([a, b], weights=[1.0, 0.5], reliability=None).observe(row)
    np.testing.assert_allclose(out.log_ratio, -row - 0.25 * row)
    assert out.new_place_log_ratio == pytest.approx(-1.0 - 1.5)


def test_combined_reliability_tempers_each_part():
    a, b = PeakModel(scale=1.0, new=-1.0), PeakModel(scale=2.0, new=-3.0)
    row = np.array([0.0, 1.0, 2.0])
    model = CombinedObservation([a, b])
    out = model.observe(row)  # before any feedback: rho = 1/2 for both parts
    mix = lambda r, rho: rho * r  # tempered by the reliability
    np.testing.assert_allclose(out.log_ratio, mix(-row, 0.5) + mix(-row / 2, 0.5))
    assert out.new_place_log_ratio == pytest.approx(mix(-1.0, 0.5) + mix(-3.0, 0.5))
    # both parts' best place is 0: three hits when the answer is 0, one miss when it is 2
    for near in (slice(0, 1), slice(0, 1), slice(0, 1), np.array([False, False, True])):
        model.observe(row)
        model.feedback(near)
    np.testing.assert_allclose(model.reliability_, [(3 + 1) / (4 + 2)] * 2)
    rho = model.reliability_[0]
    np.testing.assert_allclose(model.observe(row).log_ratio, mix(-row, rho) + mix(-row / 2, rho))


def test_unreliable_part_is_damped_by_the_filter():
    # part b points at a random place every frame; part a follows the true path
    rng = np.random.default_rng(0)
    g = PlaceGraph.chain(80)
    path = np.arange(5, 65)
    rows = _rows_along(path, 80, noise=0.1, rng=rng)

    class Liar:
        def reset(self):
            self.rng = np.random.default_rng(1)

        def observe(self, row):
            r = np.zeros(len(row))
            r[self.rng.integers(len(row))] = 6.0
            return Observation(r, 0.0, True)

    model = CombinedObservation([PeakModel(scale=0.3), Liar()])
    res = Localizer(g, model, n_particles=500, seed=0).run(rows)
    assert model.reliability_[0] > 0.8 and model.reliability_[1] < 0.2
    assert np.mean(np.abs(res.place - path) <= 2) > 0.9


def test_joint_score_is_capped_by_the_recent_support():
    g = PlaceGraph.chain(60)
    rows = _rows_along(range(10, 50), 60, sharpness=8.0, noise=0.1, rng=np.random.default_rng(5))

    class Supported(PeakModel):
        def observe(self, row):
            o = super().observe(row)
            return Observation(o.log_ratio, o.new_place_log_ratio, True, np.full(len(row), 1.5))

    joint = Localizer(g, Supported(), n_particles=500, seed=0).run(rows)
    post = Localizer(g, Supported(), n_particles=500, seed=0, confidence_score="posterior").run(rows)
    np.testing.assert_array_equal(joint.place, post.place)
    np.testing.assert_allclose(post.score, post.log_odds)
    np.testing.assert_allclose(joint.score, np.minimum(joint.log_odds, 1.5))
    plain = Localizer(g, PeakModel(), n_particles=500, seed=0).run(rows)  # no support: posterior log-odds
    np.testing.assert_allclose(plain.score, plain.log_odds)


def test_errors_name_the_problem():
    g = PlaceGraph.chain(10)
    with pytest.raises(ShapeMismatchError, match="10"):
        Localizer(g, PeakModel()).step(np.zeros(7))
    with pytest.raises(InvalidParameterError, match="n_particles"):
        Localizer(g, PeakModel(), n_particles=0).reset()
    with pytest.raises(InvalidParameterError, match="resampler"):
        Localizer(g, PeakModel(), resampler="magic").reset()
    with pytest.raises(InvalidParameterError, match="ObservationModel"):
        Localizer(g, object()).reset()
    with pytest.raises(InvalidParameterError, match="confidence_score"):
        Localizer(g, PeakModel(), confidence_score="max").reset()
    with pytest.raises(InvalidParameterError, match="proposal_uniform"):
        Localizer(g, PeakModel(), proposal_uniform=0.0).reset()  # q must stay positive everywhere
    with pytest.raises(InvalidParameterError, match="proposal_power"):
        Localizer(g, PeakModel(), proposal_power=-1.0).reset()
    with pytest.raises(InvalidParameterError, match="reliability"):
        CombinedObservation([PeakModel()], reliability="always").observe(np.zeros(3))


def test_log_odds_agree_with_confidence_and_keep_ranking_at_saturation():
    g = PlaceGraph.chain(60)
    rows = _rows_along(range(10, 50), 60, sharpness=8.0, noise=0.1, rng=np.random.default_rng(5))
    res = Localizer(g, PeakModel(), n_particles=500, seed=0).run(rows)
    unsaturated = (res.confidence > 1e-6) & (res.confidence < 1 - 1e-6)
    assert unsaturated.any()
    np.testing.assert_allclose(1 / (1 + np.exp(-res.log_odds[unsaturated])), res.confidence[unsaturated], rtol=1e-6)
    saturated = res.confidence == 1.0
    if saturated.any():
        assert np.all(np.isfinite(res.log_odds[saturated])) and len(np.unique(res.log_odds[saturated])) > 1


def test_returned_posterior_is_the_mass_behind_each_estimate():
    from catgraph.datasets import make_world
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.observation import HistogramObservation
    from catgraph.pipeline import differences

    world = make_world(seed=4)
    d = differences(world.reference, world.query)[:120]
    graph = PlaceGraph.from_traverse(world.reference)
    loc = Localizer(graph, HistogramObservation(), n_particles=300, seed=1)
    res = loc.run(d, return_posterior=True)
    assert res.posterior.shape == (120, graph.n_places)
    np.testing.assert_allclose(res.posterior.sum(axis=1), 1.0 - res.new_place_probability, atol=1e-4)
    np.testing.assert_array_equal(res.posterior.argmax(axis=1), res.place)
    assert loc.run(d).posterior is None


# ---------------------------------------------------------------------- towards the grid filter
def _drive_with_a_jump(n, rng):
    """A query that drives 1 place per frame, then jumps to the other end of the route."""
    path = list(range(3, 21)) + list(range(n - 18, n - 3))
    return _rows_along(path, n, sharpness=2.0, noise=0.4, rng=rng)


def _total_variation(a, b):
    return 0.5 * np.abs(a / a.sum(1, keepdims=True) - b / b.sum(1, keepdims=True)).sum(1).mean()


def _grid_learns_recovery() -> bool:
    """Whether the grid filter learns its jump rate (the particle filter then does too)."""
    import inspect

    from catgraph.grid import GridLocalizer

    p = inspect.signature(GridLocalizer).parameters.get("learn_recovery")
    return p is not None and bool(p.default)


@pytest.mark.parametrize("proposal", ["likelihood", "best", "uniform", "sharpened"])
def test_particle_posterior_converges_to_the_grid_filter(proposal):
    """Same motion (velocity bins, blur, recovery ε), same observation: the particle
    posterior's distance to the exact one falls like 1/√N, towards 0 — on a metric graph
    with repeated positions and a query with a jump, where the recovery share decides."""
    from catgraph.grid import GridLocalizer
    from catgraph.motion import VelocityMotion

    g = _survey_graph()
    rows = _drive_with_a_jump(g.n_places, np.random.default_rng(3))
    # the blur the margin below was set with (the grid's default was 0.01 then; both filters get it)
    exact = GridLocalizer(g, _Fixed(0.8), recovery=0.05, blur=0.01).run(rows, return_posterior=True).posterior
    tv = {}
    for n in (250, 4000):
        tv[n] = np.mean([_total_variation(Localizer(g, _Fixed(0.8), n_particles=n, recovery=0.05, proposal=proposal,
                                                    learn_recovery=_grid_learns_recovery(),
                                                    motion=VelocityMotion(blur=0.01),
                                                    seed=s).run(rows, return_posterior=True).posterior, exact)
                         for s in range(3)])
    # 16 times the particles: a quarter of the error for an unbiased filter; allow a third
    assert tv[4000] < tv[250] / 3
    assert tv[4000] < 0.06


def test_recovery_share_is_exact_in_the_prediction_and_the_jump_is_found():
    """The prediction the model is told equals the grid's (1 − ε) · moved + ε / n; after a
    jump the particle filter's answer follows within a few frames, as the grid's does."""
    from catgraph.grid import GridLocalizer
    from catgraph.motion import VelocityMotion
    from catgraph.observation import FilterFeedback  # noqa: F401  (the protocol the model is told)

    class Recording(_Fixed):
        def reset(self):
            self.priors = []

        def feedback(self, fb):
            self.priors.append(fb.prior.copy())

    g = _survey_graph()
    rows = _drive_with_a_jump(g.n_places, np.random.default_rng(5))
    grid_model, pf_model = Recording(0.8), Recording(0.8)
    grid = GridLocalizer(g, grid_model).run(rows)
    pf = Localizer(g, pf_model, n_particles=4000, motion=VelocityMotion(), seed=0).run(rows)
    np.testing.assert_allclose([p.sum() for p in pf_model.priors], 1.0, atol=1e-9)
    # every place keeps at least the recovery share, as in the grid
    assert min(p.min() for p in pf_model.priors[1:]) >= 1e-4 / g.n_places - 1e-12
    fixed = Recording(0.8)
    Localizer(g, fixed, n_particles=500, motion=VelocityMotion(), learn_recovery=False, seed=0).run(rows)
    assert min(p.min() for p in fixed.priors[1:]) >= 0.05 / g.n_places - 1e-12
    assert np.mean(np.abs(pf.place - grid.place) <= 3) > 0.9


def test_sharpened_proposal_cumulative_matches_its_definition():
    """``q = (1 − u) e^{β r} / Σ e^{β r} + u / n``, cumulated: against a plain numpy
    reading of the definition, ending at 1 and positive at every place."""
    from catgraph.localizer import _sharpened_cumulative

    rng = np.random.default_rng(2)
    for n, power, share in ((1, 8.0, 0.5), (50, 1.0, 1.0), (300, 8.0, 0.5), (300, 40.0, 0.01)):
        r = 30.0 * rng.standard_normal(n)
        out = np.empty(n)
        _sharpened_cumulative(r, r.max(), power, share, out)
        q = np.exp(power * (r - r.max()))
        expected = np.cumsum((1 - share) * q / q.sum() + share / n)
        np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)
        assert out[-1] == pytest.approx(1.0)
        assert np.all(np.diff(np.r_[0.0, out]) >= share / n * (1 - 1e-9))


def test_compiled_pool_resampling_picks_what_systematic_resample_picks():
    """The cloud and one young generation resampled into the cloud's slots: the same
    particles as filterpy-style systematic resampling of the pool's weights; the
    other slots untouched; the pool's mass kept."""
    from catgraph.localizer import _resample_pool
    from catgraph.particles import systematic_resample

    rng = np.random.default_rng(0)
    for n, n_out, start, stop in ((60, 60, 0, 0), (60, 40, 50, 60), (30, 10, 10, 20)):
        w = rng.random(n) ** 4
        w[rng.random(n) < 0.3] = 0.0
        w[0] += 1e-3
        w /= w.sum()
        pool = np.concatenate([np.arange(n_out), np.arange(start, stop)])
        u = float(np.random.default_rng(7).random())
        want = pool[systematic_resample(w[pool], np.random.default_rng(7))]
        want = want[:n_out] if len(pool) == n_out else None
        src = np.arange(n)
        with np.errstate(divide="ignore"):
            lw = np.log(w)
        e, f, v, ww = src.copy(), src.astype(float), src.copy(), w.copy()
        spread = np.stack([src, -src], 1).astype(float)
        total = _resample_pool(ww, n_out, start, stop, u, e, f, v, lw, np.empty(n, dtype=np.int64), np.empty(n),
                               np.empty(n, dtype=np.int64), spread, np.empty((n, 2)))
        np.testing.assert_array_equal(spread[:, 0], e)  # the velocity distributions travel with their particles
        assert total == pytest.approx(w[pool].sum())
        if want is not None:
            np.testing.assert_array_equal(e[:n_out], want)
        else:  # a pool larger than its slots: the positions (u + k) / n_out over the pool
            c = np.cumsum(w[pool]) / w[pool].sum()
            np.testing.assert_array_equal(e[:n_out], pool[np.searchsorted(c, (u + np.arange(n_out)) / n_out,
                                                                          side="right")])
        assert np.all(w[e[:n_out]] > 0)
        np.testing.assert_allclose(ww[:n_out], total / n_out)
        rest = np.setdiff1d(np.arange(n), np.arange(n_out))
        np.testing.assert_array_equal(e[rest], rest)
        np.testing.assert_array_equal(ww[rest], w[rest])
