"""``catgraph warm-up``: compile and cache the numba kernels once, after installing.

::

    catgraph warm-up [--quiet]

Calls :func:`catgraph.live.warm_up`: steps a tiny built-in map through every live path
(both map layouts; the combined, tempered and bootstrap filters; the sequence matcher),
then :func:`catgraph.live.warm_up_batch`: every batch method (single frame, sequence,
histogram, the filter with every model, grid and particles) on tiny inputs, so the kernels are compiled once and cached on disk (:mod:`catgraph._jit`). Every later
process loads them instead of compiling: without it the first run after an install
pays the compilation (measured in ``benchmarks/results/live.md``). Optional: nothing
depends on it but start-up time.
"""

from __future__ import annotations

import time

from .commands import register


@register
def register_warm_up(sub) -> None:
    p = sub.add_parser(
        "warm-up",
        help="compile and cache the kernels once (an optional install step)",
        description="Compile the numba kernels of every live path on a tiny built-in map and cache them on disk, "
                    "so later runs start without compiling.",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing on success")
    p.set_defaults(func=cmd_warm_up)


def cmd_warm_up(args) -> int:
    from .._jit import cache_location
    from ..live import warm_up, warm_up_batch

    start = time.perf_counter()
    warm_up()
    warm_up_batch()
    if not args.quiet:
        print(f"compiled and cached the kernels in {cache_location()} ({time.perf_counter() - start:.1f} s)")
    return 0
