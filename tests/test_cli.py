import json

import numpy as np
import pytest

from catgraph.cli.main import main
from catgraph.metrics import evaluate
from catgraph.traverse import FrameTolerance, MetricTolerance
from catgraph.datasets import load_traverse

from .conftest import NORDLAND, UJI, needs_nordland, needs_uji, write_images


def recheck(payload, ground_truth):
    """Recompute the metrics from the frames section alone."""
    f = payload["frames"]
    match = np.array([-1 if m is None else m for m in f["match"]])
    conf = np.array([0.0 if c is None else c for c in f["confidence"]])
    ev = evaluate(np.array(f["query_index"]), match, conf, ground_truth)
    assert [bool(c) for c in ev.correct] == f["correct"]
    for key, value in ev.metrics.as_dict().items():
        assert payload["metrics"][key] == pytest.approx(value), key


@pytest.fixture
def image_pair(tmp_path):
    rng = np.random.default_rng(1)
    base = rng.integers(0, 255, (40, 8, 16))
    noisy = np.clip(base + rng.normal(0, 20, base.shape), 0, 255)
    return write_images(tmp_path / "ref", base), write_images(tmp_path / "qry", noisy)


def test_match_writes_json_that_rechecks(image_pair, tmp_path, capsys):
    ref, qry = image_pair
    out = tmp_path / "x.json"
    assert main(["match", str(ref), str(qry), "--window", "1", "--tolerance", "1", "--output", str(out), "-q"]) == 0
    payload = json.loads(out.read_text())
    assert set(payload) >= {"method", "params", "metrics", "frames"}
    assert set(payload["metrics"]) == {"auc", "recall_at_100p", "recall_at_99p", "recall_at_90p", "mtl", "accuracy",
                                       "n_queries"}
    assert payload["metrics"]["accuracy"] > 0.8
    recheck(payload, FrameTolerance(40, 1))
    out = capsys.readouterr().out  # --quiet: the table, no progress or messages
    assert out.startswith("method") and "single-frame" in out and "wrote" not in out


def test_match_shuffled_query_indices_refer_to_loaded_order(image_pair, tmp_path):
    ref, qry = image_pair
    out = tmp_path / "s.json"
    assert main(["match", str(ref), str(qry), "--tolerance", "0", "--shuffle", "0", "-o", str(out), "-q"]) == 0
    f = json.loads(out.read_text())["frames"]
    assert sorted(f["query_index"]) == list(range(40)) and f["query_index"] != list(range(40))
    recheck(json.loads(out.read_text()), FrameTolerance(40, 0))


@pytest.mark.parametrize("args, needle", [
    (["match", "MISSING", "MISSING", "--tolerance", "1"], "does not exist"),
    (["match", "EMPTY", "EMPTY", "--tolerance", "1"], "no PNG or JPG"),
    (["match", "REF", "QRY", "--tolerance-m", "2"], "positions"),
    (["match", "REF", "SMALL", "--tolerance", "1"], "the map's are 16×8"),
    (["match", "NPY", "NAN", "--tolerance", "1"], "NaN"),
    (["match", "REF", "CORRUPT", "--tolerance", "1"], "cannot read image"),
])
def test_user_mistakes_give_one_line_and_exit_1(args, needle, image_pair, tmp_path, capsys):
    ref, qry = image_pair
    (tmp_path / "empty").mkdir()
    small = write_images(tmp_path / "small", np.zeros((3, 4, 8)))
    corrupt = write_images(tmp_path / "corrupt", np.zeros((2, 8, 16)))
    (corrupt / "img-00030.png").write_bytes(b"broken")
    np.save(tmp_path / "d.npy", np.ones((3, 4)))
    np.save(tmp_path / "nan.npy", np.array([[1.0, np.nan, 1, 1]] * 3))
    paths = {"MISSING": str(tmp_path / "missing"), "EMPTY": str(tmp_path / "empty"), "REF": str(ref),
             "QRY": str(qry), "SMALL": str(small), "NPY": str(tmp_path / "d.npy"), "NAN": str(tmp_path / "nan.npy"),
             "CORRUPT": str(corrupt)}
    code = main([paths.get(a, a) for a in args] + ["-q"])
    err = capsys.readouterr().err.strip()
    assert code == 1
    assert err.startswith("catgraph: error:") and needle in err
    assert "\n" not in err and "Traceback" not in err


@needs_nordland
def test_nordland_match_end_to_end(tmp_path):
    out = tmp_path / "n.json"
    assert main(["match", str(NORDLAND / "summer"), str(NORDLAND / "winter"), "--window", "1", "--tolerance", "2",
                 "--output", str(out), "-q"]) == 0
    payload = json.loads(out.read_text())
    assert payload["metrics"]["n_queries"] == 3576
    recheck(payload, FrameTolerance(3576, 2))


