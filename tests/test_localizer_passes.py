"""The particle filter's O(n_places) passes, cut or fused, against the plain forms they
replace (kept here as references): the same floats, bit for bit.

- :func:`catgraph.localizer._birth_kernel` finds each birth's place by bisection of the
  proposal's cumulative instead of a scan from the previous birth's place;
- :func:`catgraph.localizer._posterior_kernel` writes the marginal step's place masses,
  the place posterior and the answer in one pass (they were the reweighting's last pass,
  numpy's product and ``np.argmax``)."""

import numpy as np
import pytest

from catgraph._jit import njit
from catgraph.graph import PlaceGraph
from catgraph.localizer import _birth_kernel, _posterior_kernel
from catgraph.particles import _first_in_edge


@njit
def _reference_birth(kind, like, proposal, top, log_keep, log_recovery, start, stop, edge, fraction, log_weight,
                     velocity, uniform, out_ptr, first_in, normalise):  # pragma: no cover - compiled
    """The births as first written: each place found by a scan from the last one."""
    n_all = edge.shape[0]
    n = like.shape[0]
    if not normalise:
        log_keep = -np.inf  # no velocity copies below
    mx = -np.inf
    for i in range(n_all):
        if (i < start or i >= stop) and log_weight[i] > mx:
            mx = log_weight[i]
    n_rest = n_all - (stop - start)
    if not normalise:
        pass
    elif np.isfinite(mx):
        t = 0.0
        for i in range(n_all):
            if i < start or i >= stop:
                t += np.exp(log_weight[i] - mx)
        shift = mx + np.log(t) - log_keep
        for i in range(n_all):
            if i < start or i >= stop:
                log_weight[i] -= shift
    else:  # every particle left the map: start again from uniform weights
        for i in range(n_all):
            if i < start or i >= stop:
                log_weight[i] = log_keep - np.log(n_rest)
    m_slots = stop - start
    if m_slots == 0:
        return
    if kind == 1:
        acc = 0.0
        for j in range(n):
            acc += 0.5 / n
            proposal[j] = acc
        for t in range(top.shape[0]):
            j = top[t]
            if j >= 0:
                for jj in range(j, n):
                    proposal[jj] += 0.5 / top.shape[0]
    elif kind == 2:
        for j in range(n):
            proposal[j] = (j + 1.0) / n
    cumulative = like if kind == 0 else proposal  # kind 3: filled by _sharpened_cumulative
    total = cumulative[n - 1]
    j = 0
    for m in range(m_slots):
        pos = (uniform[0] + m) / m_slots * total
        while j < n - 1 and cumulative[j] <= pos:
            j += 1
        low = cumulative[j - 1] if j > 0 else 0.0
        width = cumulative[j] - low
        within = (pos - low) / width if width > 0 else 0.0
        k = start + m
        n_out = out_ptr[j + 1] - out_ptr[j]
        if n_out > 0:
            edge[k] = out_ptr[j] + min(int(within * n_out), n_out - 1)
            fraction[k] = 0.0
        else:
            edge[k] = first_in[j]
            fraction[k] = 1.0
        log_weight[k] = log_recovery - np.log(n * m_slots * width / total)
        velocity[k] = -1 - m // 2  # the prior, stratified (even slots are overwritten below)
    n_copy = (m_slots + 1) // 2 if normalise else 0
    keep = np.exp(log_keep)
    acc = 0.0
    c = -1
    for t in range(n_copy):
        pos = (uniform[1] + t) / n_copy * keep
        while acc <= pos and c < n_all - 1:
            c += 1
            if c < start or c >= stop:
                acc += np.exp(log_weight[c])
        if c >= 0 and (c < start or c >= stop) and velocity[c] >= 0:
            velocity[start + 2 * t] = velocity[c]


