"""A self-contained HTML report (and a markdown table) comparing localisation runs.

:func:`write_report` takes result payloads — the JSON every evaluating command writes
(:mod:`catgraph.results`) — or paths to them, and writes two files into a folder:

``index.html``
    One page with no external assets: a table of the metrics of every run (method,
    the parameters that tell the runs apart, AUC, R@100P, R@99P, R@90P, MTL, accuracy,
    number of query frames; the best value of each column in bold), then the figures,
    embedded as base64 PNG: precision–recall curves, AUC and MTL bars, a strip per run
    showing which frames were localised correctly, and — where the runs' frames carry
    them — the adaptive window length and ``P(new place)`` over the frames. Further
    figures can be appended (``extra_figures``). It opens offline in any browser.

    Reading aids: ``notes`` (paragraphs under the table, e.g. why a method loses on
    this input); every parameter of a run is shown in full, one per line, never cut;
    a run that learns online has its initialisation stage (``n_init`` frames, in which
    it cannot localise yet) hatched on the timeline; the frames truly outside the map
    (``new_place_truth``) are shaded on the ``P(new place)`` figure, and each run keeps
    one colour in every figure.
``results.md``
    The same table in GitHub-flavoured markdown, for pasting into notes and pull
    requests.

Both files are written atomically (temporary file in the same folder, then rename), so
a reader never sees half a report. Parameters shared by every run are listed once under
the table instead of repeating them in each row.

The report is a pure function of its inputs: the same results give byte-identical files.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ._atomic import write_text_atomic
from .exceptions import DataError, InvalidParameterError

__all__ = ["COLUMNS", "environment_note", "initialisation_frames", "load_results", "run_labels", "markdown_table",
           "write_report"]

#: (metrics key, column title, format, better) of the metric columns, in table order.
COLUMNS: tuple[tuple[str, str, str, str], ...] = (
    ("auc", "AUC", "{:.3f}", "max"),
    ("recall_at_100p", "R@100P", "{:.3f}", "max"),
    ("recall_at_99p", "R@99P", "{:.3f}", "max"),
    ("recall_at_90p", "R@90P", "{:.3f}", "max"),
    ("mtl", "MTL", "{:.0f}", "min"),
    ("accuracy", "accuracy", "{:.3f}", "max"),
    ("n_queries", "n", "{:.0f}", None),
)

_NEW_PLACE_KEYS = ("p_new_place", "new_place_probability")
_MAX_PARAM_CHARS = 60


# ---------------------------------------------------------------------------- inputs
def load_results(results: Sequence[Mapping[str, Any] | str | os.PathLike]) -> list[dict]:
    """Result payloads from dicts and/or paths, checked for the keys a report reads.

    Parameters
    ----------
    results : sequence of dict or path
        Payloads from :meth:`catgraph.results.RunResult.to_dict`, or paths to the JSON
        files the commands write (a ``catgraph compare`` file adds all of its runs).

    Returns
    -------
    list of dict

    Raises
    ------
    InvalidParameterError
        ``results`` is empty or not a sequence.
    DataNotFoundError
        A path does not exist.
    DataError
        A file is unreadable, not JSON, or not a catgraph result.
    """
    from .results import read_results

    if isinstance(results, (str, os.PathLike, Mapping)) or not isinstance(results, Sequence):
        raise InvalidParameterError(
            f"results must be a list of result dicts or paths; got {type(results).__name__}. "
            "Wrap a single result in a list."
        )
    if len(results) == 0:
        raise InvalidParameterError("no results given; pass at least one result dict or result JSON path.")
    payloads = []
    for k, item in enumerate(results):
        if isinstance(item, (str, os.PathLike)):
            path = Path(item)
            if path.is_dir():
                raise DataError(f"{path} is a folder; give the result JSON files inside it.")
            try:
                runs = read_results(path)
            except (PermissionError, IsADirectoryError, OSError) as exc:
                if isinstance(exc, FileNotFoundError):
                    raise
                raise DataError(f"cannot read result file {path}: {exc.strerror or exc}.") from None
            for run in runs:
                _check_payload(run, str(path))
            payloads.extend(runs)
            continue
        elif isinstance(item, Mapping):
            missing = [key for key in ("method", "params", "metrics", "frames") if key not in item]
            if missing:
                raise DataError(f"result {k + 1} is not a catgraph result (missing {', '.join(missing)}).")
            payload, source = dict(item), f"result {k + 1}"
        else:
            raise InvalidParameterError(
                f"result {k + 1} must be a dict or a path to a result JSON; got {type(item).__name__}."
            )
        _check_payload(payload, source)
        payloads.append(payload)
    return payloads


def _check_payload(payload: dict, source: str) -> None:
    if not isinstance(payload.get("frames"), Mapping):
        raise DataError(f"{source}: 'frames' must be an object of per-frame lists.")
    _check_frames(payload["frames"], source)
    for key in ("params", "environment"):
        if payload.get(key) is not None and not isinstance(payload[key], Mapping):
            raise DataError(f"{source}: '{key}' must be an object.")
    metrics = payload.get("metrics")
    if metrics is None:
        return
    if not isinstance(metrics, Mapping):
        raise DataError(f"{source}: 'metrics' must be an object or null.")
    for key, *_ in COLUMNS:
        value = metrics.get(key)
        if value is not None and not _finite_number(value):
            raise DataError(f"{source}: metric '{key}' must be a finite number; got {value!r}.")


def _finite_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: What each per-frame list the report reads may hold (``null``: no output, or not evaluated).
_FRAME_VALUES = (
    ("correct", lambda v: v is None or isinstance(v, bool), "true, false or null"),
    ("match", lambda v: v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0),
     "a reference index (≥ 0) or null"),
    ("confidence", lambda v: v is None or _finite_number(v), "a finite number or null"),
)


def _check_frames(frames: Mapping[str, Any], source: str) -> None:
    for key, allowed, what in _FRAME_VALUES:
        values = frames.get(key)
        if values is None:
            continue
        if not isinstance(values, list):
            raise DataError(f"{source}: frames '{key}' must be a list, one value per query frame.")
        bad = next((k for k, v in enumerate(values) if not allowed(v)), None)
        if bad is not None:
            raise DataError(f"{source}: frames '{key}' must hold {what} per frame; frame {bad} holds "
                            f"{values[bad]!r}.")


# ---------------------------------------------------------------------------- table
def _flatten(params: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(params, Mapping):
        for key, value in params.items():
            name = f"{prefix}.{key}" if prefix else str(key)
            if isinstance(value, Mapping) and value:
                out.update(_flatten(value, name))
            else:
                out[name] = value
    return out


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value, separators=(",", ":"))
    return "null" if value is None else str(value)


def _summary(params: Mapping[str, Any], keys: Sequence[str]) -> str:
    return ", ".join(f"{k}={_format_value(params[k])}" for k in keys if k in params)


def _split_params(payloads: Sequence[dict]) -> tuple[list[dict[str, Any]], dict[str, Any], list[list[str]]]:
    """Flattened params per run, the ones shared by all runs, and each run's varying keys."""
    flat = [_flatten(p.get("params") or {}) for p in payloads]
    if len(flat) == 1:
        return flat, {}, [list(flat[0])]
    keys = list(dict.fromkeys(k for f in flat for k in f))
    shared = {k: flat[0][k] for k in keys if all(k in f and f[k] == flat[0][k] for f in flat)}
    varying = [[k for k in f if k not in shared] for f in flat]
    return flat, shared, varying


