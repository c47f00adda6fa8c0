"""Rule "tracked" and variants of it, on the whole condition table (measured; diagnosis).

Rule "tracked" (the library's default window rule) chooses, of the candidate lengths (each
at its own most significant velocity), the one whose best place holds the most of a
tracking filter's place posterior within ±1 place. This script recomputes that choice
from the matcher's per-frame statistics (`rule_harness.py`'s cache) and the tracking
filter (the registry's ``filter`` method as the grid, as
`catgraph._window_rule.tracking_filter` makes it, stepped on the same raw rows; its place
posteriors cached beside the statistics) and measures variants of the choice, each seeing
only the frames. The first row is the library's rule itself; the next is the rule with
its filter's rigid line off (``rigid_prior`` 0: the rule before the rigid line), and the
variants below, but the last, are variants of that one:

* **fallback when no window agrees**: where the most any window's best place holds is less
  than ``κ`` times the most any ±1 neighbourhood of the posterior holds (the filter's
  own answer agrees with no window), the most significant window instead;
* **mass times significance**: each window's mass weighed by its significance, the
  window maximising ``log mass − λ · log p / L`` (``log p`` the window's log probability of
  a draw at most its best score, ``L`` its length: the evidence per frame);
* **mass times tempered evidence**: the window maximising ``log mass − η · log p`` (the
  window's whole evidence, tempered: the filter has read the same rows);
* **mass times relative significance**: the window maximising ``log mass + ρ · log p /
  min log p`` (the window's significance as a share of the frame's most significant
  window's: scale-free);
* **a tracker with a rigid line**: the choice of rule "tracked" with its filter given a rigid
  line beside its motion (``rigid_prior``, `catgraph.grid`).

Run from the repository root::

    python benchmarks/rule_tracked_variants.py [--datasets Nordland,UJI,synthetic] [--out NAME]

writes ``benchmarks/results/NAME.md`` and ``.json`` (default ``window_tracked_variants``).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import rule_harness as H  # noqa: E402
from rule_filter_track import cell_of, log_odds, write_tables  # noqa: E402

from catgraph import _window_rule as wr  # noqa: E402
from catgraph.metrics import evaluate  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
KAPPAS = (0.1, 0.25, 0.5)
LAMBDAS = (0.1, 0.3, 1.0)
ETAS = (0.02, 0.05, 0.1)
RHOS = (1.0, 2.0, 3.0, 5.0)
RIGIDS = (0.05, 0.01)


def tracker_posterior(key: str, raw: np.ndarray, rigid: float = 0.0) -> np.ndarray:
    """The library's tracking filter's place posterior after each raw row (float32, cached);
    ``rigid``: the same filter with a rigid line beside its motion (``rigid_prior``)."""
    h = hashlib.sha1(np.ascontiguousarray(raw).tobytes()).hexdigest()[:12]
    tag = f"_rigid{rigid:g}" if rigid else ""
    path = H.CACHE / f"tracker{tag}_{key.replace(' ', '_').replace('/', '-')}_{h}.npy"
    if path.exists():
        return np.load(path)
    from catgraph.graph import PlaceGraph
    from catgraph.methods import make_filter, observation_model, resolve_params

    params = resolve_params("filter", {"mode": "grid", "rigid_prior": rigid})
    f = make_filter(params, PlaceGraph.chain(raw.shape[1]), observation_model(params, raw.shape[1], None))
    out = np.empty(raw.shape, dtype=np.float32)
    for t, row in enumerate(raw):
        f.step(row)
        out[t] = f.place_posterior_
    H.CACHE.mkdir(parents=True, exist_ok=True)
    np.save(path, out)
    return out


def window_masses(st: wr._Stats, posterior: np.ndarray, radius: int = wr.TRACK_PLACES):
    """Each length's most significant velocity, best place, its ±radius mass and log p."""
    log_p = wr._log_p(st)
    v = np.argmin(log_p, axis=1)                                          # (n, G)
    j = np.take_along_axis(st.best_j, v[:, None, :], axis=1)[:, 0, :]     # (n, G)
    lp = np.take_along_axis(log_p, v[:, None, :], axis=1)[:, 0, :]        # (n, G)
    n_places = posterior.shape[1]
    cum = np.concatenate([np.zeros((len(j), 1)), np.cumsum(posterior.astype(np.float64), axis=1)], axis=1)
    lo = np.clip(j - radius, 0, n_places)
    hi = np.clip(j + radius + 1, 0, n_places)
    mass = np.take_along_axis(cum, hi, axis=1) - np.take_along_axis(cum, lo, axis=1)
    top = (cum[:, 2 * radius + 1:] - cum[:, :-(2 * radius + 1)]).max(axis=1)   # the best ±radius neighbourhood
    return v, j, mass, lp, top


def longest_argmax(x: np.ndarray) -> np.ndarray:
    return x.shape[1] - 1 - np.argmax(x[:, ::-1], axis=1)