@pytest.mark.parametrize("kind", [0, 1, 2])
@pytest.mark.parametrize("normalise", [True, False])
def test_births_by_bisection_land_where_the_scan_put_them(kind, normalise):
    """Every birth's edge, fraction, log-weight and velocity, and every other particle's
    weight, equal to the scan's, on proposals with flat stretches (places of zero
    likelihood: a cumulative that repeats), a dead end and a first place of zero mass."""
    g = PlaceGraph.chain(300)
    first_in = _first_in_edge(g)
    rng = np.random.default_rng(4)
    for trial in range(6):
        e = np.exp(-rng.random(g.n_places) * 6)
        e[rng.integers(0, g.n_places, 60)] = 0.0
        e[:trial] = 0.0
        like = np.cumsum(e)
        n_all, start, stop = 120, 40 + trial, 70 + trial
        places = rng.integers(0, g.n_places - 1, n_all)
        edge0 = g.out_ptr[places].astype(np.int64)
        log_weight0 = np.log(rng.random(n_all)) - 2.0
        velocity0 = rng.integers(-3, 8, n_all).astype(np.int64)
        top = rng.choice(g.n_places, 10, replace=False).astype(np.int64)
        outs = []
        for kernel in (_birth_kernel, _reference_birth):
            edge, fraction, log_weight, velocity = edge0.copy(), np.zeros(n_all), log_weight0.copy(), velocity0.copy()
            proposal = np.full(g.n_places, np.nan)
            kernel(kind, like, proposal, top, np.log(0.95), np.log(0.05), start, stop, edge, fraction, log_weight,
                   velocity, np.array([0.3 + 0.1 * trial, 0.71, 0.5]), g.out_ptr, first_in, normalise)
            outs.append((edge, fraction, log_weight, velocity))
        for ours, ref in zip(*outs):
            np.testing.assert_array_equal(ours, ref)


def _reference_posterior(marginal_mass, scale, like, share, recover, keep):
    """The reweighting's last pass as it was (a cleared array, the marginal masses, then the
    recovery share's), numpy's product and ``np.argmax``."""
    mass = np.zeros(len(like))
    below = 0.0
    for j in range(len(like)):
        mass[j] += marginal_mass[j] * scale
        if recover:
            mass[j] += share * (like[j] - below)
            below = like[j]
    return mass, np.multiply(mass, keep), int(np.argmax(mass))


@pytest.mark.parametrize("recover", [True, False])
def test_posterior_pass_equals_the_reweighting_pass_product_and_argmax(recover):
    rng = np.random.default_rng(5)
    n = 500
    for trial in range(5):
        mm = np.where(rng.random(n) < 0.1, rng.random(n), 0.0)
        if trial == 1:
            mm[:] = 0.0  # ties everywhere but the recovery share
        like = np.cumsum(np.exp(-rng.random(n) * 5) * (rng.random(n) < 0.9))
        if trial == 2:
            like[:] = 0.0
        scale, share, keep = 0.7 + 0.1 * trial, 1e-3 * rng.random(), 1.0 - 0.1 * trial
        mass, post = np.full(n, np.nan), np.full(n, np.nan)
        best = _posterior_kernel(mm, scale, like, share, recover, mass, post, keep)
        ref_mass, ref_post, ref_best = _reference_posterior(mm, scale, like, share, recover, keep)
        np.testing.assert_array_equal(mass, ref_mass)
        np.testing.assert_array_equal(post, ref_post)
        assert best == ref_best


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_likelihood_cumulative_on_threads_equals_the_one_pass(threads):
    """The frame's cumulative likelihood and its maximum on any number of threads, the
    maximum found or given, equal to :func:`_likelihood_cumulative`'s, bit for bit (a NaN:
    the one pass's, which skips it)."""
    from catgraph.localizer import _likelihood_cumulative, likelihood_cumulative

    rng = np.random.default_rng(6)
    for n in (1, 7, 1000, 70_001):
        r = rng.standard_normal(n) * 5
        for known in (np.nan, float(r.max())):
            ref, out = np.empty(n), np.full(n, np.nan)
            top = _likelihood_cumulative(r, ref, known)
            assert likelihood_cumulative(r, out, known, threads=threads) == top
            np.testing.assert_array_equal(out, ref)
    r[5] = np.nan
    ref, out = np.empty(len(r)), np.empty(len(r))
    assert likelihood_cumulative(r, out, threads=threads) == _likelihood_cumulative(r, ref, np.nan)
    np.testing.assert_array_equal(out, ref)


