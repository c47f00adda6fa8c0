"""The experiment layer: one path from inputs to results, for every entry point."""

import json

import numpy as np
import pytest

from catgraph.cli.main import main
from catgraph.compare import compare_plan
from catgraph.conditions import Condition
from catgraph.datasets import load_traverse
from catgraph.exceptions import ConfigError, DataError, InvalidParameterError
from catgraph.experiment import Experiment, payload, prepare, run, run_method
from catgraph.io import build_map, save_map
from catgraph.metrics import evaluate
from catgraph.traverse import FrameTolerance

from .conftest import write_images


@pytest.fixture
def image_pair(tmp_path):
    rng = np.random.default_rng(3)
    base = rng.integers(0, 255, (60, 8, 16))
    noisy = np.clip(base + rng.normal(0, 25, base.shape), 0, 255)
    return write_images(tmp_path / "ref", base), write_images(tmp_path / "qry", noisy)


def _method_output(p: dict) -> dict:
    """What the method produced: every per-frame field except the evaluation's."""
    return {k: v for k, v in p["frames"].items() if k not in ("correct", "has_true_match")}


def _plan():
    plan = []
    for method, params in compare_plan(window=5):
        if method == "filter":  # mode auto: the grid filter on this map
            params = dict(params)
            if params["model"] in ("adaptive", "combined", "histogram-combined"):
                params["l_max"] = 20
            if params["model"] in ("histogram-bootstrap", "histogram-combined"):
                params["max_different"] = 2000
        elif method == "sequence" and params["window"] == "adaptive":
            params = {**params, "l_max": 20}
        plan.append((method, params))
    plan.append(("histogram", {"learning": "bootstrap", "max_different": 2000}))
    plan.append(("filter", {"model": "tempered", "mode": "grid"}))
    plan.append(("filter", {"model": "combined", "mode": "particles", "n_particles": 200, "l_max": 20}))
    return plan


# the online histogram model's default initialisation outlasts this 60-frame query; the warning says so
@pytest.mark.filterwarnings(r"ignore:n_init \(T_init\) = 100 frames is not shorter than the query")
def test_saved_map_and_folder_agree_for_every_method(image_pair, tmp_path):
    ref, qry = image_pair
    path = save_map(tmp_path / "m.npz", build_map(load_traverse(ref)))
    from_folder = prepare(Experiment(query=qry, reference=ref, tolerance=1))
    from_map = prepare(Experiment(query=qry, map=path, tolerance=1))
    np.testing.assert_array_equal(from_folder.differences, from_map.differences)
    np.testing.assert_array_equal(from_folder.bootstrap_samples(5, 500, 0), from_map.bootstrap_samples(5, 500, 0))
    for method, params in _plan():
        a = run_method(method, params, from_folder)
        b = run_method(method, params, from_map)
        assert a.method == b.method
        np.testing.assert_array_equal(a.match, b.match, err_msg=f"{method} {params}")
        np.testing.assert_array_equal(a.confidence, b.confidence, err_msg=f"{method} {params}")
        for key in a.extra:
            np.testing.assert_array_equal(a.extra[key], b.extra[key], err_msg=f"{method} {params} {key}")


def test_evaluation_tolerance_never_reaches_the_method(image_pair, tmp_path):
    ref, qry = image_pair
    outputs = []
    for tolerance in ("0", "5"):
        out = tmp_path / f"t{tolerance}.json"
        assert main(["localize", str(ref), str(qry), "--model", "histogram", "--init-frames",
                     "10", "--tolerance", tolerance, "-o", str(out), "-q"]) == 0
        p = json.loads(out.read_text())
        outputs.append((json.dumps(_method_output(p), sort_keys=True),
                        {k: v for k, v in p["params"].items() if k != "ground_truth"}))
    assert outputs[0] == outputs[1]  # byte-identical answers and method parameters


def test_runs_without_ground_truth(image_pair, tmp_path, capsys):
    ref, qry = image_pair
    out = tmp_path / "x.json"
    assert main(["localize", str(ref), str(qry), "--model", "histogram", "-o", str(out)]) == 0
    p = json.loads(out.read_text())
    assert p["metrics"] is None and p["params"]["ground_truth"] is None
    assert len(p["frames"]["match"]) == 60 and "correct" not in p["frames"]
    assert all(0 <= v <= 1 for v in p["frames"]["p_new_place"])
    assert "no ground truth" in capsys.readouterr().out
    assert main(["report", str(out), "--out", str(tmp_path / "rep"), "-q"]) == 0


