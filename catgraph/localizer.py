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
    resample_if_degenerate()               # the cloud and the oldest young generation
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

Recovery. The prediction is the grid filter's (:mod:`catgraph.grid`): the moved
particles mixed with a share ``ε`` spread uniformly over the places — the probability
per frame of a jump anywhere (shuffled queries, kidnapping), learned online as the grid
filter learns it (``learn_recovery``). Each step a new *generation* of
``M = redraw_fraction · n_particles`` particles carries that share: places drawn
systematically from a proposal ``q`` (``"likelihood"``: ``q ∝ e^{r}``, the frame's
own evidence; ``"sharpened"``: ``q = ½ e^{β r} / Σ e^{β r} + ½ / n``, most of the
births on the few places the frame favours most, with a uniform half so that every
place keeps ``q ≥ 1 / (2n)``; ``"best"``; ``"uniform"``), importance weights
``ε / (n · M · q_j)``,
velocities half from the current velocity marginal, half from the prior (the grid's
jump). After reweighting the generation is scaled to carry exactly the share's
posterior mass ``ε · mean_j e^{r_j} / E_map``, so the confidence and ``P(new)`` see
exactly how likely a jump was; the place masses use that share's exact distribution
(``∝ e^{r_j}``) for the newborn generation.

Jump grid (``jump_graduation`` ``λ < 1``). A jump's particles born from one frame's
evidence carry the mass of "jumped exactly at this frame to here", which on real data
(Nordland shuffled) is about 10⁻⁴ at the right place when its generation must compete:
systematic resampling into the cloud's ~10³ slots then keeps it with probability ~0.1,
and the births land within two places of the truth 0.4 times per frame (of 200). Which
seed keeps the first such particle decides when the filter re-localises (31 frames for
one seed, 234 for another after the same jump, where the grid takes 27). The jump grid
keeps the recovery share exactly instead, as the grid filter does: ``J_t = ((1 − ε) ·
predict(J_{t−1}) + ε / n · v_jump) · e^{r}``; a share ``λ`` of ``J_t`` becomes the
newborn generation, drawn from ``J_t`` itself, and ``(1 − λ) J_t`` stays. The posterior
is the particles plus the grid (the place masses add the grid's exactly), so the
particles still converge to the grid filter (``tests/test_localizer_jump_grid.py``);
the births now carry the mass of "jumped in the last few frames and since moved
here", which grows with every frame that agrees. On a route whose places follow each
other by index (every map built from traverses) the grid's prediction, the frame and the
sums the step reads from it are one compiled pass over (velocity bin, place), shared
among the free cores (:mod:`catgraph._jump_kernels`, tested against
:func:`catgraph.grid.predict`); any other route takes :func:`catgraph.grid.predict`.

Young particles are not resampled at once. The particles live in ``n_particles``
fixed slots: the *cloud*, then ``recovery_frames`` generations of ``M`` slots in a
ring. Every step the cloud and the *oldest* generation are resampled together
(systematic) into the cloud's slots, and the freed slots take the next births; the
younger generations keep their weights. A jump's particles are thus weighed over
``recovery_frames`` frames of evidence before they must compete with the tracking
cloud — resampled at birth, a hypothesis that the frame alone barely supports would be
dropped before the next frames could confirm it. Resampling a subset while keeping its
mass leaves the weighted particle set a valid approximation of the same posterior, so
the particle filter still converges to the grid filter as particles grow
(``tests/test_localizer.py``). (A mean-weight redraw at the best single-frame matches,
mixture MCL, does not: it gives a jump far more prior mass than ``ε`` wherever the
frame alone looks good.)

Estimate. Posterior mass per place ``m_j = (1 − P(new)) (Σ_{i: place(i) = j} w_i + ρ_j)``
(a particle belongs to the nearer of its two places; ``ρ_j`` the recovery share's exact
mass at ``j``); the answer is
``argmax_j m_j``, its confidence the mass within ``confidence_radius`` mean spacings of the
map along the route (the grid filter's neighbourhood: ``± confidence_radius`` places on
a map of evenly spaced frames, a surveyed point's own scans on a Wi-Fi map), or within
``confidence_radius_m`` metres where the graph has positions and that is given. A loop closure is declared when confidence ≥ a threshold; sweeping
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
``P(d|L)`` from it, the combined model its parts' reliability. The posterior it is
handed is smoothed over the confidence neighbourhoods (``smooth_feedback``, the
default): place ``j`` gets the mean mass of the places an answer at ``j`` would count
(:func:`neighbourhood_means`), rescaled to the same total. The tempered model's
agreement reads the posterior at the frame's own best place against its maximum, two
single places; a particle cloud resolves the posterior to a place or two only up to
where its particles happened to land. At the low temperatures real data settle at,
2,000 particles also hold a flatter posterior than the grid filter (measured on
Nordland), so they read a lower agreement and learn a lower temperature, which flattens
the posterior further: a Monte Carlo error the feedback loop amplifies, by an amount
that differs from seed to seed. Over a neighbourhood the particles' sums vary far less
(``tests/test_localizer_feedback.py``). The smoothed posterior is the limit of
the grid filter's posterior smoothed the same way, not of the grid's own feedback: the
agreement then asks whether the frame's best place lies within the neighbourhood the
filter would answer with, a coarser question whose answer the particles can give;
what it does to accuracy and seed spread is measured per condition in
``benchmarks/results/particles.md``.

The velocity marginalised (``marginal_velocity``, the default where it applies: a
:class:`~catgraph.motion.VelocityMotion` on a route without junctions, frames without
odometry). A particle then carries a *distribution* over the grid filter's state bins
(every speed, a fractional speed split into its phases as the grid's ``max_phases``
splits it) instead of one sampled bin (Rao–Blackwellisation), and the prediction and the frame are taken
together (:meth:`~catgraph.motion.VelocityMotion.move_marginal`): the particles on one
place predict as the grid filter predicts a state with all its mass there; they move to
destinations drawn from that prediction times the frame's likelihood (the locally optimal
proposal), split systematically in proportion to it, and their weight gains the
predictive likelihood ``Σ_c π_c e^{r_c}`` rather than the likelihood of where they
happened to land. The place masses ``m_j`` are the particles' predictions before that
draw (Rao–Blackwellised too), the first frame is drawn systematically from its own
posterior ``∝ e^{r_j}``, and the recovery generation is born with the jump's velocity
distribution (half the posterior velocity marginal, half uniform) instead of a sampled
bin. So in this mode the order of a step is observe → move with the frame → inject →
reweight the newborn → resample → summarise → feedback. What it bought, per condition
and dataset, is measured in ``benchmarks/results/particles.md``: the sampled velocity
and the landing place were most of the filter's seed-to-seed spread.

Cost. A step is O(n_particles · hops + n_places), in compiled loops (motion, recovery,
reweighting with the place masses, systematic resampling) over arrays allocated once in
:meth:`Localizer.reset`; no per-particle Python and no per-step particle arrays (the
marginalised motion: O(occupied places · n_bins² + n_particles), its families' scratch
allocated per step). The O(n_places) part is what the answer and the feedback read: the
frame's cumulative ``e^{r − max r}`` (one ``exp`` per place, on the free cores,
:func:`likelihood_cumulative`), the place masses, the posterior and the answer in one
pass (:func:`_posterior_kernel`), the confidence's two sums and the smoothed posterior
handed to the model, and the recent support's scores and moments that the joint score
reads (from 2¹⁷ places formed on a worker thread while the rest of the step runs, where a
core is free: :meth:`Localizer._form_support_ahead`). On a map larger than the particles'
reach the marginal motion clears and rescales only the places it wrote
(:class:`~catgraph.motion.PlacesWritten`) and the frame's ratio is taken only where it
reads (:meth:`~catgraph.motion.VelocityMotion.reach_places`); the births find their places
by bisection. Each of these gives the floats of the full passes it replaced (tested, and
whole runs checked bit for bit). Same seed, same output: every random draw comes from
the one ``numpy.random.Generator`` made from ``seed``. The jump grid adds O(n_places ·
n_bins) per step (its pass, above). Measured: ``benchmarks/results/particles_step_speed.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ._jit import njit
from ._observation_kernels import all_finite
from ._twin import TwinReadings, logistic, mixed_answer
from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .graph import PlaceGraph
from .grid import learn_jump_rate
from .jumps import frame_jump_rate
from .motion import FrameMotion, MotionModel, OdometryMotion, PlacesWritten, VelocityMotion, check_odometry
from .observation import FramePool, Observation, ObservationModel, check_model, claim_model, feedback_reads_prior
from .particles import ParticleSet, _first_in_edge, get_resampler, normalise_in_place

__all__ = ["Estimate", "LocalizationResult", "Localizer", "check_odometry", "confidence_log_odds",
           "neighbourhood_means"]

#: Floor on the mass outside the answer's neighbourhood when taking log-odds: keeps them
#: finite (and ordered) where the confidence is exactly 1.
_MASS_FLOOR = 1e-300


def check_query_index(query_index, n: int) -> np.ndarray:
    """A run's ``query_index``: one whole number per frame, as int64.

    Raises
    ------
    ShapeMismatchError
        Not one index per frame.
    DataError
        Not whole numbers.
    """
    qi = np.asarray(query_index)
    if qi.shape != (n,):
        raise ShapeMismatchError(f"query_index has shape {qi.shape} for {n} frames; give one index per frame.")
    if qi.dtype.kind not in "iu" and not (qi.dtype.kind == "f" and np.all(np.isfinite(qi)) and np.all(qi == np.rint(qi))):
        raise DataError(f"query_index must hold whole frame numbers; got dtype {qi.dtype} ({qi[:3].tolist()} …).")
    return qi.astype(np.int64)


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