def run_labels(payloads: Sequence[Mapping[str, Any]]) -> list[str]:
    """A short, unique label per run.

    The payload's ``name``, else its ``method``; runs that would share a label get the
    parameters in which they differ appended (``"sequence (window=50)"``), and a
    counter if that is not enough.
    """
    base = [str(p.get("name") or p.get("method") or f"run {k + 1}") for k, p in enumerate(payloads)]
    labels = list(base)
    for name in set(base):
        group = [k for k, b in enumerate(base) if b == name]
        if len(group) < 2:
            continue
        flat, shared, varying = _split_params([payloads[k] for k in group])
        # the keys that tell the runs apart most first (a shuffle's seed before its kind), each
        # by its last part where that is unambiguous (seed=1, not condition.seed=1): the label is
        # cut at 40 characters, and what it keeps must still tell the runs apart
        keys = list(dict.fromkeys(k for v in varying for k in v))
        distinct = {k: len({repr(f.get(k)) for f in flat}) for k in keys}
        last = [k.rsplit(".", 1)[-1] for k in keys]
        short = {k: (t if last.count(t) == 1 else k) for k, t in zip(keys, last)}
        for k, f, own in zip(group, flat, varying):
            ordered = sorted(own, key=lambda key: -distinct[key])
            text = ", ".join(f"{short[key]}={_format_value(f[key])}" for key in ordered if key in f)
            if text:
                labels[k] = f"{name} ({_shorten(text, 40)})"
    counts = {label: labels.count(label) for label in labels}
    seen: dict[str, int] = {}
    for k, label in enumerate(labels):
        if counts[label] > 1:
            seen[label] = seen.get(label, 0) + 1
            labels[k] = f"{label} #{seen[label]}"
    return labels


