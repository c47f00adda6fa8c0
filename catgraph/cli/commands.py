"""Sub-commands. Each ``register_*`` adds a parser; each ``cmd_*`` runs one.

The evaluating commands (``match``, ``localize``, ``compare``) only translate their
options into a :class:`catgraph.experiment.Experiment` and call the experiment layer.
Method options are generated from the method registry (:mod:`catgraph.methods`): their
names, types, ranges, choices and help exist there once. An option is passed on only
when the user gives it, so an option that does not apply to the chosen method is an
error, never silently ignored.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..exceptions import InvalidParameterError

REGISTRY = []

# modules that add sub-commands with ``@register`` when imported
COMMAND_MODULES = ("report_cmd", "map_cmd", "bench_cmd", "warmup_cmd", "info_cmd")


def register(fn):
    """Decorator: ``fn(subparsers)`` adds one sub-command."""
    if fn not in REGISTRY:
        REGISTRY.append(fn)
    return fn


def load_command_modules() -> None:
    import importlib

    for name in COMMAND_MODULES:
        importlib.import_module(f"{__package__}.{name}")


# ---------------------------------------------------------------------------- option types
#: The largest magnitude an integer option takes (int64, what the kernels index with).
_INT_LIMIT = 2 ** 63 - 1


def _int(text: str) -> int:
    """An integer option's value; one that no int64 holds is refused here, where its option is named."""
    value = int(text)
    if abs(value) > _INT_LIMIT:
        raise argparse.ArgumentTypeError(f"expected an integer of at most {_INT_LIMIT} in magnitude, got {text!r}")
    return value


def folder(text: str) -> Path:
    """An output folder option's value: a name, never empty (``Path("")`` would be the
    working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return Path(text)


#: ``--fps``'s help, one text for every command that reads a video
FPS_HELP = ("video inputs: frames kept per second, by the frames' timestamps (default: every frame); a map keeps it "
            "and reads a video query at the same rate")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        size = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 32x16, got {text!r}") from None
    if not all(0 < v <= 100_000 for v in size):
        raise argparse.ArgumentTypeError(f"width and height must be in [1, 100000] pixels, got {text!r}")
    return size


def _crop(text: str) -> tuple[int, int, int, int]:
    try:
        crop = tuple(_int(v) for v in text.split(","))
    except ValueError:
        crop = ()
    if len(crop) != 4 or not all(0 <= v <= 100_000 for v in crop):
        raise argparse.ArgumentTypeError(f"expected TOP,BOTTOM,LEFT,RIGHT pixels to cut, each in [0, 100000], such as "
                                         f"0,4,0,0; got {text!r}")
    return crop


def _window(text: str):
    if text == "adaptive":
        return text
    try:
        return _int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of frames or 'adaptive', got {text!r}") from None


def _grid(text: str):
    if text in ("geometric", "all"):
        return text
    try:
        values = [_int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'geometric', 'all', a count or a list such as 10,20,50; "
                                         f"got {text!r}") from None
    return values[0] if len(values) == 1 else values


def _number(kind):
    def parse(text: str):
        try:
            return _int(text) if kind is int else kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None

    parse.__name__ = kind.__name__
    return parse


def _range(what: str):
    """An argparse type: two numbers ``A:B`` (``what`` names them in the error)."""
    def parse(text: str) -> tuple[float, float]:
        try:
            lo, hi = (float(v) for v in text.split(":"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        return lo, hi

    return parse


_segment_range = _range("MIN:MAX fractions of the query such as 0.02:0.2")


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas such as -1,1,2; got {text!r}") from None


_TYPES = {"int": _number(int), "float": _number(float), "window": _window, "grid": _grid, "floats": _floats}


def add_method_options(p: argparse.ArgumentParser, methods: tuple[str, ...], skip: tuple[str, ...] = (),
                       shown_defaults: dict[str, str] | None = None) -> None:
    """One option per parameter of ``methods`` (each once), from the registry's declarations;
    ``shown_defaults``: the default a command's help gives instead of the declared one, where
    the command's own choice of method decides it (``match``: no ``--window``, one frame)."""
    shown_defaults = shown_defaults or {}
    from ..methods import METHODS

    group = p.add_argument_group("method options")
    seen = set(skip)
    for method in methods:
        for param in METHODS[method].params:
            if param.name in seen:
                continue
            seen.add(param.name)
            default = shown_defaults.get(param.name, param.default)
            help_text = param.help + ("" if default is None else f" (default {default})")
            kwargs = {"dest": f"param_{param.name}", "default": argparse.SUPPRESS, "help": help_text}
            if param.kind == "bool":
                group.add_argument(param.option, action=argparse.BooleanOptionalAction, **kwargs)
                continue
            if param.choices:
                kwargs["choices"] = param.choices
            else:
                kwargs["type"] = _TYPES.get(param.kind, str)
                kwargs["metavar"] = param.name.upper()
            group.add_argument(param.option, **kwargs)


