"""Fuzzing the public boundary: whatever goes in, a typed error or a valid result comes out.

Every public entry point that takes user data — the loaders, the front-ends,
``difference_matrix``, ``difference_row``, ``normalise_rows``, ``best_matches``, the
metrics, ``SequenceMatcher.step``, ``Localizer.step`` and ``LiveLocalizer.step`` — is fed arrays of random
shape (0-d, empty, 1- to 3-d), dtype (bool, int, unsigned, float16/32/64, complex,
Python objects, strings) and NaN/infinity placements. The only acceptable outcomes:

* a :class:`~catgraph.exceptions.CatgraphError` (a typed, explained refusal), or
* a result with no NaN where a number is promised, and no warning escaping (a
  :class:`~catgraph.exceptions.CatgraphWarning` about the data is allowed: it is
  catgraph talking to the user, not numpy complaining about arithmetic).

Hypothesis runs derandomised, so the suite is reproducible and fast.
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

from catgraph.exceptions import CatgraphError, CatgraphWarning

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

_FLOAT_WIDTH = {np.float16: 16, np.float32: 32, np.float64: 64}


def _numeric(dtype, shape):
    if dtype in _FLOAT_WIDTH:
        elements = st.floats(allow_nan=True, allow_infinity=True, width=_FLOAT_WIDTH[dtype])
        return arrays(dtype, shape, elements=elements)
    if dtype is np.complex128:
        return arrays(dtype, shape, elements=st.complex_numbers(allow_nan=True, allow_infinity=True))
    return arrays(dtype, shape)


@st.composite
def any_array(draw, min_dims: int = 0, max_dims: int = 3, max_side: int = 6, shape=None):
    """An array of any dtype catgraph may be handed, NaN and infinity included."""
    if shape is None:
        shape = draw(array_shapes(min_dims=min_dims, max_dims=max_dims, min_side=0, max_side=max_side))
    kind = draw(st.sampled_from(["bool", "int8", "int64", "uint8", "float16", "float32", "float64", "float64",
                                 "float64", "complex", "object", "str"]))
    if kind == "object":
        cells = draw(st.lists(st.one_of(st.none(), st.integers(), st.floats(), st.text(max_size=2)),
                              min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
        out = np.empty(shape, dtype=object)
        out.reshape(-1)[:] = cells
        return out
    if kind == "str":
        return np.full(shape, "x")
    dtype = {"bool": np.bool_, "int8": np.int8, "int64": np.int64, "uint8": np.uint8, "float16": np.float16,
             "float32": np.float32, "float64": np.float64, "complex": np.complex128}[kind]
    return draw(_numeric(dtype, shape))


def finite_matrix(min_rows=1, max_rows=8, min_cols=1, max_cols=12):
    shape = st.tuples(st.integers(min_rows, max_rows), st.integers(min_cols, max_cols))
    return arrays(np.float64, shape, elements=st.floats(-10, 10, allow_nan=False, allow_infinity=False))


@contextlib.contextmanager
def only_typed_outcomes():
    """Turn every escaping warning (but catgraph's own) into an error; let CatgraphError through."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", CatgraphWarning)
        try:
            yield
        except CatgraphError:
            pass


# Regressions the fuzzing found (fixed): each stays as an explicit case.
@pytest.mark.parametrize("row", [np.array([1 + 1j, 2]), np.array([], dtype=complex)])
def test_normalise_rows_refuses_complex_rows(row):
    from catgraph.differences import normalise_rows

    with only_typed_outcomes():
        normalise_rows(row)
        pytest.fail("a complex row was accepted")


@pytest.mark.parametrize("which", ["matrix", "row"])
def test_differences_refuse_an_empty_3d_reference(which):
    from catgraph.differences import difference_matrix, difference_row

    with only_typed_outcomes():
        if which == "matrix":
            difference_matrix(np.ones((2, 3)), np.zeros((0, 0, 0)))
        else:
            difference_row(np.ones(3), np.zeros((0, 0, 0)))


@pytest.mark.parametrize("row", [np.array("x"), np.full(8, "x"), np.ones(8, dtype=complex),
                                 np.array([""] * 8, dtype=object)])
def test_localizer_refuses_string_object_or_complex_rows(row):
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.methods import observation_model, resolve_params

    model = observation_model(resolve_params("filter", {"model": "histogram"}), 8, None)
    loc = Localizer(PlaceGraph.chain(8), model, n_particles=50, seed=0)
    with only_typed_outcomes():
        loc.step(row)
        pytest.fail("a string or complex row was accepted")


def test_a_live_descriptor_too_large_for_float32_is_refused_in_one_line():
    from catgraph.exceptions import DataError
    from catgraph.live import LiveLocalizer, LiveMap
    from catgraph.traverse import Traverse

    live = LiveLocalizer(LiveMap(Traverse(np.random.default_rng(0).standard_normal((12, 5)))), model="tempered")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match="too large for float32"):
            live.step(np.full(5, 3.40282357e38))
    assert np.isfinite(live.step(np.arange(5.0)).score)