def environment_note(payloads: Sequence[Mapping[str, Any]]) -> str | None:
    """One sentence on the environments the runs were made in (``None`` where no run records
    one): shared by all, or what differs (versions, the compile target), which alone can move
    a metric's last digits (``docs/evaluation.md``, "Reproducing the tables on another machine")."""
    from .environment import DECISIVE

    envs = [p.get("environment") for p in payloads]
    known = [env for env in envs if isinstance(env, Mapping)]
    if not known:
        return None
    unrecorded = len(envs) - len(known)
    tail = f" {unrecorded} of the {len(envs)} runs do not record theirs." if unrecorded else ""
    differ = {key: sorted({str(env.get(key)) for env in known}) for key in DECISIVE}
    differ = {key: values for key, values in differ.items() if len(values) > 1}
    if differ:
        what = "; ".join(f"{key} {' / '.join(values)}" for key, values in differ.items())
        return (f"The runs were made in different environments ({what}): their metrics can differ in the last "
                f"digits for that alone.{tail}")
    env = known[0]
    return (f"Environment of the runs: catgraph {env.get('catgraph')}, numba {env.get('numba')}, kernels compiled "
            f"for {env.get('compiled_for')} ({env.get('processor')}).{tail}")


def _shorten(text: str, limit: int = _MAX_PARAM_CHARS) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _metric_cells(payloads: Sequence[dict]) -> list[list[tuple[str, bool]]]:
    """Formatted metric cells per run, each with a flag: best in its column."""
    rows: list[list[tuple[str, bool]]] = [[] for _ in payloads]
    for key, _, fmt, better in COLUMNS:
        values = [((p.get("metrics") or {}).get(key)) for p in payloads]
        numbers = [float(v) for v in values if v is not None and math.isfinite(float(v))]
        best = None
        if better and len(payloads) > 1 and numbers:
            best = max(numbers) if better == "max" else min(numbers)
        for row, value in zip(rows, values):
            if value is None or not math.isfinite(float(value)):
                row.append(("–", False))
            else:
                row.append((fmt.format(float(value)), best is not None and float(value) == best))
    return rows


def markdown_table(results: Sequence[Mapping[str, Any] | str | os.PathLike], title: str | None = None) -> str:
    """The comparison table as GitHub-flavoured markdown (the content of ``results.md``).

    Parameters
    ----------
    results : sequence of dict or path
        As for :func:`write_report`.
    title : str, optional
        A level-1 heading above the table.

    Returns
    -------
    str
    """
    payloads = load_results(results)
    labels = run_labels(payloads)
    flat, shared, varying = _split_params(payloads)
    cells = _metric_cells(payloads)

    def esc(text: str) -> str:
        return text.replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")

    lines = []
    if title:
        lines += [f"# {esc(title)}", ""]
    header = ["method", "params"] + [c[1] for c in COLUMNS]
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join([":--", ":--"] + ["--:"] * len(COLUMNS)) + "|")
    for label, f, keys, row in zip(labels, flat, varying, cells):
        metric_text = [f"**{text}**" if best else text for text, best in row]
        lines.append("| " + " | ".join([esc(label), esc(_summary(f, keys)) or "–"] + metric_text) + " |")
    if shared:
        lines += ["", "Shared by all runs: " + esc(_summary(shared, list(shared))) + "."]
    environment = environment_note(payloads)
    if environment:
        lines += ["", esc(environment)]
    lines += ["", "AUC: area under the precision–recall curve; R@xP: largest recall at precision ≥ x %; "
              "MTL: longest run of consecutive query frames without a correct match; "
              "accuracy: correct frames / frames with a true match; n: query frames. Best per column in bold."]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- figures
