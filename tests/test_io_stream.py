"""Map descriptors left in the file (``load_map(path, descriptors="stream")``): the same
map as one read whole, row slices read from the file, the compact live map coded block
by block without the float map, and the checks of a whole read."""

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError, MapFileError
from catgraph.graph import PlaceGraph
from catgraph.io import CatgraphMap, StoredDescriptors, _digest, load_map, save_map
from catgraph.live import LiveMap

from .test_io import assert_same_map, make_map


def _route_map(n=700, dim=40, seed=0):
    values = np.cumsum(np.random.default_rng(seed).standard_normal((n, dim)), axis=0).astype(np.float32)
    return CatgraphMap(values, "sad", {"size": None, "patch": 0, "metric": "sad", "normalise": True},
                       PlaceGraph.chain(n), meta={"kind": "descriptors"})


@pytest.fixture(params=[True, False], ids=["deflated", "stored"])
def route(tmp_path, request):
    the_map = _route_map()
    return the_map, save_map(tmp_path / "route.npz", the_map, compress=request.param)


@pytest.mark.parametrize("compress", [True, False])
def test_a_streamed_map_is_the_map_read_whole(tmp_path, rng, compress):
    _, the_map = make_map(rng)
    path = save_map(tmp_path / "map.npz", the_map, compress=compress)
    whole = load_map(path)
    streamed = load_map(path, descriptors="stream")
    assert isinstance(streamed.descriptors, StoredDescriptors)
    assert streamed.descriptors.shape == whole.descriptors.shape and streamed.n_places == whole.n_places
    assert_same_map(whole, CatgraphMap(np.asarray(streamed.descriptors), streamed.metric, streamed.frontend,
                                       streamed.graph, streamed.positions, streamed.floors, streamed.ids,
                                       streamed.histograms, streamed.name, streamed.meta))
    streamed.descriptors.close()


def test_row_slices_and_blocks_read_the_file(route):
    the_map, path = route
    stored = load_map(path, descriptors="stream").descriptors
    values = the_map.descriptors
    # forward, backward, overlapping, empty, open-ended, negative: each the array's own slice
    for a, b in [(0, 5), (5, 300), (300, 301), (10, 20), (0, 700), (650, None), (-30, -10), (400, 400), (600, 900)]:
        got = stored[a:b]
        assert got.dtype == values.dtype and np.array_equal(got, values[a:b]), (a, b)
    assert np.array_equal(np.concatenate(list(stored.blocks(rows=37))), values)
    assert np.array_equal(stored[[3, 1]], values[[3, 1]])  # row numbers: read in one pass (take)
    assert np.array_equal(stored[np.array([True] * 700)], values)  # anything else: read whole, then indexed
    assert np.array_equal(np.asarray(stored, dtype=np.float64), values.astype(np.float64))
    stored.close()
    with pytest.raises(ValueError):
        stored[0:3]


def test_rows_by_number_are_read_in_one_ascending_pass(route, monkeypatch):
    the_map, path = route
    stored = load_map(path, descriptors="stream").descriptors
    values = the_map.descriptors
    monkeypatch.setattr(StoredDescriptors, "TAKE_ROWS", 50)
    monkeypatch.setattr(StoredDescriptors, "__array__", lambda self, dtype=None, copy=None: 1 / 0)
    reads = []
    rows_of = StoredDescriptors._rows
    monkeypatch.setattr(StoredDescriptors, "_rows", lambda self, a, b: (reads.append((a, b)), rows_of(self, a, b))[1])
    opened = []
    open_member = stored._zip.open
    stored._zip.open = lambda *a, **k: (opened.append(a), open_member(*a, **k))[1]
    rows = np.array([640, 3, 3, 699, 0, 41, -1, 120, 121, 400])  # any order, repeated, from the end
    got = stored[rows]
    assert got.dtype == values.dtype and np.array_equal(got, values[rows])
    # one stream, skipping forward (a stream opened again reads the member from its start)
    assert len(opened) == 1
    # ascending slices of at most TAKE_ROWS rows, each from a row asked for to one asked for
    assert reads == [(0, 42), (120, 122), (400, 401), (640, 641), (699, 700)]
    assert np.array_equal(stored.take(np.array([], dtype=np.int64)), values[:0])
    for bad in (np.array([700]), np.array([-701]), np.array([1.0]), np.array([[1]])):
        with pytest.raises(IndexError, match="row numbers|1-D array"):
            stored.take(bad)
    stored.close()


def test_the_compact_live_map_codes_the_file_block_by_block(route, monkeypatch):
    the_map, path = route
    whole = LiveMap(load_map(path), layout="uint8")

    def refuse(self, dtype=None, copy=None):
        raise AssertionError("the descriptors were read whole")

    monkeypatch.setattr(StoredDescriptors, "__array__", refuse)
    monkeypatch.setattr(StoredDescriptors, "BLOCK_ROWS", 64)
    streamed = LiveMap(load_map(path, descriptors="stream"), layout="uint8")
    assert streamed.map is None
    a, b = whole.reference, streamed.reference
    assert (a.offset, a.step) == (b.offset, b.step)
    assert b.descriptors.dtype == np.uint8 and np.array_equal(a.descriptors, b.descriptors)
    frames = the_map.descriptors[[3, 350, 699]] + 0.25
    for frame in frames:
        assert np.array_equal(whole.difference_row(frame), streamed.difference_row(frame))


def test_the_float32_live_map_reads_the_file_whole(route):
    the_map, path = route
    live = LiveMap(load_map(path, descriptors="stream"))
    assert np.array_equal(live.reference.descriptors, the_map.descriptors)


