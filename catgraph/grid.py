"""An exact (point-mass) Bayes filter over places and velocities on the place graph.

The particle filter (:mod:`catgraph.localizer`) approximates a posterior that, on a graph
of up to ~10⁵ places, can simply be computed: one probability per (place, velocity bin).
:class:`GridLocalizer` does that. It is the slow, obviously correct reference the
particle filter is tested against, and a mode of its own where the map is small enough.

State
-----
``P[j, b]``: the probability of being at place ``j`` moving with velocity ``v_b``
(places per frame, *signed*: ``v_b < 0`` drives the route backwards), plus one scalar
``P(new)`` for "a place the map does not cover" (the new-place hypothesis of
:mod:`catgraph.localizer`, with the same two-state prior).

One step
--------
Predict (:func:`predict`), then update with the observation model's log-likelihood
ratios ``r_j`` (:mod:`catgraph.observation`)::

    P ← P · T                         sticky velocity transition (B × B)
    P ← shift(P)                      each bin moves |v_b| places in direction sign(v_b)
    P ← (1 − 2q) P + q (P⁺ + P⁻)      blur: a little mass one place either way
    P ← (1 − ε) P + ε · U             recovery: uniform over places × velocity prior
    P[j, b] ← P[j, b] · e^{r_j}       likelihood (every velocity of a place alike)
    normalise (with the new place)

``T`` keeps a velocity with probability ``velocity_stay``, moves to a neighbouring
speed of the same sign otherwise, and turns round (``v → −v``) with probability
``reverse_probability``. A fractional speed ``w + p/q`` (``q ≤ max_phases``, default 4)
is driven by ``q`` *phase bins* that move ``w`` or ``w + 1`` places in a fixed cycle
(``v = 0.5``: 0, 1, 0, 1 … places; :func:`phase_bins`), so that a track at half the
reference's speed stays as sharp as one at full speed; a fraction that would need more
phases moves mass to the two bracketing places linearly (a random walk: one bin at
``v = 0.5`` spreads a point mass over ±5 places in 100 frames, which lost Nordland at
half speed, ``docs/particle_filter.md``). ``P[j, b]`` and ``T`` are over these state
bins; :attr:`GridLocalizer.state_` sums the phases of each velocity. A *hop* follows the route
edge of the direction of travel (chain edge forwards, reverse edge backwards); at a
place with junction edges a share ``junction_probability`` per junction leaves along
it and continues at the other place, half in each direction (a crossing may turn
either way; where the velocity set has no ``−v`` bin, both halves keep ``v``). Mass
that would run past a dead end leaves the map (the normalisation gives its share back
to the rest): a route end is no place to wait, and letting mass stop there would pile
every backward-moving hypothesis up at place 0. Where every hypothesis runs off (odometry
longer than the route), there is no rest: the filter starts again uniform over the
places, with the jump velocity. With odometry ``u`` (metres since the
last frame) the shift is ``u`` along the route instead of ``|v_b|`` places, walking the
chain's edge lengths (junctions are taken only by frame-based motion).

Recovery and jumps. ``ε`` is the probability per frame of a jump anywhere on the map; a
jump is then found by Bayes' rule: the uniform share is weighted by the frame's
likelihood like everything else, so a run of frames the current track cannot explain
moves the mass. A jump changes the place, not the speed: the recovery share lands with
half the current velocity marginal and half uniform (``jump_velocity="current"``, the
class default), or with the query's long-run velocity distribution (``"long-run"``, the
registry's ``filter`` method; :class:`~catgraph.motion.LongRunVelocity`: a discounted
mean of the posterior velocity marginal, half-life ``RECOVERY_MEMORY`` frames, the
uniform prior worth ``RECOVERY_PRIOR_FRAMES`` frames; ``docs/particle_filter.md``, tenth
round). ``ε`` is learned
online (``learn_recovery``, default): after each frame the posterior share of that
frame's recovery mass, ``ε · mean_j e^{r_j} / Σ_j prior_j e^{r_j}`` (the E-step of EM
for a mixture weight), enters a discounted mean (half-life ``RECOVERY_MEMORY`` frames,
the ``recovery`` argument as a prior worth ``RECOVERY_PRIOR_FRAMES`` frames). A query in
order drives ``ε`` down, so the track is held tightly; a query that jumps drives it up,
so the filter lets go of a track sooner.

Jump rates weighed by the evidence (``jump_rates``, off by default). With one jump rate
a jump anywhere costs ``log(N / ε)`` nats however long the track has held, so a stretch
over which a wrong track out-scores the true one by more than that moves the answer,
whatever the hundreds of frames before it said; and the one rate also decides how fast a
real jump is followed. With ``jump_rates = (ε_1 … ε_K)`` the state is one posterior over
(place, velocity) per rate, with weights ``w_k``, each weighted by its evidence ``Σ_j
prior_kj e^{r_j}`` frame by frame; the answer, its confidence and the model's feedback
read the mixture. Two models of what a rate belongs to (``jump_rate_scope``):

* ``"query"`` (Bayesian model averaging over the rate): the query has one jump rate,
  unknown; component ``k`` is the fixed-rate filter of ``ε_k`` and ``w_k`` its
  posterior probability. A query that has held its track for thousands of frames has
  given the small rates its evidence (each frame without a jump costs the rate ``ε``
  about ``ε`` nats), so there a jump costs about ``log(N / ε_K)``; a query that jumps
  often has given it to the large rates, which then follow a jump at once.
* ``"run"`` (a run-length hazard, Bayesian online change-point detection, Adams &
  MacKay 2007): each run between two jumps draws its rate from ``π`` at its start and
  keeps it, so the hazard of the run's length is a mixture of geometric ones that falls
  with the run's age. Component ``k`` keeps ``w_k (1 − ε_k)`` of its moved mass and
  receives ``π_k J`` of the jump mass ``J = Σ_k w_k ε_k``. ``π`` is learned
  (``learn_recovery``): the posterior probability that a run ended at a frame, ``J ·
  mean_j e^{r_j} / Σ_j prior_j e^{r_j}``, is counted to the rates in proportion to
  ``w_k ε_k`` (the rate of the run that ended), on a uniform Dirichlet prior. A
  decreasing hazard is the wrong shape for a query cut into segments of bounded length
  (whose hazard rises with the segment's age): measured in ``docs/particle_filter.md``,
  ninth round.

Every jump lands uniformly over places with the mixture's jump velocity. Time and
memory ``× K``.

A rigid line beside the filter's motion (``rigid_prior``; off in this class by default, on in
the registry's ``filter`` method on maps of at most 10,000 places, ``catgraph.methods.RIGID_PRIOR``
and ``RIGID_MAX_PLACES``). A long fixed
window compares whole lines of one slope and never considers a jump or a change of
speed; a filter whose motion allows both (any jump rate, any ``velocity_stay < 1``) lets
a wrong track that out-scores the true one over a hard stretch take the answer, because
a jump costs at most ``log(N / ε)`` nats whatever the frames before the stretch said
(``docs/particle_filter.md``, eighth to eleventh rounds). With ``rigid_prior = p`` the
filter averages two motion models by Bayes' rule (the ``"query"`` scope of ``jump_rates``:
one posterior over (place, velocity) each, weighted by its evidence ``Σ_j prior_kj
e^{r_j}`` frame by frame): its own (``velocity_stay``, ``blur``, the jump rate, learned
or fixed), prior weight ``1 − p``, and a *rigid line*, prior weight ``p``: the velocity
never changes (``velocity_stay`` 1, no turning), no blur, jump rate
:data:`RIGID_JUMP_RATE`. ``p`` is the prior probability that the query is one unbroken
line driven at one speed. A query that does neither gives the rigid line the weight
(each frame the flexible motion pays its jump rate and velocity leak, about 0.03 nats on
Nordland, so after ``n`` frames its log-odds have grown by about ``0.03 n``), and a jump
then costs ``log(N / RIGID_JUMP_RATE)`` nats. A query that jumps or changes speed refutes
the rigid line once the frames' evidence has spent that lead (its weight falls to the
floor its own rare jump keeps, and grows back only as slowly as it was earned), and the
filter's own motion carries on: a jump is followed later by about the frames that spend
the lead, the price of the rigid line on a query that does jump. Every
jump lands with the mixture's jump velocity; the jump rate of the filter's own motion is
learned from its own component's evidence. Time and memory ``× 2``.

New place. ``P(new)`` is a two-state hypothesis "this frame is a place the map does
not cover", entered with probability ``new_place_prior`` per frame and kept with
``new_place_stay``, weighted by the model's ``new_place_log_ratio`` against the map's
``log Σ_j prior_j e^{r_j}``. When the track stops explaining the frames (after a jump,
or in unmapped space) the map's evidence falls below the new place's and ``P(new)``
rises, so the confidence ``P(map) · mass near the answer`` falls at once, before the
mass has moved to the new place. :attr:`Estimate.score` and the confidence drop as
soon as either happens.

Outlier frames (``outlier_probability`` ``p``, default 0). A camera frame with a lorry in
front of it, a blank image or a Wi-Fi scan that missed its access points shows no place of
the map, and the linear evidence of the tempered model would let such a frame move a track
by ten nats or more. With ``p > 0`` each frame shows no mapped place with probability
``p``, in which case its likelihood at every place is the new-place hypothesis's (a frame
as a place drawn at random from the map would look); place ``j``'s likelihood is then
``(1 − p) e^{r_j} + p e^{r_new}``. Computed on the ``e_j = e^{r_j − top}`` the update uses
anyway: ``e_j + c`` with ``c = p/(1 − p) · e^{r_new − top}``, rescaled to a largest value of
1 (one pass over the places). The map's evidence for the new-place step is the same
mixture. A frame that explains nothing costs a track at most about ``log(1/p)`` nats against
a place that the frame explains no better than a new place would; a real jump then moves
the mass once the frames after it confirm the new place rather than at its first frame
(measured in ``docs/particle_filter.md``, "Outlier frames").

Speeds between the bins. A track moves at its bin's speed, so a query driven at a speed
between two bins drifts from every bin by the difference, and only the blur and the
velocity transition (a few nats each time) bring it back: with :data:`DEFAULT_VELOCITIES`
(±0.5, 1, 2, 3) Nordland at 1.5 times the reference's speed scored AUC 0.13, at 0.75
0.40 and at 1.1 0.77, against 0.98–0.99 at 0.5, 1 and 2
(``benchmarks/results/generalisation_speeds.md``). A speed split between the places
either side of its move (a bin of 1.1 moves one place, and a tenth of its mass two) blurs
a track by ``f (1 − f)`` places² a frame, which absorbs a drift of a twentieth of a place
per frame: a bin at 1.1 held Nordland at 1.05, 1.1 and 1.15 (AUC 0.980, 0.982, 0.968) and
lost it at 1.2 (0.912). :data:`DENSE_VELOCITIES` has a bin every tenth of a place per
frame from 0.9 to 4, and below it only a half, two thirds and three quarters, as phase
bins: every slow bin is a track that can creep along a stretch of look-alike places, and
on short routes they cost more than they were worth (ten 357-frame sections of Nordland:
bins at a quarter, a third and every tenth from 0.4 lowered the mean AUC in order from
0.937 to 0.912, one section from 0.976 to 0.812), so a query slower than half the
reference's speed, or between the slow bins, is not followed (``docs/particle_filter.md``,
"Speeds between the bins").

A speed that changes all the time (``varying_prior``; off in this class by default, on in the
registry's ``filter`` method on maps of at most 10,000 places, ``catgraph.methods.VARYING_SHARE``).
With bins a tenth of a place per frame apart, the filter's own velocity (kept with
``velocity_stay`` 0.99) moves a tenth at ``log 0.005`` nats a time, so a query whose speed keeps
changing falls off its track at each change (UJI months 02–06 at a speed that moves between
0.5 and 2 times the reference's all the time, ``Condition("vary")``: AUC 0.57–0.70, against
0.91–0.98 at a constant 0.5 or 2), and a looser own velocity costs the shuffles
(``velocity_stay`` 0.95: a Nordland shuffle down by 0.07). With ``varying_prior = q`` a third
motion model joins the average with the rigid line (the same Bayes' rule: its own posterior
over (place, velocity), weighted by its evidence frame by frame): the filter's own kind of
motion with its velocity kept with :data:`VARYING_VELOCITY_STAY`, the same blur and turning,
and the jump rate the own motion learns, prior weight ``q`` (the own motion ``1 − p − q``). A
query at one speed gives it little weight, one whose speed keeps changing most of it (UJI
0.68–0.79; ``docs/particle_filter.md``, "A speed that changes all the time"). Time and memory:
one more component.

Frames that come again (``repeat_prior``; off in this class by default, the registry's
``filter`` method: ``catgraph.methods.REPEAT_PRIOR``; :mod:`catgraph._twin`, shared with the
particle filter). A query frame equal to the one before
(the same difference row, with no odometry) says nothing new about the place and nothing about
whether the robot moved. The tempered model gives it almost no evidence, so through a run of
them the filter moves on at its speed; a query that *stands still* — stopped at lights, or
driven at a fraction of the reference's speed, whose frames then repeat (``Condition("stop")``,
``Condition("speed", factor=1/4)``) — is found again only by a jump after the run (Nordland
in order with stops of 5–50 frames: AUC 0.86–0.88 against 0.99; a quarter of the speed:
0.04). The obvious repair, to hold the filter through a run, is wrong on the real data:
there the frames that repeat are a camera or scanner repeating itself while the robot moved
on (Nordland's winter video is frozen for its first 17 and last 15 frames, UJI delivers a
Wi-Fi scan twice now and then), and holding cost Nordland in order 0.986 → 0.977 and UJI's
R@100P 0.98 → 0.34. So the filter keeps both readings: from the first repeat it runs a twin
that stands still through every run (it advances on new frames only) beside itself, which
moves on; each is weighed by its evidence frame by frame (Bayes' rule over the two readings
of the whole query, from the prior ``repeat_prior``), the answer is their mixture, and once
keeping one reading moves the mixture by no more than round-off (the lighter one's weight
times the distance between the two posteriors: :data:`GridLocalizer.TWIN_AGREEMENT`) the
heavier one goes on alone, with what it learned, until the next repeat (the answers after
it can differ from keeping both: ``docs/particle_filter.md``). A reading per run instead (the held
posterior merged back at each run's end with a fixed weight) made speed 0.5 erratic
(Nordland 0.71–0.985 as that weight went from 0.05 to 0.9): with runs every other frame,
each merge mixed two tracks of different speeds.

Estimate. Mass per place ``m_j = (1 − P(new)) Σ_b P[j, b]``; the answer ``argmax_j m_j``,
its confidence the mass within ``confidence_radius`` places of it along the route (or
metres, on a graph with positions, ``confidence_radius_m``), its log-odds the log-odds of
that mass. A "place" of the radius is the map's mean spacing along the route
(:attr:`~catgraph.graph.PlaceGraph.frame_spacing`), not an index step: the neighbourhood is
every place whose route distance from the answer is at most ``confidence_radius`` mean
spacings. On a map of evenly spaced frames the two agree (±2 places); on a map surveyed
as several samples per point (UJI's Wi-Fi: six scans at each point, 4.4 m between
points, mean spacing 0.9 m) an index step would count a neighbouring point's first scan
as the same place as this point's last, so at every point boundary the confidence would
mix two points; by route distance the neighbourhood is the point's own scans. Log-odds are
computed from the masses with a floor of ``1e-300`` on the outside mass, so they stay
finite and ordered when the confidence is exactly 1 (a two-place map).

Score (what ranks frames, :attr:`Estimate.score`). The log-odds, lowered by
``unconverged_penalty`` until the filter has *converged* for the first time: until its
log-odds have stayed above ``converged_log_odds`` for ``converged_frames`` consecutive
frames. A filter that starts uniform over thousands of places, with a model that is
still learning its temperature and hub levels, can put half its mass on a wrong stretch
for a few frames before it has ever held a track (Nordland in order: frames 47–49, the
most confident wrong answers of the traverse, ranked 2,927th–3,112th of 3,576 by the
log-odds); a filter that has held one has shown that its evidence is strong enough to
track, and from then on the log-odds rank its frames unchanged. The penalty never
returns after a jump: a jump is the filter's normal business, and a young track after
one is usually right (UJI's short shuffles). Measured on every condition of Nordland,
UJI and the synthetic world in ``docs/particle_filter.md``.

Feedback. After each step the filter calls ``model.feedback(FilterFeedback)`` with the
predicted (prior) and posterior place masses (:class:`~catgraph.observation.FilterFeedback`):
models that learn from the filter (the tempered whole-image model) do it there.

Cost. On a *line* graph (the chain of a route: place ``j``'s neighbours are ``j ± 1``,
no junctions) without odometry, the prediction is a per-velocity shift by index
arithmetic plus the blur, computed in one compiled pass over a velocity-major state, a
block of places at a time (:data:`_LINE_BLOCK`; a block's state rows and its halo stay
in cache, and each row's transition is shifted and blurred while it is still there),
and the update is kept factored (prediction × the frame's likelihood per place, whose
``exp`` numpy computes before the prediction, so that the kernel forms the posterior's
velocity sums while it writes each row): a step reads the state once and writes it
once, ``O(n_places · n_bins)`` (see ``benchmarks/results/filter_speed.md``). The
update's per-place writes — the likelihood, the posterior place masses, the place
posterior handed out, and the answer's place — are one compiled pass, run once the
new-place step has given the map's share (:func:`_posterior_pass`). On a large
map (:data:`LINE_WORK_PER_THREAD` state values per thread) the blocks are shared among
the cores not busy with other processes (:func:`_cores_free`) in
runs of whole blocks, each taken by whichever thread is free; every block
writes its own places and its own velocity sums, added in block order afterwards, so
the numbers are those of one thread, bit for bit (tested against the one-pass serial
kernel). The result is the unfused one's to round-off (the velocity sums are added in
another order). That
path stores the prediction in float32 (half the memory traffic; every sum, the
likelihood and the place masses stay float64): it agrees with the float64 path to
about 1e-6 relative over tens of steps (tested to 1e-5), and exactly when given a
float64 state. Branching graphs and odometry take the general path (:func:`predict`: a
walk along the graph's edges, junctions included, float64), which is also the slow
reference the line path is tested against.
Memory ``O(n_places · n_bins)``.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from ._jit import njit
from ._twin import TwinReadings, logistic as _logistic, mixed_answer
from ._validation import check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .graph import PlaceGraph
from .jumps import JUMP_RATE_CAP, frame_jump_rate

__all__ = ["GridLocalizer", "route_neighbours", "velocity_transition", "predict", "learn_jump_rate"]

_CHAIN, _REVERSE, _JUNCTION = 0, 1, 2

#: The learned jump rate: half-life (frames) of its running mean, weight (frames) of
#: the ``recovery`` prior, and its range.
RECOVERY_MEMORY = 100.0
RECOVERY_PRIOR_FRAMES = 20.0
RECOVERY_RANGE = (1e-4, JUMP_RATE_CAP)  # one owner of the largest rate: catgraph.jumps

def learn_jump_rate(jumps: float, frames: float, prior: float, current: float,
                    ratio: float) -> tuple[float, float, float]:
    """One step of the online EM for the jump rate ``ε``, shared by both filters.

    The E-step: this frame's posterior share of the recovery mass, ``current · ratio``
    with ``ratio = mean_j e^{r_j} / Σ_j prior_j e^{r_j}`` (at most 1). It enters
    discounted sums (half-life :data:`RECOVERY_MEMORY` frames); the M-step is their
    ratio, shrunk towards ``prior`` (worth :data:`RECOVERY_PRIOR_FRAMES` frames) and
    clipped to :data:`RECOVERY_RANGE`.

    Returns
    -------
    jumps, frames, epsilon : float
        The updated discounted sums and the new jump rate.
    """
    decay = 0.5 ** (1.0 / RECOVERY_MEMORY)
    jumps = decay * jumps + min(1.0, current * ratio)
    frames = decay * frames + 1.0
    eps = (jumps + RECOVERY_PRIOR_FRAMES * prior) / (frames + RECOVERY_PRIOR_FRAMES)
    return jumps, frames, float(min(max(eps, RECOVERY_RANGE[0]), RECOVERY_RANGE[1]))


#: The rigid line's jump rate (``rigid_prior``): about ``log(N / 1e-12)`` ≈ 36 nats to
#: leave a track on a map of 3,576 places.
RIGID_JUMP_RATE = 1e-12

#: The velocity of the varying speed's motion (``varying_prior``) keeps its bin with this
#: probability per frame, and moves to a neighbouring speed otherwise: ten times as often as
#: the filter's own (``velocity_stay`` 0.99), so that a speed that changes all the time is
#: followed through the dense bins (module docstring, "A speed that changes all the time").
VARYING_VELOCITY_STAY = 0.9

#: What ``jump_rates`` are the rates of: the whole query (Bayesian model averaging over
#: the rates) or each run between two jumps (a run-length hazard).
JUMP_RATE_SCOPES = ("query", "run")

#: The velocity distribution a jump lands with: half the current marginal and half
#: uniform, or the query's long-run one.
JUMP_VELOCITIES = ("current", "long-run")

#: Default signed velocity bins (places per query frame).
DEFAULT_VELOCITIES = (-3.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 3.0)

#: Signed velocity bins for a query at any speed from half the reference's to four times
#: it (the registry's on maps of at most ``methods.DENSE_VELOCITY_MAX_PLACES`` places):
#: every tenth of a place per frame from 0.9 to 4, and below it a half, two thirds and
#: three quarters (phase bins), both ways (module docstring, "Speeds between the bins").
DENSE_VELOCITIES = tuple(sorted({s * v for s in (-1.0, 1.0)
                                 for v in (1.0 / 2.0, 2.0 / 3.0, 3.0 / 4.0, *(k / 10.0 for k in range(9, 41)))}))


def route_neighbours(graph: PlaceGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The one-hop structure the grid filter moves mass along.

    Returns
    -------
    forward, backward : ndarray of int64, shape (n_places,)
        Target of the chain edge (route order) / reverse-chain edge leaving each place,
        or ``-1``.
    forward_length, backward_length : ndarray of float64, shape (n_places,)
        Their lengths (``inf`` where there is none).
    junction_ptr : ndarray of int64, shape (n_places + 1,)
    junction_target : ndarray of int64
        CSR lists of the places reached by each place's junction edges.
    """
    n = graph.n_places
    fwd = np.full(n, -1, dtype=np.int64)
    bwd = np.full(n, -1, dtype=np.int64)
    fl = np.full(n, np.inf)
    bl = np.full(n, np.inf)
    chain = graph.kind == _CHAIN
    rev = graph.kind == _REVERSE
    fwd[graph.source[chain]] = graph.target[chain]
    fl[graph.source[chain]] = graph.length[chain]
    bwd[graph.source[rev]] = graph.target[rev]
    bl[graph.source[rev]] = graph.length[rev]
    # a graph given without edge kinds (all "chain") still has reverse edges: the one
    # going back to a smaller index is "backward"
    if not rev.any():
        back = chain & (graph.target < graph.source)
        fwd_only = chain & (graph.target > graph.source)
        fwd[:] = -1
        fl[:] = np.inf
        fwd[graph.source[fwd_only]] = graph.target[fwd_only]
        fl[graph.source[fwd_only]] = graph.length[fwd_only]
        bwd[graph.source[back]] = graph.target[back]
        bl[graph.source[back]] = graph.length[back]
    junction = graph.kind == _JUNCTION
    src, dst = graph.source[junction], graph.target[junction]
    order = np.argsort(src, kind="stable")
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(ptr, src + 1, 1)
    return fwd, bwd, fl, bl, np.cumsum(ptr), dst[order].astype(np.int64)