def _png_data_uri(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, metadata={"Software": None})
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def initialisation_frames(payload: Mapping[str, Any]) -> int:
    """Frames an online-learning run spends initialising (its ``n_init``/``T_init``), else 0.

    Read from the run's parameters: a key ``n_init`` (at any depth) whose sibling
    ``learning``, where present, is ``"online"``.
    """
    flat = _flatten(payload.get("params") or {})
    for key, value in flat.items():
        if key.split(".")[-1] not in ("n_init", "init_frames", "t_init"):
            continue
        prefix = key.rsplit(".", 1)[0] + "." if "." in key else ""
        learning = flat.get(prefix + "learning", "online")
        if learning == "online" and isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
            n = len((payload.get("frames") or {}).get("query_index") or [])
            return int(min(value, n)) if n else int(value)
    return 0


def _standard_figures(payloads: Sequence[dict], labels: Sequence[str],
                      new_place_truth: Any = None) -> list[tuple[str, str]]:
    """(caption, data URI) of the figures the runs support."""
    from matplotlib.figure import Figure

    from . import plot

    colors = plot.method_colors(len(payloads))
    figures: list[tuple[str, str]] = []
    evaluated = [k for k, p in enumerate(payloads) if "correct" in p["frames"]]

    if evaluated:
        fig = Figure(figsize=(6.4, 4.6), layout="constrained")
        plot.plot_pr_curves([payloads[k] for k in evaluated], labels=[labels[k] for k in evaluated],
                            colors=[colors[k] for k in evaluated], ax=fig.add_subplot())
        figures.append(("Precision–recall curves (threshold swept over the confidence).", _png_data_uri(fig)))

    with_metrics = [k for k, p in enumerate(payloads) if p.get("metrics")]
    if with_metrics:
        width = max(8.0, min(16.0, 1.2 * len(with_metrics) + 4.0))
        fig = Figure(figsize=(width, 3.8), layout="constrained")
        ax_auc, ax_mtl = fig.subplots(1, 2)
        chosen = [payloads[k] for k in with_metrics]
        names = [labels[k] for k in with_metrics]
        chosen_colors = [colors[k] for k in with_metrics]
        plot.plot_metric_bars(chosen, "auc", labels=names, colors=chosen_colors, ax=ax_auc)
        plot.plot_metric_bars(chosen, "mtl", labels=names, colors=chosen_colors, ax=ax_mtl)
        ax_auc.set_title("AUC (higher is better)", fontsize="medium")
        ax_mtl.set_title("MTL, frames (lower is better)", fontsize="medium")
        figures.append(("Area under the PR curve and maximum time to localisation per run.", _png_data_uri(fig)))

    if evaluated:
        fig = Figure(figsize=(9.0, 0.9 + 0.32 * len(evaluated)), layout="constrained")
        init = [initialisation_frames(payloads[k]) for k in evaluated]
        plot.plot_localisation_timeline([payloads[k] for k in evaluated], labels=[labels[k] for k in evaluated],
                                        ax=fig.add_subplot(), initialisation=init)
        caption = ("Query frames in processing order: correct match (green), wrong match (red), "
                   "no output (grey). The longest stretch without green is the MTL.")
        if any(init):
            caption += (" Hatched: the online model's initialisation stage (T_init frames), in which it only "
                        "collects samples of differences between different places and cannot localise yet; "
                        "its answers there are noise by design, not failures.")
        figures.append((caption, _png_data_uri(fig)))

    windowed = [k for k, p in enumerate(payloads) if _usable(p["frames"].get("window_length"))]
    if windowed:
        fig = Figure(figsize=(9.0, 3.2), layout="constrained")
        values = [payloads[k]["frames"]["window_length"] for k in windowed]
        plot.plot_window_length(values, labels=[labels[k] for k in windowed], colors=[colors[k] for k in windowed],
                                ax=fig.add_subplot(), log_scale=_spans_decades(values))
        figures.append(("Window length chosen for each query frame.", _png_data_uri(fig)))

    new_place = []
    for k, p in enumerate(payloads):
        key = next((key for key in _NEW_PLACE_KEYS if _usable(p["frames"].get(key))), None)
        if key is not None:
            new_place.append((k, key))
    if new_place:
        fig = Figure(figsize=(9.0, 3.2), layout="constrained")
        plot.plot_new_place_probability([payloads[k]["frames"][key] for k, key in new_place],
                                        labels=[labels[k] for k, _ in new_place], is_new_place=new_place_truth,
                                        colors=[colors[k] for k, _ in new_place], ax=fig.add_subplot())
        caption = "Probability that the current frame shows a place not in the map (one colour per run, as above)."
        if new_place_truth is not None:
            caption += " Shaded: frames truly outside the map."
        figures.append((caption, _png_data_uri(fig)))
    return figures