def methods() -> list[str]:
    return (["tracked (library)", "tracked without the rigid line (the rule before)"]
            + [f"fallback to most significant, κ = {k:g}" for k in KAPPAS]
            + [f"mass × significance, λ = {lam:g}" for lam in LAMBDAS]
            + [f"mass × p^−η, η = {eta:g}" for eta in ETAS]
            + [f"mass × e^(ρ·relative significance), ρ = {rho:g}" for rho in RHOS]
            + [f"tracker with a rigid line, prior {r:g}" for r in RIGIDS])


def answers(st: wr._Stats, raw: np.ndarray, rows: np.ndarray, posterior: np.ndarray, rigid: list) -> dict:
    cfg = H.config("tracked", confidence="tracked")
    rec = wr._new_record(cfg)
    lib = wr._decide(st, cfg, np.arange(rows.shape[0]), False, rows, rec, raw_rows=raw)
    out = {methods()[0]: (lib[0], lib[2])}
    v, j, mass, lp, top = window_masses(st, posterior)
    n = np.arange(len(j))
    g = longest_argmax(mass)
    out[methods()[1]] = (j[n, g], log_odds(mass[n, g]))
    significant = np.argmin(lp, axis=1)
    for k, m in zip(KAPPAS, methods()[2:2 + len(KAPPAS)]):
        lost = mass[n, g] < k * top
        gg = np.where(lost, significant, g)
        out[m] = (j[n, gg], log_odds(mass[n, gg]))
    lengths = np.asarray(H.config().grid, dtype=np.float64)
    for lam, m in zip(LAMBDAS, methods()[2 + len(KAPPAS):]):
        s = np.log(np.maximum(mass, 1e-300)) - lam * lp / lengths[None, :]
        gg = longest_argmax(s)
        out[m] = (j[n, gg], log_odds(mass[n, gg]))
    for eta, m in zip(ETAS, methods()[2 + len(KAPPAS) + len(LAMBDAS):]):
        s = np.log(np.maximum(mass, 1e-300)) - eta * lp
        gg = longest_argmax(s)
        out[m] = (j[n, gg], log_odds(mass[n, gg]))
    most = lp.min(axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(most < 0, np.minimum(lp, 0.0) / most, 0.0)   # 1 at the most significant, 0 at none
    for rho, m in zip(RHOS, methods()[2 + len(KAPPAS) + len(LAMBDAS) + len(ETAS):]):
        s = np.log(np.maximum(mass, 1e-300)) + rho * relative
        gg = longest_argmax(s)
        out[m] = (j[n, gg], log_odds(mass[n, gg]))
    for post, m in zip(rigid, methods()[-len(RIGIDS):]):
        _, j, mass, _, _ = window_masses(st, post)
        gg = longest_argmax(mass)
        out[m] = (j[n, gg], log_odds(mass[n, gg]))
    return out


def measure(datasets: tuple[str, ...]) -> list[dict]:
    from datasets import conditioned

    from catgraph.conditions import condition_table
    from catgraph.hubs import hub_offsets
    from catgraph.pipeline import differences

    best = H._best_fixed_table()
    cells = []
    for name, cases in H.dataset_groups(datasets):
        offsets = hub_offsets(differences(cases[0].reference, cases[0].reference))
        for condition in condition_table(seeds=range(5)):
            aucs = {m: [] for m in methods()}
            for case in cases:
                c = conditioned(case, condition)
                key = f"{case.name} {condition.label}"
                st, rows = H.cached_stats(key, c.differences, offsets)
                posterior = tracker_posterior(key, np.ascontiguousarray(c.differences))
                rigid = [tracker_posterior(key, np.ascontiguousarray(c.differences), r) for r in RIGIDS]
                for m, (match, conf) in answers(st, c.differences, rows, posterior, rigid).items():
                    aucs[m].append(evaluate(c.query.index, match, conf, c.ground_truth).metrics.auc)
            cells.append(cell_of(name, condition.label, best[(name, condition.label)], aucs))
    return cells


def write(cells: list[dict], seconds: float, out: str) -> None:
    from bench_cold_install import _commit

    write_tables(cells, methods(), out, "Rule \"tracked\" and variants of its choice",
                 f"Measured at commit `{_commit()}`. Generated by `benchmarks/rule_tracked_variants.py` (module "
                 f"docstring: the variants) in {seconds / 60:.1f} minutes. AUC per cell (UJI: mean of months 02–06); "
                 "*best fixed*: the committed best fixed window of the cell (`sequence.json`), chosen with hindsight.")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default="Nordland,UJI,synthetic")
    ap.add_argument("--out", default="window_tracked_variants")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    cells = measure(tuple(args.datasets.split(",")))
    write(cells, time.perf_counter() - start, args.out)


if __name__ == "__main__":
    main()
