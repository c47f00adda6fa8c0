"""Sequence matching with a fixed or an adaptive window, along lines of any velocity.

SeqSLAM and "Look No Further" (paper 1) with the query driven in any order, direction
and speed (DESIGN.md §4).

Scores along lines
------------------
Given a difference matrix ``d`` of shape ``(n_query, N)`` (query frame ``i`` against
reference place ``j``; usually per-query normalised, see
:func:`catgraph.differences.normalise_rows`), a *velocity* ``v`` is the number of
reference places the route advances per query frame: ``1`` is the classic diagonal (the
query at the reference's frame rate), ``2`` twice as fast, ``0.5`` half as fast, ``-1``
the route driven backwards. Query frame ``i`` sits at reference offset
``pos_v(i) = floor(v * i + 1/2)``, and the window score of length ``L`` ending at
``(i, j)`` is the mean difference along the line through ``(i, j)``::

    s_ij(L, v) = (1/L) * sum_{t=0}^{L-1} d_{i-t, j - (pos_v(i) - pos_v(i-t))}

For an integer ``v`` this is exactly ``d_{i-t, j - v t}``; for ``v = ±0.5`` the line
advances by 0 and 1 places on alternate frames (a line through the origin of time,
rounded half up), so it is within half a place of ``j - v t``.

Lines are global: the line ``c = j - pos_v(i)`` visits place ``c + pos_v(t)`` at frame
``t``, so its window sum follows one frame to the next,
``S_{v,L}(i, c) = S_{v,L}(i-1, c) + val(i, c) - val(i-L, c)`` (``val``: the term, or the
edge fill below; no subtraction while ``i < L``; a line that enters the reference starts
from the fills of the window's earlier frames). The matcher keeps *one* ring of the last
``l_max + 1`` difference rows, shared by every velocity, and one running sum per
velocity, candidate length and line; every window score, and every sub-window score the
window rule tests, is then ``O(1)``: ``O(N V G)`` per query frame for ``V`` velocities
and ``G`` lengths. Memory: the ring, ``2 N (l_max + 1)`` bytes (int16 codes: 100 MB at
``N = 10^5``, 1.0 GB at ``N = 10^6`` with ``l_max = 500``; 3.6 MB for Nordland's 3,576
places), plus ``4 N G`` bytes per velocity (int32 running sums: 5.2 MB per velocity at
``N = 10^5`` with 13 lengths; the robust and mixture approximations add one float64
scratch row of ``8 N`` bytes); never an ``N x N`` matrix.

Precision (a documented policy). Each difference is stored once as an int16 *code*, the
nearest integer multiple of a quantum ``u = 2^(e - 12)`` fixed by the query's first row
(``max_j |d_0j| < 2^e``, so the first row's codes stay below ``2^12``; leading rows of
zeros, blank frames once normalised, are skipped: they are codes 0 in any quantum); the
row means are stored as rounded mean codes. Later differences up to 8 times the first
row's largest keep their value to ``u / 2``; larger ones saturate at ``±32767 u`` (they
never wrap around), and the matcher warns (``CatgraphWarning``, once per query) where
any does: rows that are not normalised per query can grow far beyond their first. The running sums are integers (int32: ``|S| <= l_max 32767 < 2^31``; int64 for
``l_max > 65,538``), so they never drift, a window summed in any order gives the same
value, and places whose windows tie exactly keep tying (the first place wins). Scores
and statistics are converted to float64 once, where they are divided. Against the
float64 scores of the same policy each score is off by at most ``u`` (``u / 2`` for a
line inside the reference; a fill, the rounded mean of rounded values, by up to ``u``),
plus the saturation. On the benchmark data (rows normalised to unit spread, every
traversal condition) ``u`` is ``2^-10`` or ``2^-9`` and the largest code below 6,000:
nothing saturates (``benchmarks/results/matcher.md``).

Edges (a documented policy). Early query frames (``i < L - 1``) use the
``L_eff = min(L, i + 1)`` frames seen so far; the reported ``window_length`` is that
effective length. A term whose place falls outside ``[0, N)`` (a line running off
either end of the reference) is filled with its query row's mean difference
``mean_j d_{i-t, j}`` — the expected difference of an unrelated place (0 for
normalised rows), i.e. *no evidence either way* — and the sum is divided by the full
``L_eff``. Averaging only the terms that exist instead gives the short lines near the
ends of the reference a larger spread, so they win by chance (and, on data with
featureless frames at the start of the reference, by a lot); excluding them would make
the first ``L - 1`` places unmatchable. Every frame gets an output (no abstention),
which is what a localiser embedded in a navigation stack needs, and what the MTL
metric rewards. The fill is one more term of the running sums, so it
costs nothing extra.

Significance, velocity and window
---------------------------------
For each query frame, velocity ``v`` (``velocities``, default
:data:`DEFAULT_VELOCITIES`: ±0.5, ±1, ±2, ±3) and candidate length ``L`` (a grid in
``[l_min, l_max]``, default 13 geometric lengths from 5 to 500), the distribution of
``{s_ij(L, v)}_j`` is approximated and ``p_i(L, v)``, the probability of drawing a value
at most the best score ``min_j s_ij(L, v)``, is computed in log space
(``scipy.special.log_ndtr``; the probabilities underflow for strong matches)::

    gaussian   N(mean, std)
    robust     N(median, 1.4826 * MAD)
    gmm2/gmm3  K-component mixture, 10 EM steps started at equal weights, std ``std`` and
               means spread over mean ± std;  log p = logsumexp_k(log w_k + log Phi(z_k)).
               EM runs on every ``ceil(N / 1024)``-th score (a deterministic subsample:
               the fit costs ``O(1024 K)`` per window instead of ``O(N K)``).

Lines of different velocities average different numbers of distinct places, so their
score spreads differ; judged each against its own spread, a mediocre line of a
narrow-spread velocity looks significant (measured on the UJI Wi-Fi survey, whose
reference holds 24 scans per point: choosing the velocity by each line's own spread cut
the fixed-window AUC at L = 100 from 0.99 to 0.58). Every approximation is therefore
widened to the *widest* spread over the velocities at that length (with one velocity
nothing changes). The velocity of a frame is the one whose windows are the most
significant *summed over every candidate length*, ``argmin_v sum_L log p_i(L, v)``;
the window is then chosen at that velocity. Taking instead the velocity of the single
most significant window lets short windows decide: on a map recorded with several
frames per place (the UJI survey: 24 scans at each of 24 points) every velocity fits a
short window equally well, and the best of eight velocities is then chosen by noise.
Summing over the lengths lets the long windows, where the velocity is identifiable,
outvote the short ones. Measured on the condition table (same window rule and
confidence): UJI in order, reversed and at speed 2 AUC 0.971 → 0.982, 0.958 → 0.982,
0.952 → 0.976; Nordland −0.02 … +0.04 per cell (``docs/sequence.md``).

The *literal* rule of the paper (``rule="literal"``) picks ``L_i = argmin_L p_i(L)``.
Its weakness shows on out-of-order queries: after a jump to another part of the route,
the hypothesis that continues the *old* line stays very significant for long windows,
because most of such a window still lies on the old, well-matching segment, and the
literal rule keeps choosing it for hundreds of frames.

The rule ``rule="consistent"`` only admits a window whose best hypothesis is
supported by its own recent past: for every shorter candidate ``l`` in the grid with
``recent_fraction * L <= l < L`` (``recent_fraction = 0``: every shorter length), the
hypothesis' score over its most recent ``l`` frames must lie closer to the
window's own score than to the mean score of random places at that length,

    s_{i, j*}(l, v) <= (s_{i, j*}(L, v) + mean_j s_ij(l, v)) / 2,

i.e. a likelihood-ratio test between "the recent frames continue the same alignment"
and "the recent frames are unrelated to it" with equal spreads, and no threshold. A
window that reaches back across a discontinuity fails it as soon as more than about
half of its shortest tested sub-window lies after the discontinuity. Among the admitted
windows (the shortest is always admitted) the one with the smallest ``p_i(L, v)`` is
chosen, as in the paper. Testing only the sub-windows from ``L/8`` keeps the long
windows through hard stretches of an in-order route, but after a jump it holds on to
the old alignment for ``L/16`` frames; testing every sub-window catches short segments
but rejects correct long windows in hard stretches, where the correct line's recent
frames are much worse than its own average.

Rule ``"evident"`` (default ``recent_fraction = 0.05``) applies the
midpoint test to the sub-windows from ``L/20`` and asks *every* shorter sub-window to
stand out from random places at its length,

    s_{i, j*}(l, v) <= mean_j s_ij(l, v) - EVIDENT_SPREADS * std_l,   EVIDENT_SPREADS = 1,

``std_l`` the common spread at length ``l`` (below). The midpoint test compares the
recent frames with the window's own average; this one compares them with random
places only. After a jump the old line's recent frames *are* random places, so it still
catches jumps, while a hard stretch whose frames are worse than the line's average but
better than random no longer cuts the window. On the whole condition table (Nordland,
UJI, the synthetic world; ``docs/sequence.md``) it is at least as good as "consistent"
with every sub-window tested (the 0.2 draft default) within 0.01 AUC in every cell, and
better by up to 0.03 on Nordland in order, reversed and at speed 2 and by up to 0.16 on
UJI's shuffles; it does not close the gap to the best fixed window on Nordland in order
(``benchmarks/results/sequence.md``).

Rule ``"unrivalled"`` (the default until ``"spanning"``) adds to "evident" a test against a *rival*
line: over each recent sub-window from ``RIVAL_FRACTION = 0.2`` of the window on, the
window's best line may trail the best line of that length (same velocity) by at most
``RIVAL_SPREADS = 0.5`` common spreads, unless that best line is no more significant than
chance, ``log p_i(l, v) >= -ln N - RIVAL_MARGIN`` (``N`` reference places,
``RIVAL_MARGIN = 10`` nats). On a route driven at a varying speed a long straight line
drifts off the route, and through repeated scenery a wrong long line stays consistently
better than random places, so the tests against random places admit it; a short line
that is significant far beyond chance and clearly better over the same frames exposes
it. Where no short line is that significant (Nordland's hard stretches, every UJI frame
measured) nothing changes. Measured on the condition table: synthetic world +0.015 …
+0.154 AUC per cell, Nordland within ±0.007, UJI unchanged (``docs/sequence.md``).

``rule="sustained"`` admits the windows of "consistent" but takes the *longest* admitted window
whose ``log p`` is at most ``SUSTAINED_FRACTION = 0.5`` times the smallest admitted
``log p`` (at least half as significant, on the log scale).

``rule="predictive"`` is no hypothesis test on window statistics: it chooses the window by
how well each candidate length has been *predicting* (prequential model choice, follow
the best expert). The line a length ``L`` chose at frame ``i - K`` (its best place
``j*(i - K, L)`` at that frame's velocity ``v``) predicts the place
``j*(i - K, L) + pos_v(i) - pos_v(i - K)`` at frame ``i``, and frame ``i``'s row alone scores
the prediction: the loss is the row's standardised difference there,
``(d_ij - mean_j d_ij) / std_j d_ij`` (0, a random place's expectation, where the line has
left the reference). Each length keeps the discounted mean of its losses, with a
half-life of ``PREDICTION_HALF_LIFE = 1000`` frames, and the frame's window is the length
with the lowest mean (ties, as when every length has found the same line: the longer;
before frame ``K``: the longest). A line that drifts off a route driven at a varying speed
predicts badly, a long straight line on a constant-speed route predicts well, and after
a jump every long line predicts badly at once. The horizon ``K = PREDICTION_HORIZON = 10``
matters: predicting only the next frame (``K = 1``) favours the short windows, because
consecutive rows are alike and a short window's line was chosen for fitting the frames
just before (Nordland in order, ``K = 1``: 5–7 frames chosen, AUC 0.42). Its state is
``O(G K)`` numbers, and it reads ``G`` (frame, place) values and the mean and spread of each
row. ``K`` and the half-life were chosen on the whole condition table (Nordland, UJI,
the synthetic world; ``K`` in {5, 7, 10, 15, 20}, half-life in {10, 30, 100, 300, 1000}
frames: the best mean AUC margin to the best fixed window). Measured against the default
(``benchmarks/results/sequence.md``, ``docs/sequence.md``): better in order, reversed and at
both speeds on Nordland (reversed 0.953, speed 2 0.927) and in every cell of the synthetic
world, but worse on the short shuffles of Nordland and on most UJI shuffles, so it is not
the default.

``rule="decorrelated"`` keeps the record of "predictive" but reads its horizon from the
query itself: the first lag ``k`` at which the rows have decorrelated, i.e. at which a row's
mean standardised difference at the ``DECORRELATION_PLACES = 10`` best places of the row
``k`` frames back, over the same at its own best places, averaged over recent frames
(half-life ``DECORRELATION_HALF_LIFE = 100``), falls below ``DECORRELATION_LEVEL = 0.4``
(at most ``HORIZON_MAX = 48`` frames). Long enough to outlast the likeness of consecutive
rows (which favours short windows), as short as the data allow: on Nordland about 20
frames, about twice that at half the speed; on the synthetic world 2; on UJI's 0.5–3 %
shuffles 4–6. ``O(K m)`` more numbers of state and ``O(N + K m)`` more work per frame.
Measured on the condition table (``docs/sequence.md``): mean AUC margin to the best fixed
window over the 42 cells of Nordland, UJI and the synthetic world −0.075 (the default
−0.094); Nordland reversed 0.971, speed 2 0.909, in order 0.932; better than the default in
every synthetic cell and every held-out world, worse on Nordland's 0.5–3 % shuffles and
most of UJI's 2–20 % shuffles. Not the default: the cluster matcher
(:mod:`catgraph.distributed`) decides only the rules that need window statistics alone.

``rule="spanning"`` keeps the tests of "unrivalled" and reads the horizon of "decorrelated":
a line shorter than the query's decorrelation time is about one observation, so only a line
that spans it re-chooses the velocity (where the chosen window spans the frame's horizon, the
velocity is the most significant at that length) or counts as a rival (over the sub-windows
from ``recent_fraction * L`` on, significant beyond chance by ``SPANNING_MARGIN = 6`` nats).
Measured (``docs/sequence.md``): mean AUC margin to the best fixed window over the 42 cells
−0.058 (the default −0.094), on the held-out worlds of ``bench_generalisation.py`` −0.040
(−0.159); Nordland −0.043 (−0.035). The default rule until "punctuated"; the cluster
matcher (:mod:`catgraph.distributed`) runs it exactly.

``rule="punctuated"`` is "spanning" with the spread test read only on the sub-windows that
span half the frame's decorrelation horizon (``SPREAD_HORIZON_FRACTION = 0.5``) or that hold
a *break* of the query's rows (a frame whose best places are random places for each of the
``BREAK_LAGS = 3`` rows before it, read from the same clock): within a stretch of alike rows a
correct line's last few frames are about one observation and may be no better than random
places (Nordland's hard stretches), while right after the rows break they are evidence again
(a jump that changes the scene). Measured with the confidence "changepoint" (``docs/sequence.md``):
mean AUC margin to the best fixed window over the 42 cells −0.050 ("spanning" −0.052), Nordland
−0.031 (−0.045), UJI −0.063 (−0.056), the synthetic world and the held-out worlds unchanged.
The default rule until "gated"; the cluster matcher (:mod:`catgraph.distributed`) runs it exactly.

``rule="gated"`` is "spanning" with the spread test read on the sub-windows that span the
frame's decorrelation horizon and, on a shorter one, only where the window's own line is weak:
its score less than ``WEAK_LINE_SPREADS = 1.75`` common spreads (at the sub-window's length)
below the random places' mean. A strong line, a correct one through a stretch of alike rows
(Nordland's hard stretches), survives a few recent frames no better than random places; a weak
one, the old line right after a jump (UJI's shuffles), does not. No clock beyond the horizon's.
Measured with the confidence "changepoint" (``docs/sequence.md``): mean AUC margin to the best
fixed window over the 42 cells −0.046 ("punctuated" −0.050, "spanning" −0.052), Nordland −0.023
(−0.031, −0.045), UJI −0.058 (−0.063, −0.056), the synthetic world unchanged, the 30 held-out
cells −0.0305 (one cell −0.0003). The default rule until "contested"; the cluster matcher
(:mod:`catgraph.distributed`) runs it exactly.

``rule="contested"`` is "gated" with a second rival. Where the window's own line is weak at a
recent sub-window's length (its score less than ``CONTEST_LINE_SPREADS = 2.5`` common spreads at
that length below the random places' mean), a line of that length counts as a rival where it
spans ``CONTEST_SPANS = 2`` decorrelation horizons and is significant beyond the best of the
``N V`` random lines searched (``N`` places, ``V`` velocities) by ``CONTEST_MARGIN = 1`` nat
(``log p < -ln(N V) - 1``, not ``SPANNING_MARGIN`` nats beyond ``-ln N``); as with the rival of
"spanning", the window is rejected where its line trails that rival by more than
``RIVAL_SPREADS`` spreads over those frames. Where the rows decorrelate within a few frames (the
synthetic worlds, horizon about 2), a wrong long line (through repeated scenery, or straight
across a stretch driven at another speed) is weak, and a 5- to 16-frame line of several
independent observations that beats it is evidence, although rarely 6 nats beyond chance; a
strong line (Nordland's correct long lines) and a rival shorter than two horizons (about one
observation) are left to the tests of "gated". The same statistics and clock as "gated".
Measured with the confidence "changepoint" (``docs/sequence.md``): mean AUC margin to the best
fixed window over the 42 cells −0.0440 ("gated" −0.0456), Nordland −0.0224 (−0.0225), UJI
−0.0584 (unchanged in every cell), synthetic world −0.0512 (−0.0559), the 30 held-out cells
−0.0273 (−0.0305); no cell more than 0.002 below "gated". The default rule until
"persistent"; the cluster matcher (:mod:`catgraph.distributed`) runs it exactly.

``rule="persistent"`` is "contested" with the midpoint test read only on the recent sub-windows
that span the frame's horizon, where the window's own line is weak (less than
``CONTEST_LINE_SPREADS`` common spreads below the random places' mean at that length), or that
hold a *break* of the rows (the clock of "punctuated"). On Nordland the midpoint test was what
kept the correct 500-frame line out in its hard stretches (its last 34-73 frames, 1.5-3
horizons, more than half way to random places); a strong line now persists through such a
stretch unless the rows broke within it (a jump). Measured with the confidence "changepoint"
(``docs/sequence.md``): mean AUC margin to the best fixed window over the 42 cells −0.0431
("contested" −0.0440), Nordland −0.0198 (−0.0224), UJI, the synthetic world and the 30 held-out
cells equal to "contested" in every cell; no cell more than 0.0021 below it. The default rule
until "challenged"; the cluster matcher (:mod:`catgraph.distributed`) runs it exactly (it
reads what "punctuated" reads).

``rule="challenged"`` is "persistent" whose weak-line rival counts as soon as it is beyond
chance (``log p < -ln N``, no margin: the first form of "contested"), but only where the
window's own line is *unproven* at its full length: not significant beyond the best of the
``N V`` random lines searched by ``PROVEN_MARGIN`` = 10 nats. Without that condition the
rival beyond chance rejects correct weak lines of a constant speed in white rows (weak over
every short stretch, where 8 velocities make chance lines of 4-10 frames look significant);
over its whole length such a line is proven, while the synthetic worlds' wrong long lines are
not. Measured with the confidence "changepoint" (``docs/sequence.md``): mean AUC margin to the
best fixed window over the 42 cells −0.0392 ("persistent" −0.0431), Nordland −0.0195
(−0.0198), UJI −0.0584 (−0.0584), synthetic world −0.0397 (−0.0512), the 30 held-out cells
−0.0187 (−0.0273); no cell more than 0.0065 below "persistent". The default rule until
"tracked", and still the default of the rules that read the matcher's statistics alone
(:data:`DEFAULT_LINE_RULE`: the cluster matcher's, :mod:`catgraph.distributed`, which runs it
exactly, reading what "punctuated" reads; and the filter's sequence models').

``rule="tracked"`` lets a tracker choose the window: an exact grid filter (the registry's
``filter`` method with its defaults, as the grid at any size: the
:class:`~catgraph.observation.TemperedObservation` model, the long-run jump velocity, and a
rigid line beside its motion, prior 0.05 on maps of at most 10,000 places, which holds a track
through a stretch where the frames say little as a long window does; on the chain of the
reference's places) runs beside the matcher on the same rows (before the hub correction,
which its model makes itself). Of the candidate lengths, each at its own most significant velocity, the
window is the one whose best place holds the most of the filter's place posterior within ±1
place (the longest of equals), and its confidence (``"tracked"``, the only one this rule
reads) is that mass as log-odds. A window therefore ends where the filter's track began: it
does not reach back across a jump the filter has followed. Cost: one filter step per frame,
``O(N)`` time and memory on top of the matcher's. The default rule (:data:`DEFAULT_RULE`;
``docs/sequence.md``, "the window chosen by a tracking filter" and "a rigid line beside the
tracker": on the condition table of Nordland, UJI and the synthetic world its AUC is within
0.01 of the best fixed window in all 42 cells, against 13 for "challenged"); the cluster
matcher does not run it.

Hub references (flat, textureless frames close to every query) are corrected before
matching when ``hub_offsets`` (from :func:`catgraph.hubs.hub_offsets`, computed from the
reference map alone) are given: each row has the offsets subtracted and is normalised
again.

Confidence
----------
``confidence="gap"`` is the SeqSLAM-style margin between the best hypothesis and the
best one more than ``radius`` places away (same velocity and window), in units of the
common score spread: ``(s_second - s_best) / std``. ``"support"`` adds up the
gaps of every *admitted* candidate window (at the chosen velocity) whose own best
hypothesis lies within ``radius`` places of the match, and weighs the sum by how well
the *current* frame alone agrees with the match::

    support_i = Phi(-z_i) * sum_{L admitted, |j*(L) - match_i| <= radius} gap_i(L),
    z_i = (d_{i, match_i} - mean_j d_ij) / std_j d_ij

(``Phi`` the standard normal distribution function; the rows as matched, i.e. after the
hub correction). The sum trusts a match that every window length agrees on more than
one that only the chosen length finds, and does not rank gaps measured at different
lengths against each other one by one (the gap grows with the window, so ranking single
gaps ranks frames mostly by their chosen length). The factor ``Phi(-z_i)`` is the
probability that a random place is further from the current frame than the match is:
right after a jump the long windows still carry the old line for a few frames (their
sub-windows cannot yet see the jump), but the current frame already disagrees with it.
Measured on the condition table against ``"gap"`` at the same matches
(``docs/sequence.md``): AUC on UJI's shuffles +0.007 … +0.14 per cell (in order,
reversed, speed 2 within 0.002), Nordland −0.013 … +0.018; R@100P on shuffled Nordland
up in three of five seeds (0.17 → 0.38, 0.08 → 0.25, 0.15 → 0.60) but down on
in-order-like queries (Nordland in order 0.82 → 0.76, speed 0.5 0.64 → 0.35; UJI in
order 0.63 → 0.38).

``"posterior"`` (the default until ``"changepoint"``) keeps the sum but replaces ``Phi(-z_i)`` (a factor of a few at
most: 0.84 at ``z_i = -1``, 0.98 at ``z_i = -2``, where many correct frames lie, against
supports that differ tenfold; the most confident wrong frames right after a jump on
shuffled Nordland lie at ``z_i`` between about −1.3 and +0.6) by the posterior
probability that the current frame still lies on the chosen line::

    posterior_i = P_i * sum_{L admitted, |j*(L) - match_i| <= radius} gap_i(L),
    P_i = sigmoid((z_i^2 - (z_i - mu_i)^2) / 2 - ln JUMP_ODDS),
    mu_i = (s_best(L_i, v_i) - mean_j d_ij) / std_j d_ij

a likelihood ratio between "on the line" (``z_i`` a unit normal around the line's mean
standardised difference ``mu_i``) and "a random place after a jump" (a standard normal),
with prior odds ``JUMP_ODDS = 0.3`` of a jump. Where single frames are distinctive (the
Wi-Fi scans, the synthetic worlds: ``mu_i`` far below 0) one poor frame cuts the
confidence; where they say little (Nordland: ``mu_i`` near 0) it stays near its prior
and the windows' evidence ranks the frames. Measured on the condition table against
``"support"`` at the same matches (``benchmarks/results/sequence.md``, ``docs/sequence.md``):
AUC per cell Nordland −0.000 … +0.003, UJI −0.002 … +0.003, synthetic world +0.008 …
+0.025 (held-out worlds of ``bench_generalisation.py``: +0.002 … +0.020, one cell
−0.001); R@100P on shuffled Nordland 0.27 → 0.34 (mean over seeds) but 0.80 → 0.77 in
order, 0.81 → 0.80 reversed, 0.84 → 0.82 at speed 2.

``"changepoint"`` (default, :data:`DEFAULT_CONFIDENCE`) keeps the sum and weighs the latest
``T = CHANGE_POINT_FRAMES = 5`` frames along the chosen line instead of the current one
alone: every jump time ``t = 1 .. T`` frames back is a hypothesis at the prior odds
``JUMP_ODDS``, the frames since it at random places, those before it on the line::

    changepoint_i = P_i * sum_{L admitted, |j*(L) - match_i| <= radius} gap_i(L),
    P_i = 1 / (1 + JUMP_ODDS * sum_{t=1..T} exp(-sum_{f<t} (z_f^2 - (z_f - mu_i)^2) / 2)),
    z_f = (d_{i-f, j_f} - mean d_{i-f}) / std d_{i-f},  j_f = match_i - (pos_v(i) - pos_v(i - f))

(a term is left out where ``j_f`` is off the reference or the row is flat; ``T = 1`` is
``"posterior"``). Right after a jump on Nordland the long windows still carry the old line
and one frame is weak evidence; a few frames together are stronger. The matcher keeps the
last ``T - 1`` rows for it (``8 (T - 1) N`` bytes). Measured on the condition table against
``"posterior"`` at the same matches (``benchmarks/results/window_rules.md``,
``docs/sequence.md``): mean AUC margin to the best fixed window over the 42 cells −0.0578 →
−0.0524, UJI −0.0632 → −0.0563, synthetic world −0.0676 → −0.0559, held-out worlds −0.0404 →
−0.0305, Nordland −0.0426 → −0.0451; R@100P on shuffled Nordland 0.316 → 0.358 (mean over
seeds) but 0.77 → 0.72 in order, 0.80 → 0.75 reversed, 0.82 → 0.77 at speed 2.

With a fixed window ``"support"``, ``"posterior"`` and ``"changepoint"`` are SeqSLAM's gap
(no factor), so that a fixed window gives the classic method's numbers. ``"neglogp"`` is
``-log p_i(L_i, v_i)``; ``"z"`` is ``(mean - s_best) / std``. ``"tracked"`` (rule
"tracked" only) is the log-odds of the tracking filter's place posterior within ±1 place of
the match. Larger is more confident for all seven.

Two forms
---------
:class:`SequenceMatcher` is the streaming form (one :meth:`~SequenceMatcher.step` per
query frame; time per step ``O(N V G)`` and independent of how many frames came before)
and :func:`match_sequences` the batch form. Both run the same compiled kernel for each
velocity and frame on the same stored values, so they return identical numbers. The
velocities are shared among ``numba.get_num_threads()`` threads (per frame when
streaming, per up to 64 frames in the batch form), each reading the shared ring and writing
only its own sums and outputs, so the result does not depend on the thread count either. Measured figures:
``benchmarks/results/matcher.md``.
"""

