"""Sub-commands. Each ``register_*`` adds a parser; each ``cmd_*`` runs one."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..exceptions import InvalidParameterError

REGISTRY = []

# modules that add sub-commands with ``@register`` when imported
COMMAND_MODULES = ("report_cmd", "map_cmd", "bench_cmd")


def register(fn):
    """Decorator: ``fn(subparsers)`` adds one sub-command."""
    if fn not in REGISTRY:
        REGISTRY.append(fn)
    return fn


def load_command_modules() -> None:
    import importlib

    for name in COMMAND_MODULES:
        importlib.import_module(f"{__package__}.{name}")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 32x16, got {text!r}") from None


def _window(text: str):
    if text == "adaptive":
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of frames or 'adaptive', got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"the window must be at least 1 frame, got {value}")
    return value


def add_common_inputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="REFERENCE QUERY",
                   help="reference and query traverses: image folders, UJI prefixes (db/01/trn01), .npy/.npz "
                        "files or synthetic:SEED; with --map, only QUERY")
    p.add_argument("--map", type=Path, metavar="MAP", help="a saved map (catgraph build-map) as the reference")
    gt = p.add_mutually_exclusive_group()
    gt.add_argument("--tolerance", type=int, metavar="FRAMES", help="ground truth: same index ± FRAMES")
    gt.add_argument("--tolerance-m", type=float, metavar="METRES", help="ground truth: positions within METRES")
    p.add_argument("--shuffle", type=int, metavar="SEED", help="shuffle the query in segments of 2–20%% (seeded)")
    p.add_argument("--size", type=_size, metavar="WxH", help="resize images to WxH before patch normalisation")
    p.add_argument("--patch", type=int, default=4, help="patch-normalisation patch side in pixels (0 = off)")
    p.add_argument("--metric", choices=["sad", "ssd", "cosine", "hamming"], help="difference metric")
    p.add_argument("--output", "-o", type=Path, metavar="FILE", help="write the result JSON here")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars or tables")


class Inputs:
    """Loaded inputs of an evaluating command."""

    def __init__(self, reference, query, ground_truth, differences, frontend, graph=None, sources=None):
        self.reference, self.query, self.ground_truth = reference, query, ground_truth
        self.differences, self.frontend, self.graph, self.sources = differences, frontend, graph, sources or {}


def load_inputs(args) -> Inputs:
    """Load reference (or map) and query, shuffle the query if asked, build ground truth and differences."""
    from ..experiment import default_tolerance_m, load_input
    from ..pipeline import differences, ground_truth_for
    from ..traverse import shuffle_segments

    expected = 1 if args.map is not None else 2
    if len(args.inputs) != expected:
        raise InvalidParameterError(
            "give QUERY only when --map is used" if args.map is not None else
            f"give REFERENCE and QUERY (got {len(args.inputs)} path{'s' if len(args.inputs) != 1 else ''})."
        )
    if args.tolerance is not None and args.tolerance < 0:
        raise InvalidParameterError(f"--tolerance must be ≥ 0 frames; got {args.tolerance}.")
    if args.tolerance_m is not None and args.tolerance_m < 0:
        raise InvalidParameterError(f"--tolerance-m must be ≥ 0 metres; got {args.tolerance_m}.")
    query_source = args.inputs[-1]
    tolerance_m = args.tolerance_m
    if args.tolerance is None and tolerance_m is None:
        tolerance_m = default_tolerance_m(query_source)
    if args.tolerance is None and tolerance_m is None:
        raise InvalidParameterError(
            "no ground truth given: add --tolerance FRAMES (same index = same place) "
            "or --tolerance-m METRES (for data with positions)."
        )
    query = load_input(query_source, "query")
    graph = None
    if args.map is not None:
        from ..io import load_map, query_differences, reference_from_map

        saved = load_map(args.map)
        reference, frontend, graph = reference_from_map(saved), saved.frontend_settings(), saved.graph
        ground_truth = ground_truth_for(reference, query, args.tolerance, tolerance_m)
        if args.shuffle is not None:
            query = shuffle_segments(query, seed=args.shuffle)
        diff = query_differences(saved, query)
        sources = {"map": str(args.map), "query": str(query_source)}
    else:
        reference = load_input(args.inputs[0], "reference")
        frontend = frontend_from(args)
        ground_truth = ground_truth_for(reference, query, args.tolerance, tolerance_m)
        if args.shuffle is not None:
            query = shuffle_segments(query, seed=args.shuffle)
        diff = differences(reference, query, frontend)
        sources = {"reference": str(args.inputs[0]), "query": str(query_source)}
    return Inputs(reference, query, ground_truth, diff, frontend, graph, sources)


def frontend_from(args):
    from ..pipeline import FrontEnd

    return FrontEnd(size=args.size, patch=args.patch, metric=args.metric)


def run_params(args, inputs: "Inputs") -> dict:
    """The parameters every result file records about its inputs."""
    return {**inputs.sources, "shuffle": args.shuffle, "frontend": inputs.frontend.as_dict(),
            "ground_truth": inputs.ground_truth.describe()}


def finish(args, result, ground_truth, extra_params=None) -> int:
    """Evaluate, print the metrics table, write the JSON."""
    from ..results import write_json_atomic

    evaluation = result.evaluate(ground_truth)
    result.params.update(extra_params or {})
    payload = result.to_dict(evaluation)
    if args.output is not None:
        write_json_atomic(args.output, payload)
    if not args.quiet:
        print_metrics_table([(result.method, evaluation.metrics.as_dict(), result.seconds)])
        if args.output is not None:
            print(f"wrote {args.output}")
    return 0


def print_metrics_table(rows, per_frame: int | None = None) -> None:
    """rows: (name, metrics dict, seconds) → an aligned text table on stdout.

    With ``per_frame`` (the number of frames) the last column is milliseconds per frame.
    """
    header = ["method", "AUC", "R@100P", "R@99P", "R@90P", "MTL", "accuracy", "n",
              "ms/frame" if per_frame else "seconds"]
    lines = [header]
    for name, m, seconds in rows:
        lines.append([name, f"{m['auc']:.3f}", f"{m['recall_at_100p']:.3f}", f"{m['recall_at_99p']:.3f}",
                      f"{m['recall_at_90p']:.3f}", str(m["mtl"]), f"{m['accuracy']:.3f}", str(m["n_queries"]),
                      "-" if seconds != seconds else
                      f"{1000 * seconds / per_frame:.2f}" if per_frame else f"{seconds:.2f}"])
    widths = [max(len(row[k]) for row in lines) for k in range(len(header))]
    for row in lines:
        print("  ".join(cell.ljust(w) if k == 0 else cell.rjust(w) for k, (cell, w) in enumerate(zip(row, widths))))
    sys.stdout.flush()


@register
def register_match(sub) -> None:
    p = sub.add_parser("match", help="match every query frame to the reference (single frame or sequences)",
                       description="Match each query frame to a reference place and evaluate the result.")
    add_common_inputs(p)
    p.add_argument("--window", type=_window, default=1, help="sequence length in frames, or 'adaptive' (default 1)")
    p.add_argument("--approximation", choices=["gaussian", "robust", "gmm2", "gmm3"], default="gaussian",
                   help="adaptive window: approximation of the score distribution (default gaussian)")
    p.add_argument("--rule", choices=["sustained", "consistent", "literal"], default="sustained",
                   help="adaptive window: 'literal' = the paper's argmin p(L); 'consistent' = argmin p(L) among "
                        "windows whose hypothesis also holds over their recent frames; 'sustained' (default) = "
                        "the longest such window at least half as significant as the best")
    p.add_argument("--l-min", type=int, default=10, help="adaptive window: shortest window (default 10)")
    p.add_argument("--l-max", type=int, default=500, help="adaptive window: longest window (default 500)")
    p.add_argument("--model", choices=["sequence", "histogram"], default="sequence",
                   help="'sequence' (SeqSLAM; --window 1 = single frame) or 'histogram' (P(d|L), P(d|¬L) model)")
    p.add_argument("--learning", choices=["online", "trained", "bootstrap"], default="online",
                   help="histogram model: online (training-free), trained (fit on the labelled query: an "
                        "upper-bound baseline) or bootstrap (from the reference map)")
    p.add_argument("--init-frames", type=int, default=100, help="histogram model, online: T_init (default 100)")
    p.add_argument("--same-place-m", type=float, metavar="METRES",
                   help="histogram model: reference places within METRES count as the same place (needs "
                        "positions; default: ± a few places along the route)")
    p.add_argument("--exclusion", type=int, default=10,
                   help="confidence = margin to the best match outside ± this many places (default 10)")
    p.set_defaults(func=cmd_match)


def cmd_match(args) -> int:
    from ..methods import run_method
    from ..pipeline import match_single_frames

    inputs = load_inputs(args)
    common = {"reference": inputs.reference, "query": inputs.query, "differences": inputs.differences,
              "frontend": inputs.frontend}
    if args.model == "histogram":
        params = {"learning": args.learning, "n_init": args.init_frames}
        if args.same_place_m is not None:
            params.update(confidence_distance=args.same_place_m, exclusion_distance=args.same_place_m)
        result = run_method("histogram", params, ground_truth=inputs.ground_truth, **common)
    elif args.window == 1:
        result = match_single_frames(inputs.differences, inputs.query.index, exclusion=args.exclusion)
    else:
        params = {"window": args.window, "radius": args.exclusion}
        if args.window == "adaptive":
            params.update(approximation=args.approximation, rule=args.rule, l_min=args.l_min, l_max=args.l_max)
        result = run_method("sequence", params, **common)
    return finish(args, result, inputs.ground_truth, run_params(args, inputs))


# observation models of the particle filter (catgraph.compare.MODEL_NAMES)
FILTER_MODELS = ("histogram", "histogram-bootstrap", "sequence", "adaptive", "combined")


def add_filter_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--particles", type=int, default=2000, help="number of particles (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the filter (default 0)")
    p.add_argument("--window", type=int, default=50, help="window of the fixed sequence model (default 50)")
    p.add_argument("--junction-radius-m", type=float, metavar="METRES",
                   help="join places of different parts of the route within METRES (needs positions)")


@register
def register_localize(sub) -> None:
    p = sub.add_parser("localize", help="localise the query with the CAT-Graph particle filter",
                       description="Run the particle filter on a place graph built from the reference (or a saved "
                                   "map) with the chosen observation model, and evaluate it.")
    add_common_inputs(p)
    p.add_argument("--model", choices=FILTER_MODELS, default="histogram",
                   help="observation model (default histogram: online, training-free)")
    add_filter_options(p)
    p.set_defaults(func=cmd_localize)


def cmd_localize(args) -> int:
    from ..compare import localize

    if args.particles < 1:
        raise InvalidParameterError(f"--particles must be ≥ 1; got {args.particles}.")
    inputs = load_inputs(args)
    from ..methods import confidence_from_ground_truth

    result = localize(inputs.reference, inputs.query, model=args.model, n_particles=args.particles,
                      seed=args.seed, window=args.window, graph=inputs.graph,
                      junction_radius_m=args.junction_radius_m, differences=inputs.differences,
                      frontend=inputs.frontend, progress=not args.quiet,
                      **confidence_from_ground_truth(inputs.ground_truth))
    return finish(args, result, inputs.ground_truth, run_params(args, inputs))


@register
def register_compare(sub) -> None:
    p = sub.add_parser("compare", help="run every observation model on the same input and print one table",
                       description="Run the standalone sequence matchers and the particle filter with every "
                                   "observation model on one reference/query pair; print one table.")
    add_common_inputs(p)
    add_filter_options(p)
    p.set_defaults(func=cmd_compare)


def cmd_compare(args) -> int:
    from ..methods import run_method
    from ..results import write_json_atomic

    inputs = load_inputs(args)
    common = {"reference": inputs.reference, "query": inputs.query, "differences": inputs.differences,
              "frontend": inputs.frontend, "ground_truth": inputs.ground_truth}
    filter_params = {"n_particles": args.particles, "seed": args.seed, "window": args.window,
                     "junction_radius_m": args.junction_radius_m}
    plan = [("single-frame", {}), ("sequence", {"window": args.window}), ("sequence", {"window": "adaptive"}),
            ("histogram", {"learning": "online"})]
    plan += [(f"filter-{m}", dict(filter_params)) for m in FILTER_MODELS]
    rows, payloads = [], []
    for name, params in progress_iter(plan, args.quiet, "methods"):
        result = run_method(name, params, graph=inputs.graph, **common)
        result.params.update(run_params(args, inputs))
        evaluation = result.evaluate(inputs.ground_truth)
        payloads.append(result.to_dict(evaluation))
        rows.append((result.method, evaluation.metrics.as_dict(), result.seconds))
    if not args.quiet:
        print_metrics_table(rows, per_frame=len(inputs.query))
    if args.output is not None:
        write_json_atomic(args.output, {"runs": payloads})
        if not args.quiet:
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


@register
def register_demo(sub) -> None:
    p = sub.add_parser("demo", help="run everything on the built-in synthetic world and write a report",
                       description="Localise an out-of-order night drive through a synthetic city against a day "
                                   "map with single-frame matching, the adaptive sequence matcher and the particle "
                                   "filter; print a table and write an HTML report.")
    p.add_argument("--out", type=Path, default=Path("catgraph-demo"), help="report folder (default catgraph-demo/)")
    p.add_argument("--seed", type=int, default=0, help="seed of the world and the filter (default 0)")
    p.add_argument("--particles", type=int, default=2000, help="particles in the filter (default 2000)")
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing but errors")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    from ..demo import run_demo

    if args.seed < 0:
        raise InvalidParameterError(f"--seed must be ≥ 0; got {args.seed}.")
    log = (lambda *a: None) if args.quiet else print
    report, payloads = run_demo(args.out, seed=args.seed, n_particles=args.particles, progress=not args.quiet, log=log)
    if not args.quiet:
        print_metrics_table([(p["method"], p["metrics"], p.get("seconds", float("nan"))) for p in payloads])
        print(f"report: {report}")
    return 0
