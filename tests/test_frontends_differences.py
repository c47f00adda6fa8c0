import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.distance import cdist

from catgraph.differences import difference_matrix, difference_row, iter_difference_blocks, normalise_rows
from catgraph.exceptions import DataError, InsufficientMemoryError, InvalidParameterError, ShapeMismatchError
from catgraph.frontends import patch_normalise, seqslam_preprocess, wifi_vectors


def test_patch_normalise_matches_hand_computation_and_flat_patch_is_zero():
    img = np.zeros((1, 4, 8))
    img[0, :, 4:] = np.arange(16).reshape(4, 4)
    out = patch_normalise(img, patch=4)
    assert np.all(out[0, :, :4] == 0)  # flat patch: zeros, not NaN
    block = np.arange(16.0).reshape(4, 4)
    np.testing.assert_allclose(out[0, :, 4:], (block - block.mean()) / block.std(), rtol=1e-6)


def test_patch_normalise_uneven_edges_finite():
    out = patch_normalise(np.random.default_rng(0).random((2, 5, 7)), patch=4)
    assert out.shape == (2, 5, 7) and np.all(np.isfinite(out))


def test_seqslam_preprocess_shapes_and_constant_images():
    imgs = np.full((3, 16, 32, 3), 200, dtype=np.uint8)
    d = seqslam_preprocess(imgs, size=(16, 8))
    assert d.shape == (3, 128) and d.dtype == np.float32 and np.all(d == 0)


def _whole_at_once(images, size=None, patch=4, crop=None):
    """The front-end on every frame at once, step by step: the reference for the blocks."""
    from catgraph.frontends import resize_images, to_greyscale

    x = to_greyscale(images)
    if crop is not None:
        top, bottom, left, right = crop
        x = x[:, top : x.shape[1] - bottom, left : x.shape[2] - right]
    if size is not None:
        x = resize_images(x, size)
    if patch:
        x = patch_normalise(x, patch)
    return x.reshape(len(x), -1).astype(np.float32)


@pytest.mark.parametrize("shape", [(7, 30, 45, 3), (7, 30, 45), (5, 18, 22, 4), (6, 17, 23, 1)])
@pytest.mark.parametrize("size, patch, crop", [(None, 4, None), ((16, 8), 4, None), ((9, 7), 3, (2, 3, 4, 1)),
                                               (None, 0, (1, 0, 0, 5)), ((12, 6), 0, None)])
def test_seqslam_preprocess_in_blocks_is_the_whole_at_once(monkeypatch, shape, size, patch, crop):
    """Frames described a block at a time give the floats of every frame at once, for any block."""
    from catgraph import frontends

    images = np.random.default_rng(sum(shape)).integers(0, 256, shape, dtype=np.uint8)
    expected = _whole_at_once(images, size, patch, crop)
    for block_frames in (1, 2, 3, 100):
        monkeypatch.setattr(frontends, "_FRONTEND_BLOCK_BYTES", 4 * shape[1] * shape[2] * block_frames)
        out = seqslam_preprocess(images, size=size, patch=patch, crop=crop)
        assert out.dtype == np.float32 and out.shape == expected.shape
        np.testing.assert_array_equal(out, expected)


def test_seqslam_preprocess_bounds_its_temporaries():
    """Colour frames are described a block at a time: the float temporaries stay about one
    block's size, not a multiple of all the frames' (measured with tracemalloc)."""
    import tracemalloc

    from catgraph import frontends

    images = np.random.default_rng(0).integers(0, 256, (64, 120, 160, 3), dtype=np.uint8)  # 3.7 MB
    block = frontends._FRONTEND_BLOCK_BYTES
    try:
        frontends._FRONTEND_BLOCK_BYTES = 4 * 120 * 160 * 4  # four frames a block
        tracemalloc.start()
        out = seqslam_preprocess(images, size=(32, 16))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        frontends._FRONTEND_BLOCK_BYTES = block
    np.testing.assert_array_equal(out, _whole_at_once(images, (32, 16)))
    # the whole traverse at once holds float32 colour (14.7 MB) and greyscale (4.9 MB)
    assert peak < images.nbytes, peak


def test_wifi_not_detected_is_weak_not_strong():
    v = wifi_vectors(np.array([[100, -40, -104, -110]]))
    np.testing.assert_allclose(v, [[0, 65, 1, 0]])
    with pytest.raises(DataError, match="dBm"):
        wifi_vectors(np.array([[5, -40]]))