def test_ground_truth_file_gives_the_same_metrics_as_the_tolerance(image_pair, tmp_path):
    ref, qry = image_pair
    pairs = [(q, r) for q in range(60) for r in range(max(0, q - 2), min(60, q + 3))]
    (tmp_path / "pairs.csv").write_text("query,reference\n" + "".join(f"{q},{r}\n" for q, r in pairs))
    m = np.zeros((60, 60), bool)
    for q, r in pairs:
        m[q, r] = True
    np.save(tmp_path / "gt.npy", m)
    results = []
    for gt in (["--tolerance", "2"], ["--ground-truth", str(tmp_path / "pairs.csv")],
               ["--ground-truth", str(tmp_path / "gt.npy")]):
        out = tmp_path / "r.json"
        assert main(["match", str(ref), str(qry), "--window", "5", "-o", str(out), "-q"] + gt) == 0
        results.append(json.loads(out.read_text())["metrics"])
    assert results[0] == results[1] == results[2]


@pytest.mark.parametrize("condition", [["--reverse"], ["--speed", "2"], ["--speed", "0.5"],
                                       ["--shuffle", "1", "--segment-range", "0.005:0.03"],
                                       ["--vary", "2", "--speed-range", "0.5:3"],
                                       ["--stop", "3", "--stop-frames", "2:6", "--segment-range", "0.1:0.3"]])
def test_conditions_score_against_the_moved_ground_truth(condition, image_pair, tmp_path):
    ref, qry = image_pair
    out = tmp_path / "c.json"
    assert main(["match", str(ref), str(qry), "--window", "5", "--tolerance", "2", "-o", str(out), "-q"]
                + condition) == 0
    p = json.loads(out.read_text())
    f = p["frames"]
    expected = {"--reverse": "reverse", "--speed": f"speed:{condition[-1]}", "--shuffle": "shuffle:1:0.005:0.03",
                "--vary": "vary:2:0.5:3", "--stop": None}[condition[0]]
    expected = Condition.parse(expected) if expected else Condition("stop", seed=3, stop_frames=(2, 6),
                                                                     segment_range=(0.1, 0.3))
    order = expected.order(60)
    assert (np.diff(order) == 0).any() if condition[0] == "--stop" else True  # the query does stop
    assert f["query_index"] == order.tolist()
    match = np.array([-1 if v is None else v for v in f["match"]])
    ev = evaluate(np.array(f["query_index"]), match, np.array([0.0 if c is None else c for c in f["confidence"]]),
                  FrameTolerance(60, 2))
    assert [bool(c) for c in ev.correct] == f["correct"]
    assert p["metrics"]["auc"] == pytest.approx(ev.metrics.auc)
    assert p["params"]["condition"]["kind"] in ("reverse", "speed", "shuffle", "vary", "stop")


def test_filter_options_reach_the_filter_from_the_cli_and_a_sweep(tmp_path):
    runs = {}
    for window in ("3", "15"):
        out = tmp_path / f"w{window}.json"
        assert main(["localize", "synthetic:2", "synthetic:2", "--model", "histogram-combined", "--window", window,
                     "--max-different", "2000", "-o", str(out), "-q"]) == 0
        runs[window] = json.loads(out.read_text())
        assert runs[window]["params"]["window"] == int(window)
    assert runs["3"]["frames"]["match"] != runs["15"]["frames"]["match"]
    from catgraph.config import parse_config
    from catgraph.experiment import run_experiment

    config = parse_config({"dataset": [{"name": "c", "reference": "synthetic:2", "query": "synthetic:2"}],
                           "method": [{"method": "filter", "params": {"model": "histogram-combined", "max_different": 2000},
                                       "grid": {"window": [3, 15]}}]})
    swept = [run_experiment(spec) for spec in config.specs]
    assert [s["params"]["window"] for s in swept] == [3, 15]
    assert [s["frames"]["match"] for s in swept] == [runs["3"]["frames"]["match"], runs["15"]["frames"]["match"]]


