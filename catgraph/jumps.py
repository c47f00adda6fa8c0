"""Jump evidence: whether the query jumped between two frames, from how much the frame changed.

A filter on the place graph finds a jump (an out-of-order query, a kidnapped robot) by
Bayes' rule: each frame a share ``ε`` of its mass may land anywhere, and a run of frames
that the current track cannot explain moves the mass there. Single frames carry weak
per-place evidence on a change of season or sensor (Nordland summer → winter: a single
frame's best place is right about 5 % of the time), so the jump is found several frames
late and, meanwhile, the old track's continuation is answered with confidence.

The frames carry a second sign, free of places: a jump replaces the scene, so the frame
after a jump is unlike its predecessor, about as unlike as two frames of different
places. With ``ρ_k`` the correlation (over the places) of the query's difference row
``k`` with row ``k − 1`` — the quantity the novelty weight of
:class:`~catgraph.observation.TemperedObservation` reads — the *change*
``s_k = 1 − ρ_k`` in ``[0, 2]`` is

* small between consecutive frames of one stretch (measured: median 0.02 on the UJI Wi-Fi
  walks, 0.33 on Nordland, 0.72 on the synthetic world),
* larger between frames of different places (median 1.0–1.1 on UJI, 0.6–0.7 on Nordland,
  0.96 on the synthetic world; the same at the jumps of shuffled queries as between
  frames 60 apart).

Neither distribution is known in advance and both depend on the sensor, the route and the
speed, so both are learned from the query itself, online and without training:

* ``P(s | step)`` from the change between consecutive frames (most are no jump; the rare
  jumps among them only make the evidence more cautious);
* ``P(s | jump)`` from the change between the current frame and a kept frame at least
  ``apart`` frames earlier (:data:`APART_FRAMES`), which shows another place unless the
  query stood still or came back (both, again, only make the evidence more cautious).

The evidence of frame ``k`` is the log-likelihood ratio ``log P(s_k | jump) − log P(s_k
| step)``, read from discounted histograms (``n_bins`` bins over ``[0, 2]``, half-life
``memory`` frames) *before* frame ``k`` enters them, and kept only where it is positive:
a change can show a jump but never rule one out, because a filter's jump rate also
stands for its own errors (a wrong track, a place it lost), which no change between
frames reveals. (Measured: letting a frame that changes little *lower* the jump rate,
down to a twentieth of it on the UJI walks, held wrong tracks longer and cost the UJI
short shuffles up to 0.022 AUC; ``docs/particle_filter.md``, "Jump evidence from the
frames' change".) Each histogram starts from ``prior_frames`` samples spread evenly, so
the evidence is 0 until the query has shown both kinds of change. A frame shown twice
(an exact repeat: a query slower than the reference) is no measurement: its evidence is
0 and it enters neither histogram nor counts towards ``apart``.

A filter turns the evidence ``e_k`` into the frame's jump rate by Bayes' rule on the
odds, ``ε_k = ε λ / (ε λ + 1 − ε)`` with ``λ = e^{e_k}`` (:func:`frame_jump_rate`, at
most :data:`JUMP_RATE_CAP`); its learned rate ``ε`` (:func:`catgraph.grid.learn_jump_rate`)
is then the prior rate that the frames' changes modulate. Where the change does not tell
jumps from steps ``λ ≈ 1`` and the filter is as before; where it does (Wi-Fi
fingerprints, whose consecutive scans hardly change), a jump is followed at once. A
filter that averages several motion models (:class:`~catgraph.grid.GridLocalizer`'s
``rigid_prior`` or ``jump_rates``) also weighs each by how well it explains the change:
before its normalisation a model of rate ``ε`` keeps ``1 − ε`` of its mass on its track
and lands ``ε λ``, so a change that looks like a jump weighs up a model that may jump
against a rigid line that may not (without that factor the normalised rate would charge
the jumping model for the change and hand the rigid line the weight).

Cost per frame: one dot product over the places (the kept frame against the current
one; half the frames), on the calling thread, and two histogram reads; memory: one kept
row (``n_places`` float64).
"""

from __future__ import annotations

import math

import numpy as np

from ._validation import check_scalar

__all__ = ["JumpEvidence", "frame_jump_rate", "APART_FRAMES", "JUMP_MEMORY", "JUMP_PRIOR_FRAMES", "JUMP_BINS",
           "JUMP_RATE_CAP"]

#: Frames between the kept frame and the frames compared with it (``P(s | jump)``).
APART_FRAMES = 50
#: Half-life, in frames, of the two histograms.
JUMP_MEMORY = 1000.0
#: Weight, in frames, of each histogram's even start.
JUMP_PRIOR_FRAMES = 10.0
#: Bins of the change ``s`` over ``[0, 2]``.
JUMP_BINS = 20
#: The largest jump rate, learned (:data:`catgraph.grid.RECOVERY_RANGE` reads it) or given
#: by a frame's evidence: half the mass stays on the track and the frames that follow decide.
JUMP_RATE_CAP = 0.5


