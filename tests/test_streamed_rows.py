"""The batch methods walk the difference rows block by block: the same answers as on the
matrix, bit for bit, without the ``n_query × N`` matrix ever being made."""

import numpy as np
import pytest

import catgraph.io
from catgraph.conditions import Condition
from catgraph.datasets import load_traverse
from catgraph.differences import DifferenceRows
from catgraph.exceptions import DataError, ShapeMismatchError
from catgraph.experiment import Experiment, prepare, run, run_method
from catgraph.grid import GridLocalizer
from catgraph.graph import PlaceGraph
from catgraph.io import build_map, query_difference_rows, query_differences
from catgraph.localizer import Localizer
from catgraph.observation import TemperedObservation
from catgraph.recogniser import HistogramPlaceRecogniser
from catgraph.likelihood import HistogramLikelihood
from catgraph.sequence import match_sequences

from .conftest import write_images

#: the batch methods of the registry (the trained histogram, which needs ground truth, below)
METHODS = [("single-frame", {}), ("histogram", {}), ("sequence", {"window": 5}),
           ("sequence", {"window": "adaptive", "l_max": 20}),
           ("sequence", {"window": "adaptive", "rule": "challenged", "l_max": 20}),
           ("filter", {}), ("filter", {"model": "combined", "l_max": 20}),
           ("filter", {"mode": "particles", "n_particles": 200})]


@pytest.fixture
def images(tmp_path):
    rng = np.random.default_rng(5)
    base = rng.integers(0, 255, (70, 8, 16))
    noisy = np.clip(base + rng.normal(0, 30, base.shape), 0, 255)
    noisy[11] = 128  # a blank frame: no information, its row made constant
    return write_images(tmp_path / "ref", base), write_images(tmp_path / "qry", noisy)


def test_rows_of_a_matrix_in_blocks():
    d = np.arange(35.0).reshape(7, 5)
    rows = DifferenceRows.of(d)
    assert (len(rows), rows.n_places, rows.shape) == (7, 5, (7, 5))
    blocks = list(rows.blocks(3))
    assert [s for s, _ in blocks] == [0, 3, 6] and [len(b) for _, b in blocks] == [3, 3, 1]
    assert np.array_equal(rows.matrix(), d)
    with pytest.raises(DataError, match="2 dimensions"):
        DifferenceRows.of(np.zeros(4))


@pytest.mark.parametrize("block_rows", [None, 1, 4, 1000])
def test_query_rows_equal_the_matrix(images, block_rows):
    ref, qry = images
    p = prepare(Experiment(query=qry, reference=ref))
    whole = query_differences(p.map, p.query)
    rows = query_difference_rows(p.map, p.query)
    stacked = np.concatenate([b for _, b in rows.blocks(block_rows)])
    assert np.array_equal(stacked, whole)  # bit for bit, the blank frame's zero row included
    assert np.all(whole[11] == 0.0)


def test_prepare_keeps_no_matrix_and_under_reorders_the_rows(images):
    ref, qry = images
    p = prepare(Experiment(query=qry, reference=ref))
    assert p._differences is None  # computed when read, not when prepared
    whole = prepare(Experiment(query=qry, reference=ref)).differences
    for c in (Condition("shuffle", seed=2), Condition("reverse"), Condition("speed", factor=0.5)):
        lazy = p.under(c)
        assert lazy._differences is None
        expected = whole[c.order(len(p.query))]
        assert np.array_equal(lazy.difference_rows().matrix(), expected)
        assert np.array_equal(prepare(Experiment(query=qry, reference=ref, condition=c)).differences, expected)
    assert p._differences is None
    assert np.array_equal(p.differences, whole) and p._differences is not None  # read once: kept


@pytest.mark.parametrize("method,params", METHODS)
def test_methods_answer_as_on_the_matrix(images, method, params):
    ref, qry = images
    for c in (Condition(), Condition("shuffle", seed=1)):
        lazy = prepare(Experiment(query=qry, reference=ref, condition=c))
        kept = prepare(Experiment(query=qry, reference=ref, condition=c))
        kept.differences  # the matrix, as the benchmarks keep it
        a, b = run_method(method, params, lazy), run_method(method, params, kept)
        assert lazy._differences is None  # the method walked the rows, it made no matrix
        assert np.array_equal(a.match, b.match) and np.array_equal(a.confidence, b.confidence)


def test_commands_never_make_the_matrix(images, monkeypatch, tmp_path):
    """A run from the experiment layer (what the commands call) never computes the
    ``n_query × N`` matrix: each method walks the rows."""
    ref, qry = images
    path = tmp_path / "map.npz"
    catgraph.io.save_map(path, build_map(load_traverse(ref), graph=True))

    def refused(*args, **kwargs):
        raise AssertionError("the whole difference matrix was computed")

    monkeypatch.setattr(catgraph.io, "query_differences", refused)
    for method, params in METHODS:
        result, out, _ = run(Experiment(query=qry, map=path, method=method, params=params))
        assert len(result.match) == len(out["frames"]["match"]) == 70


def _blocks(d, cuts, n=None):
    """DifferenceRows over ``d`` (announcing ``n`` rows, default all) in blocks ``[a, b)``
    for consecutive ``cuts`` ``a, b``; a pair ``(a, b)`` given as a tuple in ``cuts`` is
    one block as it is, so a malformed source can skip rows."""
    def blocks_of(_):
        pairs = [c if isinstance(c, tuple) else None for c in cuts]
        if any(pairs):
            for a, b in cuts:
                yield a, d[a:b]
            return
        for a, b in zip(cuts[:-1], cuts[1:]):
            yield a, d[a:b]
    return DifferenceRows(len(d) if n is None else n, d.shape[1], blocks_of)


