"""The adaptive window capped by the run length of a tracker's track (measured; not a rule).

A window "must not reach across a discontinuity": the ideal window of a frame is the
number of frames since the query's last jump. This script asks how close the matcher
comes to the best fixed window when that run length is known (an oracle: the jumps of the
condition's shuffle, read for this diagnosis only) and when it is *estimated* online by the
library's grid filter (`GridLocalizer(graph, TemperedObservation())`, the registry's map
graph, as `bench_filter.py` runs it) on the same frames:

* **answer continuity**: frames since the filter's answer last moved by more than 5 places
  from one frame to the next;
* **posterior track** (`θ`): from the filter's answer at frame ``t``, the longest line of
  one of the matcher's velocities back in time along which the filter's place posterior of
  every earlier frame holds at least ``θ / N`` within ±3 places (``θ`` times the uniform
  mass), at most 5 frames in a row below it;
* **with the default rule**: the longer, or the shorter, of the default rule's window
  (``"challenged"``) and the posterior track's run length + 1 (``θ`` = 10).

Two more rows choose the window instead of capping it: **the window chosen by the
filter's posterior** is, of the grid's lengths (each at its most significant velocity),
the one whose best place holds the most of the filter's place posterior within
±``TRACK_PLACES`` places (the longest of equals). Its confidence is either the gaps of the
agreeing windows (as below) or that mass as log-odds; four more rows count the mass
within ±0, 1, 2 and 5 places instead (the library's rule "tracked" is the ±1 row, on the
chain of the reference's places rather than the registry's map graph).

In every capped variant the window of frame ``t`` is the longest of the matcher's window lengths
(``cfg.grid``) at most the run length + 1 (at least ``l_min``); the velocity is the most
significant at that length, the match its best place, and the confidence the sum of the
gaps of the windows up to it whose best place agrees within the exclusion radius (the
library's weighed confidence without its change-point factor). The matcher's per-frame
statistics come from `rule_harness.py`'s cache, so the matcher is the library's.

Run from the repository root (about 10 minutes on 2 cores; the filter's posteriors are
cached beside the harness's statistics)::

    python benchmarks/rule_filter_track.py [--datasets Nordland,UJI,synthetic]

writes ``benchmarks/results/window_filter_track.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter1d

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import rule_harness as H  # noqa: E402

from catgraph import _window_rule as wr  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
ORACLE_PLACES = 3  # a speed-2 query moves 2 places a frame; a jump moves more
CONTINUITY_PLACES = 5
TRACK_PLACES = 3
TRACK_MISSES = 5
THETAS = (10.0, 100.0)
CHOICE_RADII = (0, 1, 2, 5)  # ±TRACK_PLACES (3) is the row before them


def filter_run(key: str, graph, d: np.ndarray, query_index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid filter's answers, scores and place posteriors (cached on disk)."""
    from catgraph.grid import GridLocalizer
    from catgraph.observation import TemperedObservation

    h = hashlib.sha1(np.ascontiguousarray(d).tobytes()).hexdigest()[:12]
    path = H.CACHE / f"filter_{key.replace(' ', '_').replace('/', '-')}_{h}.npz"
    if path.exists():
        z = np.load(path)
        return z["place"], z["score"], z["posterior"]
    r = GridLocalizer(graph, TemperedObservation()).run(d, query_index=query_index, return_posterior=True)
    H.CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, place=r.place, score=r.score, posterior=r.posterior)
    return r.place, r.score, r.posterior


def run_length(sequence: np.ndarray, places: int) -> np.ndarray:
    """Frames since ``sequence`` last moved by more than ``places`` from one frame to the
    next: the query's own index (the oracle, diagnosis only) or the filter's answers."""
    q = np.asarray(sequence, dtype=np.int64)
    r = np.zeros(len(q), dtype=np.int64)
    for t in range(1, len(q)):
        r[t] = r[t - 1] + 1 if abs(q[t] - q[t - 1]) <= places else 0
    return r


def track_run_length(posterior: np.ndarray, place: np.ndarray, velocities: np.ndarray, theta: float,
                     k_max: int) -> np.ndarray:
    """The posterior track's run length of every frame (see the module docstring)."""
    n, n_places = posterior.shape
    held = maximum_filter1d(posterior, size=2 * TRACK_PLACES + 1, axis=1) >= theta / n_places
    out = np.zeros(n, dtype=np.int64)
    window = np.ones(TRACK_MISSES + 1)
    for t in range(1, n):
        k = np.arange(1, min(k_max, t) + 1)
        best = 0
        for v in velocities:
            x = np.rint(place[t] - v * k).astype(np.int64)
            inside = (x >= 0) & (x < n_places)
            ok = np.zeros(len(k), dtype=bool)
            ok[inside] = held[t - k[inside], x[inside]]
            # cut at the first run of more than TRACK_MISSES frames below θ / N
            runs = np.convolve(~ok, window, mode="valid") >= TRACK_MISSES + 1
            stop = int(np.argmax(runs)) if runs.any() else len(k)
            hits = np.flatnonzero(ok[:stop])
            if hits.size:
                best = max(best, int(k[hits[-1]]))
        out[t] = best
    return out