@pytest.mark.parametrize("metric, reference", [("sad", "cityblock"), ("ssd", "sqeuclidean"), ("cosine", "cosine")])
def test_difference_matrix_against_scipy(metric, reference, rng):
    q, r = rng.random((23, 17)), rng.random((31, 17))
    expected = cdist(q, r, reference)
    np.testing.assert_allclose(difference_matrix(q, r, metric, block_rows=5), expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(difference_row(q[3], r, metric), expected[3], rtol=1e-5, atol=1e-5)


def test_hamming_bool_and_packed(rng):
    q, r = rng.random((4, 16)) > 0.5, rng.random((6, 16)) > 0.5
    expected = cdist(q, r, "hamming") * 16
    np.testing.assert_allclose(difference_matrix(q, r, "hamming"), expected)
    np.testing.assert_allclose(difference_matrix(np.packbits(q, axis=1), np.packbits(r, axis=1), "hamming"), expected)


def test_packed_descriptors_through_the_pipeline_and_the_live_front_end(rng):
    """Bits packed in uint8 (ORB, BRISK) under ``metric="hamming"``: the pipeline and the
    live front-end keep them as bits (the same differences as the unpacked booleans), where
    they were cast to float32 and refused; without the metric they stay numbers (cosine)."""
    from catgraph.live import describe_frame
    from catgraph.pipeline import FrontEnd, describe, differences
    from catgraph.traverse import Traverse

    q, r = rng.random((5, 64)) > 0.5, rng.random((7, 64)) > 0.5
    packed_q, packed_r = Traverse(np.packbits(q, axis=1)), Traverse(np.packbits(r, axis=1))
    hamming = FrontEnd(metric="hamming", normalise=False)
    expected = cdist(q, r, "hamming") * 64
    np.testing.assert_allclose(differences(packed_r, packed_q, hamming), expected)
    np.testing.assert_allclose(differences(Traverse(r), Traverse(q), hamming), expected)
    descriptors, metric = describe(packed_r, hamming)
    assert metric == "hamming" and descriptors.dtype == np.uint8
    assert describe(packed_r)[1] == "cosine"
    one = describe_frame(np.packbits(q[0]), "descriptors", hamming)
    assert one.dtype == np.uint8
    np.testing.assert_array_equal(one, np.packbits(q[0]))
    assert describe_frame(np.packbits(q[0]), "descriptors").dtype == np.float32
    # booleans against packed bits: said so, not a count of values that blames the front-end
    with pytest.raises(ShapeMismatchError, match="packed in uint8"):
        differences(packed_r, Traverse(q), hamming)
    with pytest.raises(ShapeMismatchError, match="packed in uint8"):
        differences(Traverse(r), packed_q, hamming)


def test_blocks_are_bounded_and_cover_everything(rng):
    q, r = rng.random((10, 3)), rng.random((7, 3))
    blocks = list(iter_difference_blocks(q, r, "sad", block_rows=4))
    assert [s for s, _ in blocks] == [0, 4, 8]
    assert max(b.shape[0] for _, b in blocks) <= 4


def test_mismatched_sizes_unknown_metric_and_nan():
    with pytest.raises(ShapeMismatchError, match="same front-end"):
        difference_matrix(np.zeros((2, 3)), np.zeros((2, 4)))
    with pytest.raises(InvalidParameterError, match="metric"):
        difference_matrix(np.zeros((2, 3)), np.zeros((2, 3)), "l7")
    with pytest.raises(DataError, match="NaN"):
        difference_matrix(np.array([[np.nan, 1.0]]), np.zeros((2, 2)))


def test_cosine_zero_vector_is_finite():
    d = difference_matrix(np.zeros((1, 3)), np.ones((2, 3)), "cosine")
    np.testing.assert_allclose(d, 1.0)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 5), st.integers(1, 9)),
              elements=st.floats(-1e3, 1e3, allow_nan=False)))
def test_normalise_rows_finite_zero_mean_unit_std(d):
    out = normalise_rows(d)
    assert np.all(np.isfinite(out))
    for row, src in zip(out, d):
        if np.ptp(src) > 1e-6 * max(1.0, np.abs(src).max()):
            assert abs(row.mean()) < 1e-6 and abs(row.std() - 1) < 1e-6
        else:
            assert np.all(np.abs(row) < 1e3)


def test_informative_frames_black_flat_undetected_zero():
    from catgraph.frontends import informative_frames

    rng = np.random.default_rng(1)
    images = rng.integers(0, 255, (5, 16, 32)).astype(np.uint8)
    images[1] = 0  # black
    images[3] = 77  # flat grey
    d = seqslam_preprocess(images, patch=4)
    np.testing.assert_array_equal(informative_frames(d), [True, False, True, False, True])
    wifi = wifi_vectors(np.array([[100, 100, 100], [-60, 100, -80], [-110, 100, -120]]))
    np.testing.assert_array_equal(informative_frames(wifi), [False, True, False])
    assert informative_frames(np.zeros((0, 3))).shape == (0,)


def test_check_information_warns_for_queries_and_refuses_an_empty_map():
    from catgraph.exceptions import CatgraphWarning
    from catgraph.frontends import check_information

    d = np.eye(4)
    d[2] = 0
    with pytest.warns(CatgraphWarning, match=r"1 of 4 query frames carry no information.*first at frame 2"):
        np.testing.assert_array_equal(check_information(d, "query"), [True, True, False, True])
    with pytest.raises(DataError, match="none of the 3 reference frames"):
        check_information(np.zeros((3, 5)), "reference")


