"""The Python API against a caller's mistakes: each a typed error naming the problem, never a
silent wrong answer, a NaN that travels, or an exception from deep inside."""

from __future__ import annotations

import copy
import gc
import pickle

import numpy as np
import pytest

from catgraph.exceptions import DataError, InsufficientMemoryError, InvalidParameterError, ShapeMismatchError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.localizer import Localizer
from catgraph.observation import CombinedObservation, HistogramObservation, SequenceObservation, TemperedObservation

N = 60


@pytest.fixture(scope="module")
def rows():
    return np.random.default_rng(0).normal(size=(30, N))


@pytest.mark.parametrize("make", [lambda m: GridLocalizer(PlaceGraph.chain(N), m),
                                  lambda m: Localizer(PlaceGraph.chain(N), m, n_particles=100)])
def test_one_model_serves_one_filter_at_a_time(make, rows):
    """Two filters stepping one model in turn would mix two queries' evidence: once a second
    filter has reset the model, the first may not step it again. One filter after another
    may use it (each reset starts it afresh), and a copy of a filter steps its own copy."""
    model = TemperedObservation()
    first = make(model)
    before = [first.step(r).place for r in rows[:10]]
    twin = copy.deepcopy(first)
    second = make(model)
    assert [second.step(r).place for r in rows[:10]] == before  # the model started afresh
    with pytest.raises(InvalidParameterError, match="now serves another filter"):
        first.step(rows[10])
    twin.step(rows[10])  # its own copy of the model
    pickle.loads(pickle.dumps(second)).step(rows[10])
    first.reset()  # the first filter takes the model back
    assert [first.step(r).place for r in rows[:10]] == before
    with pytest.raises(InvalidParameterError, match="now serves another filter"):
        second.step(rows[10])
    del first, twin
    gc.collect()
    assert [make(model).step(r).place for r in rows[:1]] == before[:1]


def test_a_model_stepped_alone_answers_as_before_the_check(rows):
    """The check only refuses: a filter with its own model gives the answers it gave."""
    alone = GridLocalizer(PlaceGraph.chain(N), TemperedObservation()).run(rows).place
    other = GridLocalizer(PlaceGraph.chain(N), TemperedObservation()).run(rows).place
    np.testing.assert_array_equal(alone, other)


def test_combined_parts_are_distinct_models_with_bounded_weights(rows):
    m = TemperedObservation()
    with pytest.raises(InvalidParameterError, match="one model instance twice"):
        CombinedObservation([m, m]).observe(rows[0])
    with pytest.raises(InvalidParameterError, match="part 1 of CombinedObservation is a str"):
        CombinedObservation([TemperedObservation(), "x"]).observe(rows[0])
    for bad in ([1.0, np.inf], [1.0, np.nan], [1.0, 1e300], [1.0, -1.0], [True, 1.0]):
        with pytest.raises(InvalidParameterError, match="'weights'"):
            CombinedObservation([TemperedObservation(), TemperedObservation()], weights=bad).observe(rows[0])
    obs = CombinedObservation([TemperedObservation(), TemperedObservation()],
                              weights=[np.float32(1.0), 1]).observe(rows[0])
    assert np.all(np.isfinite(obs.log_ratio))


@pytest.mark.parametrize("params, name", [({"novelty_cap": -1.0}, "novelty_cap"),
                                          ({"novelty_cap": float("nan")}, "novelty_cap"),
                                          ({"hub_threshold": float("nan")}, "hub_threshold"),
                                          ({"novelty": "no"}, "novelty")])
def test_tempered_parameters_are_checked(params, name, rows):
    with pytest.raises(InvalidParameterError, match=f"'{name}'"):
        TemperedObservation(**params).observe(rows[0])


def test_sequence_and_histogram_model_arguments(rows):
    with pytest.raises(InvalidParameterError, match="'matcher_params'.*bogus"):
        SequenceObservation(matcher_params={"bogus": 1}).observe(rows[0])
    with pytest.raises(InvalidParameterError, match="'matcher_params'.*window"):
        SequenceObservation(window=5, matcher_params={"window": 7}).observe(rows[0])
    with pytest.raises(InvalidParameterError, match="seed"):
        HistogramObservation(n_init=3, new_place_samples=10, seed=-3).observe(rows[0])
    reference = np.random.default_rng(1).normal(size=(N, N))
    with pytest.raises(InvalidParameterError, match="'gap'"):
        HistogramObservation.bootstrap(reference, gap=N)  # was clamped to N - 2 without a word
    HistogramObservation.bootstrap(reference[:8, :8])  # the default gap still fits a small map


def test_a_sequence_model_pickles_mid_run_and_goes_on_alike(rows):
    f = GridLocalizer(PlaceGraph.chain(N), SequenceObservation(window=5, calibration="agreement"))
    for r in rows[:12]:
        f.step(r)
    g = pickle.loads(pickle.dumps(f))
    assert [f.step(r).place for r in rows[12:]] == [g.step(r).place for r in rows[12:]]


