import json
import zipfile

import numpy as np
import pytest

from catgraph.exceptions import CatgraphError, DataNotFoundError, MapFileError
from catgraph.graph import PlaceGraph
from catgraph.io import FORMAT_VERSION, CatgraphMap, build_map, load_map, query_differences, reference_from_map, save_map
from catgraph.pipeline import FrontEnd, differences
from catgraph.traverse import Traverse


def make_map(rng, with_histogram=True):
    n = 60
    t = np.linspace(0, 2 * np.pi, n)
    positions = np.stack([50 * np.cos(t), 50 * np.sin(t)], 1)  # a loop: first and last places meet
    reference = Traverse(rng.normal(size=(n, 24)).astype(np.float32), positions=positions,
                         floors=np.arange(n) % 2, ids=np.arange(100, 100 + n), name="loop",
                         meta={"kind": "descriptors", "source": "memory"})
    histograms = {}
    if with_histogram:
        from catgraph.likelihood import HistogramLikelihood

        histograms["image"] = HistogramLikelihood(n_bins=16).fit(rng.normal(0, 1, 300), rng.normal(3, 1, 900))
    return reference, build_map(reference, FrontEnd(patch=0), junction_radius_m=6.0, histograms=histograms,
                                meta={"note": "test"})


def assert_same_map(a: CatgraphMap, b: CatgraphMap):
    assert a.descriptors.dtype == b.descriptors.dtype
    assert a.descriptors.tobytes() == b.descriptors.tobytes()
    for key in ("positions", "floors", "ids"):
        x, y = getattr(a, key), getattr(b, key)
        assert (x is None) == (y is None), key
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), key
    assert (a.metric, a.frontend, a.name, a.meta) == (b.metric, b.frontend, b.name, b.meta)
    assert (a.graph is None) == (b.graph is None)
    if a.graph is not None:
        for key in ("source", "target", "length", "kind", "out_ptr", "reverse", "straight", "route_distance",
                    "positions"):
            x, y = getattr(a.graph, key), getattr(b.graph, key)
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), key
        assert (a.graph.n_places, a.graph.unit) == (b.graph.n_places, b.graph.unit)
    assert sorted(a.histograms) == sorted(b.histograms)
    for name, h in a.histograms.items():
        g = b.histograms[name]
        assert type(h) is type(g) and h.get_params() == g.get_params()
        state_a = {k: v for k, v in vars(h).items() if k.endswith("_")}
        state_b = {k: v for k, v in vars(g).items() if k.endswith("_")}
        assert sorted(state_a) == sorted(state_b)
        for key, value in state_a.items():
            if isinstance(value, np.ndarray):
                assert value.tobytes() == state_b[key].tobytes() and value.dtype == state_b[key].dtype, key
            else:
                assert value == state_b[key] and type(value) is type(state_b[key]), key


def test_round_trip_is_exact(tmp_path, rng):
    reference, m = make_map(rng)
    assert len(m.graph.junction_pairs()) >= 1  # the loop closes
    path = save_map(tmp_path / "sub" / "map.npz", m)
    loaded = load_map(path)
    assert_same_map(m, loaded)
    # the learned histogram evaluates identically after loading
    d = np.linspace(-3, 6, 50)
    assert np.array_equal(m.histograms["image"].log_likelihood_ratio(d), loaded.histograms["image"].log_likelihood_ratio(d))
    # nothing pickled, no stray temporary files
    assert np.load(path, allow_pickle=False)["__version__"] == FORMAT_VERSION
    assert [p.name for p in path.parent.iterdir()] == ["map.npz"]


def test_round_trip_without_optional_parts(tmp_path, rng):
    m = CatgraphMap(rng.random((5, 3)) > 0.5, "hamming", FrontEnd().as_dict())
    loaded = load_map(save_map(tmp_path / "m.npz", m, compress=False))
    assert_same_map(m, loaded)
    assert loaded.graph is None and loaded.histograms == {} and loaded.positions is None