def _no_nan(*values):
    for v in values:
        arr = np.asarray(v, dtype=np.float64)
        assert not np.isnan(arr).any(), f"NaN in a result: {arr}"


# ---------------------------------------------------------------------------- differences
@FUZZ
@given(any_array(), st.sampled_from([None, "sad", "ssd", "cosine", "hamming", "nope"]))
def test_normalise_rows_typed_or_finite(x, _metric):
    from catgraph.differences import normalise_rows

    with only_typed_outcomes():
        out = normalise_rows(x)
        assert np.all(np.isfinite(out)) and out.shape == np.shape(x)


@pytest.mark.parametrize("row", [[1.0, np.inf, 2.0], [], [np.nan, 1.0], np.array(np.inf), [[1.0, 2.0], [3.0, -np.inf]]])
def test_normalise_rows_known_hostile_rows(row):
    from catgraph.differences import normalise_rows

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CatgraphError):
            normalise_rows(row)


@FUZZ
@given(any_array(max_dims=3), any_array(max_dims=3), st.sampled_from(["sad", "ssd", "cosine", "hamming", "l2"]))
def test_difference_matrix_typed_or_finite(query, reference, metric):
    from catgraph.differences import difference_matrix

    with only_typed_outcomes():
        out = difference_matrix(query, reference, metric)
        assert out.ndim == 2 and np.all(np.isfinite(out))


@FUZZ
@given(st.data(), st.sampled_from(["sad", "ssd", "cosine"]))
def test_difference_matrix_of_valid_input_is_finite(data, metric):
    from catgraph.differences import difference_matrix

    d = data.draw(st.integers(1, 6))
    q = data.draw(finite_matrix(1, 5, d, d))
    r = data.draw(finite_matrix(1, 7, d, d))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = difference_matrix(q, r, metric, normalise=data.draw(st.booleans()))
    assert out.shape == (q.shape[0], r.shape[0]) and np.all(np.isfinite(out))


@FUZZ
@given(any_array(max_dims=3), any_array(min_dims=0, max_dims=3), st.sampled_from(["sad", "ssd", "cosine", "hamming"]))
def test_difference_row_typed_or_finite(descriptor, reference, metric):
    from catgraph.differences import difference_row

    with only_typed_outcomes():
        out = difference_row(descriptor, reference, metric)
        assert out.ndim == 1 and np.all(np.isfinite(out))
        assert np.ndim(descriptor) == 1, "a multi-dimensional descriptor must be refused, not flattened"


def test_difference_row_refuses_an_image_shaped_descriptor():
    from catgraph.differences import difference_row

    with pytest.raises(CatgraphError):
        difference_row(np.ones((2, 2, 4)), np.ones((3, 16)))


# ---------------------------------------------------------------------------- matching and metrics
@FUZZ
@given(any_array(max_dims=3), st.one_of(st.integers(-2, 20), st.floats(), st.none(), st.booleans()))
def test_best_matches_typed_or_finite(scores, exclusion):
    from catgraph.matching import best_matches

    with only_typed_outcomes():
        match, confidence = best_matches(scores, exclusion)
        assert match.shape == confidence.shape and np.all(np.isfinite(confidence)) and np.all(confidence >= 0)
        assert np.all(match >= -1)