def test_run_arguments_are_checked(rows):
    for make in (lambda: GridLocalizer(PlaceGraph.chain(N), TemperedObservation()),
                 lambda: Localizer(PlaceGraph.chain(N), TemperedObservation(), n_particles=100)):
        with pytest.raises(ShapeMismatchError, match="query_index has shape"):
            make().run(rows, query_index=np.arange(5))
        with pytest.raises(DataError, match="whole frame numbers"):
            make().run(rows, query_index=np.linspace(0, 1, len(rows)))
        with pytest.raises(DataError, match="whole frame numbers"):
            make().run(rows, query_index=["a"] * len(rows))
        for odometry in ("3", True):
            with pytest.raises(DataError, match="odometry"):
                make().step(rows[0], odometry)
        np.testing.assert_array_equal(make().run(rows, query_index=np.arange(len(rows), dtype=float)).query_index,
                                      np.arange(len(rows)))
    with pytest.raises(InvalidParameterError, match="'motion'"):
        Localizer(PlaceGraph.chain(N), TemperedObservation(), n_particles=100, motion="velocity").step(rows[0])


def test_sizes_beyond_memory_are_refused_before_allocating(rows):
    from catgraph.sequence import SequenceMatcher

    with pytest.raises(InsufficientMemoryError, match="matcher's state"):
        SequenceMatcher(l_min=5, l_max=10**9, grid=[5, 10**9]).step(rows[0])
    with pytest.raises(InsufficientMemoryError, match="particles"):
        Localizer(PlaceGraph.chain(N), TemperedObservation(), n_particles=10**12).step(rows[0])


def test_velocities_beyond_the_fastest_line(rows):
    from catgraph.sequence import MAX_VELOCITY, SequenceMatcher, match_sequences

    with pytest.raises(InvalidParameterError, match="'velocities'"):
        match_sequences(rows, window=5, velocities=(1e300,))
    with pytest.raises(InvalidParameterError, match="'velocities'"):
        SequenceMatcher(window=5, velocities=(1.0, -MAX_VELOCITY - 1)).step(rows[0])
    match_sequences(rows, window=5, velocities=(1.0, MAX_VELOCITY))


def test_histogram_likelihood_edges():
    from catgraph.histogram import HistogramLikelihood

    model = HistogramLikelihood().fit([-1e308, 0.0], [1e308, 1.0])  # samples near ±float max
    assert np.all(np.isfinite(model.log_likelihood_ratio(np.array([0.0, 1.0]))))
    rng = np.random.default_rng(0)
    model = HistogramLikelihood().fit(rng.normal(size=50), rng.normal(size=50) + 2)
    with pytest.raises(DataError, match="no place any mass"):
        model.log_posterior(np.zeros(5), log_prior=np.full(5, -np.inf))


def test_graphs_and_maps(tmp_path):
    from catgraph.io import CatgraphMap, build_map, save_map

    with pytest.raises(InvalidParameterError, match="'spacing'"):
        PlaceGraph.chain(20, spacing=0.0)
    with pytest.raises(DataError, match="coordinates"):
        PlaceGraph.from_edges(3, [[0, 1], [1, 2]], positions=np.zeros((3, 1)))
    with pytest.raises(DataError, match="edge kind 'bogus'"):
        PlaceGraph.from_edges(3, [[0, 1], [1, 2]], kinds=["chain", "bogus"])
    with pytest.raises(InvalidParameterError, match="build_map describes a Traverse"):
        build_map(np.zeros((5, 4)))
    with pytest.raises(InvalidParameterError, match="save_map writes a CatgraphMap"):
        save_map(tmp_path / "x.npz", {"descriptors": 1})
    with pytest.raises(DataError, match=r"^map descriptors: 6 NaN or infinite values \(first nan at row 0\)"):
        CatgraphMap(np.full((3, 2), np.nan, dtype=np.float32), "sad", {})
    from catgraph.experiment import run_method

    with pytest.raises(InvalidParameterError, match=r"run_method needs .* \(a Prepared\); got dict"):
        run_method("single-frame", {}, {"map": None})
    with pytest.raises(DataError, match="metric 'l7'"):
        CatgraphMap(np.zeros((3, 2), dtype=np.float32), "l7", {})
    (tmp_path / "afile").write_text("")
    from catgraph.traverse import Traverse

    m = build_map(Traverse(np.random.default_rng(0).normal(size=(10, 4)).astype(np.float32)))
    with pytest.raises(InvalidParameterError, match="not a folder"):
        save_map(tmp_path / "afile" / "inner.npz", m)


def test_live_frames_of_the_wrong_kind():
    from catgraph.live import LiveLocalizer, LiveMap
    from catgraph.traverse import Traverse

    reference = np.random.default_rng(0).normal(size=(50, 16)).astype(np.float32)
    loc = LiveLocalizer(LiveMap(Traverse(reference)), model="tempered")
    with pytest.raises(DataError, match="numeric or boolean"):
        loc.step("abc")
    with pytest.raises(DataError, match="numeric or boolean"):
        loc.step(reference[0].astype(complex))
    with pytest.raises(ShapeMismatchError, match="odometry has 2 entries for 3 frames"):
        loc.run(reference[:3], odometry=[0.0, 1.0])
