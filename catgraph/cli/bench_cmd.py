"""``catgraph bench``: run an experiment configuration as a sweep and write its results.

    catgraph bench CONFIG.toml [--out DIR] [--scheduler ADDRESS] [--processes N] [--list] [--quiet]

Writes into DIR (default ``results/NAME``, NAME the configuration's name):

* ``RUN.json`` per run — the result payload plus the ``spec`` that reproduces it
  (``RUN`` is the run name with ``/`` as ``__``);
* ``summary.md`` — the metrics table in markdown, failed runs listed below it;
* ``summary.json`` — name, metrics, seconds and spec of every run (or its error);
* ``index.html`` and ``results.md`` — the HTML report (:func:`catgraph.report.write_report`).

A failing run does not stop the others (they are recorded); the command then exits
with status 1 and names the failed runs.
"""

from __future__ import annotations

import json
from pathlib import Path

from .._atomic import write_text_atomic
from .commands import folder, register


@register
def register_bench(sub) -> None:
    p = sub.add_parser("bench", help="run an experiment configuration (TOML) as a sweep, locally or on Dask",
                       description="Expand an experiment configuration into runs, run them in parallel (local "
                                   "processes or a Dask cluster) and write every result, a summary table and an "
                                   "HTML report.")
    p.add_argument("config", type=Path, help="experiment configuration (.toml); see docs/maps_and_sweeps.md")
    p.add_argument("--out", "-o", type=folder, metavar="DIR", help="output folder (default results/NAME)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786); needs pip install \"catgraph[dask]\"")
    p.add_argument("--processes", type=int, metavar="N", help="local worker processes (default: CPUs; 1 = serial)")
    p.add_argument("--list", action="store_true", help="only list the runs the configuration expands to")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar or table")
    p.set_defaults(func=cmd_bench)


def _summary_markdown(config, payloads: list[dict], failed: list[dict]) -> str:
    try:
        from ..report import markdown_table
    except ImportError:  # the report module is optional here
        markdown_table = None
    lines = [f"# {config.name}", ""]
    if config.description:
        lines += [config.description, ""]
    if payloads and markdown_table is not None:
        lines.append(markdown_table(payloads).rstrip("\n"))
    else:
        lines += ["| run | AUC | R@100P | R@99P | R@90P | MTL | accuracy | n |", "|:--|--:|--:|--:|--:|--:|--:|--:|"]
        for p in payloads:
            m = p["metrics"]
            lines.append(f"| {p['name']} | {m['auc']:.3f} | {m['recall_at_100p']:.3f} | {m['recall_at_99p']:.3f} | "
                         f"{m['recall_at_90p']:.3f} | {m['mtl']} | {m['accuracy']:.3f} | {m['n_queries']} |")
    if failed:
        lines += ["", "Failed runs:", ""] + [f"- `{f['name']}`: {f['error'].splitlines()[0]}" for f in failed]
    return "\n".join(lines) + "\n"


def _earlier_run_files(out: Path) -> set[str]:
    """The run files an earlier bench's summary in ``out`` lists (none: no readable summary)."""
    try:
        runs = json.loads((out / "summary.json").read_text()).get("runs", [])
        return {run["file"] for run in runs if isinstance(run, dict) and isinstance(run.get("file"), str)
                and Path(run["file"]).name == run["file"] and run["file"].endswith(".json")}
    except (OSError, ValueError, AttributeError):
        return set()


