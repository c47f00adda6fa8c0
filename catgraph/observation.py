"""Observation models: from one query frame to a log-likelihood ratio per place.

The particle filter (:mod:`catgraph.localizer`) is indifferent to *how* a frame is
compared with the map. Each step it asks its observation model for

* ``log_ratio`` ``(n_places,)``: ``r_j = log P(z_k | L_k = j) − log P(z_k)`` up to a
  constant shared by all places, the evidence the frame gives for being at place ``j``;
* ``new_place_log_ratio``: the same quantity for the hypothesis "a place not in the
  map", on the same scale (CAT-Graph's new-place particle, paper 2 eq. 10).

A particle between places ``a`` and ``b`` at fraction ``α`` gains the linear
interpolation of the two places' log-ratios, ``(1 − α) r_a + α r_b``. (Paper 2
interpolates the *difference*, ``d = (1 − α) d_a + α d_b``, then looks it up; the
log-ratio interpolation gives the same value at the places themselves, is monotone in
between, and works for every model below, including those whose per-place quantity is a
sequence score rather than a single difference.)

Models (all follow :class:`ObservationModel`: ``reset()``, ``observe(row)``):

:class:`HistogramObservation`
    Paper 2's whole-image model, wrapping :mod:`catgraph.likelihood`:
    ``r_j = log P(d_kj | L) − log P(d_kj)`` from the online histograms of
    :class:`~catgraph.likelihood.HistogramPlaceRecogniser` (``mode="online"``:
    training-free; ``T_init`` frames of initialisation, during which ``r = 0``, the
    filter only moves), or from a given fitted
    :class:`~catgraph.likelihood.HistogramLikelihood` (``"trained"``: fixed;
    ``"bootstrap"``: starts from the fitted model and keeps learning online). The
    new-place ratio is ``log E_{d_s ~ P(d|¬L)} [P(d_s|L)/P(d_s)]``.
:class:`SequenceObservation`
    Paper 1's window scores, wrapping :class:`~catgraph.sequence.SequenceMatcher`:
    the matcher chooses the window ``L_k`` (fixed, or adaptive), the scores
    ``s_kj(L_k)`` of every place are standardised, ``z_j = (s_kj − mean_j) / std_j``,
    and ``z`` is fed to the same online histogram method as a difference would be
    (``d_min = min z`` to ``L``, the smallest ``z`` outside the best match's
    neighbourhood to ``¬L``). So ``r_j = log P(z_j|L) − log P(z_j)``, learned from
    the query itself, no threshold to tune.
:class:`CombinedObservation`
    A tempered product of models: ``r = Σ_m w_m ρ_m r^{(m)}`` (and likewise the
    new-place ratio), ``w_m = 1`` by default; ``ρ_m`` is each part's reliability,
    learned online as how often its own best place agrees with the filter's answer
    (``reliability="online"``, the default; ``None``: ``ρ = 1``, the plain sum of
    log-ratios, exact if the models' errors were independent). A part that is rarely
    right on its own is flattened so that it cannot outvote a reliable one.

:class:`SequenceObservation` also reports a *recent support* per place
(``Observation.support``): ``−log Φ(−z_j)`` of the standardised score at the shortest
window, the evidence of the most recent frames alone, which caps the filter's
confidence (:mod:`catgraph.localizer`).

Every model takes a ``temperature`` ``τ`` (``r ← τ r``); values below 1 flatten an
over-confident model so that one frame cannot wipe out the particle cloud.

Models see the difference row the filter is given — usually the per-query normalised
row (:func:`catgraph.differences.normalise_rows`), which makes histogram ranges
comparable across frames and datasets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import InvalidParameterError, NotFittedError, ShapeMismatchError

__all__ = [
    "Observation",
    "ObservationModel",
    "HistogramObservation",
    "SequenceObservation",
    "CombinedObservation",
    "make_model",
    "MODEL_NAMES",
]


@dataclass(frozen=True)
class Observation:
    """What one query frame says about every place.

    Attributes
    ----------
    log_ratio : ndarray of float64, shape (n_places,)
        Per-place log-likelihood ratio.
    new_place_log_ratio : float
        Log-likelihood ratio of the new-place hypothesis, same scale.
    informative : bool
        False while a model is still initialising (all ratios zero).
    support : ndarray of float64, shape (n_places,), or None
        Optional *recent support* of each place: ``−log`` of the probability that an
        unrelated place would look at least as good over the most recent frames alone
        (:class:`SequenceObservation`: the shortest window). The filter's confidence is
        the smaller of its posterior log-odds and this (:mod:`catgraph.localizer`).
        ``None``: the model has no such measure.
    """

    log_ratio: np.ndarray
    new_place_log_ratio: float
    informative: bool = True
    support: np.ndarray | None = None


@runtime_checkable
class ObservationModel(Protocol):
    """What the particle filter needs from an observation model."""

    def reset(self) -> None:
        """Forget everything learned from earlier query frames."""

    def observe(self, difference_row: np.ndarray) -> Observation:
        """Learn from (if the model learns) and score one query frame.

        Parameters
        ----------
        difference_row : ndarray, shape (n_places,)
            The frame's difference to every reference place (lower = more alike).
        """


def _check_row(row, n_expected: int | None) -> np.ndarray:
    r = check_array(row, "difference row", ndim=1)
    if n_expected is not None and len(r) != n_expected:
        raise ShapeMismatchError(
            f"difference row has {len(r)} places but earlier rows had {n_expected}; "
            "compare every query frame against the same reference map."
        )
    return r


class HistogramObservation:
    """Paper 2's whole-image histogram model as an observation model.

    Parameters
    ----------
    mode : {"online", "trained", "bootstrap"}
        ``"online"``: training-free, learned from the query (``likelihood`` optional as
        a starting point, usually ``None``). ``"trained"``: ``likelihood`` must be
        fitted; it is not changed. ``"bootstrap"``: ``likelihood`` fitted (e.g. from
        :func:`catgraph.likelihood.reference_samples`), learning continues online with
        no initialisation stage.
    likelihood : HistogramLikelihood, optional
        Copied, never modified.
    n_init : int
        Online initialisation frames ``T_init`` (``"online"`` only).
    exclusion_radius : int
        Places ``best ± r`` count as the same location when choosing the ``¬L`` sample.
    temperature : float
        Multiplies every log-ratio.
    new_place_samples : int or None
        Monte Carlo samples for the new-place ratio (``None``: exact expectation).
    seed : int or None
        For the Monte Carlo new-place samples.

    Attributes
    ----------
    recogniser_ : HistogramPlaceRecogniser
        The online learner (its ``model_`` is the current histogram model).
    """

    def __init__(self, mode: str = "online", likelihood=None, n_init: int = 100, exclusion_radius: int = 5,
                 temperature: float = 1.0, new_place_samples: int | None = None, seed: int | None = 0) -> None:
        self.mode = mode
        self.likelihood = likelihood
        self.n_init = n_init
        self.exclusion_radius = exclusion_radius
        self.temperature = temperature
        self.new_place_samples = new_place_samples
        self.seed = seed

    @classmethod
    def bootstrap(cls, reference_differences: np.ndarray, gap: int | None = None, max_different: int = 100_000,
                  seed: int | None = 0, **kwargs) -> "HistogramObservation":
        """A model whose ``¬L`` histogram starts from the reference map itself.

        Parameters
        ----------
        reference_differences : ndarray, shape (n_places, n_places)
            Reference-vs-reference differences, normalised like the query rows will be.
        gap : int, optional
            Reference frames more than ``gap`` apart are different places (default
            ``max(10, n_places // 100)``).
        max_different : int
            ``¬L`` samples drawn.
        seed : int or None
        **kwargs
            Further constructor parameters (``temperature`` …).
        """
        from .likelihood import HistogramLikelihood, reference_samples

        r = check_array(reference_differences, "reference differences", ndim=2)
        gap = max(10, len(r) // 100) if gap is None else gap
        same, different = reference_samples(r, gap=min(gap, len(r) - 2), max_different=max_different, seed=seed)
        return cls(mode="bootstrap", likelihood=HistogramLikelihood().fit(same, different), **kwargs)

    @classmethod
    def trained(cls, differences: np.ndarray, ground_truth, query_index: np.ndarray | None = None,
                seed: int | None = 0, **kwargs) -> "HistogramObservation":
        """A fixed model fitted on a labelled traverse (paper 2's "trained" baseline).

        Parameters
        ----------
        differences : ndarray, shape (n_query, n_places)
            Training query vs reference differences.
        ground_truth : GroundTruth
        query_index : ndarray of int, optional
        seed : int or None
        """
        from .likelihood import HistogramLikelihood, labelled_samples

        same, different = labelled_samples(differences, ground_truth, query_index, seed=seed)
        return cls(mode="trained", likelihood=HistogramLikelihood().fit(same, different), **kwargs)

    def reset(self) -> None:
        self.__dict__.pop("recogniser_", None)
        self.__dict__.pop("_rng", None)

    def _start(self) -> None:
        from .likelihood import HistogramLikelihood, HistogramPlaceRecogniser

        owner = type(self).__name__
        if self.mode not in ("online", "trained", "bootstrap"):
            raise InvalidParameterError(
                f"The 'mode' parameter of {owner} must be 'online', 'trained' or 'bootstrap'. Got {self.mode!r} instead."
            )
        check_scalar(self.temperature, "temperature", owner, float, 0.0, low_inclusive=False)
        if self.mode != "online":
            if not isinstance(self.likelihood, HistogramLikelihood) or not self.likelihood._is_fitted():
                raise NotFittedError(
                    f"{owner}(mode={self.mode!r}) needs a fitted HistogramLikelihood as 'likelihood'; fit one with "
                    "catgraph.likelihood.labelled_samples (trained) or reference_samples (bootstrap)."
                )
        n_init = self.n_init if self.mode == "online" else 0
        self.recogniser_ = HistogramPlaceRecogniser(
            model=self.likelihood, n_init=n_init, exclusion_radius=self.exclusion_radius,
            learn=self.mode != "trained",
        )
        self._rng = np.random.default_rng(self.seed)

    def observe(self, difference_row: np.ndarray) -> Observation:
        if not hasattr(self, "recogniser_"):
            self._start()
        rec = self.recogniser_
        row = _check_row(difference_row, getattr(rec, "n_reference_", None))
        informative = not rec.initialising
        rec.update(row)
        if not informative:
            return Observation(np.zeros(len(row)), 0.0, False)
        model = rec.model_
        tau = float(self.temperature)
        log_ratio = model.log_likelihood_ratio(row)
        new = model.new_place_log_likelihood(self.new_place_samples, self._rng if self.new_place_samples else None)
        return Observation(tau * np.asarray(log_ratio, dtype=np.float64), tau * float(new), True)


class SequenceObservation:
    """Sequence-matching scores, calibrated online into log-likelihood ratios.

    Parameters
    ----------
    window : int or "adaptive"
        Fixed window length, or the adaptive choice of paper 1.
    matcher_params : dict, optional
        Further :class:`~catgraph.sequence.SequenceMatcher` parameters
        (``approximation``, ``rule``, ``l_min``, ``l_max``, ``grid`` …).
    n_init : int
        Frames of online initialisation of the score histograms (ratios 0 meanwhile).
    exclusion_radius : int
        Places ``best ± r`` excluded when choosing the ``¬L`` sample.
    temperature : float
        Multiplies every log-ratio.

    Attributes
    ----------
    matcher_ : SequenceMatcher
    recogniser_ : HistogramPlaceRecogniser
        Online histograms of the standardised scores.
    last_match_ : SequenceMatch
        The matcher's answer for the latest frame.
    """

    def __init__(self, window: int | str = "adaptive", matcher_params: dict | None = None, n_init: int = 20,
                 exclusion_radius: int = 5, temperature: float = 1.0) -> None:
        self.window = window
        self.matcher_params = matcher_params
        self.n_init = n_init
        self.exclusion_radius = exclusion_radius
        self.temperature = temperature

    def reset(self) -> None:
        for k in ("matcher_", "recogniser_", "last_match_", "_scores"):
            self.__dict__.pop(k, None)

    def _start(self) -> None:
        from .likelihood import HistogramPlaceRecogniser
        from .sequence import SequenceMatcher

        check_scalar(self.temperature, "temperature", type(self).__name__, float, 0.0, low_inclusive=False)
        self.matcher_ = SequenceMatcher(window=self.window, **(self.matcher_params or {}))
        self.recogniser_ = HistogramPlaceRecogniser(n_init=self.n_init, exclusion_radius=self.exclusion_radius)

    def window_scores(self, length: int | None = None) -> np.ndarray:
        """``(n_places,)`` scores ``s_kj(L)`` of the latest frame.

        Parameters
        ----------
        length : int, optional
            Window length ``L`` (default: the matcher's chosen window ``L_k``).
        """
        m = self.matcher_
        length = int(self.last_match_.window_length) if length is None else int(length)
        return m.window_scores(length)

    def observe(self, difference_row: np.ndarray) -> Observation:
        if not hasattr(self, "matcher_"):
            self._start()
        row = _check_row(difference_row, getattr(self.matcher_, "n_reference_", None))
        self.last_match_ = self.matcher_.step(row)
        s = self.window_scores()
        sd = s.std()
        z = (s - s.mean()) / sd if sd > 0 else np.zeros_like(s)
        rec = self.recogniser_
        informative = not rec.initialising
        rec.update(z)
        if not informative:
            return Observation(np.zeros(len(row)), 0.0, False)
        tau = float(self.temperature)
        model = rec.model_
        return Observation(tau * np.asarray(model.log_likelihood_ratio(z), dtype=np.float64),
                           tau * float(model.new_place_log_likelihood()), True, self._recent_support())

    def _recent_support(self) -> np.ndarray:
        """``−log Φ(−z_j)``, ``z_j = (mean − s_kj(l)) / std`` at the shortest window ``l``
        of the matcher's grid (the most recent frames only)."""
        from scipy.special import log_ndtr

        s = self.window_scores(int(self.matcher_.window_grid_[0]))
        sd = s.std()
        z = (s.mean() - s) / sd if sd > 0 else np.zeros_like(s)
        return -log_ndtr(-z)


class CombinedObservation:
    """Tempered product of observation models, each part tempered by its reliability.

    ``r_j = Σ_m w_m ρ_m r^{(m)}_j`` (and likewise the new-place ratio). With
    ``reliability="online"``, ``ρ_m`` is learned from the query: the filter reports its
    answer after every step (:meth:`feedback`) and ``ρ_m`` is the posterior mean of a
    Beta(1, 1) on how often the part's own best place lies within the answer's
    tolerance. A part that is rarely right on its own (the single-frame histogram on a
    season change) is flattened towards ratio 1 and can no longer outvote a reliable
    part; where every part is reliable, ``ρ → 1`` and the plain sum of log-ratios is
    recovered. Tempering (an exponent) rather than a mixture with an uninformative
    model keeps a part's negative evidence: a mixture caps it at ``log(1 − ρ)`` while
    its positive evidence stays unbounded, so one spurious peak could outvote a
    reliable part and then, through the feedback, keep its reliability.
    ``reliability=None`` uses ``ρ_m = 1`` (``r = Σ_m w_m r^{(m)}``).

    The feedback is self-referential — the answer it is judged against comes from the
    combined evidence — so a part that dominates from the start keeps a high ``ρ``:
    ``ρ`` measures agreement with the filter, which equals reliability only when the
    filter is mostly right.

    Parameters
    ----------
    models : sequence of ObservationModel
    weights : sequence of float, optional
        Exponents ``w_m`` (default all 1).
    reliability : {"online", None}

    Attributes
    ----------
    reliability_ : ndarray of float64, shape (n_models,)
        Current ``ρ_m``.
    """

    def __init__(self, models: Sequence[ObservationModel], weights: Sequence[float] | None = None,
                 reliability: str | None = "online") -> None:
        self.models = models
        self.weights = weights
        self.reliability = reliability

    def reset(self) -> None:
        for m in self.models:
            m.reset()
        for k in ("reliability_", "_hits", "_trials", "_best"):
            self.__dict__.pop(k, None)

    def feedback(self, near) -> None:
        """Learn each part's reliability from the filter's answer.

        Parameters
        ----------
        near : slice or ndarray of bool, shape (n_places,)
            The places within tolerance of the filter's answer for the latest frame.
        """
        best = getattr(self, "_best", None)
        if best is None or self.reliability is None:
            return
        for m, b in enumerate(best):
            if b < 0:
                continue
            if isinstance(near, slice):
                hit = near.start <= b < near.stop
            else:
                hit = bool(near[b])
            self._hits[m] += hit
            self._trials[m] += 1
        self.reliability_ = (self._hits + 1.0) / (self._trials + 2.0)

    def observe(self, difference_row: np.ndarray) -> Observation:
        if len(self.models) == 0:
            raise InvalidParameterError("CombinedObservation needs at least one model.")
        w = [1.0] * len(self.models) if self.weights is None else list(self.weights)
        if len(w) != len(self.models) or any(not (isinstance(x, (int, float)) and x >= 0) for x in w):
            raise InvalidParameterError(
                f"The 'weights' parameter of CombinedObservation must give one non-negative float per model "
                f"({len(self.models)}). Got {self.weights!r} instead."
            )
        if self.reliability not in ("online", None):
            raise InvalidParameterError(
                f"The 'reliability' parameter of CombinedObservation must be 'online' or None. "
                f"Got {self.reliability!r} instead."
            )
        if not hasattr(self, "_hits"):
            n = len(self.models)
            self._hits, self._trials = np.zeros(n), np.zeros(n)
            self.reliability_ = np.full(n, 0.5 if self.reliability else 1.0)
        parts = [m.observe(difference_row) for m in self.models]
        self._best = [int(np.argmax(p.log_ratio)) if p.informative else -1 for p in parts]
        rho = self.reliability_ if self.reliability else np.ones(len(parts))
        log_ratio, new, supports = None, 0.0, []
        for wi, p, r in zip(w, parts, rho):
            if not p.informative:
                continue
            lr, nr = p.log_ratio, p.new_place_log_ratio
            lr, nr = r * lr, r * nr
            log_ratio = wi * lr if log_ratio is None else log_ratio + wi * lr
            new += wi * nr
            if wi > 0 and p.support is not None:
                supports.append(p.support)
        if log_ratio is None:
            return Observation(np.zeros(len(parts[0].log_ratio)), 0.0, False)
        support = None if not supports else (supports[0] if len(supports) == 1 else np.maximum.reduce(supports))
        return Observation(np.asarray(log_ratio, dtype=np.float64), float(new), True, support)


#: Model names understood by :func:`make_model` (and the command line).
MODEL_NAMES = ("histogram", "sequence", "adaptive", "combined")


def make_model(name: str, window: int = 50, **kwargs) -> ObservationModel:
    """A default observation model by name.

    Parameters
    ----------
    name : {"histogram", "sequence", "adaptive", "combined"}
        ``"histogram"``: :class:`HistogramObservation` (online); ``"sequence"``:
        :class:`SequenceObservation` with a fixed ``window``; ``"adaptive"``: the
        adaptive window; ``"combined"``: histogram + adaptive.
    window : int
        Fixed window length for ``"sequence"``.
    **kwargs
        Passed to the model's constructor (``"combined"``: to both parts' ``temperature``
        only via ``temperature``).
    """
    if name == "histogram":
        return HistogramObservation(**kwargs)
    if name == "sequence":
        return SequenceObservation(window=window, **kwargs)
    if name == "adaptive":
        return SequenceObservation(window="adaptive", **kwargs)
    if name == "combined":
        return CombinedObservation([HistogramObservation(**kwargs), SequenceObservation(window="adaptive", **kwargs)])
    raise InvalidParameterError(f"The 'model' parameter must be one of {list(MODEL_NAMES)}. Got {name!r} instead.")
