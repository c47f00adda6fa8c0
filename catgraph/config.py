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
    reference = "../../shared/data/nordland/32x16/summer"   # path or "synthetic:SEED" …
    # map = "summer.npz"                 # … or a saved map (catgraph build-map)
    query = "../../shared/data/nordland/32x16/winter"
    tolerance = 2                        # optional ground truth: frames …
    # tolerance_m = 3.0                  # … or metres …
    # ground_truth = "pairs.csv"         # … or a file (at most one; none: no metrics)
    conditions = ["in-order", "shuffle:0", "shuffle:1:0.005:0.03", "reverse", "speed:2"]  # optional
    # shuffle = [false, 0]               # optional shorthand: false = in order, int = shuffle seed
    frontend = { size = "32x16", patch = 4, metric = "sad", normalise = true }  # optional; also crop = [0, 4, 0, 0]
    # junction_radius_m = 1.0            # optional: junctions of the place graph (needs positions)

    [[method]]
    name = "fixed"                       # optional, unique (default: the method)
    method = "sequence"                  # a name in catgraph.methods.METHODS
    params = { approximation = "gaussian" }      # checked against the method's parameters
    grid = { window = [10, 25, 50] }     # optional: every combination is one run
    datasets = ["summer-winter"]         # optional: only these datasets (default: all)

    [[run]]                              # optional: explicit runs, added after the grid
    name = "one-off"
    dataset = "summer-winter"            # inherit reference/query/ground truth/front-end …
    method = "single-frame"              # … or give reference, query, tolerance … here
    params = { exclusion = 5 }
    shuffle = 0

Every ``[[method]]`` runs on every dataset it applies to, for every condition of the
dataset (:meth:`catgraph.conditions.Condition.parse`: ``in-order``, ``reverse``,
``speed:FACTOR``, ``shuffle:SEED``, ``shuffle:SEED:MIN:MAX``, ``vary:SEED``,
``vary:SEED:SLOWEST:FASTEST``, ``stop:SEED`` or ``stop:SEED:MIN:MAX``) and every combination of
its ``grid`` values (the Cartesian product, in the order written). ``grid`` is separate
from ``params`` because some parameters are lists themselves (a window ``grid``):
``params`` are never expanded. TOML has no null, so ``false`` stands for "no shuffle".

Relative paths are relative to the configuration file's folder (so a configuration
works from any working directory); ``"synthetic:SEED"`` names the built-in world.

Run names
---------
Expanded runs are named ``DATASET/METHOD[/KEY=VALUE…][/CONDITION]`` (the condition part
— ``in-order``, ``shuffle=SEED``, ``shuffle=SEED,MIN-MAX``, ``reverse``, ``speed=F``,
``vary=SEED,SLOWEST-FASTEST``, ``stop=SEED,MIN-MAX`` — only
when the dataset lists ``conditions`` or ``shuffle``), e.g.
``summer-winter/fixed/window=25/shuffle=0``. Names are unique; the bench command uses
them for the result files.

Checks
------
Unknown keys (with the closest known key suggested), wrong types, missing required
keys, duplicate names, unknown methods and unknown dataset references raise
:class:`~catgraph.exceptions.ConfigError` naming the file, the table and its number,
and the key, e.g. ``config.toml: [[method]] #2: The 'window' parameter of method
'sequence' must be an int ≥ 1 or 'adaptive'. Got 'ten' instead.`` Method parameters are
checked against the method's own declarations (:mod:`catgraph.methods`), every grid
combination included, so a sweep never fails an hour in on a value it could have
refused at once.
"""

from __future__ import annotations

import copy
import difflib
import itertools
import math
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .conditions import SEGMENT_RANGE, Condition
from .exceptions import ConfigError, DataNotFoundError

__all__ = ["ExperimentConfig", "load_config", "parse_config", "run_file_name"]

_TOP_KEYS = ("name", "description", "dataset", "method", "run")
_SOURCE_KEYS = ("reference", "map", "query", "tolerance", "tolerance_m", "ground_truth", "frontend",
                "junction_radius_m")
_DATASET_KEYS = ("name", *_SOURCE_KEYS, "shuffle", "conditions")
_METHOD_KEYS = ("name", "method", "params", "grid", "datasets")
_RUN_KEYS = ("name", "dataset", *_SOURCE_KEYS, "shuffle", "condition", "method", "params")


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


def _check_params(where: _Where, table: str, method: str, params: Any, key: str = "params") -> dict:
    """The method's own checks (:meth:`catgraph.methods.Method.resolve`), located in the file."""
    from .exceptions import InvalidParameterError
    from .methods import get_method

    if not isinstance(params, Mapping):
        raise where.error(table, f"'{key}' must be a table of parameters, got {_show(params)}.")
    try:
        get_method(method).resolve(params)
    except InvalidParameterError as exc:
        raise where.error(table, f"{exc}") from None
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
    from .exceptions import InvalidParameterError
    from .pipeline import FrontEnd

    _check_keys(where, f"{table} frontend", frontend, FrontEnd.KEYS)
    try:
        checked = FrontEnd.from_dict(frontend)
    except InvalidParameterError as exc:
        raise where.error(table, f"'frontend': {exc}") from None
    return {k: v for k, v in checked.as_dict().items() if k in frontend}