def frame_jump_rate(rate, evidence: float):
    """The jump rate of one frame: the prior rate ``ε`` (a float or an array of rates)
    given the frame's jump evidence ``e`` (a log-likelihood ratio), ``ε λ / (ε λ + 1 − ε)``
    with ``λ = e^e``, at most :data:`JUMP_RATE_CAP` (or ``ε`` where it is larger).
    ``e = 0`` returns ``rate`` itself.

    >>> frame_jump_rate(0.01, 0.0)
    0.01
    >>> round(frame_jump_rate(0.01, math.log(99.0)), 6)
    0.5
    >>> round(frame_jump_rate(0.5, -math.log(3.0)), 6)
    0.25
    """
    if evidence == 0.0:
        return rate
    lam = math.exp(min(max(float(evidence), -700.0), 700.0))
    r = np.asarray(rate, dtype=np.float64)
    out = np.minimum(r * lam / (r * lam + (1.0 - r)), np.maximum(r, JUMP_RATE_CAP))
    return float(out) if out.ndim == 0 else out


def _product_sum(x: np.ndarray, y: np.ndarray) -> float:
    """``Σ x y`` on the calling thread (numpy's ``(x * y).sum()``, the same float). Not
    ``np.dot``: BLAS hands a long product to its own threads, which then spin for a while
    on the cores the live step's threads need (measured at 10⁵ places: the matcher's step
    6.5 → 11.5 ms for the 50 frames of every 100 in which this product is taken)."""
    if x.flags.c_contiguous and y.flags.c_contiguous and x.dtype == np.float64 and y.dtype == np.float64:
        from ._observation_kernels import product_sum

        return float(product_sum(x, y))
    return float(np.multiply(x, y).sum())


class JumpEvidence:
    """Online jump evidence from the change between frames (see the module docstring).

    Parameters
    ----------
    n_bins : int
        Bins of the change ``s = 1 − ρ`` over ``[0, 2]``.
    apart : int
        Frames between the kept frame and the frames compared with it.
    memory : float
        Half-life, in frames, of the histograms.
    prior_frames : float
        Weight, in frames, of each histogram's even start.

    Attributes
    ----------
    evidence_ : float
        The latest frame's evidence (0 for the first frame, a repeat or a blank frame).
    step_counts_, jump_counts_ : ndarray of float64, shape (n_bins,)
        The discounted histograms of ``s`` between consecutive frames and between frames
        ``apart`` or more apart.
    """

    def __init__(self, n_bins: int = JUMP_BINS, apart: int = APART_FRAMES, memory: float = JUMP_MEMORY,
                 prior_frames: float = JUMP_PRIOR_FRAMES) -> None:
        self.n_bins = n_bins
        self.apart = apart
        self.memory = memory
        self.prior_frames = prior_frames

    def reset(self) -> "JumpEvidence":
        owner = type(self).__name__
        check_scalar(self.n_bins, "n_bins", owner, int, 2)
        check_scalar(self.apart, "apart", owner, int, 1)
        check_scalar(self.memory, "memory", owner, float, 1.0)
        check_scalar(self.prior_frames, "prior_frames", owner, float, 0.0, low_inclusive=False)
        start = float(self.prior_frames) / self.n_bins
        self.step_counts_ = np.full(self.n_bins, start)
        self.jump_counts_ = np.full(self.n_bins, start)
        self._decay = 0.5 ** (1.0 / float(self.memory))
        self._kept = None  # a centred row kept as the frame "apart" frames before later ones
        self._kept_sq = 0.0
        self._age = 0
        self.evidence_ = 0.0
        return self

    def _bin(self, change: float) -> int:
        return min(max(int(change * 0.5 * self.n_bins), 0), self.n_bins - 1)

    def observe(self, change: float, centred: np.ndarray, sum_sq: float) -> float:
        """The evidence of a frame whose change from its predecessor is ``change``
        (``1 − ρ``), then learn from it.

        Parameters
        ----------
        change : float
            ``1 − ρ_k``: one minus the correlation of this difference row with the
            previous frame's.
        centred : ndarray of float64, shape (n_places,)
            This frame's difference row less its mean (read, and copied where it is
            kept; the caller may reuse the array afterwards).
        sum_sq : float
            ``Σ centred²``.

        Returns
        -------
        float
            ``log P(s | jump) − log P(s | step)`` from the histograms before this frame.
        """
        if not hasattr(self, "step_counts_"):
            self.reset()
        if not math.isfinite(change):
            self.evidence_ = 0.0
            return 0.0
        b = self._bin(change)
        step, jump = self.step_counts_, self.jump_counts_
        # a change can show a jump, never rule one out: the jump rate also stands for the
        # filter's own errors (a wrong track), which no change between frames reveals
        self.evidence_ = max(0.0, float(math.log(jump[b] / jump.sum()) - math.log(step[b] / step.sum())))
        step *= self._decay
        jump *= self._decay
        step[b] += 1.0
        kept = self._kept
        self._age += 1
        if kept is not None and self._age >= self.apart and sum_sq > 0.0 and self._kept_sq > 0.0:
            rho = _product_sum(centred, kept) / math.sqrt(sum_sq * self._kept_sq)
            if math.isfinite(rho):
                jump[self._bin(1.0 - rho)] += 1.0
        if kept is None or self._age >= 2 * self.apart:
            # keep this frame: compared with the frames apart..2·apart − 1 after it
            if kept is None or len(kept) != len(centred):
                kept = self._kept = np.empty(len(centred))
            np.copyto(kept, centred)
            self._kept_sq = float(sum_sq)
            self._age = 0
        return self.evidence_
