"""The standalone single-frame recogniser of paper 2: online histograms, eq. (2) per frame.

The mathematics and the online scheme are in :mod:`catgraph.likelihood`.
"""

from __future__ import annotations

import copy
import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, NotFittedError, ShapeMismatchError
from .histogram import HistogramLikelihood
from .matching import NO_MATCH, NO_OUTPUT_CONFIDENCE
from .samples import OnlineSamples, online_samples

__all__ = ["Recognition", "Recognitions", "HistogramPlaceRecogniser"]


@dataclass(frozen=True)
class Recognition:
    """The answer for one query frame.

    Attributes
    ----------
    match : int
        Best reference index (smallest difference); :data:`~catgraph.matching.NO_MATCH`
        for a frame with no information (every place equally far), which also teaches
        the model nothing.
    confidence : float
        Posterior probability (eq. 2) that the frame is within ``± confidence_radius``
        of ``match``; 0 while initialising or with no match.
    new_place_probability : float
        Posterior probability of the new-place hypothesis; 0 while initialising.
    prob_same : float
        ``P(L | d_min)``: probability that the single best pair shows the same place.
    d_min : float
        The smallest difference.
    initialising : bool
        True during the first ``n_init`` frames (nothing localised).
    """

    match: int
    confidence: float
    new_place_probability: float
    prob_same: float
    d_min: float
    initialising: bool


@dataclass(frozen=True)
class Recognitions:
    """Batch answers, one entry per query row, arrays of shape (n_query,)."""

    match: np.ndarray
    confidence: np.ndarray
    new_place_probability: np.ndarray
    prob_same: np.ndarray
    d_min: np.ndarray
    initialising: np.ndarray


def _blank(row: np.ndarray) -> bool:
    """A row with no information: every place equally far (a blank frame, :mod:`catgraph.matching`)."""
    return bool(row.max() == row.min())


