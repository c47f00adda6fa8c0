"""The exact grid filter: kernels against slow references, localisation, and the particle
filter converging to it as particles grow."""

import math

import numpy as np
import pytest

from catgraph.exceptions import DataError, InvalidParameterError, ShapeMismatchError
from catgraph.graph import PlaceGraph
from catgraph.grid import (GridLocalizer, _bin_moves, _frames_rows, _sparse_columns, _transition_rows, predict,
                           route_neighbours, velocity_transition)
from catgraph.localizer import Localizer
from catgraph.motion import VelocityMotion
from catgraph.observation import CombinedObservation, SequenceObservation, TemperedObservation


def _fixed(tau=1.0):
    return TemperedObservation(likelihood="linear", hub=None, temperature=tau)


# ---------------------------------------------------------------------- slow references
def _walk(j, sign, hops, fwd, bwd, jptr, jdst, p_junction, has_mirror):
    """Distribution of (place, sign flipped?) after ``hops`` hops from ``j``: recursive."""
    if hops == 0:
        return {(j, False): 1.0}
    out: dict = {}
    nj = jptr[j + 1] - jptr[j]
    pj = min(0.5, p_junction * nj)
    t = fwd[j] if sign > 0 else bwd[j]
    branches = []
    if t >= 0:
        branches.append((t, sign, 1.0 - pj, False))
    for c in range(jptr[j], jptr[j + 1]):
        branches.append((jdst[c], sign, pj / nj * 0.5, False))
        # the other direction exists only where the mirror bin does
        branches.append((jdst[c], -sign, pj / nj * 0.5, True) if has_mirror else (jdst[c], sign, pj / nj * 0.5, False))
    for k, s, w, flipped in branches:
        for (place, f2), m in _walk(k, s, hops - 1, fwd, bwd, jptr, jdst, p_junction, has_mirror).items():
            key = (place, flipped != f2)
            out[key] = out.get(key, 0.0) + w * m
    return out


def _reference_predict(state, v, stay, reverse, blur, recovery, graph, p_junction):
    n, nb = state.shape
    fwd, bwd, _, _, jptr, jdst = route_neighbours(graph)
    p = state @ velocity_transition(v, stay, reverse)
    moved = np.zeros_like(p)
    mirror = {b: int(np.flatnonzero(np.isclose(v, -v[b]))[0]) if np.isclose(v, -v[b]).any() else b
              for b in range(nb)}
    for j in range(n):
        for b in range(nb):
            whole = int(math.floor(abs(v[b])))
            frac = abs(v[b]) - whole
            sign = 1 if v[b] >= 0 else -1
            for hops, w in ((whole, 1.0 - frac), (whole + 1, frac)):
                if w == 0:
                    continue
                for (place, flipped), m in _walk(j, sign, hops, fwd, bwd, jptr, jdst, p_junction,
                                                  mirror[b] != b).items():
                    moved[place, mirror[b] if flipped else b] += w * m * p[j, b]
    out = (1 - 2 * blur) * moved
    for j in range(n):
        out[fwd[j] if fwd[j] >= 0 else j] += blur * moved[j]
        out[bwd[j] if bwd[j] >= 0 else j] += blur * moved[j]
    out /= out.sum()
    return (1 - recovery) * out + recovery / (n * nb)


