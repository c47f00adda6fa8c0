"""Live API: one frame at a time gives the batch answers; bounded bootstrap."""

import json
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from catgraph.datasets.synthetic import make_world
from catgraph.exceptions import DataError, InvalidParameterError
from catgraph.live import LiveEstimate, LiveLocalizer, LiveMap, bootstrap_pairs, describe_frame
from catgraph.pipeline import FrontEnd, describe
from catgraph.traverse import Traverse

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "live.py"


@pytest.fixture(scope="module")
def world():
    return make_world(seed=1, blocks=(2, 2), as_images=True)


@pytest.fixture(scope="module")
def short_query(world):
    return world.query.take(np.arange(120))


def test_describe_frame_equals_batch_front_end(world, rng):
    frontend = FrontEnd(size=(16, 8), patch=4)
    batch, _ = describe(world.query, frontend)
    for k in range(0, len(world.query), 37):
        assert np.array_equal(describe_frame(world.query.frames[k], "images", frontend), batch[k])
    rss = np.where(rng.random((5, 12)) < 0.4, 100.0, -rng.uniform(30, 100, (5, 12)))
    wifi = Traverse(rss, meta={"kind": "wifi", "not_detected": 100.0})
    batch, _ = describe(wifi)
    assert all(np.array_equal(describe_frame(rss[k], "wifi"), batch[k]) for k in range(5))
    bits = rng.random((3, 2, 5)) > 0.5
    assert describe_frame(bits[0], "descriptors").dtype == bool
    with pytest.raises(DataError, match=r"\(h, w\)"):
        describe_frame(np.zeros((2, 3, 4, 5)), "images")
    with pytest.raises(DataError, match="scan"):
        describe_frame(np.zeros((2, 3)), "wifi")
    with pytest.raises(InvalidParameterError, match="kind"):
        describe_frame(np.zeros(3), "lidar")


def test_bootstrap_pairs_are_those_of_reference_samples(rng):
    from catgraph.likelihood import reference_samples

    r = rng.normal(size=(60, 60))
    rows, cols = bootstrap_pairs(60, 7, 500, seed=3)
    _, different = reference_samples(r, 7, max_different=500, seed=3)
    assert np.array_equal(r[rows, cols], different)
    # anchored: rows from a sample of places, columns more than gap away
    rows, cols = bootstrap_pairs(5000, 20, 3000, seed=1, anchor_rows=40)
    assert len(np.unique(rows)) <= 40 and np.all(np.abs(rows - cols) > 20)
    assert cols.min() >= 0 and cols.max() < 5000


def test_map_bootstrap_equals_full_matrix_bootstrap(world):
    from catgraph.differences import difference_matrix
    from catgraph.observation import HistogramObservation

    live_map = LiveMap(world.reference)
    d = live_map.reference.descriptors
    full = HistogramObservation.bootstrap(difference_matrix(d, d, live_map.metric, normalise=True), gap=12,
                                          max_different=4000, seed=5).likelihood
    mine = live_map.bootstrap(gap=12, max_different=4000, seed=5)
    z = np.linspace(-4, 4, 41)
    assert np.array_equal(full.log_likelihood_ratio(z), mine.log_likelihood_ratio(z))
    hub_full = live_map.hub_
    assert hub_full.shape == (live_map.n_places,) and np.all(np.isfinite(hub_full))
    # above anchor_rows: rows sampled, never an N x N matrix
    small = live_map.bootstrap(gap=12, max_different=4000, seed=5, anchor_rows=16)
    assert np.all(np.isfinite(small.log_likelihood_ratio(z)))
    # the same from a map without a place graph (what the batch methods hold)
    from catgraph.io import build_map
    from catgraph.live import map_bootstrap

    likelihood, hub = map_bootstrap(build_map(world.reference, graph=False), gap=12, max_different=4000, seed=5)
    assert np.array_equal(likelihood.log_likelihood_ratio(z), full.log_likelihood_ratio(z))
    np.testing.assert_allclose(hub, hub_full, atol=1e-9)


@pytest.mark.parametrize("model", ["histogram", "histogram-bootstrap", "adaptive", "combined", "tempered",
                                   "histogram-combined"])