def method_params(args, method: str) -> dict:
    """The method options the user gave, checked against ``method``'s declarations."""
    from ..methods import METHODS

    m = METHODS[method]
    known = {p.name: p for p in m.params}
    out = {}
    for key, value in vars(args).items():
        if not key.startswith("param_"):
            continue
        name = key[len("param_"):]
        if name not in known:
            flag = _flag_of(name)
            raise InvalidParameterError(f"{flag} does not apply to {_method_words(method)}.")
        out[name] = known[name].check(value, method, label=known[name].option)
    return out


def _flag_of(name: str) -> str:
    from ..methods import METHODS

    for m in METHODS.values():
        for p in m.params:
            if p.name == name:
                return p.option
    return "--" + name.replace("_", "-")


def _method_words(method: str) -> str:
    return {"single-frame": "single-frame matching (--window 1)", "sequence": "sequence matching",
            "histogram": "the histogram model (--model histogram)", "filter": "the particle filter"}.get(method, method)


# ---------------------------------------------------------------------------- inputs
_USAGE = "%(prog)s [options] REFERENCE QUERY\n       %(prog)s [options] --map MAP QUERY"


def add_common_inputs(p: argparse.ArgumentParser, graph_options: bool = False) -> None:
    """Inputs, ground truth, traversal condition, front-end and output options."""
    from ..differences import METRICS

    p.add_argument("inputs", nargs="+", metavar="REFERENCE QUERY",
                   help="reference and query traverses: image folders, video files, UJI prefixes (db/01/trn01), "
                        ".npy/.npz files or synthetic:SEED; with --map, only QUERY")
    p.add_argument("--map", type=Path, metavar="MAP", help="a saved map (catgraph build-map) as the reference")
    gt = p.add_argument_group("ground truth (optional: without it, frames are written and metrics are null)")
    one = gt.add_mutually_exclusive_group()
    one.add_argument("--tolerance", type=_number(int), metavar="FRAMES", help="same index ± FRAMES is the same place")
    one.add_argument("--tolerance-m", type=_number(float), metavar="METRES",
                     help="positions within METRES (and the same floor) are the same place")
    one.add_argument("--ground-truth", type=Path, metavar="FILE",
                     help="a CSV of query,reference index pairs, or a .npy/.npz (n_query, n_reference) matrix")
    cond = p.add_argument_group("traversal condition of the query")
    how = cond.add_mutually_exclusive_group()
    how.add_argument("--shuffle", type=_number(int), metavar="SEED",
                     help="cut the query into segments and reorder them at random (seeded)")
    how.add_argument("--reverse", action="store_true", help="drive the query backwards")
    how.add_argument("--speed", type=_number(float), metavar="FACTOR",
                     help="FACTOR times the recorded speed: 2 keeps every second frame, 0.5 shows each twice")
    how.add_argument("--vary", type=_number(int), metavar="SEED",
                     help="drive the query at a speed that changes all the time (seeded; see --speed-range)")
    how.add_argument("--stop", type=_number(int), metavar="SEED",
                     help="drive the query in order, stopping now and then (seeded; see --stop-frames)")
    cond.add_argument("--segment-range", type=_segment_range, metavar="MIN:MAX",
                      help="--shuffle segment lengths, the stretches over which --vary moves from one speed to the "
                           "next, or the stretches --stop drives between stops, as fractions of the query "
                           "(default 0.02:0.2)")
    cond.add_argument("--speed-range", type=_range("SLOWEST:FASTEST speeds such as 0.5:2"), metavar="SLOWEST:FASTEST",
                      help="the speeds --vary draws from, times the recorded speed (default 0.5:2)")
    cond.add_argument("--stop-frames", type=_range("MIN:MAX frames such as 5:50"), metavar="MIN:MAX",
                      help="how long each --stop lasts, in frames (default 5:50)")
    fe = p.add_argument_group("front-end (when the map is built from REFERENCE)")
    fe.add_argument("--size", type=_size, metavar="WxH", help="resize images to WxH before patch normalisation")
    fe.add_argument("--patch", type=_number(int), metavar="PIXELS",
                    help="patch-normalisation patch side in pixels (0 = off; default 4)")
    fe.add_argument("--crop", type=_crop, metavar="T,B,L,R",
                    help="cut T, B, L and R pixels from the images' top, bottom, left and right before resizing")
    fe.add_argument("--metric", choices=METRICS, help="difference metric (default: by data kind)")
    fe.add_argument("--fps", type=_number(float), metavar="F", help=FPS_HELP)
    if graph_options:
        fe.add_argument("--junction-radius-m", type=_number(float), metavar="METRES",
                        help="join places of different parts of the route within METRES (needs positions)")
    p.add_argument("--output", "-o", type=Path, metavar="FILE", help="write the result JSON here")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars or messages (the table is printed)")


