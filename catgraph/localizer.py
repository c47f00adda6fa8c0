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
    inject(observation)                    # a few particles re-drawn from a proposal
    reweight(observation)                  # w_i ∝ w_i · exp(ℓ_i), update P(new)
    resample_if_degenerate()               # ESS < ess_threshold · n
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

Recovery. Every step a fraction ``redraw_fraction`` of the particles (chosen at random)
is replaced by draws from a proposal — ``"best"``: places among the ``proposal_top_k``
best single-frame log-ratios, ``"uniform"``: any place — each given the mean weight of
the cloud before reweighting (mixture Monte Carlo localisation). This lets the filter
recover after a jump to another part of the route (shuffled queries, kidnapping), at the
price of a small bias towards the current frame's best matches.

Estimate. Posterior mass per place ``m_j = (1 − P(new)) Σ_{i: place(i) = j} w_i``
(``np.bincount``; a particle belongs to the nearer of its two places); the answer is
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

Cost. A step is O(n_particles · hops + n_places): the motion kernel is compiled, the
rest is vectorised numpy; memory is fixed at construction. Same seed, same output:
every random draw comes from the one ``numpy.random.Generator`` made from ``seed``.
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
from .particles import ParticleSet, get_resampler, normalise_in_place, place_to_edges

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
def _reweight_kernel(edge, fraction, log_weight, source, target, log_ratio, informative, weight):  # pragma: no cover
    """In place: normalise the prior weights, add ``ℓ`` (interpolated log-ratio),
    normalise again (:func:`~catgraph.particles.normalise_in_place` both times);
    ``weight`` gets the normalised weights. Returns ``(log E_map, ESS)``,
    ``E_map = Σ w_prior · e^ℓ`` with the prior weights normalised."""
    normalise_in_place(log_weight, weight)
    if informative:
        for i in range(edge.shape[0]):
            e = edge[i]
            f = fraction[i]
            log_weight[i] += (1.0 - f) * log_ratio[source[e]] + f * log_ratio[target[e]]
    return normalise_in_place(log_weight, weight)


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


#: Where re-drawn particles go (see the module docstring).
PROPOSALS = ("best", "uniform")


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
        Resample when ESS < ``ess_threshold · n_particles``.
    redraw_fraction : float in [0, 1)
        Fraction of particles re-drawn from the proposal each step.
    proposal : {"best", "uniform"}
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
    new_place_probability_ : float
    n_steps_ : int
    """

    def __init__(self, graph: PlaceGraph, model: ObservationModel, n_particles: int = 2000,
                 motion: MotionModel | None = None, resampler: str = "systematic", ess_threshold: float = 0.5,
                 redraw_fraction: float = 0.02, proposal: str = "best", proposal_top_k: int = 10,
                 new_place_prior: float = 0.05, new_place_stay: float = 0.8, confidence_radius: int = 2,
                 confidence_radius_m: float | None = None, confidence_score: str = "joint",
                 seed: int | np.random.Generator | None = 0) -> None:
        self.graph = graph
        self.model = model
        self.n_particles = n_particles
        self.motion = motion
        self.resampler = resampler
        self.ess_threshold = ess_threshold
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
            raise InvalidParameterError(f"The 'proposal' parameter of {owner} must be 'best' or 'uniform'. Got {self.proposal!r} instead.")
        if self.confidence_radius_m is not None:
            check_scalar(self.confidence_radius_m, "confidence_radius_m", owner, float, 0.0)
            if self.graph.positions is None:
                raise DataError("confidence_radius_m needs a place graph with positions; use confidence_radius (places).")
        self._resample = get_resampler(self.resampler)

    def reset(self) -> "Localizer":
        """Start afresh: particles uniform over the graph, ``P(new) = 0``, model reset."""
        self._validate()
        self._rng = as_generator(self.seed) if not isinstance(self.seed, np.random.Generator) else self.seed
        self.particles_ = ParticleSet.uniform(self.graph, self.n_particles, self._rng)
        self.new_place_probability_ = 0.0
        self.n_steps_ = 0
        self._weight = np.exp(self.particles_.log_weight)
        self._log_new, self._log_map = -math.inf, 0.0
        self._support = None
        self._no_ratio = np.zeros(self.graph.n_places)
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
        w = np.exp(self.particles_.log_weight)
        prior = self._place_mass(w / w.sum())
        ess = self._reweight(obs)
        self._support = obs.support if obs.informative else None
        resampled = self._resample_if_degenerate(ess)
        estimate, near = self._summarise(ess, resampled)
        self._feedback(prior, near)
        self.n_steps_ += 1
        return estimate

    def _place_mass(self, weight: np.ndarray) -> np.ndarray:
        g = self.graph
        return np.bincount(self.particles_.places(g), weights=weight, minlength=g.n_places)

    def _feedback(self, prior: np.ndarray, near) -> None:
        """Tell the model the filter's prediction and answer (``ObservationModel.feedback``)."""
        if self._has_feedback:
            from .observation import FilterFeedback

            self.model.feedback(FilterFeedback(prior, self.place_posterior_, near))

    def _move(self, odometry: float | None) -> None:
        if self.n_steps_ == 0:
            return  # the first frame: nothing has moved yet
        motion = self._motions[0] if odometry is None else self._motions[1]
        motion.move(self.particles_, self.graph, self._rng, odometry)

    def _inject(self, obs: Observation) -> None:
        n_new = int(round(self.redraw_fraction * self.n_particles))
        if n_new == 0 or not obs.informative:
            return
        p, rng = self.particles_, self._rng
        who = rng.integers(0, self.n_particles, size=n_new)  # repeats are harmless
        if self.proposal == "best":
            k = min(self.proposal_top_k, self.graph.n_places)
            top = _top_k(obs.log_ratio, k)
            places = top[rng.integers(0, k, size=n_new)]
        else:
            places = rng.integers(0, self.graph.n_places, size=n_new)
        p.edge[who], p.fraction[who] = place_to_edges(self.graph, places, rng)
        if p.velocity is not None:
            p.velocity[who] = -1  # drawn afresh by the motion model
        p.log_weight[who] = -math.log(self.n_particles)  # the mean weight (log-weights are normalised)

    def _reweight(self, obs: Observation) -> float:
        p, g = self.particles_, self.graph
        log_ratio = obs.log_ratio if obs.informative else self._no_ratio
        log_map, ess = _reweight_kernel(p.edge, p.fraction, p.log_weight, g.source, g.target,
                                        np.ascontiguousarray(log_ratio, dtype=np.float64), bool(obs.informative),
                                        self._weight)
        if obs.informative:
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

    def _resample_if_degenerate(self, ess: float) -> bool:
        if ess >= self.ess_threshold * self.n_particles:
            return False
        idx = self._resample(self._weight, self._rng)
        self.particles_ = self.particles_.take(idx)
        self._weight = np.full(self.n_particles, 1.0 / self.n_particles)
        return True

    def _summarise(self, ess: float, resampled: bool) -> tuple[Estimate, slice | np.ndarray]:
        g = self.graph
        mass = self._place_mass(self._weight)
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
