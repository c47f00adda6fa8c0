"""The sequence matcher's kernels stay bit-identical when they are made faster.

Streaming runs of the kernel driver :func:`catgraph._sequence_kernels.run_batch` (one
row per call, as :meth:`catgraph.sequence.SequenceMatcher.step` calls it) against
digests of the outputs the kernels produced before any speed-up: every frame's best
places, best and second-best scores, means, spreads and sub-window scores, and the
final running sums, ring and quantum, bit for bit. The rows: random rows over several
blocks of the block minima, rows whose window sums are too large for the float64
moments to be exact (any change in their summation order would show), and a stretch
of the real Nordland difference matrix. The window rule that reads these outputs is
not part of the digests (it has tests of its own)."""

import numpy as np
import pytest

from catgraph import _sequence_kernels as k
from catgraph import sequence as seq

from .conftest import NORDLAND, assert_recorded, needs_nordland
from .conftest import array_digest as _digest


def _kernel_run(d, l_max=40):
    """Every frame's kernel outputs (best places, scores, moments, sub-window scores)."""
    cfg = seq._config("test", "adaptive", "gaussian", seq.DEFAULT_LINE_RULE, "posterior", 5, l_max, seq.DEFAULT_GRID, 10,
                      0.05, seq.DEFAULT_VELOCITIES, None)
    n_q, n = d.shape
    sums, ring, mring, state, scratch = seq._state(cfg, n)
    out = []
    for i in range(n_q):
        st = seq._Stats(1, cfg.velocities.shape[0], cfg.grid.shape[0], cfg.n_components, True)
        k.run_batch(d[i:i + 1], i, sums, ring, mring, state, cfg.velocities, cfg.grid, cfg.approx_code, 10, 1,
                    cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights, st.locs, st.scales,
                    st.sub, *scratch)
        out += [st.best_j, st.best_s, st.second_s, st.mean, st.std, st.sub]
    out += [sums, ring, mring, state[:1]]  # the quantum (state[1], counting clipped codes, came later)
    _kernel_run.sums = sums
    return _digest(out)


def _random_rows(n_q=70, n=5000, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n))
    # a line at velocity 1 and one at velocity -2, so the best places move across blocks
    for i in range(n_q):
        d[i, (1000 + i) % n] -= 4.0
        d[i, (4100 - 2 * i) % n] -= 3.0
    return d * scale


def _large_rows(n_q=150, n=5000, seed=1):
    """One pattern moving one place per frame (the velocity-1 window sums grow with the
    window) at 20 times the first row's scale: codes up to the int16 limit, window sums
    of millions, their squares summed over the places beyond 2^53 (the float64 moments
    round, so their summation order shows)."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=n)
    d = np.stack([np.roll(base, i) for i in range(n_q)]) + 0.1 * rng.normal(size=(n_q, n))
    d[0] *= 0.05
    return d


def _nordland_rows(n_q=120):
    """The first query frames' normalised difference rows of Nordland (summer map, winter query)."""
    from catgraph.datasets import load_traverse
    from catgraph.pipeline import differences
    from catgraph.traverse import Traverse

    ref = load_traverse(NORDLAND / "summer")
    query = load_traverse(NORDLAND / "winter")
    return differences(ref, Traverse(query.frames[:n_q]))


#: digests of the outputs before the speed-ups (the code of the commit that added this file)
_DIGESTS = {"random kernel": "8c8d35bac63a2adf", "large kernel": "1b49e25679892957",
            "nordland kernel": "56944d93fade143e"}
#: the same outputs on processors that round otherwise, recorded on them (Zen 4 at f19e3aa; Zen 3
#: at 8cb4901). On Zen 3 the code of the commit that added this file gives the first machines'
#: random and Nordland digests, and "dcce60ba884d1448" for the large rows: there this code's
#: spreads of windows whose moments round differ from it in the last bits (9 of 150 frames,
#: at most 8.3e-16 relative), every other output bit for bit the same
_OWN_DIGESTS = {"znver4": {"random kernel": "8c8d35bac63a2adf", "large kernel": "b6a837f4a11b4e5e",
                           "nordland kernel": "a16b250111e4750c"},
                "znver3": {"random kernel": "8c8d35bac63a2adf", "large kernel": "533b10b3a843ae6c",
                           "nordland kernel": "56944d93fade143e"}}