def condition_from(args):
    from ..conditions import Condition

    from ..conditions import SEGMENT_RANGE, STOP_FRAMES, VARY_SPEEDS

    if args.segment_range is not None and args.shuffle is None and args.vary is None and args.stop is None:
        raise InvalidParameterError("--segment-range sets the shuffle's segments, the varying speed's stretches or "
                                    "the stretches between stops; add --shuffle SEED, --vary SEED or --stop SEED.")
    if args.speed_range is not None and args.vary is None:
        raise InvalidParameterError("--speed-range sets the speeds of a varying speed; add --vary SEED.")
    if args.stop_frames is not None and args.stop is None:
        raise InvalidParameterError("--stop-frames sets how long the query stops; add --stop SEED.")
    if args.shuffle is not None:
        return Condition("shuffle", seed=args.shuffle, segment_range=args.segment_range or SEGMENT_RANGE)
    if args.vary is not None:
        return Condition("vary", seed=args.vary, segment_range=args.segment_range or SEGMENT_RANGE,
                         speed_range=args.speed_range or VARY_SPEEDS)
    if args.stop is not None:
        return Condition("stop", seed=args.stop, segment_range=args.segment_range or SEGMENT_RANGE,
                         stop_frames=args.stop_frames or STOP_FRAMES)
    if args.reverse:
        return Condition("reverse")
    if args.speed is not None:
        return Condition("speed", factor=args.speed)
    return Condition()