def velocity_transition(velocities: np.ndarray, stay: float, reverse: float) -> np.ndarray:
    """``(B, B)`` row-stochastic velocity transition.

    Row ``b``: ``stay`` on ``b``; ``reverse`` on the bin of ``−v_b`` (if there is one);
    the rest split between the neighbouring speeds of the same sign (all of it to the
    one neighbour at the end of the range).
    """
    v = np.asarray(velocities, dtype=np.float64)
    b = len(v)
    t = np.zeros((b, b))
    for i in range(b):
        same = [k for k in np.argsort(np.abs(v)) if np.sign(v[k]) == np.sign(v[i])]
        pos = same.index(i)
        nbrs = [same[p] for p in (pos - 1, pos + 1) if 0 <= p < len(same)]
        mirror = np.flatnonzero(np.isclose(v, -v[i]))
        rest = 1.0 - stay
        t[i, i] += stay
        if len(mirror) and v[i] != 0:
            t[i, mirror[0]] += reverse
            rest -= reverse
        if nbrs:
            for k in nbrs:
                t[i, k] += rest / len(nbrs)
        else:
            t[i, i] += rest
    return t


@njit
def _shift_walk(p, out, whole, frac, sign, fwd, bwd, t_ptr, t_src, t_val):  # pragma: no cover
    """Velocity transition then :func:`_frames_rows`' hops for a graph without junctions, fused:
    each place's mass walks its hops. The transition comes as sparse columns:
    ``q_b = Σ_c p[t_src[c]] t_val[c]`` for ``c`` in ``t_ptr[b]:t_ptr[b+1]``."""
    n, nb = p.shape
    out[:] = 0.0
    q = np.empty(nb)
    for j in range(n):
        for b in range(nb):
            acc = 0.0
            for c in range(t_ptr[b], t_ptr[b + 1]):
                acc += p[j, t_src[c]] * t_val[c]
            q[b] = acc
        for b in range(nb):
            m = q[b]
            if m == 0.0:
                continue
            t = j
            for _ in range(whole[b]):
                t = fwd[t] if sign[b] > 0 else bwd[t]
                if t < 0:
                    break
            if t < 0:
                continue  # ran off the route's end
            out[t, b] += (1.0 - frac[b]) * m
            if frac[b] > 0.0:
                u = fwd[t] if sign[b] > 0 else bwd[t]
                if u >= 0:
                    out[u, b] += frac[b] * m