@FUZZ
@given(st.data())
def test_evaluate_typed_or_valid(data):
    from catgraph.metrics import evaluate
    from catgraph.traverse import FrameTolerance

    n = data.draw(st.integers(0, 12))
    n_ref = data.draw(st.integers(1, 15))
    query_index = data.draw(st.one_of(arrays(np.int64, n, elements=st.integers(-2, 20)), any_array(max_dims=2)))
    match = data.draw(st.one_of(arrays(np.int64, n, elements=st.integers(-3, n_ref + 2)), any_array(max_dims=2)))
    confidence = data.draw(st.one_of(arrays(np.float64, n, elements=st.floats(-5, 5)), any_array(max_dims=2)))
    with only_typed_outcomes():
        ev = evaluate(query_index, match, confidence, FrameTolerance(n_ref, data.draw(st.integers(0, 3))))
        m = ev.metrics
        _no_nan(m.auc, m.recall_at_100p, m.recall_at_99p, m.recall_at_90p, m.accuracy, ev.curve.precision,
                ev.curve.recall)
        for value in (m.auc, m.recall_at_100p, m.recall_at_99p, m.recall_at_90p, m.accuracy):
            assert 0.0 <= value <= 1.0
        assert 0 <= m.mtl <= m.n_queries


@FUZZ
@given(any_array(max_dims=2), any_array(max_dims=2), any_array(max_dims=2), st.integers(-1, 5))
def test_pr_curve_typed_or_valid(correct, has_output, confidence, n_positive):
    from catgraph.metrics import auc, pr_curve

    with only_typed_outcomes():
        curve = pr_curve(correct, has_output, confidence, n_positive)
        _no_nan(curve.precision, curve.recall, curve.thresholds, auc(curve))
        assert 0.0 <= auc(curve) <= 1.0


@FUZZ
@given(any_array(max_dims=2))
def test_max_time_to_localisation_typed_or_valid(correct):
    from catgraph.metrics import max_time_to_localisation

    with only_typed_outcomes():
        mtl = max_time_to_localisation(correct)
        assert 0 <= mtl <= np.size(correct)


# ---------------------------------------------------------------------------- streaming steps
@FUZZ
@given(st.lists(any_array(min_dims=0, max_dims=2, max_side=8), min_size=1, max_size=4),
       st.sampled_from([1, 3, "adaptive"]))
def test_sequence_matcher_step_typed_or_valid(rows, window):
    from catgraph.sequence import SequenceMatcher

    matcher = SequenceMatcher(window=window, l_min=2, l_max=6)
    for row in rows:
        with only_typed_outcomes():
            out = matcher.step(row)
            _no_nan(out.score, out.confidence)
            assert -1 <= out.match < np.size(row)


@FUZZ
@given(st.lists(st.tuples(any_array(min_dims=0, max_dims=2, max_side=8),
                          st.one_of(st.none(), st.floats(), st.integers(-5, 5), st.just("1"))),
                min_size=1, max_size=4))
def test_localizer_step_typed_or_valid(steps):
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.methods import observation_model, resolve_params

    model = observation_model(resolve_params("filter", {"model": "histogram"}), 8, None)
    loc = Localizer(PlaceGraph.chain(8), model, n_particles=50, seed=0)
    for row, odometry in steps:
        with only_typed_outcomes():
            est = loc.step(row, odometry=odometry)
            _no_nan(est.confidence, est.new_place_probability, est.log_odds)
            assert 0.0 <= est.confidence <= 1.0 and np.isfinite(est.log_odds)
            assert 0 <= est.place < 8


@pytest.mark.parametrize("odometry", [np.nan, np.inf, -np.inf])
def test_localizer_refuses_non_finite_odometry_on_the_first_step(odometry):
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.methods import observation_model, resolve_params

    model = observation_model(resolve_params("filter", {"model": "histogram"}), 8, None)
    loc = Localizer(PlaceGraph.chain(8), model, n_particles=50, seed=0)
    with pytest.raises(CatgraphError):
        loc.step(np.linspace(0, 1, 8), odometry=odometry)