from __future__ import annotations

import numbers
import sys
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._validation import check_array, check_scalar
from ._window_rule import SUSTAINED_FRACTION, _decide, _needs_sub, _new_record, _Record, _row_reads, _Stats
from .exceptions import DataError, InvalidParameterError, NotFittedError, ShapeMismatchError

__all__ = [
    "SequenceMatch",
    "SequenceResult",
    "SequenceMatcher",
    "match_sequences",
    "window_grid",
    "fixed_window_scores",
    "APPROXIMATIONS",
    "RULES",
    "CONFIDENCES",
    "DEFAULT_VELOCITIES",
    "DEFAULT_RULE",
    "DEFAULT_LINE_RULE",
    "DEFAULT_CONFIDENCE",
]

APPROXIMATIONS = ("gaussian", "robust", "gmm2", "gmm3")
RULES = ("unrivalled", "evident", "consistent", "sustained", "literal", "predictive", "decorrelated", "spanning",
         "punctuated", "gated", "contested", "persistent", "challenged", "tracked")
#: the window rule of the adaptive window when none is named (the one owner: the matcher and the
#: registry's ``sequence`` method read it from here): the window chosen by a tracking filter
DEFAULT_RULE = "tracked"
#: the default among the rules that read the matcher's statistics alone, with no filter beside
#: the matcher: the cluster matcher's default (it runs these rules exactly) and the window rule
#: of the filter's sequence models (a filter already weighs their scores)
DEFAULT_LINE_RULE = "challenged"
CONFIDENCES = ("changepoint", "posterior", "support", "gap", "neglogp", "z", "tracked")
#: the confidence of the adaptive window's line rules (every rule but "tracked", which has its
#: own) when none is named (the one owner: the matcher, the registry and the cluster read it from here)
DEFAULT_CONFIDENCE = "changepoint"
#: reference places per query frame searched by default: driven backwards or forwards, 0.5x to 3x
DEFAULT_VELOCITIES = (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0)
#: candidate window lengths by default: 13 geometric lengths from l_min to l_max
DEFAULT_GRID = 13
EM_ITERATIONS = 10
EM_MAX_POINTS = 1024


