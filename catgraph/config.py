"""Experiment configurations: a TOML file that expands into run specs.

A benchmark is *datasets × methods × parameter values*. Writing every run by hand is
tedious and error-prone, so a configuration lists the datasets and the methods once and
:func:`load_config` expands them into the list of run specs that
:func:`catgraph.experiment.run_experiment` takes (see that module for the spec keys),
checking every key and value first so that a typo fails in a second, with the table and
key named, not an hour into a sweep.

Format
------
::

    name = "nordland"                    # optional: title of the sweep (default: file name)
    description = "..."                  # optional

    [[dataset]]
    name = "summer-winter"               # required, unique
    reference = "../../shared/data/nordland/32x16/summer"   # path or "synthetic:SEED"
    query = "../../shared/data/nordland/32x16/winter"
    tolerance = 2                        # ground truth: frames …
    # tolerance_m = 3.0                  # … or metres (exactly one; synthetic worlds: optional)
    shuffle = [false, 0]                 # optional: false = in order, int = shuffle seed
    frontend = { size = "32x16", patch = 4, metric = "sad", normalise = true }  # optional

    [[method]]
    name = "fixed"                       # optional, unique (default: the method)
    method = "sequence"                  # a name in catgraph.methods.METHODS
    params = { approximation = "gaussian" }      # passed to the method as is
    grid = { window = [10, 25, 50] }     # optional: every combination is one run
    datasets = ["summer-winter"]         # optional: only these datasets (default: all)

    [[run]]                              # optional: explicit runs, added after the grid
    name = "one-off"
    dataset = "summer-winter"            # inherit reference/query/ground truth/front-end …
    method = "single-frame"              # … or give reference, query, tolerance … here
    params = { exclusion = 5 }
    shuffle = 0

Every ``[[method]]`` runs on every dataset it applies to, for every ``shuffle`` value of
the dataset and every combination of its ``grid`` values (the Cartesian product, in the
order written). ``grid`` is separate from ``params`` because some parameters are lists
themselves (a histogram ``range``, a window ``grid``): ``params`` are never expanded.
TOML has no null, so ``false`` stands for "no shuffle".

Relative paths are relative to the configuration file's folder (so a configuration
works from any working directory); ``"synthetic:SEED"`` names the built-in world.

Run names
---------
Expanded runs are named ``DATASET/METHOD[/KEY=VALUE…][/in-order|/shuffle=SEED]`` (the
``shuffle`` part only when the dataset sets ``shuffle``), e.g.
``summer-winter/fixed/window=25/shuffle=0``. Names are unique; the bench command uses
them for the result files.

Checks
------
Unknown keys (with the closest known key suggested), wrong types, missing required
keys, duplicate names, unknown methods and unknown dataset references raise
:class:`~catgraph.exceptions.ConfigError` naming the file, the table and its number,
and the key, e.g. ``config.toml: [[method]] #2 'window' must be an int ≥ 1 or
'adaptive', got 'ten'``. Parameters with a well-known meaning (``window``,
``exclusion``, ``l_min`` …) are type-checked here; the method checks the rest.
"""

from __future__ import annotations

import copy
import difflib
import itertools
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .exceptions import ConfigError, DataNotFoundError

__all__ = ["ExperimentConfig", "load_config", "parse_config", "run_file_name"]

_TOP_KEYS = ("name", "description", "dataset", "method", "run")
_DATASET_KEYS = ("name", "reference", "query", "tolerance", "tolerance_m", "shuffle", "frontend")
_METHOD_KEYS = ("name", "method", "params", "grid", "datasets")
_RUN_KEYS = ("name", "dataset", "reference", "query", "tolerance", "tolerance_m", "shuffle", "frontend", "method",
             "params")
_FRONTEND_KEYS = ("size", "patch", "metric", "normalise")
_METRICS = ("sad", "ssd", "cosine", "hamming", "wifi")