@needs_uji
def test_wifi_match_end_to_end(tmp_path):
    out = tmp_path / "w.json"
    ref, qry = UJI / "01" / "trn01", UJI / "02" / "tst01"
    assert main(["match", str(ref), str(qry), "--tolerance-m", "3", "--output", str(out), "-q"]) == 0
    payload = json.loads(out.read_text())
    recheck(payload, MetricTolerance.between(load_traverse(qry), load_traverse(ref), 3.0))
    assert payload["metrics"]["accuracy"] > 0.3


@pytest.mark.parametrize("extra", [
    ["--window", "5"],
    ["--window", "adaptive", "--l-min", "2", "--l-max", "12"],
    ["--window", "adaptive", "--rule", "literal", "--approximation", "robust", "--l-min", "2", "--l-max", "12"],
    ["--model", "histogram", "--learning", "online", "--init-frames", "5"],
    ["--model", "histogram", "--learning", "bootstrap"],
    ["--model", "histogram", "--learning", "trained"],
])
def test_match_methods_write_rechecking_json(extra, image_pair, tmp_path):
    ref, qry = image_pair
    out = tmp_path / "m.json"
    assert main(["match", str(ref), str(qry), "--tolerance", "1", "--shuffle", "2", "-o", str(out), "-q"] + extra) == 0
    payload = json.loads(out.read_text())
    recheck(payload, FrameTolerance(40, 1))
    if "adaptive" in extra:
        lengths = payload["frames"]["window_length"]
        assert len(lengths) == 40 and all(1 <= v <= 12 for v in lengths)
    if "histogram" in extra:
        p_new = payload["frames"]["p_new_place"]
        assert all(0.0 <= v <= 1.0 for v in p_new)


def test_localize_and_compare_on_the_synthetic_world(tmp_path, capsys):
    out = tmp_path / "l.json"
    assert main(["localize", "synthetic:3", "synthetic:3", "--model", "histogram",
                 "-o", str(out), "-q"]) == 0
    payload = json.loads(out.read_text())
    from catgraph.experiment import synthetic_world

    world = synthetic_world(3)
    recheck(payload, world.ground_truth())
    p_new = np.array(payload["frames"]["p_new_place"])
    assert p_new.shape == (len(world.query),) and np.all((p_new >= 0) & (p_new <= 1))
    assert main(["compare", "synthetic:3", "synthetic:3", "-o", str(tmp_path / "c.json")]) == 0
    table = capsys.readouterr().out
    for name in ("single-frame", "adaptive", "grid-filter/histogram", "grid-filter/combined", "ms/frame"):
        assert name in table
    from catgraph.methods import FILTER_MODELS

    # four standalone methods, then the filter with every observation model
    assert len(json.loads((tmp_path / "c.json").read_text())["runs"]) == 4 + len(FILTER_MODELS)
    assert main(["report", str(tmp_path / "c.json"), "--out", str(tmp_path / "rep"), "-q"]) == 0
    assert (tmp_path / "rep" / "results.md").read_text().count("grid-filter/") == len(FILTER_MODELS)


def test_saved_map_gives_the_same_result_as_the_reference(image_pair, tmp_path):
    ref, qry = image_pair
    assert main(["build-map", str(ref), "--out", str(tmp_path / "m.npz"), "-q"]) == 0
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["match", str(ref), str(qry), "--window", "3", "--tolerance", "1", "-o", str(a), "-q"]) == 0
    assert main(["match", str(qry), "--map", str(tmp_path / "m.npz"), "--window", "3", "--tolerance", "1",
                 "-o", str(b), "-q"]) == 0
    fa, fb = json.loads(a.read_text()), json.loads(b.read_text())
    assert fa["frames"] == fb["frames"] and fa["metrics"] == fb["metrics"]


def test_build_map_no_compress_stores_the_arrays_as_they_are(image_pair, tmp_path):
    import zipfile

    from catgraph.io import load_map

    ref, _ = image_pair
    for flags, stored in (([], False), (["--no-compress"], True)):
        path = tmp_path / f"m{len(flags)}.npz"
        assert main(["build-map", str(ref), "--out", str(path), "-q", *flags]) == 0
        with zipfile.ZipFile(path) as z:
            kinds = {info.compress_type for info in z.infolist()}
        assert kinds == ({zipfile.ZIP_STORED} if stored else {zipfile.ZIP_DEFLATED})
    a, b = load_map(tmp_path / "m0.npz"), load_map(tmp_path / "m1.npz")
    assert np.array_equal(a.descriptors, b.descriptors) and a.frontend == b.frontend


def test_map_with_two_inputs_is_a_clear_error(image_pair, tmp_path, capsys):
    ref, qry = image_pair
    assert main(["build-map", str(ref), "--out", str(tmp_path / "m.npz"), "-q"]) == 0
    assert main(["match", str(ref), str(qry), "--map", str(tmp_path / "m.npz"), "--tolerance", "1", "-q"]) == 1
    assert "with --map give only QUERY" in capsys.readouterr().err