def experiment_from(args, method: str, params: dict):
    """The :class:`~catgraph.experiment.Experiment` the options describe."""
    from ..experiment import Experiment

    expected = 1 if args.map is not None else 2
    if len(args.inputs) != expected:
        raise InvalidParameterError(
            f"with --map give only QUERY (got {len(args.inputs)} paths)." if args.map is not None else
            f"give REFERENCE and QUERY (got {len(args.inputs)} path{'s' if len(args.inputs) != 1 else ''})."
        )
    frontend = {k: getattr(args, k) for k in ("size", "patch", "crop", "metric", "fps") if getattr(args, k) is not None}
    if args.map is not None and frontend:
        flags = ", ".join(f"--{k}" for k in frontend)
        raise InvalidParameterError(f"{flags} do{'es' if len(frontend) == 1 else ''} not apply to a saved map: its "
                                    "front-end is fixed when it is built (catgraph build-map).")
    junction = getattr(args, "junction_radius_m", None)
    if args.map is not None and junction is not None:
        raise InvalidParameterError("--junction-radius-m does not apply to a saved map: its place graph is fixed when "
                                    "it is built (catgraph build-map --junction-radius-m).")
    if args.output is not None:
        from .._atomic import check_writable
        from ..datasets.loaders import source_paths

        read = [path for source in args.inputs for path in source_paths(source)]
        read += [path for path in (args.map, args.ground_truth) if path is not None and Path(path).is_file()]
        check_writable(args.output, "output file", inputs=read)
    return Experiment(query=args.inputs[-1], method=method, params=params,
                      reference=None if args.map is not None else args.inputs[0], map=args.map,
                      tolerance=args.tolerance, tolerance_m=args.tolerance_m, ground_truth=args.ground_truth,
                      condition=condition_from(args), frontend=frontend or None, junction_radius_m=junction)


def progress_enabled(args) -> bool:
    """Progress bars only for a person watching: not with --quiet, not into a log file."""
    return not args.quiet and sys.stderr.isatty()


def run_and_report(args, exp) -> int:
    """Run one experiment, print its table, write its JSON."""
    from ..experiment import payload, prepare, run_method
    from ..results import write_json_atomic

    prepared = prepare(exp)
    result = run_method(exp.method, exp.params, prepared, progress=progress_enabled(args))
    out, evaluation = payload(result, prepared, exp)
    if args.output is not None:
        write_json_atomic(args.output, out)
    print_results([(result.method, out["metrics"], result.seconds)], per_frame=len(prepared.query))
    if args.output is not None and not args.quiet:
        print(f"wrote {args.output}")
    return 0


def print_results(rows, per_frame: int | None = None) -> None:
    """rows: (name, metrics dict or None, seconds) → an aligned table on stdout; runs without
    ground truth show their time only."""
    if all(m is None for _, m, _ in rows):
        for name, _, seconds in rows:
            rate = f"{1000 * seconds / per_frame:.2f} ms/frame" if per_frame and seconds == seconds else ""
            print(f"{name}: {per_frame} frames localised, no ground truth given (no metrics) {rate}".rstrip())
        sys.stdout.flush()
        return
    print_metrics_table([(n, m, s) for n, m, s in rows if m is not None], per_frame=per_frame)


def print_metrics_table(rows, per_frame: int | None = None) -> None:
    """rows: (name, metrics dict, seconds) → an aligned text table on stdout.

    With ``per_frame`` (the number of frames) the last column is milliseconds per frame.
    """
    header = ["method", "AUC", "R@100P", "R@99P", "R@90P", "MTL", "accuracy", "n",
              "ms/frame" if per_frame else "seconds"]
    lines = [header]
    for name, m, seconds in rows:
        # a run without ground truth has no metrics (None): its cells are dashes
        cells = ["–"] * 7 if m is None else [
            f"{m['auc']:.3f}", f"{m['recall_at_100p']:.3f}", f"{m['recall_at_99p']:.3f}", f"{m['recall_at_90p']:.3f}",
            str(m["mtl"]), f"{m['accuracy']:.3f}", str(m["n_queries"])]
        lines.append([name, *cells, "-" if seconds != seconds else
                      f"{1000 * seconds / per_frame:.2f}" if per_frame else f"{seconds:.2f}"])
    widths = [max(len(row[k]) for row in lines) for k in range(len(header))]
    for row in lines:
        print("  ".join(cell.ljust(w) if k == 0 else cell.rjust(w) for k, (cell, w) in enumerate(zip(row, widths))))
    sys.stdout.flush()