@njit(fastmath=True)
def _likelihood(state, e, prior_mass, like, velocity, mass, summed):  # pragma: no cover - compiled
    """The update, kept factored, in one pass over the state. ``e`` holds
    ``e^{r_j − top}`` (computed by numpy, whose vectorised ``exp`` is several times
    numba's); ``like[j] = e_j / Σ_j prior_mass_j e_j``, so that the posterior is
    ``state[b, j] · like[j]`` (velocity-major ``state``, the prediction, left untouched);
    ``mass`` gets the posterior place masses ``prior_mass · like`` and ``velocity`` the
    posterior velocity marginal (summed with the unnormalised ``e`` in the same pass,
    divided at the end). ``summed``: ``velocity`` holds those sums already (the line
    kernel forms them while it writes the prediction, :func:`_line_predict`), and the
    state is not read at all. Returns ``(total, mean e)``: the normaliser before division
    (0: every place impossible, ``like`` and ``mass`` left as they were)."""
    nb, n = state.shape
    like_sum = 0.0
    total = 0.0
    if not summed:
        for b in range(nb):
            velocity[b] = 0.0
    for j0 in range(0, n, 4096):
        j1 = min(n, j0 + 4096)
        ee = e[j0:j1]
        pm = prior_mass[j0:j1]
        for j in range(j1 - j0):
            like_sum += ee[j]
            total += pm[j] * ee[j]
        if summed:
            continue
        for b in range(nb):
            row = state[b, j0:j1]
            acc = 0.0
            for j in range(j1 - j0):
                acc += row[j] * ee[j]
            velocity[b] += acc
    if not (total > 0.0) or not np.isfinite(total):
        return 0.0, like_sum / n
    inv = 1.0 / total
    for j in range(n):
        x = e[j] * inv
        like[j] = x
        mass[j] = prior_mass[j] * x
    for b in range(nb):
        velocity[b] *= inv
    return total, like_sum / n


#: Places per block of the line kernel (its working set, the state rows of a block plus
#: their halo, stays in the second-level cache; the one row of the transition it works
#: on, in the first).
_LINE_BLOCK = 1024


@njit(fastmath=True)
def _line_kept(p, like, t_ptr, t_src, t_val, whole, frac, sign):  # pragma: no cover - compiled
    """The mass of :func:`_line_setup`'s prediction that stays on the route, summed
    directly: each bin's transition times the likelihood, over the places its hop does
    not carry past a route end."""
    nb, n = p.shape
    kept = 0.0
    for b in range(nb):
        for part in range(2):
            hops = whole[b] + part
            share = 1.0 - frac[b] if part == 0 else frac[b]
            if share == 0.0:
                continue
            lo, hi = (0, n - hops) if sign[b] > 0 else (hops, n)
            for j in range(max(lo, 0), min(hi, n)):
                acc = 0.0
                for c in range(t_ptr[b], t_ptr[b + 1]):
                    acc += t_val[c] * p[t_src[c], j]
                kept += share * acc * like[j]
    return kept


@njit(fastmath=True)
def _line_setup(p, like, prior_mass, t_ptr, t_src, t_val, whole, frac, sign, blur, recovery):  # pragma: no cover
    """The scalars of :func:`_line_predict` that need the whole state: the mass that
    runs past a route end (summed from the few places within reach of the ends), and
    from it the recovery share per place ``share0``, the blur's ``centre`` and ``side``
    weights and the largest whole hop ``reach``."""
    nb, n = p.shape
    total_in = 0.0
    for j in range(n):
        total_in += prior_mass[j] * like[j]
    lost = 0.0
    reach = 0
    for b in range(nb):
        if whole[b] > reach:
            reach = whole[b]
        for part in range(2):
            hops = whole[b] + part
            share = 1.0 - frac[b] if part == 0 else frac[b]
            if share == 0.0 or hops == 0:
                continue
            lo, hi = (n - hops, n) if sign[b] > 0 else (0, hops)
            if lo < 0:
                lo = 0
            if hi > n:
                hi = n
            for j in range(lo, hi):
                acc = 0.0
                for c in range(t_ptr[b], t_ptr[b + 1]):
                    acc += t_val[c] * p[t_src[c], j]
                lost += share * acc * like[j]
    total = total_in - lost
    if lost > 0.5 * total_in:
        # most of the mass runs off the route: the difference cancels (and in a float32 state
        # the two sums are not even of the same numbers), so sum what stays, directly
        total = _line_kept(p, like, t_ptr, t_src, t_val, whole, frac, sign)
    keep = (1.0 - recovery) / total if total > 0 else 0.0
    share0 = recovery / n if total > 0 else 1.0 / n
    centre = keep * (1.0 - 2.0 * blur)
    side = keep * blur
    return share0, centre, side, reach


@njit(fastmath=True, nogil=True)
def _line_blocks(p, like, out, mass, t_ptr, t_src, t_val, whole, frac, sign, share0, centre, side, reach,
                 velocity_prior, block, e, j_start, j_stop, accs):  # pragma: no cover - compiled
    """The blocks of places ``j_start, j_start + block, ... < j_stop`` of
    :func:`_line_predict` (``j_start`` a multiple of ``block``): for a block (plus a halo
    of the largest hop and the blur), row by row, the transition of the row times the
    likelihood (one row buffer, still in cache when it is read back), then its shift by
    index arithmetic, the blur and the recovery (into ``out[b]``); ``mass`` gets the
    predicted place masses. A whole move (a whole speed, every phase bin) inside the
    route reads the shifted row directly; a split move (a fraction beyond
    ``max_phases``) and the blocks at the route's ends go through the moved-mass buffer.
    Given the next frame's ``e`` (empty: none), ``accs[k, b]`` gets block ``k``'s
    ``Σ_j out[b, j] e_j`` (the stored prediction, rounded as stored; 0 without ``e``).
    Writes only its own blocks and releases the GIL: threads run disjoint ranges."""
    nb, n = p.shape
    fuse = len(e) > 0
    halo = reach + 2  # a hop of whole + 1 places, then the blur's one
    width = block + 2 * halo
    tb = np.empty(width)  # one row of T·like over [j0 − halo, j1 + halo), zero outside the route
    mv = np.empty(block + 2)  # moved mass over [j0 − 1, j1 + 1)
    for j0 in range(j_start, j_stop, block):
        j1 = min(n, j0 + block)
        kb = j0 // block
        a = max(0, j0 - halo)
        z = min(n, j1 + halo)
        off = a - (j0 - halo)
        lk = like[a:z]
        m = mass[j0:j1]
        for j in range(j1 - j0):
            m[j] = 0.0
        w = j1 - j0
        for i in range(off):  # before the route's start
            tb[i] = 0.0
        for i in range(off + z - a, width):  # past its end
            tb[i] = 0.0
        tt = tb[off:off + z - a]
        for b in range(nb):  # each row's transition, then at once its shift and blur (the row in cache)
            accs[kb, b] = 0.0
            c0, k = t_ptr[b], t_ptr[b + 1] - t_ptr[b]
            if k <= 4:  # velocity_transition's columns: the bin itself, two neighbours, the mirror
                r0 = p[t_src[c0], a:z]
                r1 = p[t_src[c0 + 1], a:z] if k > 1 else r0
                r2 = p[t_src[c0 + 2], a:z] if k > 2 else r0
                r3 = p[t_src[c0 + 3], a:z] if k > 3 else r0
                w0 = t_val[c0]
                w1 = t_val[c0 + 1] if k > 1 else 0.0
                w2 = t_val[c0 + 2] if k > 2 else 0.0
                w3 = t_val[c0 + 3] if k > 3 else 0.0
                for i in range(z - a):
                    tt[i] = (w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i]) * lk[i]
            elif k <= 6:  # a speed next to a phased one: its neighbour's phases add a source each
                r0, r1, r2 = p[t_src[c0], a:z], p[t_src[c0 + 1], a:z], p[t_src[c0 + 2], a:z]
                r3, r4 = p[t_src[c0 + 3], a:z], p[t_src[c0 + 4], a:z]
                r5 = p[t_src[c0 + 5], a:z] if k > 5 else r0
                w0, w1, w2, w3, w4 = t_val[c0], t_val[c0 + 1], t_val[c0 + 2], t_val[c0 + 3], t_val[c0 + 4]
                w5 = t_val[c0 + 5] if k > 5 else 0.0
                for i in range(z - a):
                    tt[i] = (w0 * r0[i] + w1 * r1[i] + w2 * r2[i] + w3 * r3[i] + w4 * r4[i] + w5 * r5[i]) * lk[i]
            else:
                for i in range(z - a):
                    tt[i] = 0.0
                for c in range(c0, c0 + k):
                    src, wc = p[t_src[c], a:z], t_val[c]
                    for i in range(z - a):
                        tt[i] += wc * src[i]
                for i in range(z - a):
                    tt[i] *= lk[i]
            # moved[j] = (1 − f) T[j − s h] + f T[j − s (h + 1)], j from j0 − 1 to j1
            step = sign[b] * whole[b]
            f0, f1 = 1.0 - frac[b], frac[b]
            ti = tb[halo - 1 - step:halo - 1 - step + w + 2]
            o = out[b, j0:j1]
            base = share0 * velocity_prior[b]
            if f1 == 0.0 and j0 > 0 and j1 < n:  # a whole move (every phase bin) inside the route: no split
                if fuse:
                    ee = e[j0:j1]
                    acc = 0.0
                    for k in range(w):
                        x = centre * ti[k + 1] + side * (ti[k] + ti[k + 2]) + base
                        o[k] = x
                        m[k] += x
                        acc += o[k] * ee[k]
                    accs[kb, b] = acc
                else:
                    for k in range(w):
                        x = centre * ti[k + 1] + side * (ti[k] + ti[k + 2]) + base
                        o[k] = x
                        m[k] += x
                continue
            tk = tb[halo - 1 - step - sign[b]:halo - 1 - step - sign[b] + w + 2]
            for k in range(w + 2):
                mv[k] = f0 * ti[k] + f1 * tk[k]
            if j0 == 0:  # a route end keeps the blur that would leave it
                mv[0] = mv[1]
            if j1 == n:
                mv[w + 1] = mv[w]
            for k in range(w):
                x = centre * mv[k + 1] + side * (mv[k] + mv[k + 2]) + base
                o[k] = x
                m[k] += x
            if fuse:
                ee = e[j0:j1]
                acc = 0.0
                for k in range(w):
                    acc += o[k] * ee[k]
                accs[kb, b] = acc


#: Places per chunk of the update's sums (:func:`_likelihood`, :func:`_evidence_sums`).
_EVIDENCE_CHUNK = 4096


@njit(fastmath=True)
def _evidence_sums(e, prior_mass, j_start, j_stop, sums):  # pragma: no cover - compiled
    """``sums += (Σ_j e_j, Σ_j prior_mass_j e_j)`` over places ``j_start .. j_stop − 1``,
    in chunks of :data:`_EVIDENCE_CHUNK` places (``j_start`` a multiple of it), each
    added to the running sums: the floats of :func:`_likelihood`'s sums."""
    like_sum = sums[0]
    total = sums[1]
    for j0 in range(j_start, j_stop, 4096):
        j1 = min(j_stop, j0 + 4096)
        ee = e[j0:j1]
        pm = prior_mass[j0:j1]
        for j in range(j1 - j0):
            like_sum += ee[j]
            total += pm[j] * ee[j]
    sums[0] = like_sum
    sums[1] = total


@njit
def _posterior_pass(e, inv, prior_mass, like, mass, posterior, keep):  # pragma: no cover - compiled
    """The update's writes in one pass, once its normaliser ``1 / inv`` and the map's
    share ``keep = 1 − P(new)`` are known: ``like[j] = e_j · inv``, the posterior place
    masses ``mass[j] = prior_mass_j · like[j]`` and ``posterior[j] = mass[j] · keep`` (the
    floats of :func:`_likelihood` and of numpy's product); returns the first place of the
    largest mass (``np.argmax``: the first NaN, if any)."""
    n = e.shape[0]
    best = 0
    top = -np.inf
    for j in range(n):
        x = e[j] * inv
        like[j] = x
        m = prior_mass[j] * x
        mass[j] = m
        posterior[j] = m * keep
        if m > top or (m != m and top == top) or j == 0:
            best = j
            top = m
    return best


@njit
def _line_sums(accs, velocity):  # pragma: no cover - compiled
    """``velocity[b] = Σ_k accs[k, b]``, added block after block (the order of one pass)."""
    for b in range(accs.shape[1]):
        velocity[b] = 0.0
    for k in range(accs.shape[0]):
        for b in range(accs.shape[1]):
            velocity[b] += accs[k, b]


#: State values (places × bins) per thread below which the line kernel runs on one
#: thread (waking a second costs more than it saves on a small map).
LINE_WORK_PER_THREAD = 1 << 18
#: Runs of whole blocks per thread the line kernel's places are cut into.
LINE_PIECES_PER_THREAD = 4
#: Seconds the machine's load average is read for (:func:`_free_cores`).
LOAD_CHECK_SECONDS = 1.0
_LOAD = [-math.inf, 0.0]  # when the load was last read, and what it was


def _free_cores(cores: int) -> int:
    """The cores not busy with other processes: ``cores`` less the one-minute load
    average beyond this process's own (at least 1; read at most every
    :data:`LOAD_CHECK_SECONDS`). A thread handed a block range on a core that another
    process holds is descheduled for whole time slices while the other threads wait for
    its range: measured on a two-core machine with a second process running, the step
    at 10⁵ places took 1.4 times as long on two threads as on one
    (``benchmarks/results/grid_speed.md``)."""
    now = time.monotonic()
    if now - _LOAD[0] > LOAD_CHECK_SECONDS:
        try:
            _LOAD[1] = os.getloadavg()[0]
        except (AttributeError, OSError):  # pragma: no cover - no load average on this platform
            _LOAD[1] = 0.0
        _LOAD[0] = now
    return int(max(1, min(cores, math.floor(cores + 1.5 - _LOAD[1]))))


#: Seconds over which this process's own CPU use is averaged (the 1-minute load average's).
OWN_LOAD_SECONDS = 60.0
_OWN = [math.nan, 0.0, 0.0]  # when this process's CPU time was last read, that time, and its running average