class HistogramPlaceRecogniser:
    """Single-frame place recognition with an (online) histogram model.

    One :meth:`step` per query frame, O(n_ref) time and memory: choose online samples
    (if learning), update the histograms, then localise with eq. (2) under a uniform
    prior over places plus a new-place hypothesis.

    Parameters
    ----------
    model : HistogramLikelihood, optional
        Starting model (copied, never modified). ``None``: a fresh
        ``HistogramLikelihood()`` (training-free). Give a fitted model for the "trained"
        (with ``n_init=0, learn=False``) or "bootstrap" (``n_init=0``) modes.
    n_init : int, default 100
        Initialisation frames ``T_init``: ``d_min`` goes to ``¬L`` only and nothing is
        localised. Needs ``learn=True`` when positive.
    exclusion_radius : int, default 5
        Reference indices ``best ± r`` count as the same location when picking the ``¬L``
        sample.
    confidence_radius : int, default 2
        Confidence is the posterior mass within ``match ± confidence_radius``.
    new_place_prior : float, default 0.01
        Prior probability of a place not in the map (0 disables the hypothesis).
    learn : bool, default True
        Update the histograms with every frame (the paper's online scheme).
    prior_same : "per-place", "model" or float, default "per-place"
        ``P(L)`` used in ``P(d)``. ``"per-place"``: ``1 / n_ref``, the chance that a
        given place is the frame's place (one true place among ``n_ref``). The online
        scheme adds one ``L`` and one ``¬L`` sample per frame, so the paper's
        frequency estimate ``N_L / (N_L + N_¬L)`` would be about 1/2 whatever the map
        size, which caps ``P(d|L)/P(d)`` at about 2 and flattens the posterior.
        ``"model"``: keep the model's own ``prior_same``. A float: that value.
    n_random_different : int, default 5
        After initialisation, also add the differences to this many places drawn
        uniformly (with replacement, seeded) outside the best match's location to
        ``¬L``. The paper's ``¬L`` sample (the smallest difference not from the same
        location) only describes the low tail of ``P(d|¬L)``, while eq. (2) weighs
        *every* place, most of which have typical differences; these samples estimate
        the whole different-place distribution. ``0``: the paper's scheme exactly.
    random_state : int, Generator or None, default 0
        Seed of those draws.
    reference_positions : array_like, shape (n_ref, n_dims), optional
        Metric positions of the reference places (add a floor as a coordinate scaled
        by more than any distance below, to keep floors apart). When given, "the same
        location" is every place within ``exclusion_distance`` of the best match (for
        ``¬L`` samples) and confidence is the posterior mass within
        ``confidence_distance`` of it, instead of the index radii; routes that pass
        a place twice (out and back) then count both visits as that place.
    confidence_distance : float, optional
        Needed with ``reference_positions``.
    exclusion_distance : float, optional
        Default: ``confidence_distance``.

    Attributes
    ----------
    model_ : HistogramLikelihood
        The model in use (after the first :meth:`step`/:meth:`update`).
    n_steps_ : int
        Frames processed.
    """

    def __init__(
        self,
        model: HistogramLikelihood | None = None,
        n_init: int = 100,
        exclusion_radius: int = 5,
        confidence_radius: int = 2,
        new_place_prior: float = 0.01,
        learn: bool = True,
        prior_same: float | str = "per-place",
        n_random_different: int = 5,
        random_state: int | np.random.Generator | None = 0,
        reference_positions: Any = None,
        confidence_distance: float | None = None,
        exclusion_distance: float | None = None,
    ) -> None:
        self.model = model
        self.n_init = n_init
        self.exclusion_radius = exclusion_radius
        self.confidence_radius = confidence_radius
        self.new_place_prior = new_place_prior
        self.learn = learn
        self.prior_same = prior_same
        self.n_random_different = n_random_different
        self.random_state = random_state
        self.reference_positions = reference_positions
        self.confidence_distance = confidence_distance
        self.exclusion_distance = exclusion_distance

    def _start(self) -> None:
        owner = type(self).__name__
        check_scalar(self.n_init, "n_init", owner, int, 0)
        check_scalar(self.exclusion_radius, "exclusion_radius", owner, int, 0)
        check_scalar(self.confidence_radius, "confidence_radius", owner, int, 0)
        check_scalar(self.new_place_prior, "new_place_prior", owner, float, 0.0, 1.0, True, False)
        check_scalar(self.n_random_different, "n_random_different", owner, int, 0)
        self._tree = None
        if self.reference_positions is not None:
            from scipy.spatial import cKDTree

            positions = check_array(self.reference_positions, "reference_positions", ndim=2)
            if self.confidence_distance is None:
                raise InvalidParameterError(
                    f"{owner} with reference_positions needs confidence_distance (the distance within which "
                    "places count as the match's location)."
                )
            check_scalar(self.confidence_distance, "confidence_distance", owner, float, 0.0)
            if self.exclusion_distance is not None:
                check_scalar(self.exclusion_distance, "exclusion_distance", owner, float, 0.0)
            self._positions = positions
            self._tree = cKDTree(positions)
        self._rng = as_generator(self.random_state)
        if not isinstance(self.learn, (bool, np.bool_)):
            raise InvalidParameterError(f"The 'learn' parameter of {owner} must be a bool. Got {self.learn!r} instead.")
        if self.model is not None and not isinstance(self.model, HistogramLikelihood):
            raise InvalidParameterError(
                f"The 'model' parameter of {owner} must be a HistogramLikelihood or None. Got {self.model!r} instead."
            )
        if not self.learn and self.n_init > 0:
            raise InvalidParameterError(
                f"{owner} with learn=False cannot run an initialisation stage; set n_init=0 "
                "and give a fitted model."
            )
        if not self.learn and (self.model is None or not self.model._is_fitted()):
            raise NotFittedError(f"{owner} with learn=False needs a fitted model (fit it, or set learn=True).")
        if not (self.prior_same in ("per-place", "model") or isinstance(self.prior_same, numbers.Real)):
            raise InvalidParameterError(
                f"The 'prior_same' parameter of {owner} must be 'per-place', 'model' or a float in (0, 1). "
                f"Got {self.prior_same!r} instead."
            )
        if isinstance(self.prior_same, numbers.Real):
            check_scalar(self.prior_same, "prior_same", owner, float, 0.0, 1.0, False, False)
        if self.model is None:
            self.model_ = HistogramLikelihood()
            self.model_._initialise()
        else:
            self.model_ = copy.deepcopy(self.model)
            if not self.model_._is_fitted():
                self.model_._initialise()
        if isinstance(self.prior_same, numbers.Real):
            self.model_.prior_same = float(self.prior_same)
        self.n_steps_ = 0

    def _row(self, differences: Any) -> np.ndarray:
        row = check_array(differences, "difference row", ndim=1)
        if self._tree is not None and row.shape[0] != self._positions.shape[0]:
            raise ShapeMismatchError(
                f"difference row has {row.shape[0]} places but reference_positions has {self._positions.shape[0]} "
                "rows; give one position per reference place."
            )
        if hasattr(self, "n_reference_") and row.shape[0] != self.n_reference_:
            raise ShapeMismatchError(
                f"difference row has {row.shape[0]} places but earlier rows had {self.n_reference_}; "
                "compare every frame against the same reference map."
            )
        if not hasattr(self, "n_reference_") and self.prior_same == "per-place":
            self.model_.prior_same = 1.0 / max(row.shape[0], 2)
        self.n_reference_ = row.shape[0]
        return row

    @property
    def initialising(self) -> bool:
        """True while the next frame still belongs to the initialisation stage."""
        return getattr(self, "n_steps_", 0) < self.n_init

    def update(self, differences: Any) -> OnlineSamples:
        """Learn from one frame (once per frame), without localising.

        During initialisation ``d_min`` goes to ``¬L``; afterwards ``d_min`` to ``L`` and
        the smallest difference outside ``best ± exclusion_radius`` to ``¬L``. With
        ``learn=False`` nothing is added. This is the call a particle filter wraps.

        Parameters
        ----------
        differences : array_like, shape (n_ref,)
        """
        if not hasattr(self, "model_"):
            self._start()
        row = self._row(differences)
        return self._update(row)

    def _near(self, best: int, distance: float) -> np.ndarray:
        """Indices of the places within ``distance`` of place ``best`` (positions given)."""
        return np.asarray(self._tree.query_ball_point(self._positions[best], distance), dtype=np.intp)

    def _same_location(self, best: int) -> np.ndarray | None:
        if self._tree is None:
            return None
        distance = self.confidence_distance if self.exclusion_distance is None else self.exclusion_distance
        return self._near(best, distance)

    def _update(self, row: np.ndarray, blank: bool | None = None) -> OnlineSamples:
        best = int(np.argmin(row))
        same_place = self._same_location(best)
        samples = online_samples(row, self.exclusion_radius, same_place)
        blank = _blank(row) if blank is None else blank
        if self.learn and not blank:  # a frame with no information teaches nothing
            if self.n_steps_ < self.n_init:
                self.model_.partial_fit(None, [samples.d_min])
            else:
                other = [] if math.isnan(samples.d_other) else [samples.d_other]
                if self.n_random_different and not math.isnan(samples.d_other):
                    outside = np.ones(row.shape[0], dtype=bool)
                    if same_place is None:
                        outside[max(0, best - self.exclusion_radius) : best + self.exclusion_radius + 1] = False
                    else:
                        outside[same_place] = False
                    drawn = row[self._rng.choice(np.flatnonzero(outside), self.n_random_different)]
                    samples = OnlineSamples(samples.best, samples.d_min, samples.d_other, tuple(drawn.tolist()))
                    other = other + list(samples.d_random)
                self.model_.partial_fit([samples.d_min], other)
        self.n_steps_ += 1
        return samples

    def step(self, differences: Any) -> Recognition:
        """Process one query frame: learn (if enabled), then localise.

        Parameters
        ----------
        differences : array_like, shape (n_ref,)
            The frame's difference to every reference place.

        Returns
        -------
        Recognition
        """
        if not hasattr(self, "model_"):
            self._start()
        row = self._row(differences)
        was_initialising = self.n_steps_ < self.n_init
        blank = _blank(row)
        samples = self._update(row, blank)
        if blank:  # no information: no output (catgraph.matching)
            return Recognition(NO_MATCH, NO_OUTPUT_CONFIDENCE, 0.0, 0.0, samples.d_min, was_initialising)
        if was_initialising:
            return Recognition(samples.best, 0.0, 0.0, 0.0, samples.d_min, True)
        log_post, log_new = self.model_.log_posterior(row, new_place_prior=self.new_place_prior)
        if self._tree is None:
            lo = max(0, samples.best - self.confidence_radius)
            near = log_post[lo : samples.best + self.confidence_radius + 1]
        else:
            near = log_post[self._near(samples.best, self.confidence_distance)]
        confidence = float(np.exp(logsumexp(near)))
        prob_same = float(self.model_.prob_same_given(samples.d_min))
        return Recognition(samples.best, min(confidence, 1.0), float(np.exp(log_new)), prob_same, samples.d_min, False)

    def run(self, differences: Any) -> Recognitions:
        """:meth:`step` over every row of a difference matrix, in order.

        Parameters
        ----------
        differences : array_like, shape (n_query, n_ref), or DifferenceRows
            The rows, or the rows block by block
            (:class:`~catgraph.differences.DifferenceRows`: one block in memory at a time).

        Returns
        -------
        Recognitions
        """
        from .observation import query_rows

        _, rows = query_rows(differences)
        out = [self.step(row) for row in rows]
        return Recognitions(
            match=np.array([r.match for r in out], dtype=np.int64),
            confidence=np.array([r.confidence for r in out]),
            new_place_probability=np.array([r.new_place_probability for r in out]),
            prob_same=np.array([r.prob_same for r in out]),
            d_min=np.array([r.d_min for r in out]),
            initialising=np.array([r.initialising for r in out], dtype=bool),
        )