@pytest.mark.parametrize("junctions", [None, [(3, 9)], [(2, 8), (2, 11)]])
def test_predict_matches_slow_reference(junctions):
    rng = np.random.default_rng(0)
    n = 14
    g = PlaceGraph.from_edges(n, np.array([(i, i + 1) for i in range(n - 1)] + [(i + 1, i) for i in range(n - 1)]),
                              kinds=np.array([0] * (n - 1) + [1] * (n - 1))) if junctions is None else None
    if g is None:
        from catgraph.traverse import Traverse

        g = PlaceGraph.from_traverse(Traverse(np.zeros((n, 2))), junctions=np.array(junctions))
    v = np.array([-2.0, -1.0, -0.5, 0.5, 1.0, 2.5])
    state = rng.random((n, len(v)))
    state /= state.sum()
    got = predict(state, velocity_transition(v, 0.8, 0.05), v, route_neighbours(g), 0.1, 0.02,
                  np.full(len(v), 1 / len(v)), 0.2)
    want = _reference_predict(state, v, 0.8, 0.05, 0.1, 0.02, g, 0.2)
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert got.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("density", [0.0, 0.05, 0.3, 1.0])
def test_sparse_transition_product_equals_the_dense_product(density):
    """The velocity transition applied from its sparse columns (junctions, odometry) is
    ``state @ transition``, empty columns and a dense matrix included."""
    rng = np.random.default_rng(int(density * 100))
    transition = rng.random((13, 13)) * (rng.random((13, 13)) < density)
    state = rng.random((40, 13))
    got = np.full((13, 40), np.nan)  # the filter's layout: (bins, places)
    _transition_rows(np.ascontiguousarray(state.T), got, *_sparse_columns(transition))
    np.testing.assert_allclose(got.T, state @ transition, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("distance", [0.0, 0.7, 2.0, 3.3, 9.5, 30.0])
def test_odometry_prediction_matches_slow_reference(distance):
    """The odometry step (the filter's ``(bins, places)`` rows, each place walked once a way)
    against the slow references: the dense velocity transition, each bin's mass walked the
    distance along uneven edges (``_slow_odometry_shift``), the blur and the recovery share
    written out; phase bins, both route ends."""
    from catgraph.grid import phase_bins, phase_transition
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(int(distance * 10))
    n = 25
    lengths = rng.uniform(0.5, 3.0, n - 1)
    positions = np.c_[np.r_[0.0, np.cumsum(lengths)], np.zeros(n)]
    g = PlaceGraph.from_traverse(Traverse(np.zeros((n, 2)), positions=positions))
    np.testing.assert_allclose(route_neighbours(g)[2][:-1], lengths)  # the edges are as long as drawn
    v = np.array([-2.0, -1.0, -0.5, 0.5, 1.0, 2.5, 4.0])
    owner, _, _, _, _, successor = phase_bins(v, 4)
    transition = phase_transition(velocity_transition(v, 0.8, 0.05), owner, successor)
    nb = len(owner)
    state = rng.random((n, nb))
    state[[0, n - 1]] += 1.0
    state /= state.sum()
    blur, recovery = 0.1, 0.02
    got = predict(state, transition, v[owner], route_neighbours(g), blur, recovery, np.full(nb, 1.0 / nb), 0.3,
                  odometry=distance)
    moved = _slow_odometry_shift(state @ transition, v[owner], lengths, distance)
    want = (1 - 2 * blur) * moved
    want[1:] += blur * moved[:-1]  # one place on (the last place keeps its own share)
    want[-1] += blur * moved[-1]
    want[:-1] += blur * moved[1:]  # one place back (the first keeps its own)
    want[0] += blur * moved[0]
    want = (1 - recovery) * want / want.sum() + recovery / (n * nb)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_frames_kernel_equals_walk_kernel_without_junctions():
    rng = np.random.default_rng(1)
    g = PlaceGraph.chain(30)
    v = np.array([-3.0, -1.0, 0.5, 1.0, 1.5, 3.0])
    fwd, bwd, _, _, jptr, jdst = route_neighbours(g)
    whole, frac, sign, mirror = _bin_moves(v)
    p = rng.random((30, len(v)))
    a = np.empty((len(v), 30))
    _frames_rows(np.ascontiguousarray(p.T), a, whole, frac, sign, mirror, fwd, bwd, jptr, jdst, 0.0)
    b = predict(p / p.sum(), np.eye(len(v)), v, (fwd, bwd, _, _, jptr, jdst), 0.0, 0.0, np.ones(len(v)), 0.0)
    np.testing.assert_allclose(a.T / a.sum(), b, atol=1e-12)


def test_odometry_shift_follows_edge_lengths():
    from catgraph.traverse import Traverse

    odometry = np.array([0.0, 1.0, 3.0, 1.0, 1.0, 2.0])
    g = PlaceGraph.from_traverse(Traverse(np.zeros((6, 2)), odometry=odometry))
    state = np.zeros((6, 2))
    state[1, 1] = 1.0  # place 1, forwards
    out = predict(state, np.eye(2), np.array([-1.0, 1.0]), route_neighbours(g), 0.0, 0.0, np.ones(2) / 2, 0.0,
                  odometry=2.0)
    # from place 1 (route 1 m) 2 m forwards: 2/3 of the 3 m edge to place 2
    np.testing.assert_allclose(out[:, 1], [0, 1 / 3, 2 / 3, 0, 0, 0])


# ---------------------------------------------------------------------- the filter
def _track_rows(n_places, places, rng, depth=3.0):
    rows = rng.standard_normal((len(places), n_places))
    rows[np.arange(len(places)), places] -= depth
    return rows


@pytest.mark.parametrize("speed", [1, -1, 2])
def test_grid_filter_follows_a_track(speed):
    rng = np.random.default_rng(2)
    n = 200
    start = 20 if speed > 0 else 180
    places = start + speed * np.arange(60)
    res = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0)).run(_track_rows(n, places, rng, depth=2.0))
    assert np.mean(np.abs(res.place[20:] - places[20:]) <= 2) > 0.95
    assert res.confidence[-1] > 0.9
    assert np.all(np.isfinite(res.log_odds))