def _free_of_others(cores: int) -> int:
    """The cores not busy with *other* processes: ``cores`` less the 1-minute load average
    beyond this process's own CPU use, averaged over the same minute (its CPU seconds per
    second), with half a core of margin; read at every call (once a frame).

    :func:`_free_cores` allows one and a half cores of load for the process itself. At 10⁶
    places the live step's row and matcher run two threads for two thirds of every frame,
    so its own load alone is 1.5–2 and that rule keeps the combined model's second thread
    (:func:`catgraph.observation._observe_parts`) off on an otherwise idle machine, where
    it was measured to save 4.7–4.8 ms a frame (``docs/live.md``, "The step at 10⁶
    places"). The average starts from the process's mean use since it started
    (:func:`_own_use_since_start`)."""
    now, cpu = time.monotonic(), time.process_time()
    last, last_cpu, own = _OWN
    if last == last:  # not the first call: fold the interval's CPU seconds per second into the average
        span = now - last
        if span > 0.0:
            keep = math.exp(-span / OWN_LOAD_SECONDS)
            own = keep * own + (1.0 - keep) * (cpu - last_cpu) / span
    else:
        own = _own_use_since_start(cpu)
    _OWN[:] = [now, cpu, own]
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # pragma: no cover - no load average on this platform
        return 1
    return int(max(1, min(cores, math.floor(cores + 0.5 - (load - own)))))


def _cores_free(cores: int) -> int:
    """The cores a pass may put threads on, one rule for every pass that threads (the
    grid filter's line kernel, the jump grid, the particle filter's ``exp`` terms, the
    combined model's second part): the cores free by the load average
    (:func:`_free_cores`) or, where this process's own threads explain the load, the
    cores free of other processes (:func:`_free_of_others`), whichever is more. On a
    large map the step's own threads (the difference row, the matcher) keep the load at
    1.5–2 on two cores, so the first rule alone keeps every later pass on one thread on
    an otherwise idle machine (``docs/live.md``, "The step at 10⁶ places")."""
    free = _free_cores(cores)
    return free if free >= cores else max(free, _free_of_others(cores))


def _own_use_since_start(cpu: float) -> float:
    """This process's CPU seconds per second of its life (``cpu``: its CPU seconds), from
    its start time in ``/proc`` (0 where that cannot be read)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = float(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0
    return cpu / age if age > 1.0 else 0.0


_POOL = {}


def _line_predict(p, like, prior_mass, out, mass, t_ptr, t_src, t_val, whole, frac, sign, blur,
                  recovery, velocity_prior, block, e, velocity, threads=None, sums=None):
    """:func:`predict` on a line graph (place ``j``'s neighbours are ``j ± 1``, no
    junctions, no odometry) from the factored posterior ``p[b, j] · like[j]``
    (velocity-major), in one pass over the state, ``block`` places at a time
    (:func:`_line_blocks`); ``mass`` gets the predicted place masses. The mass that runs
    past a route end, needed before the first place is written, is summed first
    (:func:`_line_setup`). Given the next frame's ``e`` (:func:`_likelihood`; empty:
    none), ``velocity[b]`` gets ``Σ_j out[b, j] e_j`` (the stored prediction, rounded as
    stored) while the row is written, so that the update need not read the state again.

    The blocks are shared among ``threads`` threads (default: as many as the work is
    worth, :data:`LINE_WORK_PER_THREAD`, at most the cores not busy with other
    processes, :func:`_cores_free`) in runs of whole blocks
    (:data:`LINE_PIECES_PER_THREAD` per thread), each taken by whichever thread is free;
    every block writes its own places and its own velocity sums, which are added in
    block order afterwards, so the result is the same, bit for bit, on any number of
    threads.

    ``sums`` (with ``e``): set to the update's sums ``(Σ_j e_j, Σ_j mass_j e_j)``
    (:func:`_evidence_sums`)."""
    nb, n = p.shape
    share0, centre, side, reach = _line_setup(p, like, prior_mass, t_ptr, t_src, t_val, whole, frac, sign, blur,
                                              recovery)
    blocks = -(-n // block)
    accs = np.empty((blocks, nb))
    if threads is None:
        from .differences import _threads_available

        threads = _threads_available()
        threads = min(threads, (nb * n) // LINE_WORK_PER_THREAD)
        if threads > 1:
            threads = min(threads, _cores_free(threads))
    threads = int(max(1, min(threads, blocks)))
    args = (p, like, out, mass, t_ptr, t_src, t_val, whole, frac, sign, share0, centre, side, reach,
            velocity_prior, block, e)
    if threads == 1:
        _line_blocks(*args, 0, n, accs)
    else:
        # a few runs of whole blocks per thread, each taken by whichever thread is free
        # (a thread that shares its core with other work takes fewer)
        pieces = min(blocks, LINE_PIECES_PER_THREAD * threads)
        edges = [(blocks * t // pieces) * block for t in range(pieces + 1)]
        queue = iter(list(zip(edges[:-1], edges[1:])))
        if threads - 1 not in _POOL:
            from concurrent.futures import ThreadPoolExecutor

            _POOL[threads - 1] = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="catgraph-grid")

        def take():
            for lo, hi in queue:
                _line_blocks(*args, lo, min(hi, n), accs)

        jobs = [_POOL[threads - 1].submit(take) for _ in range(threads - 1)]
        try:
            take()
        finally:
            for job in jobs:
                job.result()
    if sums is not None and len(e) > 0:
        sums[0] = sums[1] = 0.0
        _evidence_sums(e, mass, 0, n, sums)
    _line_sums(accs, velocity)


@njit
def _distance_moves(distance, step, lengths):  # pragma: no cover - compiled
    """Where ``distance`` along the route takes each place's mass one way (``step``: the
    next place that way, ``lengths``: the edge lengths to it): ``(first, second, w_first,
    w_second)`` per place, the mass landing between ``first`` and ``second`` in those shares
    (``first = -1``: it ran off the route's end; ``second = -1``: all of it on ``first``, which
    is where mass that reaches a route end exactly, or stands there, stays)."""
    n = step.shape[0]
    first, second = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
    w_first, w_second = np.zeros(n), np.zeros(n)
    for j in range(n):
        left = distance
        cur = j
        while True:
            t = step[cur]
            if t < 0:
                if left <= 0.0:  # reached the route's end exactly, or stood still there: it stays
                    first[j] = cur
                    w_first[j] = 1.0
                break  # else it ran off the route's end
            ln = lengths[cur]
            if left < ln:
                a = left / ln if ln > 0 else 1.0
                first[j], second[j] = cur, t
                w_first[j], w_second[j] = 1.0 - a, a
                break
            left -= ln
            cur = t
    return first, second, w_first, w_second


@njit
def _transition_rows(p, out, t_ptr, t_src, t_val):  # pragma: no cover - compiled
    """The velocity transition on the filter's own layout, ``(n_bins, n_places)`` rows, from
    its sparse columns (:func:`_sparse_columns`): ``out[b] = Σ_c p[t_src[c]] t_val[c]`` for
    ``c`` in ``t_ptr[b]:t_ptr[b+1]``, in that order."""
    nb, n = out.shape
    for b in range(nb):
        row = out[b]
        row[:] = 0.0
        for c in range(t_ptr[b], t_ptr[b + 1]):
            src, v = t_src[c], t_val[c]
            for j in range(n):
                row[j] += p[src, j] * v


@njit
def _distance_rows(p, out, sign, forward, backward):  # pragma: no cover - compiled
    """Move every bin's row the frame's distance along the route in its direction
    (``sign[b]``), each direction's moves from :func:`_distance_moves` (each place walked
    once a way, not once per bin)."""
    nb, n = p.shape
    for b in range(nb):
        first, second, w_first, w_second = forward if sign[b] > 0 else backward
        row, src = out[b], p[b]
        row[:] = 0.0
        for j in range(n):
            m = src[j]
            if m == 0.0:
                continue
            c1 = first[j]
            if c1 < 0:
                continue
            row[c1] += w_first[j] * m
            c2 = second[j]
            if c2 >= 0:
                row[c2] += w_second[j] * m


@njit
def _frames_rows(p, out, whole, frac, sign, mirror, fwd, bwd, jptr, jdst, p_junction):  # pragma: no cover
    """Move every bin's row its velocity's places along the route, hop by hop: ``whole``
    hops, then a ``frac`` share one hop further; at a place with junctions a share
    ``p_junction`` per junction (at most one half) turns into them, half into the bin, half
    into its mirror (``mirror[b]``: the other direction). ``p`` is the work buffer
    (overwritten)."""
    nb, n = p.shape
    cur = p
    out[:] = 0.0
    max_h = 0
    for b in range(nb):
        if whole[b] + 1 > max_h:
            max_h = whole[b] + 1
        if whole[b] == 0:
            for j in range(n):
                out[b, j] += (1.0 - frac[b]) * cur[b, j]
                cur[b, j] *= frac[b]
    nxt = np.empty_like(cur)
    for h in range(1, max_h + 1):
        nxt[:] = 0.0
        for b in range(nb):
            if not (whole[b] >= h or (whole[b] + 1 == h and frac[b] > 0.0)):
                continue
            s = sign[b]
            for j in range(n):
                m = cur[b, j]
                if m == 0.0:
                    continue
                nj = jptr[j + 1] - jptr[j]
                pj = p_junction * nj
                if pj > 0.5:
                    pj = 0.5
                t = fwd[j] if s > 0 else bwd[j]
                if t >= 0:  # at a dead end the mass leaves the map (renormalised)
                    nxt[b, t] += m * (1.0 - pj)
                if nj > 0:
                    share = m * pj / nj * 0.5
                    for c in range(jptr[j], jptr[j + 1]):
                        k = jdst[c]
                        nxt[b, k] += share
                        nxt[mirror[b], k] += share
        cur, nxt = nxt, cur
        for b in range(nb):
            if whole[b] == h:
                for j in range(n):
                    out[b, j] += (1.0 - frac[b]) * cur[b, j]
                    cur[b, j] *= frac[b]
            elif whole[b] + 1 == h:
                for j in range(n):
                    out[b, j] += cur[b, j]
                    cur[b, j] = 0.0


@njit
def _blur_rows(p, out, q, fwd, bwd, recovery, velocity_prior):  # pragma: no cover - compiled
    """Blur one place either way, normalise, mix in the recovery share (``recovery / n``
    per place, spread over the bins as ``velocity_prior``)."""
    nb, n = p.shape
    total = 0.0
    for j in range(n):
        for b in range(nb):
            total += p[b, j]
    for b in range(nb):
        for j in range(n):
            out[b, j] = (1.0 - 2.0 * q) * p[b, j]
    for b in range(nb):
        for j in range(n):
            f = fwd[j] if fwd[j] >= 0 else j
            k = bwd[j] if bwd[j] >= 0 else j
            m = q * p[b, j]
            out[b, f] += m
            out[b, k] += m
    keep = (1.0 - recovery) / total if total > 0 else 0.0
    share = recovery / n if total > 0 else 1.0 / n
    for b in range(nb):
        for j in range(n):
            out[b, j] = keep * out[b, j] + share * velocity_prior[b]


def _predict_rows(p: np.ndarray, t_sparse: tuple, moves: tuple, neighbours: tuple, blur: float, recovery: float,
                  velocity_prior: np.ndarray, junction_probability: float, odometry: float | None) -> np.ndarray:
    """:func:`predict` on the filter's own layout, for odometry or a graph with junctions:
    ``p`` the posterior as ``(n_bins, n_places)`` float64 rows (overwritten), the result the
    same rows."""
    fwd, bwd, fl, bl, jptr, jdst = neighbours
    whole, frac, sign, mirror = moves
    moved = np.empty_like(p)
    _transition_rows(p, moved, *t_sparse)
    shifted = p  # p is spent: its buffer takes the shift
    if odometry is None:
        _frames_rows(moved, shifted, whole, frac, sign, mirror, fwd, bwd, jptr, jdst, float(junction_probability))
    else:
        distance = float(odometry)
        _distance_rows(moved, shifted, sign, _distance_moves(distance, fwd, fl), _distance_moves(distance, bwd, bl))
    _blur_rows(shifted, moved, float(blur), fwd, bwd, float(recovery), np.asarray(velocity_prior, dtype=np.float64))
    return moved


def phase_bins(velocities, max_phases: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                      np.ndarray]:
    """The filter's state bins: every velocity, a fractional speed split into its phases.

    A speed ``|v| = w + p/q`` (``p/q`` in lowest terms, ``q ≤ max_phases``) is driven
    by ``q`` bins, the *phases* ``i = 0 … q − 1`` of a cycle: phase ``i`` moves
    ``w + ⌊(i + 1) p/q⌋ − ⌊i p/q⌋`` whole places and hands its mass to phase
    ``i + 1 (mod q)``. So ``v = 0.5`` alternates 0 and 1 places, exactly as a query
    driven at half the reference's speed does, and a point mass stays a point mass.
    (One bin per speed would have to split the mass between the two bracketing places
    every frame, a random walk whose spread grows as ``√(k/4)`` places after ``k``
    frames: a track at half speed held by the motion alone blurs over ±5 places in 100
    frames.) Whole speeds, and fractions that need more than ``max_phases`` phases, keep
    one bin and the linear split.

    Returns
    -------
    owner : ndarray of int64, shape (n_bins,)
        The velocity (index into ``velocities``) of each bin; bins of one velocity are
        contiguous, in phase order.
    whole, frac, sign : ndarray, shape (n_bins,)
        Each bin's move (:func:`_bin_moves`): whole places, the fractional share moved
        one place further (0 for a phase), direction.
    mirror : ndarray of int64, shape (n_bins,)
        The bin of ``−v`` (same phase where it has as many), or the bin itself.
    successor : ndarray of int64, shape (n_bins,)
        The bin a bin's mass moves to while keeping its velocity (the next phase).
    """
    from fractions import Fraction

    v = np.asarray(velocities, dtype=np.float64)
    owner, whole, frac, successor = [], [], [], []
    for b, x in enumerate(v):
        speed = abs(float(x))
        w = math.floor(speed)
        f = speed - w
        ratio = Fraction(f).limit_denominator(max(int(max_phases), 1))
        q = ratio.denominator if f > 0 and abs(float(ratio) - f) < 1e-9 and ratio.denominator > 1 else 1
        first = len(owner)
        for i in range(q):
            owner.append(b)
            if q == 1:
                whole.append(w)
                frac.append(f)
            else:
                whole.append(w + (i + 1) * ratio.numerator // q - i * ratio.numerator // q)
                frac.append(0.0)
            successor.append(first + (i + 1) % q)
    owner = np.asarray(owner, dtype=np.int64)
    sign = np.where(v[owner] >= 0, 1, -1).astype(np.int64)
    start = np.searchsorted(owner, np.arange(len(v)))
    count = np.bincount(owner, minlength=len(v))
    _, _, _, velocity_mirror = _bin_moves(v)
    mirror = np.empty(len(owner), dtype=np.int64)
    for a, b in enumerate(owner):
        m = velocity_mirror[b]
        i = a - start[b]
        mirror[a] = start[m] + (i if count[m] == count[b] else 0)
    return (owner, np.asarray(whole, dtype=np.int64), np.asarray(frac, dtype=np.float64), sign, mirror,
            np.asarray(successor, dtype=np.int64))


def phase_transition(transition: np.ndarray, owner: np.ndarray, successor: np.ndarray) -> np.ndarray:
    """The velocity transition over :func:`phase_bins`' bins, ``(n_bins, n_bins)``.

    Keeping the velocity (``transition[v, v]``) moves to the next phase; changing it
    (``transition[v, u]``, ``u ≠ v``) lands on every phase of ``u`` alike (the phase of
    a new speed is unknown). Without phases this is ``transition`` itself.
    """
    t = np.asarray(transition, dtype=np.float64)
    count = np.bincount(owner, minlength=t.shape[0]).astype(np.float64)
    out = t[np.ix_(owner, owner)] / count[owner][None, :]
    same = owner[:, None] == owner[None, :]
    out[same] = 0.0
    rows = np.arange(len(owner))
    out[rows, successor] = t[owner, owner]
    return out


def _bin_moves(velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per bin: whole places, fractional part, direction sign, index of the mirror bin."""
    v = np.asarray(velocities, dtype=np.float64)
    speed = np.abs(v)
    whole = np.floor(speed).astype(np.int64)
    sign = np.where(v >= 0, 1, -1).astype(np.int64)
    mirror = np.arange(len(v), dtype=np.int64)
    for b, x in enumerate(v):
        same = np.flatnonzero(np.isclose(v, -x))
        if len(same):
            mirror[b] = same[0]
    return whole, speed - whole, sign, mirror


