"""The decorrelation horizon's best places without standardising the row.

:class:`catgraph._window_rule._Horizon` finds each row's best places with one compiled
pass over the raw row (:func:`catgraph._sequence_kernels.smallest_places`) and forms the
standardised values only where it reads them. The reference below is the horizon as it
was written first: the whole row standardised, ``np.argpartition`` for the best places.
Both must give the same horizon and the same set of best places frame after frame; the
averages may differ in their last bits only (the order in which ten values are summed).
"""

from __future__ import annotations

import numpy as np
import pytest

from catgraph._sequence_kernels import smallest_places
from catgraph._window_rule import _Horizon


class _PartitionHorizon(_Horizon):
    """The reference: the row standardised as a whole and partitioned by numpy (``centre``,
    the row's mean where the caller has it, is recomputed here)."""

    def update(self, row, i, spread, centre=None):
        slot = i % self.capacity
        ratio = np.zeros(self.capacity)
        seen = np.zeros(self.capacity)
        if spread > 0:
            z = (row - row.mean()) / spread
            m = min(self.places, z.shape[0])
            best = np.argpartition(z, m - 1)[:m] if m < z.shape[0] else np.arange(m)
            own = z[best].mean()
            lags = np.arange(1, min(i, self.capacity) + 1)
            if own < 0 and lags.size:
                back = (i - lags) % self.capacity
                known = self.filled[back]
                ratio[: lags.size] = np.where(known, z[self.best[back, :m]].mean(axis=1) / own, 0.0)
                seen[: lags.size] = known
            self.best[slot, :m] = best
        self.filled[slot] = spread > 0
        self.total = self.decay * self.total + ratio
        self.weight = self.decay * self.weight + seen
        with np.errstate(divide="ignore", invalid="ignore"):
            below = (self.weight > 0) & (self.total / self.weight < self.level)
        return int(np.argmax(below)) + 1 if below.any() else self.capacity


def smooth_rows(n_frames, n_ref, seed, width=5, strength=3.0, integer=False):
    """Rows alike for about ``width`` frames along a diagonal, optionally rounded to integers
    (many exact ties, as differences of 8-bit images or Wi-Fi levels have)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(n_frames + width, n_ref + n_frames + width))
    d = np.empty((n_frames, n_ref))
    for i in range(n_frames):
        d[i] = sum(noise[i + w, i + w: i + w + n_ref] for w in range(width)) / np.sqrt(width)
        d[i, (i + 5) % n_ref] -= strength
    return np.rint(4 * d) if integer else d


def assert_same_clock(d, **kwargs):
    new, ref = _Horizon(**kwargs), _PartitionHorizon(**kwargs)
    for i, row in enumerate(d):
        spread = row.std()
        assert new.update(row, i, spread) == ref.update(row, i, spread), f"frame {i}"
        m = min(new.places, row.shape[0])
        slot = i % new.capacity
        assert set(new.best[slot, :m].tolist()) == set(ref.best[slot, :m].tolist()), f"frame {i}"
    np.testing.assert_array_equal(new.filled, ref.filled)
    np.testing.assert_array_equal(new.weight, ref.weight)
    np.testing.assert_allclose(new.total, ref.total, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("integer", [False, True])
def test_same_horizon_and_places_as_the_partition(seed, integer):
    d = smooth_rows(150, 300 + 37 * seed, seed, width=2 + seed, integer=integer)
    assert_same_clock(d)


def test_same_horizon_on_short_rows_and_flat_frames():
    """Rows of at most ``m`` and ``m + 1`` places (every place is a best place, or all but one),
    a flat row and a row of one repeated value among others."""
    for n_ref in (3, 10, 11, 12):
        d = smooth_rows(80, n_ref, n_ref, width=3, integer=True)
        d[20] = 0.0
        d[40, :] = 1.0
        d[40, 0] = 0.0
        assert_same_clock(d, capacity=16)


def test_ties_at_the_edge_fall_back_to_the_partition():
    """Values whose standardised differences collapse to one float at the m-th place:
    distinct raw values, equal ``z`` (a large offset), so the set is decided by the partition."""
    rng = np.random.default_rng(7)
    d = 1e15 + rng.integers(0, 40, size=(60, 200)).astype(float) + rng.integers(0, 2, size=(60, 200)) * 0.125
    assert_same_clock(d, capacity=12)


@pytest.mark.parametrize("seed", range(3))
def test_smallest_places_is_a_stable_sort_prefix(seed):
    rng = np.random.default_rng(seed)
    for _ in range(50):
        n = int(rng.integers(1, 400))
        k = int(rng.integers(1, n + 1))
        row = rng.integers(0, 25, n).astype(float)
        idx, val = np.empty(k, dtype=np.int64), np.empty(k)
        smallest_places(row, idx, val)
        order = np.lexsort((np.arange(n), row))[:k]
        np.testing.assert_array_equal(idx, order)
        np.testing.assert_array_equal(val, row[order])