def test_live_steps_give_the_batch_answers(world, short_query, model):
    from catgraph.compare import localize

    live = LiveLocalizer(LiveMap(world.reference), model=model, seed=2)
    query = short_query
    estimates = [live.step(query.frames[k], None if k == 0 else float(query.odometry[k])) for k in range(len(query))]
    batch = localize(world.reference, query, model=model, seed=2)
    assert np.array_equal([e.place for e in estimates], batch.match)
    assert np.array_equal([e.score for e in estimates], batch.confidence)
    assert np.array_equal([e.new_place_probability for e in estimates], batch.extra["p_new_place"])
    last = estimates[-1]
    assert isinstance(last, LiveEstimate) and set(last.seconds) == {"frontend", "difference", "model"}
    if model in ("adaptive", "combined", "histogram-combined"):
        assert last.window_length >= 1 and last.velocity is not None
    else:
        assert last.window_length is None


def _with_black_frames(query, frames_black):
    from dataclasses import replace

    frames = query.frames.copy()
    frames[list(frames_black)] = 0
    return replace(query, frames=frames)


@pytest.mark.filterwarnings("ignore:3 of 120 query frames carry no information")
@pytest.mark.parametrize("model", ["combined", "tempered", "adaptive"])
def test_a_frame_with_no_information_gets_the_batch_answer_live(world, short_query, model):
    """A black frame: the batch commands give it a constant row (no match, no evidence);
    live gave it a confident match and fed its row to the filter, so every later answer
    differed."""
    from catgraph.compare import localize

    query = _with_black_frames(short_query, (0, 40, 41))
    live = LiveLocalizer(LiveMap(world.reference), model=model, seed=2)
    estimates = live.run(query.frames, query.odometry)
    batch = localize(world.reference, query, model=model, seed=2)
    assert np.array_equal([e.place for e in estimates], batch.match)
    assert np.array_equal([e.score for e in estimates], batch.confidence)
    row = LiveMap(world.reference).difference_row(query.frames[40])
    assert np.all(row == 0.0)


def test_the_live_matcher_gives_no_match_for_a_frame_with_no_information(world, short_query):
    from catgraph.matching import NO_MATCH

    query = _with_black_frames(short_query, (30,))
    got = LiveLocalizer(LiveMap(world.reference), model="matcher").run(query.frames[:40])
    assert got[30].place == NO_MATCH and got[29].place != NO_MATCH


def test_live_particles_with_odometry_give_the_batch_answers(world, short_query):
    """The batch handed the first frame its odometry (documented as ignored), live handed
    it None; the particle filter started differently from the two, so every answer of a
    query with odometry differed."""
    from catgraph.compare import localize

    params = dict(mode="particles", n_particles=300, seed=2)
    live = LiveLocalizer(LiveMap(world.reference), model="tempered", **params)
    estimates = live.run(short_query.frames, short_query.odometry)
    batch = localize(world.reference, short_query, model="tempered", **params)
    assert short_query.odometry is not None
    assert np.array_equal([e.place for e in estimates], batch.match)
    assert np.array_equal([e.score for e in estimates], batch.confidence)


def test_the_first_frames_odometry_is_ignored():
    from catgraph.graph import PlaceGraph
    from catgraph.localizer import Localizer
    from catgraph.motion import VelocityMotion

    from .conftest import FixedLogRatio

    rng = np.random.default_rng(0)
    rows = rng.random((8, 50))
    odometry = np.full(8, 2.0)
    answers = []
    for first in (None, 0.0, 7.5):
        loc = Localizer(PlaceGraph.chain(50, spacing=2.0), FixedLogRatio(1.0), 200, motion=VelocityMotion(), seed=1)
        out = [loc.step(rows[0], first)] + [loc.step(r, o) for r, o in zip(rows[1:], odometry[1:])]
        answers.append([(e.place, e.confidence, e.new_place_probability) for e in out])
    assert answers[0] == answers[1] == answers[2]


def test_matcher_mode_equals_the_batch_sequence_method(world):
    from catgraph.differences import difference_matrix
    from catgraph.methods import _sequence_kwargs
    from catgraph.sequence import match_sequences

    live_map = LiveMap(world.reference)
    live = LiveLocalizer(live_map, model="matcher", l_max=60)
    got = [live.step(f) for f in world.query.frames[:60]]
    q, _ = describe(world.query)
    d = difference_matrix(q[:60], live_map.reference, live_map.metric, normalise=True)
    p = live.params_  # what the batch `sequence` method calls match_sequences with
    batch = match_sequences(d, radius=p["exclusion"], **_sequence_kwargs(p))
    assert np.array_equal([g.place for g in got], batch.match)
    assert np.array_equal([g.window_length for g in got], batch.window_length)
    assert np.isnan(got[0].new_place_probability)