def _live_maps():
    """One small live map of each data kind: images (8 × 8, 4 × 4 patches), Wi-Fi scans (dBm,
    +100 = not seen) and descriptors (cosine)."""
    from catgraph.live import LiveMap
    from catgraph.pipeline import FrontEnd
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(0)
    images = Traverse(rng.uniform(0, 255, (12, 8, 8)), name="images")
    scans = rng.uniform(-100, -40, (12, 6))
    scans[rng.random(scans.shape) < 0.3] = 100.0
    wifi = Traverse(scans, name="wifi", meta={"kind": "wifi"})
    descriptors = Traverse(rng.standard_normal((12, 5)), name="descriptors")
    return {"images": LiveMap(images, FrontEnd(patch=4)), "wifi": LiveMap(wifi), "descriptors": LiveMap(descriptors)}


_LIVE_MAPS: dict = {}


@FUZZ
@given(st.sampled_from(["images", "wifi", "descriptors"]), st.sampled_from(["combined", "tempered", "matcher"]),
       st.lists(st.tuples(any_array(min_dims=0, max_dims=3, max_side=8),
                          st.one_of(st.none(), st.floats(), st.integers(-5, 5))), min_size=1, max_size=3))
def test_live_step_typed_or_valid(kind, model, steps):
    """A camera or scanner callback hands ``LiveLocalizer.step`` whatever arrived: a typed
    refusal or a valid estimate, and a refused frame leaves the localiser usable."""
    from catgraph.live import LiveLocalizer

    if not _LIVE_MAPS:
        _LIVE_MAPS.update(_live_maps())
    live_map = _LIVE_MAPS[kind]
    options = {"combined": {"l_max": 6, "seed": 0}, "tempered": {"seed": 0}, "matcher": {"l_max": 6}}[model]
    live = LiveLocalizer(live_map, model=model, **options)
    for frame, odometry in steps:
        with only_typed_outcomes():
            est = live.step(frame, odometry)
            _no_nan(est.score, est.confidence)
            assert -1 <= est.place < live_map.n_places
            if model != "matcher":
                assert 0 <= est.place and 0.0 <= est.new_place_probability <= 1.0
    # after whatever was refused, a good frame still gets an answer
    good = {"images": np.full((8, 8), 128.0) + np.eye(8), "wifi": np.full(6, -60.0) + np.arange(6),
            "descriptors": np.arange(5.0)}[kind]
    est = live.step(good)
    assert -1 <= est.place < live_map.n_places and np.isfinite(est.score)


# ---------------------------------------------------------------------------- front-ends
@FUZZ
@given(any_array(min_dims=0, max_dims=4, max_side=6), st.one_of(st.integers(-1, 8), st.none()))
def test_seqslam_preprocess_typed_or_finite(images, patch):
    from catgraph.frontends import seqslam_preprocess

    with only_typed_outcomes():
        out = seqslam_preprocess(images, patch=patch)
        assert out.ndim == 2 and np.all(np.isfinite(out))


@FUZZ
@given(any_array(min_dims=0, max_dims=3, max_side=6))
def test_wifi_vectors_typed_or_finite(rss):
    from catgraph.frontends import wifi_vectors

    with only_typed_outcomes():
        out = wifi_vectors(rss)
        assert np.all(np.isfinite(out)) and np.all(out >= 0)


# ---------------------------------------------------------------------------- loaders
@FUZZ
@given(any_array(max_dims=4), st.sampled_from(["npy", "npz", "npz-frames", "npz-two"]))
def test_load_array_typed_or_valid(tmp_path_factory, array, how):
    from catgraph.datasets import load_traverse

    folder = tmp_path_factory.mktemp("arr")
    path = folder / f"x.{how[:3]}"
    if how == "npy":
        np.save(path, array, allow_pickle=True)
    elif how == "npz":
        np.savez(path, descriptors=array)
    elif how == "npz-frames":
        np.savez(path, frames=array, positions=array)
    else:
        np.savez(path, a=array, b=array)
    with only_typed_outcomes():
        t = load_traverse(path)
        assert t.frames.ndim >= 2 and len(t) > 0
        if np.issubdtype(t.frames.dtype, np.floating):
            assert np.all(np.isfinite(t.frames))
        assert not np.issubdtype(t.frames.dtype, np.complexfloating)


