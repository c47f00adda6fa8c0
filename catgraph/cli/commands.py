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


_register = register


def load_command_modules() -> None:
    import importlib

    for name in COMMAND_MODULES:
        try:
            importlib.import_module(f"{__package__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__package__}.{name}":
                raise


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
    p.add_argument("reference", help="reference traverse: image folder, UJI prefix (db/01/trn01) or .npy/.npz")
    p.add_argument("query", help="query traverse, in the same form as the reference")
    gt = p.add_mutually_exclusive_group()
    gt.add_argument("--tolerance", type=int, metavar="FRAMES", help="ground truth: same index ± FRAMES")
    gt.add_argument("--tolerance-m", type=float, metavar="METRES", help="ground truth: positions within METRES")
    p.add_argument("--shuffle", type=int, metavar="SEED", help="shuffle the query in segments of 2–20%% (seeded)")
    p.add_argument("--size", type=_size, metavar="WxH", help="resize images to WxH before patch normalisation")
    p.add_argument("--patch", type=int, default=4, help="patch-normalisation patch side in pixels (0 = off)")
    p.add_argument("--metric", choices=["sad", "ssd", "cosine", "hamming"], help="difference metric")
    p.add_argument("--output", "-o", type=Path, metavar="FILE", help="write the result JSON here")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars or tables")


def load_inputs(args):
    """Load reference and query, shuffle the query if asked, build ground truth."""
    from ..datasets import load_traverse
    from ..pipeline import ground_truth_for
    from ..traverse import shuffle_segments

    reference = load_traverse(args.reference, progress=not args.quiet)
    query = load_traverse(args.query, progress=not args.quiet)
    if args.tolerance is None and args.tolerance_m is None:
        raise InvalidParameterError(
            "no ground truth given: add --tolerance FRAMES (same index = same place) "
            "or --tolerance-m METRES (for data with positions)."
        )
    if args.tolerance is not None and args.tolerance < 0:
        raise InvalidParameterError(f"--tolerance must be ≥ 0 frames; got {args.tolerance}.")
    if args.tolerance_m is not None and args.tolerance_m < 0:
        raise InvalidParameterError(f"--tolerance-m must be ≥ 0 metres; got {args.tolerance_m}.")
    ground_truth = ground_truth_for(reference, query, args.tolerance, args.tolerance_m)
    if args.shuffle is not None:
        query = shuffle_segments(query, seed=args.shuffle)
    return reference, query, ground_truth


def frontend_from(args):
    from ..pipeline import FrontEnd

    return FrontEnd(size=args.size, patch=args.patch, metric=args.metric)


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


def print_metrics_table(rows) -> None:
    """rows: (name, metrics dict, seconds) → an aligned text table on stdout."""
    header = ["method", "AUC", "R@100P", "R@99P", "R@90P", "MTL", "accuracy", "n", "seconds"]
    lines = [header]
    for name, m, seconds in rows:
        lines.append([name, f"{m['auc']:.3f}", f"{m['recall_at_100p']:.3f}", f"{m['recall_at_99p']:.3f}",
                      f"{m['recall_at_90p']:.3f}", str(m["mtl"]), f"{m['accuracy']:.3f}", str(m["n_queries"]),
                      f"{seconds:.2f}" if seconds == seconds else "-"])
    widths = [max(len(row[k]) for row in lines) for k in range(len(header))]
    for row in lines:
        print("  ".join(cell.ljust(w) if k == 0 else cell.rjust(w) for k, (cell, w) in enumerate(zip(row, widths))))
    sys.stdout.flush()


@_register
def register_match(sub) -> None:
    p = sub.add_parser("match", help="match every query frame to the reference (single frame or sequences)",
                       description="Match each query frame to a reference place and evaluate the result.")
    add_common_inputs(p)
    p.add_argument("--window", type=_window, default=1, help="sequence length in frames, or 'adaptive' (default 1)")
    p.add_argument("--approximation", choices=["gaussian", "robust", "gmm2", "gmm3"], default="gaussian",
                   help="adaptive window: approximation of the score distribution (default gaussian)")
    p.add_argument("--rule", choices=["consistent", "literal"], default="consistent",
                   help="adaptive window: 'literal' = the paper's argmin p(L); 'consistent' (default) also "
                        "requires the hypothesis to hold over the window's recent frames")
    p.add_argument("--l-min", type=int, default=10, help="adaptive window: shortest window (default 10)")
    p.add_argument("--l-max", type=int, default=500, help="adaptive window: longest window (default 500)")
    p.add_argument("--model", choices=["sequence", "histogram"], default="sequence",
                   help="'sequence' (SeqSLAM; --window 1 = single frame) or 'histogram' (P(d|L), P(d|¬L) model)")
    p.add_argument("--learning", choices=["online", "trained", "bootstrap"], default="online",
                   help="histogram model: online (training-free), trained (fit on the labelled query: an "
                        "upper-bound baseline) or bootstrap (from the reference map)")
    p.add_argument("--init-frames", type=int, default=100, help="histogram model, online: T_init (default 100)")
    p.add_argument("--exclusion", type=int, default=10,
                   help="confidence = margin to the best match outside ± this many places (default 10)")
    p.set_defaults(func=cmd_match)


def cmd_match(args) -> int:
    from ..pipeline import differences, match_single_frames

    reference, query, ground_truth = load_inputs(args)
    frontend = frontend_from(args)
    diff = differences(reference, query, frontend)
    from ..methods import run_method

    if args.model == "histogram":
        params = {"learning": args.learning, "n_init": args.init_frames}
        result = run_method("histogram", params, reference=reference, query=query, differences=diff,
                            ground_truth=ground_truth, frontend=frontend)
    elif args.window == 1:
        result = match_single_frames(diff, query.index, exclusion=args.exclusion)
    else:
        params = {"window": args.window, "radius": args.exclusion}
        if args.window == "adaptive":
            params.update(approximation=args.approximation, rule=args.rule, l_min=args.l_min, l_max=args.l_max)
        result = run_method("sequence", params, reference=reference, query=query, differences=diff)
    extra = {"reference": str(args.reference), "query": str(args.query), "shuffle": args.shuffle,
             "frontend": frontend.as_dict(), "ground_truth": ground_truth.describe()}
    return finish(args, result, ground_truth, extra)