# ---------------------------------------------------------------------------- match
@register
def register_match(sub) -> None:
    from ..differences import LAYOUTS

    p = sub.add_parser("match", help="match every query frame to the reference (single frame, sequences, histogram)",
                       usage=_USAGE,
                       description="Match each query frame to a reference place; evaluate where ground truth is "
                                   "given. --window 1 (default): single frame; --window N or adaptive: sequences; "
                                   "--model histogram: the P(d|L), P(d|¬L) model.")
    add_common_inputs(p)
    p.add_argument("--model", choices=("sequence", "histogram"), default="sequence",
                   help="'sequence' (SeqSLAM; --window 1 = single frame) or 'histogram' (P(d|L), P(d|¬L) model)")
    add_method_options(p, ("sequence", "single-frame", "histogram"), shown_defaults={"window": "1: single frame"})
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster (tcp://host:8786), the map sharded over its workers: sequence matching; "
                        "needs pip install \"catgraph[dask]\"")
    p.add_argument("--shard-places", type=int, metavar="N",
                   help="with --scheduler: places per shard, rounded up to a multiple of 4096 (default: the map split "
                        "evenly over the workers)")
    p.add_argument("--layout", choices=LAYOUTS,
                   help="with --scheduler: how workers hold their shards; 'uint8': one byte per value, a quarter of "
                        "the memory, the differences of the compact layout (docs/live.md) (default float32: the local "
                        "run's answers bit for bit)")
    p.set_defaults(func=cmd_match)


def cmd_match(args) -> int:
    given = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_")}
    if args.model == "histogram":
        method = "histogram"
    else:
        method = "single-frame" if given.get("window", 1) == 1 else "sequence"
        if method == "single-frame":
            vars(args).pop("param_window", None)
    exp = experiment_from(args, method, method_params(args, method))
    if args.scheduler is None:
        given_cluster = [flag for flag, value in (("--shard-places", args.shard_places), ("--layout", args.layout))
                         if value is not None]
        if given_cluster:
            raise InvalidParameterError(f"{given_cluster[0]} sets how a cluster run shards the map; add --scheduler "
                                        "ADDRESS, or leave it out.")
        return run_and_report(args, exp)
    from ..experiment import run_on_cluster
    from ..results import write_json_atomic

    result, out, _ = run_on_cluster(exp, args.scheduler, shard_places=args.shard_places,
                                    layout=args.layout or "float32")
    if args.output is not None:
        write_json_atomic(args.output, out)
    print_results([(result.method, out["metrics"], result.seconds)], per_frame=len(result.match))
    if args.output is not None and not args.quiet:  # as the local run says it
        print(f"wrote {args.output}")
    return 0


# ---------------------------------------------------------------------------- localize
@register
def register_localize(sub) -> None:
    from ..methods import GRID_MAX_PLACES

    p = sub.add_parser("localize", help="localise the query with a Bayes filter on the place graph", usage=_USAGE,
                       description="Run a filter on the place graph of the reference (or a saved map) with the "
                                   "chosen observation model: by default the exact grid filter over (place, "
                                   f"velocity) up to {GRID_MAX_PLACES:,} places, the CAT-Graph particle filter "
                                   "above (--mode); "
                                   "evaluate where ground truth is given.")
    add_common_inputs(p, graph_options=True)
    add_method_options(p, ("filter",))
    p.set_defaults(func=cmd_localize)


def cmd_localize(args) -> int:
    return run_and_report(args, experiment_from(args, "filter", method_params(args, "filter")))


# ---------------------------------------------------------------------------- compare
_COMPARE_FILTER = ("mode", "n_particles", "seed", "confidence_radius", "confidence_radius_m", "use_odometry",
                   "resampler", "ess_threshold", "redraw_fraction", "proposal", "new_place_prior")


@register
def register_compare(sub) -> None:
    p = sub.add_parser("compare", help="run every method and observation model on the same input; print one table",
                       usage=_USAGE,
                       description="Run single-frame matching, a fixed and the adaptive sequence matcher, the "
                                   "histogram recogniser and the particle filter with every observation model on one "
                                   "reference/query pair and one difference matrix; print one table.")
    add_common_inputs(p, graph_options=True)
    from ..compare import COMPARE_WINDOW

    p.add_argument("--window", type=_number(int), default=None, metavar="FRAMES",
                   help="the fixed window of the matcher and of the filter's sequence model (default "
                        f"{COMPARE_WINDOW}, or the query's length where it is shorter)")
    from ..methods import METHODS

    skip = tuple(p.name for p in METHODS["filter"].params if p.name not in _COMPARE_FILTER)
    add_method_options(p, ("filter",), skip=skip)
    p.set_defaults(func=cmd_compare)


