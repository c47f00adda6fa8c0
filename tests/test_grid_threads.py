"""The grid filter's line kernel on threads: every block range, any thread count, gives
the arrays of the one-pass serial kernel bit for bit."""

import numpy as np
import pytest

from catgraph import grid
from catgraph._jit import njit
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.observation import TemperedObservation

# The serial line kernel as it was before its blocks were shared among threads (one
# function, velocity sums added block after block): the reference of the threaded one.


@njit(fastmath=True)
def _serial_line_predict(p, like, prior_mass, out, mass, t_ptr, t_src, t_val, whole, frac, sign, blur,
                  recovery, velocity_prior, block, e, velocity):
    """:func:`predict` on a line graph (place ``j``'s neighbours are ``j ± 1``, no
    junctions, no odometry) from the factored posterior ``p[b, j] · like[j]``
    (velocity-major), in one pass over the state, ``block`` places at a time: for a block
    (plus a halo of the largest hop and the blur), row by row, the transition of the row
    times the likelihood (one row buffer, still in cache when it is read back), then its
    shift by index arithmetic, the blur and the recovery (into ``out[b]``); ``mass`` gets
    the predicted place masses. A whole move (a whole speed, every phase bin) inside the
    route reads the shifted row directly; a split move (a fraction beyond
    ``max_phases``) and the blocks at the route's ends go through the moved-mass buffer.
    The mass that runs past a route end, needed before the first place is written, is
    summed first from the few places within reach of the ends. Given the next frame's
    ``e`` (:func:`_likelihood`; empty: none), ``velocity[b]`` gets ``Σ_j out[b, j] e_j``
    (the stored prediction, rounded as stored) while the row is written, so that the
    update need not read the state again."""
    nb, n = p.shape
    fuse = len(e) > 0
    for b in range(nb):
        velocity[b] = 0.0
    total_in = 0.0
    for j in range(n):
        total_in += prior_mass[j] * like[j]
    lost = 0.0
    reach = 0
    for b in range(nb):
        if whole[b] > reach:
            reach = whole[b]
        for part in range(2):
            hops = whole[b] + part
            share = 1.0 - frac[b] if part == 0 else frac[b]
            if share == 0.0 or hops == 0:
                continue
            lo, hi = (n - hops, n) if sign[b] > 0 else (0, hops)
            if lo < 0:
                lo = 0
            if hi > n:
                hi = n
            for j in range(lo, hi):
                acc = 0.0
                for c in range(t_ptr[b], t_ptr[b + 1]):
                    acc += t_val[c] * p[t_src[c], j]
                lost += share * acc * like[j]
    total = total_in - lost
    keep = (1.0 - recovery) / total if total > 0 else 0.0
    share0 = recovery / n if total > 0 else 1.0 / n
    centre = keep * (1.0 - 2.0 * blur)
    side = keep * blur
    halo = reach + 2  # a hop of whole + 1 places, then the blur's one
    width = block + 2 * halo
    tb = np.empty(width)  # one row of T·like over [j0 − halo, j1 + halo), zero outside the route
    mv = np.empty(block + 2)  # moved mass over [j0 − 1, j1 + 1)
    for j0 in range(0, n, block):
        j1 = min(n, j0 + block)
        a = max(0, j0 - halo)
        z = min(n, j1 + halo)
        off = a - (j0 - halo)
        lk = like[a:z]
        m = mass[j0:j1]
        for j in range(j1 - j0):
            m[j] = 0.0
        w = j1 - j0
        for i in range(off):  # before the route's start
            tb[i] = 0.0
        for i in range(off + z - a, width):  # past its end
            tb[i] = 0.0
        tt = tb[off:off + z - a]
        for b in range(nb):  # each row's transition, then at once its shift and blur (the row in cache)
            c0, k = t_ptr[b], t_ptr[b + 1] - t_ptr[b]
            if k <= 4:  # velocity_transition's columns: the bin itself, two neighbours, the mirror
                r0 = p[t_src[c0], a:z]
                r1 = p[t_src[c0 + 1], a:z] if k > 1 else r0
                r2 = p[t_src[c0 + 2], a:z] if k > 2 else r0
                r3 = p[t_src[c0 + 3], a:z] if k > 3 else r0
                w0 = t_val[c0]
                w1 = t_val[c0 + 1] if k > 1 else 0.0
                w2 = t_val[c0 + 2] if k > 2 else 0.0
                w3 = t_val[c0 + 3] if k > 3 else 0.0
                for i in range(z - a):
                    tt[i] = (w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i]) * lk[i]
            elif k <= 6:  # a speed next to a phased one: its neighbour's phases add a source each
                r0, r1, r2 = p[t_src[c0], a:z], p[t_src[c0 + 1], a:z], p[t_src[c0 + 2], a:z]
                r3, r4 = p[t_src[c0 + 3], a:z], p[t_src[c0 + 4], a:z]
                r5 = p[t_src[c0 + 5], a:z] if k > 5 else r0
                w0, w1, w2, w3, w4 = t_val[c0], t_val[c0 + 1], t_val[c0 + 2], t_val[c0 + 3], t_val[c0 + 4]
                w5 = t_val[c0 + 5] if k > 5 else 0.0
                for i in range(z - a):
                    tt[i] = (w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i] + w4 * r4[i] + w5 * r5[i]) * lk[i]
            else:
                for i in range(z - a):
                    tt[i] = 0.0
                for c in range(c0, c0 + k):
                    src, wc = p[t_src[c], a:z], t_val[c]
                    for i in range(z - a):
                        tt[i] += wc * src[i]
                for i in range(z - a):
                    tt[i] *= lk[i]
            # moved[j] = (1 − f) T[j − s h] + f T[j − s (h + 1)], j from j0 − 1 to j1
            step = sign[b] * whole[b]
            f0, f1 = 1.0 - frac[b], frac[b]
            ti = tb[halo - 1 - step:halo - 1 - step + w + 2]
            o = out[b, j0:j1]
            base = share0 * velocity_prior[b]
            if f1 == 0.0 and j0 > 0 and j1 < n:  # a whole move (every phase bin) inside the route: no split
                if fuse:
                    ee = e[j0:j1]
                    acc = 0.0
                    for k in range(w):
                        x = centre * ti[k + 1] + side * (ti[k] + ti[k + 2]) + base
                        o[k] = x
                        m[k] += x
                        acc += o[k] * ee[k]
                    velocity[b] += acc
                else:
                    for k in range(w):
                        x = centre * ti[k + 1] + side * (ti[k] + ti[k + 2]) + base
                        o[k] = x
                        m[k] += x
                continue
            tk = tb[halo - 1 - step - sign[b]:halo - 1 - step - sign[b] + w + 2]
            for k in range(w + 2):
                mv[k] = f0 * ti[k] + f1 * tk[k]
            if j0 == 0:  # a route end keeps the blur that would leave it
                mv[0] = mv[1]
            if j1 == n:
                mv[w + 1] = mv[w]
            for k in range(w):
                x = centre * mv[k + 1] + side * (mv[k] + mv[k + 2]) + base
                o[k] = x
                m[k] += x
            if fuse:
                ee = e[j0:j1]
                acc = 0.0
                for k in range(w):
                    acc += o[k] * ee[k]
                velocity[b] += acc


