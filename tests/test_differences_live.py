"""Difference rows and matrices: one arithmetic for streaming and batch, edge cases."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist

from catgraph.differences import (
    PreparedReference,
    difference_matrix,
    difference_row,
    iter_difference_blocks,
    normalise_rows,
)
from catgraph.exceptions import DataError, InvalidParameterError, ShapeMismatchError

SCIPY = {"sad": "cityblock", "ssd": "sqeuclidean", "cosine": "cosine"}


def _slow(q, r, metric):
    """Obviously correct float64 reference."""
    q64, r64 = q.astype(np.float64), r.astype(np.float64)
    if metric == "sad":
        return np.abs(q64[:, None, :] - r64[None]).sum(-1)
    if metric == "ssd":
        return ((q64[:, None, :] - r64[None]) ** 2).sum(-1)
    if metric == "cosine":
        qn, rn = np.linalg.norm(q64, axis=1), np.linalg.norm(r64, axis=1)
        denom = qn[:, None] * rn[None]
        sim = np.divide(q64 @ r64.T, denom, out=np.zeros_like(denom), where=denom > 0)
        return np.clip(1 - sim, 0, 2)
    return (q64[:, None, :] != r64[None]).sum(-1).astype(float)


@pytest.mark.parametrize("metric", ["sad", "ssd", "cosine"])
@pytest.mark.parametrize("dim", [1, 7, 16, 33])
def test_kernel_within_float32_bound_of_slow_reference(metric, dim, rng):
    q = rng.normal(size=(5, dim)).astype(np.float32)
    r = rng.normal(size=(600, dim)).astype(np.float32)
    fast, slow = difference_matrix(q, r, metric), _slow(q, r, metric)
    if metric == "cosine":
        bound = (dim + 6) * 2.0**-24 * 2  # |terms| of unit vectors sum to ≤ 1, plus the norms
    else:
        terms = np.abs(q[:, None, :].astype(float) - r[None]) ** (1 if metric == "sad" else 2)
        bound = (dim + 3) * 2.0**-24 * terms.sum(-1)
    assert np.all(np.abs(fast - slow) <= bound + 1e-12)
    np.testing.assert_allclose(fast, cdist(q.astype(float), r.astype(float), SCIPY[metric]), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("metric", ["sad", "ssd", "cosine", "hamming"])
def test_row_block_and_matrix_agree_bit_for_bit(metric, rng):
    if metric == "hamming":
        q, r = rng.random((9, 40)) > 0.5, rng.random((1000, 40)) > 0.5
    else:
        q, r = rng.normal(size=(9, 40)).astype(np.float32), rng.normal(size=(1000, 40)).astype(np.float32)
    ref = PreparedReference(r, metric)
    for normalise in (False, True):
        full = difference_matrix(q, r, metric, block_rows=4, normalise=normalise)
        assert np.array_equal(full, difference_matrix(q, ref, metric, block_rows=9, normalise=normalise))
        for i in range(len(q)):
            assert np.array_equal(ref.row(q[i], normalise=normalise), full[i])
            assert np.array_equal(difference_row(q[i], r, metric, normalise=normalise), full[i])
        stacked = np.concatenate([b for _, b in iter_difference_blocks(q, ref, metric, 2, normalise=normalise)])
        assert np.array_equal(stacked, full)
    # a shard of the reference gives the same columns (raw differences)
    raw = difference_matrix(q, r, metric)
    assert np.array_equal(PreparedReference(r[300:700], metric).block(q), raw[:, 300:700])


def test_hamming_is_exact_count(rng):
    q, r = rng.random((4, 70)) > 0.5, rng.random((6, 70)) > 0.5
    assert np.array_equal(difference_matrix(q, r, "hamming"), _slow(q, r, "hamming"))
    packed = difference_matrix(np.packbits(q, axis=1), np.packbits(r, axis=1), "hamming")
    assert np.array_equal(packed, _slow(np.unpackbits(np.packbits(q, axis=1), axis=1),
                                        np.unpackbits(np.packbits(r, axis=1), axis=1), "hamming"))


def test_normalise_rows_against_numpy_and_bitwise_row_vs_matrix(rng):
    d = rng.normal(size=(3, 9000)) * 5 + 2
    out = normalise_rows(d)
    expected = (d - d.mean(1, keepdims=True)) / d.std(1, keepdims=True)
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12)
    for i in range(3):
        assert np.array_equal(normalise_rows(d[i]), out[i])


def test_normalise_rows_rejects_non_finite_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match=r"non-finite.*inf.*index 1"):
            normalise_rows([1.0, np.inf, 2.0])
        with pytest.raises(DataError, match="nan"):
            normalise_rows([[1.0, 2.0], [np.nan, 0.0]])
        with pytest.raises(DataError, match="no reference places"):
            normalise_rows([])
        with pytest.raises(DataError, match="shape"):
            normalise_rows(np.zeros((2, 2, 2)))
        assert normalise_rows(np.zeros((0, 5))).shape == (0, 5)


def test_zero_spread_row_is_no_evidence_not_a_confident_match():
    from catgraph.matching import best_matches

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        flat = normalise_rows(np.full((1, 50), 3.7))
    assert np.all(flat == 0.0)  # the normalised difference of an unrelated place
    _, confidence = best_matches(flat, exclusion=2)
    assert confidence[0] <= 0.0  # every place ties: no margin


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 6), st.integers(1, 300), st.floats(-1e3, 1e3), st.floats(1e-3, 1e3), st.integers(0, 2**31))
def test_normalise_rows_zero_mean_unit_std(m, n, shift, scale, seed):
    d = np.random.default_rng(seed).normal(size=(m, n)) * scale + shift
    out = normalise_rows(d)
    for row, src in zip(out, d):
        if src.std() > 1e-9 * max(1.0, abs(src.mean())):
            assert abs(row.mean()) < 1e-8 and abs(row.std() - 1) < 1e-8
        else:
            assert np.all(row == 0)


def test_difference_row_refuses_anything_but_one_descriptor(rng):
    r = rng.normal(size=(5, 16))
    with pytest.raises(DataError, match=r"one descriptor of shape \(d,\).*\(2, 2, 4\)"):
        difference_row(np.zeros((2, 2, 4)), r)
    with pytest.raises(DataError, match="one descriptor"):
        difference_row(np.zeros((1, 16)), r)
    with pytest.raises(ShapeMismatchError, match="same front-end"):
        difference_row(np.zeros(15), r)
    with pytest.raises(DataError, match="NaN"):
        difference_row(np.array([np.inf] + [0.0] * 15), r)
    with pytest.raises(DataError, match="empty"):
        PreparedReference(np.zeros((0, 4)))
    with pytest.raises(InvalidParameterError, match="metric"):
        difference_row(np.zeros(16), PreparedReference(r, "sad"), "cosine")
    with pytest.raises(DataError, match="too large for float32"):
        PreparedReference(np.array([[1e300, 0.0]]))


def test_prepared_reference_validates_once_and_reuses_out(rng):
    r = rng.normal(size=(300, 8)).astype(np.float32)
    ref = PreparedReference(r, "cosine")
    assert ref.norms.shape == (300,) and ref.nbytes == r.nbytes + 300 * 8
    out = np.empty(300)
    got = ref.row(r[3], out=out)
    assert got is out and abs(out[3]) < 1e-6
    with pytest.raises(ShapeMismatchError, match="out"):
        ref.row(r[3], out=np.empty(299))


def test_result_does_not_depend_on_thread_count(rng, monkeypatch):
    import catgraph.differences as differences

    q = rng.normal(size=(3, 64)).astype(np.float32)
    r = rng.normal(size=(2000, 64)).astype(np.float32)
    monkeypatch.setattr(differences, "WORK_PER_THREAD", 1)  # every core
    many = difference_matrix(q, r, "sad", normalise=True)
    monkeypatch.setattr(differences, "WORK_PER_THREAD", 1 << 60)  # one thread
    one = difference_matrix(q, r, "sad", normalise=True)
    assert np.array_equal(many, one)


def test_complex_rows_and_empty_frames_are_refused_with_a_reason():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match="real numbers"):
            normalise_rows(np.array([1 + 1j, 2]))
        with pytest.raises(DataError, match="real numbers"):
            normalise_rows(np.array(["a", "b"]))
        with pytest.raises(DataError, match="empty"):
            difference_matrix(np.ones((2, 3)), np.zeros((0, 0, 0)))
        with pytest.raises(DataError, match="empty"):
            difference_row(np.ones(3), np.zeros((0, 0, 0)))


# ---------------------------------------------------------------------------------------
# the compact (uint8) layout


def _slow_codes(ref, q, metric):
    """Obviously correct: integer sums of code differences, times the step."""
    qc = ref.prepare_query(q).astype(np.int64)
    diff = qc[:, None, :] - ref.descriptors.astype(np.int64)[None]
    if metric == "ssd":
        return (diff**2).sum(-1) * ref.step**2
    return np.abs(diff).sum(-1) * ref.step


@pytest.mark.parametrize("metric", ["sad", "ssd", "hamming"])
def test_uint8_layout_equals_slow_integer_reference_on_every_path(metric, rng):
    if metric == "hamming":
        q, r = rng.random((7, 40)) > 0.5, rng.random((900, 40)) > 0.5
    else:
        q = (rng.normal(size=(7, 33)) * 1.5).astype(np.float32)  # some values outside the map's range
        r = rng.normal(size=(900, 33)).astype(np.float32)
    ref = PreparedReference(r, metric, layout="uint8")
    assert ref.descriptors.dtype == np.uint8 and ref.descriptors.nbytes == r.shape[0] * ref.dim
    slow = _slow_codes(ref, q, metric)
    assert np.array_equal(ref.block(q), slow)
    assert np.array_equal(difference_matrix(q, ref, metric, block_rows=3), slow)
    for i in range(len(q)):
        assert np.array_equal(ref.row(q[i]), slow[i])
        assert np.array_equal(ref.row(q[i], normalise=True), normalise_rows(slow[i]))


def test_uint8_sad_within_stated_bound_of_float_differences(rng):
    q = (rng.normal(size=(6, 50)) * 2.0).astype(np.float32)
    r = rng.normal(size=(400, 50)).astype(np.float32)
    ref = PreparedReference(r, "sad", layout="uint8")
    exact = _slow(q, r, "sad")
    got = ref.block(q)
    for i in range(len(q)):
        bound = ref.quantisation_bound(q[i])
        err = np.abs(got[i] - exact[i])
        assert err.max() <= bound + 1e-9
        # the bound is not vacuous: it is within a small factor of the worst error seen
        assert bound < 50 * max(err.max(), ref.step)
    # values outside the range widen the bound by exactly their distance to it
    inside = ref.quantisation_bound(np.zeros(50))
    outside = np.zeros(50)
    outside[0] = ref.offset + 255 * ref.step + 3.0
    assert ref.quantisation_bound(outside) == pytest.approx(inside + 3.0)


def test_uint8_layout_is_exact_for_integer_values(rng):
    # Wi-Fi strengths in whole dB: the codes are the values themselves
    r = rng.integers(0, 106, size=(300, 20)).astype(np.float32)
    q = rng.integers(0, 106, size=(4, 20)).astype(np.float32)
    ref = PreparedReference(r, "sad", layout="uint8")
    assert ref.step == 1.0 and ref.quantisation_bound(q[0]) == 20.0 * ref.step
    assert np.array_equal(ref.block(q), _slow(q, r, "sad"))
    assert np.array_equal(ref.decode(ref.descriptors), r.astype(np.float64))


def test_uint8_layout_refusals(rng):
    r = rng.normal(size=(50, 8)).astype(np.float32)
    with pytest.raises(InvalidParameterError, match="cosine needs layout='float32'"):
        PreparedReference(r, "cosine", layout="uint8")
    with pytest.raises(InvalidParameterError, match="'layout' parameter"):
        PreparedReference(r, "sad", layout="int4")
    with pytest.raises(DataError, match="NaN or infinite"):
        PreparedReference(np.full((3, 2), np.nan), "sad", layout="uint8")
    with pytest.raises(InvalidParameterError, match="float32"):
        PreparedReference(r, "sad").decode(np.zeros(8, dtype=np.uint8))


# ---------------------------------------------------------------------------------------
# compiled kernels: a writable cache wherever the package lives


def test_jit_cache_falls_back_to_a_private_folder_when_nothing_is_writable(tmp_path, monkeypatch):
    import numba

    from catgraph import _jit

    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(_jit, "_CHECKED", False)
    # the folder beside the package and numba's user folder both read-only
    monkeypatch.setattr(_jit, "_writable", lambda folder: folder.name.startswith("catgraph-numba-"))
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(_jit, "_package_cache", lambda: tmp_path / "no-build-cache")  # nothing shipped to copy
    where = _jit.cache_location()
    assert where.parent == tmp_path and where.name.startswith("catgraph-numba-")
    assert numba.config.CACHE_DIR == str(where)

    @_jit.njit
    def twice(x):  # pragma: no cover - compiled
        return 2 * x

    assert twice(21) == 42
    assert any(where.rglob("*.nbi")), "the compiled kernel is cached in the private folder"


def test_jit_cache_set_read_only_by_the_user_falls_back_with_a_warning(tmp_path, monkeypatch):
    import numba

    from catgraph import _jit
    from catgraph.exceptions import CatgraphWarning

    read_only = tmp_path / "read-only"
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(read_only))
    monkeypatch.setattr(_jit, "_CHECKED", False)
    monkeypatch.setattr(_jit, "_writable", lambda folder: folder != read_only and folder.name != "__pycache__"
                        and folder.name.startswith("catgraph-numba-"))
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(_jit, "_package_cache", lambda: tmp_path / "no-build-cache")
    with pytest.warns(CatgraphWarning, match=f"NUMBA_CACHE_DIR={read_only} cannot be written"):
        where = _jit.cache_location()
    assert where.name.startswith("catgraph-numba-") and numba.config.CACHE_DIR == str(where)


def test_jit_compiles_without_a_disk_cache_where_nothing_is_writable(tmp_path, monkeypatch):
    import numba

    from catgraph import _jit

    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(_jit, "_CHECKED", False)
    monkeypatch.setattr(_jit, "_NOWHERE", False)
    monkeypatch.setattr(_jit, "_writable", lambda folder: False)
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(tmp_path / "no-temp"))
    monkeypatch.setattr(_jit, "_package_cache", lambda: tmp_path / "no-build-cache")
    _jit.cache_location()
    assert _jit._NOWHERE and numba.config.CACHE_DIR == ""

    @_jit.njit
    def thrice(x):  # pragma: no cover - compiled
        return 3 * x

    assert thrice(14) == 42  # compiled, not cached: numba would have refused to decorate it
    assert not thrice._cache_hits and not any(tmp_path.rglob("*.nbi"))


def _shipped(folder, names):
    folder.mkdir(parents=True)
    for name in names:
        (folder / name).write_bytes(name.encode())
    return folder


def test_jit_copies_the_kernels_built_with_the_package_where_its_folder_is_read_only(tmp_path, monkeypatch):
    """The package's own __pycache__ read-only: its build-time kernels are copied into
    numba's folder for the package's sources in the cache chosen instead (the user's, or
    the private one), files already there kept, nothing else copied."""
    import numba
    from numba.core.caching import _CacheLocator

    from catgraph import _jit

    shipped = _shipped(tmp_path / "pkg" / "__pycache__",
                       ["k.f-10.py311.nbi", "k.f-10.py311.1.nbc", "m.cpython-311.pyc"])
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(_jit, "_CHECKED", False)
    monkeypatch.setattr(_jit, "_package_cache", lambda: shipped)
    user = tmp_path / "user-cache"
    monkeypatch.setattr(_jit, "_numba_user_cache", lambda: user)
    monkeypatch.setattr(_jit, "_writable", lambda folder: folder == user)
    assert _jit.cache_location() == user
    target = user / _CacheLocator.get_suitable_cache_subpath(_jit.__file__)
    assert sorted(f.name for f in target.iterdir()) == ["k.f-10.py311.1.nbc", "k.f-10.py311.nbi"]
    assert (target / "k.f-10.py311.nbi").read_bytes() == b"k.f-10.py311.nbi"
    (target / "k.f-10.py311.nbi").write_bytes(b"numba's own, newer")  # a later index is never overwritten
    assert _jit._seed(shipped, user) == 0 and (target / "k.f-10.py311.nbi").read_bytes() == b"numba's own, newer"

    # nothing writable but the private folder: the copy goes there, under numba's layout for NUMBA_CACHE_DIR
    monkeypatch.setattr(_jit, "_CHECKED", False)
    monkeypatch.setattr(_jit, "_writable", lambda folder: folder.name.startswith("catgraph-numba-"))
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    private = _jit.cache_location()
    assert numba.config.CACHE_DIR == str(private)
    assert (private / _CacheLocator.get_suitable_cache_subpath(_jit.__file__) / "k.f-10.py311.1.nbc").is_file()
    assert _jit._seed(tmp_path / "absent", user) == 0  # no build cache: nothing to do


def test_jit_uses_numba_locations_when_writable(tmp_path, monkeypatch):
    import numba

    from catgraph import _jit

    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(_jit, "_CHECKED", False)
    where = _jit.cache_location()
    assert numba.config.CACHE_DIR == "" and where.name in ("__pycache__", "numba")
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    assert _jit.cache_location() == tmp_path
    assert _jit.njit(cache=False)(lambda x: x + 1)(1) == 2


@pytest.mark.parametrize("metric, layout", [("sad", "float32"), ("sad", "uint8"), ("cosine", "float32"),
                                            ("hamming", "float32")])
def test_column_blocks_equal_the_matrix_columns_bit_for_bit(metric, layout, rng):
    from catgraph.differences import iter_difference_columns

    if metric == "hamming":
        r = rng.random((9000, 24)) > 0.5
    else:
        r = rng.normal(size=(9000, 24)).astype(np.float32)
    q = r[::311]
    ref = PreparedReference(r, metric, layout)
    for normalise in (False, True):
        full = difference_matrix(q, ref, metric, normalise=normalise)
        starts = []
        for start, block in iter_difference_columns(q, ref, metric, block_places=5000, normalise=normalise):
            starts.append(start)
            assert block.shape[0] == len(q) and block.shape[1] <= 8192
            assert np.array_equal(block, full[:, start : start + block.shape[1]])
        assert starts == [0, 8192]  # 5000 rounded up to whole chunks of 4096


@pytest.mark.parametrize("metric", ["sad", "ssd"])
@pytest.mark.parametrize("dim", [1, 63, 64, 65, 128, 200, 512])
def test_uint8_vector_kernel_exact_across_lane_boundaries(metric, dim, rng):
    # the compact kernel sums 64-byte vector steps plus a scalar tail: every split of the
    # dimension, extreme codes (0 and 255 both ways) included, equals the integer reference
    r = rng.normal(size=(300, dim)).astype(np.float32)
    r[0], r[1] = r.min(), r.max()
    ref = PreparedReference(r, metric, layout="uint8")
    q = np.stack([np.full(dim, r.min()), np.full(dim, r.max()), r[5] * 3.0]).astype(np.float32)
    slow = _slow_codes(ref, q, metric)
    assert np.array_equal(ref.block(q), slow)
    assert np.array_equal(ref.row(q[1]), slow[1])
    assert np.isclose(slow[0, 1], dim * 255 * (ref.step if metric == "sad" else 255 * ref.step**2), rtol=1e-12)


def test_normalisation_split_over_threads_equals_one_thread_bit_for_bit(rng, monkeypatch):
    # the passes run on pieces (chunk runs of one row, or row ranges of a matrix) on
    # several threads; every chunk's partial sum is the same whichever thread adds it
    import catgraph.differences as differences

    row = rng.normal(size=(1, 3 * 4096 + 77)) * 5 + 2
    matrix = rng.normal(size=(5, 9001))
    monkeypatch.setattr(differences, "NORMALISE_PER_THREAD", 1 << 60)
    one = [normalise_rows(row), normalise_rows(matrix)]
    monkeypatch.setattr(differences, "NORMALISE_PER_THREAD", 1)
    monkeypatch.setattr(differences, "_threads_available", lambda: 3)
    assert len(differences._split(1, row.shape[1], 4096)) == 3
    assert len(differences._split(5, 9001, 4096)) == 3
    many = [normalise_rows(row), normalise_rows(matrix)]
    for a, b in zip(one, many):
        assert np.array_equal(a, b)
    for x, got in zip((row, matrix), many):
        want = (x - x.mean(1, keepdims=True)) / x.std(1, keepdims=True)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("metric, layout", [("sad", "float32"), ("sad", "uint8"), ("ssd", "uint8"),
                                            ("cosine", "float32"), ("hamming", "uint8")])
def test_reference_columns_are_the_map_against_its_own_rows(metric, layout, rng):
    from catgraph.differences import iter_difference_columns, iter_reference_columns

    if metric == "hamming":
        r = rng.random((5000, 24)) > 0.5
    else:
        r = rng.normal(size=(5000, 24)).astype(np.float32)
    ref = PreparedReference(r, metric, layout)
    places = np.array([0, 17, 311, 4999])
    for normalise in (False, True):
        got = np.concatenate([b for _, b in iter_reference_columns(ref, places, block_places=4096,
                                                                   normalise=normalise)], axis=1)
        if layout == "float32":  # the original descriptors as queries: the same bits
            want = np.concatenate([b for _, b in iter_difference_columns(r[places], ref, metric, block_places=4096,
                                                                         normalise=normalise)], axis=1)
        else:  # slow integer reference on the codes themselves (never coded twice)
            c = ref.descriptors.astype(np.int64)
            diff = c[places][:, None, :] - c[None]
            want = (diff**2).sum(-1) * ref.step**2 if metric == "ssd" else np.abs(diff).sum(-1) * ref.step
            if normalise:
                want = normalise_rows(want)
        assert np.array_equal(got, want)
        assert np.all(got[np.arange(len(places)), places] == got.min(axis=1))  # each row is nearest itself
    with pytest.raises(InvalidParameterError, match="places must lie"):
        next(iter_reference_columns(ref, np.array([5000])))
    with pytest.raises(InvalidParameterError, match="PreparedReference"):
        iter_reference_columns(r, places)


@pytest.mark.parametrize("metric, layout", [("sad", "float32"), ("sad", "uint8"), ("ssd", "uint8"),
                                            ("cosine", "float32")])
def test_live_row_with_fused_normalisation_equals_the_prepared_row(metric, layout, rng):
    """The live step's row (the normalisation's passes in one compiled call) against
    :meth:`PreparedReference.row`: bit for bit, over whole and partial sum chunks, for a
    flat frame (no spread: zeros) and without normalisation."""
    from catgraph.graph import PlaceGraph
    from catgraph.io import CatgraphMap
    from catgraph.live import LiveMap

    for n in (3, 4096, 9000):
        reference = rng.standard_normal((n, 24)).astype(np.float32)
        for normalise in (True, False):
            the_map = CatgraphMap(reference, metric, {"size": None, "patch": 0, "metric": metric,
                                                      "normalise": normalise},
                                  PlaceGraph.chain(n), meta={"kind": "descriptors"})
            live_map = LiveMap(the_map, layout=layout)
            for q in (rng.standard_normal(24).astype(np.float32), reference[n // 2], np.ones(24, np.float32)):
                # (a descriptor with no information, the flat frame, then gets a constant row, as in batch)
                want = live_map._no_information(q, live_map.reference.row(q, normalise=normalise))
                got = live_map._row_into(q, np.full(n, np.nan))
                assert np.array_equal(got.view(np.int64), want.view(np.int64))