def test_kernel_outputs_are_those_before_the_speed_ups():
    assert_recorded(_kernel_run(_random_rows()), _DIGESTS, _OWN_DIGESTS, "random kernel")


def test_kernel_outputs_with_rounding_moments_are_those_before_the_speed_ups():
    d = _large_rows()
    assert_recorded(_kernel_run(d, l_max=500), _DIGESTS, _OWN_DIGESTS, "large kernel")
    # the case is what it claims: a window's squared deviations sum beyond 2^53
    s = _kernel_run.sums[5, -1].astype(np.int64)  # velocity 1, the longest window
    assert sum(int(y) ** 2 for y in s - s[0]) > 2**53


def test_kernel_outputs_do_not_depend_on_the_threads(monkeypatch):
    monkeypatch.setattr(k, "WORK_PER_THREAD", 1)  # both threads, one velocity at a time
    assert_recorded(_kernel_run(_random_rows()), _DIGESTS, _OWN_DIGESTS, "random kernel")


@needs_nordland
def test_nordland_rows_give_the_outputs_before_the_speed_ups():
    d = _nordland_rows()
    assert_recorded(_kernel_run(d, l_max=500), _DIGESTS, _OWN_DIGESTS, "nordland kernel")


def _slow_best_and_second(in_place, radius):
    """Numpy: the first place of the smallest sum, that sum, the smallest sum beyond the radius."""
    jb = int(np.argmin(in_place))
    far = np.abs(np.arange(in_place.size) - jb) > radius
    return jb, int(in_place[jb]), int(in_place[far].min()) if far.any() else int(k._NONE)


@pytest.mark.parametrize("n", [150, 2048, 2049, 5000])
def test_chunk_minima_of_the_update_and_the_best_and_second_equal_numpy(n):
    """The block minima the update loops take per chunk (blocks of CHUNK places) and
    the best and second-best search over them against numpy on the sums left behind, for
    every velocity kind (slot wrap, entering lines, old rows in and outside the
    reference), with exact ties planted across a block boundary."""
    rng = np.random.default_rng(n)
    length = 4
    d = rng.integers(-3, 4, size=(14, n)) / 8.0  # coarse values: many exact ties
    for v, dtype in ((1.0, np.int32), (0.5, np.int64), (-2.0, np.int32), (3.0, np.int32)):
        ring = np.zeros((length + 1, n), dtype=np.int16)
        mring = np.zeros(length + 1, dtype=np.int16)
        state = np.zeros(1)
        sums = np.zeros(n, dtype=dtype)
        bmin = np.empty((n + k.CHUNK - 1) // k.CHUNK, dtype=np.int64)
        for i in range(d.shape[0]):
            k.advance(ring, mring, state, i, d[i])
            k._update_stats(sums, ring, mring, i, v, length, 0, bmin)
            sbase = k.position(v, i) % n
            in_place = np.roll(sums, sbase).astype(np.int64)
            np.testing.assert_array_equal(bmin, [in_place[b:b + k.CHUNK].min() for b in range(0, n, k.CHUNK)])
            for radius in (0, 3, 40):
                assert k._best_and_second(sums, sbase, bmin, radius) == _slow_best_and_second(in_place, radius)


@pytest.mark.parametrize("n", [300, 2100, 4500])
def test_best_and_second_with_ties_and_the_radius_across_blocks(n):
    rng = np.random.default_rng(7)
    for trial in range(40):
        sums = rng.integers(-50, 50, size=n).astype(np.int32)
        low = int(sums.min()) - 1
        edge = k.CHUNK * (1 + trial % 2) if n > 2 * k.CHUNK else n // 2
        sums[rng.integers(0, n, size=3)] = low  # ties: the first place must win
        sums[(edge + rng.integers(-5, 5)) % n] = low - (trial % 3 == 0)
        sbase = int(rng.integers(0, n))
        slots = np.roll(sums, -sbase)  # place j in slot (j - sbase) mod n
        bmin = np.array([sums[b:b + k.CHUNK].min() for b in range(0, n, k.CHUNK)], dtype=np.int64)
        for radius in (0, 5, 2 * k.CHUNK):
            assert k._best_and_second(slots, sbase, bmin, radius) == _slow_best_and_second(
                sums.astype(np.int64), radius)