def test_confidence_falls_after_a_jump():
    rng = np.random.default_rng(3)
    n = 300
    places = np.concatenate([20 + np.arange(60), 200 + np.arange(40)])
    res = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0)).run(_track_rows(n, places, rng, depth=2.0))
    before = res.log_odds[55:60].mean()
    assert res.log_odds[61] < before  # the first frame after the jump is less sure
    assert np.all(np.abs(res.place[75:] - places[75:]) <= 2)  # and the new track is found


def test_log_odds_finite_when_confidence_is_one():
    g = PlaceGraph.chain(2)
    rows = np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0]])
    res = GridLocalizer(g, _fixed(), confidence_radius=2, new_place_prior=0.0).run(rows)
    np.testing.assert_allclose(res.confidence, 1.0)
    assert np.all(np.isfinite(res.log_odds)) and np.all(res.log_odds > 600)
    loc = Localizer(g, _fixed(), n_particles=1, confidence_radius=2, new_place_prior=0.0)
    est = [loc.step(r) for r in rows]
    assert all(np.isfinite(e.log_odds) and e.log_odds > 600 and e.confidence == pytest.approx(1.0) for e in est)


def test_log_odds_ordered_by_confidence():
    from catgraph.localizer import confidence_log_odds

    odds = [confidence_log_odds(1 - w, w, 0.0, -math.inf)[1] for w in (0.5, 1e-3, 1e-200, 0.0)]
    assert np.all(np.isfinite(odds)) and np.all(np.diff(odds) > 0)



def _reference_score(log_odds, level, frames, penalty):
    """The ranking score, slowly: the log-odds, less ``penalty`` at every frame before the
    first run of ``frames`` consecutive log-odds above ``level`` is complete."""
    out = np.array(log_odds, dtype=float)
    for k in range(len(out)):
        converged = frames == 0 or any(np.all(np.asarray(log_odds[t - frames + 1:t + 1]) > level)
                                       for t in range(frames - 1, k + 1))
        if not converged:
            out[k] -= penalty
    return out


@pytest.mark.parametrize("level,frames,penalty", [(1.0, 8, 1.0), (3.0, 3, 2.5), (0.0, 0, 1.0), (1.0, 8, 0.0)])
def test_score_is_lowered_until_the_filter_first_converges(level, frames, penalty):
    rng = np.random.default_rng(5)
    n = 300
    # a weak start (the filter is unsure), a track, then a jump: the penalty never returns
    places = np.concatenate([rng.integers(0, n, 15), 20 + np.arange(60), 200 + np.arange(40)])
    rows = _track_rows(n, places, rng, depth=2.0)
    rows[:15] = rng.standard_normal((15, n))
    loc = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), converged_log_odds=level, converged_frames=frames,
                        unconverged_penalty=penalty)
    res = loc.run(rows)
    expected = _reference_score(res.log_odds, level, frames, penalty)
    np.testing.assert_allclose(res.score, expected)
    assert loc.converged_
    if penalty > 0 and frames > 0:
        assert res.score[0] == res.log_odds[0] - penalty  # the first frames are penalised
        assert np.any(res.score[-60:] == res.log_odds[-60:])  # the converged track is not
    step = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), converged_log_odds=level, converged_frames=frames,
                         unconverged_penalty=penalty)
    np.testing.assert_allclose([step.step(r).score for r in rows], res.score)  # one step = run


