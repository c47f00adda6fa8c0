"""Motion models: move particles along the place graph.

Each step a particle travels a distance ``δ_i`` along its edge; when it reaches the
edge's end node it picks an out-edge and carries on with what is left, so one step may
cross several places. Two ways to get ``δ_i``:

* :class:`OdometryMotion` — from the odometry ``u_k`` (metres travelled since the last
  frame), with multiplicative and additive Gaussian noise:
  ``δ_i = max(0, u_k (1 + σ_rel ε₁) + σ_abs ε₂)``;
* :class:`FrameMotion` — no odometry: the query is assumed to advance ``speed`` reference
  frames per query frame, with velocity noise:
  ``δ_i = s · max(0, speed + σ_v ε)`` where ``s`` is the graph's mean chain edge length
  (1 on a frame graph).

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

Randomness is explicit and bounded: per step, per particle, one normal (two for
odometry) and one uniform ``u`` for all its branch choices. A choice among ``m`` options
takes ``k = ⌊u m⌋`` and goes on with ``u' = u m − k``, again uniform on [0, 1) and
independent of ``k``; the straight preference likewise rescales ``u``. So a step costs
O(n_particles · hops) in a compiled loop, hops bounded by ``max_hops``.
"""

from __future__ import annotations

import numpy as np
import numba

from ._validation import check_scalar
from .exceptions import DataError, InvalidParameterError
from .particles import ParticleSet

__all__ = ["MotionModel", "OdometryMotion", "FrameMotion", "advance"]


@numba.njit(cache=True)
def _advance_kernel(edge, fraction, distance, uniform, length, target, out_ptr, reverse, straight,
                    p_straight, reflect, max_hops):  # pragma: no cover - compiled
    n = edge.shape[0]
    for i in range(n):
        e = edge[i]
        f = fraction[i]
        d = distance[i]
        u = uniform[i]
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
        edge[i] = e
        fraction[i] = min(max(f, 0.0), 1.0)


def advance(particles: ParticleSet, graph, distance: np.ndarray, rng: np.random.Generator,
            straight_preference: float = 0.0, reverse_probability: float = 0.0,
            dead_end: str = "reflect", max_hops: int = 256) -> None:
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
    """
    n = len(particles)
    if reverse_probability > 0.0:
        turn = rng.random(n) < reverse_probability
        rev = graph.reverse[particles.edge]
        turn &= rev >= 0
        particles.edge[turn] = rev[turn]
        particles.fraction[turn] = 1.0 - particles.fraction[turn]
    uniform = rng.random(n)
    _advance_kernel(particles.edge, particles.fraction, np.ascontiguousarray(distance, dtype=np.float64), uniform,
                    graph.length, graph.target, graph.out_ptr, graph.reverse, graph.straight,
                    float(straight_preference), dead_end == "reflect", int(max_hops))


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
        return tuple(sorted((k, v) for k, v in vars(self).items() if not k.startswith("_")))

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
        """``(n,)`` distances for this step (graph units)."""
        raise NotImplementedError

    def move(self, particles: ParticleSet, graph, rng: np.random.Generator, odometry: float | None = None) -> None:
        """Advance ``particles`` in place by one step."""
        self._check()
        d = self.distances(len(particles), graph, odometry, rng)
        advance(particles, graph, d, rng, self.straight_preference, self.reverse_probability,
                self.dead_end, self.max_hops)


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
        spacing = graph.frame_spacing
        return spacing * np.maximum(0.0, self.speed + self.speed_noise * rng.standard_normal(n))

    def _validate_params(self) -> None:
        super()._validate_params()
        check_scalar(self.speed, "speed", "FrameMotion", float, 0.0)
        check_scalar(self.speed_noise, "speed_noise", "FrameMotion", float, 0.0)
