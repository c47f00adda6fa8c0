"""The combined model's filters give the same bits after the live step's passes were fused.

Whole runs of the registry's default model (``combined``: the tempered whole-image model
and the sequence part) through the grid filter and the particle filter, on a difference
matrix with a route, a jump backwards and (optionally) a run of hubs that the hub
correction partly removes, are reduced to digests of every estimate, the models' learned
scalars and every posterior. The digests were recorded with the code before its passes
were fused (separate numpy passes for the sums, maxima, centring, ratios, feedback
smoothing and predicted masses); the fused code must reproduce them bit for bit. Some
filter kernels are compiled with ``fastmath``, so the digests hold for the processor they
were recorded on; elsewhere the comparison is skipped (the kernels' own tests, against
the numpy formulas, still apply).
"""

import hashlib

import numpy as np
import pytest

from catgraph.graph import PlaceGraph
from catgraph.localizer import _smoothed, neighbourhood_means
from catgraph.methods import make_filter, observation_model, resolve_params

from .conftest import RECORDED_ON, host_processor

DIGESTS = {
    ("grid", False): "6e7a5aa2951a2cb855057bd41c6c8faa99474a9309d3cbe31af437bde6a0d406",
    ("grid", True): "e3af9c646e697dab64266b121463694402542904e09e52c0185f14612475ac1d",
    ("particles", False): "47b7acf4bc783ec3d89ad6513e4d6c002d2f9c826495c155e030a860237476ae",
    ("particles", True): "1c1a158958f1647d009beaa4573daeb2cd46056a9e620c3e63a289dfcbb5f220",
}