def test_confidence_neighbourhood_is_measured_along_the_route():
    """On a map surveyed as several samples per point, the confidence counts the places
    within ``confidence_radius`` mean spacings of route distance (the answer's own point),
    not ``confidence_radius`` index steps (which would reach into the next point)."""
    per_point, n_points, gap = 4, 12, 4.0
    n = per_point * n_points
    rd = np.repeat(np.arange(n_points) * gap, per_point).astype(float)
    i = np.arange(n - 1)
    edges = np.concatenate([np.stack([i, i + 1], 1), np.stack([i + 1, i], 1)]).astype(np.int64)
    lengths = np.tile(np.maximum(np.diff(rd), 1e-6), 2)
    kinds = np.concatenate([np.zeros(n - 1, np.int64), np.ones(n - 1, np.int64)])
    g = PlaceGraph.from_edges(n, edges, lengths, kinds, route_distance=rd, unit="m")
    rng = np.random.default_rng(7)
    rows = rng.standard_normal((30, n))
    rows[np.arange(30), np.arange(30) + 5] -= 2.0
    loc = GridLocalizer(g, _fixed(1.0))
    spacing = g.frame_spacing
    differs = 0
    for row in rows:
        est = loc.step(row)
        post = loc.place_posterior_
        near = np.abs(rd - rd[est.place]) <= 2 * spacing + 1e-12
        assert est.confidence == pytest.approx(post[near].sum(), rel=1e-9)
        index_window = post[max(0, est.place - 2):est.place + 3].sum()
        differs += not np.isclose(est.confidence, index_window)
    assert 2 * spacing < gap  # the radius stays within a point here ...
    assert differs > 0  # ... so the confidence is not the index window's


def test_confidence_neighbourhood_on_an_even_route_is_the_index_window():
    rng = np.random.default_rng(8)
    n = 80
    g = PlaceGraph.chain(n, spacing=3.0)
    rows = _track_rows(n, 10 + np.arange(40), rng, depth=2.0)
    loc = GridLocalizer(g, _fixed(1.0), confidence_radius=2)
    for row in rows:
        est = loc.step(row)
        assert est.confidence == pytest.approx(loc.place_posterior_[max(0, est.place - 2):est.place + 3].sum(),
                                               rel=1e-9)


def test_sequence_part_calibrated_by_agreement_is_the_tempered_ratio_of_its_scores():
    """``calibration="agreement"``: the log-ratio is ``(1/L_k) · τ · (−z)``, ``z`` the
    standardised window scores, ``τ = agreement_scale · ρ`` (ρ starts at 1/2 and learns
    from the filter's feedback)."""
    from catgraph.observation import FilterFeedback

    rng = np.random.default_rng(9)
    n = 60
    places = 5 + np.arange(30)
    rows = _track_rows(n, places, rng, depth=2.0)
    obs = SequenceObservation(window=10, calibration="agreement", temperature="window", agreement_scale=3.0)
    taus = []
    for k, row in enumerate(rows):
        out = obs.observe(row)
        s = obs.window_scores()
        z = (s - s.mean()) / s.std()
        tau = obs._tempered.temperature_
        taus.append(tau)
        np.testing.assert_allclose(out.log_ratio, tau / int(obs.last_match_.window_length) * (-z), rtol=1e-9,
                                   atol=1e-12)
        top = float(out.log_ratio.max())
        assert out.new_place_log_ratio == pytest.approx(top + math.log(np.mean(np.exp(out.log_ratio - top))))
        post = np.zeros(n)
        post[places[k]] = 1.0
        obs.feedback(FilterFeedback(post, post, slice(places[k] - 2, places[k] + 3)))
    assert taus[0] == pytest.approx(1.5)  # 3 · ½ before any feedback
    assert taus[-1] > 2.0  # the filter confirmed the part's best place: ρ rose towards 1


def test_sequence_calibration_validated():
    with pytest.raises(InvalidParameterError, match="calibration"):
        SequenceObservation(window=10, calibration="bogus").observe(np.zeros(20))


