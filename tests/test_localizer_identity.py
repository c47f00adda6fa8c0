"""The particle filter's step stays bit-identical when it is made faster.

:func:`catgraph.motion._marginal_kernel` (the velocity marginalised move) against its
first, plainer form kept here as the reference (same compiler flags; ``interior``
in its original ``[a, o, b]`` layout), and whole runs of :class:`Localizer` against
digests of the outputs the code produced before its speed-ups (same seed ⇒ same
estimates, particles and posteriors, bit for bit)."""

import hashlib

import numpy as np
import pytest

from catgraph._jit import njit
from catgraph.graph import PlaceGraph
from catgraph.localizer import Localizer
from catgraph.motion import PlacesWritten, VelocityMotion, _marginal_kernel

from .conftest import FixedLogRatio as _Fixed
from .conftest import survey_graph as _survey_graph
from .conftest import ROUNDS_OTHERWISE, host_processor

#: the motion pinned (the defaults may move; the digests must not)
_MOTION = dict(velocities=(-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), velocity_stay=0.99,
               reverse_probability=0.001, blur=0.01, junction_probability=0.1, max_phases=1)


@njit(fastmath=True)
def _reference_kernel(edge, fraction, log_weight, velocity, skip_start, skip_stop, log_keep, uniform, like,
                     transition, whole, frac, sign, blur, fwd, bwd, source, target, out_ptr, first_in,
                     reach, posterior, prior, family_of, members, interior,
                     interior_column):
    """The step as it was first written (``interior[a, o, b]``), for the fast one to match."""
    nb = velocity.shape[1]
    width = 2 * reach + 1
    n = edge.shape[0]
    window = np.empty(width, dtype=np.int64)
    q = np.empty(nb)
    column = np.empty(width)
    moved = np.empty((width, nb))
    row = np.empty(nb)
    origin = np.empty(nb, dtype=np.int64)
    for b in range(nb):
        origin[b] = reach + sign[b] * whole[b]
    mx = -np.inf
    for i in range(n):
        if (i < skip_start or i >= skip_stop) and log_weight[i] > mx:
            mx = log_weight[i]
    for j in range(posterior.shape[0]):
        posterior[j] = 0.0
        prior[j] = 0.0
    if not np.isfinite(mx):
        return 0.0
    total = 0.0
    scaled = np.empty(n)  # e^{log_weight − max}, computed once
    for i in range(n):
        if i < skip_start or i >= skip_stop:
            scaled[i] = np.exp(log_weight[i] - mx)
            total += scaled[i]
    log_norm = mx + np.log(total)
    # the families: the occupied places, their weights and mean velocity distributions
    place = np.empty(n, dtype=np.int64)
    family_weight = np.zeros(n)
    family_velocity = np.zeros((n, nb))
    family_place = np.empty(n, dtype=np.int64)
    family_first = np.empty(n, dtype=np.int64)
    count = np.zeros(n + 1, dtype=np.int64)
    n_families = 0
    for i in range(n):
        place[i] = -1
        if skip_start <= i < skip_stop:
            continue
        w = scaled[i] / total
        if w == 0.0:
            log_weight[i] = -np.inf
            continue
        e = edge[i]
        j = source[e] if fraction[i] < 0.5 else target[e]
        f = family_of[j]
        if f < 0:
            f = n_families
            family_of[j] = f
            family_place[f] = j
            family_first[f] = i
            n_families += 1
        place[i] = f
        family_weight[f] += w
        for b in range(nb):
            family_velocity[f, b] += w * velocity[i, b]
        count[f + 1] += 1
    for f in range(n_families):
        count[f + 1] += count[f]
        family_of[family_place[f]] = -1
    fill = count[:n_families].copy()
    for i in range(n):
        f = place[i]
        if f >= 0:
            members[fill[f]] = i
            fill[f] += 1
    centre = 1.0 - 2.0 * blur
    kept = 0.0
    for f in range(n_families):
        weight = family_weight[f]
        j = family_place[f]
        window[reach] = j
        t = j
        u = j
        for o in range(1, reach + 1):
            if t >= 0:
                t = fwd[t]
            window[reach + o] = t
            if u >= 0:
                u = bwd[u]
            window[reach - o] = u
        inside = True
        for o in range(width):
            if window[o] < 0:
                inside = False
        for a in range(nb):
            q[a] = family_velocity[f, a] / weight  # the family's velocity distribution
        if inside:  # away from the route's ends: the mixture of the bins' predictions
            for o in range(width):
                c = 0.0
                for a in range(nb):
                    c += q[a] * interior_column[a, o]
                column[o] = c
        else:
            p = q.copy()
            for b in range(nb):
                acc = 0.0
                for a in range(nb):
                    acc += p[a] * transition[a, b]
                q[b] = acc
            moved[:, :] = 0.0
            for b in range(nb):
                o = origin[b]
                for extra in range(2):
                    m = q[b] * (frac[b] if extra == 1 else 1.0 - frac[b])
                    if m == 0.0:  # (a whole speed's extra hop: no mass, and its blur would reach past the window)
                        continue
                    if extra == 1:
                        o += sign[b]
                    if window[o] < 0:
                        continue  # past the route's end: it leaves the map
                    moved[o, b] += centre * m
                    moved[o + 1 if window[o + 1] >= 0 else o, b] += blur * m  # a route end keeps its blur
                    moved[o - 1 if window[o - 1] >= 0 else o, b] += blur * m
            for o in range(width):
                c = 0.0
                for b in range(nb):
                    c += moved[o, b]
                column[o] = c
            for a in range(nb):
                q[a] = p[a]
        stays = 0.0
        evidence = 0.0
        for o in range(width):
            c = column[o]
            if c > 0.0:
                t = window[o]
                stays += c
                evidence += c * like[t]
                prior[t] += weight * c
                posterior[t] += weight * c * like[t]
        kept += weight * stays
        lo, hi = count[f], count[f + 1]
        if not evidence > 0.0:
            for m_ in range(lo, hi):
                log_weight[members[m_]] = -np.inf
            continue
        # destinations from the family's own posterior (the locally optimal proposal), systematic
        k = hi - lo
        log_each = np.log(weight * evidence / k)
        acc = 0.0
        scan = -1
        last_pick = -1
        for m_ in range(k):
            i = members[lo + m_]
            pos = (uniform[family_first[f]] + m_) / k * evidence
            while scan < width - 1 and (scan < 0 or acc <= pos):
                scan += 1
                if column[scan] > 0.0:
                    acc += column[scan] * like[window[scan]]
            pick = scan
            while column[pick] <= 0.0 or like[window[pick]] <= 0.0:  # round-off past the end
                pick -= 1
            if pick != last_pick:  # the velocity distribution at the chosen place
                last_pick = pick
                for b in range(nb):
                    if inside:
                        share = 0.0
                        for a in range(nb):
                            share += q[a] * interior[a, pick, b]
                        row[b] = share / column[pick]
                    else:
                        row[b] = moved[pick, b] / column[pick]
            for b in range(nb):
                velocity[i, b] = row[b]
            t = window[pick]
            if out_ptr[t + 1] > out_ptr[t]:
                edge[i] = out_ptr[t]
                fraction[i] = 0.0
            else:
                edge[i] = first_in[t]
                fraction[i] = 1.0
            log_weight[i] = log_each
    if not kept > 0.0:
        return 0.0
    shift = log_keep - np.log(kept)
    for i in range(n):
        if i < skip_start or i >= skip_stop:
            log_weight[i] += shift
    scale = np.exp(shift)
    for j in range(posterior.shape[0]):
        posterior[j] *= scale
        prior[j] *= scale
    return kept