def _kernels():
    # numba kernels are imported (and compiled or loaded from cache) on first use only
    from . import _sequence_kernels

    return _sequence_kernels


# ---------------------------------------------------------------------------------------
# results


@dataclass(frozen=True)
class SequenceMatch:
    """The outcome of one streaming step.

    Attributes
    ----------
    match : int
        Best reference place (``-1`` = no output: a frame with no information of its own,
        a constant row, under every rule; :mod:`catgraph.matching`).
    score : float
        ``s_ij(L, v)`` of the match at the chosen window and velocity (lower is better).
    confidence : float
        Larger is more confident (see the module docstring).
    window_length : int
        Effective window length used (``min(L, frames seen)``).
    velocity : float
        The chosen velocity (reference places per query frame).
    log_p : ndarray, shape (G,), optional
        ``log p_i(L)`` at the chosen velocity for every candidate in ``window_grid`` (on
        request).
    window_grid : ndarray of int, shape (G,), optional
        The candidate window lengths (with ``log_p``).
    """

    match: int
    score: float
    confidence: float
    window_length: int
    log_p: np.ndarray | None = None
    window_grid: np.ndarray | None = None
    velocity: float = 1.0


@dataclass(frozen=True)
class SequenceResult:
    """Batch results, one entry per query frame in processing order.

    Attributes
    ----------
    match : ndarray of int, shape (n_query,)
        Best reference place per frame (``-1`` = no output).
    score, confidence : ndarray of float, shape (n_query,)
    window_length : ndarray of int, shape (n_query,)
        Effective window length used per frame.
    window_grid : ndarray of int, shape (G,)
        The candidate window lengths.
    log_p : ndarray, shape (n_query, G), optional
        ``log p_i(L)`` curves at each frame's chosen velocity (on request).
    velocity : ndarray of float, shape (n_query,)
        The chosen velocity per frame.
    velocities : ndarray of float, shape (V,)
        The velocities searched.
    """

    match: np.ndarray
    score: np.ndarray
    confidence: np.ndarray
    window_length: np.ndarray
    window_grid: np.ndarray
    log_p: np.ndarray | None = None
    velocity: np.ndarray | None = None
    velocities: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.match.shape[0])


