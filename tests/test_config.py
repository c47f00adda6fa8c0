import json
import os
import textwrap
import tomllib
from pathlib import Path

import pytest

from catgraph.config import load_config, parse_config, run_file_name
from catgraph.exceptions import ConfigError, DataNotFoundError
from catgraph.experiment import SPEC_KEYS

GOOD = """
name = "demo"

[[dataset]]
name = "a"
reference = "ref.npz"
query = "qry.npz"
tolerance = 2
shuffle = [false, 0]
frontend = { size = "32x16", patch = 0, crop = [0, 2, 1, 1] }

[[dataset]]
name = "b"
reference = "synthetic:1"
query = "synthetic:1"

[[method]]
name = "sf"
method = "single-frame"
grid = { exclusion = [1, 5, 10] }

[[method]]
method = "single-frame"
params = { exclusion = 3 }
datasets = ["b"]

[[run]]
name = "explicit"
dataset = "a"
method = "single-frame"
shuffle = 4

[[run]]
reference = "/abs/r.npy"
query = "q.npy"
tolerance_m = 2.5
method = "single-frame"
"""


def write(tmp_path, text, name="config.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_expansion_order_names_and_specs(tmp_path):
    config = load_config(write(tmp_path, GOOD))
    names = [s["name"] for s in config.specs]
    assert names == [
        "a/sf/exclusion=1/in-order", "a/sf/exclusion=1/shuffle=0",
        "a/sf/exclusion=5/in-order", "a/sf/exclusion=5/shuffle=0",
        "a/sf/exclusion=10/in-order", "a/sf/exclusion=10/shuffle=0",
        "b/sf/exclusion=1", "b/sf/exclusion=5", "b/sf/exclusion=10",
        "b/single-frame",
        "explicit", "single-frame#2",
    ]
    assert config.name == "demo" and len(config) == 12
    first = config.specs[1]
    assert set(first) <= set(SPEC_KEYS)
    assert first["reference"] == os.path.normpath(str(tmp_path / "ref.npz"))  # relative to the file
    assert first["params"] == {"exclusion": 1} and first["tolerance"] == 2
    assert first["condition"] == {"kind": "shuffle", "seed": 0, "segment_range": [0.02, 0.2]}
    assert config.specs[0]["condition"] == {"kind": "in-order"}
    assert first["frontend"] == {"size": [32, 16], "patch": 0, "crop": [0, 2, 1, 1]}
    assert config.specs[6]["reference"] == "synthetic:1" and "tolerance" not in config.specs[6]
    assert config.specs[9]["params"] == {"exclusion": 3}
    explicit = config.specs[10]
    assert explicit["condition"]["seed"] == 4 and explicit["reference"] == first["reference"]
    assert explicit["tolerance"] == 2
    assert config.specs[11]["reference"] == "/abs/r.npy" and config.specs[11]["tolerance_m"] == 2.5


def test_params_are_copied_not_shared(tmp_path):
    specs = load_config(write(tmp_path, GOOD)).specs
    specs[0]["params"]["exclusion"] = 99
    assert specs[1]["params"]["exclusion"] == 1


def test_paths_left_alone_without_base_dir():
    data = tomllib.loads(GOOD)
    config = parse_config(data, source="x.toml")
    assert config.specs[0]["reference"] == "ref.npz"


def test_run_file_name():
    assert run_file_name("a/sf/window=10/shuffle=0") == "a__sf__window=10__shuffle=0"
    assert [run_file_name(n) for n in ("", ".", "..")] == ["_", "_.", "_.."]  # a name, never a folder


def test_paths_that_begin_with_synthetic_are_paths(tmp_path):
    text = ('[[dataset]]\nname = "d"\nreference = "synthetic_ref"\nquery = "synthetic:0"\n'
            'ground_truth = "synthetic_gt.csv"\n[[method]]\nmethod = "single-frame"\n')
    spec = load_config(write(tmp_path, text)).specs[0]
    assert spec["reference"] == str(tmp_path / "synthetic_ref") and spec["query"] == "synthetic:0"
    assert spec["ground_truth"] == str(tmp_path / "synthetic_gt.csv")
    assert run_file_name("x y:z") == "x_y_z"


BASE = """
[[dataset]]
name = "a"
reference = "synthetic:0"
query = "synthetic:0"
"""


@pytest.mark.parametrize("extra, needle", [
    ('[[method]]\nmethod = "single-frame"\nparams = { window = "ten" }\n[[method]]\nname = "x"\n'
     'method = "single-frame"\nparams = { window = "ten" }',
     "config.toml: [[method]] #1 method 'single-frame' has no parameter 'window'"),
    ('[[method]]\nmethod = "sequence"\nparams = { window = "ten" }',
     "config.toml: [[method]] #1 The 'window' parameter of method 'sequence' must be an int ≥ 1 or 'adaptive'. "
     "Got 'ten' instead."),
    ('[[method]]\nmethod = "sequence"\ngrid = { window = [5, "adaptive"] }\nparams = { rule = "literal" }',
     "'rule' does not apply to method 'sequence' here"),
    ('[[method]]\nmethod = "filter"\nparams = { model = "histogram", window = 20 }',
     "'window' does not apply to method 'filter' here: model 'histogram' has no sequence matcher"),
    ('[[method]]\nmethod = "single-frame"\n[[method]]\nname = "two"\nmethod = "single-frame"\n'
     'grid = { exclusion = [1, -2] }',
     "config.toml: [[method]] #2 The 'exclusion' parameter of method 'single-frame' must be an int in [0, 1e+06]. "
     "Got -2 instead."),
    ('[[method]]\nmethod = "single-frame"\nparmas = {}', "[[method]] #1 has unknown key 'parmas'; did you mean 'params'?"),
    ('[[method]]\nmethod = "single-fram"', "'method' 'single-fram' is not a known method; did you mean 'single-frame'?"),
    ('[[method]]\nname = "x"', "[[method]] #1 needs the key 'method'."),
    ('[[method]]\nmethod = "single-frame"\ngrid = { exclusion = 3 }', "'grid.exclusion' must be a non-empty list"),
    ('[[method]]\nmethod = "single-frame"\nparams = { exclusion = 1 }\ngrid = { exclusion = [1] }',
     "sets 'exclusion' in both 'params' and 'grid'"),
    ('[[method]]\nmethod = "single-frame"\ndatasets = ["b"]', "'datasets' names 'b', which no [[dataset]] defines"),
    ('[[method]]\nmethod = "single-frame"\n[[method]]\nmethod = "single-frame"', "repeats the method name"),
    ('[[run]]\nmethod = "single-frame"\ndataset = "zzz"', "[[run]] #1 'dataset' names 'zzz'"),
    ('[[run]]\nmethod = "single-frame"\nreference = "r.npy"', "[[run]] #1 needs the key 'query'"),
    ('[[run]]\nmethod = "single-frame"\ndataset = "a"\nshuffle = [0]', "one value"),
    ('[[run]]\nmethod = "single-frame"\ndataset = "a"\ntolerance = 3', "sets 'dataset' and 'tolerance'"),
    ('[[run]]\nname = "r"\nmethod = "single-frame"\ndataset = "a"\n[[run]]\nname = "r"\nmethod = "single-frame"\n'
     'dataset = "a"', "two runs are named 'r'"),
    ('[[metod]]\nmethod = "single-frame"', "top level has unknown key 'metod'; did you mean 'method'?"),
    ('[[run]]\nmethod = "single-frame"\ndataset = ["a"]', "'dataset' must be the name of one [[dataset]]"),
    ('[[run]]\nname = "r s"\nmethod = "single-frame"\ndataset = "a"\n[[run]]\nname = "r_s"\n'
     'method = "single-frame"\ndataset = "a"', "config.toml: two runs are named 'r_s'"),
])
def test_method_and_run_errors(tmp_path, extra, needle):
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, BASE + extra))
    assert needle in str(info.value)