def cmd_bench(args) -> int:
    from ..conditions import Condition
    from ..config import load_config, run_file_name
    from ..exceptions import CatgraphError, InvalidParameterError
    from ..results import write_json_atomic
    from ..sweep import run_sweep
    from .commands import print_metrics_table, progress_enabled

    ignored = [flag for flag, value in (("--out", args.out), ("--scheduler", args.scheduler),
                                        ("--processes", args.processes)) if value is not None]
    if args.list and ignored:
        raise InvalidParameterError(f"{' and '.join(ignored)} {'does' if len(ignored) == 1 else 'do'} not apply with "
                                    "--list (it only lists the runs); leave it out.")
    if args.scheduler is not None and args.processes is not None:
        raise InvalidParameterError("--processes does not apply with --scheduler (the cluster's workers run the "
                                    "sweep); leave it out.")
    config = load_config(args.config)
    if args.list:
        for spec in config.specs:
            condition = spec.get("condition") or {"kind": "in-order"}
            where = "" if condition["kind"] == "in-order" else f" {Condition.from_dict(condition).label}"
            print(f"{spec['name']}: {spec['method']} {spec['params']}{where}")
        print(f"{len(config.specs)} runs")
        return 0
    if args.processes is not None and args.processes < 1:
        raise InvalidParameterError(f"--processes must be ≥ 1; got {args.processes}.")
    out = args.out if args.out is not None else Path("results") / run_file_name(config.name)
    from .._atomic import check_writable_folder

    check_writable_folder(out, "--out folder")  # before the sweep, not after it
    # an earlier bench in this folder: its summary goes when the first run is done (a sweep cut
    # short must not look complete; a sweep refused before any run touches nothing), and its run
    # files that this sweep does not write go at the end
    earlier = _earlier_run_files(out)
    entries: list[tuple[dict, str, dict] | None] = [None] * len(config.specs)

    def keep(k: int, result: dict) -> None:
        """Each run's file as the run finishes: an interrupted sweep keeps what it has done."""
        if all(entry is None for entry in entries):  # the first run done
            out.mkdir(parents=True, exist_ok=True)
            for stale in ("summary.json", "summary.md", "index.html", "results.md"):
                (out / stale).unlink(missing_ok=True)
        spec = config.specs[k]
        file = f"{run_file_name(spec['name'])}.json"
        if "error" in result:
            # an earlier bench's result under this run's name is not this run's: it goes
            (out / file).unlink(missing_ok=True)
        else:
            result = dict(result, name=spec["name"], spec=spec)
            write_json_atomic(out / file, result)
        entries[k] = (spec, file, result)

    run_sweep(config.specs, scheduler=args.scheduler, processes=args.processes, progress=progress_enabled(args),
              errors="record", on_result=keep)
    payloads, failed, rows = [], [], []
    for spec, file, result in entries:  # type: ignore[misc]
        if "error" in result:
            failed.append(result)
            rows.append({"name": spec["name"], "error": result["error"], "spec": spec})
            continue
        payloads.append(result)
        rows.append({"name": spec["name"], "file": file, "metrics": result["metrics"],
                     "seconds": result.get("seconds"), "spec": spec})
    written = {row["file"] for row in rows if "file" in row}
    for file in sorted(earlier - written):  # runs the config no longer has
        (out / file).unlink(missing_ok=True)
    write_json_atomic(out / "summary.json", {"name": config.name, "description": config.description,
                                             "config": str(args.config), "runs": rows})
    write_text_atomic(out / "summary.md", _summary_markdown(config, payloads, failed))
    report = None
    if payloads:
        try:
            from ..report import write_report
        except ImportError:
            write_report = None
        if write_report is not None:
            report = write_report(payloads, out, title=config.name)
    if not args.quiet:
        print_metrics_table([(p["name"], p["metrics"], p.get("seconds", float("nan"))) for p in payloads])
        print(f"wrote {len(payloads)} results, summary.md" + (f" and {report.name}" if report else "") + f" to {out}")
    if failed:
        listed = "; ".join(f"{f['name']} ({f['error'].splitlines()[0]})" for f in failed[:5])
        more = f" and {len(failed) - 5} more" if len(failed) > 5 else ""
        rest = f"The other results are in {out}." if payloads else f"The summary is in {out}."
        raise CatgraphError(f"{len(failed)} of {len(config.specs)} runs failed: {listed}{more}. {rest}")
    return 0