def _state(graph, motion, rng, n, skip):
    """Particles on places, in families of every size, some on the route's ends, some of
    weight 0, with random velocity distributions (one-bin ones among them)."""
    nb = len(motion._owner)
    _, _, first_in, _ = motion._route(graph)
    places = rng.integers(0, graph.n_places, n)
    places[: n // 4] = places[0]  # one large family
    places[n // 4: n // 4 + 5] = graph.n_places - 1  # route ends
    places[n // 4 + 5: n // 4 + 9] = 0
    has_out = graph.out_ptr[places + 1] > graph.out_ptr[places]
    edge = np.where(has_out, graph.out_ptr[places], first_in[places]).astype(np.int64)
    fraction = np.where(has_out, 0.0, 1.0)
    spread = rng.dirichlet(np.full(nb, 0.3), n)
    spread[::7] = np.eye(nb)[rng.integers(0, nb, len(spread[::7]))]
    log_weight = np.log(rng.random(n)) - 3.0
    log_weight[5::17] = -np.inf
    like = np.exp(-rng.random(graph.n_places) * 4)
    like[rng.integers(0, graph.n_places, 3)] = 0.0
    return edge, fraction, log_weight, spread, like, rng.random(n)


def _call(kernel, interior, graph, motion, state, skip, log_keep, masses=None):
    """One call; ``masses``: ``(posterior, prior, written)`` the place masses a previous call
    left and its :class:`PlacesWritten` (the sparse clear), else NaN-filled arrays (the
    kernel must clear them all)."""
    edge, fraction, log_weight, spread, like, uniform = (a.copy() for a in state)
    fwd, bwd, first_in, _ = motion._route(graph)
    if masses is None:
        post, prior = np.full(graph.n_places, np.nan), np.full(graph.n_places, np.nan)
        written = PlacesWritten(graph.n_places, len(edge) * (2 * motion._reach + 1))
    else:
        post, prior, written = masses
    family = np.full(graph.n_places, -1, dtype=np.int64)
    extra = () if kernel is _reference_kernel else (written.places, written.count, written.marks)
    kept = kernel(edge, fraction, log_weight, spread, *skip, log_keep, uniform, like, motion._transition,
                  *motion._moves, motion._blur, fwd, bwd, graph.source, graph.target, graph.out_ptr, first_in,
                  motion._reach, post, prior, family, np.empty(len(edge), dtype=np.int64), interior,
                  motion._interior_column, *extra)
    if kernel is not _reference_kernel:
        listed = written.places[:written.count[0]]
        assert len(np.unique(listed)) == len(listed) and not written.marks.any()
        assert np.all(post[np.setdiff1d(np.arange(graph.n_places), listed)] == 0.0)
        masses = (post, prior, written)
    return kept, edge, fraction, log_weight, spread, post, prior, family, masses


@pytest.mark.parametrize("graph", [PlaceGraph.chain(60), _survey_graph()], ids=["chain", "survey"])
@pytest.mark.parametrize("velocities", [None, (-1.0, 1.0), (-2.5, -1.0, 0.5, 1.0, 1.5, 4.0)], ids=["default", "two",
                                                                                                  "six"])
def test_marginal_kernel_is_bit_identical_to_its_reference(graph, velocities):
    """Every output (the moved particles, their weights and velocity distributions, the
    place masses, the predicted mass) equal to the reference's, bit for bit."""
    kwargs = dict(_MOTION)
    if velocities is not None:
        kwargs["velocities"] = velocities
    motion = VelocityMotion(**kwargs)
    motion._check()
    rng = np.random.default_rng(3)
    masses = None  # the first call clears every place; the later ones only the places the last wrote
    for n, skip in ((200, (150, 170)), (64, (0, 0)), (300, (280, 300)), (200, (150, 170))):
        state = _state(graph, motion, rng, n, skip)
        ours = _call(_marginal_kernel, motion._interior_rows, graph, motion, state, skip, np.log(0.95), masses)
        ref = _call(_reference_kernel, motion._interior, graph, motion, state, skip, np.log(0.95))
        masses = ours[-1]
        masses[2].reserve(301 * (2 * motion._reach + 1))
        assert ours[0] > 0.0
        if host_processor() in ROUNDS_OTHERWISE:
            # the reference's own fastmath code fuses other multiply-adds there: equal to the last bit or two
            np.testing.assert_allclose(ours[0], ref[0], rtol=1e-14, atol=0)
            for a, b in zip(ours[1:-1], ref[1:-1]):
                np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)
            continue
        assert ours[0] == ref[0]
        for a, b in zip(ours[1:-1], ref[1:-1]):
            np.testing.assert_array_equal(a, b)


def _trace(seed, proposal):
    """60 steps along a route to its end and back, with three uninformative frames (a
    jump's particles): after each step, the estimate and the particles, their velocity
    distributions and the place posterior."""
    n_places, n_frames = 300, 60
    rng = np.random.default_rng(seed)
    truth = np.concatenate([np.arange(200, 300, 2.5), np.arange(299, 279, -1.0)])[:n_frames]
    rows = np.abs(np.arange(n_places)[None, :] - truth[:, None]) / 10 + rng.random((n_frames, n_places))
    rows[20:23] = rng.random((3, n_places))
    loc = Localizer(PlaceGraph.chain(n_places), _Fixed(3.0), 500, motion=VelocityMotion(**_MOTION),
                    proposal=proposal, seed=seed)
    out = []
    for r in rows:
        e = loc.step(r)
        out.append(((e.place, e.confidence, e.new_place_probability, e.ess, e.resampled, e.log_odds, e.score),
                    [np.array(a, copy=True) for a in (loc._edge, loc._fraction, loc._log_weight, loc._spread,
                                                      loc.place_posterior_)]))
    return out


def _digest(trace):
    """A digest of every estimate and every array of a :func:`_trace`."""
    h = hashlib.sha256()
    for (place, confidence, p_new, ess, resampled, log_odds, score), arrays in trace:
        h.update(repr((place, confidence.hex(), p_new.hex(), ess.hex(), resampled, log_odds.hex(),
                       score.hex())).encode())
        for a in arrays:
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _reference_move(*args):
    """:func:`_reference_kernel` called as :func:`catgraph.motion._marginal_kernel` is
    (``interior`` given ``[o, b, a]``, handed on ``[a, o, b]``; the record of the places
    written dropped: the reference clears and rescales every place)."""
    args = list(args)[:27]
    args[25] = np.ascontiguousarray(args[25].transpose(2, 0, 1))
    return _reference_kernel(*args)


@pytest.mark.parametrize("seed, proposal, expected", [
    (0, "likelihood", "39b174a6ca11a6b82cf07377eac35e2df5f9ef837fe9ca2d9d11f10fda8ab17b"),
    (1, "best", "293939387e4f1aaf1db1e5a5e86bbcdaff4a8621dc68316d69ce4b8248582f41"),
    (2, "sharpened", "9661f4965683de2343eacc9832aa4de9c00daef8fd195cb58dd4700b32c7388b"),
])
def test_filter_run_is_bit_identical_to_the_code_before_its_speed_ups(seed, proposal, expected, monkeypatch):
    """Whole runs: the same as the digests the code gave before it was made faster (same
    seed, same arithmetic: every estimate and every particle, bit for bit). The kernels are
    compiled with ``fastmath``, so the digests are those of this project's machines; where
    a run gives another digest, it must be the reference move's run on this processor (the
    processor rounds otherwise), and the digest comparison is skipped. Where the run gives
    the digest the reference's own fastmath code may round otherwise (AMD Zen 4). On a
    processor whose fused multiply-adds differ from both (AMD Zen 5: the kernel against its
    reference within 1e-14 a step, above), the run must give the reference move's answers
    and its arrays to 1e-12."""
    trace = _trace(seed, proposal)
    ours = _digest(trace)
    if ours == expected:  # the bits recorded before the speed-ups
        return
    import catgraph.motion

    monkeypatch.setattr(catgraph.motion, "_marginal_kernel", _reference_move)
    reference_trace = _trace(seed, proposal)
    if host_processor() in ROUNDS_OTHERWISE:
        for (estimate, arrays), (ref_estimate, ref_arrays) in zip(trace, reference_trace):
            assert estimate[0] == ref_estimate[0] and estimate[4] == ref_estimate[4]  # place, resampled
            np.testing.assert_allclose(estimate[1:4] + estimate[5:], ref_estimate[1:4] + ref_estimate[5:],
                                       rtol=1e-12, atol=1e-12)
            for a, b in zip(arrays, ref_arrays):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        return
    assert ours == _digest(reference_trace)
    pytest.skip("this CPU's fastmath rounding differs from the machine the digests were recorded on")