def test_combined_with_agreement_calibrated_sequence_part_tracks():
    rng = np.random.default_rng(10)
    n = 120
    places = 10 + np.arange(70)
    model = CombinedObservation([TemperedObservation(hub=None),
                                 SequenceObservation(window=10, calibration="agreement", temperature="window")],
                                reliability=None)
    res = GridLocalizer(PlaceGraph.chain(n), model).run(_track_rows(n, places, rng, depth=1.5))
    assert np.mean(np.abs(res.place[20:] - places[20:]) <= 2) > 0.9

@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
def test_bad_odometry_refused_on_every_step_first_included(bad):
    g = PlaceGraph.chain(10)
    row = np.zeros(10)
    for loc in (GridLocalizer(g, _fixed()), Localizer(g, _fixed(), n_particles=10)):
        with pytest.raises(DataError, match="odometry"):
            loc.step(row, odometry=bad)
        loc.reset()
        loc.step(row, odometry=1.0)
        with pytest.raises(DataError, match="odometry"):
            loc.step(row, odometry=bad)


def test_parameters_validated():
    g = PlaceGraph.chain(10)
    with pytest.raises(InvalidParameterError, match="velocities"):
        GridLocalizer(g, _fixed(), velocities=[1.0, 1.0]).reset()
    with pytest.raises(InvalidParameterError, match="blur"):
        GridLocalizer(g, _fixed(), blur=0.5).reset()
    with pytest.raises(InvalidParameterError, match="converged_frames"):
        GridLocalizer(g, _fixed(), converged_frames=-1).reset()
    with pytest.raises(InvalidParameterError, match="unconverged_penalty"):
        GridLocalizer(g, _fixed(), unconverged_penalty=-1.0).reset()
    with pytest.raises(ShapeMismatchError):
        GridLocalizer(g, _fixed()).step(np.zeros(9))
    with pytest.raises(DataError):
        GridLocalizer(g, _fixed()).step(np.full(10, np.nan))


def test_model_receives_feedback_once_per_step():
    class Counting:
        def __init__(self):
            self.calls = []

        def reset(self):
            self.calls = []

        def observe(self, row):
            from catgraph.observation import Observation

            return Observation(-np.asarray(row, dtype=float), 0.0)

        def feedback(self, fb):
            self.calls.append((fb.prior.sum(), fb.posterior.sum()))

    g = PlaceGraph.chain(20)
    rows = np.random.default_rng(0).standard_normal((5, 20))
    for loc in (GridLocalizer(g, Counting(), new_place_prior=0.0),
                Localizer(g, Counting(), n_particles=50, new_place_prior=0.0)):
        loc.run(rows)
        assert len(loc.model.calls) == 5
        np.testing.assert_allclose(np.array(loc.model.calls), 1.0)


# ---------------------------------------------------------------------- particles → grid
def _total_variation(a, b):
    return 0.5 * float(np.abs(a / a.sum() - b / b.sum()).sum())


def test_particle_filter_converges_to_grid_filter():
    rng = np.random.default_rng(4)
    n = 40
    places = 10 + np.arange(8)
    rows = _track_rows(n, places, rng, depth=1.5)
    v = (-1.0, 1.0, 2.0)
    kw = dict(velocity_stay=0.8, reverse_probability=0.05, blur=0.1)
    grid = GridLocalizer(PlaceGraph.chain(n), _fixed(0.7), velocities=v, recovery=0.0, **kw)
    grid.run(rows)
    exact = grid.place_posterior_
    tv = {}
    for n_particles in (100, 10_000):
        d = []
        for seed in range(3):
            loc = Localizer(PlaceGraph.chain(n), _fixed(0.7), n_particles=n_particles, redraw_fraction=0.0,
                            new_place_prior=0.0, motion=VelocityMotion(velocities=v, **kw), seed=seed)
            loc.run(rows)
            d.append(_total_variation(loc.place_posterior_, exact))
        tv[n_particles] = np.mean(d)
    assert tv[10_000] < tv[100]
    assert tv[10_000] < 0.05


# ---------------------------------------------------------------------- the line graph's fast path
#: The fast path stores the prediction in float32 (sums and likelihoods in float64): its
#: agreement with the float64 general path, relative, over a few dozen steps.
FLOAT32 = dict(rtol=1e-5, atol=1e-12)
EXACT = dict(rtol=1e-9, atol=1e-15)


