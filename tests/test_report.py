"""HTML and markdown report: content, self-containment, errors, CLI, and a real browser render."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from catgraph.cli.main import main
from catgraph.exceptions import DataError, DataNotFoundError, InvalidParameterError
from catgraph.report import load_results, markdown_table, run_labels, write_report
from catgraph.results import RunResult, write_json_atomic
from catgraph.traverse import FrameTolerance

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


def make_payload(seed, method="sequence", params=None, noise=0.3, n=80, extra=None) -> dict:
    rng = np.random.default_rng(seed)
    q = np.arange(n)
    good = rng.random(n) > noise
    match = np.where(good, q, rng.integers(0, n, n))
    match[rng.random(n) < 0.05] = -1
    result = RunResult(method, dict(params or {}), q, match, rng.random(n) + good, extra=extra or {})
    return result.to_dict(result.evaluate(FrameTolerance(n, tolerance=1)))


@pytest.fixture
def payloads():
    rng = np.random.default_rng(0)
    return [
        make_payload(1, "single-frame", {"exclusion": 10, "frontend": {"patch": 4}}, noise=0.5),
        make_payload(2, "sequence", {"window": 10, "frontend": {"patch": 4}}, noise=0.3),
        make_payload(3, "sequence", {"window": "adaptive", "frontend": {"patch": 4}}, noise=0.2,
                     extra={"window_length": rng.integers(5, 200, 80)}),
        make_payload(4, "localizer", {"n_particles": 500, "frontend": {"patch": 4}}, noise=0.1,
                     extra={"p_new_place": rng.random(80)}),
    ]


def images(page: str) -> list[str]:
    return re.findall(r'<img src="([^"]+)"', page)


def test_report_holds_every_number_and_the_figures(tmp_path, payloads):
    index = write_report(payloads, tmp_path / "out", title="Nordland <summer> → winter")
    assert index == tmp_path / "out" / "index.html"
    assert sorted(p.name for p in index.parent.iterdir()) == ["index.html", "results.md"]  # no temp files left
    page = index.read_text()
    table = (index.parent / "results.md").read_text()
    assert "<title>Nordland &lt;summer&gt; → winter</title>" in page
    assert table.startswith("# Nordland <summer> → winter\n")
    for payload in payloads:
        m = payload["metrics"]
        for text in (f"{m['auc']:.3f}", f"{m['recall_at_100p']:.3f}", f"{m['recall_at_99p']:.3f}",
                     f"{m['recall_at_90p']:.3f}", f">{m['mtl']}<", f"{m['accuracy']:.3f}"):
            assert text in page
            assert text.strip("<>") in table
    assert page.count("<tr>") == 1 + len(payloads)  # header + one row per run
    assert len(table.strip().split("\n# ")[0].splitlines()) >= 2 + len(payloads)
    # PR curves, AUC/MTL bars, timeline, window length, P(new place)
    sources = images(page)
    assert len(sources) == 5
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert "Window length" in page and "place not in the map" in page


def test_report_is_self_contained_and_deterministic(tmp_path, payloads):
    first = write_report(payloads, tmp_path / "a").read_bytes()
    second = write_report(payloads, tmp_path / "b").read_bytes()
    assert first == second
    page = first.decode()
    assert not re.search(r'(src|href)="(?!data:)', page)  # every asset inline
    assert "<script" not in page and "<link" not in page and "http://" not in page and "https://" not in page


def test_best_values_are_bold_and_shared_params_listed_once(tmp_path, payloads):
    table = markdown_table(payloads)
    best_auc = max(p["metrics"]["auc"] for p in payloads)
    best_mtl = min(p["metrics"]["mtl"] for p in payloads)
    assert f"**{best_auc:.3f}**" in table and f"**{best_mtl}**" in table
    assert "Shared by all runs: frontend.patch=4." in table
    rows = [line for line in table.splitlines() if line.startswith("| sequence")]
    assert "window=10" in rows[0] and "frontend" not in rows[0]


def test_run_labels_tell_equal_methods_apart(payloads):
    labels = run_labels(payloads)
    assert labels[0] == "single-frame" and labels[3] == "localizer"
    assert labels[1] == "sequence (window=10)" and labels[2] == "sequence (window=adaptive)"
    assert run_labels([payloads[0], payloads[0]]) == ["single-frame #1", "single-frame #2"]
    assert run_labels([dict(payloads[1], name="L=10")]) == ["L=10"]


def test_report_from_paths_and_extra_figures(tmp_path, payloads):
    from matplotlib.figure import Figure

    paths = [write_json_atomic(tmp_path / f"r{k}.json", p) for k, p in enumerate(payloads[:2])]
    fig = Figure()
    ax = fig.add_subplot()
    ax.plot([0, 1], [1, 0])
    png = tmp_path / "extra.png"
    fig.savefig(png)
    index = write_report(paths, tmp_path / "out", extra_figures={"a figure": fig, "an axes": ax, "a file": png})
    page = index.read_text()
    assert len(images(page)) == 3 + 3  # PR, bars, timeline + three extra
    assert "<figcaption>a file</figcaption>" in page
    with pytest.raises(InvalidParameterError, match="extra figure"):
        write_report(paths, tmp_path / "out", extra_figures={"bad": 3})
    with pytest.raises(DataNotFoundError):
        write_report(paths, tmp_path / "out", extra_figures={"gone": tmp_path / "missing.png"})


def test_unevaluated_run_shows_dashes(tmp_path, payloads):
    raw = RunResult("raw", {}, np.arange(3), np.array([0, 1, -1]), np.ones(3)).to_dict(None)
    index = write_report([payloads[0], raw], tmp_path)
    row = [line for line in index.read_text().splitlines() if ">raw<" in line][0]
    assert row.count('class="num">–<') == len(("auc", "r100", "r99", "r90", "mtl", "acc", "n"))


def test_unreadable_inputs_raise_typed_errors(tmp_path, payloads):
    with pytest.raises(InvalidParameterError, match="no results"):
        write_report([], tmp_path)
    with pytest.raises(InvalidParameterError, match="list"):
        write_report(payloads[0], tmp_path)
    with pytest.raises(DataNotFoundError):
        load_results([tmp_path / "missing.json"])
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(DataError, match="not valid JSON"):
        load_results([tmp_path / "broken.json"])
    (tmp_path / "other.json").write_text(json.dumps({"hello": 1}))
    with pytest.raises(DataError, match="not a catgraph result"):
        load_results([tmp_path / "other.json"])
    with pytest.raises(DataError, match="folder"):
        load_results([tmp_path])
    with pytest.raises(DataError, match="must be a finite number"):
        load_results([dict(payloads[0], metrics=dict(payloads[0]["metrics"], auc="high"))])
    with pytest.raises(DataError, match="metric 'auc' must be a finite number; got nan"):
        load_results([dict(payloads[0], metrics=dict(payloads[0]["metrics"], auc=float("nan")))])
    frames = payloads[0]["frames"]
    n = len(frames["correct"])
    with pytest.raises(DataError, match="frames 'correct' must hold true, false or null per frame; frame 1 holds 'yes'"):
        load_results([dict(payloads[0], frames=dict(frames, correct=[True, "yes"] + [True] * (n - 2)))])
    with pytest.raises(DataError, match="frames 'match' must hold a reference index"):
        load_results([dict(payloads[0], frames=dict(frames, match=[-3] * n))])
    with pytest.raises(DataError, match="frames 'confidence' must hold a finite number or null"):
        load_results([dict(payloads[0], frames=dict(frames, confidence=[float("inf")] * n))])
    (tmp_path / "file").write_text("")
    with pytest.raises(InvalidParameterError, match="is a file"):
        write_report(payloads, tmp_path / "file")


def test_cli_report(tmp_path, payloads, capsys):
    paths = [str(write_json_atomic(tmp_path / f"r{k}.json", p)) for k, p in enumerate(payloads)]
    assert main(["report", *paths, "--out", str(tmp_path / "rep"), "--title", "CLI"]) == 0
    assert "index.html" in capsys.readouterr().out
    assert "<h1>CLI</h1>" in (tmp_path / "rep" / "index.html").read_text()
    assert main(["report", paths[0], "--out", str(tmp_path / "rep"), "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    assert main(["report", str(tmp_path / "missing.json"), "--out", str(tmp_path / "rep")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("catgraph: error:") and err.count("\n") == 1 and "missing.json" in err


# The probe runs after load: title = "<decoded images>/<images> rows=<table rows>".
PROBE = ("<script>window.addEventListener('load', () => { const im = Array.from(document.images); "
         "document.title = im.filter(i => i.complete && i.naturalWidth > 0).length + '/' + im.length + "
         "' rows=' + document.querySelectorAll('#metrics tbody tr').length; });</script>")


def chromium(*args: str, profile: Path) -> subprocess.CompletedProcess:
    command = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               f"--user-data-dir={profile}", "--window-size=1200,900", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(CHROMIUM is None, reason="needs a Chromium binary (Debian: apt-get install -y chromium)")
def test_report_renders_in_headless_chromium(tmp_path, payloads):
    from PIL import Image

    index = write_report(payloads, tmp_path / "out")
    probed = tmp_path / "probed.html"
    probed.write_text(index.read_text().replace("</body>", PROBE + "</body>"))
    dom = chromium("--virtual-time-budget=5000", "--dump-dom", probed.as_uri(), profile=tmp_path / "p1").stdout
    title = re.search(r"<title>(.*?)</title>", dom)
    assert title is not None, dom[:500]
    assert title.group(1) == f"5/5 rows={len(payloads)}"
    assert 'id="metrics"' in dom

    shot = tmp_path / "shot.png"
    chromium(f"--screenshot={shot}", index.as_uri(), profile=tmp_path / "p2")
    pixels = np.asarray(Image.open(shot).convert("L"), dtype=np.float64)
    assert pixels.shape == (900, 1200)
    assert pixels.std() > 20  # text, table and plots, not a blank page


def test_parameters_are_never_cut_and_notes_are_shown(tmp_path, payloads):
    long = {"window": "adaptive", "note": "x" * 300, "frontend": {"patch": 4}}
    runs = payloads + [make_payload(5, "sequence", long)]
    note = "Single-frame matching wins here because the synthetic night is only mildly darker."
    page = write_report(runs, tmp_path / "r", notes=[note]).read_text()
    assert "note=" + "x" * 300 + "</td>" in page  # the parameter cell holds it in full
    assert note in page and note in (tmp_path / "r" / "results.md").read_text()
    with pytest.raises(InvalidParameterError):
        write_report(runs, tmp_path / "r2", notes=[3])


def test_initialisation_frames_from_params():
    from catgraph.report import initialisation_frames

    assert initialisation_frames(make_payload(1, "histogram", {"learning": "online", "n_init": 30})) == 30
    assert initialisation_frames(make_payload(1, "histogram", {"learning": "bootstrap", "n_init": 30})) == 0
    assert initialisation_frames(make_payload(1, "filter", {"model": {"n_init": 500}})) == 80  # capped at n frames
    assert initialisation_frames(make_payload(1, "sequence", {"window": 5})) == 0


def test_new_place_truth_is_shaded_once_per_report(tmp_path, payloads):
    truth = np.zeros(80, bool)
    truth[20:30] = True
    page = write_report(payloads, tmp_path / "r", new_place_truth=truth).read_text()
    assert "Shaded: frames truly outside the map" in page


def test_run_labels_keep_what_tells_runs_apart_within_their_length():
    """Runs that differ by a shuffle's seed among longer nested parameters: the seed comes
    first, by its own name, so that the label cut at its length still tells them apart."""
    runs = [{"name": "sequence-L5", "params": {"window": 5, "condition": {"kind": "in-order"}}}]
    runs += [{"name": "sequence-L5", "params": {"window": 5, "condition": {"kind": "shuffle", "seed": s,
                                                                          "segment_range": [0.02, 0.2]}}}
             for s in range(3)]
    labels = run_labels(runs)
    assert len(set(labels)) == 4 and not any("#" in label for label in labels)
    assert "seed=1" in labels[2] and "kind=shuffle" in labels[2]


def test_the_runs_environments_are_named_and_their_differences_shown(tmp_path, payloads):
    """A report names the environment its runs share, says what differs where they were made
    with other versions or for another compile target (which alone moves a metric's last
    digits), counts the runs that record none, and refuses an environment that is no object."""
    from catgraph.environment import environment
    from catgraph.report import environment_note

    assert environment_note(payloads) is None  # made without one (RunResult.to_dict alone)
    here = environment()
    same = [dict(p, environment=here) for p in payloads]
    note = environment_note(same)
    assert note.startswith("Environment of the runs") and f"compiled for {here['compiled_for']}" in note
    assert note in markdown_table(same)
    other = [dict(same[0], environment=dict(here, compiled_for="rocketlake", numba="0.0.1"))] + same[1:]
    note = environment_note(other)
    assert note.startswith("The runs were made in different environments")
    assert "numba " in note and "compiled_for " in note and "rocketlake" in note and "catgraph " not in note
    page = write_report(other, tmp_path / "r").read_text()
    assert "different environments" in page and "rocketlake" in page
    assert "do not record theirs" not in note
    assert "1 of the 4 runs do not record theirs" in environment_note([payloads[0]] + same[1:])
    with pytest.raises(DataError, match="'environment' must be an object"):
        load_results([dict(payloads[0], environment="AMD")])
