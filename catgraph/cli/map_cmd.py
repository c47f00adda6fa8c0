"""``catgraph build-map``: describe a reference once and save it as a map file.

    catgraph build-map REFERENCE --out map.npz [--size WxH] [--patch P] [--crop T,B,L,R] [--metric M]
                       [--fps F] [--junction-radius-m R] [--no-graph] [--no-compress] [--quiet]

REFERENCE is anything the other commands accept (image folder, video file, UJI prefix,
``.npy``/``.npz``, ``synthetic:SEED``). The map holds the descriptors, the front-end
settings, the place graph (chain plus junctions within R metres when positions exist)
and the reference's positions, floors and ids; see :mod:`catgraph.io`.
"""

from __future__ import annotations

from pathlib import Path

from .commands import FPS_HELP, _crop, _number, _size, register


@register
def register_build_map(sub) -> None:
    from ..differences import METRICS

    p = sub.add_parser("build-map", help="describe a reference traverse once and save it as a map file (.npz)",
                       description="Describe a reference traverse with the front-end, build its place graph and "
                                   "save everything as one checksummed .npz map file.")
    p.add_argument("reference", help="reference traverse: image folder, video file, UJI prefix (db/01/trn01), "
                                     ".npy/.npz or synthetic:SEED")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="FILE", help="map file to write (map.npz)")
    p.add_argument("--size", type=_size, metavar="WxH", help="resize images to WxH before patch normalisation")
    p.add_argument("--patch", type=_number(int), help="patch-normalisation patch side in pixels (0 = off; default 4)")
    p.add_argument("--crop", type=_crop, metavar="T,B,L,R",
                   help="cut T, B, L and R pixels from the images' top, bottom, left and right before resizing")
    p.add_argument("--metric", choices=METRICS, help="difference metric (default: by data kind)")
    p.add_argument("--fps", type=_number(float), metavar="F", help=FPS_HELP)
    p.add_argument("--junction-radius-m", type=_number(float), metavar="METRES",
                   help="join places of different parts of the route within METRES (needs positions)")
    p.add_argument("--no-graph", action="store_true", help="store no place graph")
    p.add_argument("--no-compress", action="store_true",
                   help="store the arrays uncompressed: a larger file that loads quicker (a compact live map of "
                        "10⁶ places reads it about 4 times as fast; docs/live.md)")
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing")
    p.set_defaults(func=cmd_build_map)


def cmd_build_map(args) -> int:
    from ..exceptions import InvalidParameterError
    from ..experiment import load_input
    from ..io import build_map, save_map
    from ..pipeline import FrontEnd, check_image_options

    from .._atomic import check_writable
    from ..datasets.loaders import source_paths

    if args.junction_radius_m is not None and args.no_graph:
        raise InvalidParameterError("--junction-radius-m adds edges to the place graph; drop --no-graph.")
    if args.junction_radius_m is not None and not 0 < args.junction_radius_m < float("inf"):
        raise InvalidParameterError(f"--junction-radius-m must be > 0 metres; got {args.junction_radius_m}.")
    frontend = FrontEnd.from_dict({"size": args.size, "patch": args.patch, "crop": args.crop, "metric": args.metric,
                                   "fps": args.fps})
    check_writable(args.out, "map file", inputs=source_paths(args.reference))
    reference = load_input(args.reference, "reference", frontend.fps)
    check_image_options(reference, {k for k in FrontEnd.IMAGE_KEYS if getattr(args, k) is not None})
    if args.junction_radius_m is not None and reference.positions is None:
        raise InvalidParameterError("--junction-radius-m joins places by position, but the reference has no "
                                    "positions; leave it out.")
    m = build_map(reference, frontend, junction_radius_m=args.junction_radius_m, graph=not args.no_graph,
                  meta={"source": str(args.reference)})
    path = save_map(args.out, m, compress=not args.no_compress)
    if not args.quiet:
        graph = "no graph" if m.graph is None else (
            f"{m.graph.n_edges} edges, {len(m.graph.junction_pairs())} junctions, unit {m.graph.unit}")
        print(f"wrote {path}: {m.n_places} places × {m.descriptors.shape[1]} values ({m.metric}), {graph}")
    return 0
