"""``catgraph info``: the versions and the machine a run would record, for a bug report or
before comparing numbers with another machine.

::

    catgraph info [--json]

Prints :func:`catgraph.environment.environment` (what every result file records under
``"environment"``) and the folder the compiled kernels are cached in. The versions and
``compiled_for`` (the CPU the kernels are compiled for) decide a run's numbers to the last
bit: the condition table reproduced on a second processor once they agreed
(``docs/evaluation.md``, "Reproducing the tables on another machine").
"""

from __future__ import annotations

import json

from .commands import register


@register
def register_info(sub) -> None:
    p = sub.add_parser(
        "info",
        help="print the versions and the machine a result records (and where kernels are cached)",
        description="Print catgraph's and its dependencies' versions, the processor, the CPU the kernels are "
                    "compiled for (which decides the last bits of their sums) and the kernel cache folder.",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of lines")
    p.set_defaults(func=cmd_info)


def cmd_info(args) -> int:
    from .._jit import cache_location
    from ..environment import environment

    out = environment()
    out["kernel_cache"] = str(cache_location())
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    width = max(len(k) for k in out)
    for key, value in out.items():
        print(f"{key:<{width}}  {'not installed' if value is None else value}")
    return 0