def _check_shuffle_values(where: _Where, table: str, value: Any) -> list[dict]:
    values = value if isinstance(value, list) else [value]
    ok = bool(values) and all(v is False or (_is_int(v) and v >= 0) for v in values)
    if not ok:
        raise where.error(table, f"'shuffle' must be false (in order), a seed ≥ 0, or a list of them, "
                                 f"got {_show(value)}.")
    if len({repr(v) for v in values}) != len(values):
        raise where.error(table, f"'shuffle' lists a value twice: {_show(value)}.")
    return [Condition().as_dict() if v is False else Condition("shuffle", seed=int(v)).as_dict() for v in values]


def _check_conditions(where: _Where, table: str, value: Any, key: str = "conditions") -> list[dict]:
    from .exceptions import InvalidParameterError

    values = value if isinstance(value, list) else [value]
    if not values or not all(isinstance(v, str) for v in values):
        raise where.error(table, f"'{key}' must be a list of conditions such as \"in-order\", \"reverse\", "
                                 f"\"speed:2\", \"shuffle:0\", \"shuffle:0:0.005:0.03\", \"vary:0\" or \"stop:0\", got "
                                 f"{_show(value)}.")
    try:
        out = [Condition.parse(v).as_dict() for v in values]
    except InvalidParameterError as exc:
        raise where.error(table, f"'{key}': {exc}") from None
    if len({repr(c) for c in out}) != len(out):
        raise where.error(table, f"'{key}' lists a condition twice: {_show(value)}.")
    # conditions that drive the query alike (speed 1 is the query in order) or whose runs would
    # share a name (speeds equal to the digits a name shows) would be one run twice
    same: dict[str, str] = {}
    for text, condition in zip(values, out):
        c = Condition.from_dict(condition)
        name = "in-order" if c.kind == "speed" and c.factor == 1.0 else _condition_name(condition)
        if name in same:
            raise where.error(table, f"'{key}' lists {same[name]!r} and {text!r}, which give the same runs "
                                     f"({name}); keep one.")
        same[name] = text
    return out


def _condition_name(condition: dict) -> str:
    c = Condition.from_dict(condition)
    if c.kind == "shuffle":
        lo, hi = c.segment_range
        return f"shuffle={c.seed}" if (lo, hi) == SEGMENT_RANGE else f"shuffle={c.seed},{lo:g}-{hi:g}"
    if c.kind == "speed":
        return f"speed={c.factor:g}"
    if c.kind == "vary":
        (lo, hi), (s_lo, s_hi) = c.speed_range, c.segment_range
        stretches = "" if (s_lo, s_hi) == SEGMENT_RANGE else f",{s_lo:g}-{s_hi:g}"
        return f"vary={c.seed},{lo:g}-{hi:g}{stretches}"
    if c.kind == "stop":
        (lo, hi), (s_lo, s_hi) = c.stop_frames, c.segment_range
        stretches = "" if (s_lo, s_hi) == SEGMENT_RANGE else f",{s_lo:g}-{s_hi:g}"
        return f"stop={c.seed},{lo}-{hi}{stretches}"
    return c.kind


def _is_synthetic(text: str) -> bool:
    """:func:`catgraph.experiment.is_synthetic_name` (imported where read: the experiment
    layer is heavier than a configuration check)."""
    from .experiment import is_synthetic_name

    return is_synthetic_name(text)