@njit
def _sharpened_cumulative(log_ratio, r_max, power, uniform_share, out):  # pragma: no cover - compiled
    """The ``"sharpened"`` proposal's cumulative distribution:
    ``q = (1 − u) · e^{β r} / Σ e^{β r} + u / n`` (``β = power``, ``u = uniform_share``)."""
    n = log_ratio.shape[0]
    acc = 0.0
    for j in range(n):
        acc += np.exp(power * (log_ratio[j] - r_max))
        out[j] = acc
    scale = (1.0 - uniform_share) / acc
    for j in range(n):
        out[j] = out[j] * scale + uniform_share * (j + 1.0) / n


@njit
def _likelihood_cumulative(log_ratio, out, known_max):  # pragma: no cover - compiled
    """``out[j] = Σ_{i ≤ j} e^{r_i − max r}``; returns ``max r``. ``known_max``: ``max r``
    where the observation found it (the same value), NaN: not known (a pass finds it)."""
    r_max = known_max
    if not r_max == r_max:
        r_max = -np.inf
        for j in range(log_ratio.shape[0]):
            if log_ratio[j] > r_max:
                r_max = log_ratio[j]
    acc = 0.0
    for j in range(log_ratio.shape[0]):
        acc += np.exp(log_ratio[j] - r_max)
        out[j] = acc
    return r_max


@njit(nogil=True)
def _exp_into(log_ratio, r_max, out, lo, hi):  # pragma: no cover - compiled
    """``out[j] = e^{r_j − max r}`` for places ``lo .. hi − 1`` (the floats of
    :func:`_likelihood_cumulative`'s terms)."""
    for j in range(lo, hi):
        out[j] = np.exp(log_ratio[j] - r_max)


@njit(nogil=True)
def _cumulate(out):  # pragma: no cover - compiled
    """``out`` made its own cumulative sum, in place and in order."""
    acc = 0.0
    for j in range(out.shape[0]):
        acc += out[j]
        out[j] = acc


#: Places per thread below which the frame's cumulative likelihood is taken on one thread.
EXP_WORK_PER_THREAD = 1 << 16
#: Places from which the particle filter forms the joint confidence's support on a worker
#: thread while it finishes the frame (:meth:`Localizer._form_support_ahead`).
SUPPORT_AHEAD_PLACES = 1 << 17
_SUPPORT_POOL = []  # the worker thread
_POOL = {}  # worker threads, by their number