# ---------------------------------------------------------------------------------------
# parameters


#: The most lengths a geometric grid may be asked for (``"all"`` gives every length).
MAX_GRID_COUNT = 100_000


def window_grid(l_min: int = 10, l_max: int = 500, grid: str | int | Sequence[int] = "geometric") -> np.ndarray:
    """Candidate window lengths, ascending, unique, ``(G,) int64``.

    Parameters
    ----------
    l_min, l_max : int
        Range of window lengths (inclusive) of the grids built here.
    grid : "geometric", "all", int or sequence of int
        ``"geometric"``: 32 lengths spaced geometrically from ``l_min`` to ``l_max``
        (rounded, duplicates removed); an int ``G`` (at most :data:`MAX_GRID_COUNT`): ``G``
        geometric lengths; ``"all"``:
        every integer in ``[l_min, l_max]``; a sequence: those lengths, as given
        (``l_min`` and ``l_max`` are not read: the sequence is the range).

    Examples
    --------
    >>> window_grid(10, 500, 5).tolist()
    [10, 27, 71, 188, 500]
    """
    owner = "window_grid"
    check_scalar(l_min, "l_min", owner, int, 1)
    check_scalar(l_max, "l_max", owner, int, l_min)
    if isinstance(grid, str):
        if grid == "all":
            return np.arange(l_min, l_max + 1, dtype=np.int64)
        if grid != "geometric":
            raise InvalidParameterError(
                f"The 'grid' parameter of {owner} must be 'geometric', 'all', an int or a sequence of ints. Got {grid!r} instead."
            )
        grid = 32
    if isinstance(grid, numbers.Integral) and not isinstance(grid, bool):
        check_scalar(grid, "grid", owner, int, 1, MAX_GRID_COUNT)
        if grid == 1 or l_min == l_max:
            return np.array([l_min] if grid == 1 else [l_min], dtype=np.int64)
        values = np.rint(np.geomspace(l_min, l_max, int(grid))).astype(np.int64)
        return np.unique(values)
    values = np.asarray(grid)
    if values.ndim != 1 or values.size == 0 or values.dtype.kind not in "iu" or values.min() < 1:
        raise InvalidParameterError(
            f"A window grid given as a sequence must be a non-empty 1-D list of positive ints. Got {grid!r} instead."
        )
    return np.unique(values.astype(np.int64))