def _track(n, rng, speed=1.0, start=5, frames=30):
    places = np.clip(np.rint(start + speed * np.arange(frames)).astype(int), 0, n - 1)
    rows = rng.standard_normal((frames, n))
    rows[np.arange(frames), places] -= 2.0
    return rows


@pytest.mark.parametrize("n, block", [(700, 64), (1000, 1024), (333, 16)])
@pytest.mark.parametrize("velocities, max_phases", [((-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0), 4),
                                                    ((-1.0, 0.0, 1.5, 2.0), 4), ((0.3, 1.0, 2.7), 1)])
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_threaded_line_kernel_equals_the_serial_kernel(n, block, velocities, max_phases, precision):
    rng = np.random.default_rng(n + block)
    loc = GridLocalizer(PlaceGraph.chain(n), TemperedObservation(likelihood="linear", hub=None, temperature=0.8),
                        velocities=velocities, max_phases=max_phases).reset()
    if precision == "float64":
        loc._state = loc._state.astype(np.float64)
    rows = _track(n, rng)
    rows[18:] = _track(n, rng, speed=-2.0, start=n - 10, frames=12)  # a jump and a turn
    for k, row in enumerate(rows):
        if k > 0:
            whole, frac, sign, _ = loc._moves
            args = (loc._state, loc._like, loc.prior_)
            rest = (*loc._t_sparse, whole, frac, sign, float(loc.blur), loc.recovery_, loc._jump_velocity(), block)
            for e in (np.exp(rng.standard_normal(n)), np.empty(0)):
                want = (np.empty_like(loc._state), np.empty(n), np.empty(len(loc._owner)))
                _serial_line_predict(*args, want[0], want[1], *rest, e, want[2])
                for threads in (1, 2, 3, None):
                    got = (np.empty_like(loc._state), np.empty(n), np.empty(len(loc._owner)))
                    grid._line_predict(*args, *got[:2], *rest, e, got[2], threads=threads)
                    for a, b in zip(got, want):
                        assert a.dtype == b.dtype and np.array_equal(a, b)
        loc.step(row)


def test_grid_step_is_the_same_on_one_thread_and_on_several(monkeypatch):
    """Whole runs: the line kernel forced onto several threads (the work threshold at
    one state value, every core taken as free whatever the load) against one thread;
    every estimate and the final state equal."""
    n = 600
    rows = _track(n, np.random.default_rng(3), speed=1.0, frames=40)
    runs = []
    for work in (1 << 62, 1):
        monkeypatch.setattr(grid, "LINE_WORK_PER_THREAD", work)
        monkeypatch.setattr(grid, "_LINE_BLOCK", 64)
        monkeypatch.setattr(grid, "_free_cores", lambda cores: cores)  # several threads even on a loaded machine
        loc = GridLocalizer(PlaceGraph.chain(n), TemperedObservation(likelihood="linear", hub=None)).reset()
        runs.append(([loc.step(r) for r in rows], loc._state.copy(), loc.place_posterior_.copy()))
    (est_a, state_a, post_a), (est_b, state_b, post_b) = runs
    assert [(e.place, e.score, e.confidence) for e in est_a] == [(e.place, e.score, e.confidence) for e in est_b]
    assert np.array_equal(state_a, state_b) and np.array_equal(post_a, post_b)
