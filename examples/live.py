"""Localise a query one frame at a time, as a camera or Wi-Fi callback would.

    python examples/live.py REFERENCE QUERY [--model combined] [--mode auto]
                            [--particles 2000] [--seed 0] [--output frames.json] [--every 100]

REFERENCE is a saved map (``catgraph build-map … --out map.npz``) or anything
``catgraph localize`` reads as a reference (an image folder, a video file, a UJI prefix,
an array file, ``synthetic:SEED``); QUERY is a traverse. The map is prepared once
(:class:`catgraph.live.LiveMap`); then every raw query frame (an image, a scan) is handed
to :meth:`catgraph.live.LiveLocalizer.step` on its own, which applies the map's
front-end, compares the frame with every place and updates the filter. The answers
(place, score, P(new place), window) are those ``catgraph localize`` writes for the
same reference, query, model, particles and seed; ``--output`` writes them in the
same ``frames`` layout to check. The last line is the time per frame:

    per-frame ms: median X p99 Y
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def load_live_map(source: str, layout: str = "float32"):
    """A LiveMap from a saved map (``*.npz`` written by build-map) or a reference source."""
    from catgraph.experiment import load_input
    from catgraph.live import LiveMap

    path = Path(source)
    if path.suffix.lower() == ".npz":  # a missing map is reported as one; a compact map is coded as it is read
        return LiveMap(path, layout=layout)
    return LiveMap(load_input(source, "reference"), layout=layout)


def main(argv: list[str] | None = None) -> int:
    import inspect

    from catgraph.differences import LAYOUTS
    from catgraph.live import LIVE_MODELS, LiveLocalizer, LiveMap
    from catgraph.methods import METHODS

    mode = METHODS["filter"].param("mode")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", metavar="REFERENCE")
    parser.add_argument("query", metavar="QUERY")
    defaults = {name: inspect.signature(cls).parameters[name].default  # the live API's own defaults
                for cls, name in ((LiveLocalizer, "model"), (LiveMap, "layout"))}
    parser.add_argument("--model", choices=LIVE_MODELS, default=defaults["model"])
    parser.add_argument("--mode", choices=mode.choices,
                        help=f"the filter: {mode.help} (default {mode.default})")
    parser.add_argument("--particles", type=int, help="particles in the particle filter (mode 'particles', or "
                                                       "'auto' on a map of more than 100,000 places; default 2000)")
    parser.add_argument("--seed", type=int, help="the particle filter's seed (default 0)")
    parser.add_argument("--output", type=Path, help="write the per-frame answers (JSON, 'frames' as localize writes)")
    parser.add_argument("--every", type=int, default=0, help="print every N-th answer (0: none)")
    parser.add_argument("--layout", choices=LAYOUTS, default=defaults["layout"],
                        help="the map in memory: float32 (the batch commands' numbers) or uint8 codes (a quarter "
                             "of the bytes per frame; see docs/live.md)")
    args = parser.parse_args(argv)
    from catgraph.exceptions import CatgraphError

    try:
        return run(args)
    except CatgraphError as exc:  # a user's mistake: one line, as the catgraph commands say it
        print(f"live.py: error: {exc}", file=sys.stderr)
        return 1


def run(args) -> int:
    from catgraph._atomic import check_writable
    from catgraph.datasets.loaders import source_paths
    from catgraph.exceptions import InvalidParameterError
    from catgraph.datasets.video import is_video
    from catgraph.experiment import load_input
    from catgraph.live import LiveLocalizer

    if args.every < 0:
        raise InvalidParameterError(f"--every must be ≥ 0 (0: print no answer); got {args.every}.")
    if args.output is not None:  # before any work, and never over an input
        check_writable(args.output, "output file", inputs=source_paths(args.reference) + source_paths(args.query))
    # only the options given, as the catgraph commands take them (one that does not apply is an error)
    given = {flag: value for flag, value in (("--mode", args.mode), ("--particles", args.particles),
                                             ("--seed", args.seed)) if value is not None}
    if args.model == "matcher" and given:
        verb = "does" if len(given) == 1 else "do"
        raise InvalidParameterError(f"{' and '.join(given)} {verb} not apply to --model matcher (it runs no filter); "
                                    "leave it out.")
    live_map = load_live_map(args.reference, args.layout)
    # a video query is read at the map's frames per second (the map keeps them: build-map --fps)
    query = load_input(args.query, "query", live_map.frontend.fps if is_video(args.query) else None)
    live_map.check_query(query)
    params = {name: given[flag] for name, flag in (("mode", "--mode"), ("n_particles", "--particles"),
                                                   ("seed", "--seed")) if flag in given}
    live = LiveLocalizer(live_map, model=args.model, **params)
    odometry = query.odometry
    frames = {"query_index": [], "match": [], "confidence": [], "p_new_place": [], "window_length": []}
    seconds = []
    for k in range(len(query)):  # one frame at a time, as a sensor callback receives them
        frame = query.frames[k]
        start = time.perf_counter()
        est = live.step(frame, None if odometry is None or k == 0 else float(odometry[k]))
        seconds.append(time.perf_counter() - start)
        frames["query_index"].append(int(query.index[k]))
        frames["match"].append(est.place if est.place >= 0 else None)  # no match: null, as localize writes
        frames["confidence"].append(est.score)
        frames["p_new_place"].append(est.new_place_probability)
        frames["window_length"].append(est.window_length)
        if args.every and k % args.every == 0:
            print(f"frame {k}: place {est.place} score {est.score:.2f} P(new) {est.new_place_probability:.3f} "
                  f"window {est.window_length}")
    if args.output is not None:
        args.output.write_text(json.dumps({"method": f"live/{args.model}", "frames": frames}))
    ms = 1000.0 * np.asarray(seconds)
    print(f"per-frame ms: median {np.median(ms):.2f} p99 {np.percentile(ms, 99):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