@dataclass(frozen=True)
class ExperimentConfig:
    """An expanded experiment configuration.

    Attributes
    ----------
    name : str
        Title of the sweep (the ``name`` key, else the file name without suffix).
    description : str
    specs : list of dict
        Run specs for :func:`catgraph.experiment.run_experiment`, in order; each has a
        unique ``name``.
    source : str
        Where the configuration came from (a path, or ``"<config>"``).
    """

    name: str
    description: str
    specs: list[dict[str, Any]] = field(default_factory=list)
    source: str = "<config>"

    def __len__(self) -> int:
        return len(self.specs)


# ---------------------------------------------------------------------------- value checks
def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _int_at_least(low: int) -> tuple[Callable[[Any], bool], str]:
    return (lambda v: _is_int(v) and v >= low), f"an int ≥ {low}"


def _one_of(*choices: str) -> tuple[Callable[[Any], bool], str]:
    return (lambda v: v in choices), "one of " + ", ".join(repr(c) for c in choices)


#: Checks of well-known method parameters: name → (test, description).
PARAM_CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "window": (lambda v: v == "adaptive" or (_is_int(v) and v >= 1), "an int ≥ 1 or 'adaptive'"),
    "exclusion": _int_at_least(0),
    "radius": _int_at_least(0),
    "l_min": _int_at_least(1),
    "l_max": _int_at_least(1),
    "n_bins": _int_at_least(2),
    "n_init": _int_at_least(0),
    "n_particles": _int_at_least(1),
    "seed": (lambda v: _is_int(v) and v >= 0, "an int ≥ 0"),
    "approximation": _one_of("gaussian", "robust", "gmm2", "gmm3"),
    "grid": (lambda v: v in ("geometric", "all") or (_is_int(v) and v >= 1)
             or (isinstance(v, list) and bool(v) and all(_is_int(x) and x >= 1 for x in v)),
             "'geometric', 'all', an int ≥ 1 or a list of ints ≥ 1"),
}


