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

Rounds 7–14 (docs/sequence.md, section "0.2: the adaptive window on reversed and re-timed
routes") start from rule "spanning" (:func:`decide_spanning`): the midpoint and spread tests
read only on sub-windows that span the decorrelation horizon, or that hold a *break* of the
query's rows (:func:`since_breaks`), or whose best line is significant or beats the window's;
the velocity re-chosen only where the lines part; and the confidence "change point"
(:func:`on_line_since`), the posterior of no jump over the last frames along the line.

Rounds 16–20 (docs/sequence.md, section "0.2: the adaptive window on routes driven in one
piece") start from "spanning" with the confidence "change point": the midpoint test replaced
by a *jump test* on the window's own line (:func:`jump_llr`: each recent sub-window judged
against the line's own level and the random places' mean, weighted by its effective number
of observations ``min(1, l / K_i)``), its run-length form over the segments between the grid's
lengths (:func:`segment_llr`), each with the spread test on every sub-window, from the
horizon, from half of it, across a break, or none (:func:`decide_jump`); and the neighbours of
the constants of rule "punctuated" (the library's, the spread test from ``K_i / 2`` or across
a break of the rows at lags 1–3); and the spread test read below the horizon only where the
window's own line is weak (:func:`decide_level`).
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


def support(st, cfg, adm, v, match):
    """``(n,)``: the gaps of every admitted window (velocity ``v``) whose best place agrees
    with ``match``, summed (the library's confidence "posterior" before its on-line factor)."""
    r = np.arange(st.best_s.shape[0])
    stds = wr._common_std(st)[:, 0, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        gaps = np.where(stds > 0, (st.second_s[r, v] - st.best_s[r, v]) / stds, 0.0)
    gaps = np.where(np.isfinite(gaps), gaps, 0.0)
    agree = adm & (np.abs(st.best_j[r, v] - match[:, None]) <= cfg.radius)
    return np.where(agree, gaps, 0.0).sum(axis=1)


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
    conf = support(st, cfg, adm, v, match) * wr._on_line(*wr._current_z(rows, match, best))
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


# ------------------------------------------------------------------------------------------
# round 7: the sub-window tests and the velocity re-choice read against the horizon
# (docs/sequence.md, section "0.2: the adaptive window on reversed and re-timed routes")

def admissible_spanning(st, cfg, log_p, n_places, horizon, spread_from="all", mid_from="recent",
                        margin=None, evidence=None, since_break=None, beaten_by=None):
    """``(n, V, G)``: the tests of rule "spanning" with the midpoint and spread tests optionally
    read only on sub-windows that span the frame's decorrelation horizon.

    ``spread_from``: "all" (the library: every shorter sub-window), "horizon" (those of
    ``l >= K_i``), "half" (``l >= K_i / 2``); ``mid_from``: "recent" (the library: from
    ``recent_fraction * L``), "horizon" (and ``l >= K_i``), "half", "every" (every shorter
    sub-window). With ``evidence`` (nats)
    a gated test still reads a shorter sub-window where the best line of that length (same
    velocity) is significant beyond chance, ``log p < -ln N - evidence``: the recent frames
    then say where the query is, so a window that does not follow them is rejected at once.
    With ``since_break`` (``(n,)`` frames since the query's rows last broke, :func:`breaks`) a
    gated test also reads every shorter sub-window that holds that break (``s_i < l``): its
    frames are then more than one observation. With ``beaten_by`` (common spreads) a gated test
    also reads a shorter sub-window where the best line of that length beats the window's own
    line over those frames by more than that."""
    margin = wr.SPANNING_MARGIN if margin is None else margin
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]  # (G, H)
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    k = horizon.astype(np.float64)[:, None, None, None]
    l4 = lengths[None, None, None, :]

    seen = None if evidence is None else (log_p < -np.log(n_places) - evidence)[:, :, None, :]  # (n, V, 1, H)

    def gate(base, how):
        base = base[None, None]
        if how == "horizon":
            spans = l4 >= k
        elif how == "half":
            spans = l4 >= 0.5 * k
        else:
            return base
        if since_break is not None:
            spans = spans | (since_break.astype(np.float64)[:, None, None, None] < l4)
        return base & (spans if seen is None else (spans | seen))

    common = wr._common_std(st)[:, :, None, :]
    if beaten_by is not None:
        outdone = st.sub > st.best_s[:, :, None, :] + beaten_by * common  # (n, V, G, H)
        seen = outdone if seen is None else (seen | outdone)
    mid = 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])
    ok = (st.sub <= mid) | ~(gate(shorter, "all") if mid_from == "every" else gate(recent, mid_from))
    common = wr._common_std(st)[:, :, None, :]
    ok &= (st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~gate(shorter, spread_from)
    rival = (log_p < -np.log(n_places) - margin) & (lengths[None, None, :] >= horizon[:, None, None])
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * common
    ok &= ~(beaten & rival[:, :, None, :]) | ~recent
    adm = np.all(ok, axis=3)
    adm[:, :, 0] = True
    return adm


_RATIOS = {}


def lag_ratios(rows, lag=1, places=wr.DECORRELATION_PLACES):
    """``(n,)``: each row's ratio at lag ``lag`` of :class:`catgraph._window_rule._Horizon`, per
    frame: the row's mean standardised difference at the best places of the row ``lag`` frames
    back over its mean at its own best places (1 while those rows agree on where the query is,
    about 0 when the earlier row's best places are random places for this one); 1 on the first
    frames and beside flat rows."""
    key = (hashlib.sha1(np.ascontiguousarray(rows).tobytes()).hexdigest(), lag)
    if key not in _RATIOS:
        out = np.ones(rows.shape[0])
        best = [None] * rows.shape[0]
        for i, row in enumerate(rows):
            spread = row.std()
            if not spread > 0:
                continue
            z = (row - row.mean()) / spread
            m = min(places, z.shape[0])
            best[i] = np.argpartition(z, m - 1)[:m]
            own = z[best[i]].mean()
            if i >= lag and best[i - lag] is not None and own < 0:
                out[i] = z[best[i - lag]].mean() / own
        _RATIOS[key] = out
    return _RATIOS[key]


def since_breaks(rows, level, lags=1):
    """``(n,)``: frames since the last break of the query's rows (a frame whose ratios at every
    lag ``1 .. lags``, :func:`lag_ratios`, are below ``level``: it has decorrelated from each of
    the frames before it); a large number before the first break."""
    broke = np.ones(rows.shape[0], dtype=bool)
    for lag in range(1, lags + 1):
        broke &= lag_ratios(rows, lag) < level
    n = rows.shape[0]
    idx = np.where(broke, np.arange(n), -(10 ** 6))
    last = np.maximum.accumulate(idx)
    return np.arange(n) - last


def decide_spanning(st, rows, cfg, rechoose="horizon", spread_from="all", mid_from="recent", margin=None,
                    evidence=None, break_level=None, break_lags=1, beaten_by=None, confidence="posterior", **_):
    """Rule "spanning" with the variants of :func:`admissible_spanning` and of the velocity re-choice.

    ``rechoose``: "horizon" (the library: re-chosen at the chosen length where it spans
    ``K_i``), "never", "parted" (where, in addition, the re-chosen line and the summed
    velocity's line part by at least the decorrelation length in places over the window,
    ``|v' - v| L >= K_i |v|``: two slopes are told apart only once their lines stop seeing the
    same-looking places), "twice" (the chosen length spans ``2 K_i``)."""
    n = st.best_s.shape[0]
    r = np.arange(n)
    log_p = wr._log_p(st)
    v = np.argmin(log_p.sum(axis=2), axis=1)
    horizon = horizons(rows)
    since = None if break_level is None else since_breaks(rows, break_level, break_lags)
    every = admissible_spanning(st, cfg, log_p, rows.shape[1], horizon, spread_from, mid_from, margin, evidence,
                                since, beaten_by)
    adm = every[r, v]
    g = np.argmin(np.where(adm, log_p[r, v], np.inf), axis=1)
    lengths = cfg.grid[g].astype(np.float64)
    if rechoose != "never":
        v2 = np.argmin(log_p[r, :, g], axis=1)
        if rechoose == "horizon":
            keep = lengths >= horizon
        elif rechoose == "twice":
            keep = lengths >= 2 * horizon
        elif rechoose == "parted":
            vel = cfg.velocities
            keep = (lengths >= horizon) & (np.abs(vel[v2] - vel[v]) * lengths >= horizon * np.abs(vel[v]))
        else:
            raise ValueError(rechoose)
        v = np.where(keep, v2, v)
        adm = every[r, v]
        adm[r, g] = True
    best = st.best_s[r, v, g]
    match = st.best_j[r, v, g]
    held = support(st, cfg, adm, v, match)
    if confidence == "posterior":
        conf = held * wr._on_line(*wr._current_z(rows, match, best))
    else:  # ("changepoint", span, odds): the line held over its recent frames, not the current one alone
        _, span, odds = confidence
        conf = held * on_line_since(rows, match, best, cfg.velocities[v], cfg.grid[g], span, odds)
    return match, conf, g, v


def on_line_since(rows, match, score, velocity, length, span="window", odds=wr.JUMP_ODDS, cap=64):
    """``(n,)``: the posterior probability that the query has not jumped off the chosen line
    within its last ``T`` frames (``T``: the window's length, ``span="window"``, or the
    constant ``span``; at most ``cap``).

    The confidence "posterior" weighs the current frame alone: "on the line" (its standardised
    difference at the match a unit normal around the line's mean ``mu``) against "a random
    place" (a standard normal), at prior odds ``odds`` of a jump. Here every jump time
    ``t = 1 .. T`` frames back is a hypothesis with the same prior odds: the frames since it lie
    at random places, those before it on the line; the log likelihood ratio of "no jump"
    against "jump ``t`` frames back" is the sum over the last ``t`` frames of
    ``(z^2 - (z - mu)^2) / 2`` along the line (0 where the line leaves the reference), and
    ``P = 1 / (1 + odds * sum_t exp(-LLR_t))``. With ``T = 1`` it is "posterior"."""
    n, places = rows.shape
    centre = rows.mean(axis=1)
    spread = rows.std(axis=1)
    safe = np.where(spread > 0, spread, 1.0)
    mu = np.where(spread > 0, (score - centre) / safe, 0.0)
    out = np.zeros(n)
    for i in range(n):
        horizon = int(min(length[i] if span == "window" else span, cap, i + 1))
        f = np.arange(horizon)
        at = match[i] - (_position(velocity[i], i) - _position(velocity[i], i - f))
        inside = (at >= 0) & (at < places)
        frames = i - f
        z = np.where(inside, (rows[frames, np.where(inside, at, 0)] - centre[frames]) / safe[frames], 0.0)
        llr = np.where(inside & (spread[frames] > 0), (z * z - (z - mu[i]) ** 2) / 2.0, 0.0)
        cumulative = np.cumsum(llr)
        top = max(0.0, float((-cumulative).max()))
        out[i] = np.exp(-top) / (np.exp(-top) + odds * np.exp(-cumulative - top).sum())
    return out


def _position(v, i):
    return np.floor(v * np.asarray(i, dtype=np.float64) + 0.5).astype(np.int64)


def spanning_rule(**kw):
    def apply(st, rows, cfg):
        return decide_spanning(st, rows, cfg, **kw)[:2]
    return apply


ROUNDS["7: the sub-window tests and the velocity re-choice against the horizon"] = {
    "spanning, harness copy (7)": spanning_rule(),
    "spread test from K": spanning_rule(spread_from="horizon"),
    "spread test from K/2": spanning_rule(spread_from="half"),
    "midpoint test from K": spanning_rule(mid_from="horizon"),
    "spread + midpoint from K": spanning_rule(spread_from="horizon", mid_from="horizon"),
    "spread + midpoint from K/2": spanning_rule(spread_from="half", mid_from="half"),
    "re-choice parted": spanning_rule(rechoose="parted"),
    "re-choice at 2K": spanning_rule(rechoose="twice"),
    "spread + midpoint from K, re-choice parted": spanning_rule(spread_from="horizon", mid_from="horizon",
                                                                rechoose="parted"),
    "spread + midpoint from K/2, re-choice parted": spanning_rule(spread_from="half", mid_from="half",
                                                                  rechoose="parted"),
}

ROUNDS["8: the gated tests read a short sub-window where its best line is significant"] = {
    **{f"spread from K or significant m={m:g}": spanning_rule(spread_from="horizon", evidence=m) for m in (-3, 0, 3, 6)},
    **{f"spread + midpoint from K or significant m={m:g}": spanning_rule(spread_from="horizon", mid_from="horizon",
                                                                         evidence=m) for m in (0, 3)},
    "spread from K or significant m=0, re-choice parted": spanning_rule(spread_from="horizon", evidence=0,
                                                                        rechoose="parted"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["9: the spread test from the horizon, the midpoint test on every sub-window"] = {
    "spread from K, midpoint every": spanning_rule(spread_from="horizon", mid_from="every"),
    "spread from K/2, midpoint every": spanning_rule(spread_from="half", mid_from="every"),
    "midpoint every": spanning_rule(mid_from="every"),
    "spread from K, midpoint every, re-choice parted": spanning_rule(spread_from="horizon", mid_from="every",
                                                                     rechoose="parted"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["10: the spread test from the horizon or across a break of the rows"] = {
    **{f"spread from K or across a break (r1 < {b:g})": spanning_rule(spread_from="horizon", break_level=b)
       for b in (0.0, 0.2, 0.4)},
    **{f"spread + midpoint from K or across a break (r1 < {b:g})": spanning_rule(
        spread_from="horizon", mid_from="horizon", break_level=b) for b in (0.0, 0.2)},
    "spread from K or across a break (r1 < 0), re-choice parted": spanning_rule(spread_from="horizon", break_level=0.0,
                                                                               rechoose="parted"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["11: the break at the decorrelation level, with the half horizon and the parted re-choice"] = {
    "spread from K or across a break (r1 < 0.4)": spanning_rule(spread_from="horizon", break_level=wr.DECORRELATION_LEVEL),
    "spread from K or across a break (r1 < 0.3)": spanning_rule(spread_from="horizon", break_level=0.3),
    "spread from K/2 or across a break (r1 < 0.4)": spanning_rule(spread_from="half", break_level=wr.DECORRELATION_LEVEL),
    "spread from K/2 or across a break (r1 < 0.2)": spanning_rule(spread_from="half", break_level=0.2),
    "spread from K or across a break (r1 < 0.4), re-choice parted": spanning_rule(
        spread_from="horizon", break_level=wr.DECORRELATION_LEVEL, rechoose="parted"),
    "spread from K/2 or across a break (r1 < 0.4), re-choice parted": spanning_rule(
        spread_from="half", break_level=wr.DECORRELATION_LEVEL, rechoose="parted"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["12: the confidence of a line held over its recent frames (change point)"] = {
    "posterior, harness copy": spanning_rule(),
    **{f"change point T={T}, odds {w:g}": spanning_rule(confidence=("changepoint", T, w))
       for T, w in ((1, wr.JUMP_ODDS), (5, wr.JUMP_ODDS), (10, wr.JUMP_ODDS), ("window", wr.JUMP_ODDS),
                    (10, 0.03), ("window", 0.03), ("window", 0.003))},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["13: a break as decorrelation from each of the last frames"] = {
    **{f"spread from K or across a break (r1..r{k} < {b:g})": spanning_rule(
        spread_from="horizon", break_level=b, break_lags=k) for k in (2, 3) for b in (0.4, 0.2)},
    **{f"spread from K/2 or across a break (r1..r{k} < 0.4)": spanning_rule(
        spread_from="half", break_level=0.4, break_lags=k) for k in (2, 3)},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["14: the spread test from the horizon or where a shorter line beats the window's"] = {
    **{f"spread from K or beaten by {c:g}": spanning_rule(spread_from="horizon", beaten_by=c) for c in (0.5, 1.0, 2.0)},
    **{f"spread from K/2 or beaten by {c:g}": spanning_rule(spread_from="half", beaten_by=c) for c in (0.5, 1.0)},
    "re-choice parted (14)": spanning_rule(rechoose="parted"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

def decide_calibrated(st, rows, cfg, fraction=0.5, half_life=wr.DECORRELATION_HALF_LIFE):
    """Rule "spanning" with the spread test's threshold read from the query's record: at
    sub-window length ``l`` and frame ``i``, ``min(EVIDENT_SPREADS, fraction * m_l(i))``, where
    ``m_l(i)`` is the discounted mean (``half_life`` frames) over the frames before ``i`` of how
    many common spreads the line "spanning" chose lay below the random places' mean over its
    last ``l`` frames (lengths below the chosen one). The record is read from "spanning"'s own
    choices (one pass), not from this rule's."""
    n = st.best_s.shape[0]
    r = np.arange(n)
    _, _, g0, v0 = decide_spanning(st, rows, cfg)
    common = wr._common_std(st)[:, 0, :]
    z = (st.mean[r, v0, :] - st.sub[r, v0, g0, :]) / common  # (n, H)
    valid = np.arange(z.shape[1])[None, :] < g0[:, None]
    decay = 2.0 ** (-1.0 / half_life)
    total, weight = np.zeros(z.shape[1]), np.zeros(z.shape[1])
    typical = np.full(z.shape, np.inf)
    for i in range(n):
        with np.errstate(invalid="ignore", divide="ignore"):
            typical[i] = np.where(weight > 0, total / weight, np.inf)
        total = decay * total + np.where(valid[i], z[i], 0.0)
        weight = decay * weight + valid[i]
    tau = np.minimum(wr.EVIDENT_SPREADS, fraction * typical)  # (n, H)
    log_p = wr._log_p(st)
    horizon = horizons(rows)
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    mid = 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])
    ok = (st.sub <= mid) | ~recent
    com = wr._common_std(st)[:, :, None, :]
    ok &= (st.sub <= st.mean[:, :, None, :] - tau[:, None, None, :] * com) | ~shorter
    rival = (log_p < -np.log(rows.shape[1]) - wr.SPANNING_MARGIN) & (lengths[None, None, :] >= horizon[:, None, None])
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * com
    ok &= ~(beaten & rival[:, :, None, :]) | ~recent
    every = np.all(ok, axis=3)
    every[:, :, 0] = True
    v = np.argmin(log_p.sum(axis=2), axis=1)
    g = np.argmin(np.where(every[r, v], log_p[r, v], np.inf), axis=1)
    v = np.where(cfg.grid[g] >= horizon, np.argmin(log_p[r, :, g], axis=1), v)
    adm = every[r, v]
    adm[r, g] = True
    best, match = st.best_s[r, v, g], st.best_j[r, v, g]
    conf = support(st, cfg, adm, v, match) * wr._on_line(*wr._current_z(rows, match, best))
    return match, conf


ROUNDS["15: the spread test's threshold from the query's record"] = {
    f"spread threshold {name} of the record": (lambda f: lambda st, rows, cfg: decide_calibrated(st, rows, cfg, f))(f)
    for name, f in (("1/2", 0.5), ("1/3", 1.0 / 3.0))
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

_BREAK = dict(spread_from="half", break_level=wr.DECORRELATION_LEVEL, break_lags=3)

#: the candidates of rounds 7-14 written to ``benchmarks/results/window_rules.md`` beside the
#: library's rules (docs/sequence.md, section "0.2: the adaptive window on reversed and re-timed routes")
REPORTED = {
    "spanning: spread test from K": spanning_rule(spread_from="horizon"),
    "spanning: spread test from K/2": spanning_rule(spread_from="half"),
    "spanning: spread + midpoint tests from K": spanning_rule(spread_from="horizon", mid_from="horizon"),
    "spanning: spread test from K or across a break (r1 < 0.4)": spanning_rule(
        spread_from="horizon", break_level=wr.DECORRELATION_LEVEL),
    "spanning: spread test from K/2 or across a break (r1..r3 < 0.4)": spanning_rule(**_BREAK),
    "spanning: velocity re-chosen only where the lines part": spanning_rule(rechoose="parted"),
    "spanning, confidence change point (T = 5)": spanning_rule(confidence=("changepoint", 5, wr.JUMP_ODDS)),
    "spanning: spread test from K/2 or across a break (r1..r3 < 0.4), confidence change point (T = 5)":
        spanning_rule(**_BREAK, confidence=("changepoint", 5, wr.JUMP_ODDS)),
}


# ------------------------------------------------------------------------------------------
# round 16: the sub-window tests as a jump test on the window's own line, with the rows'
# dependence (docs/sequence.md, section "0.2: the adaptive window on routes driven in one piece")

_CP = ("changepoint", 5, wr.JUMP_ODDS)


def jump_llr(st, lengths, horizon=None, ess=False):
    """``(n, V, G, H)``: per window and shorter sub-window, the log likelihood ratio of "the
    window's line holds over the sub-window's frames" against "the query left it before them"
    (the sub-window's best-line score a draw around the window's own score, one-sided: a
    sub-window better than its line is no evidence against it; or a draw around the random
    places' mean at that length; both in that length's common spread). With ``ess`` the ratio
    is weighted by the sub-window's effective number of observations over the one the spread
    counts, ``min(1, l / K_i)``: a sub-window shorter than the decorrelation horizon is about
    one observation of the rows."""
    common = wr._common_std(st)[:, :, None, :]
    safe = np.where(common > 0, common, 1.0)
    on = np.maximum(0.0, st.sub - st.best_s[..., None]) / safe
    off = (st.sub - st.mean[:, :, None, :]) / safe
    llr = np.where(common > 0, (off * off - on * on) / 2.0, 0.0)
    if ess:
        w = np.minimum(1.0, lengths[None, :] / horizon.astype(np.float64)[:, None])  # (n, H)
        llr = llr * w[:, None, None, :]
    return llr


def admissible_jump(st, cfg, log_p, n_places, horizon, spread_from="all", mid="bayes", ess=True,
                    odds=wr.JUMP_ODDS, tested="recent", cumulate=False, since_break=None, spread_fraction=0.5):
    """``(n, V, G)``: rule "spanning"'s tests with the midpoint test replaced by a jump test.

    ``mid``: "midpoint" (the library's), "bayes" (reject where a tested sub-window's weighted
    log likelihood ratio, :func:`jump_llr`, is below ``ln odds``: the posterior odds of a jump
    before its frames exceed 1 at prior odds ``odds``), "none". ``spread_from``: the spread
    test on every shorter sub-window ("all"), on those spanning the horizon ("horizon"), "half",
    "frac" (``l >= spread_fraction * K_i``), or "none". ``tested``: the jump test's
    sub-windows, "recent" (from ``recent_fraction`` of the window) or "all". ``cumulate``: the
    jump test of sub-window ``h`` sums the weighted ratios of the segments up to it instead of
    reading the sub-window alone (the run-length form)."""
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    k = horizon.astype(np.float64)[:, None, None, None]
    l4 = lengths[None, None, None, :]
    common = wr._common_std(st)[:, :, None, :]
    ok = np.ones(st.sub.shape, dtype=bool)
    if mid == "midpoint":
        ok &= (st.sub <= 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])) | ~recent
    elif mid == "bayes":
        llr = jump_llr(st, lengths, horizon, ess)
        if cumulate:
            llr = segment_llr(st, lengths, horizon, ess)
        mask = recent if tested == "recent" else shorter
        ok &= (llr >= np.log(odds)) | ~mask[None, None]
    if spread_from != "none":
        spans = shorter[None, None]
        if spread_from == "horizon":
            spans = spans & (l4 >= k)
        elif spread_from == "half":
            spans = spans & (l4 >= 0.5 * k)
        elif spread_from == "frac":
            spans = spans & (l4 >= spread_fraction * k)
        if since_break is not None and spread_from != "all":
            spans = spans | (shorter[None, None] & (since_break.astype(np.float64)[:, None, None, None] < l4))
        ok &= (st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~spans
    rival = (log_p < -np.log(n_places) - wr.SPANNING_MARGIN) & (lengths[None, None, :] >= horizon[:, None, None])
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * common
    ok &= ~(beaten & rival[:, :, None, :]) | ~recent
    adm = np.all(ok, axis=3)
    adm[:, :, 0] = True
    return adm


def segment_llr(st, lengths, horizon, ess):
    """``(n, V, G, H)``: the run-length form of :func:`jump_llr`: the frames of sub-window ``h``
    cut into the segments between consecutive grid lengths (their sums from the sub-window
    scores), each segment's mean judged as in :func:`jump_llr` at the spread of the length
    nearest its own, weighted by ``min(1, segment / K_i)`` with ``ess``, summed over the
    segments of the sub-window: the log likelihood ratio of "on the line over these frames"
    against "off it over all of them"."""
    n, v_count, g_count, _ = st.sub.shape
    common = wr._common_std(st)[:, :, None, :]  # (n, 1, 1, H)
    sums = st.sub * lengths[None, None, None, :]
    prev = np.concatenate([np.zeros(sums.shape[:3] + (1,)), sums[..., :-1]], axis=3)
    seg_len = np.diff(np.concatenate([[0.0], lengths]))
    seg_mean = (sums - prev) / seg_len[None, None, None, :]
    near = np.abs(np.log(seg_len[:, None]) - np.log(lengths[None, :])).argmin(axis=1)
    sd = common[..., near]
    safe = np.where(sd > 0, sd, 1.0)
    on = np.maximum(0.0, seg_mean - st.best_s[..., None]) / safe
    off = (seg_mean - st.mean[:, :, None, near]) / safe
    llr = np.where(sd > 0, (off * off - on * on) / 2.0, 0.0)
    if ess:
        w = np.minimum(1.0, seg_len[None, :] / horizon.astype(np.float64)[:, None])
        llr = llr * w[:, None, None, :]
    return np.cumsum(llr, axis=3)


def decide_jump(st, rows, cfg, confidence=_CP, break_level=None, break_lags=1, **kw):
    """Rule "spanning" (summed velocity, ``argmin log p`` over the admitted windows, the velocity
    re-chosen where the window spans the horizon) with :func:`admissible_jump`'s tests."""
    n = st.best_s.shape[0]
    r = np.arange(n)
    log_p = wr._log_p(st)
    v = np.argmin(log_p.sum(axis=2), axis=1)
    horizon = horizons(rows)
    if break_level is not None:
        kw["since_break"] = since_breaks(rows, break_level, break_lags)
    every = admissible_jump(st, cfg, log_p, rows.shape[1], horizon, **kw)
    g = np.argmin(np.where(every[r, v], log_p[r, v], np.inf), axis=1)
    v = np.where(cfg.grid[g] >= horizon, np.argmin(log_p[r, :, g], axis=1), v)
    adm = every[r, v]
    adm[r, g] = True
    best, match = st.best_s[r, v, g], st.best_j[r, v, g]
    held = support(st, cfg, adm, v, match)
    if confidence == "posterior":
        conf = held * wr._on_line(*wr._current_z(rows, match, best))
    else:
        _, span, odds = confidence
        conf = held * on_line_since(rows, match, best, cfg.velocities[v], cfg.grid[g], span, odds)
    return match, conf, g, v


def jump_rule(**kw):
    def apply(st, rows, cfg):
        return decide_jump(st, rows, cfg, **kw)[:2]
    return apply


ROUNDS["16: the sub-window tests as a jump test on the line, with the rows' dependence"] = {
    "16 spanning + change point (harness copy)": jump_rule(mid="midpoint"),
    "16 jump test (ESS), spread all": jump_rule(),
    "16 jump test (no ESS), spread all": jump_rule(ess=False),
    "16 jump test (ESS), spread from K": jump_rule(spread_from="horizon"),
    "16 jump test (ESS), spread from K/2": jump_rule(spread_from="half"),
    "16 jump test (ESS), no spread test": jump_rule(spread_from="none"),
    "16 jump test (ESS), every sub-window, spread from K": jump_rule(spread_from="horizon", tested="all"),
    "16 run length (ESS), spread from K": jump_rule(spread_from="horizon", cumulate=True),
    "16 run length (ESS), spread all": jump_rule(cumulate=True),
    "16 run length (ESS), no spread test": jump_rule(spread_from="none", cumulate=True),
    "16 midpoint, spread from K (change point)": jump_rule(mid="midpoint", spread_from="horizon"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["17: the jump test with the spread test from the horizon or across a break"] = {
    "17 jump test (ESS), spread from K/2 or a break (r1..r3 < 0.4)": jump_rule(
        spread_from="half", break_level=wr.DECORRELATION_LEVEL, break_lags=3),
    "17 jump test (ESS), spread from K or a break (r1..r3 < 0.4)": jump_rule(
        spread_from="horizon", break_level=wr.DECORRELATION_LEVEL, break_lags=3),
    "17 jump test (ESS), spread from K/2 or a break (r1 < 0.4)": jump_rule(
        spread_from="half", break_level=wr.DECORRELATION_LEVEL, break_lags=1),
    "17 midpoint, spread from K/2 or a break (r1..r3 < 0.4) (change point)": jump_rule(
        mid="midpoint", spread_from="half", break_level=wr.DECORRELATION_LEVEL, break_lags=3),
    "17 jump test (no ESS), every sub-window, spread all": jump_rule(ess=False, tested="all"),
    "17 jump test (ESS), every sub-window, spread all": jump_rule(tested="all"),
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["18: rule 'punctuated' (library, confidence 'changepoint'): its constants' neighbours"] = {
    **{f"18 midpoint, spread from {f:g} K or a break (r1..r{k} < 0.4) (change point)": jump_rule(
        mid="midpoint", spread_from="frac", spread_fraction=f, break_level=wr.DECORRELATION_LEVEL, break_lags=k)
       for f, k in ((0.75, 3), (1.0, 3), (0.5, 2), (0.5, 4), (0.25, 3))},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}


# ------------------------------------------------------------------------------------------
# round 19: the gated spread test read again where the window's line is weak

def admissible_level(st, cfg, log_p, n_places, horizon, since, level, fraction=0.5):
    """``(n, V, G)``: rule "punctuated"'s tests, with the spread test also read on a short
    sub-window (shorter than ``fraction * K_i``, no break in it) where the window's own line is
    weak: its mean lies less than ``level`` common spreads of that sub-window's length below
    the random places' mean. A strong line (Nordland's correct one in a hard stretch) survives
    a weak recent stretch; a weak line (the old line after a jump) does not."""
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    k = horizon.astype(np.float64)[:, None, None, None]
    l4 = lengths[None, None, None, :]
    common = wr._common_std(st)[:, :, None, :]
    safe = np.where(common > 0, common, 1.0)
    line_level = (st.mean[:, :, None, :] - st.best_s[..., None]) / safe  # (n, V, G, H)
    ok = (st.sub <= 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])) | ~recent
    spans = (l4 >= fraction * k) | (since.astype(np.float64)[:, None, None, None] < l4) | (line_level < level)
    ok &= (st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~(shorter[None, None] & spans)
    rival = (log_p < -np.log(n_places) - wr.SPANNING_MARGIN) & (lengths[None, None, :] >= horizon[:, None, None])
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * common
    ok &= ~(beaten & rival[:, :, None, :]) | ~recent
    adm = np.all(ok, axis=3)
    adm[:, :, 0] = True
    return adm


def decide_level(st, rows, cfg, level, fraction=0.5, breaks=True):
    n = st.best_s.shape[0]
    r = np.arange(n)
    log_p = wr._log_p(st)
    v = np.argmin(log_p.sum(axis=2), axis=1)
    horizon = horizons(rows)
    since = since_breaks(rows, wr.DECORRELATION_LEVEL, wr.BREAK_LAGS) if breaks else np.full(n, 10 ** 9)
    every = admissible_level(st, cfg, log_p, rows.shape[1], horizon, since, level, fraction)
    g = np.argmin(np.where(every[r, v], log_p[r, v], np.inf), axis=1)
    v = np.where(cfg.grid[g] >= horizon, np.argmin(log_p[r, :, g], axis=1), v)
    adm = every[r, v]
    adm[r, g] = True
    best, match = st.best_s[r, v, g], st.best_j[r, v, g]
    conf = support(st, cfg, adm, v, match) * on_line_since(rows, match, best, cfg.velocities[v], cfg.grid[g], 5,
                                                           wr.JUMP_ODDS)
    return match, conf


ROUNDS["19: the gated spread test read again where the window's line is weak"] = {
    **{f"19 punctuated + weak line < {lam:g}": (lambda lam: lambda st, rows, cfg: decide_level(st, rows, cfg, lam))(lam)
       for lam in (1.5, 2.0, 2.5, 3.0)},
    **{f"19 spread from K, weak line < {lam:g}, no break": (lambda lam: lambda st, rows, cfg: decide_level(
        st, rows, cfg, lam, fraction=1.0, breaks=False))(lam) for lam in (2.0, 2.5)},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}

ROUNDS["20: the spread test from the horizon, read below it where the line is weak"] = {
    **{f"20 spread from {f:g} K, weak line < {lam:g}, no break": (lambda lam, f: lambda st, rows, cfg: decide_level(
        st, rows, cfg, lam, fraction=f, breaks=False))(lam, f) for lam, f in ((1.5, 1.0), (1.75, 1.0), (2.0, 0.5))},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}


# ------------------------------------------------------------------------------------------
# rounds 21-22: a rival for weak lines (rule "contested"), and the midpoint test gated

def admissible_contest(st, cfg, log_p, n_places, horizon, margin=None, span=wr.CONTEST_SPANS, weak=None,
                       distinct=None, mid_span=None, mid_weak=None, since=None, null="chance"):
    """``(n, V, G)``: rule "gated"'s tests plus a second rival: a line of a recent sub-window's
    length ``l`` that spans ``span`` horizons (``l >= span * K_i``) and is significant beyond
    chance by ``margin(l, K)`` nats counts as a rival; with ``weak`` only where the window's own
    line lies less than ``weak`` common spreads below the random places' mean at that length
    (``null`` "velocities", ``margin`` 1 and ``weak`` = 2.5 is the library's "contested"); ``distinct``: "all" (every
    rival) or "new" (the second kind) must point more than ``radius`` places from the window's
    match. ``mid_span`` / ``mid_weak``: the midpoint test read only on the recent sub-windows that
    span ``mid_span`` horizons, where the line is weaker than ``mid_weak``, or (``since``, frames
    since the latest break of the rows) that hold a break."""
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    common = wr._common_std(st)[:, :, None, :]
    l4 = lengths[None, None, None, :]
    k4 = horizon.astype(np.float64)[:, None, None, None]
    level = (st.mean[:, :, None, :] - st.best_s[..., None]) / np.where(common > 0, common, 1.0)  # (n, V, G, H)
    mid_read = recent[None, None]
    if mid_span is not None:
        read = (l4 >= mid_span * k4) | (level < mid_weak)
        if since is not None:
            read |= since.astype(np.float64)[:, None, None, None] < l4
        mid_read = mid_read & read
    ok = (st.sub <= 0.5 * (st.best_s[..., None] + st.mean[:, :, None, :])) | ~mid_read
    spans = (l4 >= k4) | (level < wr.WEAK_LINE_SPREADS)
    ok &= (st.sub <= st.mean[:, :, None, :] - wr.EVIDENT_SPREADS * common) | ~(shorter[None, None] & spans)
    k3 = horizon.astype(np.float64)[:, None, None]
    l3 = lengths[None, None, :]
    strict = (log_p < -np.log(n_places) - wr.SPANNING_MARGIN) & (l3 >= k3)  # (n, V, H)
    beaten = st.sub > st.best_s[:, :, None, :] + wr.RIVAL_SPREADS * common  # (n, V, G, H)
    apart = np.abs(st.best_j[:, :, None, :] - st.best_j[:, :, :, None]) > cfg.radius  # rival's place vs match
    first = beaten & (apart if distinct == "all" else True)
    ok &= ~(first & strict[:, :, None, :]) | ~recent
    if margin is not None:
        # the chance level: the best of N random places (-ln N), of N places at each of V
        # velocities (-ln NV), or the frame's own best place beyond the exclusion radius
        base = {"chance": -np.log(n_places), "velocities": -np.log(n_places * log_p.shape[1])}.get(null)
        if base is None:
            base = log_p_at(st, st.second_s)
        loose = (log_p < base - margin(l3, k3)) & (l3 >= span * k3)
        second = beaten & loose[:, :, None, :]
        if weak is not None:
            second &= level < weak
        if distinct is not None:
            second &= apart
        ok &= ~second | ~recent
    adm = np.all(ok, axis=3)
    adm[:, :, 0] = True
    return adm


def contest_rule(breaks: bool = False, **kw):
    """A rule function: the library's ``_decide`` (rule "gated"'s velocity, window and confidence
    "changepoint") with :func:`admissible_contest` in place of the library's admissibility."""

    def rule(st, rows, cfg):
        c = H_config(cfg)
        since = since_breaks(rows, wr.DECORRELATION_LEVEL, wr.BREAK_LAGS) if breaks else None
        library = wr._admissible

        def admissible(st_, cfg_, log_p=None, n_places=1, horizon=None, since_=None):
            return admissible_contest(st_, cfg_, log_p, n_places, horizon, since=since, **kw)
        wr._admissible = admissible
        try:
            match, _, conf, _, _, _ = wr._decide(st, c, np.arange(rows.shape[0]), False, rows, wr._new_record(c))
        finally:
            wr._admissible = library
        return match, conf
    return rule


def H_config(cfg):
    """The harness's configuration of rule "gated" with the confidence "changepoint"."""
    import rule_harness

    return rule_harness.config("gated", confidence="changepoint")


def _flat(m):
    return lambda l, k: np.full(np.broadcast_shapes(l.shape, k.shape), float(m))


ROUNDS["21: a rival for weak lines"] = {
    "21 rival margin 3 from K": contest_rule(margin=_flat(3.0), span=1.0),
    "21 rival margin 0 from K": contest_rule(margin=_flat(0.0), span=1.0),
    "21 rival margin 3 from 2K": contest_rule(margin=_flat(3.0)),
    "21 rival margin 0 from 2K": contest_rule(margin=_flat(0.0)),
    "21 rival margin 6 K / l": contest_rule(margin=lambda l, k: 6.0 * np.minimum(1.0, k / l), span=1.0),
    "21 rival margin 6 (2K / l - 1)": contest_rule(margin=lambda l, k: 6.0 * np.clip(2 * k / l - 1, 0, 1), span=1.0),
    "21 rival margin 0 from 2K, every rival at another place": contest_rule(margin=_flat(0.0), distinct="all"),
    "21 rival margin 0 from 2K, the new rivals at another place": contest_rule(margin=_flat(0.0), distinct="new"),
    **{f"21 weak < {w:g}, margin {m:g} from {s:g} K": contest_rule(margin=_flat(m), span=s, weak=w)
       for w, m, s in ((1.75, 0, 2), (2.25, 0, 2), (2.5, 0, 1), (2.5, 0, 1.5), (2.5, 0, 2), (2.5, 0, 3), (2.5, 1.5, 2),
                       (2.5, 3, 2), (2.75, 0, 2), (3.0, 0, 2), (3.0, 0, 3), (3.5, 0, 2))},
    # the chance level of the N V random lines searched, or of the frame's own best place beyond
    # the exclusion radius ("weak < 2.5, margin 1 beyond -ln NV from 2 K" is the library's "contested")
    **{f"21 weak < {w:g}, margin {m:g} beyond -ln NV from 2 K": contest_rule(margin=_flat(m), weak=w, null="velocities")
       for w, m in ((2.5, 0), (2.5, 1), (2.5, 2), (3.0, 1))},
    "21 weak < 2.5, margin 2 beyond the best place past the radius, from 2 K": contest_rule(
        margin=_flat(2), weak=2.5, null="second"),
}

_CONTESTED = dict(margin=_flat(0.0), weak=wr.CONTEST_LINE_SPREADS)  # measured before the -ln NV chance level

ROUNDS["22: rule contested with the midpoint test gated"] = {
    **{f"22 contested, midpoint from {k:g} K or weak < {w:g}": contest_rule(mid_span=k, mid_weak=w, **_CONTESTED)
       for k, w in ((2, 1.75), (2, 2.5), (4, 1.75), (4, 2.5), (8, 2.5))},
    "22 contested, midpoint from 2 K, weak < 2.5 or across a break": contest_rule(
        breaks=True, mid_span=2.0, mid_weak=2.5, **_CONTESTED),
    # on the library's "contested" (the chance level of the N V lines, margin 1)
    **{f"22 library contested, midpoint from {k:g} K, weak < 2.5{' or across a break' if b else ''}": contest_rule(
        breaks=b, mid_span=k, mid_weak=2.5, margin=_flat(1.0), weak=wr.CONTEST_LINE_SPREADS, null="velocities")
       for k, b in ((1.0, True), (2.0, True), (2.0, False))},
}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}


# ------------------------------------------------------------------------------------------
# round 23: the window as the last segment of the best partition of the query into lines

def _partition_gain(st, n_places, gain):
    """``(n, V, G)``: a segment's gain by its best line: "logp" ``-log p - ln(N V)``; "z" the
    best line's distance below the random places' mean in common spreads, ``z^2 / 2 - ln(N V)``
    (the Gaussian tail's log, free of the fitted mixture's floor); "runner-up" ``(z^2 - z_2^2) / 2``
    with ``z_2`` the best line's rival beyond the exclusion radius."""
    v_count = st.best_s.shape[1]
    if gain == "logp":
        return -wr._log_p(st) - np.log(n_places * v_count)
    common = wr._common_std(st)
    safe = np.where(common > 0, common, 1.0)
    z = np.maximum(0.0, (st.mean - st.best_s) / safe)
    if gain == "z":
        return z * z / 2.0 - np.log(n_places * v_count)
    z2 = np.maximum(0.0, (st.mean - st.second_s) / safe)
    return (z * z - z2 * z2) / 2.0


def partition_choice(st, cfg, n_places, penalty, gain="logp"):
    """``(g, v)`` per frame: the last segment of the best partition of the frames so far into
    straight lines (optimal partitioning, computed online). A segment of length ``L`` ending at
    frame ``i`` gains the significance of its best line beyond chance, ``-log p_i(L, v) - ln(N V)``
    (the best velocity), less ``penalty`` nats; ``F(i) = max_L F(i - L) + gain_i(L)`` over the
    window grid, and the window is the ``L`` of the maximum (the frames since the partition's last
    cut, on the grid). Reads the statistics alone; ``O(G)`` per frame, ``l_max`` values carried."""
    n, v_count, _ = st.best_s.shape
    grid = cfg.grid.astype(np.int64)
    gain_v = _partition_gain(st, n_places, gain)
    v_best = np.argmax(gain_v, axis=1)  # (n, G)
    gain = np.take_along_axis(gain_v, v_best[:, None, :], axis=1)[:, 0, :] - penalty
    total = np.zeros(n + 1)
    g = np.zeros(n, dtype=np.int64)
    for i in range(n):
        cand = total[np.maximum(0, i + 1 - grid)] + gain[i]
        g[i] = int(np.argmax(cand))
        total[i + 1] = cand[g[i]]
    return g, v_best[np.arange(n), g]


def partition_rule(penalty, gain="logp"):
    """The partition's window and velocity with the library's confidence "changepoint" (the
    support of every shorter window at the chosen velocity whose best place agrees)."""
    def apply(st, rows_d, cfg):
        import rule_harness

        c = rule_harness.config("challenged", confidence="changepoint")
        n = st.best_s.shape[0]
        frames = np.arange(n)
        g, v = partition_choice(st, c, rows_d.shape[1], penalty, gain)
        best, match = st.best_s[frames, v, g], st.best_j[frames, v, g]
        shorter = c.grid[None, :] <= c.grid[g][:, None]
        stds = wr._common_std(st)[:, 0, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            gaps = np.where(stds > 0, (st.second_s[frames, v] - st.best_s[frames, v]) / stds, 0.0)
        gaps = np.where(np.isfinite(gaps), gaps, 0.0)
        agree = shorter & (np.abs(st.best_j[frames, v] - match[:, None]) <= c.radius)
        conf = np.where(agree, gaps, 0.0).sum(axis=1)
        moments = wr._row_moments(rows_d)
        _, mu = wr._current_z(rows_d, match, best, moments)
        recent = wr._new_record(c).recent
        conf = conf * wr._on_line_since(*wr._line_z(rows_d, moments, frames, match, c.velocities[v], recent), mu)
        return match, conf
    return apply


ROUNDS["23: the window as the last segment of the best partition into lines"] = {
    **{f"23 partition -log p penalty {p:g}": partition_rule(float(p)) for p in (0, 5, 10, 20, 40)},
    **{f"23 partition z penalty {p:g}": partition_rule(float(p), "z") for p in (0, 5, 20)},
    **{f"23 partition runner-up penalty {p:g}": partition_rule(float(p), "runner-up")
       for p in (0, 1, 3, 10)}}

CANDIDATES = {name: f for r in ROUNDS.values() for name, f in r.items()}