def likelihood_cumulative(log_ratio: np.ndarray, out: np.ndarray, known_max: float = math.nan,
                          threads: int | None = None) -> float:
    """``out[j] = Σ_{i ≤ j} e^{r_i − max r}``; returns ``max r`` (``known_max`` where the
    observation found it, NaN: found here).

    The terms (one ``exp`` per place, most of the step's cost on a large map) are taken
    on ``threads`` threads (default: as many as the free cores, :func:`catgraph.grid._cores_free`,
    and the work, :data:`EXP_WORK_PER_THREAD` places each), each on its own places, and
    summed in order on one: the floats of :func:`_likelihood_cumulative` on any number of
    threads."""
    n = log_ratio.shape[0]
    if threads is None and n < 1 << 14:  # a small map: one compiled pass is the cheapest
        return float(_likelihood_cumulative(log_ratio, out, known_max))
    if not known_max == known_max and n:  # numpy's maximum, unless a NaN hides it (the loop skips NaN)
        top = float(np.max(log_ratio))
        known_max = top if top == top else known_max
    if threads is None and n >= 2 * EXP_WORK_PER_THREAD:
        from .differences import _threads_available
        from .grid import _cores_free

        threads = min(_threads_available(), n // EXP_WORK_PER_THREAD)
        threads = _cores_free(threads) if threads > 1 else 1
    if threads is None or threads <= 1:
        return float(_likelihood_cumulative(log_ratio, out, known_max))
    if not known_max == known_max:
        known_max = float(_likelihood_cumulative(log_ratio, out, known_max))
        return known_max
    if threads - 1 not in _POOL:
        from concurrent.futures import ThreadPoolExecutor

        _POOL[threads - 1] = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="catgraph-evidence")
    cuts = [n * k // threads for k in range(threads + 1)]
    jobs = [_POOL[threads - 1].submit(_exp_into, log_ratio, known_max, out, cuts[k], cuts[k + 1])
            for k in range(1, threads)]
    try:
        _exp_into(log_ratio, known_max, out, cuts[0], cuts[1])
    finally:
        for job in jobs:
            job.result()
    _cumulate(out)
    return known_max


@njit
def _birth_kernel(kind, like, proposal, top, log_keep, log_recovery, start, stop, edge, fraction, log_weight,
                  velocity, uniform, out_ptr, first_in, normalise):  # pragma: no cover - compiled
    """The prediction's mixture ``(1 − ε) · particles + ε · uniform``, in place.

    The particles outside the birth slots ``start .. stop`` are normalised and scaled
    by ``1 − ε`` (``log_keep``); the birth slots get places drawn systematically
    (offset ``uniform[0]``) from a proposal ``q`` — ``kind`` 0: the likelihood
    (``like``, cumulative ``e^{r}``), 1: half uniform, half the ``top`` places, 2:
    uniform (``proposal`` is filled for 1 and 2) — each with the importance weight
    ``ε / (n_places · M · q_j)`` (``log_recovery = log ε``). A slot's out-edge comes from
    where its position falls inside the place's interval. Velocities as the grid
    filter's jump: even slots copy the velocity of a particle drawn systematically
    (offset ``uniform[1]``) from the others' weights — the velocity marginal — odd
    slots draw from the prior (stratified, resolved by the motion model).
    ``normalise=False``: the particles outside the birth slots were already given their
    share (and the frame's evidence) by the motion (:meth:`VelocityMotion.move_marginal`,
    which also gives the newborn their velocity): only the births are made."""
    n_all = edge.shape[0]
    n = like.shape[0]
    if not normalise:
        log_keep = -np.inf  # no velocity copies below
    mx = -np.inf
    for i in range(n_all):
        if (i < start or i >= stop) and log_weight[i] > mx:
            mx = log_weight[i]
    n_rest = n_all - (stop - start)
    if not normalise:
        pass
    elif np.isfinite(mx):
        t = 0.0
        for i in range(n_all):
            if i < start or i >= stop:
                t += np.exp(log_weight[i] - mx)
        shift = mx + np.log(t) - log_keep
        for i in range(n_all):
            if i < start or i >= stop:
                log_weight[i] -= shift
    else:  # every particle left the map: start again from uniform weights
        for i in range(n_all):
            if i < start or i >= stop:
                log_weight[i] = log_keep - np.log(n_rest)
    m_slots = stop - start
    if m_slots == 0:
        return
    if kind == 1:
        acc = 0.0
        for j in range(n):
            acc += 0.5 / n
            proposal[j] = acc
        for t in range(top.shape[0]):
            j = top[t]
            if j >= 0:
                for jj in range(j, n):
                    proposal[jj] += 0.5 / top.shape[0]
    elif kind == 2:
        for j in range(n):
            proposal[j] = (j + 1.0) / n
    cumulative = like if kind == 0 else proposal  # kind 3: filled by _sharpened_cumulative
    total = cumulative[n - 1]
    j = 0
    for m in range(m_slots):
        pos = (uniform[0] + m) / m_slots * total
        # the first place from j on whose cumulative exceeds pos (at most n − 1), by
        # bisection: the cumulative never decreases, so a scan from j stops at the same place
        hi = n - 1
        while j < hi:
            mid = (j + hi) // 2
            if cumulative[mid] <= pos:
                j = mid + 1
            else:
                hi = mid
        low = cumulative[j - 1] if j > 0 else 0.0
        width = cumulative[j] - low
        within = (pos - low) / width if width > 0 else 0.0
        k = start + m
        n_out = out_ptr[j + 1] - out_ptr[j]
        if n_out > 0:
            edge[k] = out_ptr[j] + min(int(within * n_out), n_out - 1)
            fraction[k] = 0.0
        else:
            edge[k] = first_in[j]
            fraction[k] = 1.0
        log_weight[k] = log_recovery - np.log(n * m_slots * width / total)
        velocity[k] = -1 - m // 2  # the prior, stratified (even slots are overwritten below)
    n_copy = (m_slots + 1) // 2 if normalise else 0
    keep = np.exp(log_keep)
    acc = 0.0
    c = -1
    for t in range(n_copy):
        pos = (uniform[1] + t) / n_copy * keep
        while acc <= pos and c < n_all - 1:
            c += 1
            if c < start or c >= stop:
                acc += np.exp(log_weight[c])
        if c >= 0 and (c < start or c >= stop) and velocity[c] >= 0:
            velocity[start + 2 * t] = velocity[c]


@njit
def _reweight_kernel(edge, fraction, log_weight, source, target, log_ratio, start, stop, log_recovery, like, weight,
                     mass, marginal, log_scale, marginal_mass, log_graduate, terms):  # pragma: no cover - compiled
    """Reweight every particle, normalise, and sum the posterior mass per place.

    ``log_weight`` holds the prediction (:func:`_birth_kernel`); particle ``i`` gains
    ``ℓ_i`` (its interpolated log-ratio). The newborn particles (slots ``start ..
    stop``) are then scaled to carry exactly the recovery share's posterior mass,
    ``log_recovery = log(ε · mean_j e^{r_j})`` (``-inf``: none), so only *where* a jump
    went is sampled, never *how likely* it was. ``mass[j]`` gets the other particles
    plus that share's exact distribution ``∝ e^{r_j}`` (``like``, cumulative;
    Rao–Blackwellised), so the outside of any neighbourhood keeps the mass of a jump
    there, as in the grid filter. Returns ``(log E_map, ESS)``, ``E_map = Σ prior · e^ℓ``.

    ``marginal``: the particles outside the newborn slots already carry the frame's
    evidence in units of ``e^{log_scale}`` (:meth:`VelocityMotion.move_marginal`), and
    their place masses are ``marginal_mass`` (their mixtures before the draw, same
    units) instead of where they landed. The place masses are then left to
    :func:`_posterior_kernel` (one pass with the place posterior and the answer): ``terms``
    gets its factors ``(e^{log_scale − log E_map}, share, 1)``, ``share`` the recovery
    share's mass per unit of ``like``, 0 without; ``terms[2] = 0``: ``mass`` is written
    here."""
    k = edge.shape[0]
    terms[2] = 0.0
    for i in range(k):
        if marginal and (i < start or i >= stop):
            log_weight[i] += log_scale
            continue
        e = edge[i]
        f = fraction[i]
        if f == 0.0:  # at a place: its ratio alone (an impossible neighbour, -inf, must not make 0 · -inf)
            log_weight[i] += log_ratio[source[e]]
        elif f == 1.0:
            log_weight[i] += log_ratio[target[e]]
        else:
            log_weight[i] += (1.0 - f) * log_ratio[source[e]] + f * log_ratio[target[e]]
    mx = -np.inf
    for i in range(k):
        if (i < start or i >= stop) and log_weight[i] > mx:
            mx = log_weight[i]
    log_rest = -np.inf
    if np.isfinite(mx):
        t = 0.0
        for i in range(k):
            if i < start or i >= stop:
                t += np.exp(log_weight[i] - mx)
        log_rest = mx + np.log(t)
    if stop > start and np.isfinite(log_recovery):
        mr = -np.inf
        for i in range(start, stop):
            if log_weight[i] > mr:
                mr = log_weight[i]
        tr = 0.0
        for i in range(start, stop):
            tr += np.exp(log_weight[i] - mr)
        shift = log_recovery + log_graduate - (mr + np.log(tr))
        for i in range(start, stop):
            log_weight[i] += shift
    else:
        log_recovery = -np.inf
        for i in range(start, stop):
            log_weight[i] = -np.inf
    log_map = np.logaddexp(log_rest, log_recovery)
    if not (marginal and np.isfinite(log_map)):
        mass[:] = 0.0
    if not np.isfinite(log_map):  # nothing left: uniform, as normalise_in_place does
        lse, ess = normalise_in_place(log_weight, weight)
        for i in range(k):
            e = edge[i]
            mass[source[e] if fraction[i] < 0.5 else target[e]] += weight[i]
        return lse, ess
    sq = 0.0
    for i in range(k):
        log_weight[i] -= log_map
        w = np.exp(log_weight[i])
        weight[i] = w
        sq += w * w
        if (i < start or i >= stop) and not marginal:
            e = edge[i]
            mass[source[e] if fraction[i] < 0.5 else target[e]] += w
    # the marginal masses, then the recovery share's, added place by place in one pass
    scale = np.exp(log_scale - log_map) if marginal else 0.0
    recover = np.isfinite(log_recovery)
    share = np.exp(log_recovery - log_map) / like[like.shape[0] - 1] if recover else 0.0
    if marginal:  # left to _posterior_kernel
        terms[0] = scale
        terms[1] = share
        terms[2] = 1.0 if recover else 0.5
    elif recover:
        below = 0.0
        for j in range(like.shape[0]):
            mass[j] += share * (like[j] - below)
            below = like[j]
    return log_map, 1.0 / sq


@njit
def _posterior_kernel(marginal_mass, scale, like, share, recover, mass, posterior, keep):  # pragma: no cover
    """The marginal step's place masses, the place posterior and the answer in one pass:
    ``mass[j] = marginal_mass[j] · scale + share · (like[j] − like[j − 1])`` (the recovery
    share's exact masses, where ``recover``), ``posterior[j] = mass[j] · keep`` (``keep =
    1 − P(new)``) — the floats of :func:`_reweight_kernel`'s masses and of numpy's product —
    and returns the first place of the largest mass (``np.argmax``: the first NaN, if any)."""
    n = mass.shape[0]
    best = 0
    top = -np.inf
    below = 0.0
    for j in range(n):
        m = marginal_mass[j] * scale
        if recover:
            m += share * (like[j] - below)
            below = like[j]
        mass[j] = m
        posterior[j] = m * keep
        if m > top or (m != m and top == top) or j == 0:
            best = j
            top = m
    return best


@njit
def _place_mass_kernel(edge, fraction, weight, source, target, out, skip_start, skip_stop):  # pragma: no cover
    """``out[j] = Σ_{i: place(i) = j} weight[i]`` over the particles outside
    ``skip_start .. skip_stop``; a particle's place is the nearer of its edge's two."""
    out[:] = 0.0
    for i in range(edge.shape[0]):
        if skip_start <= i < skip_stop:
            continue
        e = edge[i]
        out[source[e] if fraction[i] < 0.5 else target[e]] += weight[i]


@njit
def _resample_pool(weight, n_out, start, stop, u, edge, fraction, velocity, log_weight, edge_tmp, fraction_tmp,
                   velocity_tmp, spread, spread_tmp):  # pragma: no cover - compiled
    """Systematic resampling of the pool — slots ``0 .. n_out`` and ``start .. stop`` — into
    slots ``0 .. n_out``, each then weighing the pool's mass ``/ n_out``; the other
    slots keep their particles and weights. The indices are the ones
    :func:`~catgraph.particles.systematic_resample` gives the pool's weights for the
    same uniform ``u``, without building them; ``spread`` (``(n, n_bins)``, the velocity
    distributions; ``(n, 0)`` without) is copied with them. Returns the pool's mass."""
    total = 0.0
    for i in range(n_out):
        total += weight[i]
    for i in range(start, stop):
        total += weight[i]
    if not total > 0.0:
        for i in range(n_out):
            log_weight[i] = -np.inf
            weight[i] = 0.0
        return 0.0
    size = n_out + stop - start
    acc = 0.0
    p = -1
    i = 0
    for k in range(n_out):
        pos = (u + k) / n_out
        while p < size - 1 and acc / total <= pos:
            p += 1
            i = p if p < n_out else start + p - n_out
            acc += weight[i]
        edge_tmp[k] = edge[i]
        fraction_tmp[k] = fraction[i]
        velocity_tmp[k] = velocity[i]
        for b in range(spread.shape[1]):
            spread_tmp[k, b] = spread[i, b]
    each = total / n_out
    for k in range(n_out):
        edge[k] = edge_tmp[k]
        fraction[k] = fraction_tmp[k]
        velocity[k] = velocity_tmp[k]
        for b in range(spread.shape[1]):
            spread[k, b] = spread_tmp[k, b]
        weight[k] = each
        log_weight[k] = np.log(each)
    return total


@njit
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


@njit
def _window_means(values, lo, hi, out):  # pragma: no cover - compiled
    """``out[j] = mean(values[lo[j]:hi[j]])`` for windows whose ends never move back
    (``lo``, ``hi`` non-decreasing): a running sum, recomputed from scratch every 64
    places so that round-off cannot build up; returns ``Σ out``."""
    total = 0.0
    acc = 0.0
    a = 0
    b = 0
    for j in range(values.shape[0]):
        if j % 64 == 0:
            acc = 0.0
            for k in range(lo[j], hi[j]):
                acc += values[k]
            a = lo[j]
            b = hi[j]
        else:
            while b < hi[j]:
                acc += values[b]
                b += 1
            while a < lo[j]:
                acc -= values[a]
                a += 1
        v = acc / (hi[j] - lo[j])
        if v < 0.0:  # round-off where a large mass has just left the window
            v = 0.0
        out[j] = v
        total += v
    return total


@njit
def _list_means(values, ptr, index, out):  # pragma: no cover - compiled
    """``out[j] = mean(values[index[ptr[j]:ptr[j + 1]]])``; returns ``Σ out``."""
    total = 0.0
    for j in range(values.shape[0]):
        acc = 0.0
        for t in range(ptr[j], ptr[j + 1]):
            acc += values[index[t]]
        out[j] = acc / max(ptr[j + 1] - ptr[j], 1)
        total += out[j]
    return total


def confidence_neighbourhoods(graph, confidence_radius: int, confidence_radius_m: float | None, tree, route,
                               route_radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """Each place's confidence neighbourhood, the one a filter counts around an answer at
    that place (:class:`Localizer` and :class:`~catgraph.grid.GridLocalizer` alike).

    Parameters
    ----------
    graph : PlaceGraph
    confidence_radius : int
        Places either side (by index, where ``route`` is None).
    confidence_radius_m : float or None
        Metres around the place (needs ``tree``, a ``cKDTree`` of the positions).
    tree : scipy.spatial.cKDTree or None
    route : ndarray of float64 or None
        The places' route distances where they are non-decreasing.
    route_radius : float
        Route distance either side (with ``route``).

    Returns
    -------
    tuple or None
        ``(lo, hi, None)``: places ``lo[j] .. hi[j] − 1`` (both ends non-decreasing in
        ``j``; int32 where the places' indices fit it, half the memory of int64), or
        ``(ptr, index, True)``, a CSR list (a metric radius); ``None`` where every
        neighbourhood is the place alone (nothing to smooth).
    """
    n = graph.n_places
    j = np.arange(n)
    if confidence_radius_m is not None:
        lists = tree.query_ball_point(graph.positions, confidence_radius_m)
        ptr = np.zeros(n + 1, dtype=np.int64)
        ptr[1:] = np.cumsum([len(x) for x in lists])
        index = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if n else ptr[:0]
        return ptr, index, True
    if route is not None:
        lo = np.searchsorted(route, route - route_radius, "left")
        hi = np.searchsorted(route, route + route_radius, "right")
    else:
        lo = np.maximum(j - confidence_radius, 0)
        hi = np.minimum(j + confidence_radius + 1, n)
    if np.all(hi - lo == 1):
        return None
    index = np.int32 if n < np.iinfo(np.int32).max else np.int64
    return lo.astype(index), hi.astype(index), None


def neighbourhood_means(mass: np.ndarray, first: np.ndarray, second: np.ndarray, is_list) -> np.ndarray:
    """Each place's mean mass over its neighbourhood, rescaled to the total of ``mass``.

    Parameters
    ----------
    mass : ndarray of float64, shape (n_places,)
    first, second : ndarray of int64
        ``lo, hi`` (place ``j``'s neighbourhood is ``lo[j] .. hi[j] − 1``, both
        non-decreasing in ``j``) or, with
        ``is_list``, ``ptr, index`` (a CSR list: ``index[ptr[j]:ptr[j + 1]]``).
    is_list : bool or None

    Returns
    -------
    ndarray of float64, shape (n_places,)
        ``m̃_j = c · mean_{k ∈ N(j)} m_k``, ``c`` such that ``Σ m̃ = Σ m``.
    """
    return _smoothed(mass, first, second, is_list)[0]


def _smoothed(mass: np.ndarray, first: np.ndarray, second: np.ndarray, is_list,
              out: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """:func:`neighbourhood_means` (into ``out``, float64 of the length of ``mass``, if
    given) and its maximum, taken once for every reader of the feedback (a maximum
    tracked inside the compiled window pass was measured to slow that latency-bound loop
    by more than a numpy pass costs)."""
    values = np.ascontiguousarray(mass, dtype=np.float64)
    out = np.empty_like(values) if out is None else out
    total = (_list_means if is_list else _window_means)(values, first, second, out)
    want = float(values.sum())
    if total > 0.0 and want > 0.0:
        out *= want / total
    return out, float(out.max())


def _all_finite(x: np.ndarray) -> bool:
    """``np.isfinite(x).all()`` of a contiguous float64 row."""
    return bool(all_finite(x))


def _check_observation(observation, n_places: int) -> np.ndarray:
    """Check a row once per step (1-D, real, finite, one value per place); return it as
    a :class:`~catgraph.observation.CheckedRow`, which models do not scan again."""
    from .observation import CheckedRow

    if type(observation) is CheckedRow and observation.ndim == 1 and len(observation) == n_places:
        return observation
    if type(observation) is np.ndarray and observation.dtype == np.float64 and observation.shape == (n_places,) \
            and observation.flags.c_contiguous and _all_finite(observation):
        # the usual row: what check_array would accept as it is (one compiled pass, no temporary)
        return observation.view(CheckedRow)
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


#: Where recovery particles are drawn (see the module docstring); the first is the default.
PROPOSALS = ("likelihood", "best", "uniform", "sharpened")
_PROPOSAL_CODE = {name: k for k, name in enumerate(PROPOSALS)}


class Localizer(TwinReadings):
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
        Without recovery: resample when ESS < ``ess_threshold · n_particles`` (with
        recovery the cloud and the oldest young generation are resampled every step).
    recovery : float in [0, 1)
        ``ε``: probability per frame of a jump anywhere on the map, the grid filter's
        ``recovery``.
    learn_recovery : bool
        Learn ``ε`` online from the frames (the grid filter's online EM, shrunk towards
        ``recovery``); its current value is ``recovery_``.
    redraw_fraction : float in [0, 1)
        Particles born each step to carry the recovery share, as a fraction of
        ``n_particles`` (0 turns recovery off).
    recovery_frames : int
        Frames a generation of recovery particles is weighed before it is first
        resampled (capped so that the young generations hold at most half the
        particles).
    proposal : {"likelihood", "best", "uniform", "sharpened"}
        Where recovery particles are born: ``∝ e^{r}`` (the frame's likelihood), half
        uniform and half the ``proposal_top_k`` best places, uniform, or
        ``(1 − u) · e^{β r} / Σ e^{β r} + u / n`` (``β = proposal_power``,
        ``u = proposal_uniform``). Importance weights make every choice target the same
        posterior (the grid filter's); they differ in variance.
    proposal_top_k : int
        Number of best places the ``"best"`` proposal draws from.
    proposal_power : float ≥ 0
        ``β`` of the ``"sharpened"`` proposal (1: the likelihood; larger: the births
        gather on the frame's best places).
    proposal_uniform : float in (0, 1]
        Uniform share ``u`` of the ``"sharpened"`` proposal; positive, so that every
        place can be proposed and the importance weights stay bounded.
    new_place_prior : float in [0, 1), optional
        Per-step probability of entering unmapped space (0 disables the new place);
        default: the grid filter's (:class:`~catgraph.grid.GridLocalizer`).
    new_place_stay : float in [0, 1)
        Per-step probability of staying in unmapped space.
    confidence_radius : int
        Places either side of the answer counted in its confidence, in mean spacings of
        the map along the route (the grid filter's neighbourhood; on a map of evenly
        spaced frames: places).
    confidence_radius_m : float, optional
        Use a metric radius instead (needs graph positions).
    confidence_score : {"joint", "posterior"}
        What :attr:`Estimate.score` ranks by: ``"joint"`` = the smaller of the posterior
        log-odds and the observation's recent support at the answer (where the model
        gives one), ``"posterior"`` = the posterior log-odds alone.
    marginal_velocity : bool
        Rao–Blackwellise the velocity (default): with a
        :class:`~catgraph.motion.VelocityMotion` on a route without junctions and a
        frame without odometry, each particle carries a distribution over the grid
        filter's state bins (a fractional speed's phases each), predicts as the grid
        filter does from its one place, and moves with the
        frame's evidence (:meth:`~catgraph.motion.VelocityMotion.move_marginal`); the
        place masses are the particles' mixtures before their draw. ``False``, junction
        graphs and odometry: one sampled velocity bin per particle.
    smooth_feedback : bool
        Hand the observation model (``FilterFeedback.posterior``) each place's mean
        posterior mass over its confidence neighbourhood (``confidence_radius`` or
        ``confidence_radius_m``; :func:`neighbourhood_means`) instead of the mass at the
        place alone: far less Monte Carlo noise in what the model learns from (see the
        module docstring). ``Localizer.place_posterior_`` and the estimates are unchanged.
    jump_graduation : float in (0, 1]
        Below 1 (with the velocity marginalised and ``proposal="likelihood"``), the
        recovery share is kept exactly on a *jump grid* over (place, velocity bin) that
        predicts as the grid filter (:func:`catgraph.grid.predict`) and weighs every
        frame; each step this fraction of its mass is handed to the newborn generation,
        drawn systematically from it (equal weights, the grid's velocities at their place),
        and the rest stays in the grid. A jump's particles are then born where several
        frames of evidence already agree, with their mass, instead of where the one frame
        points (see the module docstring). 1: no grid (births from the frame alone).
        Costs one grid prediction per step, O(n_places · n_bins): one compiled pass on a
        route by place index (about one grid-filter step; the particle step ×1.6 at 10⁴
        and ×1.85 at 10⁵ places on one thread, ``docs/particle_filter.md``), else
        :func:`catgraph.grid.predict`.
    repeat_prior : float in [0, 1]
        The prior probability that the query stands still while its frame comes again
        unchanged (the grid filter's ``repeat_prior``, :mod:`catgraph._twin`): from the first
        frame equal to the previous one (the same row, without odometry) the filter runs a
        twin that stands still through every run of them beside itself, which moves on, and
        answers with their mixture, each weighed by its evidence frame by frame from this
        prior (``repeat_log_odds_``); once the lighter reading's weight times the distance
        between the two is at most one particle's share of the cloud (:data:`TWIN_PARTICLES`),
        it goes until the next repeat (the heavier kept, with what it learned). Default 0:
        off (the registry's ``filter`` method: :data:`catgraph.methods.REPEAT_PRIOR`). Time
        and memory while the twin lives: twice the filter's.
    seed : int, Generator or None

    Attributes
    ----------
    particles_ : ParticleSet
        All ``n_particles`` particles (the cloud, then the young generations), weighted:
        the filter's fixed arrays.
    new_place_probability_ : float
    recovery_ : float
        The jump rate ``ε`` (learned, or ``recovery``). Each frame's prediction uses it
        modulated by that frame's jump evidence (``Observation.jump_evidence``,
        :mod:`catgraph.jumps`).
    place_posterior_ : ndarray of float64, shape (n_places,)
        With ``repeat_prior``: the two readings' mixture (as the answer and
        ``new_place_probability_``; ``particles_`` are the moving reading's).
    repeat_log_odds_ : float
        With ``repeat_prior``: the log-odds that the query stands still through its repeated
        frames against that it moves on.
    frame_log_evidence_ : float
        The latest frame's log evidence, ``log(P(new)' e^{r_new} + (1 − P(new)') Σ prior ·
        e^{ℓ})`` (the particles' estimate, ``P(new)'`` the new place's prior for the frame);
        0 for a frame without information.
    n_steps_ : int
    """

    def __init__(self, graph: PlaceGraph, model: ObservationModel, n_particles: int = 2000,
                 motion: MotionModel | None = None, resampler: str = "systematic", ess_threshold: float = 0.5,
                 recovery: float = 0.05, learn_recovery: bool = True, redraw_fraction: float = 0.1,
                 recovery_frames: int = 8, proposal: str = "likelihood",
                 proposal_top_k: int = 10, proposal_power: float = 8.0, proposal_uniform: float = 0.5,
                 new_place_prior: float | None = None, new_place_stay: float = 0.8,
                 confidence_radius: int = 2, confidence_radius_m: float | None = None,
                 confidence_score: str = "joint", marginal_velocity: bool = True, smooth_feedback: bool = True,
                 jump_graduation: float = 1.0, repeat_prior: float = 0.0,
                 seed: int | np.random.Generator | None = 0) -> None:
        self.graph = graph
        self.model = model
        self.n_particles = n_particles
        self.motion = motion
        self.resampler = resampler
        self.ess_threshold = ess_threshold
        self.recovery = recovery
        self.learn_recovery = learn_recovery
        self.redraw_fraction = redraw_fraction
        self.recovery_frames = recovery_frames
        self.proposal = proposal
        self.proposal_top_k = proposal_top_k
        self.proposal_power = proposal_power
        self.proposal_uniform = proposal_uniform
        self.new_place_prior = new_place_prior
        self.new_place_stay = new_place_stay
        self.confidence_radius = confidence_radius
        self.confidence_radius_m = confidence_radius_m
        self.confidence_score = confidence_score
        self.marginal_velocity = marginal_velocity
        self.smooth_feedback = smooth_feedback
        self.jump_graduation = jump_graduation
        self.repeat_prior = repeat_prior
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
        if self.motion is not None and not isinstance(self.motion, MotionModel):
            raise InvalidParameterError(f"The 'motion' parameter of {owner} must be a MotionModel (such as "
                                        f"VelocityMotion()) or None. Got {self.motion!r} instead.")
        check_scalar(self.ess_threshold, "ess_threshold", owner, float, 0.0, 1.0)
        check_scalar(self.recovery, "recovery", owner, float, 0.0, 1.0, True, False)
        for flag in ("learn_recovery", "marginal_velocity", "smooth_feedback"):
            if not isinstance(getattr(self, flag), (bool, np.bool_)):
                raise InvalidParameterError(f"The '{flag}' parameter of {owner} must be a bool. "
                                            f"Got {getattr(self, flag)!r} instead.")
        check_scalar(self.redraw_fraction, "redraw_fraction", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.proposal_top_k, "proposal_top_k", owner, int, 1)
        check_scalar(self.proposal_power, "proposal_power", owner, float, 0.0)
        check_scalar(self.proposal_uniform, "proposal_uniform", owner, float, 0.0, 1.0, False, True)
        check_scalar(self.jump_graduation, "jump_graduation", owner, float, 0.0, 1.0, False, True)
        if self.jump_graduation < 1.0 and self.proposal != "likelihood":
            raise InvalidParameterError(
                f"The 'jump_graduation' parameter of {owner} below 1 draws the births from the jump grid, which "
                f"needs proposal='likelihood'. Got proposal={self.proposal!r} instead.")
        check_scalar(self.recovery_frames, "recovery_frames", owner, int, 1)
        check_scalar(self.repeat_prior, "repeat_prior", owner, float, 0.0, 1.0)
        if self.new_place_prior is None:  # the grid filter's, so that both filters share one model
            import inspect

            from .grid import GridLocalizer

            self._new_place_prior = float(inspect.signature(GridLocalizer).parameters["new_place_prior"].default)
        else:
            check_scalar(self.new_place_prior, "new_place_prior", owner, float, 0.0, 1.0, True, False)
            self._new_place_prior = float(self.new_place_prior)
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

    def marginal_applies(self) -> bool:
        """Whether the particles carry velocity distributions on this graph (``marginal_velocity``
        with :class:`~catgraph.motion.VelocityMotion` on a route without junctions); the jump
        grid (``jump_graduation < 1``) rides on them, on the frames without odometry."""
        return bool(self.marginal_velocity) and isinstance(self.motion, VelocityMotion) and \
            self.motion.supports_marginal(self.graph)

    def reset(self) -> "Localizer":
        """Start afresh: particles uniform over the graph, ``P(new) = 0``, model reset.

        Every array a step touches is allocated here, once: the particles (the cloud,
        then ``recovery_frames`` generations of ``M = redraw_fraction · n_particles``
        young particles), the weights, the resampling and proposal buffers."""
        self._validate()
        g, n = self.graph, self.n_particles
        from ._validation import check_memory

        # the particles' edge, fraction, weights, velocities and their scratch: about 100 bytes each
        check_memory(100.0 * n, f"{n} particles", "use fewer particles (2,000 is the default)")
        self._rng = as_generator(self.seed) if not isinstance(self.seed, np.random.Generator) else self.seed
        m = int(round(self.redraw_fraction * n)) if self.recovery > 0 and n >= 2 else 0
        m = min(m, n // 2)
        k = max(1, min(self.recovery_frames, (n // 2) // m)) if m > 0 else 0
        self._births, self._generations = m, k
        self._n_cloud = n - m * k
        cloud = ParticleSet.uniform(g, n, self._rng)
        self._edge, self._fraction, self._log_weight = cloud.edge, cloud.fraction, cloud.log_weight
        self._velocity = -1 - np.arange(n, dtype=np.int64)  # stratified draws from the velocity prior
        self.particles_ = ParticleSet(self._edge, self._fraction, self._log_weight, self._velocity)
        self._weight = np.exp(self._log_weight)
        self._gathered = (np.empty(n, dtype=np.int64), np.empty(n), np.empty(n, dtype=np.int64))
        self._uniform = np.empty(3)
        self._proposal = np.empty(g.n_places)
        self._like = np.empty(g.n_places)
        self._mass = np.empty(g.n_places)
        self._first_in = _first_in_edge(g)
        self._top = np.full(min(self.proposal_top_k, g.n_places), -1, dtype=np.int64)
        self._newborn = (0, 0)
        self.recovery_ = float(self.recovery)
        self._jumps, self._frames = 0.0, 0.0
        self._log_like_mean = 0.0
        self._log_recovery = -math.inf
        self.new_place_probability_ = 0.0
        self.n_steps_ = 0
        self._advanced = 0  # frames this reading moved and weighed its particles on (its births' schedule)
        self._log_new, self._log_map = -math.inf, 0.0
        self._reset_twin()
        self._support = None
        self._no_ratio = np.zeros(g.n_places)
        self._motions = (self.motion or FrameMotion(), self.motion or OdometryMotion())
        self._marginal = self.marginal_applies()
        # velocity distributions over the motion's state bins (marginal mode; a fractional speed
        # has one bin per phase)
        nb = len(self.motion._owner) if self._marginal else 0
        self._velocity_prior = self.motion._bin_prior.copy() if self._marginal else np.ones(0)
        self._spread = np.empty((n, nb))
        self._spread[:] = self._velocity_prior
        self._gathered = (*self._gathered, np.empty((n, nb)))
        self._velocity_marginal = self._velocity_prior.copy()
        self._e = np.empty(g.n_places)
        self._e_dense = False
        self._pool = FramePool(6)  # the per-frame posteriors and predicted masses handed out
        self._marginal_mass = np.empty(g.n_places)
        self._marginal_prior = np.empty(g.n_places)
        # where the particles' reach can be far smaller than the map (else a pass over every place
        # is cheaper than listing places): the places the marginal motion wrote into the two (0
        # elsewhere; new arrays: all of them), and the frame's e^{r − max r} only where it reads
        self._sparse_ratio = self._marginal and g.n_places > n * (2 * self.motion._reach + 1)
        self._written = PlacesWritten(g.n_places, 0) if self._sparse_ratio else None
        self._deferred = None  # the place masses' terms, where the reweighting left them to _summarise
        self._terms = np.zeros(3)
        self._marginal_step = False
        # the jump grid (jump_graduation < 1): the recent jumps' exact mass over (place, velocity bin)
        self._jump_grid = self._marginal and self.jump_graduation < 1.0 and self._births > 0
        self._jumps_mass = 0.0
        self._jumps_predicted = None
        if self._jump_grid:
            self._reset_jump_grid(nb)
        rd = np.asarray(g.route_distance, dtype=np.float64)
        monotone = len(rd) < 2 or bool(np.all(np.diff(rd) >= 0))
        self._route = rd if monotone else None  # the confidence neighbourhood along the route
        spacing = float(g.frame_spacing)
        self._route_radius = self.confidence_radius * spacing + 1e-9 * spacing
        claim_model(self.model, self)
        self.model.reset()
        self._has_feedback = callable(getattr(self.model, "feedback", None))
        if self.confidence_radius_m is not None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.graph.positions)
        self._neighbourhoods = self._feedback_neighbourhoods() if self._has_feedback and self.smooth_feedback \
            else None
        return self

    def _reset_jump_grid(self, nb: int) -> None:
        """The jump grid's arrays (two grids over (place, velocity bin), the one the last
        step wrote and the one the next writes), its sums and the route it moves along."""
        from .grid import route_neighbours
        from ._jump_kernels import block_starts, line_segments, segment_edges

        g, motion = self.graph, self.motion
        n = g.n_places
        # velocity-major, (n_bins, n_places): the compiled pass runs along the places
        self._jumps_buffers = (np.zeros((nb, n)), np.zeros((nb, n)))
        # J_t = _jumps_unit · _jumps_t (the grid after the frame, before the births take their
        # share), the jump state after the reweighting _jumps_scale · _jumps_t
        self._jumps_t = self._jumps_buffers[0]
        self._jumps_unit = 1.0
        self._jumps_scale = 0.0
        self._jumps_total = 0.0  # Σ J_t
        self._jumps_stored = 0.0  # Σ _jumps_t
        self._jumps_predicted = np.empty(n)
        self._jumps_velocity = np.zeros(nb)  # Σ_j J_t[b, j]
        nbrs = g.__dict__.get("_jump_neighbours")
        if nbrs is None:
            nbrs = route_neighbours(g)
            object.__setattr__(g, "_jump_neighbours", nbrs)
        self._jumps_neighbours = nbrs
        self._jumps_moves = motion._bin_moves
        whole, frac = self._jumps_moves[:2]
        self._jumps_reach = int(whole.max()) if len(whole) else 0
        seg = line_segments(nbrs[0], nbrs[1])
        hops = int((whole + (frac > 0)).max()) if len(whole) else 0
        # the route by place index (the compiled pass), or None (catgraph.grid.predict)
        self._jumps_line = None if seg is None else (seg, segment_edges(seg, hops),
                                                     block_starts(seg, self._jumps_reach))
        blocks = 1 if seg is None else len(self._jumps_line[2]) - 1
        self._jumps_bins = np.zeros((blocks, nb))
        self._jumps_totals = np.empty(blocks)

    def jump_state(self) -> np.ndarray | None:
        """The jump grid's mass over (place, velocity bin) after the latest step, in the
        units of the particles' normalised weights (``None`` without a jump grid)."""
        if not getattr(self, "_jump_grid", False):
            return None
        if self._jumps_mass == 0.0:
            return np.zeros(self._jumps_t.shape[::-1])
        return self._jumps_t.T * self._jumps_scale

    def _feedback_neighbourhoods(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """Each place's confidence neighbourhood (:func:`confidence_neighbourhoods`)."""
        return confidence_neighbourhoods(self.graph, self.confidence_radius, self.confidence_radius_m,
                                         getattr(self, "_tree", None), self._route, self._route_radius)

    def _generation(self, step: int) -> tuple[int, int]:
        """Slots of the young generation ``step mod recovery_frames``."""
        start = self._n_cloud + (step % self._generations) * self._births
        return start, start + self._births

    # ------------------------------------------------------------------ one step
    def step(self, observation: np.ndarray, odometry: float | None = None) -> Estimate:
        """Process one query frame.

        Parameters
        ----------
        observation : ndarray, shape (n_places,)
            The frame's difference to every reference place (what the model observes).
        odometry : float, optional
            Distance travelled since the previous frame (graph units). Ignored on the
            first frame (there is no previous one): a first frame given its odometry
            runs as one given ``None``.

        Returns
        -------
        Estimate
        """
        if not hasattr(self, "particles_"):
            self.reset()
        row = _check_observation(observation, self.graph.n_places)
        odometry = check_odometry(odometry)
        if self.n_steps_ == 0:
            odometry = None  # ignored, as a query's odometry[0] (the marginal start must not hang on it)
        check_model(self.model, self)
        repeated = self._repeated(row, odometry)
        self._log_ratio = None  # the previous frame's ratios: the model may reuse their array now
        obs = self.model.observe(row)
        twin = self._twin
        if repeated and obs.informative and twin is None and self.repeat_prior > 0.0:
            twin = self._twin = self._fork()  # this frame's prior: the robot where the run began
        pending = []
        try:
            prior, ess, resampled = self._advance(obs, odometry, pending)
            if twin is not None and not repeated:  # the twin stands still through the repeats
                twin._advance(obs, odometry)
                twin._resolve(twin._mass)
                twin._log_ratio = None
                twin.recovery_ = twin._prior_rate
                twin.n_steps_ += 1
                self._weigh_twin(twin)
            ahead = pending[0] if pending else None
            estimate, near = self._summarise(self._mass, ess, resampled, joint=ahead is None)
            if twin is not None and not repeated:
                self._settle(twin)
            self._feedback(prior, near)
            if ahead is not None:
                ahead.result()  # the support's scores and moments (and the worker's error, if any)
                estimate = self._joint_score(estimate, near)
        finally:
            if pending and pending[0] is not None:  # done before the model's matcher can step again
                from concurrent.futures import wait

                wait(pending)
        self.recovery_ = self._prior_rate
        self.n_steps_ += 1
        return estimate

    def _advance(self, obs: Observation, odometry: float | None, pending: list | None = None):
        """Predict and weigh the particles with the frame's observation ``obs``; returns the
        prediction's place masses where the model's feedback reads them (else None), the
        ESS and whether the cloud was resampled. ``pending``: gets the future of the
        support's scores formed on a worker thread (:meth:`_form_support_ahead`; None: none)."""
        # the frame's jump rate while the frame is processed (catgraph.jumps); the learned one after it
        self._prior_rate = self.recovery_
        self.recovery_ = frame_jump_rate(self._prior_rate, obs.jump_evidence)
        self._support = obs.support if obs.informative else None
        self.frame_log_evidence_ = 0.0
        self._evidence(obs)
        if pending is not None:
            pending.append(self._form_support_ahead())  # after the evidence, whose exp terms take both cores
        self._move(odometry)
        self._inject()
        # the prediction's place masses, where the model's feedback reads them
        prior = self._predicted_mass() if self._has_feedback and feedback_reads_prior(self.model) else None
        ess = self._reweight(obs)
        resampled = self._resample_if_degenerate(ess)
        self._advanced += 1
        return prior, ess, resampled

    def _form_support_ahead(self):
        """The joint confidence score reads the recent support at the answer's places,
        whose scores and moments are passes over every place (about 3 ms at 10⁶ places):
        on a large map, with a core free (:func:`catgraph.grid._cores_free`), they are
        formed on a worker thread while the particles move and are weighed, the answer is
        summarised and the model is told (the future; None: formed where read, as
        before). The same floats either way."""
        from .observation import RecentSupport

        support = self._support
        if self.confidence_score != "joint" or type(support) is not RecentSupport \
                or self.graph.n_places < SUPPORT_AHEAD_PLACES:
            return None
        from .differences import _threads_available
        from .grid import _cores_free

        if _cores_free(_threads_available()) < 2:
            return None
        if not _SUPPORT_POOL:
            from concurrent.futures import ThreadPoolExecutor

            _SUPPORT_POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="catgraph-support"))
        return _SUPPORT_POOL[0].submit(support.form)

    def _predicted_mass(self) -> np.ndarray:
        """The prediction's place masses, ``(1 − ε) · particles + ε / n_places`` (the
        grid's ``prior_``): the particles', plus the recovery share exactly."""
        # a fresh array every frame: the feedback hands it to the model as it is
        g = self.graph
        born = self._newborn[1] > self._newborn[0]
        prior = self._pool.take(g.n_places)
        if self._marginal_step:  # the copy and the recovery share in one pass
            if born and self._jumps_predicted is not None and self._jump_grid:
                return np.add(self._marginal_prior, self._jumps_predicted, out=prior)
            if born:
                return np.add(self._marginal_prior, self.recovery_ / g.n_places, out=prior)
            prior[:] = self._marginal_prior
            return prior
        np.exp(self._log_weight, out=self._weight)
        _place_mass_kernel(self._edge, self._fraction, self._weight, g.source, g.target, prior, *self._newborn)
        if born:
            prior += self.recovery_ / g.n_places
        return prior

    def _feedback(self, prior, near) -> None:
        """Tell the model the filter's prediction and answer (``ObservationModel.feedback``);
        the posterior smoothed over the confidence neighbourhoods (``smooth_feedback``)."""
        if self._has_feedback:
            from .observation import FilterFeedback

            posterior, top = self.place_posterior_, None
            if self._neighbourhoods is not None:
                posterior, top = _smoothed(posterior, *self._neighbourhoods, out=self._pool.take(len(posterior)))
            # prior: fresh every frame (None where the model does not read it)
            self.model.feedback(FilterFeedback(prior, posterior, near, top))

    def _evidence(self, obs: Observation) -> None:
        """The frame's log-ratios, their cumulative ``e^{r − max r}`` (the likelihood
        proposal) and the recovery share's log-mass ``log ε + log mean_j e^{r_j}``."""
        g = self.graph
        log_ratio = obs.log_ratio if obs.informative else self._no_ratio
        self._log_ratio = log_ratio = np.ascontiguousarray(log_ratio, dtype=np.float64)
        known = obs.log_ratio_max if obs.informative and obs.log_ratio_max is not None else math.nan
        self._r_max = r_max = likelihood_cumulative(log_ratio, self._like, float(known))
        if r_max == -math.inf:  # every place impossible: no evidence, the prediction stands (as in the grid filter)
            self._log_ratio = log_ratio = self._no_ratio
            self._r_max = r_max = likelihood_cumulative(log_ratio, self._like, math.nan)
        self._log_like_mean = r_max + math.log(self._like[-1] / g.n_places)  # log mean_j e^{r_j}
        born = self._births > 0 and self._advanced > 0
        self._newborn = self._generation(self._advanced - 1) if born else (0, 0)
        self._log_recovery = math.log(self.recovery_) + self._log_like_mean if born else -math.inf
        # e^{r − max r}: where the jump grid reads it, every place now; else the places the
        # marginal motion reads, when it moves (_frame_ratio)
        self._e_dense = False
        if self._jump_grid:
            self._frame_ratio()

    def _frame_ratio(self, places: np.ndarray | None = None) -> None:
        """``_e = e^{r − max r}`` at ``places`` (every place: None), numpy's floats (they do not
        depend on which places a call takes)."""
        if self._e_dense:
            return
        if places is None:
            np.exp(np.subtract(self._log_ratio, self._r_max, out=self._e), out=self._e)
            self._e_dense = True
            return
        x = self._log_ratio[places]
        np.exp(np.subtract(x, self._r_max, out=x), out=x)
        self._e[places] = x

    def _move(self, odometry: float | None) -> None:
        """Predict: the motion model moves the particles (not on the first frame). With
        the velocity marginalised (``marginal_velocity``), the particles outside the
        coming births move with the frame's evidence and carry their share ``1 − ε``."""
        self._marginal_step = self._marginal and odometry is None
        if self._advanced == 0:
            if self._marginal_step:
                self._spread_from_frame(0, self.n_particles, 0.0)
            return  # the first frame: nothing has moved yet
        motion = self._motions[0] if odometry is None else self._motions[1]
        if not self._marginal_step:
            if self._marginal:
                self._sample_velocity()
            motion.move(self.particles_, self.graph, self._rng, odometry)
            if self._marginal:  # the speed each particle drove at, its phases alike
                self._spread[:] = self.motion._speed_bins[np.maximum(self._velocity, 0)]
            return
        start, stop = self._newborn
        log_keep = math.log1p(-self.recovery_) if stop > start else 0.0
        if self._jump_grid and stop > start:
            log_keep += math.log1p(-min(self._jumps_mass, 1.0 - 1e-12))
        if not self._e_dense:  # (the jump grid took every place)
            self._frame_ratio(motion.reach_places(self.particles_, self.graph, self._newborn, self._written)
                              if self._sparse_ratio else None)
        kept = motion.move_marginal(self.particles_, self._spread, self.graph, self._rng, self._e, log_keep,
                                    self._newborn, self._marginal_mass, self._marginal_prior, self._written)
        if kept == 0.0:  # every particle left the map: start them again from this frame
            self._spread_from_frame(*self._cloud_slots(), log_keep)

    def _cloud_slots(self) -> tuple[int, int]:
        """The slots outside the coming births, as one range when the births are at the
        end, else the cloud's (the young generations in between then keep theirs)."""
        start, stop = self._newborn
        return (0, start) if stop == self.n_particles or stop == start else (0, self._n_cloud)

    def _spread_from_frame(self, first: int, last: int, log_keep: float) -> None:
        """Slots ``first .. last`` drawn systematically from this frame's posterior under
        a uniform prior, ``∝ e^{r_j}``, with equal weights summing to ``e^{log_keep}`` ·
        mean_j e^{r_j}`` (in units of ``e^{max r}``) and the uniform velocity
        distribution: the exact posterior of a uniform prediction (the first frame)."""
        g, m = self.graph, last - first
        self._frame_ratio()
        cumulative = self._like / self._like[-1]
        cumulative[-1] = 1.0
        u = (self._rng.random() + np.arange(m)) / m
        places = np.minimum(np.searchsorted(cumulative, u, side="right"), g.n_places - 1)
        has_out = g.out_ptr[places + 1] > g.out_ptr[places]
        self._edge[first:last] = np.where(has_out, g.out_ptr[places], self._first_in[places])
        self._fraction[first:last] = np.where(has_out, 0.0, 1.0)
        mean = self._like[-1] / g.n_places
        self._log_weight[first:last] = log_keep + math.log(mean) - math.log(m)
        self._spread[first:last] = self._velocity_prior
        keep = math.exp(log_keep)
        np.multiply(self._e, keep / g.n_places, out=self._marginal_mass)
        self._marginal_prior[:] = keep / g.n_places
        if self._written is not None:
            self._written.dense()
        if last - first < self.n_particles:  # the rest (young generations) as they are: weight 0 here
            rest = np.ones(self.n_particles, dtype=bool)
            rest[first:last] = False
            rest[self._newborn[0]:self._newborn[1]] = False
            self._log_weight[rest] = -math.inf

    def _sample_velocity(self) -> None:
        """One speed per particle from its velocity distribution (for a step the sampled
        motion takes: odometry): a bin drawn, its speed kept."""
        c = np.cumsum(self._spread, axis=1)
        u = self._rng.random(self.n_particles)[:, None] * c[:, -1:]
        self._velocity[:] = self.motion._owner[np.minimum((c <= u).sum(1), c.shape[1] - 1)]

    def _inject(self) -> None:
        """The recovery share ``ε``: a new generation of particles in the slots the
        oldest one left at the last resampling (:func:`_birth_kernel`); none on the
        first frame. With the velocity marginalised their velocity distribution is the
        jump's, half the posterior velocity marginal and half uniform (the grid's)."""
        g = self.graph
        born = self._newborn[1] > self._newborn[0]
        if self.proposal == "sharpened" and born:
            _sharpened_cumulative(self._log_ratio, self._r_max, float(self.proposal_power),
                                  float(self.proposal_uniform), self._proposal)
        if self.proposal == "best" and born:
            self._top[:] = _top_k(self._log_ratio, len(self._top))
        self._rng.random(out=self._uniform)
        jump_grid = self._jump_grid and born and self._marginal_step
        if jump_grid:
            self._predict_jumps()
        _birth_kernel(_PROPOSAL_CODE[self.proposal], self._like, self._proposal, self._top,
                      math.log1p(-self.recovery_) if born else 0.0, math.log(self.recovery_) if born else -math.inf,
                      *self._newborn, self._edge, self._fraction, self._log_weight, self._velocity, self._uniform,
                      g.out_ptr, self._first_in, not self._marginal_step)
        if self._marginal and born and not jump_grid:
            self._spread[self._newborn[0]:self._newborn[1]] = 0.5 * self._velocity_marginal + 0.5 * self._velocity_prior
        if jump_grid:  # the births carry the grid's mass at their place, and its velocities there
            start, stop = self._newborn
            g = self.graph
            e, f = self._edge[start:stop], self._fraction[start:stop]
            places = np.where(f < 0.5, g.source[e], g.target[e])
            at = self._jumps_t[:, places].T
            self._spread[start:stop] = at / at.sum(1, keepdims=True)
            # equal weights after the reweighting adds the frame's ratio: e^{-r} · (J_t / q) = const
            self._log_weight[start:stop] += np.log(self._jumps_predicted[places])

    def _predict_jumps(self) -> None:
        """The jump grid's prediction and update: ``J_t = ((1 − ε) · predict(J_{t−1}) + ε / n ·
        v_jump) · e^{r − max r}`` (the grid filter's motion, :func:`catgraph.grid.predict`,
        its lost mass renormalised as the particles'); ``like`` becomes its place marginal's
        cumulative, the births' proposal and the recovery share's exact masses, and the
        recovery share's log-mass ``log Σ J_t + max r``. On a route by place index in one
        compiled pass (:func:`catgraph._jump_kernels.jump_step`), else through
        :func:`catgraph.grid.predict`."""
        g, motion, eps = self.graph, self.motion, self.recovery_
        n = g.n_places
        jv = 0.5 * self._velocity_marginal + 0.5 * self._velocity_prior
        s = self._jumps_t
        out = self._jumps_buffers[1] if s is self._jumps_buffers[0] else self._jumps_buffers[0]
        whole, frac, sign, _ = self._jumps_moves
        kept_mass = (1.0 - eps) * self._jumps_mass
        if kept_mass < 1e-100 * eps:  # below any float's precision beside the new jump mass
            kept_mass = 0.0
        # the stored grid in units of its predicted mass (Σ = kept_mass + ε): its values stay of
        # order 1 / n however small its mass beside the particles' (far from subnormal floats)
        unit = 1.0 / (kept_mass + eps) if kept_mass + eps > 0.0 else 1.0
        c, a = 0.0, eps / n
        if self._jumps_line is not None:
            from ._jump_kernels import jump_lost, jump_step

            seg, edges, starts = self._jumps_line
            t_ptr, t_src, t_val = motion._columns
            if kept_mass > 0.0:
                kept = self._jumps_stored - jump_lost(s, seg, edges, t_ptr, t_src, t_val, whole, frac, sign)
                if kept > 0.0:  # what ran past a route end given back to the rest
                    c = kept_mass / kept
                else:  # all of it: spread uniformly (as the grid filter's prediction does)
                    a += kept_mass / (n * float(jv.sum()))
            jump_step(s, out, seg, t_ptr, t_src, t_val, whole, frac, sign, self._jumps_reach, motion._blur, c, a,
                      jv, self._e, unit, starts, self._jumps_predicted, self._like, self._jumps_bins,
                      self._jumps_totals)
            self._jumps_bins.sum(0, out=self._jumps_velocity)
        else:
            from .grid import predict

            if kept_mass > 0.0:
                moved = predict(np.ascontiguousarray(s.T) * (1.0 / s.sum()), motion._transition, motion._v[motion._owner],
                                self._jumps_neighbours, motion._blur, 0.0, jv, 0.0, moves=self._jumps_moves)
                total = moved.sum()
                moved *= kept_mass / total if total > 0 else 0.0
            else:
                moved = np.zeros(s.shape[::-1])
            moved += a * jv[None, :]
            moved.sum(1, out=self._jumps_predicted)
            jumps = moved.T * self._e[None, :]
            np.cumsum(jumps.sum(0), out=self._like)
            jumps.sum(1, out=self._jumps_velocity)
            np.multiply(jumps, unit, out=out)
        self._jumps_t = out
        self._jumps_unit = 1.0 / unit
        self._jumps_total = float(self._like[-1])
        self._jumps_stored = self._jumps_total * unit  # Σ _jumps_t
        self._log_recovery = math.log(self._like[-1]) + self._r_max

    def _reweight(self, obs: Observation) -> float:
        g = self.graph
        jump_grid = self._jump_grid and self._marginal_step and self._newborn[1] > self._newborn[0]
        log_graduate = math.log(self.jump_graduation) if jump_grid else 0.0
        log_map, ess = _reweight_kernel(self._edge, self._fraction, self._log_weight, g.source, g.target,
                                        self._log_ratio, *self._newborn, self._log_recovery, self._like, self._weight,
                                        self._mass, self._marginal_step, self._r_max, self._marginal_mass,
                                        log_graduate, self._terms)
        # the place masses: written, or their terms left for one pass with the posterior (_summarise)
        self._deferred = (float(self._terms[0]), float(self._terms[1]), self._terms[2] == 1.0) \
            if self._terms[2] > 0.0 else None
        if jump_grid:  # what the births did not take stays in the grid, normalised with the rest
            kept = (1.0 - self.jump_graduation) * math.exp(self._r_max - log_map)
            self._jumps_scale = kept * self._jumps_unit
            self._jumps_mass = kept * self._jumps_total
        elif self._jump_grid:
            self._jumps_scale = 0.0
            self._jumps_mass = 0.0
        if self._marginal:  # the posterior velocity marginal, for the next jump's velocity
            np.dot(self._weight, self._spread, out=self._velocity_marginal)
            if self._jump_grid and self._jumps_mass > 0.0:
                self._velocity_marginal += (self._jumps_mass / self._jumps_total) * self._jumps_velocity
        if obs.informative and np.isfinite(log_map):
            self._learn_recovery(math.exp(self._log_like_mean - log_map))
            prior = self.new_place_stay * self.new_place_probability_ + self._new_place_prior * (
                1.0 - self.new_place_probability_)
            if prior > 0.0:
                a_new = math.log(prior) + obs.new_place_log_ratio
                a_map = math.log1p(-prior) + log_map
                total = np.logaddexp(a_new, a_map)
                self._log_new, self._log_map = a_new - total, a_map - total
                self.new_place_probability_ = float(math.exp(self._log_new))
                self.frame_log_evidence_ = float(total)
            else:
                self.new_place_probability_ = 0.0
                self._log_new, self._log_map = -math.inf, 0.0
                self.frame_log_evidence_ = float(log_map)
        return float(ess)

    def _learn_recovery(self, ratio: float) -> None:
        """Online EM for the jump rate, as the grid filter learns it
        (:func:`catgraph.grid.learn_jump_rate`)."""
        if not self.learn_recovery or self.recovery == 0.0:
            return
        self._jumps, self._frames, self._prior_rate = learn_jump_rate(self._jumps, self._frames, float(self.recovery),
                                                                      self.recovery_, ratio)

    def _resample_if_degenerate(self, ess: float) -> bool:
        """With recovery: every step, resample the cloud together with the oldest young
        generation into the cloud's slots (that generation's slots take the next
        births); the younger generations keep their weights, so a jump's particles are
        weighed over ``recovery_frames`` frames before they must compete. Without:
        resample everything when ESS < ``ess_threshold · n_particles``."""
        n = self.n_particles
        if self._births > 0:
            n_out, (start, stop) = self._n_cloud, self._generation(self._advanced)
        elif ess < self.ess_threshold * n:
            n_out, start, stop = n, 0, 0
        else:
            return False
        e_tmp, f_tmp, v_tmp, s_tmp = self._gathered
        if self.resampler == "systematic":  # compiled, no index array
            _resample_pool(self._weight, n_out, start, stop, self._uniform[2], self._edge, self._fraction,
                           self._velocity, self._log_weight, e_tmp, f_tmp, v_tmp, self._spread, s_tmp)
            return True
        pool = np.concatenate([np.arange(n_out), np.arange(start, stop)])
        total = float(self._weight[pool].sum())
        if total > 0:
            idx = pool[self._resample(self._weight[pool] / total, self._rng)]
            idx = idx[self._rng.permutation(len(idx))[:n_out]]
            self._edge[:n_out], self._fraction[:n_out] = self._edge[idx], self._fraction[idx]
            self._velocity[:n_out] = self._velocity[idx]
            self._spread[:n_out] = self._spread[idx]
        self._weight[:n_out] = total / n_out
        self._log_weight[:n_out] = math.log(total / n_out) if total > 0 else -math.inf
        return True

    def _summarise(self, mass: np.ndarray, ess: float, resampled: bool,
                   joint: bool = True) -> tuple[Estimate, slice | np.ndarray]:
        """The frame's estimate and the answer's neighbourhood; ``joint=False``: its score
        is the log-odds until :meth:`_joint_score` reads the support."""
        g = self.graph
        best = self._resolve(mass)
        p_new, log_map, log_new = self.new_place_probability_, self._log_map, self._log_new
        twin = self._twin
        if twin is not None:
            # the two readings of the repeats, each weighed by its evidence (Bayes' rule): the
            # answer is the mixture's, over the map and the new place together
            self._own_posterior = self.place_posterior_  # (read by _agrees)
            self.place_posterior_, p_new, mass, best, log_map, log_new = mixed_answer(
                logistic(self.repeat_log_odds_), self.place_posterior_, p_new, twin.place_posterior_,
                twin.new_place_probability_)
        else:
            self.__dict__.pop("_own_posterior", None)
        if self.confidence_radius_m is not None:
            near = np.zeros(g.n_places, dtype=bool)
            near[self._tree.query_ball_point(g.positions[best], self.confidence_radius_m)] = True
        elif self._route is not None:  # by route distance, in mean spacings (the grid filter's)
            rd = self._route
            near = slice(int(np.searchsorted(rd, rd[best] - self._route_radius, "left")),
                         int(np.searchsorted(rd, rd[best] + self._route_radius, "right")))
        else:
            near = slice(max(0, best - self.confidence_radius), best + self.confidence_radius + 1)
        from .grid import _inside_outside

        w_in, w_out = _inside_outside(mass, near)
        # in log space, so that the new-place mass still ranks frames whose map mass is all inside
        confidence, log_odds = confidence_log_odds(w_in, w_out, log_map, log_new)
        position = None if g.positions is None else g.positions[best].copy()
        estimate = Estimate(best, position, confidence, p_new, ess, resampled, log_odds, log_odds)
        return (self._joint_score(estimate, near) if joint else estimate), near

    def _resolve(self, mass: np.ndarray) -> int:
        """The place masses where the reweighting left them to this pass, ``place_posterior_``
        and the best place (given the map)."""
        self.__dict__.pop("place_posterior_", None)  # the previous frame's: reusable if no one else holds it
        posterior = self._pool.take(len(mass))
        if self._deferred is not None:  # the place masses, the posterior and the answer in one pass
            scale, share, recover = self._deferred
            self._deferred = None
            best = int(_posterior_kernel(self._marginal_mass, scale, self._like, share, recover, mass, posterior,
                                         1.0 - self.new_place_probability_))
            self.place_posterior_ = posterior
        else:
            self.place_posterior_ = np.multiply(mass, 1.0 - self.new_place_probability_, out=posterior)
            best = int(np.argmax(mass))
        return best

    # ------------------------------------------------------------------ frames that come again
    _FORK_SHARED = ("_tree", "_route", "_neighbourhoods", "_first_in", "_no_ratio")

    #: The two readings become one once that moves the answer's posterior by at most this many
    #: particles' share of the cloud (``TWIN_PARTICLES / n_particles``): the lighter reading's
    #: weight times the distance between the two readings, which a cloud of ``n_particles``
    #: drawn from the mixture could not show. Two clouds differ by their sampling however
    #: alike the posteriors they stand for, so the grid filter's round-off
    #: (:data:`TWIN_AGREEMENT`) is below what they can tell.
    TWIN_PARTICLES = 1.0

    def _agrees(self, twin: "Localizer", weight: float) -> bool:
        """Whether ``weight`` times the distance between the two readings is at most
        :data:`TWIN_PARTICLES` particles' share: the total variation distance between their
        place posteriors with ``P(new)``, or, where larger, between their velocity marginals
        (the particles' distributions over the velocity bins, with the velocity marginalised)."""
        limit = self.TWIN_PARTICLES / self.n_particles
        if weight <= limit:
            return True
        own = self.__dict__.get("_own_posterior")
        if own is None:
            return False
        distance = 0.5 * (float(np.abs(own - twin.place_posterior_).sum())
                          + abs(self.new_place_probability_ - twin.new_place_probability_))
        if self._marginal and distance * weight <= limit:
            v, u = self._velocity_marginal, twin._velocity_marginal
            distance = max(distance, 0.5 * float(np.abs(v / max(v.sum(), 1e-300) - u / max(u.sum(), 1e-300)).sum()))
        return weight * distance <= limit

    def _joint_score(self, estimate: Estimate, near) -> Estimate:
        """``estimate`` with the joint confidence score: ``min(log-odds, max support near the
        answer)`` (``confidence_score="joint"`` with a support; else as it is)."""
        if self.confidence_score == "joint" and self._support is not None:
            return replace(estimate, score=min(estimate.log_odds, float(np.max(self._support[near]))))
        return estimate

    # ------------------------------------------------------------------ batch
    def run(self, observations, odometry: np.ndarray | None = None, query_index: np.ndarray | None = None,
            reference=None, progress: bool = False, return_posterior: bool = False) -> LocalizationResult:
        """Reset, then :meth:`step` through a whole query.

        Parameters
        ----------
        observations : ndarray, shape (n_query, n_places), DifferenceRows, or Traverse
            Difference matrix (rows in processing order), its rows block by block
            (:class:`~catgraph.differences.DifferenceRows`: one block in memory at a
            time), or a query
            :class:`~catgraph.traverse.Traverse` — then ``reference`` (a Traverse) is
            needed, the differences are those of :func:`catgraph.pipeline.differences`
            (normalised per query), computed a block at a time, and the query's odometry
            and index are used unless given.
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
            from .io import build_map, query_difference_rows
            from .pipeline import FrontEnd

            query = observations  # its rows block by block, as catgraph.pipeline.differences computes them
            observations = query_difference_rows(build_map(reference, FrontEnd(), graph=False), query)
            odometry = query.odometry if odometry is None else odometry
            query_index = query.index if query_index is None else query_index
        from .observation import query_rows

        n, rows_checked = query_rows(observations, self.graph.n_places)
        if odometry is not None:
            odometry = check_array(odometry, "odometry", ndim=1)
            if len(odometry) != n:
                raise ShapeMismatchError(f"odometry has {len(odometry)} entries for {n} query frames; give one per frame.")
        qi = np.arange(n) if query_index is None else check_query_index(query_index, n)
        self.reset()
        place = np.empty(n, dtype=np.int64)
        conf, p_new, ess, log_odds, score = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        pos = None if self.graph.positions is None else np.empty((n, self.graph.positions.shape[1]))
        posterior = np.empty((n, self.graph.n_places), dtype=np.float32) if return_posterior else None
        frames = range(n)
        if progress:
            from tqdm import tqdm

            frames = tqdm(frames, desc="localising", unit="frame", leave=False)
        start = time.perf_counter()
        for k, row in zip(frames, rows_checked):
            est = self.step(row, None if odometry is None else float(odometry[k]))
            place[k], conf[k], p_new[k], ess[k] = est.place, est.confidence, est.new_place_probability, est.ess
            log_odds[k], score[k] = est.log_odds, est.score
            if pos is not None:
                pos[k] = est.position
            if posterior is not None:
                posterior[k] = self.place_posterior_
        seconds = (time.perf_counter() - start) / max(n, 1)
        return LocalizationResult(place, conf, p_new, ess, pos, qi, seconds, log_odds, score, posterior)