def test_filters_and_recogniser_take_rows_and_refuse_broken_blocks():
    rng = np.random.default_rng(0)
    d = rng.standard_normal((40, 30))
    graph = PlaceGraph.chain(30)
    for make in (lambda: GridLocalizer(graph, TemperedObservation()),
                 lambda: Localizer(graph, TemperedObservation(), n_particles=100, seed=1)):
        a = make().run(d)
        b = make().run(_blocks(d, [0, 7, 8, 40]))
        assert np.array_equal(a.place, b.place) and np.array_equal(a.score, b.score)
        with pytest.raises(ShapeMismatchError, match="follow each other"):
            make().run(_blocks(d, [(0, 7), (8, 40)]))  # a row skipped
        with pytest.raises(ShapeMismatchError, match="held 38 rows, not the 40"):
            make().run(_blocks(d[:38], [0, 20, 38], n=40))
        with pytest.raises(ShapeMismatchError, match="31 places but the graph has 30"):
            make().run(DifferenceRows.of(rng.standard_normal((5, 31))))
        bad = d.copy()
        bad[25, 3] = np.nan
        with pytest.raises(DataError, match="frames 20–39"):
            make().run(_blocks(bad, [0, 20, 40]))
    rec = lambda: HistogramPlaceRecogniser(HistogramLikelihood(), n_init=10)  # noqa: E731
    a, b = rec().run(d), rec().run(_blocks(d, [0, 13, 40]))
    assert np.array_equal(a.match, b.match) and np.array_equal(a.confidence, b.confidence)


def test_sequence_matching_takes_rows_in_any_blocks():
    rng = np.random.default_rng(2)
    d = rng.standard_normal((90, 60))
    for kw in ({"window": 10}, {"window": "adaptive", "l_max": 40, "rule": "challenged"},
               {"window": "adaptive", "l_max": 40}):
        a = match_sequences(d, **kw)
        for cuts in ([0, 1, 2, 50, 90], [0, 89, 90]):
            b = match_sequences(_blocks(d, cuts), **kw)
            assert np.array_equal(a.match, b.match) and np.array_equal(a.confidence, b.confidence)
            assert np.array_equal(a.window_length, b.window_length)
    with pytest.raises(ShapeMismatchError, match="follow each other"):
        match_sequences(_blocks(d, [(0, 10), (11, 90)]), window=10)
    with pytest.raises(ShapeMismatchError, match="held 80 rows, not the 90"):
        match_sequences(_blocks(d[:80], [0, 80], n=90), window=10)
    with pytest.raises(DataError, match="empty"):
        match_sequences(DifferenceRows.of(np.zeros((0, 60))), window=10)


def _labelled_by_mask(d, gt, q, max_different, seed):
    """The samples of the whole matrix's masks (the slow form): every same-place value in
    row order, then the different-place values drawn by index from their row order."""
    columns = np.arange(d.shape[1])
    same = np.array([gt.correct(np.full(d.shape[1], q[r]), columns) for r in range(len(d))])
    diff = d[~same]
    if max_different is not None and diff.size > max_different:
        diff = diff[np.random.default_rng(seed).choice(diff.size, size=max_different, replace=False)]
    return d[same], diff


@pytest.mark.parametrize("max_different", [None, 1, 500, 10_000])
def test_labelled_samples_in_blocks_equal_the_masks(max_different):
    from catgraph.samples import labelled_samples
    from catgraph.traverse import FrameTolerance

    rng = np.random.default_rng(4)
    d = rng.standard_normal((53, 41))
    gt = FrameTolerance(41, 2)
    q = rng.permutation(53) % 41
    want = _labelled_by_mask(d, gt, q, max_different, 7)
    for source in (d, _blocks(d, [0, 1, 20, 53]), _blocks(d, [0, 53])):
        got = labelled_samples(source, gt, q, max_different=max_different, seed=7)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_the_trained_baseline_walks_the_rows_too(images, monkeypatch):
    ref, qry = images
    kept = prepare(Experiment(query=qry, reference=ref, tolerance=2))
    kept.differences
    params = {"learning": "trained"}
    b = run_method("histogram", params, kept)

    def refused(*args, **kwargs):
        raise AssertionError("the whole difference matrix was computed")

    monkeypatch.setattr(catgraph.io, "query_differences", refused)
    a = run(Experiment(query=qry, reference=ref, tolerance=2, method="histogram", params=params))[0]
    assert np.array_equal(a.match, b.match) and np.array_equal(a.confidence, b.confidence)


def test_particle_filter_run_on_a_query_traverse_walks_its_rows(monkeypatch):
    """``Localizer.run(query, reference=...)``: the answers of the run on
    ``catgraph.pipeline.differences``'s matrix, without that matrix being made."""
    from catgraph.datasets.synthetic import make_world
    from catgraph.pipeline import differences

    world = make_world(seed=2)
    graph = PlaceGraph.chain(len(world.reference))
    make = lambda: Localizer(graph, TemperedObservation(), n_particles=300, seed=3)  # noqa: E731
    whole = make().run(differences(world.reference, world.query), odometry=world.query.odometry,
                       query_index=world.query.index)

    def refused(*args, **kwargs):
        raise AssertionError("the whole difference matrix was computed")

    monkeypatch.setattr(catgraph.io, "query_differences", refused)
    rows = make().run(world.query, reference=world.reference)
    assert np.array_equal(rows.place, whole.place) and np.array_equal(rows.score, whole.score)
    with pytest.raises(DataError, match="needs reference"):
        make().run(world.query)