@pytest.mark.parametrize("args, needle", [
    (["localize", "REF", "QRY", "--model", "adaptive", "--window", "20"], "--window does not apply"),
    (["localize", "REF", "QRY", "--model", "histogram", "--rule", "literal"], "--rule does not apply"),
    (["match", "REF", "QRY", "--window", "5", "--rule", "literal"], "--rule does not apply"),
    (["match", "REF", "QRY", "--learning", "online"], "--learning does not apply to single-frame matching"),
    (["match", "QRY", "--map", "MAP", "--size", "8x4"], "--size does not apply to a saved map"),
    (["match", "QRY", "--map", "MAP", "--patch", "2", "--metric", "ssd"], "--patch, --metric do not apply"),
    (["localize", "QRY", "--map", "MAP", "--junction-radius-m", "3"], "--junction-radius-m does not apply"),
    (["localize", "REF", "QRY", "--junction-radius-m", "3"], "the reference has no positions"),
    (["match", "REF", "QRY", "--segment-range", "0.1:0.2"], "add --shuffle SEED, --vary SEED or --stop SEED"),
    (["match", "REF", "QRY", "--stop-frames", "1:2"], "add --stop SEED"),
    (["match", "REF", "QRY", "--speed-range", "1:2"], "add --vary SEED"),
    (["match", "REF", "QRY", "--speed", "0"], "speed factor must be in [0.01, 100]"),
    (["match", "REF", "QRY", "--shuffle", "1", "--segment-range", "0.3:0.1"], "0 < MIN ≤ MAX ≤ 1"),
    (["match", "REF", "QRY", "--reverse", "--speed", "2"], "not allowed with argument"),
    (["match", "REF", "QRY", "--ground-truth", "NOPE.csv"], "does not exist"),
    (["localize", "REF", "QRY", "--particles", "0"], "--particles must be an int in [1, 1e+07]"),
    (["match", "REF", "QRY", "--window", "ten"], "expected a number of frames or 'adaptive'"),
    (["match", "REF", "QRY", "--bogus"], "unrecognized arguments: --bogus"),
])
def test_options_that_do_not_apply_are_errors(args, needle, image_pair, tmp_path, capsys):
    ref, qry = image_pair
    save_map(tmp_path / "m.npz", build_map(load_traverse(ref)))
    paths = {"REF": str(ref), "QRY": str(qry), "MAP": str(tmp_path / "m.npz"), "NOPE.csv": str(tmp_path / "no.csv")}
    assert main([paths.get(a, a) for a in args] + ["-q"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("catgraph: error:") and needle in err and "\n" not in err, err


def test_ground_truth_files_are_checked(tmp_path):
    from catgraph.datasets.ground_truth import load_ground_truth

    (tmp_path / "a.csv").write_text("0,1\n1,x\n")
    (tmp_path / "b.csv").write_text("0,1,2\n")
    (tmp_path / "c.csv").write_text("0,9\n")
    np.save(tmp_path / "d.npy", np.ones((3, 3)))
    np.save(tmp_path / "e.npy", np.array([[np.nan, 1.0]]))
    for name, needle in (("a.csv", "row 2"), ("b.csv", "one 'query,reference' pair"), ("c.csv", "outside"),
                         ("d.npy", "must be (n_query, n_reference) = (2, 4)"), ("e.npy", "must be")):
        with pytest.raises(DataError, match=needle.replace("(", r"\(").replace(")", r"\)")):
            load_ground_truth(tmp_path / name, 2, 4)
    np.savez(tmp_path / "f.npz", ground_truth=np.eye(2, 4), other=np.zeros(1))
    gt = load_ground_truth(tmp_path / "f.npz", 2, 4)
    assert gt.correct(np.array([0, 1]), np.array([0, 0])).tolist() == [True, False]


def test_experiment_spec_round_trip_and_checks():
    exp = Experiment(query="synthetic:1", reference="synthetic:1", method="sequence", params={"window": 4},
                     condition="reverse")
    again = Experiment.from_spec(exp.spec())
    assert again.spec() == exp.spec()
    a, b = run(exp)[1], run(again)[1]
    assert a["frames"] == b["frames"]
    with pytest.raises(ConfigError, match="unknown run keys"):
        Experiment.from_spec({"query": "x", "reference": "y", "shuffle": 0})
    with pytest.raises(InvalidParameterError, match="exactly one"):
        Experiment(query="synthetic:1")
    with pytest.raises(InvalidParameterError, match="unknown method 'sequense'; did you mean 'sequence'"):
        Experiment(query="synthetic:1", reference="synthetic:1", method="sequense")


def test_prepared_inputs_serve_every_condition():
    # prepare() describes the reordered query; under() reorders the rows: the same, bit for bit
    prepared = prepare(Experiment(query="synthetic:1", reference="synthetic:1"))
    for condition in (Condition("reverse"), Condition("speed", factor=2.0), Condition("speed", factor=0.5),
                      Condition("shuffle", seed=3, segment_range=(0.05, 0.2))):
        direct = prepare(Experiment(query="synthetic:1", reference="synthetic:1", condition=condition))
        under = prepared.under(condition)
        np.testing.assert_array_equal(direct.differences, under.differences)
        np.testing.assert_array_equal(direct.query.index, under.query.index)
        a, _ = payload(run_method("single-frame", {}, direct), direct)
        b, _ = payload(run_method("single-frame", {}, under), under)
        assert a["frames"] == b["frames"] and a["metrics"] == b["metrics"]


def test_every_filter_model_runs_on_the_grid_with_its_seed(image_pair):
    """Mode 'grid' drops the particle options but keeps the seed of the histogram
    models' samples: every model runs, and a histogram model's seed is honoured."""
    from catgraph.methods import FILTER_MODELS

    ref, qry = image_pair
    prepared = prepare(Experiment(query=qry, reference=ref, tolerance=1))
    for model in FILTER_MODELS:
        params = {"model": model, "mode": "grid"}
        if model in ("adaptive", "combined", "histogram-combined"):
            params["l_max"] = 20
        if model in ("histogram-bootstrap", "histogram-combined"):
            params["max_different"] = 2000
        result = run_method("filter", params, prepared)
        assert result.method == f"grid-filter/{model}"
        assert result.match.shape == (len(prepared.query),)
    seeded = run_method("filter", {"model": "histogram-bootstrap", "mode": "grid", "max_different": 2000,
                                   "seed": 3}, prepared)
    assert seeded.params["seed"] == 3


def test_auto_mode_refuses_the_options_of_the_filter_it_does_not_run(capsys):
    from catgraph.methods import GRID_MAX_PLACES, concrete_params, resolve_params

    # the synthetic world is small: mode auto runs the grid, which has no particles
    assert main(["localize", "synthetic:2", "synthetic:2", "--particles", "100", "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("catgraph: error: --particles does not apply here: mode 'auto' runs the exact grid filter")
    assert "choose mode 'particles', or leave --particles out" in err and "Traceback" not in err
    for key, value in (("resampler", "multinomial"), ("motion", "frame"), ("ess_threshold", 0.3),
                       ("redraw_fraction", 0.2), ("proposal", "uniform"), ("jump_graduation", 0.5)):
        given = {key: value, **({"redraw_fraction": 0.0} if key == "ess_threshold" else {})}  # (ESS: no redraws)
        with pytest.raises(InvalidParameterError, match="does not apply here: mode 'auto' runs the exact"):
            concrete_params(resolve_params("filter", given), 100)
        assert concrete_params(resolve_params("filter", given), GRID_MAX_PLACES + 1)[key] == value
    # above the grid's size auto runs particles, which have no grid
    for key, value in (("rigid_prior", 0.1), ("jump_velocity", "current"), ("home_speed_odds", 2.0),
                       ("outlier_probability", 0.1), ("velocity_bins", [-1.0, 1.0])):
        with pytest.raises(InvalidParameterError, match=f"'{key}' does not apply here: mode 'auto' runs the particle"):
            concrete_params(resolve_params("filter", {key: value}), GRID_MAX_PLACES + 1)
        assert concrete_params(resolve_params("filter", {key: value}), 100)[key] == value


def test_filter_runs_record_the_parameters_of_the_filter_that_ran(tmp_path):
    from catgraph.localizer import Localizer
    from catgraph.grid import DENSE_VELOCITIES
    from catgraph.methods import JUMP_VELOCITY, OUTLIER_PROBABILITY, RIGID_PRIOR, home_speed_odds, particle_defaults

    out = tmp_path / "grid.json"
    assert main(["localize", "synthetic:2", "synthetic:2", "-o", str(out), "-q"]) == 0
    params = json.loads(out.read_text())["params"]
    assert params["mode"] == "grid"
    assert not {"n_particles", "resampler", "motion", "proposal", "jump_graduation"} & set(params)
    assert (params["jump_velocity"], params["rigid_prior"], params["home_speed_odds"],
            params["outlier_probability"]) == (JUMP_VELOCITY, RIGID_PRIOR, 34.0, OUTLIER_PROBABILITY)
    assert params["velocity_bins"] == list(DENSE_VELOCITIES) and home_speed_odds(DENSE_VELOCITIES) == 34.0
    out = tmp_path / "particles.json"
    assert main(["compare", "synthetic:2", "synthetic:2", "--mode", "particles", "--particles", "50", "-o", str(out),
                 "-q"]) == 0
    runs = [r for r in json.loads(out.read_text())["runs"] if r["method"].startswith("particle-filter/")]
    assert len(runs) == 7
    own = particle_defaults(Localizer)
    assert own["n_particles"] == 2000 and own["resampler"] == "systematic"
    for run in runs:
        p = run["params"]
        assert p["mode"] == "particles" and p["n_particles"] == 50 and p["motion"] == "velocity"
        assert {k: p[k] for k in own if k != "n_particles"} == {k: v for k, v in own.items() if k != "n_particles"}
        assert not {"jump_velocity", "rigid_prior", "home_speed_odds", "outlier_probability", "velocity_bins"} & set(p)


def test_compare_checks_every_filters_options_before_its_first_run(monkeypatch, capsys):
    import catgraph.experiment as experiment

    ran = []
    monkeypatch.setattr(experiment, "run_method", lambda *a, **k: ran.append(a[0]))
    assert main(["compare", "synthetic:2", "synthetic:2", "--particles", "100", "-q"]) == 1
    assert ran == [] and "--particles does not apply here" in capsys.readouterr().err


def test_a_condition_is_not_stacked_on_a_query_already_driven_under_one():
    from catgraph.datasets.synthetic import make_world

    world = make_world(seed=1, blocks=(2, 2))
    driven = Condition.parse("reverse").apply(world.query)
    with pytest.raises(InvalidParameterError, match="already driven under"):
        prepare(Experiment(query=driven, reference=world.reference, condition="speed:2"))
    assert len(prepare(Experiment(query=driven, reference=world.reference)).query) == len(world.query)


def test_use_odometry_given_where_there_is_none_is_refused_and_runs_record_whether_it_drove(tmp_path, capsys):
    rng = np.random.default_rng(0)
    ref, qry = tmp_path / "r.npy", tmp_path / "q.npy"
    np.save(ref, np.cumsum(rng.normal(size=(100, 8)), axis=0).astype(np.float32))
    np.save(qry, np.cumsum(rng.normal(size=(40, 8)), axis=0).astype(np.float32))
    assert main(["localize", str(ref), str(qry), "--use-odometry", "-q"]) == 1  # no odometry: it was ignored
    assert "--use-odometry does not apply here: the query has no odometry" in capsys.readouterr().err
    recorded = {}
    for name, argv in (("descriptors", [str(ref), str(qry)]), ("synthetic", ["synthetic:2", "synthetic:2"]),
                       ("synthetic, off", ["synthetic:2", "synthetic:2", "--no-use-odometry"])):
        out = tmp_path / "out.json"
        assert main(["localize", *argv, "-o", str(out), "-q"]) == 0
        recorded[name] = json.loads(out.read_text())["params"]["use_odometry"]
    assert recorded == {"descriptors": False, "synthetic": True, "synthetic, off": False}


def test_live_use_odometry_needs_a_metric_map():
    from catgraph.io import build_map
    from catgraph.live import LiveLocalizer, LiveMap
    from catgraph.traverse import Traverse

    frames = np.cumsum(np.random.default_rng(1).normal(size=(60, 8)), axis=0).astype(np.float32)
    live_map = LiveMap(build_map(Traverse(frames)))  # no positions, no odometry: a graph in frames
    with pytest.raises(InvalidParameterError, match="use_odometry' does not apply here: the map's place graph is in"):
        LiveLocalizer(live_map, model="tempered", use_odometry=True)
    assert LiveLocalizer(live_map, model="tempered").use_odometry is False


def test_jump_graduation_applies_only_where_the_jump_grid_runs():
    """The jump grid rides on the velocity-marginalised particles; where odometry drives
    them (the synthetic world) a jump_graduation given was recorded and ignored, and the
    default was recorded as 0.2 though no grid ran."""
    prepared = prepare(Experiment(query="synthetic:0", reference="synthetic:0"))
    with pytest.raises(InvalidParameterError, match="'jump_graduation' does not apply here.*odometry"):
        run_method("filter", {"mode": "particles", "n_particles": 100, "jump_graduation": 0.5}, prepared)
    ran = run_method("filter", {"mode": "particles", "n_particles": 100}, prepared)
    assert ran.params["use_odometry"] is True and ran.params["jump_graduation"] == 1.0
    import inspect

    from catgraph.localizer import Localizer

    # the defaults it ran with are recorded (new_place_prior was saved as null)
    assert ran.params["new_place_prior"] == inspect.signature(Localizer).parameters["new_place_prior"].default
    frames = run_method("filter", {"mode": "particles", "n_particles": 100, "use_odometry": False,
                                   "jump_graduation": 0.5}, prepared)
    assert frames.params["jump_graduation"] == 0.5


def test_the_synthetic_worlds_tolerance_scores_only_against_its_own_reference():
    """Implicitly, the query's world scored a run against another world's reference (AUC 0)
    and failed a reference without positions with a ground-truth error."""
    from dataclasses import replace

    from catgraph.experiment import load_input

    assert run(Experiment(query="synthetic:1", reference="synthetic:1"))[2] is not None
    assert run(Experiment(query="synthetic:0", reference="synthetic:1"))[2] is None
    no_positions = replace(load_input("synthetic:1", "reference"), positions=None, odometry=None)
    assert run(Experiment(query="synthetic:1", reference=no_positions))[2] is None
    # given explicitly, a tolerance scores any pair
    assert run(Experiment(query="synthetic:0", reference="synthetic:1", tolerance_m=5.0))[2] is not None


def test_a_frame_missing_from_one_folder_is_reported_where_the_tolerance_pairs_by_index():
    """Query frame i is scored against reference frame i: where both name their frames
    and a query frame carries another reference frame's name (a frame missing from one
    folder), the run warns instead of scoring every later frame against its neighbour."""
    import warnings

    from catgraph.exceptions import CatgraphWarning
    from catgraph.experiment import check_frame_pairing
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(0)
    frames = rng.random((30, 8)).astype(np.float32)
    names = 10 * np.arange(1, 31)  # file numbers, as the image-folder loader gives them (images-00010.png …)
    reference = Traverse(frames, ids=names)
    keep = np.r_[0:3, 4:30]  # the query folder lacks the fourth frame: loaded, it is 29 frames from 0
    missing = Traverse(frames[keep] + 0.01, ids=names[keep])
    with pytest.warns(CatgraphWarning, match=r"26 of 29 query frames .*query frame 3 is '50'; reference frame 3 is '40'"):
        run(Experiment(query=missing, reference=reference, method="single-frame", tolerance=0))
    # the same names in the same order, names of their own, or a query driven out of order: silent
    with warnings.catch_warnings():
        warnings.simplefilter("error", CatgraphWarning)
        run(Experiment(query=Traverse(frames + 0.01, ids=names), reference=reference, method="single-frame",
                       tolerance=0))
        assert check_frame_pairing(reference, Traverse(frames, ids=1000 + np.arange(30))) == 0
        assert check_frame_pairing(reference, Condition("shuffle", seed=1).apply(Traverse(frames, ids=names))) == 0
        assert check_frame_pairing(reference, Traverse(frames)) == 0
        # a longer query than the reference: its later frames have no pair, and no name either
        assert check_frame_pairing(Traverse(frames[:9], ids=names[:9]), Traverse(frames, ids=names)) == 0


def test_a_crop_reaches_the_map_the_saved_map_the_cli_and_the_live_frames(image_pair, tmp_path):
    """``crop`` (top, bottom, left, right pixels) is one front-end setting from the CLI,
    a config, a saved map and a live frame alike: the descriptors are the SeqSLAM pipeline's
    on the cropped images, a map saved with it answers as its folder does, and it is
    refused for frames that are not images and for a saved map (fixed when built)."""
    from catgraph.datasets import load_traverse
    from catgraph.frontends import seqslam_preprocess
    from catgraph.io import load_map, query_differences
    from catgraph.live import LiveMap
    from catgraph.pipeline import FrontEnd, describe
    from catgraph.traverse import Traverse

    ref, qry = image_pair
    crop = (1, 2, 3, 0)
    reference = load_traverse(ref)
    descriptors, metric = describe(reference, FrontEnd(crop=crop))
    np.testing.assert_array_equal(descriptors, seqslam_preprocess(reference.frames, crop=crop))
    assert descriptors.shape[1] == (8 - 3) * (16 - 3) and metric == "sad"
    cropped = prepare(Experiment(query=qry, reference=ref, tolerance=1, frontend={"crop": list(crop)}))
    whole = prepare(Experiment(query=qry, reference=ref, tolerance=1))
    assert not np.array_equal(cropped.differences, whole.differences)
    # the CLI: build-map --crop, then localize --map, against localize REFERENCE --crop
    path = tmp_path / "crop.npz"
    assert main(["build-map", str(ref), "--out", str(path), "--crop", "1,2,3,0", "-q"]) == 0
    assert load_map(path).frontend_settings().crop == crop
    np.testing.assert_array_equal(query_differences(load_map(path), load_traverse(qry)), cropped.differences)
    outputs = []
    for source in (["--map", str(path), str(qry)], [str(ref), str(qry), "--crop", "1,2,3,0"]):
        out = tmp_path / f"o{len(outputs)}.json"
        assert main(["localize", *source, "--tolerance", "1", "-o", str(out), "-q"]) == 0
        outputs.append(json.loads(out.read_text()))
    assert _method_output(outputs[0]) == _method_output(outputs[1])
    # live frames through the saved map's front-end: the batch's descriptors
    live = LiveMap(load_map(path))
    np.testing.assert_array_equal(live.describe(load_traverse(qry).frames[0]),
                                  seqslam_preprocess(load_traverse(qry).frames[:1], crop=crop)[0])
    # refused where it cannot apply, or as a malformed value
    assert main(["localize", "--map", str(path), str(qry), "--tolerance", "1", "--crop", "1,1,1,1", "-q"]) == 1
    with pytest.raises(InvalidParameterError, match="crop"):
        describe(Traverse(np.zeros((3, 5), dtype=np.float32)), FrontEnd(crop=crop))
    for bad in ((1, 1, 1), (1.5, 0, 0, 0), (-1, 0, 0, 0), "1,1,1,1", (True, 0, 0, 0)):
        with pytest.raises(InvalidParameterError, match="crop"):
            FrontEnd(crop=bad)
    assert FrontEnd.from_dict({"crop": "1,2,3,0"}).crop == crop
    assert main(["localize", str(ref), str(qry), "--tolerance", "1", "--crop", "1,2,3", "-q"]) == 1
    with pytest.raises(InvalidParameterError, match="crop"):
        seqslam_preprocess(reference.frames, crop=(1, 1, 1))


def test_numpy_numbers_are_tolerances_as_python_numbers_are(image_pair):
    ref, qry = image_pair
    a = run(Experiment(query=qry, reference=ref, method="single-frame", tolerance=np.int64(1)))[2].metrics
    b = run(Experiment(query=qry, reference=ref, method="single-frame", tolerance=1))[2].metrics
    assert a == b
    assert Experiment(query=qry, reference=ref, tolerance_m=np.float32(3.0)).tolerance_m == 3.0
    for bad in (np.bool_(True), np.float64(1.0), -1):
        with pytest.raises(InvalidParameterError, match="tolerance"):
            Experiment(query=qry, reference=ref, tolerance=bad)
