"""``catgraph report``: an HTML page and a markdown table comparing result files.

::

    catgraph report single.json adaptive.json --out report/ [--title "Nordland"] [--quiet]

Calls :func:`catgraph.report.write_report`; writes ``report/index.html`` (self-contained,
opens offline) and ``report/results.md``.
"""

from __future__ import annotations

from pathlib import Path

from .commands import folder, register


@register
def register_report(sub) -> None:
    p = sub.add_parser(
        "report",
        help="write an HTML report and a markdown table comparing result files",
        description="Compare result JSON files (written by match, localize, bench …) in one self-contained HTML "
                    "page with PR curves, AUC/MTL bars and per-frame plots, plus a markdown table (results.md).",
    )
    p.add_argument("results", nargs="+", type=Path, metavar="RESULTS.json", help="result files, in the order to show")
    p.add_argument("--out", "-o", type=folder, required=True, metavar="DIR",
                   help="folder to write index.html and results.md into (created if missing)")
    p.add_argument("--title", default="catgraph report", help="page title (default: 'catgraph report')")
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing on success")
    p.set_defaults(func=cmd_report)


def cmd_report(args) -> int:
    from .._atomic import check_writable_folder
    from ..report import write_report

    check_writable_folder(args.out, "--out folder")
    index = write_report(list(args.results), args.out, title=args.title)
    if not args.quiet:
        print(f"wrote {index} and {index.parent / 'results.md'}")
    return 0
