import json

import numpy as np
import pytest

from catgraph.config import load_config
from catgraph.exceptions import CatgraphError, DataNotFoundError, InvalidParameterError
from catgraph.sweep import run_sweep


def write_pair(folder, seed, n=50, dim=24):
    """A reference and a noisy query of descriptors with positions (metres)."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n, dim)).astype(np.float32)
    positions = np.stack([np.arange(n) * 3.0, np.zeros(n)], 1)
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "ref.npz", descriptors=base, positions=positions)
    np.savez(folder / "qry.npz", descriptors=base + rng.normal(0, 0.9, base.shape).astype(np.float32),
             positions=positions + rng.normal(0, 0.5, positions.shape))
    return folder


CONFIG = """
name = "tiny"

[[dataset]]
name = "a"
reference = "a/ref.npz"
query = "a/qry.npz"
tolerance = 1
shuffle = [false, 0]

[[dataset]]
name = "b"
reference = "b/ref.npz"
query = "b/qry.npz"
tolerance_m = 4.0

[[method]]
name = "sf"
method = "single-frame"
grid = { exclusion = [1, 4, 10] }
"""


@pytest.fixture
def tiny_config(tmp_path):
    write_pair(tmp_path / "a", 0)
    write_pair(tmp_path / "b", 1)
    path = tmp_path / "tiny.toml"
    path.write_text(CONFIG)
    return path


def without_seconds(payload):
    return {k: v for k, v in payload.items() if k != "seconds"}


def echo_runner(spec):
    """A stand-in runner: returns its spec (module level, so workers can import it)."""
    if spec.get("params", {}).get("fail"):
        raise InvalidParameterError("this run fails on purpose")
    return {"name": spec["name"], "spec": spec}


def test_local_and_dask_give_identical_results(tiny_config):
    distributed = pytest.importorskip("distributed")
    specs = load_config(tiny_config).specs
    assert len(specs) == 9
    serial = run_sweep(specs, processes=1, progress=False)
    local = run_sweep(specs, processes=2, progress=False)
    with distributed.LocalCluster(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask = run_sweep(specs, scheduler=client, progress=False)
    assert [p["name"] for p in serial] == [s["name"] for s in specs]
    for a, b, c in zip(serial, local, on_dask):
        assert without_seconds(a) == without_seconds(b) == without_seconds(c)
    # the runs really differ: a different exclusion gives different confidences
    assert serial[0]["frames"]["confidence"] != serial[2]["frames"]["confidence"]
    # and the shuffled run processed the frames in another order
    assert serial[1]["frames"]["query_index"] != serial[0]["frames"]["query_index"]


def test_results_come_back_in_spec_order(tmp_path):
    specs = [{"name": f"r{k}", "params": {}} for k in range(7)]
    for processes in (1, 3):
        assert [p["name"] for p in run_sweep(specs, processes=processes, progress=False, runner=echo_runner)] == \
            [s["name"] for s in specs]
    assert run_sweep([], progress=False) == []


def test_errors_raise_with_run_name_or_are_recorded():
    specs = [{"name": "ok", "params": {}}, {"name": "bad", "params": {"fail": True}}]
    for processes in (1, 2):
        with pytest.raises(InvalidParameterError, match="run 'bad': this run fails on purpose"):
            run_sweep(specs, processes=processes, progress=False, runner=echo_runner)
    recorded = run_sweep(specs, processes=1, progress=False, runner=echo_runner, errors="record")
    assert recorded[0]["name"] == "ok"
    assert recorded[1]["name"] == "bad" and "this run fails on purpose" in recorded[1]["error"]
    assert recorded[1]["spec"] == specs[1]


def test_real_run_error_names_the_run(tmp_path):
    spec = {"name": "missing", "reference": str(tmp_path / "nope.npz"), "query": str(tmp_path / "nope.npz"),
            "method": "single-frame", "tolerance": 1}
    with pytest.raises(DataNotFoundError, match="run 'missing': .*does not exist"):
        run_sweep([spec], processes=1, progress=False)


def test_argument_checks():
    with pytest.raises(InvalidParameterError, match="'processes'"):
        run_sweep([{}], processes=0)
    with pytest.raises(InvalidParameterError, match="'errors'"):
        run_sweep([{}], errors="ignore")
    with pytest.raises(InvalidParameterError, match="must be a dict"):
        run_sweep(["spec"])
    with pytest.raises(InvalidParameterError, match="'scheduler'"):
        run_sweep([{}], scheduler=42)


def test_missing_dask_is_explained(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails as if not installed
    with pytest.raises(CatgraphError, match=r'pip install "catgraph\[dask\]"'):
        run_sweep([{}], scheduler="tcp://127.0.0.1:1", progress=False)


def test_bench_command_end_to_end(tiny_config, tmp_path, capsys):
    from catgraph.cli.main import main

    out = tmp_path / "out"
    assert main(["bench", str(tiny_config), "--out", str(out), "--processes", "1", "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    names = sorted(p.name for p in out.glob("*.json") if p.name != "summary.json")
    assert len(names) == 9 and "a__sf__exclusion=1__shuffle=0.json" in names
    payload = json.loads((out / "a__sf__exclusion=1__shuffle=0.json").read_text())
    assert payload["name"] == "a/sf/exclusion=1/shuffle=0" and payload["spec"]["condition"]["seed"] == 0
    assert set(payload["metrics"]) >= {"auc", "mtl", "accuracy"}
    summary = (out / "summary.md").read_text()
    assert "a/sf/exclusion=4/in-order" in summary and "AUC" in summary
    rows = json.loads((out / "summary.json").read_text())["runs"]
    assert [r["name"] for r in rows][:2] == ["a/sf/exclusion=1/in-order", "a/sf/exclusion=1/shuffle=0"]
    assert rows[0]["metrics"] == json.loads((out / "a__sf__exclusion=1__in-order.json").read_text())["metrics"]


def test_bench_list_and_errors(tiny_config, tmp_path, capsys):
    from catgraph.cli.main import main

    assert main(["bench", str(tiny_config), "--list"]) == 0
    listed = capsys.readouterr().out
    assert "b/sf/exclusion=10" in listed and "9 runs" in listed
    # options that a listing or a cluster would not read are refused, not ignored
    for extra, needle in ((["--out", str(tmp_path / "o")], "--out does not apply with --list"),
                          (["--processes", "2"], "--processes does not apply with --list"),
                          (["--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1", "--processes", "2"],
                           "--processes does not apply with --scheduler")):
        assert main(["bench", str(tiny_config), *extra, *(["--list"] if "list" in needle else [])]) == 1
        assert needle in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text(CONFIG.replace("grid", "gird"))
    assert main(["bench", str(bad), "--out", str(tmp_path / "x"), "-q"]) == 1
    assert "did you mean 'grid'?" in capsys.readouterr().err
    # a failing run: the others are written, the command fails naming it
    broken = tmp_path / "broken.toml"
    broken.write_text(CONFIG + '\n[[run]]\nname = "gone"\nreference = "gone.npz"\nquery = "gone.npz"\n'
                               'tolerance = 1\nmethod = "single-frame"\n')
    out = tmp_path / "broken"
    assert main(["bench", str(broken), "--out", str(out), "--processes", "1", "-q"]) == 1
    err = capsys.readouterr().err
    assert "1 of 10 runs failed" in err and "gone" in err
    assert len([p for p in out.glob("*.json") if p.name != "summary.json"]) == 9
    assert "gone" in (out / "summary.md").read_text()


def test_bench_into_an_earlier_output_keeps_no_stale_result(tiny_config, tmp_path, capsys):
    """A run that fails now leaves no earlier bench's result under its name, and a bench with
    no result leaves no earlier report, so the folder says only what this bench found."""
    from catgraph.cli.main import main

    out = tmp_path / "out"
    assert main(["bench", str(tiny_config), "--out", str(out), "--processes", "1", "-q"]) == 0
    assert (out / "index.html").exists() and (out / "a__sf__exclusion=1__in-order.json").exists()
    gone = tmp_path / "tiny_gone.toml"  # the same runs, whose references have gone
    gone.write_text(CONFIG.replace("/ref.npz", "/gone.npz"))
    assert main(["bench", str(gone), "--out", str(out), "--processes", "1", "-q"]) == 1
    assert "9 of 9 runs failed" in capsys.readouterr().err
    rows = json.loads((out / "summary.json").read_text())["runs"]
    assert len(rows) == 9 and all("error" in r for r in rows)
    assert [p.name for p in out.glob("*.json")] == ["summary.json"]
    assert not (out / "index.html").exists() and not (out / "results.md").exists()


def dying_runner(spec):
    """A stand-in runner whose worker process dies on one spec (as the out-of-memory killer
    ends it): no exception reaches the runner's guard."""
    if spec.get("params", {}).get("die"):
        import os

        os._exit(9)
    return {"name": spec["name"], "spec": spec}