def _resolve(path: Any, base_dir: Path | None) -> str:
    text = str(path)
    if _is_synthetic(text):
        return text
    p = Path(os.path.expanduser(text))
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return os.path.normpath(os.path.abspath(p)) if base_dir is not None else os.path.normpath(p)




def _check_source(where: _Where, table: str, data: Mapping, base_dir: Path | None) -> dict:
    """Reference or map, query, ground truth, front-end and graph options of a dataset (or run)."""
    out: dict[str, Any] = {}
    if ("reference" in data) == ("map" in data):
        raise where.error(table, "needs exactly one of 'reference' (a traverse) and 'map' (a saved map).")
    if "query" not in data:
        raise where.error(table, "needs the key 'query'.")
    for key in ("reference", "map", "query"):
        if key not in data:
            continue
        value = data[key]
        _check_value(where, table, key, value, lambda v: isinstance(v, str) and v != "",
                     "a path or 'synthetic:SEED'" if key != "map" else "a path to a map file")
        if _is_synthetic(value) and key != "map":
            _, _, seed = value.partition(":")
            if value != "synthetic" and not seed.isdigit():
                raise where.error(table, f"'{key}' {value!r} must be written 'synthetic:SEED' with an integer seed.")
        out[key] = _resolve(value, base_dir)
    given = [k for k in ("tolerance", "tolerance_m", "ground_truth") if data.get(k) is not None]
    if len(given) > 1:
        raise where.error(table, f"gives {' and '.join(repr(g) for g in given)}; keep one ground truth.")
    if "tolerance" in data:
        _check_value(where, table, "tolerance", data["tolerance"], lambda v: _is_int(v) and v >= 0,
                     "an int ≥ 0 (frames)")
        out["tolerance"] = data["tolerance"]
    if "tolerance_m" in data:
        _check_value(where, table, "tolerance_m", data["tolerance_m"], lambda v: _is_number(v) and 0 <= v < math.inf,
                     "a number ≥ 0 (metres)")
        out["tolerance_m"] = float(data["tolerance_m"])
    if "ground_truth" in data:
        _check_value(where, table, "ground_truth", data["ground_truth"], lambda v: isinstance(v, str) and v != "",
                     "a path to a pairs .csv or a .npy/.npz matrix")
        out["ground_truth"] = _resolve(data["ground_truth"], base_dir)
    if "frontend" in data:
        if "map" in data:
            raise where.error(table, "sets 'frontend' with a saved 'map': its front-end is fixed when it is built.")
        out["frontend"] = _check_frontend(where, table, data["frontend"])
    if "junction_radius_m" in data:
        if "map" in data:
            raise where.error(table, "sets 'junction_radius_m' with a saved 'map': its graph is fixed when it is built.")
        _check_value(where, table, "junction_radius_m", data["junction_radius_m"],
                     lambda v: _is_number(v) and 0 < v < math.inf,
                     "a number > 0 (metres)")
        out["junction_radius_m"] = float(data["junction_radius_m"])
    return out


def _conditions_of(where: _Where, table: str, data: Mapping) -> list[dict] | None:
    if "shuffle" in data and "conditions" in data:
        raise where.error(table, "sets both 'shuffle' and 'conditions'; list shuffles in 'conditions' "
                                 "(\"shuffle:SEED\").")
    if "shuffle" in data:
        return _check_shuffle_values(where, table, data["shuffle"])
    if "conditions" in data:
        return _check_conditions(where, table, data["conditions"])
    return None


def _format_value(value: Any) -> str:
    if isinstance(value, list):
        return ",".join(_format_value(v) for v in value)
    return str(value).replace("/", "-")