@pytest.mark.parametrize("dataset, needle", [
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\ntolerance_m = 2.0',
     "gives 'tolerance' and 'tolerance_m'; keep one ground truth"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nground_truth = "gt.csv"', "keep one ground truth"),
    ('name = "d"\nmap = "m.npz"\nquery = "q"\nfrontend = { patch = 2 }', "'frontend' with a saved 'map'"),
    ('name = "d"\nmap = "m.npz"\nquery = "q"\njunction_radius_m = 2.0', "'junction_radius_m' with a saved 'map'"),
    ('name = "d"\nreference = "r"\nmap = "m.npz"\nquery = "q"', "exactly one of 'reference'"),
    ('name = "d"\nreference = "r"\nquery = "q"\nconditions = ["sideways"]', "cannot read condition 'sideways'"),
    ('name = "d"\nreference = "r"\nquery = "q"\nconditions = ["speed:0"]', "speed factor must be in [0.01, 100]"),
    ('name = "d"\nreference = "r"\nquery = "q"\nconditions = ["reverse", "reverse"]', "lists a condition twice"),
    ('name = "d"\nreference = "r"\nquery = "q"\nconditions = ["reverse"]\nshuffle = 0', "both 'shuffle' and"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1.5', "'tolerance' must be an int ≥ 0 (frames), got 1.5"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = true', "'tolerance' must be an int"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nshuffle = [false, "x"]', "'shuffle' must be false"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nshuffle = [0, 0]', "lists a value twice"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nconditions = ["speed:1", "in-order"]',
     "lists 'speed:1' and 'in-order', which give the same runs"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nconditions = ["speed:2", "speed:2.0000001"]',
     "which give the same runs (speed=2)"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nfrontend = { size = "32by16" }',
     "write the size as WIDTHxHEIGHT"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nfrontend = { patch_size = 4 }',
     "[[dataset]] #1 frontend has unknown key 'patch_size'; did you mean 'patch'?"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nfrontend = { metric = "l1" }', "unknown metric 'l1'"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\nfrontend = { crop = [1, 2] }',
     "crop must be (top, bottom, left, right)"),
    ('name = "d"\nreference = "r"\nquery = "q"\nfrontend = { metric = "wifi" }', "unknown metric 'wifi'"),
    ('name = "d/e"\nreference = "r"\nquery = "q"\ntolerance = 1', "'name' must be a non-empty string without '/'"),
    ('name = "d"\nreference = "synthetic:x"\nquery = "q"\ntolerance = 1', "'synthetic:SEED'"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance_m = inf', "'tolerance_m' must be a number ≥ 0"),
    ('name = "d"\nreference = "r"\nquery = "q"\ntolerance = 1\njunction_radius_m = inf', "'junction_radius_m'"),
    ('name = "d"\nquery = "q"\ntolerance = 1', "[[dataset]] #1 needs exactly one of 'reference' (a traverse) and "
     "'map'"),
])
def test_dataset_errors(tmp_path, dataset, needle):
    text = f"[[dataset]]\n{dataset}\n[[method]]\nmethod = \"single-frame\"\n"
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    assert needle in str(info.value)


def test_file_errors(tmp_path):
    with pytest.raises(DataNotFoundError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match=r"bad.toml: not valid TOML: .*line 1"):
        load_config(write(tmp_path, "[[dataset]\n", "bad.toml"))
    with pytest.raises(ConfigError, match="defines no runs"):
        load_config(write(tmp_path, BASE))
    with pytest.raises(ConfigError, match="'dataset' must be an array of tables"):
        load_config(write(tmp_path, 'dataset = "x"\n'))


EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.toml"))


def test_examples_exist():
    assert {"synthetic.toml", "nordland.toml", "uji.toml"} <= {p.name for p in EXAMPLES}


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_examples_parse(path):
    config = load_config(path)
    assert len(config) >= 1
    for spec in config.specs:
        for key in ("reference", "query"):
            assert spec[key].startswith("synthetic") or Path(spec[key]).is_absolute()


@pytest.mark.parametrize("method, params, message", [
    ("filter", {"mode": "particles", "jump_graduation": 0.0}, r"\(0, 1\]"),
    ("filter", {"mode": "particles", "jump_graduation": 0.5, "proposal": "uniform"}, "proposal 'likelihood'"),
    ("filter", {"model": "adaptive", "l_min": 600, "l_max": 100}, "'l_min' \\(600\\) is longer"),
    ("sequence", {"window": "adaptive", "l_min": 600, "l_max": 100}, "'l_min' \\(600\\) is longer"),
    ("sequence", {"window": "adaptive", "exclusion": 3}, "rule 'tracked'"),
    ("sequence", {"window": "adaptive", "recent_fraction": 0.2}, "rule 'tracked'"),
    ("filter", {"mode": "particles", "ess_threshold": 0.9}, "resamples every frame"),
])
def test_values_that_would_fail_or_be_ignored_once_running_are_refused_at_once(method, params, message):
    """Checks across parameters that need no data: a sweep refused these only when the run
    started (or ran and ignored them)."""
    from catgraph.exceptions import InvalidParameterError
    from catgraph.methods import resolve_params

    with pytest.raises(InvalidParameterError, match=message):
        resolve_params(method, params)
    # what still applies is taken
    assert resolve_params("sequence", {"window": "adaptive", "rule": "challenged", "exclusion": 3})["exclusion"] == 3
    assert resolve_params("filter", {"mode": "particles", "redraw_fraction": 0.0, "ess_threshold": 0.9})[
        "ess_threshold"] == 0.9


@pytest.mark.parametrize("conditions,names,second,bad", [
    (["vary:0", "vary:1:0.25:4", "speed:2"], ["vary=0,0.5-2", "vary=1,0.25-4", "speed=2"],
     {"kind": "vary", "seed": 1, "segment_range": [0.02, 0.2], "speed_range": [0.25, 4.0]}, ("vary:1:0.25:4", "vary:1:4:0.25")),
    (["stop:0", "stop:1:2:9", "in-order"], ["stop=0,5-50", "stop=1,2-9", "in-order"],
     {"kind": "stop", "seed": 1, "segment_range": [0.02, 0.2], "stop_frames": [2, 9]}, ("stop:1:2:9", "stop:1:9:2")),
])
def test_varying_and_stopping_conditions_name_their_runs(tmp_path, conditions, names, second, bad):
    text = f"""
    [[dataset]]
    name = "d"
    reference = "r.npy"
    query = "q.npy"
    tolerance = 1
    conditions = {json.dumps(conditions)}

    [[method]]
    method = "single-frame"
    """
    config = load_config(write(tmp_path, text))
    assert [s["name"] for s in config.specs] == [f"d/single-frame/{n}" for n in names]
    assert config.specs[1]["condition"] == second
    with pytest.raises(ConfigError, match="MIN ≤ MAX"):
        load_config(write(tmp_path, text.replace(f'"{bad[0]}"', f'"{bad[1]}"')))
