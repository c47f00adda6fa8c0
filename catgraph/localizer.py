"""The CAT-Graph particle filter: one step as a few named calls.

State
-----
``n_particles`` particles on the :class:`~catgraph.graph.PlaceGraph` (edge, fraction,
log-weight; :class:`~catgraph.particles.ParticleSet`) carry the posterior over places
*given that the robot is in the map*; one scalar ``P(new)`` carries the probability that
it is somewhere the map does not cover (CAT-Graph's new-place particle). The joint
posterior is ``P(new)`` on the new place and ``(1 − P(new)) · w_i`` on particle ``i``.

One step (:meth:`Localizer.step`), as in ``particles.SMC.__next__``::

    observation = model.observe(row)       # r_j, r_new from the frame
    move(odometry)                         # motion model: predict
    inject(observation)                    # the recovery share ε: (1 − ε) · cloud + ε · uniform
    reweight(observation)                  # w_i ∝ w_i · exp(ℓ_i), update P(new)
    resample_if_degenerate()               # fold the recovery share in; else ESS < threshold · n
    estimate = summarise()                 # Estimate
    feedback(prior, posterior, answer)     # model.feedback(FilterFeedback)
    return estimate

Odometry is checked on every step, the first included: NaN, infinite or negative
odometry raises :class:`~catgraph.exceptions.DataError`. The row is checked once per
step, here, and handed to the model as a
:class:`~catgraph.observation.CheckedRow`, which the model does not scan again.

Reweighting. Particle ``i`` on edge ``a → b`` at fraction ``α`` gains
``ℓ_i = (1 − α) r_a + α r_b`` (:mod:`catgraph.observation`). The new-place hypothesis
has a two-state Markov prior — the robot enters unmapped space with probability
``new_place_prior`` per step and stays there with probability ``new_place_stay`` —
and gains ``r_new``::

    π_k   = new_place_stay · P_{k−1}(new) + new_place_prior · (1 − P_{k−1}(new))
    E_map = Σ_i w_i exp(ℓ_i)                    (weights normalised before the update)
    P_k(new) = π_k e^{r_new} / (π_k e^{r_new} + (1 − π_k) E_map)

so the new place takes part in the normalisation with the map particles, as in paper 2
(eq. 10). Everything is in log space.

Recovery. The prediction is the grid filter's (:mod:`catgraph.grid`): the moved cloud
mixed with a share ``ε = recovery`` spread uniformly over the places, the prior
probability of a jump anywhere (shuffled queries, kidnapping). The particle filter
keeps that share *exact* rather than sampling it: after reweighting its mass is
``ε / n · Σ_j e^{r_j}`` in closed form, and its posterior over places is
``∝ e^{r_j}``. So the place masses, the confidence and ``P(new)`` see exactly the mass a
jump has, and when the cloud is resampled (every step with a recovery share) the slots
the share earns get places drawn afresh from ``∝ e^{r_j}`` — systematically, so every
slot is a new place — with velocities drawn from the prior (stratified). With
``proposal="best"`` or ``"uniform"`` the share is carried by ``redraw_fraction ·
n_particles`` importance-weighted particles instead (weight ``ε / (n · M · q_j)``),
which target the same posterior with more variance. Either way the particle filter
converges to the grid filter as particles grow (``tests/test_localizer.py``), which a
mean-weight redraw at the best single-frame matches (mixture MCL) does not: it gives a
jump far more prior mass than ``ε`` wherever the frame alone looks good.

Estimate. Posterior mass per place ``m_j = (1 − P(new)) (Σ_{i: place(i) = j} w_i + ρ_j)``
(a particle belongs to the nearer of its two places; ``ρ_j`` the recovery share's exact
mass at ``j``); the answer is
``argmax_j m_j``, its confidence the mass within ``± confidence_radius`` places (along the
reference index), or within ``confidence_radius_m`` metres where the graph has positions
and that is given. A loop closure is declared when confidence ≥ a threshold; sweeping
it gives the PR curve.

Score. The posterior log-odds of that mass ranks frames badly at the top: sequence
observations overlap from frame to frame, so the filter counts the same evidence many
times and is most sure just after a jump, while the cloud still follows the old stretch
of route. Models that can say how well the *most recent* frames alone support a place
(``Observation.support``, e.g. the shortest sequence window) bound it:
``score = min(log-odds, max_{j near answer} support_j)`` (``confidence_score="joint"``,
the default) — a frame is only as sure as both its history and its recent evidence.
Both are in nats, and stay finite: the mass outside the answer is floored at
``1e-300`` (:func:`confidence_log_odds`), so a confidence of exactly 1 (a two-place map,
one particle) still gives a finite, ordered score.

Feedback. After each step the filter tells the model what it predicted and what it
concluded (:class:`~catgraph.observation.FilterFeedback`: the place masses before and
after the frame and the answer's neighbourhood) through ``ObservationModel.feedback``,
its own named step: the tempered whole-image model chooses its temperature and learns
``P(d|L)`` from it, the combined model its parts' reliability.

Cost. A step is O(n_particles · hops + n_places), in compiled loops (motion, recovery,
reweighting with the place masses, systematic resampling) over arrays allocated once in
:meth:`Localizer.reset`; no per-particle Python and no per-step particle arrays. Same
seed, same output: every random draw comes from the one ``numpy.random.Generator`` made
from ``seed``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np

from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .graph import PlaceGraph
from .motion import FrameMotion, MotionModel, OdometryMotion
from .observation import Observation, ObservationModel
from .particles import ParticleSet, _first_in_edge, get_resampler, normalise_in_place

__all__ = ["Estimate", "LocalizationResult", "Localizer", "check_odometry", "confidence_log_odds"]

#: Floor on the mass outside the answer's neighbourhood when taking log-odds: keeps them
#: finite (and ordered) where the confidence is exactly 1.
_MASS_FLOOR = 1e-300


def check_odometry(odometry) -> float | None:
    """Validate one step's odometry: ``None`` or a finite, non-negative distance.

    Raises
    ------
    DataError
        For NaN, infinite or negative odometry, on every step (the first included).
    """
    if odometry is None:
        return None
    try:
        u = float(odometry)
    except (TypeError, ValueError):
        raise DataError(f"odometry must be a finite, non-negative distance; got {odometry!r}.") from None
    if not math.isfinite(u) or u < 0:
        raise DataError(
            f"odometry must be a finite, non-negative distance; got {odometry!r}. "
            "Drop or repair the frame's odometry, or give None for a frame without it."
        )
    return u


def confidence_log_odds(w_in: float, w_out: float, log_map: float, log_new: float) -> tuple[float, float]:
    """Confidence and its log-odds from the map masses inside / outside the answer's
    neighbourhood (normalised over the map) and the log-probabilities of the map and of
    the new place.

    ``confidence = P(map) · w_in``; ``log_odds = log(P(map) w_in) − log(P(map) w_out + P(new))``,
    with ``w_out`` floored at ``1e-300`` so that the log-odds stay finite, and still
    grow with ``w_in``, when the confidence rounds to (or is exactly) 1.
    """
    log_in = log_map + math.log(w_in) if w_in > 0 else -math.inf
    log_out = float(np.logaddexp(log_new, log_map + math.log(max(w_out, _MASS_FLOOR))))
    if not math.isfinite(log_in):
        log_in = log_map + math.log(_MASS_FLOOR)
    confidence = float(math.exp(log_in)) if w_in > 0 else 0.0
    return min(confidence, 1.0), float(log_in - log_out)



@numba.njit(cache=True)
def _reweight_kernel(edge, fraction, log_weight, source, target, log_ratio, n_cloud, log_recovery, like, weight,
                     mass):  # pragma: no cover - compiled
    """Reweight the cloud and the recovery particles, normalise, and sum the posterior
    mass per place. ``log_weight`` holds the prediction: the cloud (slots
    ``< n_cloud``) sums to ``1 − ε``, the recovery share is ``ε`` — exactly
    ``log_recovery`` after reweighting, ``log(ε / n · Σ_j e^{r_j})``, or ``-inf`` without
    recovery. Particle ``i`` gains ``ℓ_i`` (interpolated log-ratio); the recovery
    particles are then scaled so that they carry exactly that mass, so only *where* a
    jump went is sampled, never *how likely* it was. ``mass[j]`` gets the cloud's
    particles plus the recovery share's exact distribution ``∝ e^{r_j}`` (Rao–
    Blackwellised): the outside of any neighbourhood keeps the mass of a jump there,
    as in the grid filter. Returns ``(log E_map, ESS)``, ``E_map = Σ prior · e^ℓ``."""
    k = edge.shape[0]
    for i in range(k):
        e = edge[i]
        f = fraction[i]
        log_weight[i] += (1.0 - f) * log_ratio[source[e]] + f * log_ratio[target[e]]
    mx = -np.inf
    for i in range(n_cloud):
        if log_weight[i] > mx:
            mx = log_weight[i]
    t = 0.0
    if np.isfinite(mx):
        for i in range(n_cloud):
            t += np.exp(log_weight[i] - mx)
        log_cloud = mx + np.log(t)
    else:
        log_cloud = -np.inf
    if k > n_cloud and np.isfinite(log_recovery):  # recovery particles: they carry the share
        mr = -np.inf
        for i in range(n_cloud, k):
            if log_weight[i] > mr:
                mr = log_weight[i]
        tr = 0.0
        for i in range(n_cloud, k):
            tr += np.exp(log_weight[i] - mr)
        shift = log_recovery - (mr + np.log(tr))
        for i in range(n_cloud, k):
            log_weight[i] += shift
    log_map = np.logaddexp(log_cloud, log_recovery)
    if not np.isfinite(log_map):  # nothing left: uniform, as normalise_in_place does
        lse, ess = normalise_in_place(log_weight, weight)
        mass[:] = 0.0
        for i in range(k):
            e = edge[i]
            mass[source[e] if fraction[i] < 0.5 else target[e]] += weight[i]
        return lse, ess
    sq = 0.0
    mass[:] = 0.0
    for i in range(k):
        log_weight[i] -= log_map
        w = np.exp(log_weight[i])
        weight[i] = w
        sq += w * w
        if i < n_cloud:
            e = edge[i]
            mass[source[e] if fraction[i] < 0.5 else target[e]] += w
    if np.isfinite(log_recovery):  # like: cumulative e^{r − max r} (_likelihood_cumulative)
        share = np.exp(log_recovery - log_map) / like[like.shape[0] - 1]
        below = 0.0
        for j in range(like.shape[0]):
            mass[j] += share * (like[j] - below)
            below = like[j]
    return log_map, 1.0 / sq


@numba.njit(cache=True)
def _likelihood_cumulative(log_ratio, out):  # pragma: no cover - compiled
    """``out[j] = Σ_{i ≤ j} e^{r_i − max r}``; returns ``max r``."""
    r_max = -np.inf
    for j in range(log_ratio.shape[0]):
        if log_ratio[j] > r_max:
            r_max = log_ratio[j]
    acc = 0.0
    for j in range(log_ratio.shape[0]):
        acc += np.exp(log_ratio[j] - r_max)
        out[j] = acc
    return r_max


@numba.njit(cache=True)
def _recovery_kernel(log_ratio, kind, top, log_keep, log_recovery, n_cloud, edge, fraction, log_weight, velocity,
                     uniform, cumulative, out_ptr, first_in):  # pragma: no cover - compiled
    """The prediction's recovery share, exactly as the grid filter mixes it:
    ``(1 − ε) · cloud + ε · uniform``. The cloud (slots ``< n_cloud``) is normalised and
    scaled by ``1 − ε``; the ``M`` slots after it get places drawn from a proposal ``q``
    (systematically: one offset ``uniform[0]``, positions ``(u + m) / M``), each with
    the weight ``ε / (n_places · M · q_j)`` of an importance sample of the uniform
    share. ``kind``: 0 likelihood (``q ∝ e^{r}``, so after reweighting every recovery
    particle weighs the same, ``ε Σ_j e^{r_j} / (n_places M)``: the mass of a jump is
    exact, only where it went is sampled), 1 best (half uniform, half the ``top``
    places), 2 uniform."""
    n = log_ratio.shape[0]
    m_slots = edge.shape[0] - n_cloud
    # the cloud: normalise (a cloud that left the map entirely becomes uniform), times 1 − ε
    mx = -np.inf
    for i in range(n_cloud):
        if log_weight[i] > mx:
            mx = log_weight[i]
    if np.isfinite(mx):
        t = 0.0
        for i in range(n_cloud):
            t += np.exp(log_weight[i] - mx)
        shift = mx + np.log(t) - log_keep
        for i in range(n_cloud):
            log_weight[i] -= shift
    else:
        for i in range(n_cloud):
            log_weight[i] = log_keep - np.log(n_cloud)
    # the proposal's cumulative distribution over places
    if kind == 0:
        pass  # cumulative already holds the likelihood's (_likelihood_cumulative)
    elif kind == 1:
        acc = 0.0
        for j in range(n):
            acc += 0.5 / n
            cumulative[j] = acc
        for t in range(top.shape[0]):
            j = top[t]
            if j >= 0:
                for jj in range(j, n):
                    cumulative[jj] += 0.5 / top.shape[0]
    else:
        for j in range(n):
            cumulative[j] = (j + 1.0) / n
    total = cumulative[n - 1]
    # velocities as the grid filter's jump: half from the cloud's velocity marginal
    # (systematic positions over its weights, which now sum to e^{log_keep}), half the prior
    n_copy = (m_slots + 1) // 2
    keep = np.exp(log_keep)
    acc = 0.0
    c = -1
    for t in range(n_copy):
        pos = (uniform[0] + t) / n_copy * keep
        while c < n_cloud - 1 and acc <= pos:
            c += 1
            acc += np.exp(log_weight[c])
        velocity[n_cloud + 2 * t] = velocity[max(c, 0)]
    j = 0
    for m in range(m_slots):
        pos = (uniform[0] + m) / m_slots * total
        while j < n - 1 and cumulative[j] <= pos:
            j += 1
        q = (cumulative[j] - (cumulative[j - 1] if j > 0 else 0.0)) / total
        k = n_cloud + m
        n_out = out_ptr[j + 1] - out_ptr[j]
        if n_out > 0:
            edge[k] = out_ptr[j] + min(int(uniform[m + 1] * n_out), n_out - 1)
            fraction[k] = 0.0
        else:
            edge[k] = first_in[j]
            fraction[k] = 1.0
        if m % 2 == 1:
            velocity[k] = -1 - m // 2  # drawn by the motion model from its prior, stratified
        log_weight[k] = log_recovery - np.log(n * m_slots * q)


@numba.njit(cache=True)
def _place_mass_kernel(edge, fraction, weight, source, target, out):  # pragma: no cover - compiled
    """``out[j] = Σ_{i: place(i) = j} weight[i]``; a particle's place is the nearer of
    its edge's two places. ``weight`` may be log-weights (``log=True`` callers exp first)."""
    out[:] = 0.0
    for i in range(edge.shape[0]):
        e = edge[i]
        j = source[e] if fraction[i] < 0.5 else target[e]
        out[j] += weight[i]