def _matrix(n_places: int, n_frames: int, seed: int, hubs: bool) -> np.ndarray:
    """A normalised difference matrix: a route forwards, then a jump and a route backwards;
    with ``hubs``, 15 places (half a percent) look like every frame."""
    rng = np.random.default_rng(seed)
    half = n_frames // 2
    truth = np.concatenate([np.arange(40, 40 + half),
                            np.arange(n_places // 2, n_places // 2 + n_frames - half)[::-1]])
    d = rng.normal(size=(n_frames, n_places))
    d[np.arange(n_frames), truth] -= 3.0
    d[np.arange(n_frames), np.minimum(truth + 1, n_places - 1)] -= 1.5
    if hubs:
        d[:, 200:215] -= 2.5
    return (d - d.mean(1, keepdims=True)) / d.std(1, keepdims=True)


def _digest(mode: str, hubs: bool, seed: int = 0, n_places: int = 3000, n_frames: int = 120) -> str:
    d = _matrix(n_places, n_frames, seed, hubs)
    extra = {"n_particles": 400, "seed": seed} if mode == "particles" else {}
    # the sequence part with the window rule the digests were recorded with (the default then)
    p = resolve_params("filter", {"model": "combined", "mode": mode, "rule": "unrivalled", **extra})
    obs = observation_model(p, n_places, None)
    obs.models[1].temperature = "window"  # the sequence part's temperature then (the default is now "longest")
    obs.models[0].jump_evidence = False  # no jump evidence then (catgraph.jumps)
    loc = make_filter(p, PlaceGraph.chain(n_places), obs)
    if mode == "grid":
        loc.blur = 0.01  # the grid filter's blur then (the default is now 0.005)
        loc.jump_velocity = "current"  # a jump's velocity then (the registry's is now "long-run")
        loc.rigid_prior = 0.0  # no rigid line then (the registry's is now 0.05 on maps of this size)
        loc.home_speed_odds = 1.0  # a uniform velocity prior then (the registry's now favours ±1)
        loc.outlier_probability = 0.0  # no outlier frames then (the registry's are now 1 %)
    else:
        loc.motion.blur = 0.01  # the particles follow the grid's blur unless given one
        loc.motion.max_phases = 1  # one bin per speed then (the particles' marginal motion now has phase bins)
    loc.reset()
    h = hashlib.sha256()
    tempered = obs.models[0]
    for k in range(n_frames):
        e = loc.step(d[k])
        h.update(repr((int(e.place), float(e.confidence).hex(), float(e.new_place_probability).hex(),
                       float(e.log_odds).hex(), float(e.score).hex(), float(tempered.temperature_).hex(),
                       float(tempered.novelty_).hex(), float(getattr(tempered, "hub_shrinkage_", 0.0)).hex())).encode())
        h.update(np.ascontiguousarray(loc.place_posterior_).tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("mode, hubs", sorted(DIGESTS))
def test_combined_filter_runs_are_the_bits_recorded_before_the_fusion(mode, hubs):
    if host_processor() != RECORDED_ON:
        pytest.skip("the digests were recorded on another processor (fastmath kernels round per machine)")
    assert _digest(mode, hubs) == DIGESTS[(mode, hubs)]


@pytest.mark.parametrize("radius", [1, 2, 7])
def test_smoothed_feedback_and_its_maximum_are_the_numpy_formula(radius):
    """The window means with numpy's total and the maximum found in the same pass: the
    plain formula (``mean`` per window, ``values.sum()``, the rescaling, ``.max()``)."""
    rng = np.random.default_rng(radius)
    for n in (1, 5, 129, 1000, 4099):
        mass = rng.random(n) ** 8
        mass[rng.random(n) < 0.3] = 0.0
        j = np.arange(n)
        lo, hi = np.maximum(j - radius, 0), np.minimum(j + radius + 1, n)
        out, top = _smoothed(mass, lo, hi, None)
        assert np.array_equal(out, neighbourhood_means(mass, lo, hi, None))
        assert top == out.max()
        plain = np.array([mass[a:b].mean() for a, b in zip(lo, hi)])
        want = plain * (mass.sum() / plain.sum()) if plain.sum() > 0 and mass.sum() > 0 else plain
        np.testing.assert_allclose(out, want, rtol=0, atol=1e-13 * want.max())  # the running sums round
        ptr = np.concatenate([[0], np.cumsum(hi - lo)])
        index = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)])
        listed, listed_top = _smoothed(mass, ptr, index, True)
        assert listed_top == listed.max()
        narrow, narrow_top = _smoothed(mass, lo.astype(np.int32), hi.astype(np.int32), None)  # the filters' ends
        assert np.array_equal(narrow, out) and narrow_top == top


@pytest.mark.parametrize("route", [False, True])
def test_confidence_neighbourhoods_are_int32_and_the_int64_ends(route):
    """The filters hold each place's window ends as int32 (half the memory at 10⁵ places):
    the same places as the int64 ends."""
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import confidence_neighbourhoods

    n = 3001
    graph = PlaceGraph.chain(n)
    distance = np.cumsum(np.random.default_rng(2).uniform(0.5, 2.0, n)) if route else None
    lo, hi, is_list = confidence_neighbourhoods(graph, 4, None, None, distance, 6.0)
    assert is_list is None and lo.dtype == hi.dtype == np.int32
    if route:
        want_lo = np.searchsorted(distance, distance - 6.0, "left")
        want_hi = np.searchsorted(distance, distance + 6.0, "right")
    else:
        j = np.arange(n)
        want_lo, want_hi = np.maximum(j - 4, 0), np.minimum(j + 5, n)
    assert np.array_equal(lo, want_lo) and np.array_equal(hi, want_hi)


def test_the_particle_filter_forms_the_prior_only_for_models_that_read_it():
    """``feedback_reads_prior``: the default models do not read the predicted masses (the
    particle filter skips them); a predictive temperature, predictive weights and a model
    that does not say are given them, the same masses either way."""
    from catgraph.localizer import Localizer
    from catgraph.observation import (CombinedObservation, SequenceObservation, TemperedObservation,
                                      feedback_reads_prior)

    assert not feedback_reads_prior(TemperedObservation())
    assert feedback_reads_prior(TemperedObservation(temperature="predictive"))
    assert feedback_reads_prior(TemperedObservation(hub_weights=(0.5, 1.0)))
    assert not feedback_reads_prior(TemperedObservation(hub=None, hub_weights=(0.5, 1.0)))
    part = SequenceObservation(window=5, calibration="agreement")
    assert not feedback_reads_prior(CombinedObservation([TemperedObservation(), part]))
    assert feedback_reads_prior(CombinedObservation([TemperedObservation(), part], weights="predictive"))

    class Recording(TemperedObservation):  # its reset keeps only its parameters: record outside
        priors: list = []

        def feedback(self, feedback):
            self.priors.append(None if feedback.prior is None else feedback.prior.copy())
            super().feedback(feedback)

    class Silent(Recording):  # no say: treated as reading the prior
        priors: list = []
        _reads_prior = None

    d = _matrix(400, 30, 3, True)
    runs = {}
    for says, kind in ((False, Recording), (True, Silent)):
        model = kind()
        loc = Localizer(PlaceGraph.chain(400), model, 300, seed=1)
        runs[says] = [loc.step(r).score for r in d], kind.priors
    assert runs[False][0] == runs[True][0]  # the same answers
    assert all(p is None for p in runs[False][1])
    given = runs[True][1]
    assert all(p is not None and p.shape == (400,) and np.isclose(p.sum(), 1.0) for p in given[1:])


def test_recent_support_is_formed_on_first_read_and_keeps_its_frame():
    """The sequence part's recent support forms its window scores only when read: a grid
    filter, which never reads it, never pays for them; a support still held when the next
    frame comes keeps its own frame's values; one read after its matcher was stepped
    directly is refused."""
    from catgraph.exceptions import NotFittedError
    from catgraph.observation import RecentSupport, SequenceObservation

    d = _matrix(500, 12, 4, False)
    model = SequenceObservation(window="adaptive", matcher_params={"l_max": 8, "l_min": 2},
                                calibration="agreement", temperature="window", agreement_scale=1.0)
    calls = []
    held = []
    chosen_shortest = 0  # frames whose own window is the shortest (observe reads those scores itself)
    for k, row in enumerate(d):
        obs = model.observe(row)
        if k == 0:
            m = model.matcher_
            plain = m.window_scores
            m.window_scores = lambda length, velocity=None: calls.append(length) or plain(length, velocity)
        shortest = int(m.window_grid_[0])
        chosen_shortest += k > 0 and int(model.last_match_.window_length) == shortest
        eager = RecentSupport(plain(shortest, float(model.last_match_.velocity)))
        if k % 3 == 0:
            held.append((obs.support, np.asarray(eager).copy()))
        del obs
    assert calls.count(shortest) == chosen_shortest + len(held)  # formed only for the supports still held
    for support, want in held:
        assert np.array_equal(np.asarray(support), want)
    obs = model.observe(d[0])
    model.matcher_.step(d[1])  # stepped directly: the support's frame is gone
    with pytest.raises(NotFittedError, match="earlier frame"):
        obs.support[0]


def test_frame_pool_never_hands_out_an_array_someone_holds():
    from catgraph.observation import FramePool

    pool = FramePool(3)
    a = pool.take(10)
    a_id = id(a)
    del a
    b = pool.take(10)
    assert id(b) == a_id  # released: taken again
    c = pool.take(10)
    assert c is not b  # b is still held
    view = c[2:5]
    del c
    d = pool.take(10)
    assert d.base is None and d is not view.base and d is not b  # a view holds its base
    assert pool.take(7).shape == (7,)  # another length: its own array


def test_frame_pool_hands_out_arrays_of_the_shape_and_dtype_asked():
    from catgraph.observation import FramePool

    pool = FramePool(4)
    s = pool.take((3, 10), np.float32)
    assert s.shape == (3, 10) and s.dtype == np.float32
    s_id = id(s)
    del s
    assert pool.take(30, np.float32).shape == (30,)  # the same bytes, another shape: not this one
    f64 = pool.take((3, 10))
    assert f64.dtype == np.float64 and id(f64) != s_id  # another dtype: not this one
    again = pool.take((3, 10), np.float32)
    assert id(again) == s_id  # released, the same shape and dtype: taken again
    assert pool.take((3, 10), np.float32) is not again  # still held


@pytest.mark.parametrize("mode", ["grid", "particles"])
def test_kept_posteriors_are_never_overwritten(mode):
    """A caller that keeps every frame's posterior (and the ratios of a model it calls
    directly) holds arrays the filter never writes again: the same values as the run's
    own, frame by frame."""
    d = _matrix(600, 25, 5, True)
    extra = {"n_particles": 300, "seed": 2} if mode == "particles" else {}
    p = resolve_params("filter", {"model": "combined", "mode": mode, **extra})

    def run(keep: bool):
        obs = observation_model(p, 600, None)
        loc = make_filter(p, PlaceGraph.chain(600), obs)
        loc.reset()
        kept, copies = [], []
        for row in d:
            loc.step(row)
            copies.append(loc.place_posterior_.copy())
            if keep:
                kept.append(loc.place_posterior_)
        return kept, copies

    kept, copies = run(True)
    assert len({id(x) for x in kept}) == len(kept)
    assert all(np.array_equal(k, c) for k, c in zip(kept, copies))
    assert all(np.array_equal(a, b) for a, b in zip(copies, run(False)[1]))


def test_handed_on_maxima_are_the_arrays_maxima():
    """``Observation.log_ratio_max`` and ``FilterFeedback.posterior_max`` are exactly the
    maxima of the arrays they come with (the filters and models use them instead of a
    pass of their own)."""
    from catgraph.observation import FilterFeedback, TemperedObservation

    d = _matrix(700, 20, 6, True)
    seen = []

    class Watching(TemperedObservation):
        def feedback(self, feedback: FilterFeedback) -> None:
            seen.append(feedback.posterior_max == np.asarray(feedback.posterior).max())
            super().feedback(feedback)

    for mode in ("grid", "particles"):
        extra = {"n_particles": 300} if mode == "particles" else {}
        p = resolve_params("filter", {"model": "combined", "mode": mode, **extra})
        obs = observation_model(p, 700, None)
        obs.models[0].__class__ = Watching
        loc = make_filter(p, PlaceGraph.chain(700), obs)
        loc.reset()
        for row in d:
            loc.step(row)
            o = obs.observe(row)  # a direct call: the combined ratios and their maximum
            assert o.log_ratio_max == o.log_ratio.max()
        single = TemperedObservation()
        for row in d[:5]:
            o = single.observe(row)
            assert o.log_ratio_max == o.log_ratio.max()
    assert len(seen) > 30 and all(seen)