def test_demo_writes_a_report(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "demo"), "--particles", "500"]) == 0
    out = capsys.readouterr().out
    assert "grid-filter/tempered" in out and "adaptive" in out
    html = (tmp_path / "demo" / "index.html").read_text()
    assert html.count("data:image/png;base64") >= 5
    assert (tmp_path / "demo" / "results.md").exists()
    assert len(list((tmp_path / "demo").glob("*.json"))) == 5


def test_histogram_same_place_by_position(tmp_path, image_pair, capsys):
    out = tmp_path / "h.json"
    assert main(["match", "synthetic:2", "synthetic:2", "--model", "histogram", "--same-place-m", "10",
                 "-o", str(out), "-q"]) == 0
    from catgraph.experiment import synthetic_world

    recheck(json.loads(out.read_text()), synthetic_world(2).ground_truth())
    ref, qry = image_pair
    assert main(["match", str(ref), str(qry), "--tolerance", "1", "--model", "histogram", "--same-place-m", "5",
                 "-q"]) == 1
    assert "needs reference positions" in capsys.readouterr().err


def test_compare_and_localize_with_a_saved_map(tmp_path):
    m = tmp_path / "city.npz"
    assert main(["build-map", "synthetic:5", "--junction-radius-m", "10", "--out", str(m), "-q"]) == 0
    assert main(["compare", "--map", str(m), "synthetic:5", "-q",
                 "-o", str(tmp_path / "c.json")]) == 0
    runs = json.loads((tmp_path / "c.json").read_text())["runs"]
    from catgraph.methods import FILTER_MODELS

    assert [r["params"]["map"] for r in runs] == [str(m)] * (4 + len(FILTER_MODELS))
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["localize", "--map", str(m), "synthetic:5", "-q", "-o", str(a)]) == 0
    assert main(["localize", "synthetic:5", "synthetic:5", "--junction-radius-m", "10", "-q",
                 "-o", str(b)]) == 0
    assert json.loads(a.read_text())["frames"] == json.loads(b.read_text())["frames"]


def test_warm_up_compiles_into_the_cache_folder(capsys):
    """``catgraph warm-up`` runs every live path once and says where the kernels are cached."""
    from catgraph._jit import cache_location

    assert main(["warm-up"]) == 0
    out = capsys.readouterr().out
    assert "compiled and cached the kernels in" in out and str(cache_location()) in out
    assert main(["warm-up", "--quiet"]) == 0
    assert capsys.readouterr().out == ""


def test_closed_or_narrow_standard_streams_are_not_a_traceback(tmp_path):
    """``catgraph … >&-`` (Python's stdout is None) and an ASCII locale (``≥`` in the help
    and the messages): the command still runs, exits as it would and writes no traceback."""
    import os
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "catgraph.cli.main"]
    closed = subprocess.run([*cmd, "match", "--help"], capture_output=False, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: os.close(1), timeout=120)
    assert closed.returncode == 0 and closed.stderr == "", closed.stderr
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    narrow = subprocess.run([*cmd, "match", "--help"], capture_output=True, text=True, env=env, timeout=120)
    assert narrow.returncode == 0 and "Traceback" not in narrow.stderr and "usage:" in narrow.stdout
    bad = subprocess.run([*cmd, "match", "synthetic:1", "synthetic:1", "--window", "0"], capture_output=True,
                         text=True, env=env, timeout=120)
    assert bad.returncode == 1 and bad.stderr.splitlines() == [
        "catgraph: error: --window must be an int \\u2265 1 or 'adaptive'. Got 0 instead."]


def test_compare_runs_a_query_shorter_than_its_default_window(tmp_path, capsys):
    """A 30-frame query: the default fixed window becomes the query's length (said on
    stderr), and the runs are those of --window 30; a window the user sets longer than the
    query is refused."""
    from catgraph.compare import COMPARE_WINDOW, compare_window

    rng = np.random.default_rng(3)
    ref = rng.random((60, 16)).astype(np.float32)
    qry = (ref[10:40] + rng.normal(0, 0.05, (30, 16))).astype(np.float32)
    np.save(tmp_path / "ref.npy", ref)
    np.save(tmp_path / "qry.npy", qry)
    assert 30 < COMPARE_WINDOW and compare_window(30) == 30 and compare_window(30, 7) == 7
    assert compare_window(10 * COMPARE_WINDOW) == COMPARE_WINDOW
    given = ["compare", str(tmp_path / "ref.npy"), str(tmp_path / "qry.npy")]
    assert main([*given, "-o", str(tmp_path / "default.json")]) == 0
    assert "the fixed window is 30 frames" in capsys.readouterr().err
    assert main([*given, "--window", "30", "-q", "-o", str(tmp_path / "set.json")]) == 0
    default, chosen = (json.loads((tmp_path / f"{n}.json").read_text())["runs"] for n in ("default", "set"))
    assert "sequence-L30" in [r["method"] for r in default]
    for a, b in zip(default, chosen):
        assert a["method"] == b["method"] and a["frames"]["match"] == b["frames"]["match"]
    capsys.readouterr()
    assert main([*given, "--window", "31", "-q"]) == 1
    assert "--window 31 frames is longer than the query (30 frames)" in capsys.readouterr().err