def cmd_compare(args) -> int:
    from ..compare import COMPARE_WINDOW, compare_plan, compare_window
    from ..experiment import payload, prepare, run_method
    from ..methods import concrete_params, resolve_params
    from ..results import write_json_atomic

    if args.window is not None and args.window < 1:
        raise InvalidParameterError(f"--window must be ≥ 1 frame; got {args.window}.")
    filter_params = method_params(args, "filter")
    exp = experiment_from(args, "single-frame", {})
    prepared = prepare(exp)
    window = compare_window(len(prepared.query), args.window)
    if window > len(prepared.query):
        raise InvalidParameterError(f"--window {window} frames is longer than the query ({len(prepared.query)} "
                                    f"frames); choose at most {len(prepared.query)}, or leave --window out.")
    if args.window is None and window < COMPARE_WINDOW and not args.quiet:
        print(f"catgraph: the query has {window} frames: the fixed window is {window} frames, not "
              f"{COMPARE_WINDOW} (set it with --window)", file=sys.stderr)
    plan = compare_plan(window, filter_params)
    for name, params in plan:  # every filter's options checked on this map before the first run, not after
        if name == "filter":
            concrete_params(resolve_params(name, params), prepared.map.n_places)
    rows, payloads = [], []
    for name, params in progress_iter(plan, not progress_enabled(args), "methods"):
        result = run_method(name, params, prepared)
        out, _ = payload(result, prepared)
        payloads.append(out)
        rows.append((result.method, out["metrics"], result.seconds))
    if args.output is not None:
        write_json_atomic(args.output, {"runs": payloads})
    print_results(rows, per_frame=len(prepared.query))
    if args.output is not None and not args.quiet:
        print(f"wrote {args.output}")
    return 0


def progress_iter(items, quiet: bool, desc: str):
    if quiet:
        yield from items
        return
    from tqdm.auto import tqdm

    bar = tqdm(items, desc=desc, leave=False, file=sys.stderr)
    for item in bar:
        bar.set_postfix_str(item[0] if isinstance(item, tuple) else str(item))
        yield item


# ---------------------------------------------------------------------------- demo
@register
def register_demo(sub) -> None:
    p = sub.add_parser("demo", help="run everything on the built-in synthetic world and write a report",
                       description="Localise an out-of-order night drive through a synthetic city against a day "
                                   "map with single-frame matching, the adaptive sequence matcher and the particle "
                                   "filter; print a table and write an HTML report.")
    p.add_argument("--out", type=folder, default=Path("catgraph-demo"), help="report folder (default catgraph-demo/)")
    p.add_argument("--seed", type=_number(int), default=0, help="seed of the world and the filter (default 0)")
    p.add_argument("--particles", type=_number(int), default=2000,
                   help="particles of the particle filter whose posterior the report draws; the filter runs are the "
                        "exact grid filter, which has none (default 2000)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress messages (the table is printed)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    from ..demo import run_demo
    from ..methods import METHODS

    METHODS["filter"].param("seed").check(args.seed, "demo", label="--seed")
    METHODS["filter"].param("n_particles").check(args.particles, "demo", label="--particles")
    from .._atomic import check_writable_folder

    check_writable_folder(args.out, "--out folder")
    log = (lambda *a: None) if args.quiet else print
    report, payloads = run_demo(args.out, seed=args.seed, n_particles=args.particles,
                                progress=progress_enabled(args), log=log)
    print_metrics_table([(p["method"], p["metrics"], p.get("seconds", float("nan"))) for p in payloads])
    if not args.quiet:
        print(f"report: {report}")
    return 0