def _usable(values: Any) -> bool:
    return isinstance(values, Sequence) and any(v is not None for v in values)


def _spans_decades(series: Sequence[Sequence[Any]]) -> bool:
    values = [float(v) for s in series for v in s if v is not None and float(v) > 0]
    return bool(values) and max(values) / min(values) >= 20


def _extra_figures(extra: Any) -> list[tuple[str, str]]:
    """(caption, data URI) of user figures: Figure, Axes or a .png/.svg file."""
    if extra is None:
        return []
    items = list(extra.items()) if isinstance(extra, Mapping) else list(extra)
    out = []
    for item in items:
        if not (isinstance(item, tuple) and len(item) == 2):
            raise InvalidParameterError(
                "extra_figures must be a mapping caption → figure or a list of (caption, figure) pairs; "
                f"got an item {type(item).__name__}."
            )
        caption, figure = item
        if hasattr(figure, "savefig"):
            out.append((str(caption), _png_data_uri(figure)))
        elif hasattr(figure, "figure") and hasattr(figure.figure, "savefig"):
            out.append((str(caption), _png_data_uri(figure.figure)))
        elif isinstance(figure, (str, os.PathLike)):
            path = Path(figure)
            kinds = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
            if path.suffix.lower() not in kinds:
                raise InvalidParameterError(f"extra figure {path} must be a .png, .svg or .jpg file.")
            if not path.is_file():
                from .exceptions import DataNotFoundError

                raise DataNotFoundError(f"extra figure {path} does not exist.")
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            out.append((str(caption), f"data:{kinds[path.suffix.lower()]};base64,{data}"))
        else:
            raise InvalidParameterError(
                f"extra figure {caption!r} must be a matplotlib Figure or Axes or an image path; "
                f"got {type(figure).__name__}."
            )
    return out