def _float64_state(loc):
    """The fast path with its state kept in float64 (the kernel is the same)."""
    loc._state = loc._state.astype(np.float64)
    return loc


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("velocities", [(-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), (-1.0, 0.0, 1.5, 2.0)])
def test_line_fast_path_equals_the_general_path(velocities, precision):
    """The fused line kernel (index arithmetic) against the general graph walk, step by
    step: same predicted and posterior place masses, same learned jump rate; exactly
    (to round-off) with a float64 state, to float32's precision with the default one."""
    rng = np.random.default_rng(5)
    n = 60
    rows = _track_rows(n, 3 + np.arange(40), rng, depth=1.5)
    rows[25:] = _track_rows(n, 50 - np.arange(15), rng, depth=1.5)  # a jump and a turn
    fast = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8), velocities=velocities).reset()
    slow = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8), velocities=velocities).reset()
    assert fast._line and fast._state.dtype == np.float32
    slow._line = False
    slow._state = slow._state.astype(np.float64)
    tol = FLOAT32 if precision == "float32" else EXACT
    if precision == "float64":
        _float64_state(fast)
    for row in rows:
        a, b = fast.step(row), slow.step(row)
        np.testing.assert_allclose(fast.prior_, slow.prior_, **tol)
        np.testing.assert_allclose(fast.place_posterior_, slow.place_posterior_, **tol)
        np.testing.assert_allclose(fast.state_, slow.state_, **tol)
        assert a.place == b.place and fast.recovery_ == pytest.approx(slow.recovery_, rel=tol["rtol"])


def test_line_detection():
    from catgraph.traverse import Traverse

    assert GridLocalizer(PlaceGraph.chain(10), _fixed()).reset()._line
    assert not GridLocalizer(PlaceGraph.chain(10, bidirectional=False), _fixed()).reset()._line
    g = PlaceGraph.from_traverse(Traverse(np.zeros((10, 2))), junctions=np.array([(2, 7)]))
    assert not GridLocalizer(g, _fixed()).reset()._line


# ---------------------------------------------------------------------- new place and jumps
def test_new_place_probability_rises_after_a_jump_and_in_unmapped_space():
    rng = np.random.default_rng(6)
    n = 300
    rows = _track_rows(n, 20 + np.arange(60), rng, depth=2.5)
    jump = _track_rows(n, 200 + np.arange(30), rng, depth=2.5)
    unmapped = rng.standard_normal((20, n))  # frames like no place of the map
    res = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), new_place_prior=0.05).run(np.vstack([rows, jump, unmapped]))
    p_new = res.new_place_probability
    on_track = p_new[45:60].mean()
    assert on_track < 0.05  # on a track the map explains the frames
    assert p_new[60:63].max() > 0.3  # the track stops explaining them: at once
    assert res.confidence[60:63].min() < 0.5 < res.confidence[45:60].min()
    assert np.all(np.abs(res.place[70:90] - (200 + np.arange(10, 30))) <= 2)  # the new track is found
    assert p_new[70:90].mean() < 0.05
    assert p_new[95:].mean() > 5 * on_track and res.confidence[95:].max() < 0.8  # unmapped frames


def test_jump_rate_is_learned_from_the_frames():
    rng = np.random.default_rng(7)
    n = 400
    in_order = _track_rows(n, 10 + np.arange(300), rng, depth=2.0)
    starts = rng.integers(0, n - 10, size=30)
    jumping = np.vstack([_track_rows(n, s + np.arange(10), rng, depth=2.0) for s in starts])
    rates = []
    for rows in (in_order, jumping):
        loc = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), recovery=0.05)
        loc.run(rows)
        rates.append(loc.recovery_)
    assert rates[0] < 0.02 < rates[1]
    loc = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), recovery=0.05, learn_recovery=False)
    loc.run(jumping)
    assert loc.recovery_ == 0.05
    loc = GridLocalizer(PlaceGraph.chain(n), _fixed(1.0), recovery=0.0)
    loc.run(jumping)
    assert loc.recovery_ == 0.0  # no jumps means none, learned or not