#: The fastest line searched, in reference places per query frame either way (a line's
#: position ``v t`` must stay an exact integer index).
MAX_VELOCITY = 100.0


def _velocity_set(velocities, owner: str) -> np.ndarray:
    try:
        values = np.asarray(velocities, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = np.array([np.nan])
    if values.size == 0 or not np.all(np.isfinite(values)) or np.unique(values).size != values.size \
            or np.abs(values).max() > MAX_VELOCITY:
        raise InvalidParameterError(
            f"The 'velocities' parameter of {owner} must be a non-empty sequence of distinct finite floats in "
            f"[-{MAX_VELOCITY:g}, {MAX_VELOCITY:g}] (reference places per query frame, e.g. (-1.0, 1.0, 2.0)). "
            f"Got {velocities!r} instead.")
    return values


@dataclass(frozen=True)
class _Config:
    grid: np.ndarray
    velocities: np.ndarray
    approx_code: int
    n_components: int
    rule: str
    confidence: str
    radius: int
    fixed: bool
    recent_fraction: float
    hub_offsets: np.ndarray | None


def _config(owner, window, approximation, rule, confidence, l_min, l_max, grid, radius, recent_fraction,
            velocities, hub_offsets) -> _Config:
    if approximation not in APPROXIMATIONS:
        raise InvalidParameterError(
            f"The 'approximation' parameter of {owner} must be one of {APPROXIMATIONS}. Got {approximation!r} instead."
        )
    if rule not in RULES:
        raise InvalidParameterError(f"The 'rule' parameter of {owner} must be one of {RULES}. Got {rule!r} instead.")
    tracked = rule == "tracked" and isinstance(window, str)
    if confidence is None:  # the rule's own
        confidence = "tracked" if tracked else DEFAULT_CONFIDENCE
    if confidence not in CONFIDENCES:
        raise InvalidParameterError(
            f"The 'confidence' parameter of {owner} must be one of {CONFIDENCES}. Got {confidence!r} instead."
        )
    if tracked != (confidence == "tracked"):
        raise InvalidParameterError(
            f"{owner}: confidence 'tracked' (the tracking filter's mass) and the adaptive window's rule 'tracked' go "
            f"together; got rule {rule!r}, window {window!r}, confidence {confidence!r}. Leave the confidence unset "
            "(None: the rule's own) or name both.")
    check_scalar(radius, "radius", owner, int, 0)
    check_scalar(recent_fraction, "recent_fraction", owner, float, 0.0, 1.0)
    if isinstance(window, str):
        if window != "adaptive":
            raise InvalidParameterError(
                f"The 'window' parameter of {owner} must be 'adaptive' or a positive int. Got {window!r} instead."
            )
        check_scalar(l_min, "l_min", owner, int, 1)
        check_scalar(l_max, "l_max", owner, int, l_min)
        values = window_grid(l_min, l_max, grid)
        fixed = False
    else:
        check_scalar(window, "window", owner, int, 1)
        values = np.array([int(window)], dtype=np.int64)
        fixed = True
    vel = _velocity_set(velocities, owner)
    offsets = None if hub_offsets is None else check_array(hub_offsets, "hub offsets", ndim=1)
    code = {"gaussian": 0, "robust": 1, "gmm2": 2, "gmm3": 2}[approximation]
    k = {"gaussian": 1, "robust": 1, "gmm2": 2, "gmm3": 3}[approximation]
    return _Config(values, vel, code, k, rule, confidence, int(radius), fixed, float(recent_fraction), offsets)


def _prepare_rows(d: np.ndarray, cfg: _Config) -> np.ndarray:
    """Rows as the kernels see them: hub-corrected (and normalised again) when asked."""
    if cfg.hub_offsets is None:
        return d
    if cfg.hub_offsets.shape[0] != d.shape[-1]:
        raise ShapeMismatchError(
            f"the difference rows have {d.shape[-1]} reference places but there are {cfg.hub_offsets.shape[0]} hub "
            "offsets; compute the offsets from the same reference map (catgraph.hubs.hub_offsets).")
    from .hubs import apply_hub_offsets

    return np.ascontiguousarray(apply_hub_offsets(d, cfg.hub_offsets))


_BLOCK_VALUES = 4_000_000
_CHUNK_VALUES = 1 << 24
#: difference values per block of rows of :func:`match_sequences` (float64: 32 MiB, and as
#: much again for the hub-corrected copy)
_ROW_VALUES = 1 << 22


def _state(cfg: _Config, n: int, chunk: int = 1):
    """The matcher's state for ``N = n`` places: the integer window sums (int32; int64
    beyond ``l_max = 65,538``), the int16 ring of the codes of the last ``l_max + chunk``
    rows (``chunk`` new rows are stored at a time) with their mean codes, and the scratch
    the kernels need (the robust and mixture scratch only for those approximations)."""
    v_count, g_count, rows = cfg.velocities.shape[0], cfg.grid.shape[0], int(cfg.grid[-1]) + chunk
    sums_dtype = _kernels().sums_dtype(cfg.grid[-1])
    from ._validation import check_memory

    check_memory(float(n) * (v_count * g_count * np.dtype(sums_dtype).itemsize + 2 * rows), f"the matcher's state for "
                 f"{n} places (a ring of the last {rows} rows, {v_count * g_count} running sums per place)",
                 "use a shorter l_max, fewer window lengths or velocities, or a smaller map")
    sums = np.zeros((v_count, g_count, n), dtype=sums_dtype)
    ring = np.zeros((rows, n), dtype=np.int16)
    mring = np.zeros(rows, dtype=np.int16)
    state = np.zeros(2)  # the quantum (fixed by the first row not all zeros), the count of clipped values
    scores = np.empty((v_count, n if cfg.approx_code != 0 else 0))  # the Gaussian path reads the sums only
    work = np.empty((v_count, n if cfg.approx_code == 1 else 0))
    resp = np.empty((v_count, cfg.n_components, n if cfg.approx_code == 2 else 0))
    return sums, ring, mring, state, (scores, work, resp)


def _warn_clipped(state: np.ndarray) -> None:
    """Warn where the matcher stored values at its largest code (clipped: the precision
    policy of the module docstring)."""
    count = int(state[1])
    if count:
        from .exceptions import warn

        warn(
            f"{count} differences reached the sequence matcher's largest stored value (8 times the largest |d| of "
            "the query's first row that is not all zeros) and were clipped there: the window scores that hold them "
            "are approximate. Normalise the rows per query (catgraph.differences.normalise_rows, the front-end's "
            "default), or start the query with a frame of its typical scale.")


def _record(cfg: _Config) -> _Record | None:
    """Rules "predictive" and "decorrelated" carry each length's predictive record from frame to frame."""
    return _new_record(cfg)


def _em_stride(n: int) -> int:
    """Mixtures are fitted to every ``stride``-th score, at most ~``EM_MAX_POINTS``."""
    return max(1, -(-n // EM_MAX_POINTS))


# ---------------------------------------------------------------------------------------
# batch form


def fixed_window_scores(differences: np.ndarray, window: int, velocity: float = 1.0) -> np.ndarray:
    """All window scores ``s_ij(L, v)`` for one window and velocity, ``(n_query, N) float64``.

    Uses the line and edge policy of the module docstring. Memory is the output itself
    plus ``O(N * L)``; for long queries prefer :func:`match_sequences`, which never
    stores the scores.
    """
    d = check_array(differences, "difference matrix", ndim=2)
    check_scalar(window, "window", "fixed_window_scores", int, 1)
    check_scalar(velocity, "velocity", "fixed_window_scores", float, -MAX_VELOCITY, MAX_VELOCITY)
    return _kernels().fixed_scores(np.ascontiguousarray(d), int(window), float(velocity))


def match_sequences(
    differences: np.ndarray,
    window: int | str = "adaptive",
    approximation: str = "gaussian",
    rule: str = DEFAULT_RULE,
    confidence: str | None = None,
    l_min: int = 5,
    l_max: int = 500,
    grid: str | int | Sequence[int] = DEFAULT_GRID,
    radius: int = 10,
    recent_fraction: float = 0.05,
    return_curves: bool = False,
    velocities: Sequence[float] = DEFAULT_VELOCITIES,
    hub_offsets: np.ndarray | None = None,
) -> SequenceResult:
    """Match every query frame (rows of ``differences``, in processing order).

    Parameters
    ----------
    differences : ndarray, shape (n_query, N), or DifferenceRows
        Difference matrix (lower = more similar), rows in the order the query frames
        are processed (e.g. a shuffled query's order). Usually per-query normalised. Or
        its rows block by block (:class:`~catgraph.differences.DifferenceRows`): the
        same answers, one block of rows in memory at a time.
    window : int or "adaptive"
        A fixed window length, or ``"adaptive"`` to choose one per frame.
    approximation : {"gaussian", "robust", "gmm2", "gmm3"}
        Approximation of the score distribution used for ``p_i(L)``.
    rule : str
        Window choice, one of :data:`RULES` ("unrivalled", "evident", "consistent", "sustained",
        "literal", "predictive", "decorrelated", "spanning", "punctuated", "gated", "contested",
        "persistent", "challenged", "tracked"), see the module
        docstring (default :data:`DEFAULT_RULE`).
    confidence : {"changepoint", "posterior", "support", "gap", "neglogp", "z", "tracked"}, optional
        Confidence given to each match (see the module docstring). Default ``None``: the
        rule's own, "tracked" for rule "tracked" (which reads no other), else
        :data:`DEFAULT_CONFIDENCE`.
    l_min, l_max : int
        Range of candidate window lengths (adaptive only; a ``grid`` given as a sequence
        of lengths is its own range).
    grid : "geometric", "all", int or sequence of int
        Candidate lengths, see :func:`window_grid`.
    radius : int
        Places either side of the best match excluded when looking for the second best
        (``confidence="gap"``, ``"support"``, ``"posterior"`` and ``"changepoint"``), and the
        agreement radius of the last three.
    recent_fraction : float
        A window of length ``L`` is tested on its recent sub-windows of length ``l`` in
        the grid with ``recent_fraction * L <= l < L`` (the midpoint test of rules
        "unrivalled", "evident", "consistent" and "sustained"; "unrivalled" and "evident"
        also test every shorter sub-window against random places).
    return_curves : bool
        Also return ``log p_i(L)`` (at each frame's chosen velocity) for every frame and
        candidate length.
    velocities : sequence of float
        Velocities searched (reference places per query frame; negative = driven
        backwards). ``(1.0,)`` is the classic diagonal.
    hub_offsets : ndarray, shape (N,), optional
        Per-reference offsets from :func:`catgraph.hubs.hub_offsets`; each row is
        corrected (and normalised again) before matching.

    Returns
    -------
    SequenceResult
    """
    from .differences import DifferenceRows

    cfg = _config("match_sequences", window, approximation, rule, confidence, l_min, l_max, grid, radius,
                  recent_fraction, velocities, hub_offsets)
    if not isinstance(differences, DifferenceRows):  # checked block by block below
        differences = DifferenceRows.of(check_array(differences, "difference matrix", ndim=2, finite=False))
    n_q, n = differences.shape
    if n_q == 0 or n == 0:
        raise DataError(f"difference matrix is empty (shape {differences.shape}); at least one frame is needed.")
    run = _kernels().matcher_kernel(cfg.approx_code)
    g = cfg.grid.shape[0]
    v_count = cfg.velocities.shape[0]
    # the ring holds up to 64 rows more than the longest window: the kernel stores that
    # many rows at a time, then runs the velocities in parallel over those frames
    sums, ring, mring, state, scratch = _state(cfg, n, max(1, min(64, _CHUNK_VALUES // n)))
    # rows are processed in blocks so that the (block, V, G, G) sub-window scores stay small,
    # and so do the block's rows (the answers do not depend on the blocks: the streaming step
    # is a block of one row)
    block = max(1, min(n_q, _BLOCK_VALUES // (v_count * g * g), _ROW_VALUES // n))
    record = _record(cfg)
    parts = []
    for start, raw in differences.checked(block):
        raw = np.ascontiguousarray(raw)
        stop = start + len(raw)
        d = _prepare_rows(raw, cfg)
        st = _Stats(stop - start, v_count, g, cfg.n_components, _needs_sub(cfg))
        run(d, start, sums, ring, mring, state, cfg.velocities, cfg.grid, cfg.approx_code,
            EM_ITERATIONS, _em_stride(n), cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std,
            st.weights, st.locs, st.scales, st.sub, *scratch)
        parts.append(_decide(st, cfg, np.arange(start, stop), return_curves, d, record, raw_rows=raw))
    _warn_clipped(state)
    match, score, conf, length, velocity = (np.concatenate([p[c] for p in parts]) for c in range(5))
    log_p = np.concatenate([p[5] for p in parts]) if return_curves else None
    return SequenceResult(match=match, score=score, confidence=conf, window_length=length,
                          window_grid=cfg.grid.copy(), log_p=log_p, velocity=velocity,
                          velocities=cfg.velocities.copy())


# ---------------------------------------------------------------------------------------
# streaming form


def _checked_row(difference_row) -> np.ndarray:
    """The streaming step's row as the kernels read it (1-D, float64, contiguous, finite):
    a row a filter has checked already (:class:`catgraph.observation.CheckedRow`) is not
    scanned again; any other row is checked in full (:func:`check_array`, its errors). The
    observation module is not imported for this: a row can be a ``CheckedRow`` only once it is."""
    observation = sys.modules.get(__package__ + ".observation")
    if observation is not None and type(difference_row) is observation.CheckedRow and difference_row.ndim == 1 \
            and difference_row.dtype == np.float64 and difference_row.flags.c_contiguous and difference_row.size:
        return difference_row.view(np.ndarray)
    return np.ascontiguousarray(check_array(difference_row, "difference row", ndim=1))


class SequenceMatcher:
    """Streaming sequence matcher: one :meth:`step` per query frame.

    Parameters are those of :func:`match_sequences`. The constructor only stores them;
    the first :meth:`step` fixes the number of reference places ``N`` and the quantum of
    the stored values (module docstring), and allocates one int16 ring of the codes of the
    last ``max(grid) + 1`` difference rows shared by every velocity
    (``2 * N * (l_max + 1)`` bytes) and, per velocity, an int32 running sum per
    candidate length and line (``4 * N * G`` bytes; one float64 row more for the robust
    and mixture approximations). Time per
    step is ``O(N * V * G)`` (``V`` velocities, ``G`` candidate lengths), however many
    frames came before; the velocities run in parallel threads.

    Attributes
    ----------
    n_reference_ : int
        ``N``, set by the first step.
    n_steps_ : int
        Frames processed so far.
    window_grid_ : ndarray of int, shape (G,)
        Candidate window lengths.
    velocities_ : ndarray of float, shape (V,)
        Velocities searched.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(size=(30, 50))
    >>> matcher = SequenceMatcher(window=5)
    >>> out = [matcher.step(row) for row in d]
    >>> batch = match_sequences(d, window=5)
    >>> bool(np.all(batch.match == [o.match for o in out]))
    True
    """

    def __init__(
        self,
        window: int | str = "adaptive",
        approximation: str = "gaussian",
        rule: str = DEFAULT_RULE,
        confidence: str | None = None,
        l_min: int = 5,
        l_max: int = 500,
        grid: str | int | Sequence[int] = DEFAULT_GRID,
        radius: int = 10,
        recent_fraction: float = 0.05,
        velocities: Sequence[float] = DEFAULT_VELOCITIES,
        hub_offsets: np.ndarray | None = None,
    ) -> None:
        self.window = window
        self.approximation = approximation
        self.rule = rule
        self.confidence = confidence
        self.l_min = l_min
        self.l_max = l_max
        self.grid = grid
        self.radius = radius
        self.recent_fraction = recent_fraction
        self.velocities = velocities
        self.hub_offsets = hub_offsets

    def reset(self) -> "SequenceMatcher":
        """Forget all frames (the next step starts a new query)."""
        for name in ("n_reference_", "n_steps_", "window_grid_", "velocities_", "_cfg", "_sums", "_ring", "_mring",
                     "_state", "_buffers", "_stats", "_record", "_clipped_told"):
            self.__dict__.pop(name, None)
        return self

    def _start(self, n: int) -> None:
        cfg = _config(type(self).__name__, self.window, self.approximation, self.rule, self.confidence,
                      self.l_min, self.l_max, self.grid, self.radius, self.recent_fraction, self.velocities,
                      self.hub_offsets)
        self._cfg = cfg
        self.window_grid_ = cfg.grid.copy()
        self.velocities_ = cfg.velocities.copy()
        self.n_reference_ = n
        self.n_steps_ = 0
        self._sums, self._ring, self._mring, self._state, self._buffers = _state(cfg, n)
        self._stats = _Stats(1, cfg.velocities.shape[0], cfg.grid.shape[0], cfg.n_components, _needs_sub(cfg))
        self._record = _record(cfg)

    def window_scores(self, length: int, velocity: float | None = None) -> np.ndarray:
        """``(N,)`` window scores ``s_ij(L, v)`` of the latest frame ``i`` at length ``L``.

        Same policy and stored values as the matcher itself (query start:
        ``min(L, i+1)`` terms; outside the reference: neutral fill): a candidate length
        reads the matcher's own running sums, any other length is summed from the ring in
        ``O(N L)``, with the same result. ``L`` may not exceed the longest candidate
        length (``l_max``, or a fixed window, or the largest of a grid given as lengths:
        the ring holds no more); ``velocity`` must be one of the matcher's velocities
        (default: ``1.0`` if searched, else the first).
        """
        if not hasattr(self, "n_steps_") or self.n_steps_ == 0:
            raise NotFittedError("window_scores needs at least one step(); call step(difference_row) first.")
        check_scalar(length, "length", "SequenceMatcher.window_scores", int, 1, self._ring.shape[0] - 1)
        vel = self.velocities_
        if velocity is None:
            vi = int(np.flatnonzero(vel == 1.0)[0]) if np.any(vel == 1.0) else 0
        else:
            hits = np.flatnonzero(vel == float(velocity))
            if hits.size == 0:
                raise InvalidParameterError(
                    f"velocity {velocity!r} is not searched by this matcher; choose one of {vel.tolist()}.")
            vi = int(hits[0])
        s = np.empty(self.n_reference_)
        i, v = self.n_steps_ - 1, float(vel[vi])
        hits = np.flatnonzero(self.window_grid_ == int(length))
        if hits.size:  # the matcher's own running sums
            _kernels().scores_from_sums(self._sums[vi, int(hits[0])], i, v, int(length), self._state[0], s)
        else:  # any other length, summed term by term from the ring
            _kernels().direct_scores(self._ring, self._mring, i, v, int(length), self._state[0], s)
        return s

    def step(self, difference_row: np.ndarray, return_curve: bool = False) -> SequenceMatch:
        """Process one query frame.

        Parameters
        ----------
        difference_row : ndarray, shape (N,)
            Differences of this query frame to every reference place.
        return_curve : bool
            Also return ``log p_i(L)`` over the candidate lengths (chosen velocity).

        Returns
        -------
        SequenceMatch
        """
        row = _checked_row(difference_row)
        if not hasattr(self, "_ring"):
            self._start(row.shape[0])
        elif row.shape[0] != self.n_reference_:
            raise ShapeMismatchError(
                f"difference row has {row.shape[0]} reference places but the matcher was started with "
                f"{self.n_reference_}; call reset() before matching against another reference."
            )
        raw, row = row, _prepare_rows(row, self._cfg)
        cfg, st, i = self._cfg, self._stats, self.n_steps_
        s, work, resp = self._buffers
        run = _kernels().matcher_kernel(cfg.approx_code)
        frame, rows = np.array([i]), row[None, :]
        reads = []  # the window rule's reads of the row alone, formed beside the kernels' other threads
        tracker = getattr(self._record, "tracker", None)

        def beside():
            reads.append(_row_reads(cfg, frame, rows, self._record))
            if tracker is not None:  # rule "tracked": its filter reads the row alone
                tracker.step(raw)

        run(rows, i, self._sums, self._ring, self._mring, self._state, cfg.velocities, cfg.grid,
            cfg.approx_code, EM_ITERATIONS, _em_stride(self.n_reference_), cfg.radius, st.best_j, st.best_s,
            st.second_s, st.mean, st.std, st.weights, st.locs, st.scales, st.sub, s, work, resp, beside=beside)
        self.n_steps_ = i + 1
        if self._state[1] and not self.__dict__.get("_clipped_told"):  # once per query
            self._clipped_told = True
            _warn_clipped(self._state)
        match, score, conf, length, velocity, log_p = _decide(st, cfg, frame, return_curve, rows, self._record,
                                                             reads[0], raw[None, :])
        return SequenceMatch(
            match=int(match[0]), score=float(score[0]), confidence=float(conf[0]), window_length=int(length[0]),
            log_p=None if log_p is None else log_p[0].copy(),
            window_grid=self.window_grid_.copy() if return_curve else None, velocity=float(velocity[0]),
        )