def test_string_ids_round_trip(tmp_path, rng):
    m = CatgraphMap(rng.random((3, 2)), "cosine", {}, ids=np.array(["a.png", "b.png", "c.png"], dtype=object))
    assert list(load_map(save_map(tmp_path / "m.npz", m)).ids) == ["a.png", "b.png", "c.png"]


def test_map_differences_equal_pipeline_differences(rng):
    from catgraph.datasets.loaders import load_array  # noqa: F401  (same path the CLI takes)

    ref_images = rng.integers(0, 255, (12, 8, 16)).astype(np.uint8)
    qry_images = np.clip(ref_images + rng.normal(0, 20, ref_images.shape), 0, 255).astype(np.uint8)
    reference = Traverse(ref_images, meta={"kind": "images"})
    query = Traverse(qry_images[::-1], meta={"kind": "images"})
    frontend = FrontEnd(size=(8, 4), patch=2)
    m = build_map(reference, frontend)
    expected = differences(reference, query, frontend)
    assert np.array_equal(query_differences(m, query), expected)
    as_traverse = reference_from_map(m)
    assert as_traverse.frames.shape == (12, 32) and as_traverse.meta["kind"] == "descriptors"


@pytest.fixture
def saved(tmp_path, rng):
    _, m = make_map(rng)
    return save_map(tmp_path / "map.npz", m)


def test_truncated_file(saved):
    data = saved.read_bytes()
    saved.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError, match="corrupt or truncated"):
        load_map(saved)


def test_flipped_byte_is_detected(saved):
    data = bytearray(saved.read_bytes())
    # flip one byte inside the descriptors member's compressed data
    with zipfile.ZipFile(saved) as z:
        info = z.getinfo("descriptors.npy")
    offset = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    data[offset] ^= 0x01
    saved.write_bytes(bytes(data))
    with pytest.raises(MapFileError, match="corrupt|checksum"):
        load_map(saved)