@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_line_fast_path_on_maps_shorter_than_a_hop(n):
    rows = np.random.default_rng(n).standard_normal((6, n))
    fast = _float64_state(GridLocalizer(PlaceGraph.chain(n), _fixed(0.8)).reset())
    slow = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8)).reset()
    slow._line = False
    for row in rows:
        fast.step(row), slow.step(row)
        np.testing.assert_allclose(fast.place_posterior_, slow.place_posterior_, **EXACT)


@pytest.mark.parametrize("block", [1, 4, 7, 64])
def test_line_fast_path_in_blocks_equals_the_general_path(block, monkeypatch):
    """The line kernel works through the route in blocks (with a halo of the largest hop
    and the blur): blocks smaller than a hop, and a last block shorter than the others,
    give the general walk's answer."""
    import catgraph.grid as grid

    monkeypatch.setattr(grid, "_LINE_BLOCK", block)
    rng = np.random.default_rng(11)
    n = 47
    rows = _track_rows(n, 2 + np.arange(30), rng, depth=1.5)
    rows[18:] = _track_rows(n, 44 - 2 * np.arange(12), rng, depth=1.5)  # a jump, then backwards at speed 2
    fast = _float64_state(GridLocalizer(PlaceGraph.chain(n), _fixed(0.8)).reset())
    slow = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8)).reset()
    slow._line = False
    for row in rows:
        fast.step(row), slow.step(row)
        np.testing.assert_allclose(fast.prior_, slow.prior_, **EXACT)
        np.testing.assert_allclose(fast.state_, slow.state_, **EXACT)


@pytest.mark.parametrize("block", [3, 16])
@pytest.mark.parametrize("velocities, max_phases", [((-2.0, -0.5, 0.5, 1.0, 2.0), 1), ((-1.0, 0.0, 0.3, 1.5, 2.0), 4)])
def test_line_fast_path_in_blocks_with_split_moves_equals_the_general_path(block, velocities, max_phases,
                                                                           monkeypatch):
    """Inside the route a whole move reads the shifted row directly and a split move (a
    fraction with more phases than ``max_phases``) goes through the moved-mass buffer:
    both, in blocks away from the route's ends, give the general walk's answer."""
    import catgraph.grid as grid

    monkeypatch.setattr(grid, "_LINE_BLOCK", block)
    rng = np.random.default_rng(12)
    n = 53
    rows = _track_rows(n, 3 + np.arange(30), rng, depth=1.5)
    rows[15:] = _track_rows(n, 40 - np.arange(15), rng, depth=1.5)  # a jump and a turn
    kw = dict(velocities=velocities, max_phases=max_phases)
    fast = _float64_state(GridLocalizer(PlaceGraph.chain(n), _fixed(0.8), **kw).reset())
    slow = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8), **kw).reset()
    assert np.any(fast._moves[1] > 0) and fast._line
    slow._line = False
    for row in rows:
        fast.step(row), slow.step(row)
        np.testing.assert_allclose(fast.prior_, slow.prior_, **EXACT)
        np.testing.assert_allclose(fast.state_, slow.state_, **EXACT)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_velocity_sums_formed_by_the_line_kernel_are_the_posterior_velocity_marginal(precision):
    """On the line path the update does not read the state again: the velocity sums are
    formed while the prediction is written. After every step they are the posterior's
    velocity marginal, ``Σ_j state[b, j] · like[j]`` (recomputed here from the stored
    state), and the kernel's prediction is the one it writes without them."""
    import catgraph.grid as grid

    rng = np.random.default_rng(13)
    n = 70
    rows = _track_rows(n, 5 + np.arange(40), rng, depth=1.5)
    rows[20:] = _track_rows(n, 60 - np.arange(20), rng, depth=1.5)  # a jump and a turn
    loc = GridLocalizer(PlaceGraph.chain(n), _fixed(0.8)).reset()
    if precision == "float64":
        _float64_state(loc)
    for k, row in enumerate(rows):
        if k > 0:  # the kernel with and without the sums, from the same posterior
            whole, frac, sign, _ = loc._moves
            args = (loc._state, loc._like, loc.prior_)
            rest = (*loc._t_sparse, whole, frac, sign, float(loc.blur), loc.recovery_, loc._jump_velocity(), 16)
            e = np.exp(rng.standard_normal(n))
            (out_a, mass_a, v_a), (out_b, mass_b, v_b) = [
                (np.empty_like(loc._state), np.empty(n), np.empty(len(loc._owner))) for _ in range(2)]
            grid._line_predict(*args, out_a, mass_a, *rest, e, v_a)
            grid._line_predict(*args, out_b, mass_b, *rest, np.empty(0), v_b)
            np.testing.assert_allclose(out_a, out_b, rtol=1e-15, atol=0)
            np.testing.assert_allclose(mass_a, mass_b, rtol=1e-15, atol=0)
            np.testing.assert_allclose(v_a, out_a.astype(np.float64) @ e, rtol=1e-12)
            assert np.all(v_b == 0.0)
        loc.step(row)
        want = (loc._state.astype(np.float64) * loc._like).sum(1)
        np.testing.assert_allclose(loc._velocity, want, rtol=1e-12, atol=1e-300)
        assert (k > 0) == (loc._summed is not None)