@numba.njit(cache=True)
def _systematic_gather(weight, u, edge, fraction, velocity, n_out, edge_out, fraction_out,
                       velocity_out):  # pragma: no cover - compiled
    """Systematic resampling of ``weight`` (any length) to ``n_out`` particles, written
    into ``*_out``: the indices :func:`~catgraph.particles.systematic_resample` gives for
    the same uniform ``u``, without building them."""
    total = 0.0
    for i in range(weight.shape[0]):
        total += weight[i]
    acc = weight[0]
    i = 0
    last = weight.shape[0] - 1
    for k in range(n_out):
        pos = (u + k) / n_out
        while i < last and acc / total <= pos:
            i += 1
            acc += weight[i]
        edge_out[k] = edge[i]
        fraction_out[k] = fraction[i]
        velocity_out[k] = velocity[i]


@numba.njit(cache=True)
def _fill_recovery(start, n_new, u_places, cumulative, out_ptr, first_in, edge_out, fraction_out,
                   velocity_out):  # pragma: no cover - compiled
    """Slots ``start .. start + n_new``: places drawn systematically (offset ``u_places``)
    from ``cumulative``, each on an out-edge chosen by where its position falls inside
    the place's interval (uniform, independent of the place). Velocities as the grid
    filter's jump: half the slots copy the velocity of the cloud's slots ``< start``
    (evenly spaced through them: its velocity marginal, the cloud being equally
    weighted), half draw from the prior (stratified)."""
    n_copy = (n_new + 1) // 2 if start > 0 else 0
    n = cumulative.shape[0]
    z = cumulative[n - 1]
    j = 0
    for m in range(n_new):
        pos = (u_places + m) / n_new * z
        while j < n - 1 and cumulative[j] <= pos:
            j += 1
        low = cumulative[j - 1] if j > 0 else 0.0
        within = (pos - low) / (cumulative[j] - low) if cumulative[j] > low else 0.0
        k = start + m
        n_edges = out_ptr[j + 1] - out_ptr[j]
        if n_edges > 0:
            edge_out[k] = out_ptr[j] + min(int(within * n_edges), n_edges - 1)
            fraction_out[k] = 0.0
        else:
            edge_out[k] = first_in[j]
            fraction_out[k] = 1.0
        if m % 2 == 0 and n_copy > 0:
            velocity_out[k] = velocity_out[((m // 2) * start) // n_copy]
        else:
            velocity_out[k] = -1 - m // 2  # drawn by the motion model from its prior, stratified


@numba.njit(cache=True)
def _systematic_gather_recovering(weight, recovery_weight, u, u_places, edge, fraction, velocity, n_out, cumulative,
                                  out_ptr, first_in, edge_out, fraction_out,
                                  velocity_out):  # pragma: no cover - compiled
    """Systematic resampling of the cloud (``weight``) and the recovery share (one more
    entry, ``recovery_weight``) to ``n_out`` particles. The slots the recovery share
    earns are filled with places drawn afresh — systematically, offset ``u_places`` —
    from its exact posterior, ``cumulative`` (``∝ e^{r_j}``): every slot a new place, so
    the share is as diverse as its mass allows. A slot's out-edge comes from where its
    position falls inside the place's interval (uniform, independent of the place)."""
    total = recovery_weight
    for i in range(weight.shape[0]):
        total += weight[i]
    acc = 0.0
    i = -1
    last = weight.shape[0] - 1
    n_cloud_slots = n_out
    for k in range(n_out):
        pos = (u + k) / n_out * total
        while i < last and acc <= pos:
            i += 1
            acc += weight[i]
        if acc <= pos:  # past the cloud: the rest of the slots go to the recovery share
            n_cloud_slots = k
            break
        edge_out[k] = edge[i]
        fraction_out[k] = fraction[i]
        velocity_out[k] = velocity[i]
    n_new = n_out - n_cloud_slots
    _fill_recovery(n_cloud_slots, n_new, u_places, cumulative, out_ptr, first_in, edge_out, fraction_out,
                   velocity_out)
    return n_new


@numba.njit(cache=True)
def _top_k(values, k):  # pragma: no cover - compiled
    """Indices of the ``k`` largest values (any order), one pass with a small buffer."""
    best_v = np.full(k, -np.inf)
    best_i = np.full(k, -1, dtype=np.int64)
    lowest = 0  # slot holding the smallest kept value
    for j in range(values.shape[0]):
        v = values[j]
        if v > best_v[lowest] or best_i[lowest] < 0:
            best_v[lowest] = v
            best_i[lowest] = j
            for s in range(k):
                if best_i[s] < 0 or best_v[s] < best_v[lowest]:
                    lowest = s
                    if best_i[s] < 0:
                        break
    return best_i


def _check_observation(observation, n_places: int) -> np.ndarray:
    """Check a row once per step (1-D, real, finite, one value per place); return it as
    a :class:`~catgraph.observation.CheckedRow`, which models do not scan again."""
    from .observation import CheckedRow

    if type(observation) is CheckedRow and observation.ndim == 1 and len(observation) == n_places:
        return observation
    row = check_array(observation, "observation", ndim=1)
    if len(row) != n_places:
        raise ShapeMismatchError(
            f"the observation has {len(row)} places but the graph has {n_places}; "
            "give the frame's difference to every reference place of the map."
        )
    return row.view(CheckedRow)


@dataclass(frozen=True)
class Estimate:
    """The filter's answer after one query frame.

    Attributes
    ----------
    place : int
        Most likely reference place (index as loaded).
    position : ndarray, shape (2|3,) or None
        Metric position of ``place`` where the graph has positions.
    confidence : float
        Posterior mass within the tolerance of ``place`` (in [0, 1]).
    new_place_probability : float
        ``P(new place | Z^k)``.
    ess : float
        Effective sample size after reweighting (before any resampling).
    resampled : bool
        Whether this step resampled.
    log_odds : float
        ``log(confidence / (1 − confidence))`` computed in log space, so it keeps ordering
        frames where ``confidence`` rounds to 1.0.
    score : float
        What to rank frames by for PR curves: ``min(log_odds, support)`` where the model
        gives a recent support (``confidence_score="joint"``), else ``log_odds``.
    """

    place: int
    position: np.ndarray | None
    confidence: float
    new_place_probability: float
    ess: float
    resampled: bool
    log_odds: float = 0.0
    score: float = 0.0


@dataclass
class LocalizationResult:
    """Per-frame outputs of :meth:`Localizer.run`, in processing order.

    Attributes
    ----------
    place : ndarray of int64, shape (n,)
    confidence, new_place_probability, ess, log_odds, score : ndarray of float64, shape (n,)
    position : ndarray, shape (n, 2|3) or None
    query_index : ndarray of int64, shape (n,)
    seconds_per_frame : float
        Mean wall time of a step, observation model included.
    posterior : ndarray of float32, shape (n, n_places) or None
        Posterior mass per place after each frame (``run(return_posterior=True)``).
    """

    place: np.ndarray
    confidence: np.ndarray
    new_place_probability: np.ndarray
    ess: np.ndarray
    position: np.ndarray | None
    query_index: np.ndarray
    seconds_per_frame: float
    log_odds: np.ndarray | None = None
    score: np.ndarray | None = None
    posterior: np.ndarray | None = None

    @property
    def match(self) -> np.ndarray:
        """Alias of ``place`` (the name :func:`catgraph.metrics.evaluate` uses)."""
        return self.place


#: The learned jump rate (``learn_recovery``), as the grid filter's: half-life (frames)
#: of its running mean, weight (frames) of the ``recovery`` prior, and its range.
RECOVERY_MEMORY = 100.0
RECOVERY_PRIOR_FRAMES = 20.0
RECOVERY_RANGE = (1e-4, 0.5)

#: Where recovery particles are drawn (see the module docstring); the first is the default.
PROPOSALS = ("likelihood", "best", "uniform")
_PROPOSAL_CODE = {name: k for k, name in enumerate(PROPOSALS)}


class Localizer:
    """CAT-Graph particle filter over a place graph.

    Parameters
    ----------
    graph : PlaceGraph
    model : ObservationModel
        E.g. :class:`~catgraph.observation.HistogramObservation`; reset by :meth:`reset`.
    n_particles : int
    motion : MotionModel, optional
        Default: :class:`~catgraph.motion.OdometryMotion` for steps given odometry,
        :class:`~catgraph.motion.FrameMotion` otherwise.
    resampler : {"systematic", "stratified", "residual", "multinomial"}
    ess_threshold : float in [0, 1]
        Without recovery particles: resample when ESS < ``ess_threshold · n_particles``
        (with them, every step folds them into the cloud).
    recovery : float in [0, 1)
        ``ε``: probability per frame of a jump anywhere on the map, the grid filter's
        ``recovery``.
    learn_recovery : bool
        Learn ``ε`` online from the frames (the grid filter's online EM, shrunk towards
        ``recovery``); its current value is ``recovery_``.
    redraw_fraction : float in [0, 1)
        0 turns recovery off. Otherwise, for the ``"best"`` and ``"uniform"`` proposals,
        the recovery particles drawn each step, as a fraction of ``n_particles``; the
        ``"likelihood"`` proposal needs none (the share's mass is exact and its places
        are drawn at resampling, as many as the mass earns).
    proposal : {"likelihood", "best", "uniform"}
        Where the recovery share's particles come from: its exact posterior ``∝ e^{r}``
        (drawn at resampling; the default), or importance samples — half uniform and
        half the ``proposal_top_k`` best places, or uniform. Every choice targets the
        same posterior (the grid filter's); they differ in variance.
    proposal_top_k : int
        Number of best places the ``"best"`` proposal draws from.
    new_place_prior : float in [0, 1)
        Per-step probability of entering unmapped space (0 disables the new place).
    new_place_stay : float in [0, 1)
        Per-step probability of staying in unmapped space.
    confidence_radius : int
        Places either side of the answer counted in its confidence.
    confidence_radius_m : float, optional
        Use a metric radius instead (needs graph positions).
    confidence_score : {"joint", "posterior"}
        What :attr:`Estimate.score` ranks by: ``"joint"`` = the smaller of the posterior
        log-odds and the observation's recent support at the answer (where the model
        gives one), ``"posterior"`` = the posterior log-odds alone.
    seed : int, Generator or None

    Attributes
    ----------
    particles_ : ParticleSet
        The cloud (``n_particles``), views into the filter's fixed arrays.
    new_place_probability_ : float
    recovery_ : float
        The jump rate ``ε`` of the latest prediction (learned, or ``recovery``).
    place_posterior_ : ndarray of float64, shape (n_places,)
    n_steps_ : int
    """

    def __init__(self, graph: PlaceGraph, model: ObservationModel, n_particles: int = 2000,
                 motion: MotionModel | None = None, resampler: str = "systematic", ess_threshold: float = 0.5,
                 recovery: float = 0.05, learn_recovery: bool = True, redraw_fraction: float = 0.1,
                 proposal: str = "likelihood",
                 proposal_top_k: int = 10, new_place_prior: float = 0.0, new_place_stay: float = 0.8,
                 confidence_radius: int = 2, confidence_radius_m: float | None = None,
                 confidence_score: str = "joint", seed: int | np.random.Generator | None = 0) -> None:
        self.graph = graph
        self.model = model
        self.n_particles = n_particles
        self.motion = motion
        self.resampler = resampler
        self.ess_threshold = ess_threshold
        self.recovery = recovery
        self.learn_recovery = learn_recovery
        self.redraw_fraction = redraw_fraction
        self.proposal = proposal
        self.proposal_top_k = proposal_top_k
        self.new_place_prior = new_place_prior
        self.new_place_stay = new_place_stay
        self.confidence_radius = confidence_radius
        self.confidence_radius_m = confidence_radius_m
        self.confidence_score = confidence_score
        self.seed = seed

    # ------------------------------------------------------------------ setup
    def _validate(self) -> None:
        owner = type(self).__name__
        if not isinstance(self.graph, PlaceGraph):
            raise InvalidParameterError(f"The 'graph' parameter of {owner} must be a PlaceGraph. Got {type(self.graph).__name__}.")
        if not hasattr(self.model, "observe") or not hasattr(self.model, "reset"):
            raise InvalidParameterError(
                f"The 'model' parameter of {owner} must be an ObservationModel (reset(), observe(row)). Got {self.model!r}."
            )
        check_scalar(self.n_particles, "n_particles", owner, int, 1)
        check_scalar(self.ess_threshold, "ess_threshold", owner, float, 0.0, 1.0)
        check_scalar(self.recovery, "recovery", owner, float, 0.0, 1.0, True, False)
        if not isinstance(self.learn_recovery, (bool, np.bool_)):
            raise InvalidParameterError(f"The 'learn_recovery' parameter of {owner} must be a bool. "
                                        f"Got {self.learn_recovery!r} instead.")
        check_scalar(self.redraw_fraction, "redraw_fraction", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.proposal_top_k, "proposal_top_k", owner, int, 1)
        check_scalar(self.new_place_prior, "new_place_prior", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.new_place_stay, "new_place_stay", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.confidence_radius, "confidence_radius", owner, int, 0)
        if self.confidence_score not in ("joint", "posterior"):
            raise InvalidParameterError(
                f"The 'confidence_score' parameter of {owner} must be 'joint' or 'posterior'. "
                f"Got {self.confidence_score!r} instead."
            )
        if self.proposal not in PROPOSALS:
            raise InvalidParameterError(
                f"The 'proposal' parameter of {owner} must be one of {', '.join(map(repr, PROPOSALS))}. "
                f"Got {self.proposal!r} instead.")
        if self.confidence_radius_m is not None:
            check_scalar(self.confidence_radius_m, "confidence_radius_m", owner, float, 0.0)
            if self.graph.positions is None:
                raise DataError("confidence_radius_m needs a place graph with positions; use confidence_radius (places).")
        self._resample = get_resampler(self.resampler)

    def reset(self) -> "Localizer":
        """Start afresh: particles uniform over the graph, ``P(new) = 0``, model reset.

        Every array a step touches is allocated here, once: the cloud and the recovery
        slots after it, the weights, the resampling and proposal buffers."""
        self._validate()
        g, n = self.graph, self.n_particles
        self._rng = as_generator(self.seed) if not isinstance(self.seed, np.random.Generator) else self.seed
        # the likelihood proposal is exact: the share's mass in closed form, its places drawn
        # from its posterior at resampling; the others are importance samples, m of them
        self._exact_recovery = self.recovery > 0 and self.redraw_fraction > 0 and self.proposal == "likelihood"
        m = int(round(self.redraw_fraction * n)) if self.recovery > 0 and not self._exact_recovery else 0
        self._n_recovery = m
        cloud = ParticleSet.uniform(g, n, self._rng)
        self._edge = np.concatenate([cloud.edge, np.zeros(m, dtype=np.int64)])
        self._fraction = np.concatenate([cloud.fraction, np.zeros(m)])
        self._log_weight = np.concatenate([cloud.log_weight, np.full(m, -np.inf)])
        self._velocity = -1 - np.arange(n + m, dtype=np.int64)  # stratified draws from the velocity prior
        self.particles_ = ParticleSet(self._edge[:n], self._fraction[:n], self._log_weight[:n], self._velocity[:n])
        self._weight = np.exp(self._log_weight)
        self._gathered = (np.empty(n, dtype=np.int64), np.empty(n), np.empty(n, dtype=np.int64))
        self._uniform = np.empty(m + 1)
        self._u2 = np.empty(2)
        self._recovery_weight = 0.0
        self.recovery_ = float(self.recovery)
        self._jumps, self._frames = 0.0, 0.0
        self._log_like_mean = 0.0
        self._cumulative = np.empty(g.n_places)
        self._like = np.empty(g.n_places)
        self._mass = np.empty(g.n_places)
        self._prior = np.empty(g.n_places)
        self._first_in = _first_in_edge(g)
        self._top = np.full(min(self.proposal_top_k, g.n_places), -1, dtype=np.int64)
        self.new_place_probability_ = 0.0
        self.n_steps_ = 0
        self._log_new, self._log_map = -math.inf, 0.0
        self._support = None
        self._recovered = False
        self._no_ratio = np.zeros(g.n_places)
        self._motions = (self.motion or FrameMotion(), self.motion or OdometryMotion())
        self.model.reset()
        self._has_feedback = callable(getattr(self.model, "feedback", None))
        if self.confidence_radius_m is not None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.graph.positions)
        return self

    # ------------------------------------------------------------------ one step
    def step(self, observation: np.ndarray, odometry: float | None = None) -> Estimate:
        """Process one query frame.

        Parameters
        ----------
        observation : ndarray, shape (n_places,)
            The frame's difference to every reference place (what the model observes).
        odometry : float, optional
            Distance travelled since the previous frame (graph units).

        Returns
        -------
        Estimate
        """
        if not hasattr(self, "particles_"):
            self.reset()
        row = _check_observation(observation, self.graph.n_places)
        odometry = check_odometry(odometry)
        obs = self.model.observe(row)
        self._move(odometry)
        self._inject(obs)
        prior = self._predicted_mass() if self._has_feedback else None
        ess = self._reweight(obs)
        self._support = obs.support if obs.informative else None
        mass = self._mass
        resampled = self._resample_if_degenerate(ess)
        estimate, near = self._summarise(mass, ess, resampled)
        self._feedback(prior, near)
        self.n_steps_ += 1
        return estimate

    def _place_mass(self, weight: np.ndarray) -> np.ndarray:
        g = self.graph
        _place_mass_kernel(self._edge, self._fraction, weight, g.source, g.target, self._mass)
        return self._mass

    def _predicted_mass(self) -> np.ndarray:
        """The prediction's place masses, ``(1 − ε) · cloud + ε / n_places`` (the grid's
        ``prior_``): the cloud's, plus the recovery share exactly rather than sampled."""
        g, n = self.graph, self.n_particles
        np.exp(self._log_weight[:n], out=self._weight[:n])
        _place_mass_kernel(self._edge[:n], self._fraction[:n], self._weight[:n], g.source, g.target, self._prior)
        if self._recovered:
            self._prior += self.recovery_ / g.n_places
        return self._prior

    def _feedback(self, prior, near) -> None:
        """Tell the model the filter's prediction and answer (``ObservationModel.feedback``)."""
        if self._has_feedback:
            from .observation import FilterFeedback

            self.model.feedback(FilterFeedback(prior.copy(), self.place_posterior_, near))

    def _move(self, odometry: float | None) -> None:
        if self.n_steps_ == 0:
            return  # the first frame: nothing has moved yet
        motion = self._motions[0] if odometry is None else self._motions[1]
        motion.move(self.particles_, self.graph, self._rng, odometry)

    def _inject(self, obs: Observation) -> None:
        """The recovery share ``ε`` (see :func:`_recovery_kernel`); none on the first frame."""
        n, m, g = self.n_particles, self._n_recovery, self.graph
        log_ratio = obs.log_ratio if obs.informative else self._no_ratio
        log_ratio = np.ascontiguousarray(log_ratio, dtype=np.float64)
        r_max = _likelihood_cumulative(log_ratio, self._like)
        self._log_like_mean = r_max + math.log(self._like[-1] / g.n_places)  # log mean_j e^{r_j}
        self._recovered = (m > 0 or self._exact_recovery) and self.n_steps_ > 0
        if not self._recovered:
            normalise_in_place(self._log_weight[:n], self._weight[:n])
            return
        self._log_recovery = math.log(self.recovery_) + self._log_like_mean
        if self.proposal == "best":
            self._top[:] = _top_k(log_ratio, len(self._top))
        self._rng.random(out=self._uniform)
        k = n + m
        _recovery_kernel(log_ratio, _PROPOSAL_CODE[self.proposal], self._top, math.log1p(-self.recovery_),
                         math.log(self.recovery_), n, self._edge[:k], self._fraction[:k], self._log_weight[:k],
                         self._velocity[:k], self._uniform, self._like if self.proposal == "likelihood"
                         else self._cumulative, g.out_ptr, self._first_in)

    def _reweight(self, obs: Observation) -> float:
        g, n = self.graph, self.n_particles
        k = n + (self._n_recovery if self._recovered else 0)
        self._active = k
        log_ratio = np.ascontiguousarray(obs.log_ratio if obs.informative else self._no_ratio, dtype=np.float64)
        if k < len(self._log_weight):
            self._log_weight[k:] = -np.inf
            self._weight[k:] = 0.0
        log_recovery = self._log_recovery if self._recovered else -math.inf
        log_map, ess = _reweight_kernel(self._edge[:k], self._fraction[:k], self._log_weight[:k], g.source, g.target,
                                        log_ratio, n, log_recovery, self._like, self._weight[:k], self._mass)
        self._recovery_weight = math.exp(log_recovery - log_map) if k == n and np.isfinite(log_map) else 0.0
        if obs.informative and np.isfinite(log_map):
            self._learn_recovery(math.exp(self._log_like_mean - log_map))
            prior = self.new_place_stay * self.new_place_probability_ + self.new_place_prior * (
                1.0 - self.new_place_probability_)
            if prior > 0.0:
                a_new = math.log(prior) + obs.new_place_log_ratio
                a_map = math.log1p(-prior) + log_map
                total = np.logaddexp(a_new, a_map)
                self._log_new, self._log_map = a_new - total, a_map - total
                self.new_place_probability_ = float(math.exp(self._log_new))
            else:
                self.new_place_probability_ = 0.0
                self._log_new, self._log_map = -math.inf, 0.0
        return float(ess)

    def _learn_recovery(self, ratio: float) -> None:
        """Online EM for the jump rate, as the grid filter learns it: the posterior share
        of this step's recovery mass, ``ε · mean_j e^{r_j} / Σ prior · e^r``, averaged
        over the recent frames (half-life :data:`RECOVERY_MEMORY`) and shrunk towards
        ``recovery`` (worth :data:`RECOVERY_PRIOR_FRAMES` frames)."""
        if not self.learn_recovery or self.recovery == 0.0:
            return
        responsibility = min(1.0, self.recovery_ * ratio)
        decay = 0.5 ** (1.0 / RECOVERY_MEMORY)
        self._jumps = decay * self._jumps + responsibility
        self._frames = decay * self._frames + 1.0
        eps = (self._jumps + RECOVERY_PRIOR_FRAMES * float(self.recovery)) / (self._frames + RECOVERY_PRIOR_FRAMES)
        self.recovery_ = float(min(max(eps, RECOVERY_RANGE[0]), RECOVERY_RANGE[1]))

    def _resample_if_degenerate(self, ess: float) -> bool:
        """Fold the recovery share into the cloud (every step that has one), else
        resample when ESS < ``ess_threshold · n_particles``."""
        n = self.n_particles
        if not self._recovered and ess >= self.ess_threshold * n:
            return False
        k = self._active
        e_out, f_out, v_out = self._gathered
        g = self.graph
        if self._recovered and self._exact_recovery:
            self._rng.random(out=self._u2)
            if self.resampler == "systematic":  # compiled, no index array
                _systematic_gather_recovering(self._weight[:n], self._recovery_weight, self._u2[0], self._u2[1],
                                              self._edge, self._fraction, self._velocity, n, self._like,
                                              g.out_ptr, self._first_in, e_out, f_out, v_out)
            else:
                w = np.append(self._weight[:n], self._recovery_weight)
                idx = np.sort(self._resample(w, self._rng))
                keep = idx[idx < n]
                e_out[:len(keep)], f_out[:len(keep)], v_out[:len(keep)] = (
                    self._edge[keep], self._fraction[keep], self._velocity[keep])
                _fill_recovery(len(keep), n - len(keep), self._u2[1], self._like, g.out_ptr, self._first_in,
                               e_out, f_out, v_out)
        elif self.resampler == "systematic":  # compiled, no index array
            _systematic_gather(self._weight[:k], self._rng.random(), self._edge, self._fraction, self._velocity, n,
                               e_out, f_out, v_out)
        else:
            idx = self._resample(self._weight[:k], self._rng)[:n]
            if len(idx) != n:  # drawn for k particles; keep n of them at random
                idx = idx[self._rng.permutation(len(idx))[:n]]
            e_out[:], f_out[:], v_out[:] = self._edge[idx], self._fraction[idx], self._velocity[idx]
        self._edge[:n], self._fraction[:n], self._velocity[:n] = e_out, f_out, v_out
        self._log_weight[:n] = -math.log(n)
        self._weight[:n] = 1.0 / n
        return True

    def _summarise(self, mass: np.ndarray, ess: float, resampled: bool) -> tuple[Estimate, slice | np.ndarray]:
        g = self.graph
        self.place_posterior_ = mass * (1.0 - self.new_place_probability_)
        best = int(np.argmax(mass))
        if self.confidence_radius_m is not None:
            near = np.zeros(g.n_places, dtype=bool)
            near[self._tree.query_ball_point(g.positions[best], self.confidence_radius_m)] = True
        else:
            near = slice(max(0, best - self.confidence_radius), best + self.confidence_radius + 1)
        from .grid import _inside_outside

        w_in, w_out = _inside_outside(mass, near)
        # in log space, so that the new-place mass still ranks frames whose map mass is all inside
        confidence, log_odds = confidence_log_odds(w_in, w_out, self._log_map, self._log_new)
        score = log_odds
        if self.confidence_score == "joint" and self._support is not None:
            score = min(log_odds, float(np.max(self._support[near])))
        position = None if g.positions is None else g.positions[best].copy()
        return Estimate(best, position, confidence, self.new_place_probability_, ess, resampled, log_odds,
                        score), near

    # ------------------------------------------------------------------ batch
    def run(self, observations, odometry: np.ndarray | None = None, query_index: np.ndarray | None = None,
            reference=None, progress: bool = False, return_posterior: bool = False) -> LocalizationResult:
        """Reset, then :meth:`step` through a whole query.

        Parameters
        ----------
        observations : ndarray, shape (n_query, n_places), or Traverse
            Difference matrix (rows in processing order), or a query
            :class:`~catgraph.traverse.Traverse` — then ``reference`` (a Traverse) is
            needed, the differences come from :func:`catgraph.pipeline.differences`
            (normalised per query), and the query's odometry and index are used unless
            given.
        odometry : ndarray, shape (n_query,), optional
            Per-frame odometry (``odometry[0]`` is ignored).
        query_index : ndarray of int, shape (n_query,), optional
            Index of each frame as loaded (default ``arange``).
        reference : Traverse, optional
        progress : bool
            Show a tqdm progress bar.
        return_posterior : bool
            Also return the posterior mass of every place after every frame
            (``(n_query, n_places) float32``; memory grows with the query, so off by
            default).

        Returns
        -------
        LocalizationResult
        """
        from .traverse import Traverse

        if isinstance(observations, Traverse):
            if reference is None:
                raise DataError("Localizer.run(query_traverse) needs reference=<reference Traverse> to compute differences.")
            from .pipeline import differences

            query = observations
            observations = differences(reference, query)
            odometry = query.odometry if odometry is None else odometry
            query_index = query.index if query_index is None else query_index
        d = check_array(observations, "difference matrix", ndim=2)
        n = len(d)
        if odometry is not None:
            odometry = check_array(odometry, "odometry", ndim=1)
            if len(odometry) != n:
                raise ShapeMismatchError(f"odometry has {len(odometry)} entries for {n} query frames; give one per frame.")
        qi = np.arange(n) if query_index is None else np.asarray(query_index, dtype=np.int64)
        self.reset()
        place = np.empty(n, dtype=np.int64)
        conf, p_new, ess, log_odds, score = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        pos = None if self.graph.positions is None else np.empty((n, self.graph.positions.shape[1]))
        posterior = np.empty((n, self.graph.n_places), dtype=np.float32) if return_posterior else None
        from .observation import CheckedRow

        if d.shape[1] != self.graph.n_places:
            raise ShapeMismatchError(
                f"the difference matrix has {d.shape[1]} places but the graph has {self.graph.n_places}; "
                "give every frame's difference to every reference place of the map."
            )
        rows_checked = d.view(CheckedRow)  # checked once, here
        rows = range(n)
        if progress:
            from tqdm import tqdm

            rows = tqdm(rows, desc="localising", unit="frame", leave=False)
        start = time.perf_counter()
        for k in rows:
            est = self.step(rows_checked[k], None if odometry is None else float(odometry[k]))
            place[k], conf[k], p_new[k], ess[k] = est.place, est.confidence, est.new_place_probability, est.ess
            log_odds[k], score[k] = est.log_odds, est.score
            if pos is not None:
                pos[k] = est.position
            if posterior is not None:
                posterior[k] = self.place_posterior_
        seconds = (time.perf_counter() - start) / max(n, 1)
        return LocalizationResult(place, conf, p_new, ess, pos, qi, seconds, log_odds, score, posterior)