def predict(state: np.ndarray, transition: np.ndarray, velocities: np.ndarray, neighbours: tuple,
            blur: float, recovery: float, velocity_prior: np.ndarray, junction_probability: float,
            odometry: float | None = None, moves: tuple | None = None,
            t_sparse: tuple | None = None) -> np.ndarray:
    """One prediction of the grid filter (see the module docstring).

    Parameters
    ----------
    state : ndarray of float64, shape (n_places, n_bins)
        Normalised (sums to 1).
    transition : ndarray, shape (n_bins, n_bins)
    velocities : ndarray, shape (n_bins,)
    neighbours : tuple
        :func:`route_neighbours` of the graph.
    blur, recovery, junction_probability : float
    velocity_prior : ndarray, shape (n_bins,)
        Velocity distribution of the recovery share.
    odometry : float, optional
        Distance travelled (graph units); replaces the bins' speeds.
    moves : tuple, optional
        Precomputed ``_bin_moves(velocities)``.
    t_sparse : tuple, optional
        Precomputed ``_sparse_columns(transition)`` (the velocity transition is applied in
        this sparse form: a few entries per bin instead of ``n_bins²``).

    Returns
    -------
    ndarray, shape (n_places, n_bins)
        The predicted state (sums to 1).
    """
    fwd, bwd, _, _, _, jdst = neighbours
    moves = _bin_moves(velocities) if moves is None else moves
    t_sparse = _sparse_columns(transition) if t_sparse is None else t_sparse
    velocity_prior = np.asarray(velocity_prior, dtype=np.float64)
    state = np.ascontiguousarray(state, dtype=np.float64)
    if odometry is None and len(jdst) == 0:  # no junctions: the transition fused into each place's walk
        whole, frac, sign, _ = moves
        moved = np.empty_like(state)
        _shift_walk(state, moved, whole, frac, sign, fwd, bwd, *t_sparse)
        out = np.empty((state.shape[1], state.shape[0]))
        _blur_rows(np.ascontiguousarray(moved.T), out, float(blur), fwd, bwd, float(recovery), velocity_prior)
    else:  # odometry, or junctions: the filter's own kernels, on its (bins, places) layout
        out = _predict_rows(np.ascontiguousarray(state.T), t_sparse, moves, neighbours, blur, recovery, velocity_prior,
                            junction_probability, odometry)
    return np.ascontiguousarray(out.T)