def capped(st: wr._Stats, run_length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Match and confidence with each frame's window capped at its run length + 1."""
    grid = H.config().grid
    g = np.clip(np.searchsorted(grid, np.maximum(run_length + 1, grid[0]), side="right") - 1, 0, len(grid) - 1)
    return at_window(st, g)


def chosen_by_posterior(st: wr._Stats, posterior: np.ndarray, radius: int = TRACK_PLACES
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's window chosen by the filter: of the grid's lengths (each at its most
    significant velocity), the one whose best place holds the most place posterior within
    ±``radius`` places (the longest of equals). Returns the window's index and that mass."""
    rows = np.arange(st.best_s.shape[0])
    v = np.argmin(wr._log_p(st), axis=1)                      # (n, G)
    j = np.take_along_axis(st.best_j, v[:, None, :], axis=1)[:, 0, :]
    n_places = posterior.shape[1]
    cum = np.concatenate([np.zeros((len(rows), 1)), np.cumsum(posterior, axis=1)], axis=1)
    j = np.clip(j, 0, n_places - 1)
    lo = np.clip(j - radius, 0, n_places)
    hi = np.clip(j + radius + 1, 0, n_places)
    mass = np.take_along_axis(cum, hi, axis=1) - np.take_along_axis(cum, lo, axis=1)
    g = mass.shape[1] - 1 - np.argmax(mass[:, ::-1], axis=1)
    return g, mass[rows, g]


def log_odds(mass: np.ndarray) -> np.ndarray:
    held = np.clip(mass, 1e-300, 1.0 - 1e-16)
    return np.log(held) - np.log1p(-held)


def at_window(st: wr._Stats, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Match and confidence of each frame at window index ``g`` (its most significant
    velocity; the gaps of the agreeing windows up to it summed)."""
    cfg = H.config()
    grid, rows = cfg.grid, np.arange(st.best_s.shape[0])
    v = np.argmin(wr._log_p(st)[rows, :, g], axis=1)
    match = st.best_j[rows, v, g]
    std = wr._common_std(st)[:, 0, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        gaps = np.where(std > 0, (st.second_s[rows, v] - st.best_s[rows, v]) / std, 0.0)
    gaps = np.where(np.isfinite(gaps), gaps, 0.0)
    agree = (np.arange(len(grid))[None, :] <= g[:, None]) & (np.abs(st.best_j[rows, v] - match[:, None])
                                                            <= cfg.radius)
    return match, np.where(agree, gaps, 0.0).sum(axis=1)


def methods() -> list[str]:
    return (["default rule (\"challenged\")", "grid filter itself", "cap: oracle run length (diagnosis)",
             "cap: answer continuity"] + [f"cap: posterior track, θ = {t:g}" for t in THETAS]
            + ["cap: the longer of the default's window and the track's (θ = 10)", "cap: the shorter of the two",
               "window chosen by the filter's posterior, gaps", "window chosen by the filter's posterior, its mass"]
            + [f"chosen by the posterior within ±{r}, its mass" for r in CHOICE_RADII])


def measure(datasets: tuple[str, ...]) -> list[dict]:
    from datasets import conditioned

    from catgraph.conditions import condition_table
    from catgraph.hubs import hub_offsets
    from catgraph.io import place_graph
    from catgraph.pipeline import differences

    best = H._best_fixed_table()
    groups = H.dataset_groups(datasets)
    default = H.library_rule("challenged", confidence="changepoint")
    velocities = np.asarray(H.config().velocities)
    k_max = int(H.config().grid[-1])
    cells = []
    for name, cases in groups:
        offsets = hub_offsets(differences(cases[0].reference, cases[0].reference))
        graphs = [place_graph(c.reference) for c in cases]
        for condition in condition_table(seeds=range(5)):
            aucs = {m: [] for m in methods()}
            for case, graph in zip(cases, graphs):
                c = conditioned(case, condition)
                key = f"{case.name} {condition.label}"
                st, rows = H.cached_stats(key, c.differences, offsets)
                place, score, posterior = filter_run(key, graph, c.differences, c.query.index)
                qi, truth = c.query.index, c.ground_truth
                answers = {methods()[0]: default(st, rows, None), methods()[1]: (place, score),
                           methods()[2]: capped(st, run_length(qi, ORACLE_PLACES)),
                           methods()[3]: capped(st, run_length(place, CONTINUITY_PLACES))}
                tracks = {t: track_run_length(posterior, place, velocities, t, k_max) for t in THETAS}
                for theta, m in zip(THETAS, methods()[4:]):
                    answers[m] = capped(st, tracks[theta])
                cfg = H.config("challenged", confidence="changepoint")
                length = wr._decide(st, cfg, np.arange(rows.shape[0]), False, rows, wr._new_record(cfg))[3]
                answers[methods()[6]] = capped(st, np.maximum(length, tracks[10.0] + 1) - 1)
                answers[methods()[7]] = capped(st, np.minimum(length, tracks[10.0] + 1) - 1)
                g, mass = chosen_by_posterior(st, posterior)
                answers[methods()[-2 - len(CHOICE_RADII)]] = at_window(st, g)
                answers[methods()[-1 - len(CHOICE_RADII)]] = (at_window(st, g)[0], log_odds(mass))
                for r, m in zip(CHOICE_RADII, methods()[-len(CHOICE_RADII):]):
                    g, mass = chosen_by_posterior(st, posterior, r)
                    answers[m] = (at_window(st, g)[0], log_odds(mass))
                for m, (match, conf) in answers.items():
                    aucs[m].append(evaluate(qi, match, conf, truth).metrics.auc)
            cells.append(cell_of(name, condition.label, best[(name, condition.label)], aucs))
    return cells


def cell_of(dataset: str, condition: str, best_fixed: float, aucs: dict) -> dict:
    """One cell of the table (each method's mean AUC over the cell's cases), printed as it is made."""
    cell = {"dataset": dataset, "condition": condition, "best_fixed": best_fixed,
            "auc": {m: float(np.mean(a)) for m, a in aucs.items()}}
    print(f"{dataset[:10]:10s} {condition:28s} best fixed {best_fixed:.3f} "
          + " ".join(f"{a:.3f}" for a in cell["auc"].values()), flush=True)
    return cell


def summary(cells: list[dict], method: str, dataset: str) -> tuple[float, float, int, int]:
    m = np.array([c["auc"][method] - c["best_fixed"] for c in cells if c["dataset"] == dataset])
    return float(m.mean()), float(m.min()), int(np.sum(m >= -0.01)), int(m.size)


def write_tables(cells: list[dict], names: list[str], stem: str, title: str, intro: str) -> None:
    """``RESULTS/stem.json`` (the cells) and ``stem.md``: the title, the intro, the margins to
    the best fixed window per method and dataset, and every cell's AUC."""
    datasets = list(dict.fromkeys(c["dataset"] for c in cells))
    (RESULTS / f"{stem}.json").write_text(json.dumps({"cells": cells}, indent=1))
    lines = [f"# {title}", "", intro, "",
             "## Margin to the best fixed window (mean / worst / cells within 0.01)", "",
             "| method | " + " | ".join(datasets) + " |", "|---|" + "---|" * len(datasets)]
    for m in names:
        lines.append(f"| {m} | " + " | ".join("{:+.3f} / {:+.3f} / {} of {}".format(*summary(cells, m, ds))
                                             for ds in datasets) + " |")
    lines += ["", "## Every cell (AUC)", "", "| dataset | condition | best fixed | " + " | ".join(names) + " |",
              "|---|---|---|" + "---|" * len(names)]
    for c in cells:
        lines.append(f"| {c['dataset']} | {c['condition']} | {c['best_fixed']:.3f} | "
                     + " | ".join(f"{c['auc'][m]:.3f}" for m in names) + " |")
    (RESULTS / f"{stem}.md").write_text("\n".join(lines) + "\n")


def write(cells: list[dict], seconds: float) -> None:
    from bench_cold_install import _commit  # the checkout's commit (git), "unknown" outside one

    write_tables(cells, methods(), "window_filter_track",
                 "The adaptive window and a tracker: capped by its run length, or chosen by its posterior",
                 f"Measured at commit `{_commit()}`. Generated by `benchmarks/rule_filter_track.py` (module docstring: "
                 f"the variants) in {seconds / 60:.1f} minutes. AUC per cell (UJI: mean of months 02–06); *best "
                 "fixed*: the committed best fixed window of the cell (`sequence.json`), chosen with hindsight. The "
                 "oracle reads the shuffle's jumps (diagnosis only); every other row sees only the frames.")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default="Nordland,UJI,synthetic")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    cells = measure(tuple(args.datasets.split(",")))
    write(cells, time.perf_counter() - start)


if __name__ == "__main__":
    main()