def test_uint8_live_map_equals_the_batch_matcher_on_its_own_differences(world):
    from catgraph.differences import difference_matrix
    from catgraph.methods import _sequence_kwargs
    from catgraph.sequence import match_sequences

    live_map = LiveMap(world.reference, layout="uint8")
    assert live_map.reference.layout == "uint8" and "uint8" in repr(live_map)
    live = LiveLocalizer(live_map, model="matcher", l_max=60)
    got = [live.step(f) for f in world.query.frames[:60]]
    q, _ = describe(world.query)
    d = difference_matrix(q[:60], live_map.reference, live_map.metric, normalise=True)
    # the codes' differences are those of the float map to within the stated bound
    raw = difference_matrix(q[:5], live_map.reference, live_map.metric)
    float_map, _ = describe(world.reference)
    exact = np.abs(q[:5, None, :].astype(float) - float_map[None].astype(float)).sum(-1)
    for i in range(5):
        assert np.abs(raw[i] - exact[i]).max() <= live_map.reference.quantisation_bound(q[i]) + 1e-9
    p = live.params_
    batch = match_sequences(d, radius=p["exclusion"], **_sequence_kwargs(p))
    assert np.array_equal([g.place for g in got], batch.match)
    # the bootstrapped combined filter runs on the compact map and its bootstrap
    live = LiveLocalizer(live_map, model="histogram-combined", seed=0)
    assert 0 <= live.step(world.query.frames[0]).place < live_map.n_places


def test_compact_live_map_holds_no_float_copy_and_its_statistics_read_the_codes(world):
    import gc
    import weakref

    from catgraph.hubs import map_hub_offsets
    from catgraph.io import build_map
    from catgraph.live import reference_bootstrap_samples, reference_hub_offsets

    source = build_map(world.reference)
    floats = weakref.ref(source.descriptors)
    compact = LiveMap(source, layout="uint8")
    assert compact.map is None
    held = [v for v in vars(compact).values() if isinstance(v, np.ndarray) and v is not compact.positions]
    held += [v for v in vars(compact.reference).values() if isinstance(v, np.ndarray)]
    assert [a.dtype for a in held if a.ndim == 2] == [np.uint8]
    assert sum(a.nbytes for a in held) <= compact.n_places * compact.reference.dim
    del source
    gc.collect()
    assert floats() is None  # the caller dropped the map: nothing of the float descriptors is left
    # bootstrap and hub statistics come from the codes: equal to the slow reference on the codes
    from catgraph.differences import normalise_rows

    codes = compact.reference.descriptors.astype(np.int64)
    full = normalise_rows(np.abs(codes[:, None, :] - codes[None]).sum(-1) * compact.reference.step)
    from catgraph.observation import HistogramObservation

    z = np.linspace(-4, 4, 41)
    want = HistogramObservation.bootstrap(full, gap=12, max_different=4000, seed=5).likelihood
    assert np.array_equal(compact.bootstrap(gap=12, max_different=4000, seed=5).log_likelihood_ratio(z),
                          want.log_likelihood_ratio(z))
    from catgraph.hubs import hub_offsets

    assert np.array_equal(compact.hub_offsets(), hub_offsets(full))
    # the float32 layout: the map's own descriptors (no copy) and the batch hub offsets, bit for bit
    source = build_map(world.reference)
    plain = LiveMap(source)
    assert plain.map is source and np.shares_memory(plain.reference.descriptors, source.descriptors)
    assert np.array_equal(plain.hub_offsets(), map_hub_offsets(source))
    assert np.array_equal(reference_hub_offsets(plain.reference, max_rows=40), map_hub_offsets(source, max_rows=40))
    values, hub = reference_bootstrap_samples(plain.reference, True, 12, 500, 5)
    assert values.shape == (500,) and hub.shape == (plain.n_places,)


