"""Hub offsets from the reference map (catgraph.hubs)."""

import numpy as np
import pytest

from catgraph.exceptions import CatgraphError, ShapeMismatchError
from catgraph.hubs import apply_hub_offsets, hub_offsets


def _slow_offsets(r, threshold):
    n = r.shape[0]
    typical = np.array([np.median([r[i, j] for i in range(n) if i != j]) for j in range(n)])
    centre = np.median(typical)
    spread = 1.4826 * np.median(np.abs(typical - centre))
    return np.array([t - centre if t < centre - threshold * spread else 0.0 for t in typical])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_offsets_match_slow_reference(seed):
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(40, 40))
    r[:, rng.integers(0, 40, size=3)] -= rng.uniform(1, 4, size=3)
    for threshold in (0.5, 2.0, 3.0):
        np.testing.assert_allclose(hub_offsets(r, threshold), _slow_offsets(r, threshold))


def test_hubs_found_and_map_without_hubs_untouched():
    rng = np.random.default_rng(3)
    r = rng.normal(size=(300, 300))
    assert not np.any(hub_offsets(r, threshold=5.0))  # no outlying column: the correction is the identity
    d = rng.normal(size=(20, 300))
    np.testing.assert_allclose(apply_hub_offsets(d, hub_offsets(r, threshold=5.0), renormalise=False), d)
    r[:, [5, 150]] -= 4.0
    offsets = hub_offsets(r, threshold=5.0)
    assert set(np.flatnonzero(offsets)) == {5, 150}
    assert np.all(offsets[[5, 150]] < -3.0)


def test_apply_renormalises_and_demotes_the_hub():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(50, 100))
    d[:, 9] -= 5.0  # the hub wins every row before the correction
    offsets = np.zeros(100)
    offsets[9] = -5.0
    out = apply_hub_offsets(d, offsets)
    np.testing.assert_allclose(out.mean(axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(out.std(axis=1), 1.0)
    assert np.mean(d.argmin(axis=1) == 9) > 0.9
    assert np.mean(out.argmin(axis=1) == 9) < 0.2
    np.testing.assert_allclose(apply_hub_offsets(d[3], offsets), out[3])


def test_typed_errors():
    with pytest.raises(ShapeMismatchError, match="square"):
        hub_offsets(np.zeros((4, 5)))
    with pytest.raises(ShapeMismatchError, match="hub offsets"):
        apply_hub_offsets(np.zeros((2, 5)), np.zeros(4))
    with pytest.raises(CatgraphError, match="threshold"):
        hub_offsets(np.zeros((4, 4)), threshold=-1.0)


def test_map_hub_offsets_from_a_sample_of_rows_find_the_same_hubs():
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import build_map
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(4)
    frames = rng.normal(size=(400, 16)).astype(np.float32)
    frames[[30, 31, 200]] = 0.05 * rng.normal(size=(3, 16))  # nearly flat: close to everything (SAD)
    from catgraph.pipeline import FrontEnd

    m = build_map(Traverse(frames), FrontEnd(metric="sad"), graph=False)
    full = map_hub_offsets(m)
    sampled = map_hub_offsets(m, max_rows=150)
    assert set(np.flatnonzero(full)) == {30, 31, 200}
    assert set(np.flatnonzero(sampled)) == {30, 31, 200}


def test_map_hub_offsets_read_in_blocks_equal_the_matrix_form(monkeypatch):
    """The map's offsets, read in blocks of places, equal :func:`hub_offsets` of the full
    (sampled rows × map) difference matrix."""
    import catgraph.differences as differences
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import build_map
    from catgraph.pipeline import FrontEnd
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(5)
    n = 5000  # more than one block of 4096 places
    frames = rng.normal(size=(n, 16)).astype(np.float32)
    frames[[10, 4500]] = 0.05 * rng.normal(size=(2, 16))
    m = build_map(Traverse(frames), FrontEnd(metric="sad"), graph=False)
    rows = np.sort(np.random.default_rng(0).choice(n, 64, replace=False))
    r = differences.difference_matrix(m.descriptors[rows], m.descriptors, "sad", normalise=True)
    monkeypatch.setattr(differences, "_BLOCK_VALUES", 64 * 4096)
    offsets = map_hub_offsets(m, max_rows=64)
    np.testing.assert_allclose(offsets, hub_offsets(r, rows=rows), atol=1e-12)
    assert {10, 4500} <= set(np.flatnonzero(offsets))


def test_apply_in_blocks_equals_the_whole_matrix_formula_bit_for_bit(monkeypatch):
    import catgraph.hubs as hubs

    rng = np.random.default_rng(5)
    d = rng.normal(size=(23, 300)) * 3 + 1
    d[4] = 2.0  # a constant row stays constant, shifted to 0
    before = d.copy()
    offsets = np.where(rng.random(300) < 0.05, -2.0, 0.0)
    whole = d - offsets
    mean, std = whole.mean(axis=-1, keepdims=True), whole.std(axis=-1, keepdims=True)
    want = (whole - mean) / np.where(std > 0, std, 1.0)
    want[4] = 0.0  # the constant row (no information) is not corrected
    for values in (1, 700, 1 << 22):  # one row per block, a few rows, everything at once
        monkeypatch.setattr(hubs, "RENORMALISE_VALUES", values)
        assert np.array_equal(apply_hub_offsets(d, offsets), want)
        assert np.array_equal(apply_hub_offsets(d[7], offsets), want[7])
        assert np.array_equal(apply_hub_offsets(d[4], offsets), np.zeros(300))
    assert np.array_equal(apply_hub_offsets(d, offsets, renormalise=False)[4], d[4])
    assert np.array_equal(d, before)  # the input is not modified


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("n", [1, 2])
def test_map_hub_offsets_on_maps_too_small_for_hubs_are_zero_and_silent(n):
    """A map of one or two places has no typical difference for a place to stand out from
    (an all-NaN median, numpy's warning, before): no offsets, as hub_offsets requires 3 frames."""
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import build_map
    from catgraph.pipeline import FrontEnd
    from catgraph.traverse import Traverse

    frames = np.random.default_rng(n).normal(size=(n, 8)).astype(np.float32)
    offsets = map_hub_offsets(build_map(Traverse(frames), FrontEnd(metric="sad"), graph=False))
    assert offsets.shape == (n,) and np.all(offsets == 0.0)


def test_sampled_rows_must_be_distinct_integer_frames():
    """A frame named twice emptied its own column (every entry left out as its own), whose
    NaN median dropped every offset, the obvious hub's too; fractional rows were truncated."""
    from catgraph.exceptions import DataError

    r = np.random.default_rng(1).normal(size=(3, 5))
    r[:, 0] -= 10.0
    assert hub_offsets(r, rows=[0, 1, 2])[0] < -5.0
    with pytest.raises(DataError, match="twice"):
        hub_offsets(r, rows=[0, 0, 0])
    with pytest.raises(DataError, match="integers"):
        hub_offsets(r, rows=[0.9, 1.9, 2.9])
