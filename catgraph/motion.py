"""Motion models: move particles along the place graph.

Each step a particle travels a distance ``δ_i`` along its edge; when it reaches the
edge's end node it picks an out-edge and carries on with what is left, so one step may
cross several places. Two ways to get ``δ_i``:

* :class:`OdometryMotion` — from the odometry ``u_k`` (metres travelled since the last
  frame), with multiplicative and additive Gaussian noise:
  ``δ_i = max(0, u_k (1 + σ_rel ε₁) + σ_abs ε₂)``;
* :class:`FrameMotion` — no odometry: the query is assumed to advance ``speed`` reference
  frames per query frame, with velocity noise: ``δ_i = max(0, speed + σ_v ε)`` *places*.

Without odometry a step is counted in places, on the graph's ``hop_length`` (1 per
edge), never in metres: a reference sampled several times at one point (Wi-Fi surveys)
has runs of zero-length chain edges, and a query advancing one sample per frame
advances one place, which a mean spacing in metres would not give (it would jump
every run of repeated samples at once and crawl along the long edges between them).
With odometry the distance is in graph units along ``graph.length``.

Branch choice at a node: never a U-turn onto the edge just travelled (its reverse); with
probability ``straight_preference`` the route continuation (``graph.straight``), otherwise
uniformly among the remaining out-edges (the continuation included).

Direction: a particle's direction is that of its edge. On a bidirectional graph a
particle may turn round: spontaneously with probability ``reverse_probability`` per step
(a query that drives a street the other way), and at *dead ends*. Dead-end policy
``"reflect"`` (default) turns the particle onto the reverse edge with the distance left;
``"stop"`` leaves it at the end of its edge. Without a reverse edge (a one-way chain) a
particle always stops at the end. Particles never leave the graph: every edge index
stays valid and every fraction stays in ``[0, 1]``.

* :class:`VelocityMotion` — a *velocity state* per particle (CAT-SLAM), the particle
  version of :class:`~catgraph.grid.GridLocalizer`'s motion: each particle carries a
  signed velocity bin ``v_b`` (places per frame; ``v < 0`` drives the route
  backwards), which changes by the grid's sticky transition ``T``; it then travels
  ``⌊|v_b|⌋`` places, one more with probability ``|v_b| − ⌊|v_b|⌋`` (the grid's
  fractional shift), or the odometry when the frame has it, in the direction
  ``sign(v_b)``, hop by hop as the grid filter moves mass (not the branch rule
  above: junctions at the grid's rate, then on in either direction); then one place
  either way along the route with probability ``blur`` each (a route end keeps it).
  Without odometry particles therefore sit on places, like the grid's point masses.
  Its defaults are the grid filter's, and one compiled loop does the whole step, so the
  particle filter is a Monte Carlo version of the grid filter's prediction and
  converges to it as particles grow, on a chain and at junctions
  (``tests/test_localizer.py``, ``tests/test_motion_junctions.py``), with two
  differences of representation in this sampled motion: a fractional speed is a random
  extra hop, the grid's linear split (``max_phases=1``), not its phase bins; and with
  odometry a particle keeps its position between two places and counts at the nearer
  one, where the grid splits the mass between both. The velocity-marginalised motion
  below (the default on chains without odometry) has the grid's phase bins.

:meth:`VelocityMotion.move_marginal` is the same motion with the velocity *marginalised*
(Rao–Blackwellised): a particle carries a distribution over the grid filter's state bins
(every speed, a fractional one split into its phases: :func:`catgraph.grid.phase_bins`,
so that a track at half speed stays sharp, ``tests/test_localizer_phases.py``) instead of
one bin, and the particles on one place (a *family*) predict exactly as the grid filter
predicts a state with all its mass at that place — transition, shift, fractional shift
and blur (:meth:`VelocityMotion.marginal_transition`, tested against
:func:`catgraph.grid.predict`). The family then splits over the places it can reach in
proportion to that prediction times the frame's likelihood (systematic positions, one
uniform per family), each member weighted by the family's predictive likelihood, and
each member's velocity distribution becomes the prediction's at the place it took. So
nothing about the velocity is sampled, and a step costs one small prediction
(``O(n_bins²)``) per occupied place plus ``O(n_particles)``. It needs a route without
junction edges (:meth:`VelocityMotion.supports_marginal`); odometry and junction graphs
keep the sampled motion.

:class:`LongRunVelocity` is the velocity a *jump* lands with in the grid filter: the
query's long-run velocity distribution, a discounted mean of the filter's posterior
velocity marginal shrunk towards a prior. A query cut into segments and shuffled keeps
its speed across a jump (the segments are pieces of one drive), so a jump should land
with the speeds the query drives at, not the speed of the frame before the jump alone
(which, right after a jump, is itself spread) nor a uniform one.

Randomness is explicit and bounded: per step, per particle, one normal (two for
odometry) and one uniform ``u`` for all its branch choices. A choice among ``m`` options
takes ``k = ⌊u m⌋`` and goes on with ``u' = u m − k``, again uniform on [0, 1) and
independent of ``k``; the straight preference likewise rescales ``u``. So a step costs
O(n_particles · hops) in a compiled loop, hops bounded by ``max_hops``.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit
from ._validation import check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError
from .particles import ParticleSet

__all__ = ["MotionModel", "OdometryMotion", "FrameMotion", "VelocityMotion", "LongRunVelocity", "PlacesWritten", "advance",
           "check_odometry"]


def check_odometry(odometry) -> float | None:
    """Validate one step's odometry: ``None`` or a finite, non-negative distance.

    Raises
    ------
    DataError
        For NaN, infinite or negative odometry, on every step (the first included).
    """
    if odometry is None:
        return None
    if isinstance(odometry, (bool, np.bool_, str, bytes)):  # float() would take them: True is 1, "3" is 3
        raise DataError(f"odometry must be a finite, non-negative distance (a number); got {odometry!r}.")
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


@njit(inline="always")
def _advance_one(e, f, d, u, length, target, out_ptr, reverse, straight, p_straight, reflect,
                 max_hops):  # pragma: no cover - compiled
    """Move one particle ``d`` along the graph from ``(e, f)``; returns ``(e, f, leftover, u)``
    (``u``: the branch uniform, rescaled after each choice; see the module docstring)."""
    hops = 0
    while True:
        ln = length[e]
        left = (1.0 - f) * ln
        if d < left:
            f += d / ln
            break
        d -= left
        f = 1.0
        if hops >= max_hops:
            break
        v = target[e]
        r = reverse[e]
        start = out_ptr[v]
        stop = out_ptr[v + 1]
        n_fwd = stop - start
        if r >= 0:
            n_fwd -= 1
        if n_fwd <= 0:
            if reflect and r >= 0:
                e = r
                f = 0.0
                hops += 1
                continue
            break
        s = straight[e]
        nxt = -1
        if s >= 0 and p_straight > 0.0:
            if u < p_straight:
                u = u / p_straight
                nxt = s
            else:
                u = (u - p_straight) / (1.0 - p_straight)
        if nxt < 0:
            k = int(u * n_fwd)
            if k >= n_fwd:
                k = n_fwd - 1
            u = u * n_fwd - k
            for c in range(start, stop):
                if c == r:
                    continue
                if k == 0:
                    nxt = c
                    break
                k -= 1
        e = nxt
        f = 0.0
        hops += 1
    f = min(max(f, 0.0), 1.0)
    return e, f, (d if f >= 1.0 else 0.0), u


@njit
def _advance_kernel(edge, fraction, distance, uniform, length, target, out_ptr, reverse, straight,
                    p_straight, reflect, max_hops, leftover):  # pragma: no cover - compiled
    for i in range(edge.shape[0]):
        e, f, rest, _ = _advance_one(edge[i], fraction[i], distance[i], uniform[i], length, target, out_ptr,
                                     reverse, straight, p_straight, reflect, max_hops)
        edge[i] = e
        fraction[i] = f
        leftover[i] = rest


@njit(inline="always")
def _route_walk(e, f, d, length, ahead, max_hops):  # pragma: no cover - compiled
    """Move ``d`` along the route from ``(e, f)`` (``e`` a route edge), never leaving it:
    returns ``(e, f, leftover)``, the leftover > 0 where the route ended first (or
    ``max_hops`` edges were crossed)."""
    hops = 0
    while True:
        ln = length[e]
        left = (1.0 - f) * ln
        if d < left:
            f += d / ln
            break
        d -= left
        f = 1.0
        if hops >= max_hops:
            break
        nxt = ahead[e]
        if nxt < 0:
            break
        e = nxt
        f = 0.0
        hops += 1
    f = min(max(f, 0.0), 1.0)
    return e, f, (d if f >= 1.0 else 0.0)


@njit
def _velocity_kernel(edge, fraction, log_weight, velocity, uniform, speeds, cumulative, mirror, hop, metric,
                     odometry, source, target, reverse, direction, ahead, out_fwd, out_bwd, at_edge, at_fraction,
                     jptr, jdst, p_junction, blur, max_hops, tolerance):  # pragma: no cover - compiled
    """One :class:`VelocityMotion` step for every particle, in place (see its Notes).
    ``uniform``: ``(4, n)`` — bin transition, fractional speed, junctions, blur.
    ``odometry < 0``: none (move ``|v|`` places, hop by hop, as the grid filter's
    ``_frames_rows``). ``direction[e]``: +1 / −1 for the route's forward / backward
    edges, 0 for the rest; ``ahead[e]``: the route edge after ``e`` in its direction;
    ``out_fwd`` / ``out_bwd``: the route edge leaving each place; ``at_edge[0|1, j]``,
    ``at_fraction``: where a particle standing at place ``j`` facing backwards / forwards
    sits."""
    nb = speeds.shape[0]
    for i in range(edge.shape[0]):
        b = velocity[i]
        if b < 0:  # not drawn yet: the uniform velocity prior, stratified (bin −1 − b mod nb)
            b = (-1 - b) % nb
        u = uniform[0, i]
        k = 0
        while k < nb - 1 and u > cumulative[b, k]:
            k += 1
        v = speeds[k]
        s = 1 if v >= 0.0 else -1
        e = edge[i]
        f = fraction[i]
        gone = False
        if odometry < 0.0:  # hop by hop between places
            j = source[e] if f < 0.5 else target[e]
            a = abs(v)
            whole = math.floor(a)
            d = whole + (1 if uniform[1, i] < a - whole else 0)
            u = uniform[2, i]
            for h in range(d):
                if h >= max_hops:
                    gone = True
                    break
                nj = jptr[j + 1] - jptr[j]
                pj = 0.0
                if nj > 0:
                    pj = min(p_junction * nj, 0.5)
                if u < pj:  # a junction, each alike; then half go on each way
                    u = u / pj * nj
                    c = min(int(u), nj - 1)
                    u -= c
                    j = jdst[jptr[j] + c]
                    if mirror[k] != k:
                        if u < 0.5:
                            u = 2.0 * u
                        else:
                            u = 2.0 * u - 1.0
                            k = mirror[k]
                            s = -s
                    continue
                if pj > 0.0:
                    u = (u - pj) / (1.0 - pj)
                t = out_fwd[j] if s > 0 else out_bwd[j]
                if t < 0:  # ran past the route's end: it leaves the map, as grid mass does
                    gone = True
                    break
                j = target[t]
            c = uniform[3, i]
            if not gone and c < 2.0 * blur:  # one place either way along the route; a route end keeps it
                t = out_fwd[j] if (c < blur) == (s > 0) else out_bwd[j]
                if t >= 0:
                    j = target[t]
            side = 1 if s > 0 else 0
            e = at_edge[side, j]
            f = at_fraction[side, j]
        else:  # the odometry along the route's edges (junctions are taken by frame motion only)
            if direction[e] != s:  # face the velocity's direction
                r = reverse[e]
                if direction[e] == -s and r >= 0 and direction[r] == s:
                    e = r
                    f = 1.0 - f
                else:
                    j = source[e] if f < 0.5 else target[e]
                    side = 1 if s > 0 else 0
                    e = at_edge[side, j]
                    f = at_fraction[side, j]
            if direction[e] == s:
                e, f, rest = _route_walk(e, f, odometry, metric, ahead, max_hops)
                gone = rest > tolerance
            elif odometry > tolerance:  # a place with no route onwards (a route end): it leaves the map
                gone = True
            c = uniform[3, i]
            if not gone and c < 2.0 * blur:  # one place either way along the route; a route end keeps it
                back = c >= blur
                r = reverse[e]
                if not back and direction[e] == s:
                    e, f, rest = _route_walk(e, f, 1.0, hop, ahead, max_hops)
                elif back and r >= 0 and direction[r] == -s:
                    e, f, rest = _route_walk(r, 1.0 - f, 1.0, hop, ahead, max_hops)
                    r = reverse[e]
                    if r >= 0:
                        e = r
                        f = 1.0 - f
        velocity[i] = k
        if gone:
            log_weight[i] = -np.inf
        edge[i] = e
        fraction[i] = f


def _velocity_route(graph) -> tuple:
    """The grid filter's route on ``graph`` (:func:`catgraph.grid.route_neighbours`) as
    edges, for :func:`_velocity_kernel`, computed once per graph: ``direction``,
    ``ahead``, ``out_fwd``, ``out_bwd``, ``at_edge``, ``at_fraction``, and the junction
    lists ``jptr``, ``jdst``."""
    route = graph.__dict__.get("_velocity_route")
    if route is not None:
        return route
    from .grid import route_neighbours
    from .particles import _first_in_edge

    n = graph.n_places
    fwd, bwd, _, _, jptr, jdst = route_neighbours(graph)
    key = graph.source * n + graph.target
    order = np.argsort(key, kind="stable")

    def edge_to(nxt):  # the edge from each place to nxt[place], or -1
        out = np.full(n, -1, dtype=np.int64)
        has = np.flatnonzero(nxt >= 0)
        if len(has):
            want = has * n + nxt[has]
            pos = np.minimum(np.searchsorted(key, want, sorter=order), len(order) - 1)
            hit = key[order[pos]] == want
            out[has[hit]] = order[pos[hit]]
        return out

    out_fwd, out_bwd = edge_to(fwd), edge_to(bwd)
    direction = np.zeros(graph.n_edges, dtype=np.int64)
    ahead = np.full(graph.n_edges, -1, dtype=np.int64)
    for out, sign in ((out_fwd, 1), (out_bwd, -1)):
        e = out[out >= 0]
        direction[e] = sign
        ahead[e] = out[graph.target[e]]
    first_in = _first_in_edge(graph)
    at_edge = np.empty((2, n), dtype=np.int64)
    at_fraction = np.empty((2, n))
    for side, (ahead_out, behind_out) in enumerate(((out_bwd, out_fwd), (out_fwd, out_bwd))):
        into = np.full(n, -1, dtype=np.int64)  # the route edge arriving at each place facing this way
        e = ahead_out[ahead_out >= 0]
        into[graph.target[e]] = e
        into_back = np.full(n, -1, dtype=np.int64)
        e = behind_out[behind_out >= 0]
        into_back[graph.target[e]] = e
        start = graph.out_ptr[:-1]
        has_out = graph.out_ptr[1:] > start
        # in order of preference: leaving this way, arrived this way (a route end), then the other way
        choices = [(ahead_out, 0.0), (into, 1.0), (behind_out, 0.0), (into_back, 1.0),
                   (np.where(has_out, start, -1), 0.0), (first_in, 1.0)]
        at_edge[side] = -1
        at_fraction[side] = 0.0
        for edges, frac in reversed(choices):
            ok = edges >= 0
            at_edge[side, ok] = edges[ok]
            at_fraction[side, ok] = frac
    route = (direction, ahead, out_fwd, out_bwd, at_edge, at_fraction, jptr, jdst)
    object.__setattr__(graph, "_velocity_route", route)
    return route


def advance(particles: ParticleSet, graph, distance: np.ndarray, rng: np.random.Generator,
            straight_preference: float = 0.0, reverse_probability: float = 0.0,
            dead_end: str = "reflect", max_hops: int = 256, lengths: np.ndarray | None = None) -> np.ndarray:
    """Move every particle ``distance[i]`` along the graph, in place.

    Parameters
    ----------
    particles : ParticleSet
    graph : PlaceGraph
    distance : ndarray, shape (n,)
        Non-negative distances (graph units).
    rng : numpy.random.Generator
    straight_preference, reverse_probability : float
        See the module docstring.
    dead_end : {"reflect", "stop"}
    max_hops : int
        Most places one particle may cross in one step (bounds the time of a step).
    lengths : ndarray, shape (E,), optional
        Edge lengths to travel ``distance`` on: ``graph.length`` (default; metres or
        frames) or ``graph.hop_length`` (places).

    Returns
    -------
    ndarray of float64, shape (n,)
        Distance each particle could not travel (stopped at a dead end, or at
        ``max_hops``); 0 for most.
    """
    n = len(particles)
    if reverse_probability > 0.0:
        turn = rng.random(n) < reverse_probability
        rev = graph.reverse[particles.edge]
        turn &= rev >= 0
        particles.edge[turn] = rev[turn]
        particles.fraction[turn] = 1.0 - particles.fraction[turn]
    uniform = rng.random(n)
    leftover = np.empty(n)
    _advance_kernel(particles.edge, particles.fraction, np.ascontiguousarray(distance, dtype=np.float64), uniform,
                    graph.length if lengths is None else lengths, graph.target, graph.out_ptr, graph.reverse, graph.straight,
                    float(straight_preference), dead_end == "reflect", int(max_hops), leftover)
    return leftover


class MotionModel:
    """Base class: holds the branch and dead-end parameters; subclasses say how far.

    Parameters
    ----------
    straight_preference : float in [0, 1]
        Probability of taking the route continuation at a node.
    reverse_probability : float in [0, 1]
        Probability per step that a particle turns round (bidirectional graphs).
    dead_end : {"reflect", "stop"}
    max_hops : int
    """

    def __init__(self, straight_preference: float = 0.0, reverse_probability: float = 0.0,
                 dead_end: str = "reflect", max_hops: int = 256) -> None:
        self.straight_preference = straight_preference
        self.reverse_probability = reverse_probability
        self.dead_end = dead_end
        self.max_hops = max_hops

    def _params(self) -> tuple:
        # the public attributes in the order they were set (checked every step: kept cheap)
        return tuple(item for item in vars(self).items() if item[0][:1] != "_")

    def _check(self) -> bool:
        """Validate the parameters; False when they were already validated unchanged."""
        key = self._params()
        if getattr(self, "_checked", None) == key:
            return False
        self._validate_params()
        self._checked = key
        return True

    def _validate_params(self) -> None:
        name = type(self).__name__
        check_scalar(self.straight_preference, "straight_preference", name, float, 0.0, 1.0)
        check_scalar(self.reverse_probability, "reverse_probability", name, float, 0.0, 1.0)
        check_scalar(self.max_hops, "max_hops", name, int, 1)
        if self.dead_end not in ("reflect", "stop"):
            raise InvalidParameterError(
                f"The 'dead_end' parameter of {name} must be 'reflect' or 'stop'. Got {self.dead_end!r} instead."
            )

    def distances(self, n: int, graph, odometry: float | None, rng: np.random.Generator) -> np.ndarray:
        """``(n,)`` distances for this step: graph units with odometry, places without."""
        raise NotImplementedError

    def move(self, particles: ParticleSet, graph, rng: np.random.Generator, odometry: float | None = None) -> None:
        """Advance ``particles`` in place by one step."""
        self._check()
        odometry = check_odometry(odometry)
        d = self.distances(len(particles), graph, odometry, rng)
        # without odometry the distance is in places (hop lengths); with it, in graph units
        advance(particles, graph, d, rng, self.straight_preference, self.reverse_probability,
                self.dead_end, self.max_hops, graph.hop_length if odometry is None else None)


class OdometryMotion(MotionModel):
    """Distance from odometry with multiplicative and additive noise.

    Parameters
    ----------
    relative_noise : float
        ``σ_rel``, standard deviation of the multiplicative error (0.1 = 10 %).
    absolute_noise : float
        ``σ_abs``, standard deviation of the additive error (graph units, metres).
    **kwargs
        Branch and dead-end parameters of :class:`MotionModel`.
    """

    def __init__(self, relative_noise: float = 0.1, absolute_noise: float = 0.5, **kwargs) -> None:
        super().__init__(**kwargs)
        self.relative_noise = relative_noise
        self.absolute_noise = absolute_noise

    def distances(self, n, graph, odometry, rng):
        if odometry is None:
            raise DataError("OdometryMotion needs the odometry of every step; use FrameMotion for a query without odometry.")
        u = float(odometry)
        if not np.isfinite(u) or u < 0:
            raise DataError(f"odometry must be a finite, non-negative distance; got {odometry!r}.")
        eps = rng.standard_normal((2, n))
        return np.maximum(0.0, u * (1.0 + self.relative_noise * eps[0]) + self.absolute_noise * eps[1])

    def _validate_params(self) -> None:
        super()._validate_params()
        check_scalar(self.relative_noise, "relative_noise", "OdometryMotion", float, 0.0)
        check_scalar(self.absolute_noise, "absolute_noise", "OdometryMotion", float, 0.0)


class FrameMotion(MotionModel):
    """``speed`` reference frames per query frame, with velocity noise.

    Parameters
    ----------
    speed : float
        Mean number of reference frames advanced per query frame.
    speed_noise : float
        ``σ_v``, standard deviation of the per-step speed (frames).
    **kwargs
        Branch and dead-end parameters of :class:`MotionModel`.
    """

    def __init__(self, speed: float = 1.0, speed_noise: float = 0.3, **kwargs) -> None:
        super().__init__(**kwargs)
        self.speed = speed
        self.speed_noise = speed_noise

    def distances(self, n, graph, odometry, rng):
        return np.maximum(0.0, self.speed + self.speed_noise * rng.standard_normal(n))

    def _validate_params(self) -> None:
        super()._validate_params()
        check_scalar(self.speed, "speed", "FrameMotion", float, 0.0)
        check_scalar(self.speed_noise, "speed_noise", "FrameMotion", float, 0.0)


class VelocityMotion(MotionModel):
    """Signed velocity state per particle, as the grid filter's motion.

    Parameters
    ----------
    velocities : sequence of float
        Signed speed bins (places per query frame).
    velocity_stay : float in [0, 1]
        Probability of keeping the bin from one frame to the next.
    reverse_probability : float in [0, 1 − velocity_stay]
        Probability per frame of turning round (``v → −v``).
    blur : float in [0, 0.5)
        Probability of one extra place forwards, and likewise backwards.
    junction_probability : float in [0, 0.5]
        Probability, per junction edge, that a hop from a place with junction edges
        takes that one (at most 0.5 for all of them together), as the grid filter's.
    max_phases : int >= 1
        The velocity-marginalised motion (:meth:`move_marginal`) drives a fractional
        speed ``w + p/q`` (``q ≤ max_phases``) by ``q`` phase bins, as the grid filter
        does (:func:`~catgraph.grid.phase_bins`): ``v = 0.5`` moves 0, 1, 0, 1 … places
        and a track at half speed stays sharp. 1: one bin per speed, a fractional speed
        split between the two bracketing places each frame (a random walk). The sampled
        motion (:meth:`move`: odometry, junction graphs) keeps one bin per speed.

    Each one left ``None`` is :class:`~catgraph.grid.GridLocalizer`'s default (read from
    its signature), so the two filters share one motion model by construction.
    max_hops : int
        Most edges one particle may cross in one step (bounds the time of a step); a
        particle that would cross more gets weight 0.

    Notes
    -----
    Without odometry a particle moves ``|v_b|`` *hops* between places, as the grid
    filter's ``_frames_rows`` moves mass: each hop follows the route edge of the
    direction of travel (``sign(v_b)``; the grid's :func:`~catgraph.grid.route_neighbours`),
    except that from a place with junction edges it takes each one with probability
    ``junction_probability`` (together at most 0.5) and then goes on, with probability
    ½ each, with ``v_b`` or with ``−v_b`` (a crossing may turn either way; where the
    velocity set has no ``−v_b``, with ``v_b``). With odometry ``u`` the distance is ``u``
    along the route's edge lengths (the bins keep only their sign; junctions are taken
    by frame motion only, as in the grid filter). A particle that would run past a route
    end gets weight 0 (the grid filter's mass leaves the map there). Without odometry
    particles sit on places. Randomness: four uniforms per particle per step (bin,
    fractional hop, junctions, blur), drawn into a buffer kept between steps.
    """

    def __init__(self, velocities=None, velocity_stay: float | None = None, reverse_probability: float | None = None,
                 blur: float | None = None, junction_probability: float | None = None, max_phases: int | None = None,
                 max_hops: int = 256) -> None:
        super().__init__(max_hops=max_hops)
        self.velocities = velocities
        self.velocity_stay = velocity_stay
        self.velocity_reverse_probability = reverse_probability
        self.blur = blur
        self.junction_probability = junction_probability
        self.max_phases = max_phases

    def _params(self) -> tuple:
        v = self.velocities
        rest = tuple(item for item in vars(self).items() if item[0][:1] != "_" and item[0] != "velocities")
        return rest + (None if v is None else tuple(np.asarray(v, dtype=float).ravel().tolist()),)

    def _validate_params(self) -> None:
        import inspect

        from .grid import GridLocalizer, _bin_moves, phase_bins, phase_transition, velocity_transition

        # one owner for the motion's defaults: the grid filter's signature
        grid = {k: p.default for k, p in inspect.signature(GridLocalizer.__init__).parameters.items()}
        resolved = {k: grid[k] if getattr(self, attr) is None else getattr(self, attr) for k, attr in (
            ("velocities", "velocities"), ("velocity_stay", "velocity_stay"),
            ("reverse_probability", "velocity_reverse_probability"), ("blur", "blur"),
            ("junction_probability", "junction_probability"), ("max_phases", "max_phases"))}
        super()._validate_params()
        name = type(self).__name__
        v = np.asarray(resolved["velocities"], dtype=np.float64)
        if v.ndim != 1 or len(v) == 0 or not np.all(np.isfinite(v)) or len(np.unique(v)) != len(v):
            raise InvalidParameterError(
                f"The 'velocities' parameter of {name} must be a non-empty sequence of distinct finite speeds. "
                f"Got {self.velocities!r} instead."
            )
        stay, reverse = resolved["velocity_stay"], resolved["reverse_probability"]
        check_scalar(stay, "velocity_stay", name, float, 0.0, 1.0)
        check_scalar(reverse, "reverse_probability", name, float, 0.0, 1.0 - stay)
        check_scalar(resolved["blur"], "blur", name, float, 0.0, 0.5, True, False)
        check_scalar(resolved["junction_probability"], "junction_probability", name, float, 0.0, 0.5)
        check_scalar(resolved["max_phases"], "max_phases", name, int, 1, 64)
        self._v = v
        self._junction = float(resolved["junction_probability"])
        self._mirror = _bin_moves(v)[3]
        self._blur = float(resolved["blur"])
        transition = velocity_transition(v, stay, reverse)
        # the sampled motion (move): one bin per speed
        self._cumulative = np.cumsum(transition, axis=1)
        self._cumulative[:, -1] = 1.0
        # the velocity-marginalised motion's state bins: the grid filter's (a fractional speed
        # split into its phases where max_phases allows; else one bin per speed)
        owner, whole, frac, sign, mirror, successor = phase_bins(v, int(resolved["max_phases"]))
        self._owner = owner
        self._transition = phase_transition(transition, owner, successor)  # without phases: transition itself
        self._moves = (whole, frac, sign)
        self._bin_moves = (whole, frac, sign, mirror)  # as catgraph.grid.predict takes them
        nz = self._transition.T != 0  # the transition's columns, sparse
        self._columns = (np.concatenate([[0], np.cumsum(nz.sum(1))]).astype(np.int64),
                         np.nonzero(nz)[1].astype(np.int64), np.ascontiguousarray(self._transition.T[nz]))
        count = np.bincount(owner, minlength=len(v))
        # uniform over the speeds, each shared evenly by its phases (the grid's prior, odds 1)
        self._bin_prior = 1.0 / (len(v) * count[owner])
        # per speed, the bin distribution of a particle known to drive at it (its phases alike)
        self._speed_bins = (owner[None, :] == np.arange(len(v))[:, None]) / count[:, None].astype(np.float64)
        # route offsets a particle can reach in one step: its fastest bin's hops (one more
        # for a fractional speed), then the blur's one place
        self._reach = int(np.max(whole + (frac > 0))) + 1
        # away from the route's ends, a one-bin state's prediction per (offset, bin): the
        # prediction of any velocity distribution there is their mixture
        width = 2 * self._reach + 1
        line = np.arange(width + 2)
        fwd, bwd = np.where(line + 1 < width + 2, line + 1, -1), line - 1
        nb = len(owner)
        self._interior = np.empty((nb, width, nb))
        window, moved = np.empty(width, dtype=np.int64), np.empty((width, nb))
        for a in range(nb):
            _marginal_transition(self._reach + 1, np.eye(nb)[a], self._transition, *self._moves, self._blur,
                                 fwd, bwd, self._reach, window, np.empty(nb), moved)
            self._interior[a] = moved
        self._interior_column = np.ascontiguousarray(self._interior.sum(2))
        self._interior_rows = np.ascontiguousarray(self._interior.transpose(1, 2, 0))  # [o, b, a]

    def move(self, particles: ParticleSet, graph, rng: np.random.Generator, odometry: float | None = None) -> None:
        self._check()
        odometry = check_odometry(odometry)
        n = len(particles)
        if particles.velocity is None:
            particles.velocity = -1 - np.arange(n, dtype=np.int64)
        buffer = self.__dict__.get("_uniform")
        if buffer is None or buffer.shape[1] != n:
            buffer = self._uniform = np.empty((4, n))
        rng.random(out=buffer)
        metric = odometry is not None
        _velocity_kernel(particles.edge, particles.fraction, particles.log_weight, particles.velocity, buffer,
                         self._v, self._cumulative, self._mirror, graph.hop_length, graph.length,
                         float(odometry) if metric else -1.0, graph.source, graph.target, graph.reverse,
                         *_velocity_route(graph), float(self._junction), self._blur, int(self.max_hops),
                         1e-9 * (graph.frame_spacing if metric else 1.0))

    # ------------------------------------------------------------------ velocity marginalised
    @staticmethod
    def _route(graph) -> tuple:
        """The grid filter's route neighbours of ``graph`` and each place's first in-edge,
        computed once per graph."""
        route = graph.__dict__.get("_marginal_route")
        if route is None:
            from .grid import route_neighbours
            from .particles import _first_in_edge

            fwd, bwd, _, _, _, junction_target = route_neighbours(graph)
            route = (fwd, bwd, _first_in_edge(graph), len(junction_target) == 0)
            object.__setattr__(graph, "_marginal_route", route)
        return route

    def supports_marginal(self, graph) -> bool:
        """Whether :meth:`move_marginal` applies to ``graph``: a route without junction
        edges whose forward and backward neighbours undo each other (a chain, e.g. every
        map built from one traverse). Junction graphs and odometry take :meth:`move`."""
        self._check()
        fwd, bwd, _, plain = self._route(graph)
        if not plain:
            return False
        ahead, behind = fwd >= 0, bwd >= 0
        idx = np.arange(graph.n_places)
        return bool(np.all(bwd[fwd[ahead]] == idx[ahead]) and np.all(fwd[bwd[behind]] == idx[behind]))

    def marginal_transition(self, graph, place: int, velocity_distribution: np.ndarray) -> np.ndarray:
        """The prediction of one particle that carries a velocity distribution: the grid
        filter's prediction of a state with all its mass at ``place`` (no recovery share,
        no normalisation: mass that runs past a route end is lost).

        Parameters
        ----------
        graph : PlaceGraph
            A graph :meth:`supports_marginal` accepts.
        place : int
        velocity_distribution : ndarray, shape (n_bins,)

        Returns
        -------
        ndarray of float64, shape (n_places, n_bins)
        """
        self._check()
        fwd, bwd, _, _ = self._route(graph)
        whole, frac, sign = self._moves
        nb = len(self._owner)
        width = 2 * self._reach + 1
        window = np.empty(width, dtype=np.int64)
        moved = np.empty((width, nb))
        _marginal_transition(int(place), np.ascontiguousarray(velocity_distribution, dtype=np.float64),
                             self._transition, whole, frac, sign, self._blur, fwd, bwd, self._reach, window,
                             np.empty(nb), moved)
        out = np.zeros((graph.n_places, nb))
        for o in range(width):
            if window[o] >= 0:
                out[window[o]] += moved[o]
        return out

    def reach_places(self, particles: ParticleSet, graph, skip: tuple[int, int],
                     written: "PlacesWritten | None" = None) -> np.ndarray:
        """The places :meth:`move_marginal` can read ``like`` at: those within one step's
        reach along the route of a particle outside the slots ``skip``, each once.

        Parameters
        ----------
        particles : ParticleSet
        graph : PlaceGraph
            A graph :meth:`supports_marginal` accepts.
        skip : (int, int)
        written : PlacesWritten, optional
            Its ``marks`` lend the scratch (left all 0).

        Returns
        -------
        ndarray of int64
        """
        self._check()
        fwd, bwd, _, _ = self._route(graph)
        n = len(particles)
        marks = written.marks if written is not None else np.zeros(graph.n_places, dtype=np.uint8)
        out = self.__dict__.get("_reach_buffer")
        size = min(n * (2 * self._reach + 1), graph.n_places)
        if out is None or len(out) < size:
            out = self._reach_buffer = np.empty(size, dtype=np.int64)
        k = _reach_places(particles.edge, particles.fraction, graph.source, graph.target, fwd, bwd, self._reach,
                          int(skip[0]), int(skip[1]), marks, out)
        return out[:k]

    def move_marginal(self, particles: ParticleSet, velocity: np.ndarray, graph, rng: np.random.Generator,
                      like: np.ndarray, log_keep: float, skip: tuple[int, int], posterior: np.ndarray,
                      prior: np.ndarray, written: "PlacesWritten | None" = None) -> float:
        """Move particles that carry a velocity *distribution* (Rao–Blackwellised), with
        the frame's evidence (the locally optimal proposal), in place.

        Each particle ``i`` at place ``j`` with velocity distribution ``p_i`` predicts
        exactly as the grid filter predicts a state with all its mass at ``j``
        (:meth:`marginal_transition`): a mixture ``π_ic`` over the places ``c`` a step can
        reach (and, per place, over velocity bins). It then moves to one place drawn
        from that mixture times the frame's likelihood, its weight is multiplied by the
        predictive likelihood ``L_i = Σ_c π_ic e^{r_c}`` (what its weight would gain on
        average), and its velocity distribution becomes the mixture's at the chosen place.
        No velocity is ever sampled, and the weights no longer depend on where a particle
        happened to land. The particles' mixtures before the draw are also summed into
        ``posterior`` and ``prior`` (place masses): the Rao–Blackwellised estimate.

        Parameters
        ----------
        particles : ParticleSet
            Particles on places (fraction 0, or 1 at a dead end).
        velocity : ndarray of float64, shape (n, n_bins)
            Each particle's velocity distribution (rows sum to 1); updated in place.
        graph : PlaceGraph
            A graph :meth:`supports_marginal` accepts.
        rng : numpy.random.Generator
            One uniform per particle.
        like : ndarray of float64, shape (n_places,)
            ``e^{r_j − max r}`` (read only at :meth:`reach_places`).
        log_keep : float
            Log of the share of the prediction the particles carry (``log(1 − ε)``).
        skip : (int, int)
            Slots left alone (they are about to take new particles).
        posterior, prior : ndarray of float64, shape (n_places,)
            Filled with the mixtures (see :func:`_marginal_kernel`).
        written : PlacesWritten, optional
            The places the previous call wrote into ``posterior`` and ``prior`` (which hold
            0 everywhere else): only those are cleared, and only the places this call
            reaches are rescaled, so the step costs O(occupied places), not O(n_places);
            the arrays end exactly as the dense clear and rescale leave them. ``None``:
            clear and rescale every place (cheaper where the particles' reach covers much
            of the map).

        Returns
        -------
        float
            The particles' predicted mass before normalisation (0: every one left the map).
        """
        self._check()
        n = len(particles)
        buffer = self.__dict__.get("_uniform_marginal")
        if buffer is None or len(buffer) != n:
            buffer = self._uniform_marginal = np.empty(n)
        rng.random(out=buffer)
        fwd, bwd, first_in, _ = self._route(graph)
        whole, frac, sign = self._moves
        family_of = graph.__dict__.get("_marginal_family")
        if family_of is None:  # -1 per place, left so by the kernel
            family_of = np.full(graph.n_places, -1, dtype=np.int64)
            object.__setattr__(graph, "_marginal_family", family_of)
        members = self.__dict__.get("_members")
        if members is None or len(members) != n:
            members = self._members = np.empty(n, dtype=np.int64)
        if written is None:  # every place cleared and rescaled
            written = _EVERY_PLACE
        elif len(written.marks) != len(posterior):
            raise ShapeMismatchError(f"the PlacesWritten record holds {len(written.marks)} places; the place masses "
                                     f"have {len(posterior)}.")
        if written is not _EVERY_PLACE:
            written.reserve(n * (2 * self._reach + 1))
        return float(_marginal_kernel(particles.edge, particles.fraction, particles.log_weight, velocity,
                                      int(skip[0]), int(skip[1]), float(log_keep), buffer, like, self._transition,
                                      whole, frac, sign, self._blur, fwd, bwd, graph.source, graph.target,
                                      graph.out_ptr, first_in, self._reach, posterior, prior, family_of, members,
                                      self._interior_rows, self._interior_column, written.places, written.count,
                                      written.marks))


class PlacesWritten:
    """Which places a sparse writer (:meth:`VelocityMotion.move_marginal`) wrote into its
    place-mass arrays, so that the next call clears only those.

    Attributes
    ----------
    places : ndarray of int64
        The places written, ``places[:count[0]]`` (each once).
    count : ndarray of int64, shape (1,)
        How many; ``-1``: the arrays were written everywhere (or are new), clear them all.
    marks : ndarray of uint8, shape (n_places,)
        0 outside a call (a call's scratch: which places it has listed).

    Call :meth:`dense` after writing the arrays by other means.
    """

    __slots__ = ("places", "count", "marks")

    def __init__(self, n_places: int, capacity: int) -> None:
        self.places = np.empty(capacity, dtype=np.int64)
        self.count = np.full(1, -1, dtype=np.int64)
        self.marks = np.zeros(n_places, dtype=np.uint8)

    def dense(self) -> None:
        """The arrays were written at every place: the next call clears them all."""
        self.count[0] = -1

    def reserve(self, capacity: int) -> None:
        """Room for ``capacity`` places (keeps what is listed)."""
        if len(self.places) < capacity:
            places = np.empty(capacity, dtype=np.int64)
            k = max(int(self.count[0]), 0)
            places[:k] = self.places[:k]
            self.places = places


#: The record that asks :func:`_marginal_kernel` to clear and rescale every place (no marks).
_EVERY_PLACE = PlacesWritten(0, 0)


# ---------------------------------------------------------------------- the velocity marginalised
@njit
def _reach_places(edge, fraction, source, target, fwd, bwd, reach, skip_start, skip_stop, marks,
                  out):  # pragma: no cover - compiled
    """The places within ``reach`` steps along the route (``fwd``, ``bwd``) of the place of
    a particle outside ``skip_start .. skip_stop`` (the nearer of its edge's two, as
    :func:`_marginal_kernel` takes it), each once, into ``out``; returns how many.
    ``marks``: ``(n_places,)`` uint8 of 0, left so."""
    k = 0
    for i in range(edge.shape[0]):
        if skip_start <= i < skip_stop:
            continue
        e = edge[i]
        j = source[e] if fraction[i] < 0.5 else target[e]
        if marks[j] == 2:
            continue  # its window is listed already
        if marks[j] == 0:
            out[k] = j
            k += 1
        marks[j] = 2  # listed, and so is its window (1: listed)
        for direction in range(2):
            t = j
            for o in range(reach):
                t = fwd[t] if direction == 0 else bwd[t]
                if t < 0:
                    break
                if marks[t] == 0:
                    marks[t] = 1
                    out[k] = t
                    k += 1
    for m in range(k):
        marks[out[m]] = 0
    return k


@njit(inline="always")
def _one_place_transition(j, p, transition, whole, frac, sign, blur, fwd, bwd, reach, window, q,
                          moved):  # pragma: no cover - compiled
    """The grid filter's prediction of a state with all its mass at place ``j`` and
    velocity distribution ``p``, without the recovery share: ``moved[o, b]`` is the mass
    at route offset ``o − reach`` from ``j`` (``window[o]``, ``-1`` past a route end) in
    bin ``b``. Mass that runs past a route end is lost (``moved`` then sums to less
    than 1), as the grid's is before its normalisation."""
    nb = p.shape[0]
    width = 2 * reach + 1
    window[reach] = j
    t = j
    for o in range(1, reach + 1):
        if t >= 0:
            t = fwd[t]
        window[reach + o] = t
    t = j
    for o in range(1, reach + 1):
        if t >= 0:
            t = bwd[t]
        window[reach - o] = t
    for b in range(nb):
        acc = 0.0
        for a in range(nb):
            acc += p[a] * transition[a, b]
        q[b] = acc
    for o in range(width):
        for b in range(nb):
            moved[o, b] = 0.0
    for b in range(nb):
        if q[b] == 0.0:
            continue
        for extra in range(2):
            m = q[b] * (frac[b] if extra == 1 else 1.0 - frac[b])
            if m == 0.0:
                continue
            o = reach + sign[b] * (whole[b] + extra)
            if window[o] < 0:
                continue  # ran past the route's end: it leaves the map
            moved[o, b] += (1.0 - 2.0 * blur) * m
            ahead = o + 1 if window[o + 1] >= 0 else o  # a route end keeps its blur
            behind = o - 1 if window[o - 1] >= 0 else o
            moved[ahead, b] += blur * m
            moved[behind, b] += blur * m


@njit(fastmath=True)
def _marginal_kernel(edge, fraction, log_weight, velocity, skip_start, skip_stop, log_keep, uniform, like,
                     transition, whole, frac, sign, blur, fwd, bwd, source, target, out_ptr, first_in,
                     reach, posterior, prior, family_of, members, interior,
                     interior_column, written, n_written, marks):  # pragma: no cover - compiled
    """One step of :meth:`VelocityMotion.move_marginal` for every particle outside
    ``skip_start .. skip_stop``, in place; returns the particles' predicted mass
    ``K = Σ_i w_i Σ_c π_ic`` before its normalisation (0: every particle left the map).

    The particles on one place form a *family*: the prediction is linear in the state,
    so the family predicts exactly as one particle of the family's weight ``W`` whose
    velocity distribution is the members' weighted mean. That prediction is computed
    once per family (:func:`_one_place_transition`'s, per route offset and bin; tested
    against it), and its ``k`` members take the destinations at the systematic positions
    ``(u + m) / k`` of the family's posterior (``u`` the first member's uniform), each
    with weight ``W L / k``: a family splits over the places in proportion, not at
    random, and a step costs one prediction per occupied place, not per particle.

    ``like``: ``e^{r_j − max r}``. ``log_weight`` enters normalised over the particles
    moved to ``log_keep`` (the share the prediction keeps) and leaves as
    ``log(W L / (k K'))``, ``L = Σ_c π_c like[c]`` the family's predictive likelihood
    (in units of ``e^{max r}``; ``K' = K / e^{log_keep}``). ``posterior[j]`` and
    ``prior[j]`` get the families' mixtures before the draw (``Σ W π_c like[c] / K'``
    and ``Σ W π_c / K'``): the Rao–Blackwellised place masses. ``family_of``:
    ``(n_places,)`` int64 of ``-1`` (left so); ``members``: ``(n,)`` int64 scratch.
    ``interior[o, b, a]``: the prediction of bin ``a`` alone away from the route's ends
    (``interior_column[a, o]`` its sum over ``b``); a family there predicts as their
    mixture, and its bins' split is computed only at the places its members draw (the
    sum over ``a`` runs along contiguous memory, which the compiler vectorises).

    ``written[:n_written[0]]``: the places the previous call wrote (``n_written[0] = -1``:
    every place may be non-zero); they are cleared, this call's places listed there
    instead (``marks``, ``(n_places,)`` uint8 of 0, left so; empty: every place cleared
    and rescaled, ``n_written`` left -1), and only they rescaled: the
    floats of a clear and a rescale of every place, in O(occupied places)."""
    nb = velocity.shape[1]
    width = 2 * reach + 1
    n = edge.shape[0]
    window = np.empty(width, dtype=np.int64)
    q = np.empty(nb)
    column = np.empty(width)
    moved = np.empty((width, nb))
    row = np.empty(nb)
    origin = np.empty(nb, dtype=np.int64)
    for b in range(nb):
        origin[b] = reach + sign[b] * whole[b]
    mx = -np.inf
    for i in range(n):
        if (i < skip_start or i >= skip_stop) and log_weight[i] > mx:
            mx = log_weight[i]
    done = n_written[0]
    if done < 0:
        for j in range(posterior.shape[0]):
            posterior[j] = 0.0
            prior[j] = 0.0
    else:
        for k in range(done):
            posterior[written[k]] = 0.0
            prior[written[k]] = 0.0
    track = marks.shape[0] > 0  # else every place is cleared and rescaled (n_written stays -1)
    n_written[0] = 0 if track else -1
    if not np.isfinite(mx):
        return 0.0
    listed = 0
    total = 0.0
    scaled = np.empty(n)  # e^{log_weight − max}, computed once
    for i in range(n):
        if i < skip_start or i >= skip_stop:
            scaled[i] = np.exp(log_weight[i] - mx)
            total += scaled[i]
    log_norm = mx + np.log(total)
    # the families: the occupied places, their weights and mean velocity distributions
    place = np.empty(n, dtype=np.int64)
    family_weight = np.zeros(n)
    family_velocity = np.zeros((n, nb))
    family_place = np.empty(n, dtype=np.int64)
    family_first = np.empty(n, dtype=np.int64)
    count = np.zeros(n + 1, dtype=np.int64)
    n_families = 0
    for i in range(n):
        place[i] = -1
        if skip_start <= i < skip_stop:
            continue
        w = scaled[i] / total
        if w == 0.0:
            log_weight[i] = -np.inf
            continue
        e = edge[i]
        j = source[e] if fraction[i] < 0.5 else target[e]
        f = family_of[j]
        if f < 0:
            f = n_families
            family_of[j] = f
            family_place[f] = j
            family_first[f] = i
            n_families += 1
        place[i] = f
        family_weight[f] += w
        for b in range(nb):
            family_velocity[f, b] += w * velocity[i, b]
        count[f + 1] += 1
    for f in range(n_families):
        count[f + 1] += count[f]
        family_of[family_place[f]] = -1
    fill = count[:n_families].copy()
    for i in range(n):
        f = place[i]
        if f >= 0:
            members[fill[f]] = i
            fill[f] += 1
    centre = 1.0 - 2.0 * blur
    kept = 0.0
    for f in range(n_families):
        weight = family_weight[f]
        j = family_place[f]
        window[reach] = j
        t = j
        u = j
        for o in range(1, reach + 1):
            if t >= 0:
                t = fwd[t]
            window[reach + o] = t
            if u >= 0:
                u = bwd[u]
            window[reach - o] = u
        inside = True
        for o in range(width):
            if window[o] < 0:
                inside = False
        for a in range(nb):
            q[a] = family_velocity[f, a] / weight  # the family's velocity distribution
        if inside:  # away from the route's ends: the mixture of the bins' predictions
            for o in range(width):  # each column[o] summed over a in order, the offsets side by side
                column[o] = 0.0
            for a in range(nb):
                qa = q[a]
                for o in range(width):
                    column[o] += qa * interior_column[a, o]
        else:
            p = q.copy()
            for b in range(nb):
                acc = 0.0
                for a in range(nb):
                    acc += p[a] * transition[a, b]
                q[b] = acc
            moved[:, :] = 0.0
            for b in range(nb):
                o = origin[b]
                for extra in range(2):
                    m = q[b] * (frac[b] if extra == 1 else 1.0 - frac[b])
                    if m == 0.0:  # (a whole speed's extra hop: no mass, and its blur would reach past the window)
                        continue
                    if extra == 1:
                        o += sign[b]
                    if window[o] < 0:
                        continue  # past the route's end: it leaves the map
                    moved[o, b] += centre * m
                    moved[o + 1 if window[o + 1] >= 0 else o, b] += blur * m  # a route end keeps its blur
                    moved[o - 1 if window[o - 1] >= 0 else o, b] += blur * m
            for o in range(width):
                c = 0.0
                for b in range(nb):
                    c += moved[o, b]
                column[o] = c
            for a in range(nb):
                q[a] = p[a]
        stays = 0.0
        evidence = 0.0
        for o in range(width):
            c = column[o]
            if c > 0.0:
                t = window[o]
                if track and marks[t] == 0:
                    marks[t] = 1
                    written[listed] = t
                    listed += 1
                stays += c
                evidence += c * like[t]
                prior[t] += weight * c
                posterior[t] += weight * c * like[t]
        kept += weight * stays
        lo, hi = count[f], count[f + 1]
        if not evidence > 0.0:
            for m_ in range(lo, hi):
                log_weight[members[m_]] = -np.inf
            continue
        # destinations from the family's own posterior (the locally optimal proposal), systematic
        k = hi - lo
        log_each = np.log(weight * evidence / k)
        acc = 0.0
        scan = -1
        last_pick = -1
        for m_ in range(k):
            i = members[lo + m_]
            pos = (uniform[family_first[f]] + m_) / k * evidence
            while scan < width - 1 and (scan < 0 or acc <= pos):
                scan += 1
                if column[scan] > 0.0:
                    acc += column[scan] * like[window[scan]]
            pick = scan
            while column[pick] <= 0.0 or like[window[pick]] <= 0.0:  # round-off past the end
                pick -= 1
            if pick != last_pick:  # the velocity distribution at the chosen place
                last_pick = pick
                for b in range(nb):
                    if inside:
                        share = 0.0
                        for a in range(nb):
                            share += q[a] * interior[pick, b, a]
                        row[b] = share / column[pick]
                    else:
                        row[b] = moved[pick, b] / column[pick]
            for b in range(nb):
                velocity[i, b] = row[b]
            t = window[pick]
            if out_ptr[t + 1] > out_ptr[t]:
                edge[i] = out_ptr[t]
                fraction[i] = 0.0
            else:
                edge[i] = first_in[t]
                fraction[i] = 1.0
            log_weight[i] = log_each
    if track:
        n_written[0] = listed
    for k in range(listed):
        marks[written[k]] = 0
    if not kept > 0.0:
        return 0.0
    shift = log_keep - np.log(kept)
    for i in range(n):
        if i < skip_start or i >= skip_stop:
            log_weight[i] += shift
    scale = np.exp(shift)
    if not track:
        for j in range(posterior.shape[0]):
            posterior[j] *= scale
            prior[j] *= scale
    for k in range(listed):  # every other place holds 0, which the rescale leaves 0
        posterior[written[k]] *= scale
        prior[written[k]] *= scale
    return kept


@njit
def _marginal_transition(j, p, transition, whole, frac, sign, blur, fwd, bwd, reach, window, q,
                         moved):  # pragma: no cover - compiled
    """:func:`_one_place_transition`, callable from Python."""
    _one_place_transition(j, p, transition, whole, frac, sign, blur, fwd, bwd, reach, window, q, moved)


class LongRunVelocity:
    """The query's long-run velocity distribution, learned from a filter's posterior.

    After frame ``k`` the filter's posterior velocity marginal ``m_k`` (over its state
    bins) enters discounted sums, and the distribution is their ratio shrunk towards
    ``prior``::

        S_k = δ S_{k−1} + m_k,   F_k = δ F_{k−1} + 1,   δ = 2^(−1/memory)
        q_k = (S_k + prior_frames · prior) / (F_k + prior_frames)

    (:func:`catgraph.grid.learn_jump_rate` learns the jump rate the same way). Before
    any frame ``q = prior``. ``q`` sums to 1 when ``prior`` and every ``m_k`` do.

    Parameters
    ----------
    prior : ndarray of float64, shape (n_bins,)
        The distribution before any frame (the filter's velocity prior).
    memory : float > 0
        Half-life of the discounted sums, in frames.
    prior_frames : float >= 0
        Weight of ``prior``, in frames.

    Examples
    --------
    >>> import numpy as np
    >>> v = LongRunVelocity(np.array([0.5, 0.5]), memory=100.0, prior_frames=20.0)
    >>> for _ in range(1000):
    ...     q = v.update(np.array([0.0, 1.0]))
    >>> bool(q[1] > 0.85)
    True
    """

    def __init__(self, prior: np.ndarray, memory: float = 100.0, prior_frames: float = 20.0) -> None:
        check_scalar(memory, "memory", "LongRunVelocity", float, 0.0, None, False)
        check_scalar(prior_frames, "prior_frames", "LongRunVelocity", float, 0.0)
        self.prior = np.asarray(prior, dtype=np.float64)
        self.memory = float(memory)
        self.prior_frames = float(prior_frames)
        self._decay = 0.5 ** (1.0 / self.memory)
        self.sum_ = np.zeros(len(self.prior))
        self.frames_ = 0.0

    def update(self, marginal: np.ndarray) -> np.ndarray:
        """Add one frame's posterior velocity marginal; return the distribution."""
        self.sum_ *= self._decay
        self.sum_ += marginal
        self.frames_ = self._decay * self.frames_ + 1.0
        return self.distribution()

    def distribution(self) -> np.ndarray:
        """The current long-run distribution ``q`` (a new array)."""
        return (self.sum_ + self.prior_frames * self.prior) / (self.frames_ + self.prior_frames)