def test_reach_places_are_every_place_the_marginal_move_can_read_once():
    """:meth:`VelocityMotion.reach_places` against a walk along the route from each
    particle outside the skipped slots: the same set, each place once, the scratch left
    clear; on a chain with its ends and on a route broken into stretches."""
    from catgraph.motion import PlacesWritten, VelocityMotion
    from catgraph.particles import ParticleSet

    from .conftest import survey_graph

    rng = np.random.default_rng(7)
    for graph in (PlaceGraph.chain(80), survey_graph()):
        motion = VelocityMotion()
        assert motion.supports_marginal(graph)
        fwd, bwd = motion._route(graph)[:2]
        n = 60
        places = rng.integers(0, graph.n_places, n)
        places[:3] = [0, graph.n_places - 1, places[5]]
        first_in = _first_in_edge(graph)
        has_out = graph.out_ptr[places + 1] > graph.out_ptr[places]
        edge = np.where(has_out, graph.out_ptr[places], first_in[places]).astype(np.int64)
        fraction = np.where(has_out, 0.0, 1.0)
        particles = ParticleSet(edge, fraction, np.zeros(n))
        written = PlacesWritten(graph.n_places, 0)
        for skip in ((0, 0), (10, 30)):
            got = motion.reach_places(particles, graph, skip, written)
            want = set()
            for i in range(n):
                if skip[0] <= i < skip[1]:
                    continue
                j = places[i]
                want.add(int(j))
                for nxt in (fwd, bwd):
                    t = j
                    for _ in range(motion._reach):
                        t = nxt[t]
                        if t < 0:
                            break
                        want.add(int(t))
            assert len(got) == len(set(got.tolist())) and set(got.tolist()) == want
            assert not written.marks.any()


@pytest.mark.parametrize("jump_graduation", [1.0, 0.2])
def test_sparse_passes_give_the_dense_run_bit_for_bit(jump_graduation):
    """A map far larger than the particles' reach takes the sparse passes (the places the
    marginal motion wrote, the frame's ratio only where it reads); the same run made to
    take the dense ones gives every estimate, particle and posterior bit for bit, over a
    jump, uninformative frames and frames with odometry."""
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion

    from .conftest import FixedLogRatio

    n_places, n_frames = 1500, 40
    rng = np.random.default_rng(8)
    truth = np.r_[np.arange(100, 120), np.arange(900, 920)]
    rows = np.abs(np.arange(n_places)[None, :] - truth[:, None]) / 10 + rng.random((n_frames, n_places))
    rows[25:27] = rng.random((2, n_places))
    outs = []
    for sparse in (True, False):
        loc = Localizer(PlaceGraph.chain(n_places), FixedLogRatio(3.0), 60, motion=VelocityMotion(), seed=2,
                        jump_graduation=jump_graduation).reset()
        assert loc._sparse_ratio
        if not sparse:
            loc._sparse_ratio, loc._written = False, None
        out = []
        for k, r in enumerate(rows):
            e = loc.step(r, 1.0 if k % 9 == 4 else None)
            out.append(repr((e.place, e.confidence.hex(), e.new_place_probability.hex(), e.log_odds.hex(),
                             e.score.hex())))
            out.append(np.concatenate([loc.place_posterior_, loc._log_weight, loc._spread.ravel()]).tobytes())
        outs.append(out)
    assert outs[0] == outs[1]