_CELL = st.one_of(st.integers(-120, 120).map(str), st.sampled_from(["100", "", "nan", "inf", "x", " ", "1e400",
                                                                   "-1e-400", "20160101120000", "0x1"]))


@FUZZ
@given(st.lists(st.lists(_CELL, min_size=1, max_size=4), min_size=0, max_size=4),
       st.sampled_from(["rss", "crd", "tms", "ids"]), st.booleans())
def test_load_uji_typed_or_valid(tmp_path_factory, rows, which, binary):
    from catgraph.datasets import load_uji

    folder = tmp_path_factory.mktemp("uji")
    good = {"rss": "100,-60\n-70,100\n", "crd": "1,2,0\n3,4,0\n", "tms": "20160101120000000\n20160101120001000\n",
            "ids": "1\n2\n"}
    for name, text in good.items():
        (folder / f"trn01{name}.csv").write_text(text)
    content = "\n".join(",".join(r) for r in rows)
    target = folder / f"trn01{which}.csv"
    if binary:
        target.write_bytes(b"\xff\xfe\x00" + content.encode())
    else:
        target.write_text(content)
    with only_typed_outcomes():
        t = load_uji(folder / "trn01")
        assert np.all(np.isfinite(t.frames)) and len(t) > 0
        if t.timestamps is not None:
            assert np.all(np.isfinite(t.timestamps))


@FUZZ
@given(st.binary(max_size=64), st.sampled_from([".png", ".jpg", ".jpeg"]))
def test_load_image_folder_typed_or_valid(tmp_path_factory, blob, suffix):
    from catgraph.datasets import load_image_folder

    folder = tmp_path_factory.mktemp("img")
    (folder / f"img-001{suffix}").write_bytes(blob)
    with only_typed_outcomes():
        t = load_image_folder(folder)
        assert len(t) == 1


@pytest.mark.parametrize("source", [5, None, 2.5, b"x", ["a", "b"], {"a": 1}, np.zeros(3), "", "\x00"])
def test_load_traverse_with_a_non_path(source):
    from catgraph.datasets import load_traverse

    with pytest.raises(CatgraphError, match="path"):
        load_traverse(source)


@pytest.mark.parametrize("array", [np.array(np.inf), np.array(np.nan), np.array(1.0), np.ones((2, 3), complex),
                                   np.array([[1 + 2j, 3]]), np.zeros((0, 4)), np.zeros((3, 0))])
def test_load_array_regressions(tmp_path: Path, array):
    """0-d arrays (the NaN reporter indexed row 0), complex arrays (the imaginary part was dropped)."""
    from catgraph.datasets import load_traverse

    np.save(tmp_path / "x.npy", array)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CatgraphError):
            load_traverse(tmp_path / "x.npy")


@FUZZ
@given(st.binary(max_size=200), st.booleans())
def test_load_map_typed_or_valid(tmp_path_factory, blob, zip_header):
    from catgraph.io import load_map

    path = tmp_path_factory.mktemp("map") / "m.npz"
    path.write_bytes((b"PK\x03\x04" if zip_header else b"") + blob)
    with only_typed_outcomes():
        load_map(path)
        pytest.fail("random bytes were read as a map")


_JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=3),
                     lambda children: st.lists(children, max_size=3) | st.dictionaries(
                         st.sampled_from(["method", "params", "metrics", "frames", "runs", "auc", "match"]), children,
                         max_size=4), max_leaves=12)


@FUZZ
@given(_JSON)
def test_report_inputs_typed_or_valid(tmp_path_factory, payload):
    import json

    from catgraph.report import load_results, markdown_table

    path = tmp_path_factory.mktemp("res") / "r.json"
    path.write_text(json.dumps(payload))
    with only_typed_outcomes():
        runs = load_results([path])
        assert runs and all(isinstance(r, dict) for r in runs)
        assert markdown_table(runs).startswith("| method")
