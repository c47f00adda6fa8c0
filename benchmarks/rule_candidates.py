"""Candidate window rules for ``benchmarks/rule_harness.py`` (the diagnosis of docs/sequence.md,
section "0.2: why the adaptive window loses to a 5-frame window on unseen worlds").

Each candidate is a function ``rule(stats, rows, cfg) -> (match, confidence)`` built from the
library's own pieces (:mod:`catgraph._window_rule`), differing from rule "unrivalled" only in
the rival test: which sub-windows it tests (``fraction``), by how many common spreads the
window's line may trail the best line of a sub-window's length (``spreads``), and when that
best line counts as a rival (``gate``): ``"chance"`` — significant beyond the best of ``N``
random places (``log p < -ln N - margin``, the library's "unrivalled"); ``"distinct"`` — more
significant than the best place beyond the exclusion radius at that length by ``margin``
nats (``log p < log p_2 - margin``, ``p_2`` the same approximation at the second-best
score), a null measured at every frame and length instead of assumed.
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.special import log_ndtr

from catgraph import _window_rule as wr


def log_p_at(st, score):
    """``log P(S <= score)`` under each window's Gaussian widened to the common spread."""
    common = wr._common_std(st)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(common > 0, (score - st.mean) / common, np.where(score < st.mean, -np.inf, np.inf))
    return log_ndtr(z)