def test_live_map_from_saved_map_and_bad_inputs(world, tmp_path):
    from catgraph.io import build_map, load_map, save_map

    path = save_map(tmp_path / "m.npz", build_map(world.reference))
    live_map = LiveMap(load_map(path))
    assert live_map.kind == "images" and live_map.n_places == len(world.reference)
    with pytest.raises(InvalidParameterError, match="front-end"):
        LiveMap(load_map(path), frontend=FrontEnd())
    with pytest.raises(DataError, match="no place graph.*give LiveMap the reference traverse"):
        LiveMap(build_map(world.reference, graph=False))
    with pytest.raises(InvalidParameterError, match="LiveMap"):
        LiveMap(np.zeros((3, 3)))
    with pytest.raises(InvalidParameterError, match="model"):
        LiveLocalizer(live_map, model="kalman")
    live = LiveLocalizer(live_map, model="histogram")
    with pytest.raises(DataError):
        live.step(np.zeros((3, 3, 3, 3)))
    with pytest.raises(Exception, match="live images are 4×4"):
        live.step(np.zeros((4, 4)))


@pytest.mark.parametrize("model, layout", [("combined", "float32"), ("combined", "uint8"), ("histogram", "uint8"),
                                           ("matcher", "float32")])
def test_a_live_localizer_pickled_mid_run_goes_on_alike(world, model, layout):
    """A navigation stack can checkpoint the live state (map, learned models, filter, matcher
    ring) and resume it: the copy answers every later frame as the original does."""
    import pickle

    seed = {} if model == "matcher" else {"seed": 3}  # the matcher alone draws nothing
    live = LiveLocalizer(LiveMap(world.reference, layout=layout), model=model, **seed)
    frames = world.query.frames
    for k in range(50):
        live.step(frames[k])
    twin = pickle.loads(pickle.dumps(live))
    for k in range(50, 90):
        a, b = live.step(frames[k]), twin.step(frames[k])
        assert (a.place, a.window_length, a.velocity) == (b.place, b.window_length, b.velocity)
        # P(new place) is NaN for the matcher alone (documented): compared as equal there
        assert np.array_equal([a.score, a.confidence, a.new_place_probability],
                              [b.score, b.confidence, b.new_place_probability], equal_nan=True)


def _to_uint8(frames):
    lo, hi = np.percentile(frames, [1, 99])
    return np.clip((frames - lo) / (hi - lo) * 255, 0, 255).astype(np.uint8)


def test_example_matches_the_localize_command(world, tmp_path, capsys, monkeypatch):
    from catgraph.cli.main import main as cli

    from .conftest import write_images

    ref = write_images(tmp_path / "ref", _to_uint8(world.reference.frames))
    qry = write_images(tmp_path / "qry", _to_uint8(world.query.frames[:60]))
    map_path = tmp_path / "ref.npz"
    assert cli(["build-map", str(ref), "--out", str(map_path), "--quiet"]) == 0
    out_live = tmp_path / "live.json"
    monkeypatch.setattr(sys, "argv", ["live.py", str(map_path), str(qry), "--model", "combined", "--mode",
                                      "particles", "--particles", "200", "--output", str(out_live)])
    with pytest.raises(SystemExit) as stop:
        runpy.run_path(str(EXAMPLE), run_name="__main__")
    assert stop.value.code == 0
    assert "per-frame ms: median" in capsys.readouterr().out
    out_batch = tmp_path / "batch.json"
    assert cli(["localize", "--map", str(map_path), str(qry), "--model", "combined", "--mode", "particles",
                "--particles", "200", "-o", str(out_batch), "--quiet"]) == 0
    live_frames = json.loads(out_live.read_text())["frames"]
    batch_frames = json.loads(out_batch.read_text())["frames"]
    assert live_frames["match"] == batch_frames["match"]
    assert live_frames["confidence"] == batch_frames["confidence"]
    assert live_frames["p_new_place"] == batch_frames["p_new_place"]
    # the compact map runs from the example too
    monkeypatch.setattr(sys, "argv", ["live.py", str(map_path), str(qry), "--model", "adaptive", "--layout", "uint8"])
    with pytest.raises(SystemExit) as stop:
        runpy.run_path(str(EXAMPLE), run_name="__main__")
    assert stop.value.code == 0 and "per-frame ms: median" in capsys.readouterr().out
    # the grid filter from the example: only the options given reach the filter (a seed it has no use for was
    # always passed, and --mode grid was refused)
    monkeypatch.setattr(sys, "argv", ["live.py", str(map_path), str(qry), "--model", "tempered", "--mode", "grid"])
    with pytest.raises(SystemExit) as stop:
        runpy.run_path(str(EXAMPLE), run_name="__main__")
    assert stop.value.code == 0 and "per-frame ms: median" in capsys.readouterr().out