def test_each_result_is_handed_on_as_it_finishes_and_a_dead_worker_is_recorded():
    specs = [{"name": f"r{k}", "params": {"die": k == 2}} for k in range(5)]
    seen = {}
    out = run_sweep(specs[:2] + specs[3:], processes=1, progress=False, runner=dying_runner,
                    on_result=lambda k, payload: seen.setdefault(k, payload))
    assert [p["name"] for p in out] == ["r0", "r1", "r3", "r4"] and [seen[k] for k in range(4)] == out
    seen.clear()
    out = run_sweep(specs, processes=2, progress=False, runner=dying_runner, errors="record",
                    on_result=lambda k, payload: seen.setdefault(k, payload))
    assert sorted(seen) == list(range(5)) and [seen[k] for k in range(5)] == out
    assert "error" in out[2] and "worker" in out[2]["error"]
    # the pool breaks for the runs still pending when the worker died: each is recorded, not lost in a traceback
    assert all(p["name"] == f"r{k}" for k, p in enumerate(out))


def test_bench_keeps_only_this_configs_runs_and_prints_runs_without_ground_truth(tiny_config, tmp_path, capsys):
    """Runs the config no longer has leave the folder (their earlier files would be read as this
    bench's), and a dataset without ground truth prints dashes, not a traceback."""
    from catgraph.cli.main import main

    out = tmp_path / "out"
    assert main(["bench", str(tiny_config), "--out", str(out), "--processes", "1", "-q"]) == 0
    assert (out / "a__sf__exclusion=10__in-order.json").exists()
    fewer = tmp_path / "fewer.toml"
    fewer.write_text(CONFIG.replace("exclusion = [1, 4, 10]", "exclusion = [1, 4]"))
    assert main(["bench", str(fewer), "--out", str(out), "--processes", "1", "-q"]) == 0
    files = sorted(p.name for p in out.glob("*.json"))
    assert len(files) == 7 and "a__sf__exclusion=10__in-order.json" not in files  # 6 runs and the summary
    nogt = tmp_path / "nogt.toml"
    nogt.write_text(CONFIG.replace("tolerance = 1\n", "").replace("tolerance_m = 4.0\n", ""))
    assert main(["bench", str(nogt), "--out", str(tmp_path / "nogt"), "--processes", "1"]) == 0
    table = capsys.readouterr().out
    assert "a/sf/exclusion=1/in-order" in table and "–" in table