def test_patch_larger_than_the_image_is_refused():
    with pytest.raises(DataError, match=r"patch side 1000 is larger than the images \(32×16"):
        seqslam_preprocess(np.zeros((2, 16, 32)), patch=1000)
    assert seqslam_preprocess(np.random.default_rng(0).random((2, 16, 32)), patch=32).shape == (2, 512)


def _best_matches_reference(scores, exclusion):
    """Slow, obvious: loop over rows and columns."""
    match, conf = [], []
    for row in np.asarray(scores, dtype=float):
        finite = [v for v in row if np.isfinite(v)]
        if not finite or (len(row) > 1 and max(finite) == min(finite)):
            match.append(-1)
            conf.append(0.0)
            continue
        j = min((v, k) for k, v in enumerate(row) if np.isfinite(v))[1]
        outside = [v for k, v in enumerate(row) if abs(k - j) > exclusion and np.isfinite(v)]
        match.append(j)
        conf.append(min(outside) - row[j] if outside else 0.0)
    return np.array(match), np.array(conf)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 12)),
              elements=st.one_of(st.integers(-3, 3).map(float), st.sampled_from([np.nan, np.inf, -np.inf]))),
       st.integers(0, 4))
def test_best_matches_against_reference(scores, exclusion):
    from catgraph.matching import best_matches

    scores = np.where(np.isneginf(scores), np.nan, scores)
    match, conf = best_matches(scores, exclusion)
    ref_match, ref_conf = _best_matches_reference(scores, exclusion)
    np.testing.assert_array_equal(match, ref_match)
    np.testing.assert_allclose(conf, ref_conf)
    assert np.all(np.isfinite(conf)) and np.all(conf >= 0)


def test_best_matches_in_row_blocks_equals_one_block(monkeypatch):
    """Large inputs are processed in blocks of rows: the answers must not depend on the block size."""
    import catgraph.matching as matching

    rng = np.random.default_rng(3)
    scores = rng.random((57, 40))
    scores[5] = 2.0
    scores[11, ::3] = np.nan
    whole = matching.best_matches(scores, 3)
    monkeypatch.setattr(matching, "_BLOCK_VALUES", 40 * 4)  # blocks of 4 rows, the last one shorter
    blocked = matching.best_matches(scores, 3)
    np.testing.assert_array_equal(blocked[0], whole[0])
    np.testing.assert_array_equal(blocked[1], whole[1])
    ref_match, ref_conf = _best_matches_reference(scores, 3)
    np.testing.assert_array_equal(blocked[0], ref_match)
    np.testing.assert_allclose(blocked[1], ref_conf)


def test_black_query_frames_get_no_match_with_normalised_rows():
    """A black frame's row, treated as σ = 0, is all zeros after normalisation: no output."""
    from catgraph.matching import best_matches

    rng = np.random.default_rng(2)
    diff = normalise_rows(rng.random((4, 30)))
    diff[1] = normalise_rows(np.full(30, 7.0))
    match, conf = best_matches(diff)
    assert match[1] == -1 and conf[1] == 0.0 and np.all(match[[0, 2, 3]] >= 0)


def test_large_images_at_their_own_size_draw_a_note_that_names_the_fix():
    import warnings

    from catgraph.exceptions import CatgraphWarning
    from catgraph.pipeline import LARGE_IMAGE_PIXELS, FrontEnd, describe
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(0)
    big = Traverse(rng.uniform(0, 255, (3, 150, 200)), name="camera")
    with pytest.warns(CatgraphWarning, match=r"camera: its 200×150 frames are compared at full size, 30,000 values "
                                             r"each .* --size 64x32 .* --size 200x150 to keep this size"):
        d, _ = describe(big)
    assert d.shape == (3, 200 * 150)  # nothing changes but the note
    small = Traverse(rng.uniform(0, 255, (3, 32, 64)), name="nordland-like")
    side = int(np.sqrt(LARGE_IMAGE_PIXELS))
    at_the_limit = Traverse(rng.uniform(0, 255, (3, side, side)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        describe(small)
        describe(at_the_limit)
        describe(big, FrontEnd(size=(200, 150)))  # its own size, given: no note
        describe(big, FrontEnd(size=(64, 32)))
        describe(big, FrontEnd(crop=(30, 40, 40, 60)))  # 100 × 80 pixels left after the crop


def test_a_live_frame_reads_no_memory_figure(monkeypatch):
    """One frame's descriptor is far below any memory limit: describing it does not read the
    machine's memory figure (a file read per frame on the live path)."""
    import catgraph._validation as validation

    reads = []
    monkeypatch.setattr(validation, "available_memory", lambda: reads.append(1) or 2**40)
    seqslam_preprocess(np.random.default_rng(0).integers(0, 256, (1, 480, 640, 3), dtype=np.uint8), patch=4)
    assert reads == []
    with pytest.raises(InsufficientMemoryError, match="smaller size"):  # a traverse's descriptors are checked
        monkeypatch.setattr(validation, "available_memory", lambda: 2**20)
        seqslam_preprocess(np.zeros((40, 480, 640), dtype=np.uint8), patch=0)