def test_example_refuses_a_users_mistakes_in_one_line(world, tmp_path, capsys, monkeypatch):
    from catgraph.io import build_map, save_map

    map_path = save_map(tmp_path / "ref.npz", build_map(world.reference))
    before = map_path.read_bytes()
    for argv, message in ([[str(tmp_path / "nowhere"), "synthetic:0"], "does not exist"],
                          [[str(tmp_path / "nowhere.npz"), "synthetic:0"], "map"],
                          [[str(map_path), "synthetic:0", "--model", "matcher", "--particles", "10"],
                           "--particles does not apply to --model matcher"],
                          [[str(map_path), "synthetic:0"], "the map holds images but the query holds descriptors"],
                          [[str(map_path), "synthetic:0", "--output", str(map_path)], "would overwrite the input"],
                          [[str(map_path), "synthetic:0", "--every", "-1"], "--every must be ≥ 0"]):
        monkeypatch.setattr(sys, "argv", ["live.py", *argv])
        with pytest.raises(SystemExit) as stop:
            runpy.run_path(str(EXAMPLE), run_name="__main__")
        err = capsys.readouterr().err.strip().splitlines()
        assert stop.value.code == 1 and len(err) == 1 and err[0].startswith("live.py: error: ") and message in err[0]
    assert map_path.read_bytes() == before


def test_warm_up_steps_every_requested_path():
    from catgraph.live import warm_up

    seconds = warm_up(models=("matcher", "histogram"), layouts=("float32", "uint8"), steps=2, places=(600,))
    assert set(seconds) == {"matcher/float32", "histogram/float32", "matcher/uint8", "histogram/uint8"}
    assert all(v >= 0 for v in seconds.values())
    with pytest.raises(InvalidParameterError, match="unknown live models"):
        warm_up(models=("kalman",))
    with pytest.raises(InvalidParameterError, match="places"):
        warm_up(places=(100,))
    with pytest.raises(InvalidParameterError, match="steps"):
        warm_up(steps=0)


def test_warm_up_steps_a_map_in_every_size_regime_of_the_filter():
    """The filter's defaults change with the map's size (the jump grid, the rigid line,
    the dense velocities, the particle filter above the grid's limit), and each regime
    runs kernels of its own: the warm-up maps give every configuration that any map size
    gives, so that no map compiles in its first frames."""
    import json

    from catgraph.live import WARM_UP_PLACES
    from catgraph.methods import concrete_params, resolve_params

    params = resolve_params("filter", {})

    def regime(n):
        return json.dumps(concrete_params(params, n), sort_keys=True, default=str)

    sizes = {int(v) for v in np.geomspace(200, 10**7, 200)} | {n + d for n in WARM_UP_PLACES for d in (-1, 0, 1)}
    assert {regime(n) for n in sizes} == {regime(n) for n in WARM_UP_PLACES}


def test_batch_warm_up_plan_is_valid_for_the_registry_and_runs_both_inputs():
    from catgraph.live import BATCH_PLAN, warm_up_batch
    from catgraph.methods import FILTER_MODELS, METHODS, resolve_params

    assert {m for m, _ in BATCH_PLAN} == set(METHODS)
    filters = [p for m, p in BATCH_PLAN if m == "filter"]
    assert {p["model"] for p in filters} == set(FILTER_MODELS)
    assert {p.get("mode", "auto") for p in filters} == {"auto", "particles"}
    # both particle motions: the velocity state (the registry's) and the frame motion (the demo's figure)
    assert {p.get("motion", "velocity") for p in filters if p.get("mode") == "particles"} == {"velocity", "frame"}
    for method, params in BATCH_PLAN:
        resolve_params(method, params)  # a renamed or refused parameter fails here, not at install time
    seconds = warm_up_batch(plan=(("single-frame", {}), ("sequence", {"window": 10})))
    assert sorted(seconds) == ["sequence/window=10/chain", "sequence/window=10/graph",
                               "single-frame//chain", "single-frame//graph"]
    assert all(v >= 0 for v in seconds.values())


def test_release_free_memory_runs_and_keeps_every_array(world):
    import sys

    from catgraph.live import release_free_memory

    live = LiveLocalizer(LiveMap(world.reference, layout="uint8"), model="adaptive", seed=1)
    before = live.live_map.reference.descriptors.copy()
    done = release_free_memory()
    assert done == sys.platform.startswith("linux") or done is False
    assert np.array_equal(live.live_map.reference.descriptors, before)
    assert 0 <= live.step(world.query.frames[0]).place < live.live_map.n_places


