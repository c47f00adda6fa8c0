"""What a result records about the run that made it (:mod:`catgraph.environment`), and
``catgraph info``: the versions read from the installed packages, the compile target that
decides the last bits of the kernels' sums (``NUMBA_CPU_NAME`` where set), every result file
carrying them, and the command printing them."""

import json

import numpy as np
import numba

import catgraph
from catgraph import environment as env
from catgraph.cli.main import main

from .conftest import write_images


def test_the_environment_names_the_installed_versions():
    out = env.environment()
    assert out["catgraph"] == catgraph.__version__
    assert out["numpy"] == np.__version__ and out["numba"] == numba.__version__
    assert set(env.DEPENDENCIES) <= set(out) and {"python", "platform", "processor", "cores", "compiled_for"} <= set(out)
    assert env._version("no-such-package-catgraph-test") is None  # an optional one not installed
    json.dumps(out)  # JSON-ready as it is


def test_each_call_gives_a_dict_of_its_own():
    first = env.environment()
    first["numpy"] = "changed"
    assert env.environment()["numpy"] == np.__version__


def test_the_compile_target_is_numba_cpu_name_where_set(monkeypatch):
    import llvmlite.binding as llvm

    monkeypatch.delenv("NUMBA_CPU_NAME", raising=False)
    assert env.compile_target() == llvm.get_host_cpu_name()
    monkeypatch.setenv("NUMBA_CPU_NAME", "skylake-avx512")
    assert env.compile_target() == "skylake-avx512"


def test_the_processor_without_proc_cpuinfo(monkeypatch, tmp_path):
    monkeypatch.setattr(env, "Path", lambda _: tmp_path / "no-cpuinfo")
    monkeypatch.setattr(env.platform, "processor", lambda: "")
    assert env.processor() == env.platform.machine()
    (tmp_path / "cpuinfo").write_text("processor\t: 0\nmodel name\t:  Some   CPU  9000\n")
    monkeypatch.setattr(env, "Path", lambda _: tmp_path / "cpuinfo")
    assert env.processor() == "Some CPU 9000"


def test_a_result_file_records_the_environment(tmp_path):
    rng = np.random.default_rng(2)
    base = rng.integers(0, 255, (30, 8, 16))
    ref, qry = write_images(tmp_path / "ref", base), write_images(tmp_path / "qry", base)
    out = tmp_path / "r.json"
    assert main(["match", str(ref), str(qry), "--window", "1", "--tolerance", "1", "--output", str(out), "-q"]) == 0
    recorded = json.loads(out.read_text())["environment"]
    assert recorded == json.loads(json.dumps(env.environment()))


def test_info_prints_the_environment_and_the_kernel_cache(capsys):
    assert main(["info", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["catgraph"] == catgraph.__version__ and out["compiled_for"] == env.compile_target()
    assert out["kernel_cache"]
    assert main(["info"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.split()[0] == "compiled_for" for line in lines)
    assert len(lines) == len(out)


def test_info_says_which_optional_package_is_not_installed(monkeypatch, capsys):
    real = env._version
    monkeypatch.setattr(env, "_version", lambda name: None if name == "av" else real(name))
    env._environment.cache_clear()
    try:
        assert main(["info"]) == 0
        line = next(line for line in capsys.readouterr().out.splitlines() if line.split()[0] == "av")
        assert line.endswith("not installed")
    finally:
        env._environment.cache_clear()