class _Where:
    """Formats ``"FILE: [[TABLE]] #K"`` prefixes for messages."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, table: str, message: str) -> ConfigError:
        return ConfigError(f"{self.source}: {table} {message}")


def _check_keys(where: _Where, table: str, data: Mapping, allowed: tuple[str, ...],
                required: tuple[str, ...] = ()) -> None:
    if not isinstance(data, Mapping):
        raise where.error(table, f"must be a table, got {_show(data)}.")
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1, cutoff=0.6)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise where.error(table, f"has unknown key '{key}'; {hint}allowed keys: {', '.join(allowed)}.")
    for key in required:
        if key not in data:
            raise where.error(table, f"needs the key '{key}'.")


def _show(value: Any) -> str:
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list):
        return f"a list {value!r}" if len(repr(value)) < 60 else "a list"
    return repr(value)


def _check_value(where: _Where, table: str, key: str, value: Any, test: Callable[[Any], bool], what: str) -> None:
    if not test(value):
        raise where.error(table, f"'{key}' must be {what}, got {_show(value)}.")


def _check_name(where: _Where, table: str, value: Any) -> str:
    _check_value(where, table, "name", value, lambda v: isinstance(v, str) and v.strip() != "" and "/" not in v,
                 "a non-empty string without '/'")
    return value


def _check_params(where: _Where, table: str, params: Any, key: str = "params") -> dict:
    if not isinstance(params, Mapping):
        raise where.error(table, f"'{key}' must be a table of parameters, got {_show(params)}.")
    for name, value in params.items():
        if name in PARAM_CHECKS:
            test, what = PARAM_CHECKS[name]
            _check_value(where, table, name, value, test, what)
    return dict(params)


def _check_method_name(where: _Where, table: str, value: Any) -> str:
    from .methods import METHODS

    _check_value(where, table, "method", value, lambda v: isinstance(v, str), "a method name (string)")
    if value not in METHODS:
        close = difflib.get_close_matches(value, list(METHODS), n=1, cutoff=0.5)
        hint = f"did you mean '{close[0]}'? " if close else ""
        raise where.error(table, f"'method' {value!r} is not a known method; {hint}"
                                 f"known methods: {', '.join(sorted(METHODS))}.")
    return value


def _check_frontend(where: _Where, table: str, frontend: Any) -> dict:
    _check_keys(where, f"{table} frontend", frontend, _FRONTEND_KEYS)
    out: dict[str, Any] = {}
    if "size" in frontend:
        size = frontend["size"]
        if isinstance(size, str):
            parts = size.lower().split("x")
            if len(parts) == 2 and all(p.isdigit() and int(p) > 0 for p in parts):
                size = [int(parts[0]), int(parts[1])]
        _check_value(where, table, "frontend.size", size,
                     lambda v: isinstance(v, list) and len(v) == 2 and all(_is_int(x) and x > 0 for x in v),
                     "'WIDTHxHEIGHT' such as '32x16' or [width, height]")
        out["size"] = list(size)
    if "patch" in frontend:
        _check_value(where, table, "frontend.patch", frontend["patch"], lambda v: _is_int(v) and v >= 0,
                     "an int ≥ 0 (0 = no patch normalisation)")
        out["patch"] = frontend["patch"]
    if "metric" in frontend:
        _check_value(where, table, "frontend.metric", frontend["metric"], lambda v: v in _METRICS,
                     "one of " + ", ".join(repr(m) for m in _METRICS))
        out["metric"] = frontend["metric"]
    if "normalise" in frontend:
        _check_value(where, table, "frontend.normalise", frontend["normalise"], lambda v: isinstance(v, bool),
                     "true or false")
        out["normalise"] = frontend["normalise"]
    return out


def _check_shuffle_values(where: _Where, table: str, value: Any) -> list[int | None]:
    values = value if isinstance(value, list) else [value]
    ok = bool(values) and all(v is False or (_is_int(v) and v >= 0) for v in values)
    if not ok:
        raise where.error(table, f"'shuffle' must be false (in order), a seed ≥ 0, or a list of them, "
                                 f"got {_show(value)}.")
    out = [None if v is False else int(v) for v in values]
    if len(set(out)) != len(out):
        raise where.error(table, f"'shuffle' lists a value twice: {_show(value)}.")
    return out


def _resolve(path: Any, base_dir: Path | None) -> str:
    text = str(path)
    if text.startswith("synthetic"):
        return text
    p = Path(os.path.expanduser(text))
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return os.path.normpath(os.path.abspath(p)) if base_dir is not None else os.path.normpath(p)


def _check_source(where: _Where, table: str, data: Mapping, base_dir: Path | None) -> dict:
    """reference, query, ground truth and front-end of a dataset (or an explicit run)."""
    out: dict[str, Any] = {}
    for key in ("reference", "query"):
        value = data[key]
        _check_value(where, table, key, value, lambda v: isinstance(v, str) and v != "",
                     "a path or 'synthetic:SEED'")
        if value.startswith("synthetic"):
            _, _, seed = value.partition(":")
            if value != "synthetic" and (not value.startswith("synthetic:") or not seed.isdigit()):
                raise where.error(table, f"'{key}' {value!r} must be written 'synthetic:SEED' with an integer seed.")
        out[key] = _resolve(value, base_dir)
    tolerance, tolerance_m = data.get("tolerance"), data.get("tolerance_m")
    if tolerance is not None:
        _check_value(where, table, "tolerance", tolerance, lambda v: _is_int(v) and v >= 0, "an int ≥ 0 (frames)")
    if tolerance_m is not None:
        _check_value(where, table, "tolerance_m", tolerance_m, lambda v: _is_number(v) and v >= 0,
                     "a number ≥ 0 (metres)")
    if tolerance is not None and tolerance_m is not None:
        raise where.error(table, "gives both 'tolerance' (frames) and 'tolerance_m' (metres); keep one.")
    synthetic = out["reference"].startswith("synthetic") and out["query"].startswith("synthetic")
    if tolerance is None and tolerance_m is None and not synthetic:
        raise where.error(table, "needs a ground truth: 'tolerance' (frames, same index = same place) "
                                 "or 'tolerance_m' (metres, needs positions).")
    out["tolerance"] = tolerance
    out["tolerance_m"] = None if tolerance_m is None else float(tolerance_m)
    out["frontend"] = _check_frontend(where, table, data["frontend"]) if "frontend" in data else {}
    return out


def _format_value(value: Any) -> str:
    if isinstance(value, list):
        return ",".join(_format_value(v) for v in value)
    return str(value).replace("/", "-")


def run_file_name(name: str) -> str:
    """A file name (without suffix) for run ``name``: ``/`` becomes ``__``, and characters
    other than letters, digits and ``._=,+-`` become ``_``."""
    text = name.replace("/", "__")
    return "".join(c if c.isalnum() or c in "._=,+-" else "_" for c in text)


# ---------------------------------------------------------------------------- expansion
def parse_config(data: Mapping[str, Any], source: str = "<config>", base_dir: str | os.PathLike | None = None,
                 default_name: str = "sweep") -> ExperimentConfig:
    """Check a decoded configuration and expand it into run specs.

    Parameters
    ----------
    data : mapping
        The decoded TOML document (see the module docstring for its keys).
    source : str
        Name used in error messages (the file name).
    base_dir : path, optional
        Folder that relative paths are relative to; ``None`` leaves them as written.
    default_name : str
        Name of the sweep when ``data`` has none.

    Returns
    -------
    ExperimentConfig

    Raises
    ------
    ConfigError
        Unknown keys, wrong types, missing keys, duplicate names, unknown methods or
        datasets, or a configuration with no runs.
    """
    where = _Where(source)
    base = None if base_dir is None else Path(base_dir)
    _check_keys(where, "top level", data, _TOP_KEYS)
    for key in ("name", "description"):
        if key in data:
            _check_value(where, "top level", key, data[key], lambda v: isinstance(v, str), "a string")
    for key in ("dataset", "method", "run"):
        if key in data and not (isinstance(data[key], list) and all(isinstance(t, Mapping) for t in data[key])):
            raise where.error("top level", f"'{key}' must be an array of tables written [[{key}]], "
                                           f"got {_show(data[key])}.")

    datasets: dict[str, dict] = {}
    for k, table in enumerate(data.get("dataset", []), 1):
        label = f"[[dataset]] #{k}"
        _check_keys(where, label, table, _DATASET_KEYS, ("name", "reference", "query"))
        name = _check_name(where, label, table["name"])
        if name in datasets:
            raise where.error(label, f"repeats the dataset name {name!r}; dataset names must be unique.")
        entry = _check_source(where, label, table, base)
        entry["shuffle"] = _check_shuffle_values(where, label, table["shuffle"]) if "shuffle" in table else None
        datasets[name] = entry

    methods: list[dict] = []
    for k, table in enumerate(data.get("method", []), 1):
        label = f"[[method]] #{k}"
        _check_keys(where, label, table, _METHOD_KEYS, ("method",))
        method = _check_method_name(where, label, table["method"])
        name = _check_name(where, label, table.get("name", method))
        if any(m["name"] == name for m in methods):
            raise where.error(label, f"repeats the method name {name!r}; give each [[method]] a unique 'name'.")
        params = _check_params(where, label, table.get("params", {}))
        grid = table.get("grid", {})
        if not isinstance(grid, Mapping):
            raise where.error(label, f"'grid' must be a table of lists, got {_show(grid)}.")
        for key, values in grid.items():
            if not isinstance(values, list) or not values:
                raise where.error(label, f"'grid.{key}' must be a non-empty list of values, got {_show(values)}.")
            if key in params:
                raise where.error(label, f"sets '{key}' in both 'params' and 'grid'; keep one.")
            for value in values:
                _check_params(where, label, {key: value})
        only = table.get("datasets")
        if only is not None:
            _check_value(where, label, "datasets", only,
                         lambda v: isinstance(v, list) and bool(v) and all(isinstance(x, str) for x in v),
                         "a non-empty list of dataset names")
            for ds in only:
                if ds not in datasets:
                    raise where.error(label, f"'datasets' names {ds!r}, which no [[dataset]] defines; "
                                             f"defined: {', '.join(datasets) or 'none'}.")
        methods.append({"name": name, "method": method, "params": params, "grid": dict(grid), "datasets": only})

    specs: list[dict[str, Any]] = []
    for ds_name, ds in datasets.items():
        for m in methods:
            if m["datasets"] is not None and ds_name not in m["datasets"]:
                continue
            keys = list(m["grid"])
            for values in itertools.product(*(m["grid"][key] for key in keys)):
                params = dict(m["params"])
                params.update(zip(keys, values))
                for shuffle in ds["shuffle"] if ds["shuffle"] is not None else [None]:
                    parts = [ds_name, m["name"]] + [f"{key}={_format_value(v)}" for key, v in zip(keys, values)]
                    if ds["shuffle"] is not None:
                        parts.append("in-order" if shuffle is None else f"shuffle={shuffle}")
                    specs.append({
                        "name": "/".join(parts), "reference": ds["reference"], "query": ds["query"],
                        "method": m["method"], "params": copy.deepcopy(params), "tolerance": ds["tolerance"],
                        "tolerance_m": ds["tolerance_m"], "shuffle": shuffle, "frontend": dict(ds["frontend"]),
                    })

    for k, table in enumerate(data.get("run", []), 1):
        label = f"[[run]] #{k}"
        _check_keys(where, label, table, _RUN_KEYS, ("method",))
        method = _check_method_name(where, label, table["method"])
        if "dataset" in table:
            ds_name = table["dataset"]
            if ds_name not in datasets:
                raise where.error(label, f"'dataset' names {ds_name!r}, which no [[dataset]] defines; "
                                         f"defined: {', '.join(datasets) or 'none'}.")
            overlap = [key for key in ("reference", "query", "tolerance", "tolerance_m") if key in table]
            if overlap:
                raise where.error(label, f"sets 'dataset' and {', '.join(repr(x) for x in overlap)}; "
                                         "use one or the other.")
            source = {key: datasets[ds_name][key] for key in ("reference", "query", "tolerance", "tolerance_m")}
            source["frontend"] = (_check_frontend(where, label, table["frontend"]) if "frontend" in table
                                  else dict(datasets[ds_name]["frontend"]))
        else:
            for key in ("reference", "query"):
                if key not in table:
                    raise where.error(label, f"needs the key '{key}' (or 'dataset' naming a [[dataset]]).")
            source = _check_source(where, label, table, base)
        shuffle = None
        if "shuffle" in table:
            if isinstance(table["shuffle"], list):
                raise where.error(label, "'shuffle' of a [[run]] is one value (false or a seed), not a list.")
            (shuffle,) = _check_shuffle_values(where, label, table["shuffle"])
        name = _check_name(where, label, table["name"]) if "name" in table else f"{method}#{k}"
        params = copy.deepcopy(_check_params(where, label, table.get("params", {})))
        specs.append({"name": name, "reference": source["reference"], "query": source["query"], "method": method,
                      "params": params, "tolerance": source["tolerance"], "tolerance_m": source["tolerance_m"],
                      "shuffle": shuffle, "frontend": source["frontend"]})

    seen: set[str] = set()
    for spec in specs:
        file_name = run_file_name(spec["name"])  # names that differ only in odd characters collide as files
        if file_name in seen:
            raise ConfigError(f"{source}: two runs are named {spec['name']!r}; give the [[run]] or [[method]] "
                              "tables unique names.")
        seen.add(file_name)
    if not specs:
        raise ConfigError(f"{source}: the configuration defines no runs; add [[dataset]] and [[method]] tables "
                          "or [[run]] tables.")
    return ExperimentConfig(str(data.get("name", default_name)), str(data.get("description", "")), specs, source)


def load_config(path: str | os.PathLike) -> ExperimentConfig:
    """Read a TOML experiment configuration and expand it into run specs.

    Relative paths in it are taken relative to the file's folder.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    ExperimentConfig

    Raises
    ------
    DataNotFoundError
        The file does not exist.
    ConfigError
        It is not valid TOML, or fails a check (see :func:`parse_config`).
    """
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"configuration file {path} does not exist"
                                + ("" if not path.exists() else " (it is a folder)") + "; give a .toml file.")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path.name}: not valid TOML: {exc}.") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path.name}: not a UTF-8 text file ({exc}).") from None
    return parse_config(data, source=path.name, base_dir=path.parent, default_name=path.stem)