def _patch_normalise_loop(images, patch):
    """Patch normalisation one patch at a time (the obviously correct reference)."""
    x = np.asarray(images, dtype=np.float64)
    out = np.empty_like(x)
    for r in range(0, x.shape[1], patch):
        for c in range(0, x.shape[2], patch):
            block = x[:, r : r + patch, c : c + patch]
            mean = block.mean(axis=(1, 2), keepdims=True)
            std = block.std(axis=(1, 2), keepdims=True)
            safe = np.where(std > 1e-12 * np.maximum(1.0, np.abs(mean)), std, np.inf)
            out[:, r : r + patch, c : c + patch] = (block - mean) / safe
    return out.astype(np.float32)


def test_patch_normalise_equals_the_patch_by_patch_loop(rng, monkeypatch):
    """All whole patches at once (a strided view, a few images at a time), the edge
    patches one by one: the floats of the loop over patches, bit for bit — flat patches,
    uneven edges, one frame and several, values from 1e-5 to 1e5."""
    from catgraph import frontends
    from catgraph.frontends import patch_normalise

    monkeypatch.setattr(frontends, "_PATCH_IMAGES", 2)  # several groups of images

    for t in range(300):
        n, h, w = int(rng.integers(1, 6)), int(rng.integers(1, 24)), int(rng.integers(1, 40))
        patch = int(rng.integers(1, max(h, w) + 1))
        x = rng.standard_normal((n, h, w)) * 10.0 ** rng.uniform(-5, 5)
        if t % 3 == 0:
            x = rng.integers(0, 3, (n, h, w)).astype(np.uint8)  # many flat patches
        got, want = patch_normalise(x, patch), _patch_normalise_loop(x, patch)
        assert got.dtype == np.float32 and np.array_equal(got.view(np.uint32), want.view(np.uint32)), (n, h, w, patch)


@pytest.mark.parametrize("model, layout, params", [
    ("combined", "float32", {}), ("combined", "uint8", {}), ("tempered", "float32", {"mode": "particles"}),
    ("histogram", "uint8", {}), ("histogram-bootstrap", "float32", {}), ("adaptive", "float32", {}),
    ("histogram-combined", "float32", {}), ("sequence", "uint8", {}), ("matcher", "uint8", {})])
def test_a_frame_described_as_the_previous_one_reuses_its_row_with_the_same_answers(world, model, layout, params):
    """A sensor that sends the same scan again (or a camera whose frame does not change) gives
    the previous frame's row without a pass over the map; every answer is the one a row
    computed anew gives, whichever model reads the row."""
    seed = {} if model == "matcher" else {"seed": 4}
    frames = world.query.frames
    # runs of repeats, a copy with the same values, and one buffer that a callback rewrites in place
    order = [0, 0, 1, 2, 2, 2, 3, 4, 4, 5, 6, 6, 7, 8, 9, 9, 10, 11, 11, 11, 12, 13]
    buffer = np.empty_like(frames[0])

    def frame(k, i):
        if i % 3 == 1:
            np.copyto(buffer, frames[k])
            return buffer
        return frames[k].copy()

    reused = LiveLocalizer(LiveMap(world.reference, layout=layout), model=model, **seed, **params)
    fresh = LiveLocalizer(LiveMap(world.reference, layout=layout), model=model, **seed, **params)
    passes = []
    row_into = reused.live_map._row_into
    reused.live_map._row_into = lambda d, out: (passes.append(1), row_into(d, out))[1]
    for i, k in enumerate(order):
        fresh._last_descriptor = None  # every row computed anew
        a, b = reused.step(frame(k, i)), fresh.step(frames[k])
        assert (a.place, a.window_length, a.velocity) == (b.place, b.window_length, b.velocity)
        assert np.array_equal([a.score, a.confidence, a.new_place_probability],
                              [b.score, b.confidence, b.new_place_probability], equal_nan=True)
    assert len(passes) == len(set(order))  # one pass over the map per distinct frame
    # a changed frame after its repeats gets its own row
    changed = frames[20].copy()
    changed.flat[0] += 1.0
    np.testing.assert_array_equal(reused.step(changed).place, fresh.step(changed).place)
    assert len(passes) == len(set(order)) + 1