def run_file_name(name: str) -> str:
    """A file name (without suffix) for run ``name``: ``/`` becomes ``__``, and characters
    other than letters, digits and ``._=,+-`` become ``_``."""
    text = name.replace("/", "__")
    text = "".join(c if c.isalnum() or c in "._=,+-" else "_" for c in text)
    return text if text.strip(".") else f"_{text}"  # never empty, "." or "..": a name, not a folder


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
        _check_keys(where, label, table, _DATASET_KEYS, ("name",))
        name = _check_name(where, label, table["name"])
        if name in datasets:
            raise where.error(label, f"repeats the dataset name {name!r}; dataset names must be unique.")
        entry = _check_source(where, label, table, base)
        entry["conditions"] = _conditions_of(where, label, table)
        datasets[name] = entry

    methods: list[dict] = []
    for k, table in enumerate(data.get("method", []), 1):
        label = f"[[method]] #{k}"
        _check_keys(where, label, table, _METHOD_KEYS, ("method",))
        method = _check_method_name(where, label, table["method"])
        name = _check_name(where, label, table.get("name", method))
        if any(m["name"] == name for m in methods):
            raise where.error(label, f"repeats the method name {name!r}; give each [[method]] a unique 'name'.")
        params = _check_params(where, label, method, table.get("params", {}))
        grid = table.get("grid", {})
        if not isinstance(grid, Mapping):
            raise where.error(label, f"'grid' must be a table of lists, got {_show(grid)}.")
        for key, values in grid.items():
            if not isinstance(values, list) or not values:
                raise where.error(label, f"'grid.{key}' must be a non-empty list of values, got {_show(values)}.")
            if key in params:
                raise where.error(label, f"sets '{key}' in both 'params' and 'grid'; keep one.")
        keys = list(grid)
        for values in itertools.product(*(grid[key] for key in keys)):
            _check_params(where, label, method, {**params, **dict(zip(keys, values))})
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

    def spec(name: str, source: dict, method: str, params: dict, condition: dict | None) -> dict:
        out = {"name": name, **copy.deepcopy(source), "method": method, "params": copy.deepcopy(params)}
        out.pop("conditions", None)
        out["condition"] = condition or Condition().as_dict()
        return out

    specs: list[dict[str, Any]] = []
    for ds_name, ds in datasets.items():
        for m in methods:
            if m["datasets"] is not None and ds_name not in m["datasets"]:
                continue
            keys = list(m["grid"])
            for values in itertools.product(*(m["grid"][key] for key in keys)):
                params = dict(m["params"])
                params.update(zip(keys, values))
                for condition in ds["conditions"] if ds["conditions"] is not None else [None]:
                    parts = [ds_name, m["name"]] + [f"{key}={_format_value(v)}" for key, v in zip(keys, values)]
                    if ds["conditions"] is not None:
                        parts.append(_condition_name(condition))
                    specs.append(spec("/".join(parts), ds, m["method"], params, condition))

    for k, table in enumerate(data.get("run", []), 1):
        label = f"[[run]] #{k}"
        _check_keys(where, label, table, _RUN_KEYS, ("method",))
        method = _check_method_name(where, label, table["method"])
        if "dataset" in table:
            ds_name = table["dataset"]
            if not isinstance(ds_name, str):
                raise where.error(label, f"'dataset' must be the name of one [[dataset]] (a string); got {ds_name!r}.")
            if ds_name not in datasets:
                raise where.error(label, f"'dataset' names {ds_name!r}, which no [[dataset]] defines; "
                                         f"defined: {', '.join(datasets) or 'none'}.")
            overlap = [key for key in _SOURCE_KEYS if key in table and key != "frontend"]
            if overlap:
                raise where.error(label, f"sets 'dataset' and {', '.join(repr(x) for x in overlap)}; "
                                         "use one or the other.")
            inputs = {k: v for k, v in datasets[ds_name].items() if k != "conditions"}
            if "frontend" in table:
                inputs["frontend"] = _check_frontend(where, label, table["frontend"])
        else:
            inputs = _check_source(where, label, table, base)
        if "shuffle" in table and "condition" in table:
            raise where.error(label, "sets both 'shuffle' and 'condition'; keep 'condition'.")
        condition = None
        if "shuffle" in table:
            if isinstance(table["shuffle"], list):
                raise where.error(label, "'shuffle' of a [[run]] is one value (false or a seed), not a list.")
            (condition,) = _check_shuffle_values(where, label, table["shuffle"])
        if "condition" in table:
            if isinstance(table["condition"], list):
                raise where.error(label, "'condition' of a [[run]] is one condition, not a list.")
            (condition,) = _check_conditions(where, label, table["condition"], key="condition")
        name = _check_name(where, label, table["name"]) if "name" in table else f"{method}#{k}"
        params = _check_params(where, label, method, table.get("params", {}))
        specs.append(spec(name, inputs, method, params, condition))

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