# ---------------------------------------------------------------------------- HTML
_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;margin:2rem auto;
max-width:1100px;padding:0 1rem;color:#222;line-height:1.45}
h1{font-size:1.6rem;margin-bottom:.2rem}h2{font-size:1.2rem;margin-top:2rem;border-bottom:1px solid #ddd}
p.meta{color:#666;margin-top:0}
table{border-collapse:collapse;font-size:.9rem;width:100%}
th,td{padding:.35rem .6rem;border-bottom:1px solid #e3e3e3;text-align:left;vertical-align:top}
th{background:#f4f4f4;font-weight:600}td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
td.best{font-weight:700}td.params{color:#555;font-size:.82rem;max-width:26rem;overflow-wrap:anywhere}
span.swatch{display:inline-block;width:.8rem;height:.8rem;border-radius:2px;margin-right:.4rem;vertical-align:-1px}
figure{margin:1.5rem 0;text-align:center}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#555;font-size:.88rem;margin-top:.3rem}
details{margin:.4rem 0}pre{background:#f7f7f7;padding:.6rem;overflow-x:auto;font-size:.8rem}
p.note{color:#555;font-size:.85rem}
p.reading{background:#fffbe6;border-left:3px solid #e0c050;padding:.5rem .8rem;font-size:.92rem}
""".strip()


def _notes(notes: Any) -> list[str]:
    if notes is None:
        return []
    items = [notes] if isinstance(notes, str) else list(notes) if isinstance(notes, Sequence) else None
    if items is None or not all(isinstance(n, str) for n in items):
        raise InvalidParameterError(f"notes must be a string or a sequence of strings; got {type(notes).__name__}.")
    return [" ".join(n.split()) for n in items if n.strip()]


def _hex(color) -> str:
    r, g, b = (int(round(255 * c)) for c in color[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def _html_page(title: str, payloads: Sequence[dict], figures: Sequence[tuple[str, str]],
               notes: Sequence[str] = ()) -> str:
    from . import __version__
    from .plot import method_colors

    e = html.escape
    labels = run_labels(payloads)
    flat, shared, varying = _split_params(payloads)
    cells = _metric_cells(payloads)
    colors = method_colors(len(payloads))

    head = ['<th>method</th>', '<th>params</th>'] + [f'<th class="num">{e(c[1])}</th>' for c in COLUMNS]
    body = []
    for label, f, keys, row, color in zip(labels, flat, varying, cells, colors):
        items = [f"{k}={_format_value(f[k])}" for k in keys if k in f]
        tds = [f'<td><span class="swatch" style="background:{_hex(color)}"></span>{e(label)}</td>',
               f'<td class="params">{"<br>".join(e(item) for item in items) or "–"}</td>']
        tds += [f'<td class="num{" best" if best else ""}">{e(text)}</td>' for text, best in row]
        body.append("<tr>" + "".join(tds) + "</tr>")

    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f'<meta name="generator" content="catgraph {e(__version__)}">',
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        f'<p class="meta">{len(payloads)} run{"s" if len(payloads) != 1 else ""} · catgraph {e(__version__)}</p>',
        "<h2>Summary</h2>",
        '<table id="metrics"><thead><tr>' + "".join(head) + "</tr></thead><tbody>",
        *body,
        "</tbody></table>",
    ]
    for note in notes:
        parts.append(f'<p class="reading">{e(note)}</p>')
    if shared:
        parts.append(f'<p class="note">Shared by all runs: {e(_summary(shared, list(shared)))}.</p>')
    environment = environment_note(payloads)
    if environment:
        parts.append(f'<p class="note">{e(environment)}</p>')
    parts.append('<p class="note">AUC: area under the precision–recall curve. R@xP: largest recall at precision '
                 "≥ x %. MTL: longest run of consecutive query frames without a correct match. Accuracy: correct "
                 "frames / frames with a true match. n: query frames. Best value per column in bold.</p>")
    if figures:
        parts.append("<h2>Figures</h2>")
        for k, (caption, uri) in enumerate(figures):
            parts.append(f'<figure><img src="{uri}" alt="{e(caption)}" id="figure-{k + 1}">'
                         f"<figcaption>{e(caption)}</figcaption></figure>")
    parts.append("<h2>Runs</h2>")
    for label, payload in zip(labels, payloads):
        detail = {key: payload.get(key) for key in ("method", "name", "params", "metrics", "seconds", "environment")
                  if key in payload}
        parts.append(f"<details><summary>{e(label)}</summary><pre>"
                     f"{e(json.dumps(detail, indent=2, ensure_ascii=False))}</pre></details>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_report(
    results: Sequence[Mapping[str, Any] | str | os.PathLike],
    out_dir: str | os.PathLike,
    title: str = "catgraph report",
    extra_figures: Mapping[str, Any] | Sequence[tuple[str, Any]] | None = None,
    notes: str | Sequence[str] | None = None,
    new_place_truth: Any = None,
) -> Path:
    """Write ``index.html`` and ``results.md`` comparing the runs into ``out_dir``.

    Parameters
    ----------
    results : sequence of dict or path
        Result payloads or paths to result JSON files, in the order to show them.
    out_dir : path
        Folder to write into (created if missing; files of the same name are replaced).
    title : str
        Page title and heading.
    extra_figures : mapping caption → figure, or sequence of (caption, figure), optional
        More figures to append: a matplotlib ``Figure`` or ``Axes``, or a path to a
        ``.png``/``.svg``/``.jpg`` file (embedded, not linked).
    notes : str or sequence of str, optional
        Paragraphs shown right under the table (and under the markdown table): how to
        read the numbers, e.g. why a method loses on this input.
    new_place_truth : array-like of bool, shape (n,), optional
        Which query frames (in processing order) are truly outside the map; shaded on
        the ``P(new place)`` figure.

    Returns
    -------
    Path
        The path of ``index.html``.

    Raises
    ------
    InvalidParameterError
        No results, a bad ``extra_figures`` entry, or ``out_dir`` is a file.
    DataNotFoundError, DataError
        A result file is missing, unreadable or not a catgraph result.

    Examples
    --------
    >>> from catgraph.report import write_report
    >>> write_report(["single.json", "adaptive.json"], "report/")  # doctest: +SKIP
    PosixPath('report/index.html')
    """
    payloads = load_results(results)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidParameterError(
            f"the report folder {out} is a file; give a folder path (it is created if missing)."
        )
    title = str(title)
    notes = _notes(notes)
    figures = _standard_figures(payloads, run_labels(payloads), new_place_truth) + _extra_figures(extra_figures)
    page = _html_page(title, payloads, figures, notes)
    table = markdown_table(payloads, title=title)
    if notes:
        table += "\n" + "\n\n".join(notes) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    index = out / "index.html"
    write_text_atomic(index, page)
    write_text_atomic(out / "results.md", table)
    return index