def test_a_map_file_replaced_after_loading_is_not_read(route):
    the_map, path = route
    stored = load_map(path, descriptors="stream").descriptors
    save_map(path, _route_map(seed=1))  # written to a new file and renamed over the old one
    assert np.array_equal(np.asarray(stored), the_map.descriptors)
    assert not np.array_equal(np.asarray(load_map(path).descriptors), the_map.descriptors)


def _rewrite(path, edit, keep_digest=False):
    """The archive at ``path`` with ``edit(members)`` applied; ``keep_digest=False``: its
    digest left as it was (so the edit fails the checksum), else recomputed."""
    with np.load(path, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    edit(members)
    if keep_digest:
        arrays = {k: v for k, v in members.items() if not k.startswith("__")}
        members["__sha256__"] = np.array(_digest(int(members["__version__"]), members["__metadata__"].tobytes(),
                                                 arrays))
    np.savez(path, **members)


def test_an_edited_descriptor_fails_the_checksum(route):
    _, path = route

    def edit(members):
        members["descriptors"] = members["descriptors"].copy()
        members["descriptors"][650, 3] += 1e-3

    _rewrite(path, edit)
    with pytest.raises(MapFileError, match="checksum"):
        load_map(path, descriptors="stream")


def test_a_nan_under_a_valid_checksum_is_refused_at_its_row(route):
    _, path = route

    def edit(members):
        members["descriptors"] = members["descriptors"].copy()
        members["descriptors"][613, 7] = np.nan

    _rewrite(path, edit, keep_digest=True)
    for mode in ("memory", "stream"):
        with pytest.raises(MapFileError, match="NaN or infinite values .*at row 613"):
            load_map(path, descriptors=mode)


def test_descriptors_not_in_rows_are_refused(route):
    _, path = route

    def edit(members):
        members["descriptors"] = np.asfortranarray(members["descriptors"])

    _rewrite(path, edit, keep_digest=True)
    with pytest.raises(MapFileError, match="Fortran order"):
        load_map(path, descriptors="stream")
    assert load_map(path).descriptors.shape == (700, 40)  # read whole, the order does not matter


def test_the_descriptors_mode_is_checked(route):
    _, path = route
    with pytest.raises(InvalidParameterError, match="'memory' or 'stream'"):
        load_map(path, descriptors="mmap")


def test_a_stream_without_descriptors_is_an_incomplete_map(route):
    _, path = route
    _rewrite(path, lambda members: members.pop("descriptors"), keep_digest=True)
    with pytest.raises(MapFileError, match="lacks the entry 'descriptors'"):
        load_map(path, descriptors="stream")


def test_a_map_loaded_without_its_graph_checks_it_and_builds_none(route, monkeypatch):
    from catgraph.graph import PlaceGraph

    the_map, path = route
    whole = load_map(path)
    assert whole.graph is not None and whole.graph.n_places == 700
    monkeypatch.setattr(PlaceGraph, "from_edges", lambda *a, **k: 1 / 0)
    bare = load_map(path, descriptors="stream", graph=False)
    assert bare.graph is None and bare.n_places == 700
    assert np.array_equal(np.asarray(bare.descriptors), the_map.descriptors) and bare.frontend == whole.frontend
    bare.descriptors.close()
    monkeypatch.undo()

    def edit(members):  # the graph's arrays still count in the checksum
        members["graph.length"] = members["graph.length"] * 2

    _rewrite(path, edit)
    with pytest.raises(MapFileError, match="checksum"):
        load_map(path, graph=False)


def test_a_live_map_from_a_file_streams_the_compact_layout(route, monkeypatch):
    the_map, path = route
    for layout in ("uint8", "float32"):
        expected = LiveMap(load_map(path), layout=layout).reference
        if layout == "uint8":
            monkeypatch.setattr(StoredDescriptors, "__array__", lambda self, dtype=None, copy=None: 1 / 0)
        got = LiveMap(str(path), layout=layout).reference
        assert np.array_equal(got.descriptors, expected.descriptors) and got.step == expected.step
        monkeypatch.undo()
    with pytest.raises(InvalidParameterError, match="carries its front-end"):
        LiveMap(path, junction_radius_m=5.0)


def test_a_copy_or_pickle_of_stored_descriptors_carries_the_values(route):
    import copy
    import pickle

    the_map, path = route
    streamed = load_map(path, descriptors="stream")
    for other in (pickle.loads(pickle.dumps(streamed)), copy.deepcopy(streamed)):
        assert type(other.descriptors) is np.ndarray and np.array_equal(other.descriptors, the_map.descriptors)


@pytest.mark.parametrize("whole_numbers", [False, True])
def test_the_code_scale_comes_from_the_checksum_pass(tmp_path, monkeypatch, whole_numbers):
    """The compact live map reads the file twice in all (the checksum's pass, which takes
    the values' range too, and the coding), and its scale is the one a map read whole
    gets (whole numbers: Wi-Fi strengths, coded exactly with step 1)."""
    the_map = _route_map()
    if whole_numbers:
        values = np.round(np.clip(the_map.descriptors * 3.0 - 60.0, -100.0, 0.0)).astype(np.float32)
        the_map = CatgraphMap(values, the_map.metric, the_map.frontend, the_map.graph, meta=the_map.meta)
    path = save_map(tmp_path / "route.npz", the_map)
    passes = []
    rows = StoredDescriptors._rows

    def counted(self, a, b):
        if a == 0:
            passes.append(b)
        return rows(self, a, b)

    monkeypatch.setattr(StoredDescriptors, "_rows", counted)
    streamed = LiveMap(path, layout="uint8").reference
    assert len(passes) == 2
    whole = LiveMap(the_map, layout="uint8").reference
    assert (streamed.offset, streamed.step) == (whole.offset, whole.step)
    assert (streamed.step == 1.0) == whole_numbers
    assert np.array_equal(streamed.descriptors, whole.descriptors)