def _slow_odometry_shift(state, velocities, lengths, distance):
    """Reference: each bin's mass walks ``distance`` metres along a chain with edge
    ``lengths`` in its velocity's direction, split between the two places it lands between;
    what would pass a route end is dropped, what reaches it exactly (or stands there) stays."""
    n = state.shape[0]
    route = np.concatenate([[0.0], np.cumsum(lengths)])
    out = np.zeros_like(state)
    for j in range(n):
        for b, v in enumerate(velocities):
            m = state[j, b]
            if m == 0.0:
                continue
            x = route[j] + math.copysign(distance, v)
            if x < route[0] - 1e-12 or x > route[-1] + 1e-12:
                continue  # past the end
            k = min(int(np.searchsorted(route, x, side="right")) - 1, n - 1)
            if k == n - 1 or route[k] == x:
                out[k, b] += m
                continue
            a = (x - route[k]) / (route[k + 1] - route[k])
            out[k, b] += (1.0 - a) * m
            out[k + 1, b] += a * m
    return out


@pytest.mark.parametrize("distance", [0.0, 1.0, 2.0, 3.5, 4.0, 9.0, 10.0, 11.0])
def test_odometry_prediction_keeps_the_mass_that_reaches_a_route_end(distance):
    """Mass standing at a route end (odometry 0) or landing on it exactly was lost before."""
    graph = PlaceGraph.chain(6, spacing=2.0)
    velocities = np.array([-1.0, 1.0])
    transition = velocity_transition(velocities, 1.0, 0.0)
    state = np.random.default_rng(int(distance * 10)).uniform(0, 1, (6, 2))
    state[[0, 5]] += 1.0  # much of it at the ends
    state /= state.sum()
    got = predict(state, transition, velocities, route_neighbours(graph), 0.0, 0.0, np.array([0.5, 0.5]), 0.0,
                  odometry=distance)
    want = _slow_odometry_shift(state, velocities, np.full(5, 2.0), distance)
    # nothing left on the route (beyond its length): the documented uniform fallback
    want = want / want.sum() if want.sum() > 0 else np.full_like(state, 1.0 / state.size)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("junctions", [False, True])
def test_the_grid_filter_never_forms_the_particle_edge_tables(junctions):
    """``reverse`` and ``straight`` are formed on first use, and the grid filter does not
    use them (its graph holds ``2 E`` int64 less); the particle filter does."""
    n = 60
    edges = [[10, 40], [40, 10]] if junctions else None
    g = (PlaceGraph.from_edges(n, np.concatenate([np.stack([np.arange(n - 1), np.arange(1, n)], 1),
                                                  np.stack([np.arange(1, n), np.arange(n - 1)], 1), edges]),
                               kinds=[0] * (n - 1) + [1] * (n - 1) + [2, 2])
         if junctions else PlaceGraph.chain(n))
    rows = np.random.default_rng(0).standard_normal((8, n))
    loc = GridLocalizer(g, TemperedObservation()).reset()
    for k, row in enumerate(rows):
        loc.step(row, odometry=1.0 if k % 2 else None)
    assert "_tables" not in g.__dict__
    particles = Localizer(g, TemperedObservation(), n_particles=50, seed=0)
    particles.step(rows[0])
    particles.step(rows[1])
    assert "_tables" in g.__dict__ and g.reverse is g.__dict__["_tables"][0]