class GridLocalizer(TwinReadings):
    """Exact Bayes filter over (place, signed velocity) on a place graph.

    Parameters
    ----------
    graph : PlaceGraph
    model : ObservationModel
        Gives the per-place log-likelihood ratios (reset by :meth:`reset`).
    velocities : sequence of float
        Signed speed bins, places per query frame (default :data:`DEFAULT_VELOCITIES`,
        ``±0.5, ±1, ±2, ±3``; the registry's ``filter`` method: :data:`DENSE_VELOCITIES` on
        maps of at most ``methods.DENSE_VELOCITY_MAX_PLACES`` places, module docstring,
        "Speeds between the bins").
    velocity_stay : float in [0, 1]
        Probability of keeping the velocity bin from one frame to the next (default
        0.99: a query's speed changes slowly, and a looser velocity lets a slow
        hypothesis leak into the faster bins; measured in ``docs/particle_filter.md``).
    reverse_probability : float in [0, 1]
        Probability per frame of turning round (``v → −v``).
    blur : float in [0, 0.5)
        Share of mass moved one place either way after the shift (default 0.005: on a map
        surveyed as several samples per point, the blur is what moves a track between the
        samples of one point, which look alike; at 0.01 a side it leaked about 12 % of the
        mass per six-scan point into the neighbouring phases, more than one frame at the
        point change could correct, and UJI answered 23 point changes a scan early or late,
        ``docs/particle_filter.md``, seventh round).
    recovery : float in [0, 1)
        ``ε``: prior probability per frame of a jump anywhere on the map (0: never).
    learn_recovery : bool
        Learn ``ε`` online from the frames (see the module docstring), starting from
        and shrunk towards ``recovery``.
    junction_probability : float in [0, 0.5]
        Share of mass taking each junction edge at a junction place (all of a place's
        junction edges together take at most 0.5).
    new_place_prior, new_place_stay : float in [0, 1)
        The new-place hypothesis' two-state prior (as :class:`~catgraph.localizer.Localizer`,
        with its defaults 0.05 and 0.8; ``new_place_prior=0`` switches it off).
    confidence_radius : int
        Places either side of the answer counted in its confidence, in mean spacings of
        the map along the route (on a frame graph: places; see the module docstring).
    confidence_radius_m : float, optional
        A metric radius instead (needs graph positions).
    converged_log_odds : float
        Log-odds the answer must keep for ``converged_frames`` consecutive frames before
        the filter counts as converged (default 1.0).
    converged_frames : int
        See ``converged_log_odds`` (default 8; 0: converged from the start).
    unconverged_penalty : float
        Subtracted from the score (not the log-odds) of every frame before the first
        convergence (default 1.0 nat; 0: the score is the log-odds). See the module
        docstring.
    max_phases : int
        A fractional speed ``w + p/q`` with ``q ≤ max_phases`` is driven by ``q`` phase
        bins that move ``w`` or ``w + 1`` places in a fixed cycle (``v = 0.5``: 0, 1, 0,
        1 …), so that the motion alone keeps a track sharp (:func:`phase_bins`; default
        4; 1: every speed one bin, a fractional one splitting its mass between the two
        bracketing places each frame).
    smooth_feedback : bool
        Hand the observation model (``FilterFeedback.posterior``) each place's mean
        posterior mass over its confidence neighbourhood
        (:func:`~catgraph.localizer.neighbourhood_means`, the neighbourhood the answer's
        confidence counts) instead of the mass at the place alone (default True, as the
        particle filter). The tempered model's agreement then asks whether the frame's own
        best place lies *within the answer's neighbourhood*, not on its exact place: on
        a map whose neighbouring places look alike (Wi-Fi scans a metre apart) the exact
        place is a coin toss that read as disagreement and kept the temperature low.
        The answers and ``place_posterior_`` are unchanged.
    jump_rates : sequence of float in (0, 1), optional
        A jump model over several rates (see "Jump rates weighed by the evidence" in the
        module docstring): one posterior over (place, velocity) per jump rate, weighted
        by its evidence, so that the cost of leaving a track grows with the evidence the
        frames have given the small rates. ``recovery`` is then not used. Default
        ``None``: one jump rate (``recovery``, learned or fixed). Time and memory per
        frame × ``len(jump_rates)``.
    jump_rate_scope : {"query", "run"}
        With ``jump_rates``: ``"query"`` (default), one rate for the whole query,
        averaged over the rates by Bayes' rule; ``"run"``, a rate per run between two
        jumps, drawn at each jump (a run-length hazard; the rates of ended runs learned
        when ``learn_recovery``).
    jump_velocity : {"current", "long-run"}
        The velocity distribution of the recovery share (a jump keeps the speed, not the
        place): ``"current"`` (default), half the current velocity marginal and half
        uniform; ``"long-run"``, the query's long-run velocity distribution learned from
        the posterior (:class:`~catgraph.motion.LongRunVelocity`; the registry's
        ``filter`` method uses it: on short shuffles the frame before a jump is a poor
        witness of the speed, ``docs/particle_filter.md``, tenth round).
    rigid_prior : float in [0, 1)
        The prior probability that the query is one unbroken line at one speed: the
        filter's motion averaged by Bayes' rule with a rigid line (velocity kept, no blur,
        jump rate :data:`RIGID_JUMP_RATE`) of this prior weight (module docstring). Default
        0: off (the registry's ``filter`` method: 0.05 on maps of at most 10,000 places).
        Not with ``jump_rates``. Time and memory per frame × 2.
    varying_prior : float in [0, 1)
        The prior probability that the query's speed changes all the time: the filter's
        motion averaged by Bayes' rule with a second motion of its own kind whose velocity
        changes ten times as often (``velocity_stay`` :data:`VARYING_VELOCITY_STAY`; the same
        blur, and the jump rate the filter's own motion learns) of this prior weight (module
        docstring, "A speed that changes all the time"). ``rigid_prior + varying_prior < 1``.
        Default 0: off (the registry's ``filter`` method: 0.475 on maps of at most 10,000
        places). Not with ``jump_rates``. Time and memory per frame: one more component.
    home_speed_odds : float > 0
        The prior odds of the reference's own speed, one place per frame forwards or
        backwards (``velocities`` ``±1``), against each other velocity: the velocity prior
        of the start and of the recovery share where a jump lands (with ``"long-run"``, the
        prior its learning starts from). Default 1: uniform (the registry's ``filter``
        method: the odds that give ``±1`` together :data:`catgraph.methods.HOME_SPEED_SHARE`
        of the prior, :func:`catgraph.methods.home_speed_odds`; a traverse is most often driven
        at about the reference's speed, and a weak start-up otherwise holds a neighbouring
        speed, ``docs/particle_filter.md``, "The reference's own speed").
    outlier_probability : float in [0, 1)
        The prior probability that a frame shows no place of the map (a glitch, an
        occlusion, a blank scan): its likelihood at every place is then the new-place
        hypothesis's, so place ``j``'s is ``(1 − p) e^{r_j} + p e^{r_new}`` (module
        docstring, "Outlier frames"). A frame that no place explains costs a track at most
        about ``log(1/p)`` against a place the frame explains no better than a new place
        would. Default 0: off (the registry's ``filter`` method: 0.01,
        :data:`catgraph.methods.OUTLIER_PROBABILITY`).
    repeat_prior : float in [0, 1]
        The prior probability that the query stands still while its frame comes again
        unchanged. A frame equal to the previous one (the same row, informative, without
        odometry) does not say whether the robot moved: a vehicle stopped at lights shows
        it, a query driven at a fraction of the reference's speed too, and so does a camera
        that froze or a scanner that delivered its last scan again while the robot went on
        (both are in the real data: module docstring, "Frames that come again"). From the
        first such frame on, the filter runs a twin that stands still through every run of
        them (it advances on new frames only) beside itself, which moves on, and answers
        with their mixture, each weighed by its evidence frame by frame from this prior
        (``repeat_log_odds_``); once the two posteriors agree, or the lighter reading's
        weight makes its part of the mixture negligible (:data:`TWIN_AGREEMENT`), one
        reading goes (the heavier kept) until the next repeat. Default 0: off (the filter
        moves on; the registry's ``filter`` method: :data:`catgraph.methods.REPEAT_PRIOR`).
        Time and memory while the twin lives: twice the filter's.

    Attributes
    ----------
    state_ : ndarray of float64, shape (n_places, n_velocities)
        Posterior over (place, velocity) given that the robot is in the map.
    prior_ : ndarray of float64, shape (n_places,)
        Predicted place masses before the latest observation.
    place_posterior_ : ndarray of float64, shape (n_places,)
        ``(1 − P(new)) Σ_b state_[:, b]``.
    new_place_probability_ : float
    recovery_ : float
        The jump rate ``ε``: learned, or ``recovery``; with ``jump_rates`` or
        ``rigid_prior``, the mixture's hazard ``Σ_k w_k ε_k`` of the latest prediction.
        Each frame's prediction uses it modulated by that frame's jump evidence
        (``Observation.jump_evidence``, :mod:`catgraph.jumps`).
    rate_weights_ : ndarray of float64, shape (len(jump_rates),)
        With ``jump_rates``: the posterior probability of each rate's component (the
        current run's rate). With ``rigid_prior`` or ``varying_prior``: the posterior
        probability of each motion model, the filter's own first, then the varying speed's
        and the rigid line (those whose prior is not 0).
    converged_ : bool
        Whether the filter has converged (see ``converged_log_odds``).
    repeat_log_odds_ : float
        With ``repeat_prior``: the log-odds that the query stands still through its repeated
        frames against that it moves on (``place_posterior_``, the answer and
        ``new_place_probability_`` are the two readings' mixture; ``state_``, ``prior_`` and
        ``rate_weights_`` the moving one's).
    frame_log_evidence_ : float
        The latest frame's log evidence, ``log(P(new)' e^{r_new} + (1 − P(new)') Σ_j
        prior_j e^{r_j})`` (``P(new)'`` the new place's prior for the frame); 0 for a frame
        without information.
    n_steps_ : int
    """

    #: The line path's prediction storage (float32: half the memory traffic; a float64
    #: state gives the general path's floats).
    _line_dtype = np.float32

    def __init__(self, graph: PlaceGraph, model, velocities=DEFAULT_VELOCITIES, velocity_stay: float = 0.99,
                 reverse_probability: float = 0.001, blur: float = 0.005, recovery: float = 0.05,
                 junction_probability: float = 0.1, new_place_prior: float = 0.05, new_place_stay: float = 0.8,
                 confidence_radius: int = 2, confidence_radius_m: float | None = None,
                 learn_recovery: bool = True, converged_log_odds: float = 1.0, converged_frames: int = 8,
                 unconverged_penalty: float = 1.0, max_phases: int = 4, smooth_feedback: bool = True,
                 jump_rates=None, jump_rate_scope: str = "query", jump_velocity: str = "current",
                 rigid_prior: float = 0.0, home_speed_odds: float = 1.0, outlier_probability: float = 0.0,
                 varying_prior: float = 0.0, repeat_prior: float = 0.0) -> None:
        self.graph = graph
        self.model = model
        self.velocities = velocities
        self.velocity_stay = velocity_stay
        self.reverse_probability = reverse_probability
        self.blur = blur
        self.recovery = recovery
        self.junction_probability = junction_probability
        self.new_place_prior = new_place_prior
        self.new_place_stay = new_place_stay
        self.confidence_radius = confidence_radius
        self.confidence_radius_m = confidence_radius_m
        self.learn_recovery = learn_recovery
        self.converged_log_odds = converged_log_odds
        self.converged_frames = converged_frames
        self.unconverged_penalty = unconverged_penalty
        self.smooth_feedback = smooth_feedback
        self.max_phases = max_phases
        self.jump_rates = jump_rates
        self.jump_rate_scope = jump_rate_scope
        self.jump_velocity = jump_velocity
        self.rigid_prior = rigid_prior
        self.home_speed_odds = home_speed_odds
        self.outlier_probability = outlier_probability
        self.varying_prior = varying_prior
        self.repeat_prior = repeat_prior

    @property
    def state_(self) -> np.ndarray:
        """Posterior over (place, velocity), shape ``(n_places, n_velocities)`` (the phases
        of a velocity summed)."""
        if getattr(self, "_components", None) is not None:
            bins = sum(w * (c["_state"] * c["_like"]).T for w, c in zip(self.rate_weights_, self._components))
        else:
            bins = self._bin_state()
        if len(self._owner) == len(self._v):
            return bins
        return np.add.reduceat(bins, self._phase_start, axis=1)

    def _bin_state(self) -> np.ndarray:
        """Posterior over (place, state bin), shape ``(n_places, n_bins)`` (a view)."""
        return (self._state * self._like).T

    # ------------------------------------------------------------------ setup
    def _validate(self) -> None:
        owner = type(self).__name__
        if not isinstance(self.graph, PlaceGraph):
            raise InvalidParameterError(f"The 'graph' parameter of {owner} must be a PlaceGraph. Got {type(self.graph).__name__}.")
        if not hasattr(self.model, "observe") or not hasattr(self.model, "reset"):
            raise InvalidParameterError(
                f"The 'model' parameter of {owner} must be an ObservationModel (reset(), observe(row)). Got {self.model!r}."
            )
        v = np.asarray(self.velocities, dtype=np.float64) if np.ndim(self.velocities) == 1 else None
        if v is None or len(v) == 0 or not np.all(np.isfinite(v)) or len(np.unique(v)) != len(v) or np.abs(v).max() > 64:
            raise InvalidParameterError(
                f"The 'velocities' parameter of {owner} must be a non-empty sequence of distinct finite speeds "
                f"(places per frame, |v| <= 64). Got {self.velocities!r} instead."
            )
        check_scalar(self.velocity_stay, "velocity_stay", owner, float, 0.0, 1.0)
        check_scalar(self.reverse_probability, "reverse_probability", owner, float, 0.0, 1.0 - self.velocity_stay)
        check_scalar(self.blur, "blur", owner, float, 0.0, 0.5, True, False)
        check_scalar(self.recovery, "recovery", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.junction_probability, "junction_probability", owner, float, 0.0, 0.5)
        check_scalar(self.new_place_prior, "new_place_prior", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.new_place_stay, "new_place_stay", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.confidence_radius, "confidence_radius", owner, int, 0)
        check_scalar(self.converged_log_odds, "converged_log_odds", owner, float)
        check_scalar(self.converged_frames, "converged_frames", owner, int, 0)
        check_scalar(self.unconverged_penalty, "unconverged_penalty", owner, float, 0.0)
        if not isinstance(self.smooth_feedback, (bool, np.bool_)):
            raise InvalidParameterError(f"The 'smooth_feedback' parameter of {owner} must be a bool. "
                                        f"Got {self.smooth_feedback!r} instead.")
        check_scalar(self.max_phases, "max_phases", owner, int, 1, 64)
        if not isinstance(self.learn_recovery, (bool, np.bool_)):
            raise InvalidParameterError(f"The 'learn_recovery' parameter of {owner} must be a bool. "
                                        f"Got {self.learn_recovery!r} instead.")
        if self.jump_rates is not None:
            rates = np.asarray(self.jump_rates, dtype=np.float64) if np.ndim(self.jump_rates) == 1 else None
            if (rates is None or len(rates) == 0 or not np.all((rates > 0) & (rates < 1))
                    or len(np.unique(rates)) != len(rates)):
                raise InvalidParameterError(
                    f"The 'jump_rates' parameter of {owner} must be None or a non-empty sequence of distinct jump "
                    f"rates in (0, 1), e.g. (0.1, 0.01, 0.001, 0.0001). Got {self.jump_rates!r} instead.")
        if self.jump_rate_scope not in JUMP_RATE_SCOPES:
            raise InvalidParameterError(f"The 'jump_rate_scope' parameter of {owner} must be one of "
                                        f"{JUMP_RATE_SCOPES}. Got {self.jump_rate_scope!r} instead.")
        check_scalar(self.rigid_prior, "rigid_prior", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.home_speed_odds, "home_speed_odds", owner, float, 0.0, 1e6, False)
        check_scalar(self.outlier_probability, "outlier_probability", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.varying_prior, "varying_prior", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.repeat_prior, "repeat_prior", owner, float, 0.0, 1.0)
        for name in ("rigid_prior", "varying_prior"):
            if getattr(self, name) > 0 and self.jump_rates is not None:
                raise InvalidParameterError(f"The '{name}' and 'jump_rates' parameters of {owner} cannot be combined: "
                                            f"give one of them ({name}=0 or jump_rates=None).")
        if not self.rigid_prior + self.varying_prior < 1.0:
            raise InvalidParameterError(
                f"The 'rigid_prior' and 'varying_prior' parameters of {owner} must leave the filter's own motion a "
                f"share: their sum must be below 1. Got {self.rigid_prior!r} + {self.varying_prior!r}.")
        if self.jump_velocity not in JUMP_VELOCITIES:
            raise InvalidParameterError(f"The 'jump_velocity' parameter of {owner} must be one of "
                                        f"{JUMP_VELOCITIES}. Got {self.jump_velocity!r} instead.")
        if self.confidence_radius_m is not None:
            check_scalar(self.confidence_radius_m, "confidence_radius_m", owner, float, 0.0)
            if self.graph.positions is None:
                raise DataError("confidence_radius_m needs a place graph with positions; use confidence_radius (places).")
        self._v = v

    def reset(self) -> "GridLocalizer":
        """Start afresh: uniform over places and velocity bins, ``P(new) = 0``, model reset."""
        self._validate()
        g = self.graph
        neighbours = route_neighbours(g)
        owner, whole, frac, sign, mirror, successor = phase_bins(self._v, self.max_phases)
        nb = len(owner)
        self._owner = owner
        self._phase_start = np.searchsorted(owner, np.arange(len(self._v)))
        self._transition = phase_transition(velocity_transition(self._v, self.velocity_stay, self.reverse_probability),
                                            owner, successor)
        self._moves = (whole, frac, sign, mirror)
        fwd, bwd, _, _, _, jdst = neighbours
        idx = np.arange(g.n_places)
        self._line = len(jdst) == 0 and bool(np.all(fwd == np.where(idx + 1 < g.n_places, idx + 1, -1))
                                             and np.all(bwd == idx - 1))
        # the general path's walk along the edges (five arrays of n_places): a line graph
        # needs it only for a frame with odometry, so there it is rebuilt on that use
        self._neighbours = None if self._line else neighbours
        del neighbours, idx
        self._t_sparse = _sparse_columns(self._transition)
        # a prior over velocities (``home_speed_odds`` to one on ±1; 1: uniform), each shared
        # evenly by its phases
        weights = np.where(np.abs(np.abs(self._v) - 1.0) < 1e-12, float(self.home_speed_odds), 1.0)
        self._velocity_prior = weights[owner] / (weights.sum() * np.bincount(owner)[owner])
        self._velocity = self._velocity_prior.copy()
        from .motion import LongRunVelocity

        self._long_run = LongRunVelocity(self._velocity_prior, RECOVERY_MEMORY, RECOVERY_PRIOR_FRAMES)
        self._landing, self._landing_step = None, -1
        self.recovery_ = float(self.recovery)
        self._jumps, self._frames = 0.0, 0.0
        self._e = np.empty(g.n_places)
        from .observation import FramePool

        self._pool = FramePool(6)  # the per-frame masses and posteriors handed out
        self._no_e = np.empty(0)  # the line kernel without an update to form sums for
        self._summed = None
        self._summed_evidence = False
        self._sums = np.zeros(2)  # the update's sums formed by the line kernel
        self._deferred = None  # (e, 1 / Σ prior e): the update's writes, left to the summary
        self._like_buffer = np.empty(g.n_places)
        # the line path keeps the prediction in float32 (half the memory traffic of a step;
        # every sum and the likelihood stay float64); the general path, the reference, float64
        dtype = self._line_dtype if self._line else np.float64
        # the posterior, factored: the prediction (velocity-major, so that shifts are
        # contiguous) times the latest frame's normalised likelihood per place
        self._state = np.empty((nb, g.n_places), dtype=dtype)  # filled row by row: no float64 copy
        for b, p in enumerate(self._velocity_prior / g.n_places):
            self._state[b] = p
        self._ones = np.ones(g.n_places)  # the likelihood of a prediction not yet updated (never written)
        self._like = self._ones
        self.prior_ = self._state.sum(0, dtype=np.float64)
        self.place_posterior_ = self.prior_.copy()
        self._mass = self.prior_.copy()
        self.new_place_probability_ = 0.0
        self._log_new, self._log_map = -math.inf, 0.0
        self.n_steps_ = 0
        self.converged_ = self.converged_frames == 0
        self._held = 0
        self._reset_twin()
        from .observation import claim_model

        claim_model(self.model, self)
        self.model.reset()
        rd = np.asarray(g.route_distance, dtype=np.float64)
        # the confidence neighbourhood by route distance (a slice where the route is monotone)
        self._route = rd if len(rd) < 2 or bool(np.all(np.diff(rd) >= 0)) else None
        spacing = float(g.frame_spacing)
        self._route_radius = self.confidence_radius * spacing + 1e-9 * spacing
        if self.confidence_radius_m is not None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(g.positions)
        self._neighbourhoods = None
        if self.smooth_feedback and callable(getattr(type(self.model), "feedback", None)):
            from .localizer import confidence_neighbourhoods

            self._neighbourhoods = confidence_neighbourhoods(g, self.confidence_radius, self.confidence_radius_m,
                                                             getattr(self, "_tree", None), self._route,
                                                             self._route_radius)
        self._components = None
        if self.jump_rates is not None or self.rigid_prior > 0 or self.varying_prior > 0:
            self._reset_components(FramePool)
        # the buffers a prediction is written into: each state (the filter's, each
        # component's, the twin's) takes one nobody holds, and the state it replaces is free
        # again once replaced, so together they need one buffer beyond their states instead
        # of one each (the pool keeps as many as the filter and its twin have states, and one)
        self._state_pool = FramePool(2 * (1 if self._components is None else len(self._components)) + 1)
        return self

    #: A component's own arrays (swapped in while the shared step code runs on it).
    _COMPONENT_FIELDS = ("_state", "_like", "prior_", "_mass", "_velocity", "_summed", "_like_buffer", "_pool")

    def _reset_components(self, pool) -> None:
        """One posterior per jump rate (or per motion model, ``rigid_prior`` and
        ``varying_prior``), each uniform, the rates' weights even (the motion models' their
        prior)."""
        motions = self.jump_rates is None
        if motions:
            # the filter's own motion, the varying speed's (its jump rate the own one's, as
            # learned) and the rigid line: those whose prior is not 0
            kept = [(1.0 - self.rigid_prior - self.varying_prior, self.recovery, self.velocity_stay, self.blur),
                    (self.varying_prior, self.recovery, VARYING_VELOCITY_STAY, self.blur),
                    (self.rigid_prior, RIGID_JUMP_RATE, 1.0, 0.0)]
            kept = [kept[0]] + [m for m in kept[1:] if m[0] > 0.0]
            self._rates = np.array([m[1] for m in kept], dtype=np.float64)
            self._rate_prior = np.array([m[0] for m in kept], dtype=np.float64)
            self._flexible = 1 + int(self.varying_prior > 0.0)  # the components that share the learned rate
        else:
            self._rates = np.asarray(self.jump_rates, dtype=np.float64)
            self._rate_prior = np.full(len(self._rates), 1.0 / len(self._rates))
        k = len(self._rates)
        self._rate_runs = np.ones(k)  # the rates of ended runs, counted (a uniform Dirichlet prior)
        self.rate_weights_ = self._rate_prior.copy()
        self._components = [{"_state": self._state.copy(), "_like": self._ones,
                             "prior_": self.prior_.copy(), "_mass": self.prior_.copy(),
                             "_velocity": self._velocity.copy(), "_summed": None,
                             "_like_buffer": np.empty(self.graph.n_places), "_pool": pool(6)}
                            for _ in range(k)]
        self._own_pool = self._pool
        self.recovery_ = float(self._rate_prior @ self._rates)
        self._motions = None
        if motions:
            # each component's velocity transition (sparse columns, as the line kernel reads
            # them) and blur: the filter's own first
            successor = phase_bins(self._v, self.max_phases)[5]
            self._motions = [(self._transition, self._t_sparse, float(self.blur))]
            for _, _, stay, blur in kept[1:]:
                # turning as the own motion does, within what the motion's stay leaves (the rigid line: none)
                t = phase_transition(velocity_transition(self._v, stay, min(self.reverse_probability, 1.0 - stay)),
                                     self._owner, successor)
                self._motions.append((t, _sparse_columns(t), float(blur)))
            self._rigid_jumps = (0.0, 0.0)  # the filter's own component's learned jump rate: its sums

    # ------------------------------------------------------------------ one step
    def step(self, observation: np.ndarray, odometry: float | None = None):
        """Process one query frame.

        Parameters
        ----------
        observation : ndarray, shape (n_places,)
            The frame's difference to every reference place.
        odometry : float, optional
            Distance travelled since the previous frame (graph units).

        Returns
        -------
        Estimate
        """
        from .motion import check_odometry

        if not hasattr(self, "_state"):
            self.reset()
        from .localizer import _check_observation
        from .observation import check_model

        row = _check_observation(observation, self.graph.n_places)
        odometry = check_odometry(odometry)
        check_model(self.model, self)
        repeated = self._repeated(row, odometry)
        obs = self.model.observe(row)
        twin = self._twin
        if repeated and obs.informative and twin is None and self.repeat_prior > 0.0:
            twin = self._twin = self._fork()  # this frame's prior: the robot where the run began
        self._advance(obs, odometry)
        if twin is not None and not repeated:
            twin._advance(obs, odometry)
            twin._resolve()
            twin.n_steps_ += 1  # its own frames: the long-run jump velocity learns once a frame of its own
            self._weigh_twin(twin)
        estimate, near = self._summarise()
        if twin is not None and not repeated:
            self._settle(twin)
        self._feedback(near)
        self.n_steps_ += 1
        return estimate

    def _advance(self, obs, odometry: float | None) -> None:
        """Predict and update the posterior with the frame's observation ``obs``."""
        ratio = self._exp_ratio(obs)
        self._frame_rates(obs.jump_evidence)
        self.frame_log_evidence_ = 0.0
        if self._components is None:
            self._predict(odometry, ratio)
            self._update(ratio)
            self.recovery_ = self._prior_rate  # the learned rate again, for the next frame's evidence
        elif self._motions is not None:
            self._rigid_step(odometry, ratio)
        else:
            self._hazard_step(odometry, ratio)

    # ------------------------------------------------------------------ frames that come again
    # (``_ones``, the likelihood of a prediction not yet updated, is never written)
    _FORK_SHARED = ("_tree", "_route", "_neighbourhoods", "_neighbours", "_t_sparse", "_transition", "_motions",
                    "_ones", "_state_pool")
    _OWN_WHEN_SETTLED = (*TwinReadings._OWN_WHEN_SETTLED, "converged_", "_held")

    def _agrees(self, twin: "GridLocalizer", weight: float) -> bool:
        """Whether ``weight`` times the distance between ``twin``'s posterior and this
        filter's is at most :data:`TWIN_AGREEMENT`: the marginals first, then the whole
        posterior."""
        if weight <= 0.0:
            return self.TWIN_AGREEMENT >= 0.0
        tol = 2.0 * self.TWIN_AGREEMENT / weight
        if abs(twin.new_place_probability_ - self.new_place_probability_) > tol / 2.0:
            return False
        if self._components is not None and np.abs(twin.rate_weights_ - self.rate_weights_).sum() > tol:
            return False
        if np.abs(twin._velocity - self._velocity).sum() > tol or np.abs(twin._mass - self._mass).sum() > tol:
            return False
        if self._components is None:
            pairs = [(1.0, self.__dict__, 1.0, twin.__dict__)]
        else:
            pairs = zip(self.rate_weights_, self._components, twin.rate_weights_, twin._components)
        total = 0.0
        for a, mine, b, theirs in pairs:
            total += float(np.abs(a * mine["_state"] * mine["_like"] - b * theirs["_state"] * theirs["_like"]).sum())
            if total > tol:
                return False
        return True

    def _resolve(self) -> tuple[np.ndarray, int]:
        """The update's writes left to the summary (:func:`_posterior_pass`): the place
        masses (given the map), ``place_posterior_`` and the best place."""
        self.__dict__.pop("place_posterior_", None)  # the previous frame's: reusable if no one else holds it
        if self._deferred is not None:  # the update's writes, the place posterior and the answer in one pass
            e, inv = self._deferred
            self._deferred = None
            mass = self._pool.take(len(e))
            self.place_posterior_ = self._pool.take(len(e))
            best = int(_posterior_pass(e, inv, self.prior_, self._like_buffer, mass, self.place_posterior_,
                                       1.0 - self.new_place_probability_))
            self._like, self._mass = self._like_buffer, mass
        else:
            mass = self._mass
            self.place_posterior_ = np.multiply(mass, 1.0 - self.new_place_probability_,
                                                out=self._pool.take(len(mass)))
            best = int(np.argmax(mass))
        return mass, best

    def _frame_rates(self, evidence: float) -> None:
        """This frame's jump rate(s): the prior rate(s) given the frame's jump evidence
        (:func:`catgraph.jumps.frame_jump_rate`; evidence 0 leaves them as they are). With
        one rate, ``recovery_`` is the frame's while the frame is processed (the learning
        reads it as the E-step's rate) and the learned rate after it."""
        if self._components is None:
            self._prior_rate = self.recovery_
            self.recovery_ = frame_jump_rate(self._prior_rate, evidence)
        elif self._motions is None and self.jump_rate_scope == "run":
            # a run-length hazard's jumps are its runs' ends, shared out by the rates' prior:
            # the frame's change is not read there
            self._step_rates = self._rates
        else:
            self._step_rates = frame_jump_rate(self._rates, evidence)

    def _change_factors(self) -> np.ndarray | None:
        """Each component's likelihood of the frame's change, against a step's: ``(1 −
        ε_k) / (1 − ε'_k)``, ``ε'_k`` the frame's rate (:meth:`_frame_rates`): a component
        that keeps ``1 − ε'_k`` of its mass on its track and lands ``ε'_k`` anywhere has,
        before that normalisation, ``1 − ε_k`` on the track and ``ε_k λ`` landing (``λ``
        the change's likelihood ratio), so a component that may jump is weighed up by a
        change that looks like one and a rigid line is not. ``None``: the frame has no
        jump evidence (every factor 1)."""
        if self.n_steps_ == 0 or self._step_rates is self._rates:
            return None
        return (1.0 - self._rates) / (1.0 - self._step_rates)

    def _exp_ratio(self, obs):
        """``(e, top, new_place_log_ratio)`` of an informative observation, ``e_j =
        e^{r_j − top}`` with ``top = max_j r_j`` (in a buffer of the filter's); ``None``
        for an uninformative one (no update)."""
        if not obs.informative:
            return None
        r = np.asarray(obs.log_ratio, dtype=np.float64)
        # the maximum where the model found it while forming the ratios (the same value)
        top = float(r.max()) if obs.log_ratio_max is None else float(obs.log_ratio_max)
        if top == -math.inf:  # every place impossible: no update, the prediction stands
            return None
        e = self._e
        np.exp(np.subtract(r, top, out=e), out=e)
        new = float(obs.new_place_log_ratio)
        p = float(self.outlier_probability)
        if p > 0.0 and new > -math.inf:
            # (1 − p) e^{r_j} + p e^{r_new}, kept as e_j · e^{top} with max_j e_j = 1
            c = p / (1.0 - p) * math.exp(min(new - top, 700.0))
            e += c
            e *= 1.0 / (1.0 + c)
            top += math.log1p(-p) + math.log1p(c)
        return e, top, new

    def _predict(self, odometry: float | None, ratio=None) -> None:
        self._summed = None
        self._summed_evidence = False
        if self.n_steps_ > 0:
            jump_velocity = self._jump_velocity()
            if self._line and odometry is None:
                out = self._state_pool.take(self._state.shape, self._state.dtype)  # written before read
                whole, frac, sign, _ = self._moves
                mass = self._pool.take(self.graph.n_places)
                # the next frame's velocity sums formed while the prediction is written
                summed = np.empty(len(self._owner))
                # and, for the update, its sums Σ e_j, Σ mass_j e_j (single jump rate)
                sums = self._sums if self._components is None else None
                _line_predict(self._state, self._like, self.prior_, out, mass, *self._t_sparse, whole,
                              frac, sign, float(self.blur), self.recovery_, jump_velocity, _LINE_BLOCK,
                              self._no_e if ratio is None else ratio[0], summed, sums=sums)
                self._state = out  # the state it replaces goes back to the pool once no one holds it
                self._like = self._ones
                self.prior_ = mass
                self._mass = mass
                if ratio is not None:
                    self._summed = summed
                    self._summed_evidence = sums is not None
                return
            if self._neighbours is None:
                self._neighbours = route_neighbours(self.graph)
            # odometry, or junctions: the kernels of predict, on the filter's own layout (no transposes)
            out = _predict_rows(np.multiply(self._state, self._like, dtype=np.float64), self._t_sparse, self._moves,
                                self._neighbours, self.blur, self.recovery_, jump_velocity, self.junction_probability,
                                odometry)
            self._state = out if not self._line else out.astype(self._state.dtype)
            self._like = self._ones
        self.prior_ = self._state.sum(0, dtype=np.float64)
        self._mass = self.prior_

    def _jump_velocity(self) -> np.ndarray:
        """Velocity distribution of the recovery share (``jump_velocity``): a jump changes
        the place, not the speed. The long-run distribution takes the previous frame's
        posterior marginal once per frame (with ``jump_rates``, the mixture's: every
        component lands with it)."""
        if self.jump_velocity == "current":
            return 0.5 * self._velocity + 0.5 * self._velocity_prior
        if self._landing_step != self.n_steps_:
            self._landing, self._landing_step = self._long_run.update(self._velocity), self.n_steps_
        return self._landing

    def _update(self, ratio) -> None:
        if ratio is None:
            return
        e, top, new_place_log_ratio = ratio
        total, like_mean = self._likelihood(e, defer=True)
        if total <= 0.0:
            return  # every place impossible: keep the prediction
        if self.n_steps_ > 0:
            self._learn_recovery(like_mean / total)
        self._new_place(math.log(total) + top, new_place_log_ratio)  # log Σ prior · e^r

    def _likelihood(self, e: np.ndarray, defer: bool = False) -> tuple[float, float]:
        """The factored update of the current state by ``e`` (:func:`_likelihood`):
        ``(Σ_j prior_j e_j, mean_j e_j)``; the posterior's likelihood, place masses and
        velocity marginal are kept unless the first is 0 (every place impossible).

        ``defer`` (single jump rate): where the line kernel has formed the velocity sums
        and the update's sums already, only the velocity marginal is normalised here;
        the likelihood and the place masses are written with the place posterior and
        the answer in one pass (:func:`_posterior_pass`, :meth:`_summarise`)."""
        if defer and self._summed_evidence:
            like_sum, total = float(self._sums[0]), float(self._sums[1])
            like_mean = like_sum / len(e)
            if not (total > 0.0) or not math.isfinite(total):
                return 0.0, like_mean
            inv = 1.0 / total
            self._velocity = np.multiply(self._summed, inv, out=self._summed)
            self._deferred = (e, inv)
            return total, like_mean
        summed = self._summed is not None
        velocity = self._summed if summed else np.empty(len(self._owner))
        # the previous frame's likelihood was consumed by the prediction: its buffer is free
        like = self._like_buffer
        mass = self._pool.take(len(e))
        total, like_mean = _likelihood(self._state, e, self.prior_, like, velocity, mass, summed)
        if total > 0.0:
            self._like, self._velocity = like, velocity
            self._mass = mass
        return total, like_mean

    def _hazard_step(self, odometry: float | None, ratio) -> None:
        """Predict and update every jump rate's component, then their mixture (see the
        module docstring, "Jump rates weighed by the evidence").

        Scope ``"query"``: component ``k`` is the filter of the fixed rate ``ε_k`` (its
        jumps land in it). Scope ``"run"``: component ``k`` (weight ``w_k``) keeps ``w_k
        (1 − ε_k)`` of its mass on its moved track and receives ``π_k J`` of the jump mass
        ``J = Σ_k w_k ε_k``: its normalised prediction is the single-rate prediction with
        the jump share ``ρ_k = π_k J / (w_k (1 − ε_k) + π_k J)``, and its predicted
        weight that sum. Every jump lands uniformly over places with the mixture's jump
        velocity. The update weighs each component by its evidence ``Σ_j prior_kj
        e^{r_j}``."""
        rates, pi, w = self._step_rates, self._rate_prior, self.rate_weights_
        change = self._change_factors()
        jump = 0.0
        if self.n_steps_ > 0 and self.jump_rate_scope == "query":
            jump = float(w @ rates)
            predicted, share = w.copy(), rates.copy()
            self.recovery_ = jump
        elif self.n_steps_ > 0:
            jump = float(w @ rates)
            predicted = w * (1.0 - rates) + pi * jump
            share = pi * jump / predicted
            self.recovery_ = jump
        else:
            predicted, share = w.copy(), np.zeros(len(w))
        velocity = self._velocity  # the mixture's: every component's jump lands with it
        totals = self._step_components(odometry, ratio, velocity, share)[0]
        components = self._components
        self.prior_ = _weighted_sum(predicted, [c["prior_"] for c in components], self._pool.take(self.graph.n_places))
        evidence = predicted * totals if change is None else predicted * totals * change
        total = float(evidence.sum())
        if ratio is None or not total > 0.0:
            # no update (or every place impossible): the predictions stand
            self.rate_weights_ = predicted / predicted.sum()
            self._mass = _weighted_sum(self.rate_weights_, [c["_mass"] for c in components],
                                       self._pool.take(self.graph.n_places))
            self._velocity = velocity
            return
        if self.n_steps_ > 0 and self.learn_recovery and self.jump_rate_scope == "run":
            # the posterior probability that a run ended here, its rate ∝ w_k ε_k (the
            # jump share's evidence: mean_j e_j, uniform over places and velocities)
            ended = min(1.0, jump * float(ratio[0].mean()) / total)
            self._rate_runs += ended * (w * rates) / jump
            self._rate_prior = self._rate_runs / self._rate_runs.sum()
        self.rate_weights_ = evidence / total
        self._mass = _weighted_sum(self.rate_weights_, [c["_mass"] for c in components],
                                   self._pool.take(self.graph.n_places))
        self._velocity = _weighted_sum(self.rate_weights_, [c["_velocity"] for c in components],
                                       np.empty(len(self._owner)))
        self._new_place(math.log(total) + ratio[1], ratio[2])

    def _step_components(self, odometry: float | None, ratio, velocity: np.ndarray,
                         recoveries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predict and update every component on its own arrays (swapped in while the
        shared step code runs on it), component ``k`` with the jump share
        ``recoveries[k]``, its jumps landing with ``velocity``, and with its own motion
        where the components have motions of their own (``rigid_prior``).

        Returns
        -------
        totals, means : ndarray of float64, shape (n_components,)
            Each component's evidence ``Σ_j prior_kj e^{r_j}`` and ``mean_j e^{r_j}``
            (zeros for an uninformative frame).
        """
        totals, means = np.zeros(len(self._components)), np.zeros(len(self._components))
        fields = self._COMPONENT_FIELDS
        jump_rate = self.recovery_
        for k, component in enumerate(self._components):
            for f in fields:
                setattr(self, f, component[f])
            self._velocity = velocity
            if self._motions is not None:
                self._transition, self._t_sparse, self.blur = self._motions[k]
            self.recovery_ = float(recoveries[k])
            self._predict(odometry, ratio)
            if ratio is not None:
                totals[k], means[k] = self._likelihood(ratio[0])
            for f in fields:
                component[f] = getattr(self, f)
        self.recovery_ = jump_rate
        if self._motions is not None:
            self._transition, self._t_sparse, self.blur = self._motions[0]
        self._pool = self._own_pool
        return totals, means

    def _rigid_step(self, odometry: float | None, ratio) -> None:
        """Predict and update both motion models' components (``rigid_prior``), then
        their mixture (module docstring, "A rigid line beside the filter's motion").

        Component ``k`` is the filter of motion ``k`` (its transition, blur and jump rate;
        its jumps land in it, with the mixture's jump velocity); the update weighs each
        by its evidence ``Σ_j prior_kj e^{r_j}``. The filter's own jump rate is learned
        (``learn_recovery``) from its own component's evidence, as the single-rate
        filter learns it."""
        w, rates = self.rate_weights_, self._step_rates
        change = self._change_factors()
        velocity = self._velocity  # the mixture's: every component's jump lands with it
        totals, means = self._step_components(odometry, ratio, velocity, rates)
        self.recovery_ = float(w @ rates)
        components = self._components
        self.prior_ = _weighted_sum(w, [c["prior_"] for c in components], self._pool.take(self.graph.n_places))
        evidence = w * totals if change is None else w * totals * change
        total = float(evidence.sum())
        if ratio is None or not total > 0.0:
            self._mass = _weighted_sum(w, [c["_mass"] for c in components], self._pool.take(self.graph.n_places))
            self._velocity = velocity
            return
        if self.n_steps_ > 0 and self.learn_recovery and self.recovery > 0.0 and totals[0] > 0.0:
            jumps, frames, learned = learn_jump_rate(*self._rigid_jumps, float(self.recovery),
                                                     float(rates[0]), means[0] / totals[0])
            self._rates[:self._flexible] = learned
            self._rigid_jumps = (jumps, frames)
        self.rate_weights_ = evidence / total
        self._mass = _weighted_sum(self.rate_weights_, [c["_mass"] for c in components],
                                   self._pool.take(self.graph.n_places))
        self._velocity = _weighted_sum(self.rate_weights_, [c["_velocity"] for c in components],
                                       np.empty(len(self._owner)))
        self._new_place(math.log(total) + ratio[1], ratio[2])

    def _new_place(self, log_map: float, new_place_log_ratio: float) -> None:
        """The new-place hypothesis against the map's evidence ``log_map = log Σ_j
        prior_j e^{r_j}``."""
        p_new = self.new_place_probability_
        prior = self.new_place_stay * p_new + self.new_place_prior * (1.0 - p_new)
        if prior > 0.0:
            a_new = math.log(prior) + new_place_log_ratio
            a_map = math.log1p(-prior) + log_map
            t = np.logaddexp(a_new, a_map)
            self._log_new, self._log_map = a_new - t, a_map - t
            self.new_place_probability_ = float(math.exp(self._log_new))
            self.frame_log_evidence_ = float(t)
        else:
            self._log_new, self._log_map, self.new_place_probability_ = -math.inf, 0.0, 0.0
            self.frame_log_evidence_ = float(log_map)

    def _learn_recovery(self, ratio: float) -> None:
        """Online EM for the jump rate (:func:`learn_jump_rate`)."""
        if not self.learn_recovery or self.recovery == 0.0:
            return
        self._jumps, self._frames, self._prior_rate = learn_jump_rate(self._jumps, self._frames, float(self.recovery),
                                                                      self.recovery_, ratio)

    def _summarise(self):
        from .localizer import Estimate, confidence_log_odds

        g = self.graph
        mass, best = self._resolve()
        p_new, log_map, log_new = self.new_place_probability_, self._log_map, self._log_new
        twin = self._twin
        if twin is not None:
            # the two readings of the repeats, each weighed by its evidence (Bayes' rule): the
            # answer is the mixture's, over the map and the new place together
            self.place_posterior_, p_new, mass, best, log_map, log_new = mixed_answer(
                _logistic(self.repeat_log_odds_), self.place_posterior_, p_new, twin.place_posterior_,
                twin.new_place_probability_)
        if self.confidence_radius_m is not None:
            near = np.zeros(g.n_places, dtype=bool)
            near[self._tree.query_ball_point(g.positions[best], self.confidence_radius_m)] = True
        elif self._route is not None:
            rd = self._route
            near = slice(int(np.searchsorted(rd, rd[best] - self._route_radius, "left")),
                         int(np.searchsorted(rd, rd[best] + self._route_radius, "right")))
        else:
            near = slice(max(0, best - self.confidence_radius), best + self.confidence_radius + 1)
        w_in, w_out = _inside_outside(mass, near)
        confidence, log_odds = confidence_log_odds(w_in, w_out, log_map, log_new)
        position = None if g.positions is None else g.positions[best].copy()
        return Estimate(best, position, confidence, p_new, float(g.n_places), False,
                        log_odds, self._score(log_odds)), near

    def _score(self, log_odds: float) -> float:
        """The frame's ranking score: the log-odds, less ``unconverged_penalty`` until the
        log-odds have first stayed above ``converged_log_odds`` for ``converged_frames``
        frames in a row (this frame included)."""
        if not self.converged_:
            self._held = self._held + 1 if log_odds > self.converged_log_odds else 0
            self.converged_ = self._held >= self.converged_frames
        return log_odds if self.converged_ else log_odds - float(self.unconverged_penalty)

    def _feedback(self, near) -> None:
        from .observation import FilterFeedback

        feedback = getattr(type(self.model), "feedback", None)
        if feedback is not None:
            posterior, top = self.place_posterior_, None
            if self._neighbourhoods is not None:
                from .localizer import _smoothed

                posterior, top = _smoothed(posterior, *self._neighbourhoods, out=self._pool.take(len(posterior)))
            self.model.feedback(FilterFeedback(self.prior_, posterior, near, top))

    # ------------------------------------------------------------------ batch
    def run(self, observations, odometry: np.ndarray | None = None, query_index: np.ndarray | None = None,
            return_posterior: bool = False):
        """Reset, then :meth:`step` through a difference matrix (rows in processing order).

        Parameters
        ----------
        observations : ndarray, shape (n_query, n_places), or DifferenceRows
            The rows, or the rows block by block
            (:class:`~catgraph.differences.DifferenceRows`: one block in memory at a time).
        odometry : ndarray, shape (n_query,), optional
        query_index : ndarray of int, shape (n_query,), optional
        return_posterior : bool

        Returns
        -------
        LocalizationResult
        """
        from .localizer import LocalizationResult, check_query_index
        from .observation import query_rows

        n, rows = query_rows(observations, self.graph.n_places)
        if odometry is not None:
            odometry = check_array(odometry, "odometry", ndim=1)
            if len(odometry) != n:
                raise ShapeMismatchError(f"odometry has {len(odometry)} entries for {n} query frames; give one per frame.")
        qi = np.arange(n) if query_index is None else check_query_index(query_index, n)
        self.reset()
        place = np.empty(n, dtype=np.int64)
        conf, p_new, log_odds, score = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        pos = None if self.graph.positions is None else np.empty((n, self.graph.positions.shape[1]))
        posterior = np.empty((n, self.graph.n_places), dtype=np.float32) if return_posterior else None
        start = time.perf_counter()
        for k, row in zip(range(n), rows):
            est = self.step(row, None if odometry is None or k == 0 else float(odometry[k]))
            place[k], conf[k], p_new[k], log_odds[k] = est.place, est.confidence, est.new_place_probability, est.log_odds
            score[k] = est.score
            if pos is not None:
                pos[k] = est.position
            if posterior is not None:
                posterior[k] = self.place_posterior_
        seconds = (time.perf_counter() - start) / max(n, 1)
        return LocalizationResult(place, conf, p_new, np.full(n, float(self.graph.n_places)), pos, qi, seconds,
                                  log_odds, score, posterior)


def _sparse_columns(transition: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``(B, B)`` transition's columns as CSR arrays ``(ptr, source, value)`` (the line
    kernel's form)."""
    nz = transition.T != 0
    return (np.concatenate([[0], np.cumsum(nz.sum(1))]).astype(np.int64), np.nonzero(nz)[1].astype(np.int64),
            np.ascontiguousarray(transition.T[nz], dtype=np.float64))


def _weighted_sum(weights: np.ndarray, arrays: list, out: np.ndarray) -> np.ndarray:
    """``Σ_k weights[k] · arrays[k]`` into ``out``."""
    np.multiply(arrays[0], weights[0], out=out)
    for w, a in zip(weights[1:], arrays[1:]):
        out += w * a
    return out


def _inside_outside(mass: np.ndarray, near) -> tuple[float, float]:
    """Mass inside and outside the answer's neighbourhood, each summed directly (the
    outside is not ``1 − inside``, which would lose it to round-off)."""
    if isinstance(near, slice):
        return float(mass[near].sum()), float(mass[:near.start].sum() + mass[near.stop:].sum())
    return float(mass[near].sum()), float(mass[~near].sum())