def test_edited_array_fails_checksum(saved):
    with np.load(saved, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    members["descriptors"] = members["descriptors"].copy()
    members["descriptors"][3, 4] += 1e-3
    np.savez(saved, **members)
    with pytest.raises(MapFileError, match="checksum"):
        load_map(saved)


def test_edited_metadata_fails_checksum(saved):
    with np.load(saved, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    meta = json.loads(members["__metadata__"].tobytes())
    meta["metric"] = "ssd"
    members["__metadata__"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez(saved, **members)
    with pytest.raises(MapFileError, match="checksum"):
        load_map(saved)


def test_newer_version_is_refused(saved):
    with np.load(saved, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    members["__version__"] = np.array(FORMAT_VERSION + 2, dtype=np.int64)
    np.savez(saved, **members)
    with pytest.raises(MapFileError, match=rf"newer catgraph \(format {FORMAT_VERSION + 2} > {FORMAT_VERSION}\); upgrade"):
        load_map(saved)


def test_not_a_map(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, descriptors=np.zeros((3, 2)))
    with pytest.raises(MapFileError, match="not a catgraph map"):
        load_map(path)
    np.save(tmp_path / "single.npy", np.zeros(3))
    with pytest.raises(MapFileError, match="single array"):
        load_map(tmp_path / "single.npy")
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(MapFileError, match="not a catgraph map: it is not a .npz archive"):
        load_map(tmp_path / "text.npz")


def test_pickled_member_is_not_loaded(tmp_path):
    path = tmp_path / "evil.npz"
    np.savez(path, __format__=np.array("catgraph-map"), payload=np.array([{"a": 1}], dtype=object))
    with pytest.raises(MapFileError, match="pickle"):
        load_map(path)


def test_missing_file(tmp_path):
    with pytest.raises(DataNotFoundError, match="does not exist") as info:
        load_map(tmp_path / "nope.npz")
    assert isinstance(info.value, CatgraphError)


def test_graph_must_match_descriptors(rng):
    with pytest.raises(CatgraphError, match="place graph has 4 places"):
        CatgraphMap(rng.random((5, 2)), "sad", {}, graph=PlaceGraph.chain(4))


def test_build_map_command(tmp_path, rng, capsys):
    from catgraph.cli.main import main

    n = 30
    frames = rng.normal(size=(n, 16)).astype(np.float32)
    positions = np.stack([np.arange(n) * 2.0, np.zeros(n)], 1)
    np.savez(tmp_path / "ref.npz", descriptors=frames, positions=positions)
    out = tmp_path / "map.npz"
    assert main(["build-map", str(tmp_path / "ref.npz"), "--out", str(out), "--metric", "sad"]) == 0
    assert "wrote" in capsys.readouterr().out
    m = load_map(out)
    assert m.metric == "sad" and m.n_places == n and m.graph.unit == "m"
    assert np.array_equal(m.descriptors, frames) and np.array_equal(m.positions, positions)
    assert m.meta["source"] == str(tmp_path / "ref.npz")
    assert main(["build-map", str(tmp_path / "missing"), "--out", str(out), "-q"]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_images_of_another_shape_with_as_many_pixels_are_refused(tmp_path, rng):
    """A map keeps its images' (h, w): a transposed query (as many pixels) was compared
    pixel for pixel, silently. With --size both are resized, and any shape goes."""
    from catgraph.exceptions import ShapeMismatchError
    from catgraph.live import LiveMap

    frames = rng.integers(0, 255, (30, 16, 32)).astype(np.uint8)
    ref = Traverse(frames, meta={"kind": "images"})
    the_map = load_map(save_map(tmp_path / "m.npz", build_map(ref)))
    assert the_map.meta["image_shape"] == [16, 32]
    upright = Traverse(frames[:5], meta={"kind": "images"})
    transposed = Traverse(np.ascontiguousarray(frames[:5].transpose(0, 2, 1)), meta={"kind": "images"})
    reshaped = Traverse(frames[:5].reshape(5, 8, 64), meta={"kind": "images"})
    assert query_differences(the_map, upright).shape == (5, 30)
    for query in (transposed, reshaped):
        with pytest.raises(ShapeMismatchError, match="the map's are 32×16"):
            query_differences(the_map, query)
        with pytest.raises(ShapeMismatchError, match="the map's are 32×16"):
            differences(ref, query)  # the batch path without a saved map
        with pytest.raises(ShapeMismatchError, match="live images"):
            LiveMap(the_map).difference_row(query.frames[0])
    resized = build_map(ref, FrontEnd(size=(16, 8)))
    assert query_differences(resized, transposed).shape == (5, 30)


def test_a_loaded_graph_equals_the_saved_one_array_for_array(tmp_path):
    """A Wi-Fi-like survey (zero-length chain edges, floored at 1e-6 of the mean length):
    the floor moved on every reload (966 of 1150 UJI lengths differed)."""
    points = np.stack([4.0 * np.arange(10), np.zeros(10)], 1)
    ref = Traverse(np.random.default_rng(0).random((50, 6)), positions=np.repeat(points, 5, axis=0))
    built = build_map(ref)
    loaded = load_map(save_map(tmp_path / "m.npz", built))
    again = load_map(save_map(tmp_path / "m2.npz", loaded))
    for name in ("source", "target", "kind", "length", "out_ptr", "reverse", "straight", "route_distance"):
        assert np.array_equal(getattr(loaded.graph, name), getattr(built.graph, name)), name
        assert np.array_equal(getattr(again.graph, name), getattr(built.graph, name)), name
    assert np.sum(built.graph.length < 1e-3) > 20  # the floored edges are there


@pytest.mark.parametrize("metadata", [[1, 2], {"meta": 3}, {"meta": {"kind": "video"}}])
def test_metadata_that_is_not_a_maps_is_refused(tmp_path, metadata):
    """Re-signed files whose metadata parses but is not a map's: a typed error, not an
    AttributeError, and not a map that fails later."""
    from catgraph.io import _decode

    with pytest.raises(MapFileError, match="inconsistent map"):
        _decode(metadata, {}, tmp_path / "m.npz")