def admissible(st, cfg, log_p, n_places, spreads=0.5, fraction=0.2, gate="chance", margin=10.0, both=False,
               horizon=None):
    n, v_count, g_count = st.best_s.shape
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    mid = 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])
    ok = (st.sub <= mid) | ~recent
    common = wr._common_std(st)[:, :, None, :]
    ok &= (st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~shorter
    tested = shorter & (lengths[None, :] >= fraction * lengths[:, None])
    gate = gate.replace("horizon ", "")
    if gate == "chance":
        rival = log_p < -np.log(n_places) - margin
    else:
        rival = log_p < log_p_at(st, st.second_s) - margin
        if both:
            rival &= log_p < -np.log(n_places)
    if horizon is not None:  # a rival must span at least the query's decorrelation time
        rival &= lengths[None, None, :] >= horizon[:, None, None]
    beaten = st.sub > st.best_s[:, :, None, :] + spreads * common
    ok &= ~(beaten & rival[:, :, None, :]) | ~tested
    adm = np.all(ok, axis=3)
    adm[:, :, 0] = True
    return adm


_HORIZONS = {}


def horizons(rows):
    """Per frame, the decorrelation horizon of rule "decorrelated" (:class:`catgraph._window_rule._Horizon`)."""
    key = hashlib.sha1(np.ascontiguousarray(rows).tobytes()).hexdigest()
    if key not in _HORIZONS:
        clock = wr._Horizon()
        _HORIZONS[key] = np.array([clock.update(row, i, row.std()) for i, row in enumerate(rows)])
    return _HORIZONS[key]


def decide(st, rows, cfg, velocity="summed", vgate=None, vmargin=0.0, **kw):
    """Rule "unrivalled" with the rival test of ``kw`` (velocity, argmin p, confidence "posterior").

    ``velocity``: "summed" (the library's: most significant summed over every length), or
    "rechosen" (the window chosen at that velocity, then the velocity re-chosen as the most
    significant at the chosen length; the window's admission is not re-tested)."""
    n = st.best_s.shape[0]
    r = np.arange(n)
    log_p = wr._log_p(st)
    v = np.argmin(log_p.sum(axis=2), axis=1)
    if kw.pop("rival_horizon", False):
        kw["horizon"] = horizons(rows)
    adm_all = admissible(st, cfg, log_p, rows.shape[1], **kw)
    adm = adm_all[r, v]
    g = np.argmin(np.where(adm, log_p[r, v], np.inf), axis=1)
    if velocity == "perlength-horizon":
        # each length at its own velocity where it spans the decorrelation time, else the summed one
        own = np.argmin(log_p, axis=1)  # (n, G)
        vg = np.where(cfg.grid[None, :] >= horizons(rows)[:, None], own, v[:, None])
        lpg = np.take_along_axis(log_p, vg[:, None, :], axis=1)[:, 0]
        admg = np.take_along_axis(adm_all, vg[:, None, :], axis=1)[:, 0]
        g = np.argmin(np.where(admg, lpg, np.inf), axis=1)
        v = vg[r, g]
        adm = adm_all[r, v]
        adm[r, g] = True
    if velocity == "rechosen":
        at_g = log_p[r, :, g]  # (n, V)
        if vgate == "admitted":
            at_g = np.where(adm_all[r, :, g], at_g, np.inf)
        v2 = np.argmin(at_g, axis=1)
        lp2 = at_g[r, v2]
        if vgate == "chance":
            keep = lp2 < -np.log(rows.shape[1]) - vmargin
        elif vgate == "ratio":
            keep = lp2 < log_p[r, v, g] - vmargin
        elif vgate == "horizon":
            keep = cfg.grid[g] >= horizons(rows)
        elif vgate == "horizon+ratio":
            keep = (cfg.grid[g] >= horizons(rows)) & (lp2 < log_p[r, v, g] - vmargin)
        else:
            keep = np.ones(n, dtype=bool)
        v = np.where(keep, v2, v)
        adm = adm_all[r, v]
        adm[r, g] = True
    lp = log_p[r, v]
    best = st.best_s[r, v, g]
    match = st.best_j[r, v, g]
    stds = wr._common_std(st)[:, 0, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        gaps = np.where(stds > 0, (st.second_s[r, v] - st.best_s[r, v]) / stds, 0.0)
    gaps = np.where(np.isfinite(gaps), gaps, 0.0)
    agree = adm & (np.abs(st.best_j[r, v] - match[:, None]) <= cfg.radius)
    conf = np.where(agree, gaps, 0.0).sum(axis=1) * wr._on_line(*wr._current_z(rows, match, best))
    return match, conf, g, v


def rule(**kw):
    def apply(st, rows, cfg):
        return decide(st, rows, cfg, **kw)[:2]
    return apply


#: the rounds of the search, in the order they were measured (docs/sequence.md has the numbers);
#: "R" is the velocity re-chosen at the chosen length where it spans the decorrelation horizon
ROUNDS = {
    "1: the rival's gate and sub-windows; the velocity re-chosen": {
        "unrivalled (harness copy)": rule(),
        "unrivalled, velocity rechosen": rule(velocity="rechosen"),
        **{f"distinct m={m:g} f=0.05, velocity rechosen": rule(gate="distinct", margin=m, fraction=0.05,
                                                                velocity="rechosen") for m in (3, 5)},
        **{f"distinct m={m:g}": rule(gate="distinct", margin=m) for m in (3, 5, 7)},
        **{f"distinct m={m:g} f=0.05": rule(gate="distinct", margin=m, fraction=0.05) for m in (3, 5, 7)},
        **{f"distinct m={m:g} c=1": rule(gate="distinct", margin=m, spreads=1.0) for m in (3, 5)},
        **{f"chance m={m:g}": rule(gate="chance", margin=m) for m in (3, 5)},
    },
    "2: when to re-choose the velocity": {
        **{f"rechosen if chance m={m:g}": rule(velocity="rechosen", vgate="chance", vmargin=m) for m in (0, 3, 6)},
        **{f"rechosen if ratio m={m:g}": rule(velocity="rechosen", vgate="ratio", vmargin=m) for m in (1, 3, 6)},
        "rechosen among admitted": rule(velocity="rechosen", vgate="admitted"),
        "rechosen among admitted, distinct m=3": rule(velocity="rechosen", vgate="admitted", gate="distinct",
                                                      margin=3),
    },
    "3: the decorrelation horizon as the gate": {
        "rechosen if L >= horizon and ratio m=3": rule(velocity="rechosen", vgate="horizon+ratio", vmargin=3),
        **{f"horizon rival, chance m={m:g}, f={f:g}": rule(rival_horizon=True, margin=m, fraction=f)
           for m in (0, 5) for f in (0.05, 0.2)},
        "horizon rival, distinct m=3, f=0.05": rule(rival_horizon=True, gate="distinct", margin=3, fraction=0.05),
        "ratio m=3 + horizon rival chance m=0 f=0.05": rule(velocity="rechosen", vgate="ratio", vmargin=3,
                                                             rival_horizon=True, margin=0, fraction=0.05),
        "ratio m=3 + horizon rival distinct m=3 f=0.05": rule(velocity="rechosen", vgate="ratio", vmargin=3,
                                                               rival_horizon=True, gate="distinct", margin=3,
                                                               fraction=0.05),
        "ratio m=3 + distinct m=5": rule(velocity="rechosen", vgate="ratio", vmargin=3, gate="distinct", margin=5),
    },
    "4: R combined with a rival": {
        "R (rechosen if L >= horizon)": rule(velocity="rechosen", vgate="horizon"),
        "per-length velocity from the horizon": rule(velocity="perlength-horizon"),
        **{f"R + {gate} rival m={m:g} f={f:g}": rule(velocity="rechosen", vgate="horizon", rival_horizon=hz, gate=gate,
                                                     margin=m, fraction=f)
           for gate, m, f, hz in (("horizon chance", 5, 0.05, True), ("horizon chance", 5, 0.1, True),
                                  ("horizon distinct", 3, 0.05, True), ("horizon distinct", 5, 0.05, True),
                                  ("distinct", 5, 0.2, False), ("chance", 5, 0.2, False), ("distinct", 3, 0.2, False))},
    },
    "5: the margin, the gate and the spreads around R + horizon chance rival": {
        **{f"R + horizon chance rival m={m:g} f=0.05": rule(velocity="rechosen", vgate="horizon", rival_horizon=True,
                                                           margin=m, fraction=0.05) for m in (3, 4, 6, 7)},
        **{f"R + horizon distinct rival m={m:g} f=0.05": rule(velocity="rechosen", vgate="horizon",
                                                             rival_horizon=True, gate="distinct", margin=m,
                                                             fraction=0.05) for m in (4, 6, 7)},
        **{f"R + horizon chance rival m=5 f=0.05 c={c:g}": rule(velocity="rechosen", vgate="horizon",
                                                               rival_horizon=True, margin=5, fraction=0.05, spreads=c)
           for c in (0.25, 1.0)},
        "R + chance rival m=5 f=0.05 (no horizon gate)": rule(velocity="rechosen", vgate="horizon", margin=5,
                                                              fraction=0.05),
    },
}

ROUNDS["6: around rule 'spanning' (m = 6)"] = {
    "R + horizon chance rival m=6 f=0": rule(velocity="rechosen", vgate="horizon", rival_horizon=True, margin=6,
                                             fraction=0.0),
    **{f"per-length velocity from the horizon + horizon chance rival m={m:g} f=0.05": rule(
        velocity="perlength-horizon", rival_horizon=True, margin=m, fraction=0.05) for m in (6, 8)},
}

#: the parts of rule "spanning" alone (its margin, :data:`catgraph._window_rule.SPANNING_MARGIN`)
ABLATIONS = {
    "spanning without the rival (velocity re-chosen only)": rule(velocity="rechosen", vgate="horizon"),
    "spanning without the velocity re-choice (rival only)": rule(rival_horizon=True, margin=wr.SPANNING_MARGIN,
                                                                 fraction=0.05),
    "spanning, harness copy": rule(velocity="rechosen", vgate="horizon", rival_horizon=True,
                                   margin=wr.SPANNING_MARGIN, fraction=0.05),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}
