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

:class:`TemperedObservation`
    The whole-image model that localises on real data: the per-query normalised
    difference, a hub correction where the map has hubs, and a temperature learned
    from how often the frame's own best place survives the filter's weighing
    (:meth:`ObservationModel.feedback`). It learns from the filter, not from ``d_min``.

:class:`SequenceObservation` also reports a *recent support* per place
(``Observation.support``): ``−log Φ(−z_j)`` of the standardised score at the shortest
window, the evidence of the most recent frames alone, which caps the filter's
confidence (:mod:`catgraph.localizer`).

Every single model takes a ``temperature`` ``τ`` (``r ← τ r``); values below 1 flatten an
over-confident model so that one frame cannot wipe out the particle cloud. (A
:class:`CombinedObservation` tempers through its parts and their ``weights``.)

Per frame, a model makes a handful of passes over the places, and at 10⁵ places and more
those passes are the model's cost: the arithmetic writes into work arrays kept between
frames instead of allocating temporaries; consecutive elementwise passes run as one
compiled pass (:mod:`catgraph._observation_kernels`: the tempered model's ratios, their
maximum and the frame's best place together; centring with squaring; the hub count with
the centred levels); the hub statistic's median and MAD, which move little from frame
to frame, are selected among the few levels near the previous frame's
(:class:`_NearMedian`, exact); the previous frame's centred row is kept for the novelty
weight; and what no caller reads is not computed (the recent support is computed for the
places read, its window scores on the first read, :class:`RecentSupport`; the filter
forms the predicted masses only for a model whose feedback reads them,
:func:`feedback_reads_prior`). Sums fused into a compiled pass (the novelty weight's
``Σ a²`` and ``Σ a b``, the window scores' spread, the support's mean and spread) replay
numpy's pairwise order; a maximum found in a pass is handed on (``Observation.log_ratio_max``,
``FilterFeedback.posterior_max``) rather than taken again; the per-place arrays handed
out every frame come from a :class:`FramePool` instead of fresh pages. Every value goes
through the same IEEE operations as in the plain formulas and every sum is numpy's
float, so the floats are those of the plain formulas (``tests/test_likelihood.py``,
``tests/test_observation_kernels.py`` and ``tests/test_observation_identity.py`` check
them bit for bit; ``benchmarks/bench_models.py`` times and checks the models against an
earlier version).

Models see the difference row the filter is given — usually the per-query normalised
row (:func:`catgraph.differences.normalise_rows`), which makes histogram ranges
comparable across frames and datasets.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from ._validation import as_generator, check_array, check_scalar
from .exceptions import InvalidParameterError, NotFittedError, ShapeMismatchError
from .jumps import JumpEvidence

__all__ = [
    "CheckedRow",
    "Observation",
    "FilterFeedback",
    "ObservationModel",
    "TemperedObservation",
    "HistogramObservation",
    "SequenceObservation",
    "CombinedObservation",
    "RecentSupport",
    "predictive_weight_grid",
    "feedback_reads_prior",
    "FramePool",
    "DEFAULT_PART_WEIGHTS",
    "UNREAD_CONFIDENCE",
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
    support : ndarray of float64 of shape (n_places,), RecentSupport, or None
        Optional *recent support* of each place: ``−log`` of the probability that an
        unrelated place would look at least as good over the most recent frames alone
        (:class:`SequenceObservation`: the shortest window, as a :class:`RecentSupport`,
        which computes the places read: ``support[near]``; ``np.asarray(support)`` gives
        all). The filter's confidence is the smaller of its posterior log-odds and this
        (:mod:`catgraph.localizer`). ``None``: the model has no such measure.
    log_ratio_max : float or None
        ``log_ratio.max()`` where the model found it in a pass it made anyway (the
        filters then skip their own pass for it); ``None``: not known.
    jump_evidence : float
        Log-likelihood ratio of "the query jumped since the previous frame" against
        "it moved on", from the frame alone (:mod:`catgraph.jumps`); the filters turn
        it into the frame's jump rate (:func:`catgraph.jumps.frame_jump_rate`). 0: no
        evidence either way.
    """

    log_ratio: np.ndarray
    new_place_log_ratio: float
    informative: bool = True
    support: np.ndarray | None = None
    log_ratio_max: float | None = None
    jump_evidence: float = 0.0


@dataclass(frozen=True)
class FilterFeedback:
    """What a filter tells its observation model after each frame.

    Attributes
    ----------
    prior : ndarray of float64, shape (n_places,), or None
        Predicted place masses before the frame (given the map; sums to 1). A filter
        may leave it ``None`` for a model whose ``_reads_prior()`` says it does not read
        it (:func:`feedback_reads_prior`; the particle filter then skips forming it).
    posterior : ndarray of float64, shape (n_places,)
        Place masses after the frame (the map's share, ``1 − P(new)`` in all).
    near : slice or ndarray of bool, shape (n_places,)
        The places counted in the answer's confidence.
    posterior_max : float or None
        ``posterior.max()`` where the filter found it while forming the posterior;
        ``None``: not known.
    """

    prior: np.ndarray
    posterior: np.ndarray
    near: slice | np.ndarray
    posterior_max: float | None = None


@runtime_checkable
class ObservationModel(Protocol):
    """What the particle filter needs from an observation model."""

    def reset(self) -> None:
        """Forget everything learned from earlier query frames."""

    def feedback(self, feedback: FilterFeedback) -> None:
        """Learn from the filter's answer to the latest frame (a no-op for most models)."""

    def observe(self, difference_row: np.ndarray) -> Observation:
        """Learn from (if the model learns) and score one query frame.

        Parameters
        ----------
        difference_row : ndarray, shape (n_places,)
            The frame's difference to every reference place (lower = more alike).
        """


#: Which filter last reset each model: ``id(model) -> (weakref to the model, weakref to the filter)``.
_SERVING: dict[int, tuple] = {}


def claim_model(model, owner) -> None:
    """Record that the filter ``owner`` has reset ``model`` and steps it from now on
    (called by the filters' ``reset``; see :func:`check_model`)."""
    import weakref

    try:
        refs = (weakref.ref(model), weakref.ref(owner))
    except TypeError:  # not weakly referable: nothing can be checked
        return
    if len(_SERVING) > 256:  # forget the models that are gone
        for key in [k for k, (m, _) in _SERVING.items() if m() is None]:
            del _SERVING[key]
    _SERVING[id(model)] = refs


def check_model(model, owner) -> None:
    """Refuse a step of ``owner`` with a model that another filter has reset since ``owner``
    did (called by the filters' ``step``).

    A model learns from the rows and the feedback of the filter that steps it (its
    temperature, hub levels, histograms, the matcher's ring); two filters stepping one
    instance in turn would mix two queries' evidence and give both wrong answers without a
    word. One model may serve one filter after another (each ``reset`` starts it afresh);
    a copy of a filter steps its own copy of the model.

    Raises
    ------
    InvalidParameterError
        Another filter has reset ``model`` since ``owner`` did.
    """
    held = _SERVING.get(id(model))
    if held is not None and held[1]() is not owner and held[0]() is model:
        raise InvalidParameterError(
            f"this {type(model).__name__} now serves another filter, which reset it after this one did, and a "
            "model learns from the frames of the filter that steps it; give each filter its own model (a new "
            "instance, or copy.deepcopy(model)).")


class CheckedRow(np.ndarray):
    """A difference row a filter has already validated (1-D, float64, finite).

    The filters check each row once at their public boundary and hand it to the model
    as this view; a model's own check then only compares its length. Any other array
    is checked in full.
    """


def query_rows(observations, n_places: int | None = None) -> tuple[int, Iterator[np.ndarray]]:
    """A run's difference rows: ``(n_query, rows)``, ``rows`` an iterator of checked rows
    (:class:`CheckedRow`) in processing order (the filters' and the recogniser's ``run``), of
    ``n_places`` places each where given.

    ``observations`` is an ``(n_query, n_places)`` matrix, checked whole here, or a
    :class:`~catgraph.differences.DifferenceRows`, each block checked as it comes: one block
    in memory at a time, never the matrix.
    """
    from .differences import DifferenceRows

    if isinstance(observations, DifferenceRows):
        n, width = len(observations), observations.n_places
        rows = (row for _, block in observations.checked() for row in block.view(CheckedRow))
    else:
        observations = check_array(observations, "difference matrix", ndim=2)
        n, width = observations.shape
        rows = iter(observations.view(CheckedRow))  # checked once, here
    if n_places is not None and width != n_places:
        raise ShapeMismatchError(
            f"the difference matrix has {width} places but the graph has {n_places}; "
            "give every frame's difference to every reference place of the map.")
    return n, rows


def _reference_counts() -> tuple[int, int]:
    """What ``sys.getrefcount`` reports on this interpreter for an object that only a
    list holds (read as ``getrefcount(items[k])``) and for one that only a local name
    holds (interpreters differ in the references a call adds, so the counts are
    measured, not assumed)."""
    import sys

    items = [np.empty(0)]
    in_list = sys.getrefcount(items[0])
    holder = {"x": np.empty(0)}
    alone = holder.pop("x")
    return in_list, sys.getrefcount(alone)


#: ``sys.getrefcount`` of an object held only by a list, and only by a local name
_ONLY_LISTED, _ONLY_LOCAL = _reference_counts()


class FramePool:
    """Float64 arrays handed out once per frame, reused once nobody else holds them.

    A model or filter hands out new per-place arrays every frame (ratios, place masses,
    posteriors). Allocating ``N`` float64 anew costs the operating system's page faults
    on every frame — measured on this project's machine about 0.5 ms per 10⁵ places, as
    much as a pass over them — so the arrays are taken from a small pool instead: an
    array is taken again only when the pool's is the only reference left (CPython's
    reference count: no caller, attribute, observation or view holds it), so an array
    someone kept is never written again, exactly as a fresh one would not be. At most
    ``size`` arrays are pooled; beyond them (a caller keeping every frame's) arrays are
    allocated as before.

    Parameters
    ----------
    size : int
    """

    __slots__ = ("_arrays", "_size")

    def __init__(self, size: int = 4) -> None:
        self._arrays: list[np.ndarray] = []
        self._size = size

    def take(self, shape: int | tuple[int, ...], dtype=np.float64) -> np.ndarray:
        """An uninitialised array of ``shape`` (``(n,)`` for an int) and ``dtype`` (float64
        unless given) no one else holds."""
        import sys

        shape = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(shape)
        dtype = np.dtype(dtype)
        arrays = self._arrays
        for k in range(len(arrays)):
            # the list's reference (and the call's): nobody else's
            # (no local name for it: a name is a reference too)
            if (arrays[k].shape == shape and arrays[k].dtype == dtype
                    and sys.getrefcount(arrays[k]) <= _ONLY_LISTED):
                return arrays[k]
        out = np.empty(shape, dtype)
        if len(arrays) < self._size:
            arrays.append(out)
        return out


def _pool(owner, name: str = "_pool") -> FramePool:
    """``owner``'s :class:`FramePool` (made on first use; kept in its ``__dict__``)."""
    pool = owner.__dict__.get(name)
    if pool is None:
        pool = owner.__dict__[name] = FramePool()
    return pool


def feedback_reads_prior(model) -> bool:
    """Whether ``model.feedback`` reads :attr:`FilterFeedback.prior`: the model's own
    ``_reads_prior()`` where it has one, else True (a model that does not say is
    given the prior)."""
    says = getattr(model, "_reads_prior", None)
    return True if says is None else bool(says())


def _check_row(row, n_expected: int | None) -> np.ndarray:
    if type(row) is CheckedRow:
        r = row.view(np.ndarray)
    else:
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
    n_random_different : int
        ``¬L`` samples drawn each frame at random places outside the best match's
        location, beside the paper's one (the smallest difference there): see
        :class:`~catgraph.likelihood.HistogramPlaceRecogniser`. ``0``: paper 2's online
        scheme exactly.
    seed : int or None
        Draws those random ``¬L`` samples and the Monte Carlo new-place samples.

    Attributes
    ----------
    recogniser_ : HistogramPlaceRecogniser
        The online learner (its ``model_`` is the current histogram model).
    """

    def __init__(self, mode: str = "online", likelihood=None, n_init: int = 100, exclusion_radius: int = 5,
                 temperature: float = 1.0, new_place_samples: int | None = None, n_random_different: int = 5,
                 seed: int | None = 0) -> None:
        self.mode = mode
        self.likelihood = likelihood
        self.n_init = n_init
        self.exclusion_radius = exclusion_radius
        self.temperature = temperature
        self.new_place_samples = new_place_samples
        self.n_random_different = n_random_different
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
            :func:`catgraph.samples.default_bootstrap_gap`: 50, or a fifth of a short route).
        max_different : int
            ``¬L`` samples drawn.
        seed : int or None
        **kwargs
            Further constructor parameters (``temperature`` …).
        """
        from .likelihood import HistogramLikelihood, reference_samples
        from .samples import default_bootstrap_gap

        r = check_array(reference_differences, "reference differences", ndim=2)
        gap = default_bootstrap_gap(len(r)) if gap is None else gap  # a gap given is checked as given
        same, different = reference_samples(r, gap=gap, max_different=max_different, seed=seed)
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

    def feedback(self, feedback: FilterFeedback) -> None:
        """Paper 2's model learns from the frames alone: nothing to do."""

    def _reads_prior(self) -> bool:
        return False

    def _start(self) -> None:
        from .likelihood import HistogramLikelihood, HistogramPlaceRecogniser

        owner = type(self).__name__
        if self.mode not in ("online", "trained", "bootstrap"):
            raise InvalidParameterError(
                f"The 'mode' parameter of {owner} must be 'online', 'trained' or 'bootstrap'. Got {self.mode!r} instead."
            )
        check_scalar(self.temperature, "temperature", owner, float, 0.0, low_inclusive=False)
        if self.new_place_samples is not None:
            check_scalar(self.new_place_samples, "new_place_samples", owner, int, 1)
        if self.mode != "online":
            if not isinstance(self.likelihood, HistogramLikelihood) or not self.likelihood._is_fitted():
                raise NotFittedError(
                    f"{owner}(mode={self.mode!r}) needs a fitted HistogramLikelihood as 'likelihood'; fit one with "
                    "catgraph.likelihood.labelled_samples (trained) or reference_samples (bootstrap)."
                )
        n_init = self.n_init if self.mode == "online" else 0
        self.recogniser_ = HistogramPlaceRecogniser(
            model=self.likelihood, n_init=n_init, exclusion_radius=self.exclusion_radius,
            learn=self.mode != "trained", n_random_different=self.n_random_different, random_state=self.seed,
        )
        self._rng = as_generator(self.seed)

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


#: The confidence of a :class:`SequenceObservation`'s matcher unless its ``matcher_params``
#: name one: the model reads the matcher's window, velocity and scores and never its
#: confidence (``tests/test_combined_confidence.py``), so the matcher forms the cheapest,
#: ``-log p`` of the chosen window, which keeps nothing. The matcher's own default,
#: ``"changepoint"``, keeps the latest four rows for it (``32 N`` bytes: 3.2 MB at 10⁵
#: places, 32 MB at 10⁶) and reads them every frame.
UNREAD_CONFIDENCE = "neglogp"


class SequenceObservation:
    """Sequence-matching scores, calibrated online into log-likelihood ratios.

    Parameters
    ----------
    window : int or "adaptive"
        Fixed window length, or the adaptive choice of paper 1.
    matcher_params : dict, optional
        Further :class:`~catgraph.sequence.SequenceMatcher` parameters
        (``approximation``, ``rule``, ``l_min``, ``l_max``, ``grid`` …). The rule, unless
        given, is :data:`~catgraph.sequence.DEFAULT_LINE_RULE` (the filter that reads
        these scores is the tracker; the matcher's default rule "tracked" would run
        another one inside the model). The confidence, unless given, is
        :data:`UNREAD_CONFIDENCE`: the model reads the matcher's window, velocity and
        scores, never its confidence.
    n_init : int
        Frames of online initialisation of the score histograms (ratios 0 meanwhile).
    exclusion_radius : int
        Places ``best ± r`` excluded when choosing the ``¬L`` sample.
    temperature : float, "window" or "longest"
        Multiplies every log-ratio. ``"window"``: ``1 / L_k``, the frame's window length:
        consecutive frames' window scores share ``L − 1`` of their ``L`` frames, so a
        filter that multiplies them frame after frame counts each frame's evidence
        about ``L`` times; ``1 / L_k`` counts it about once while the window keeps its
        length. Where the adaptive window changes length it does not: frame ``i`` is
        counted ``Σ_{k : i ∈ W_k} 1 / L_k`` times, up to ``Σ_{d < L_max} 1 / (d + 1)
        ≈ ln L_max + 0.58`` (6.8 for windows up to 500 frames) when each window is
        just long enough to reach it, and the short windows the matcher picks on a
        hard stretch weigh up to 30 times more per frame than the long ones around them.
        ``"longest"``: ``1 / M_k``, ``M_k = max_{k' ≤ k} L_{k'}`` the longest window
        the matcher has chosen so far. A frame lies in at most ``M`` windows while the
        longest stays ``M``, so it is counted at most once (``1 + ln(M_end / M_i)`` at
        most over a traverse whose longest window grows from ``M_i`` to ``M_end``),
        whatever lengths the matcher picks meanwhile (``docs/particle_filter.md``,
        "the combined model counts each frame at most once").
    calibration : {"online", "agreement"}
        How standardised scores ``z`` become log-ratios. ``"online"`` (default): paper 2's
        online histograms, ``P(z|L)`` learned from each frame's best ``z``. On a shuffled
        query that sample is mostly wrong (a window across a jump matches neither line and
        still names a place), so the ratios stand 8–11 nats above the row's median whether
        the best place is right or wrong (``docs/particle_filter.md``). ``"agreement"``:
        the tempered model's linear ratio ``−z`` (:class:`TemperedObservation`, no hub
        correction, no novelty weight) at the temperature ``agreement_scale · ρ``, ``ρ`` how
        probable the part's own best place is after the filter has weighed it — a part
        that the filter rarely confirms is flattened.
    agreement_scale : float
        ``τ`` per unit of agreement for ``calibration="agreement"``.

    Attributes
    ----------
    matcher_ : SequenceMatcher
    recogniser_ : HistogramPlaceRecogniser
        Online histograms of the standardised scores.
    last_match_ : SequenceMatch
        The matcher's answer for the latest frame (its confidence the matcher's
        ``confidence``: :data:`UNREAD_CONFIDENCE` unless ``matcher_params`` names one).
    """

    def __init__(self, window: int | str = "adaptive", matcher_params: dict | None = None, n_init: int = 20,
                 exclusion_radius: int = 5, temperature: float | str = 1.0, calibration: str = "online",
                 agreement_scale: float = 4.0) -> None:
        self.window = window
        self.matcher_params = matcher_params
        self.n_init = n_init
        self.exclusion_radius = exclusion_radius
        self.temperature = temperature
        self.calibration = calibration
        self.agreement_scale = agreement_scale

    def reset(self) -> None:
        for k in ("matcher_", "recogniser_", "last_match_", "_scores", "_tempered", "_z", "_exp", "_square",
                  "_support", "_longest"):
            self.__dict__.pop(k, None)

    def feedback(self, feedback: FilterFeedback) -> None:
        """``"online"``: the score histograms learn from the frames alone, nothing to do;
        ``"agreement"``: the tempered calibration learns how often the filter confirms
        the part's best place."""
        tempered = getattr(self, "_tempered", None)
        if tempered is not None:
            tempered.feedback(feedback)

    def _reads_prior(self) -> bool:
        # the agreement calibration's tempered model has the default, agreement temperature
        tempered = getattr(self, "_tempered", None)
        return False if tempered is None else tempered._reads_prior()

    def _start(self) -> None:
        from .likelihood import HistogramPlaceRecogniser
        from .sequence import DEFAULT_LINE_RULE, SequenceMatcher

        owner = type(self).__name__
        if self.temperature not in ("window", "longest"):
            check_scalar(self.temperature, "temperature", owner, float, 0.0, low_inclusive=False)
        self._longest = 1  # the longest window chosen so far (temperature "longest")
        if self.calibration not in ("online", "agreement"):
            raise InvalidParameterError(f"The 'calibration' parameter of {owner} must be 'online' or 'agreement'. "
                                        f"Got {self.calibration!r} instead.")
        check_scalar(self.agreement_scale, "agreement_scale", owner, float, 0.0, low_inclusive=False)
        params = {"rule": DEFAULT_LINE_RULE, **(self.matcher_params or {})}
        if params["rule"] != "tracked":  # rule "tracked" has its own confidence (refused with any other)
            params.setdefault("confidence", UNREAD_CONFIDENCE)
        import inspect

        allowed = set(inspect.signature(SequenceMatcher).parameters) - {"window"}
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise InvalidParameterError(
                f"The 'matcher_params' parameter of {owner} names {unknown}, which SequenceMatcher does not take "
                f"here; choose from {sorted(allowed)} (the window is this model's own 'window').")
        self.matcher_ = SequenceMatcher(window=self.window, **params)
        self.recogniser_ = HistogramPlaceRecogniser(n_init=self.n_init, exclusion_radius=self.exclusion_radius)
        self._tempered = (TemperedObservation(hub=None, novelty=False, jump_evidence=False,
                                              temperature_scale=self.agreement_scale)
                          if self.calibration == "agreement" else None)
        if self._tempered is not None:
            self._tempered._new_place = False  # this model computes its own from the tempered ratios

    def window_scores(self, length: int | None = None) -> np.ndarray:
        """``(n_places,)`` scores ``s_kj(L, v)`` of the latest frame, along the lines of
        the velocity ``v`` the matcher chose for it (its velocity search: a query driven
        backwards or at another speed is scored along its own lines, not the diagonal).

        Parameters
        ----------
        length : int, optional
            Window length ``L`` (default: the matcher's chosen window ``L_k``).
        """
        m = self.matcher_
        length = int(self.last_match_.window_length) if length is None else int(length)
        return m.window_scores(length, float(self.last_match_.velocity))

    def observe(self, difference_row: np.ndarray) -> Observation:
        if not hasattr(self, "matcher_"):
            self._start()
        row = _check_row(difference_row, getattr(self.matcher_, "n_reference_", None))
        self._settle_support()
        self.last_match_ = self.matcher_.step(row.view(CheckedRow))  # checked above: the matcher does not scan it again
        s = self.window_scores()
        if self.temperature == "window":
            tau = 1.0 / max(int(self.last_match_.window_length), 1)
        elif self.temperature == "longest":
            self._longest = max(self._longest, int(self.last_match_.window_length))
            tau = 1.0 / self._longest
        else:
            tau = float(self.temperature)
        fused = self._tempered is not None and self._tempered._takes_standardised(s)
        if fused:  # the mean and the spread; the centring and the division come with the ratios
            mean = s.mean()
            sd = np.sqrt(_kernels().centred_sums(s, mean, _NOTHING, _NOTHING)[0] / len(s))  # s.std()
            fused = sd > 0
            if not fused:  # every score equal: the standardised scores are all 0
                z = self._work("_z", len(s))
                z[...] = 0.0
        else:
            # the squares' scratch is the exponentials' array, written only after z is formed
            z = _standardised(s, self._work("_z", len(s)), self._work("_exp", len(s)))
        if fused:
            # z = (s − mean) / sd, the tempered ratios and the window temperature in one pass
            # (z is not formed: its array, the earlier frames', is freed)
            self.__dict__.pop("_z", None)
            r, top = self._tempered._observe_standardised(s, mean, sd, tau)
        elif self._tempered is not None:
            r = self._tempered.observe(z).log_ratio
            r *= tau  # the tempered model's array is fresh every frame
            top = float(r.max())
        if self._tempered is not None:
            work = self._work("_exp", len(r))
            np.subtract(r, top, out=work)
            np.exp(work, out=work)
            return Observation(r, top + math.log(float(np.mean(work))), True, self._recent_support(), top)
        rec = self.recogniser_
        informative = not rec.initialising
        rec.update(z)
        if not informative:
            return Observation(np.zeros(len(row)), 0.0, False)
        model = rec.model_
        return Observation(tau * np.asarray(model.log_likelihood_ratio(z), dtype=np.float64),
                           tau * float(model.new_place_log_likelihood()), True, self._recent_support())

    def _recent_support(self) -> "RecentSupport":
        """``−log Φ(−z_j)``, ``z_j = (mean − s_kj(l)) / std`` at the shortest window ``l``
        of the matcher's grid (the most recent frames only), computed where it is read.

        The window scores themselves (a pass over the places) are formed on the first
        read: a filter that never reads the support (the grid filter) never pays for
        them. Before the matcher takes the next frame, a support still held by someone
        forms them (:meth:`_settle_support`), so it keeps this frame's values."""
        m = self.matcher_
        scores = _SupportScores(m, m.n_steps_, int(m.window_grid_[0]), float(self.last_match_.velocity))
        support = RecentSupport(None, scores)
        self._support = support
        return support

    def _settle_support(self) -> None:
        """Form the latest support's scores now if anyone besides this model still holds
        it (the matcher is about to move on); drop it otherwise."""
        import sys

        support = self.__dict__.pop("_support", None)
        # more references than this local name's (and the call's): someone holds it
        if support is not None and sys.getrefcount(support) > _ONLY_LOCAL:
            support._values()

    def _work(self, name: str, n: int) -> np.ndarray:
        """A float64 work array of length ``n`` kept between frames."""
        buf = self.__dict__.get(name)
        if buf is None or len(buf) != n:
            buf = np.empty(n)
            setattr(self, name, buf)
        return buf


class _SupportScores:
    """The window scores a :class:`RecentSupport` forms on its first read: the matcher's at
    one length and velocity, while the matcher is still at the frame they belong to. A
    plain object (not a closure), so that a model holding one pickles."""

    __slots__ = ("matcher", "steps", "length", "velocity")

    def __init__(self, matcher, steps: int, length: int, velocity: float) -> None:
        self.matcher, self.steps, self.length, self.velocity = matcher, steps, length, velocity

    def __call__(self) -> np.ndarray:
        if self.matcher.n_steps_ != self.steps:
            raise NotFittedError("this recent support belongs to an earlier frame of the matcher, which has "
                                 "moved on; read an observation's support before stepping its matcher directly.")
        return self.matcher.window_scores(self.length, self.velocity)


class RecentSupport:
    """A recent support ``−log Φ(−z_j)``, ``z_j = (mean − s_j) / std`` of window scores
    ``s``, computed only for the places read.

    A filter reads the support at the few places near its answer (the particle filter's
    confidence score), or not at all (the grid filter); the normal tail of every place
    costs several milliseconds per frame at 10⁵ places. Indexing (``support[near]``)
    computes the selected places; ``np.asarray(support)`` (or :meth:`copy`) all of them,
    once. Either gives the same floats: the scores' mean and standard deviation are taken
    over all places, each place's value is the same elementwise arithmetic.

    Parameters
    ----------
    scores : ndarray of float64, shape (n_places,), or None
        The window scores, owned by this object from now on.
    source : callable, optional
        With ``scores=None``: returns the scores, called once, on the first read.
    """

    __slots__ = ("_scores", "_moments", "_all", "_source")

    def __init__(self, scores: np.ndarray | None, source=None) -> None:
        self._scores = scores
        self._source = source
        self._moments = None
        self._all = None

    def _values(self) -> np.ndarray:
        if self._scores is None:
            self._scores, self._source = self._source(), None
        return self._scores

    @property
    def shape(self) -> tuple[int, ...]:
        return self._values().shape

    def __len__(self) -> int:
        return len(self._values())

    def form(self) -> "RecentSupport":
        """Form the window scores and their mean and standard deviation over every place
        now (what the first read forms; a filter may have them formed on another thread
        while it works, as long as the matcher does not step meanwhile)."""
        if self._moments is None:
            scores = self._values()
            if _plain_row(scores) and len(scores) > 0:  # numpy's mean and std (its sums), two passes
                mean, sd = _kernels().mean_std(scores)
                self._moments = (np.float64(mean), np.float64(sd))
            else:
                sd = scores.std()
                self._moments = (scores.mean(), sd)
        return self

    def _support(self, s: np.ndarray) -> np.ndarray:
        from scipy.special import log_ndtr

        mean, sd = self.form()._moments
        if not sd > 0:
            return -log_ndtr(-np.zeros_like(s))
        out = np.subtract(mean, s)  # z, then −log Φ(−z), in one fresh array
        out /= sd
        np.negative(out, out=out)
        log_ndtr(out, out=out)
        np.negative(out, out=out)
        return out

    def __getitem__(self, key) -> np.ndarray:
        if self._all is not None:
            return self._all[key]
        return self._support(np.atleast_1d(self._values()[key]))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        if self._all is None:
            self._all = self._support(self._values())
        if dtype is not None:
            return self._all.astype(dtype)
        return self._all.copy() if copy else self._all

    def copy(self) -> np.ndarray:
        """Every place's support, as a new array."""
        return np.array(self.__array__())


#: The largest weight of a part of a :class:`CombinedObservation` (a larger one would only
#: overflow the tempered log-ratios it multiplies).
MAX_PART_WEIGHT = 1e6


def _blank_row(row: np.ndarray) -> bool:
    """:func:`catgraph.recogniser._blank` (imported where first needed: it brings scipy)."""
    from .recogniser import _blank

    return _blank(row)


def _is_predictive(weights) -> bool:
    """Whether a combined model's ``weights`` ask for the predictive choice (an array of
    weights is not the string)."""
    return isinstance(weights, str) and weights == "predictive"


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

    **Weights learned online** (``weights="predictive"``): prequential model choice
    among a grid of weight vectors ``w^{(c)}`` (``weight_grid``; by default the first
    part at 1 and every other part at each of :data:`DEFAULT_PART_WEIGHTS`). After each
    frame the filter reports the place masses it predicted before seeing the frame
    (:attr:`FilterFeedback.prior`, ``π``); each candidate is scored by how much better
    that prediction explains the frame than a uniform guess would, under the candidate's
    own combination ``r^{(c)} = Σ_m w^{(c)}_m r^{(m)}``:

    ``S_c ← γ S_c + log Σ_j π_j e^{r^{(c)}_j} − log mean_j e^{r^{(c)}_j}``,

    ``γ = 2^{−1/memory}``, and the next frame is combined with the best candidate's
    weights (:attr:`weights_`; the candidate closest to the plain sum, all weights 1,
    until the first frame is scored). The score is the log predictive Bayes factor of
    the filter's prediction against the uniform one — the same score
    :class:`TemperedObservation` uses for its temperature with
    ``temperature="predictive"`` — so it needs no ground truth and no threshold: a part
    whose peaks fall where the filter's own motion expected the place gains weight, a
    part whose peaks fall elsewhere loses it, and a weight of 0 switches it off.

    Measured with the grid filter on the whole condition table
    (``benchmarks/results/combined.md``), the score prefers the largest sequence weight
    (2) on almost every frame of every traverse; with the sequence part at
    ``temperature="window"`` the filter was then worse than with the plain sum where the
    sequence part hurts (Nordland in order, speed 2, speed 0.5, UJI's short shuffles),
    and with ``"longest"`` (the registry's) it is within 0.005 of the plain sum in every
    dataset's mean, 0.042 lower on Nordland's 0.5–3 % shuffle of seed 2: the filter's prediction already holds the evidence of the
    frames the sequence part's window shares with the previous windows, so the part
    explains the frame well whether or not it is right, and a sharper weighting of a
    part that agrees with the prediction always scores higher. The option stays
    available; the registry's ``combined`` model uses the plain sum.

    Cost: the ``K`` candidates are scored over every place (the prior mixes a uniform
    recovery share, so it has no smaller support). Each part's candidate weights that
    are integer multiples ``k δ`` of their smallest (the default grid: ``δ = 0.25``,
    ``k ∈ {1, 2, 4, 8}``) share one exponential ``e^{δ (r − max r)}``, raised to ``k`` by
    multiplication of its squares, so the default grid costs two exponentials per place
    (numpy's), three squarings and one compiled pass per candidate
    (:func:`catgraph._observation_kernels.product_sums`: both sums at once). The floats agree with the plain formula to round-off
    (``tests/test_observation_combined.py``: 1e-12); where a candidate's sums fall
    below ``1e-200`` (its parts' peaks hundreds of nats apart) it is computed by the
    plain formula instead.

    Parameters
    ----------
    models : sequence of ObservationModel
    weights : sequence of float, "predictive", optional
        Exponents ``w_m`` (default all 1), or ``"predictive"``: learned online.
    reliability : {"online", None}
    weight_grid : array_like of shape (n_candidates, n_models), optional
        The candidates of ``weights="predictive"`` (non-negative; default
        :func:`predictive_weight_grid`).
    memory : float
        Half-life, in frames, of the candidates' scores.

    Attributes
    ----------
    reliability_ : ndarray of float64, shape (n_models,)
        Current ``ρ_m``.
    weights_ : ndarray of float64, shape (n_models,)
        The weights the next frame is combined with.
    weight_scores_ : ndarray of float64, shape (n_candidates,)
        Discounted predictive scores ``S_c`` (``weights="predictive"``).
    weight_grid_ : ndarray of float64, shape (n_candidates, n_models)
    """

    def __init__(self, models: Sequence[ObservationModel], weights: Sequence[float] | str | None = None,
                 reliability: str | None = "online", weight_grid=None, memory: float = 200.0) -> None:
        self.models = models
        self.weights = weights
        self.reliability = reliability
        self.weight_grid = weight_grid
        self.memory = memory

    def reset(self) -> None:
        for m in self.models:
            m.reset()
        for k in ("reliability_", "_hits", "_trials", "_best", "weights_", "weight_scores_", "weight_grid_",
                  "_plan", "_ratios", "_factors", "_pool"):
            self.__dict__.pop(k, None)

    def feedback(self, feedback) -> None:
        """Learn each part's reliability (and the weights) from the filter's answer; pass it on to the parts.

        Parameters
        ----------
        feedback : FilterFeedback, or slice / ndarray of bool of shape (n_places,)
            The filter's feedback, or just the places within tolerance of its answer
            for the latest frame (enough for the reliability, not for learned weights).
        """
        near = feedback.near if isinstance(feedback, FilterFeedback) else feedback
        if isinstance(feedback, FilterFeedback):
            for m in self.models:
                if callable(getattr(m, "feedback", None)):
                    m.feedback(feedback)
            self._learn_weights(feedback.prior)
        best = self.__dict__.pop("_best", None)  # one feedback per frame: a second one counts nothing
        if best is None or self.reliability is None:
            return
        for m, b in enumerate(best):
            if b < 0:
                continue
            if isinstance(near, slice):  # read as numpy reads it (None, negative bounds, steps)
                hit = b in range(*near.indices(self._n_places))
            else:
                hit = bool(near[b])
            self._hits[m] += hit
            self._trials[m] += 1
        self.reliability_ = (self._hits + 1.0) / (self._trials + 2.0)

    def _reads_prior(self) -> bool:
        return _is_predictive(self.weights) or any(feedback_reads_prior(m) for m in self.models
                                                   if callable(getattr(m, "feedback", None)))

    def _learn_weights(self, prior) -> None:
        """Score every candidate on the latest frame against the filter's prediction;
        choose the best for the next frame."""
        ratios = self.__dict__.pop("_ratios", None)
        if ratios is None:
            return
        prior = np.asarray(prior, dtype=np.float64)
        n = len(prior)
        parts = [np.zeros(n) if r is None else r for r in ratios]
        if not hasattr(self, "_plan"):
            self._plan = _WeightPlan(self.weight_grid_)
        work = self.__dict__.get("_factors")
        if work is None or work.shape != (self._plan.n_rows + 1, n):
            work = self._factors = np.empty((self._plan.n_rows + 1, n))
        scores = _combination_scores(parts, self.weight_grid_, prior, self._plan, work)
        self.weight_scores_ *= self._decay
        self.weight_scores_ += scores
        self.weights_ = self.weight_grid_[int(np.argmax(self.weight_scores_))].copy()

    def _start(self) -> None:
        owner = type(self).__name__
        n = len(self.models)
        if n == 0:
            raise InvalidParameterError(f"{owner} needs at least one model.")
        for k, m in enumerate(self.models):
            if not (callable(getattr(m, "observe", None)) and callable(getattr(m, "reset", None))):
                raise InvalidParameterError(f"part {k} of {owner} is a {type(m).__name__}, not an observation model "
                                            "(reset(), observe(row)); give model instances.")
        if len({id(m) for m in self.models}) != n:
            raise InvalidParameterError(f"{owner} lists one model instance twice: it would see every row twice "
                                        "(and take the second for a repeat); give each part its own instance.")
        if self.reliability not in ("online", None):
            raise InvalidParameterError(
                f"The 'reliability' parameter of {owner} must be 'online' or None. "
                f"Got {self.reliability!r} instead."
            )
        if isinstance(self.weights, str):
            if self.weights != "predictive":
                raise InvalidParameterError(
                    f"The 'weights' parameter of {owner} must be one non-negative float per model ({n}) or "
                    f"'predictive'. Got {self.weights!r} instead."
                )
            check_scalar(self.memory, "memory", owner, float, 1.0)
            grid = predictive_weight_grid(n) if self.weight_grid is None else self.weight_grid
            try:
                grid = np.array(grid, dtype=np.float64, ndmin=2)
            except (TypeError, ValueError):
                grid = None
            if grid is None or grid.ndim != 2 or grid.shape[1] != n or len(grid) == 0 or not np.all(
                    np.isfinite(grid)) or np.any(grid < 0):
                raise InvalidParameterError(
                    f"The 'weight_grid' parameter of {owner} must be a non-empty array of shape "
                    f"(n_candidates, {n}) of non-negative floats (one weight per model per candidate). "
                    f"Got {self.weight_grid!r} instead."
                )
            self.weight_grid_ = grid
            self.weight_scores_ = np.zeros(len(grid))
            self._decay = 0.5 ** (1.0 / float(self.memory))
            # until the first frame is scored: the candidate closest to the plain sum
            self.weights_ = grid[int(np.argmin(np.abs(grid - 1.0).sum(1)))].copy()
        else:
            w = [1.0] * n if self.weights is None else list(self.weights)
            if len(w) != n or any(isinstance(x, bool) or not isinstance(x, numbers.Real)
                                  or not 0.0 <= float(x) <= MAX_PART_WEIGHT for x in w):
                raise InvalidParameterError(
                    f"The 'weights' parameter of {owner} must give one float in [0, {MAX_PART_WEIGHT:g}] per model "
                    f"({n}) or be 'predictive'. Got {self.weights!r} instead."
                )
            self.weights_ = np.array(w, dtype=np.float64)
        self._hits, self._trials = np.zeros(n), np.zeros(n)
        self.reliability_ = np.full(n, 0.5 if self.reliability else 1.0)

    def observe(self, difference_row: np.ndarray) -> Observation:
        if not hasattr(self, "_hits"):
            self._start()
        parts = _observe_parts(self.models, difference_row)
        self._n_places = len(parts[0].log_ratio)
        # each part's own best place is read only to learn its reliability
        self._best = ([int(np.argmax(p.log_ratio)) if p.informative else -1 for p in parts]
                      if self.reliability is not None else None)
        if _is_predictive(self.weights):  # kept for the feedback's scores
            self._ratios = [p.log_ratio if p.informative else None for p in parts]
        w = [float(x) for x in self.weights_]
        rho = self.reliability_ if self.reliability else np.ones(len(parts))
        log_ratio, new, supports = None, 0.0, []
        owned = False  # whether log_ratio is this method's own array (free to add into)
        terms = []
        for wi, p, r in zip(w, parts, rho):
            if not p.informative:
                continue
            lr, nr = p.log_ratio, p.new_place_log_ratio
            nr = r * nr
            # a factor of exactly 1 leaves every value as it is: no product is formed
            terms.append((lr if r == 1.0 and wi == 1.0 else wi * (r * lr), lr))
            new += wi * nr
            if wi > 0 and p.support is not None:
                supports.append(p.support)
        top = None
        if len(terms) == 2 and all(_plain_row(t) for t, _ in terms) and len(terms[0][0]) == len(terms[1][0]):
            # the sum and its maximum in one compiled pass (np.add's floats)
            log_ratio = _pool(self).take(len(terms[0][0]))
            top = float(_kernels().sum_max(terms[0][0], terms[1][0], log_ratio))
            owned = True
        for term, lr in terms if top is None else ():
            if log_ratio is None:
                log_ratio, owned = term, term is not lr
            elif owned:
                log_ratio += term
            else:
                log_ratio, owned = log_ratio + term, True
        if log_ratio is None:
            return Observation(np.zeros(len(parts[0].log_ratio)), 0.0, False)
        if not owned:  # a single part's own array: hand out a copy, as the sum would be
            log_ratio = np.array(log_ratio, dtype=np.float64)
        support = None if not supports else (
            supports[0] if len(supports) == 1 else np.maximum.reduce([np.asarray(x) for x in supports]))
        # the frame's jump evidence is the frame's, not a part's to weigh: the first part that reads it
        jump = next((p.jump_evidence for p in parts if p.informative and p.jump_evidence != 0.0), 0.0)
        return Observation(np.asarray(log_ratio, dtype=np.float64), float(new), True, support, top, float(jump))


#: Places from which :class:`CombinedObservation` observes its first part on a second
#: thread while the others observe on the calling one (where a core is free).
PARALLEL_PARTS_PLACES = 1 << 16
_PARTS_POOL: list = []


def _observe_parts(models: Sequence[ObservationModel], row) -> list[Observation]:
    """Every model's observation of the row, in order.

    The models are independent (each reads the row and its own state), so on a large map
    the first part observes on a second thread while the others observe on the calling
    one — the whole-image model's passes (about 1.3 ms at 10⁵ places) beside the sequence
    part, whose matcher and window rule leave a core idle for part of the frame — and
    their answers are the same floats as one after the other. Only where a core is free
    of other processes (:func:`catgraph.grid._cores_free`, the rule of every pass that
    threads; a thread that must wait for a busy core costs more than it saves) and from
    :data:`PARALLEL_PARTS_PLACES` places on."""
    n = len(row) if hasattr(row, "__len__") else 0
    if len(models) < 2 or n < PARALLEL_PARTS_PLACES:
        return [m.observe(row) for m in models]
    from .differences import _threads_available
    from .grid import _cores_free

    if _cores_free(_threads_available()) < 2:
        return [m.observe(row) for m in models]
    if not _PARTS_POOL:
        from concurrent.futures import ThreadPoolExecutor

        _PARTS_POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="catgraph-parts"))
    first = _PARTS_POOL[0].submit(_observe_and_prepare, models[0], row)
    try:
        rest = [m.observe(row) for m in models[1:]]
    finally:
        head = first.result()  # waits (and raises the first part's error) whatever the others did
    return [head, *rest]


def _observe_and_prepare(model, row) -> Observation:
    """``model.observe(row)``, then what the model can prepare of its feedback ahead
    (:meth:`TemperedObservation._prepare_levels`), on the second thread."""
    obs = model.observe(row)
    prepare = getattr(model, "_prepare_levels", None)
    if prepare is not None:
        prepare()
    return obs


#: The exponents every part after the first may take under ``weights="predictive"``
#: (:func:`predictive_weight_grid`): off, a quarter, a half, as is, double.
DEFAULT_PART_WEIGHTS = (0.0, 0.25, 0.5, 1.0, 2.0)


def predictive_weight_grid(n_models: int, part_weights: Sequence[float] = DEFAULT_PART_WEIGHTS) -> np.ndarray:
    """The default candidates of ``CombinedObservation(weights="predictive")``: the first
    part at weight 1, every other part at each of ``part_weights`` (all combinations).

    Parameters
    ----------
    n_models : int
    part_weights : sequence of float

    Returns
    -------
    ndarray of float64, shape (len(part_weights) ** (n_models − 1), n_models)

    Examples
    --------
    >>> predictive_weight_grid(2, (0.0, 1.0)).tolist()
    [[1.0, 0.0], [1.0, 1.0]]
    """
    import itertools

    rows = [(1.0, *rest) for rest in itertools.product([float(x) for x in part_weights], repeat=n_models - 1)]
    return np.array(rows, dtype=np.float64).reshape(len(rows), n_models)


class _WeightPlan:
    """How a weight grid's candidates are formed from a few exponentials per place.

    Each part's positive candidate weights that are all integer multiples ``k δ`` of the
    smallest, ``δ``, exactly in floating point and with ``k ≤`` :attr:`MAX_POWER`, share
    one factor ``x = e^{δ (r − max r)}``; ``x^k`` is a product of its repeated squares
    ``x, x², x⁴ …``. Otherwise each distinct weight has its own factor ``e^{w (r − max r)}``.
    A weight of 0 contributes nothing. Every row is at most 1 (no overflow).

    Attributes
    ----------
    exponentials : list of (int, int, float)
        ``(row, part, δ)`` of each exponential row.
    steps : list of (int, int, int)
        ``(out, a, b)``: row ``out`` is row ``a`` times row ``b``, in order (the squares
        and their products, after the exponentials).
    n_rows : int
    rows : list of list of int
        The rows whose product is each candidate's ``e^{Σ_m w_m (r_m − max r_m)}``.
    """

    MAX_POWER = 16

    def __init__(self, grid: np.ndarray) -> None:
        exponentials, steps = [], []
        per_part = []  # for each part: {weight: row}
        n_rows = 0
        for m in range(grid.shape[1]):
            w = grid[:, m]
            positive = [float(x) for x in np.unique(w[w > 0])]
            rows: dict[float, int] = {}
            if positive:
                step = positive[0]
                k = [int(round(x / step)) for x in positive]
                if all(kk * step == x for kk, x in zip(k, positive)) and max(k) <= self.MAX_POWER:
                    exponentials.append((n_rows, m, step))
                    squares = [n_rows]
                    n_rows += 1
                    while 2 ** len(squares) <= max(k):
                        steps.append((n_rows, squares[-1], squares[-1]))
                        squares.append(n_rows)
                        n_rows += 1
                    for kk, x in zip(k, positive):
                        bits = [squares[b] for b in range(len(squares)) if kk >> b & 1]
                        row = bits[0]
                        for other in bits[1:]:
                            steps.append((n_rows, row, other))
                            row = n_rows
                            n_rows += 1
                        rows[x] = row
                else:
                    for x in positive:
                        exponentials.append((n_rows, m, x))
                        rows[x] = n_rows
                        n_rows += 1
            per_part.append(rows)
        self.exponentials, self.steps, self.n_rows = exponentials, steps, n_rows
        self.rows = [[per_part[m][float(x)] for m, x in enumerate(candidate) if x > 0] for candidate in grid]


def _combination_score(r: np.ndarray, prior: np.ndarray) -> float:
    """``log Σ_j π_j e^{r_j} − log mean_j e^{r_j}`` of one combination ``r``, the plain
    formula (``π`` normalised to sum 1; ``+1e-300`` keeps a prior with no mass where
    ``r`` has any finite)."""
    t = float(r.max())
    e = np.exp(r - t)
    return float(np.log(np.sum(prior * e) + 1e-300) - np.log(np.mean(e)))


def _combination_scores(parts: list[np.ndarray], grid: np.ndarray, prior: np.ndarray, plan: _WeightPlan,
                        work: np.ndarray) -> np.ndarray:
    """:func:`_combination_score` of every candidate ``Σ_m grid[c, m] parts[m]``.

    Parameters
    ----------
    parts : list of ndarray of float64, shape (n_places,)
    grid : ndarray, shape (n_candidates, n_models)
    prior : ndarray of float64, shape (n_places,)
        The filter's predicted place masses (any positive total).
    plan : _WeightPlan
        Of ``grid``.
    work : ndarray of float64, shape (plan.n_rows + 1, n_places)
        Overwritten.
    """
    k = _kernels()
    n = len(prior)
    total = float(prior.sum())
    if not total > 0:
        prior, total = np.full(n, 1.0 / n), 1.0
    for f, m, step in plan.exponentials:
        row = work[f]
        np.subtract(parts[m], parts[m].max(), out=row)
        row *= step
        np.exp(row, out=row)
    for out, a, b in plan.steps:
        np.multiply(work[a], work[b], out=work[out])
    scratch = work[plan.n_rows]
    num, den = np.empty(len(grid)), np.empty(len(grid))
    for c, rows in enumerate(plan.rows):
        if not rows:  # every weight 0: a flat combination
            den[c], num[c] = float(n), total
            continue
        if len(rows) > 2:
            np.multiply(work[rows[0]], work[rows[1]], out=scratch)
            for r in rows[2:-1]:
                scratch *= work[r]
            rows = [plan.n_rows, rows[-1]]
        den[c], num[c] = (k.row_sums(work[rows[0]], prior) if len(rows) == 1
                          else k.product_sums(work[rows[0]], work[rows[1]], prior))
    # both sums carry the same shift e^{−Σ_m w_m max r_m}: it cancels in the score
    with np.errstate(divide="ignore"):
        out = np.log(np.maximum(num, 1e-300) / total) - np.log(den / n)
    small = np.flatnonzero((den < 1e-200) | (num < 1e-200 * total))
    if len(small):  # the shift left too little: the plain formula for those candidates
        p = prior / total
        for c in small:
            r = np.zeros(n)
            for m, part in enumerate(parts):
                r += float(grid[c, m]) * part
            out[c] = _combination_score(r, p)
    return out


def _plain_row(x) -> bool:
    """A 1-D, C-contiguous float64 array (what the compiled passes take)."""
    return type(x) is np.ndarray and x.dtype == np.float64 and x.ndim == 1 and x.flags.c_contiguous


def _kernels():
    """The compiled passes (:mod:`catgraph._observation_kernels`), imported on first use."""
    from . import _observation_kernels

    return _observation_kernels


class _NearMedian:
    """``np.median`` of an array that changes little between calls, the same float.

    The previous call's median ``m`` and a width ``w`` make a bracket ``[m − w, m + w]``;
    one compiled pass (:func:`catgraph._observation_kernels.bracket`) counts the values
    below it and copies those inside, and where the middle position falls inside, the
    middle values are selected among those few. Otherwise (a first call, a median that
    moved out of the bracket) every value is selected as :func:`_median` does, and the
    bracket widens fourfold; a bracket holding more than a sixteenth of the values
    narrows by half. The middle order statistics are the same values whichever way they
    are found, and they are averaged as :func:`_median` averages them.

    Attributes
    ----------
    guess : float or None
        The previous median.
    width : float
        The bracket's half-width (0: no bracket yet; the owner sets the first).
    """

    __slots__ = ("guess", "width")

    def __init__(self) -> None:
        self.guess: float | None = None
        self.width = 0.0

    def median(self, values: np.ndarray, work: np.ndarray, centre: float | None = None) -> float:
        """``np.median(values)``, or with ``centre`` ``np.median(np.abs(values − centre))``.

        Parameters
        ----------
        values : ndarray of float64, shape (n,), C-contiguous
        work : ndarray of float64, shape (n,)
            Overwritten.
        centre : float, optional
        """
        from ._observation_kernels import absolute_deviations, bracket, largest_below

        n = len(values)
        k = n // 2
        absolute = centre is not None
        centre = 0.0 if centre is None else centre
        if self.guess is not None and self.width > 0.0:
            below, inside = bracket(values, centre, absolute, self.guess, self.width, k, work)
            if below <= k < below + inside:
                chosen = work[:inside]
                j = k - below
                chosen.partition(j)
                if n % 2:
                    value = float(np.mean(chosen[j:j + 1]))
                else:  # the lower middle value: the largest of the lower part, or of those below
                    low = (chosen[:j].max() if j > 0
                           else largest_below(values, centre, absolute, self.guess, self.width))
                    value = float(np.mean(np.array((low, chosen[j]))))
                if inside > n // 16:
                    self.width *= 0.5
                self.guess = value
                return value
            self.width *= 4.0
        if absolute:
            absolute_deviations(values, centre, work)
            value = _median(work, work)
        else:
            value = _median(values, work)
        self.guess = value
        return value


def _median(values: np.ndarray, work: np.ndarray) -> float:
    """``np.median(values)``, the same float, from one selection in the work array ``work``.

    ``np.median`` copies the values and partitions the copy around both middle positions,
    then averages them with ``np.mean``. Here the values are copied into ``work`` (unless
    they are already there), partitioned around the upper middle position only, and the
    lower middle value is the largest of the lower part (the order statistics are the
    same values whichever way they are selected); ``np.mean`` of the one or two middle
    values then gives the very same float.
    """
    n = len(values)
    if values is not work:
        np.copyto(work, values)
    k = n // 2
    work.partition(k)
    if n % 2:
        return float(np.mean(work[k:k + 1]))
    return float(np.mean(np.array((work[:k].max(), work[k]))))


def _centred_spread(s: np.ndarray, out: np.ndarray, work: np.ndarray) -> float:
    """``s − s.mean()`` into ``out``; returns ``s.std()``, the same floats.

    ``np.std`` of a 1-D float64 array is ``sqrt(sum((s − m)²) / n)`` with ``m`` the
    array's mean (numpy's own sums, in numpy's order); the centred values it squares are
    those the standardisation divides, so they are formed once, in ``out``, and (for a
    contiguous ``s``) squared and summed in the same compiled pass, in numpy's pairwise
    order (:func:`catgraph._observation_kernels.centred_sums`). ``work``: scratch of
    the length of ``s`` (a strided ``s`` only).
    """
    mean = s.mean()
    if s.flags.c_contiguous and out.flags.c_contiguous:
        squares, _ = _kernels().centred_sums(s, mean, _NOTHING, out)
        return np.sqrt(squares / len(s))
    np.subtract(s, mean, out=out)
    np.square(out, out=work)
    return np.sqrt(work.sum() / len(s))


#: An empty float64 array: "no second factor" for the compiled sums.
_NOTHING = np.empty(0)


def _standardised(s: np.ndarray, out: np.ndarray, work: np.ndarray) -> np.ndarray:
    """``(s − s.mean()) / s.std()`` into ``out`` (zeros where ``s.std()`` is 0), the same floats
    (:func:`_centred_spread`, then the division).
    ``tests/test_likelihood.py`` checks the floats against ``s.std()`` and ``s.mean()``.
    """
    sd = _centred_spread(s, out, work)
    if not sd > 0:
        out[...] = 0.0
        return out
    out /= sd
    return out


def _predictive_scores(base: np.ndarray, log_prior: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """``log Σ_j prior_j e^{τ b_j} − log mean_j e^{τ b_j}`` for every ``τ`` (compiled)."""
    from ._grid_kernels import predictive_scores

    return predictive_scores(np.ascontiguousarray(base, dtype=np.float64),
                             np.ascontiguousarray(log_prior, dtype=np.float64), taus)


#: Frames whose correlation with their predecessor is within this of 1 are repeats of it
#: (the novelty weight, :meth:`TemperedObservation._novelty`).
DUPLICATE_TOLERANCE = 1e-9

#: Default grid of temperatures the online temper chooses from.
DEFAULT_TEMPERATURES = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.7, 1.0, 1.5)


class TemperedObservation:
    """Whole-image evidence, hub-corrected and tempered by the filter's own answers.

    The per-place log-ratio is ``r_j = τ · b(d_j − c_j)`` where

    * ``b`` is the single-frame log-ratio ``log P(d|L) − log P(d)`` of the per-query
      normalised difference. ``likelihood="linear"`` (default) is the Gaussian-shift
      model, ``b(d) = −d``: ``P(d)`` standard normal (the row is normalised) and
      ``P(d|L)`` the same shifted down, the form the histograms start from.
      ``likelihood="histogram"`` learns ``b`` as paper 2 does, from histograms of the
      query's own differences, except that ``P(d|L)`` is learned from the *filter's*
      answers (every place weighted by its posterior mass times the answer's
      confidence; :meth:`feedback`) instead of from ``d_min``, which on a season change
      is mostly a wrong match. It starts from ``−d`` with the weight of
      ``prior_strength`` frames and is kept non-increasing in ``d`` (pooled adjacent
      violators). Paper 2's own online scheme stays available as
      :class:`HistogramObservation`.
    * ``c_j`` is the hub correction. Each reference's *level* is its mean difference to
      the query frames so far (``hub="online"``: the frames the filter has fed back,
      :meth:`feedback`, blank ones left out; applied from the third frame on, once two
      frames give a mean) or a level given from the map
      (``hub=array``, e.g. the map's levels, :func:`catgraph.hubs.map_hub_offsets`). A *hub* is a
      reference whose level is a low outlier (below ``median − hub_threshold ·
      1.4826 · MAD`` of the levels); ``c = w · (level − mean level)`` with
      ``w = min(1, f / 1 %)``, ``f`` the fraction of references that are hubs. Maps with
      a run of flat, textureless frames (Nordland) are corrected fully; maps without
      hubs (Wi-Fi fingerprints, the synthetic world), where the levels carry place
      information and correcting them was measured to hurt, are left alone.
    * ``τ`` is the temperature: frames are not independent evidence, and how much one
      frame may move the posterior depends on how often single frames are right.
      ``temperature="agreement"`` (default) learns that from the filter:
      ``τ = temperature_scale · ρ``, ``ρ`` the discounted mean (half-life ``memory``
      frames, Beta(1, 1) prior) of ``posterior(best_k) / max posterior``, how probable
      the frame's own best place is after the filter has weighed it.
      ``temperature="predictive"`` picks ``τ`` from ``temperatures`` by the discounted
      predictive log Bayes factor ``log Σ_j prior_j e^{τ b_j} − log mean_j e^{τ b_j}``
      (measured: it prefers the largest ``τ`` and locks onto hubs, see
      ``docs/particle_filter.md``); a float fixes ``τ``.

    * Each frame's ratios are further weighted by its *novelty* (``novelty=True``):
      ``ν_k = (1 − ρ_k) / (1 − ρ̄)`` clipped to ``[0, novelty_cap]``, ``ρ_k`` the
      correlation of the row with the previous one and ``ρ̄`` its discounted mean. A
      repeated frame (a stop, or a query slower than the reference) adds no evidence;
      a frame unlike its predecessor (new scenery, or a jump) counts up to
      ``novelty_cap`` times. So ``r_j = τ ν_k b(d_j − c_j)``. An exact repeat
      (``1 − ρ_k ≤`` :data:`DUPLICATE_TOLERANCE`: a frame shown twice) is no
      measurement and stays out of ``ρ̄``: were it counted, a query with every frame
      shown twice would halve ``1 − ρ̄`` and count each new frame twice, so its
      evidence per place would double (measured on Nordland at speed 0.5, where it
      cost the filter 0.05 AUC, ``docs/particle_filter.md``). With the repeats left
      out, the frames of such a query get exactly the weights of the query shown once.
      A *blank* frame (a constant row, as a textureless image normalises to) is no
      measurement either: ``ν = 0``, the filter's feedback learns nothing from it, and
      the next frame is compared with the last frame before it. On a map of fewer
      than three places (where any two frames correlate ±1) the weight is 1.

    * The same correlation ``ρ_k`` gives the frame's *jump evidence*
      (``jump_evidence=True``, :mod:`catgraph.jumps`): the log-likelihood ratio of a
      change as large as ``1 − ρ_k`` between a jump and a step, learned online from the
      query's consecutive frames and its frames far apart, kept where positive
      (``Observation.jump_evidence``; the filters raise the frame's jump rate by it).
      It leaves the ratios ``r_j`` as they are.

    The new-place log-ratio is ``log mean_j e^{r_j}``: a place not in the map looks,
    to this model, like a place drawn at random from the map.

    Parameters
    ----------
    likelihood : {"linear", "histogram"}
    hub : {"online", None} or ndarray of shape (n_places,)
    temperature : {"agreement", "predictive"} or float
    temperature_scale : float
        ``τ`` per unit of agreement (``"agreement"``; default 4, chosen with the grid
        filter's defaults on every condition of Nordland, UJI and the synthetic world:
        3 tracks Nordland in order best, 5 recovers from short jumps best, see
        ``docs/particle_filter.md``).
    temperatures : sequence of float
        The grid of ``"predictive"``.
    hub_weights : sequence of float
        Extra weights on the hub correction; with several, ``"predictive"`` also
        chooses among them.
    memory : float
        Half-life, in frames, of the agreement and of the predictive score.
    n_bins : int
        Histogram bins (``"histogram"``).
    prior_strength : float
        Frames' worth of weight of the starting ratio ``−d`` (``"histogram"``).
    hub_threshold : float
        Robust z-score below which a reference is a hub.
    novelty : bool
        Weight frames by their novelty.
    novelty_cap : float
        Largest novelty weight.
    jump_evidence : bool
        Report each frame's jump evidence (:mod:`catgraph.jumps`).

    Attributes
    ----------
    temperature_ : float
    agreement_ : float
    novelty_ : float
        ``ν`` of the latest frame.
    jump_evidence_ : float
        The latest frame's jump evidence (0: none, or switched off).
    hub_shrinkage_ : float
        ``w`` of the hub correction.
    n_hubs_ : int
    score_ : ndarray, shape (n_temperatures, n_hub_weights)
        Discounted predictive log Bayes factors (kept where they choose something:
        ``temperature="predictive"`` or several hub weights).
    """

    #: whether :meth:`observe` computes the new-place ratio (a model whose owner ignores
    #: it, :class:`SequenceObservation`'s calibration, skips that pass over the places)
    _new_place = True

    def __init__(self, likelihood: str = "linear", hub="online", temperature="agreement",
                 temperature_scale: float = 4.0,
                 temperatures: Sequence[float] = DEFAULT_TEMPERATURES, hub_weights: Sequence[float] = (1.0,),
                 memory: float = 200.0, n_bins: int = 64, prior_strength: float = 50.0,
                 hub_threshold: float = 3.0, novelty: bool = True, novelty_cap: float = 2.0,
                 jump_evidence: bool = True) -> None:
        self.likelihood = likelihood
        self.hub = hub
        self.hub_threshold = hub_threshold
        self.temperature_scale = temperature_scale
        self.novelty = novelty
        self.novelty_cap = novelty_cap
        self.jump_evidence = jump_evidence
        self.temperature = temperature
        self.temperatures = temperatures
        self.hub_weights = hub_weights
        self.memory = memory
        self.n_bins = n_bins
        self.prior_strength = prior_strength

    def reset(self) -> None:
        params = {"likelihood", "hub", "temperature", "temperature_scale", "temperatures", "hub_weights", "memory",
                  "n_bins", "prior_strength", "hub_threshold", "novelty", "novelty_cap", "jump_evidence"}
        for k in [k for k in self.__dict__ if k not in params]:
            del self.__dict__[k]

    def _start(self, row: np.ndarray) -> None:
        owner = type(self).__name__
        if self.likelihood not in ("histogram", "linear"):
            raise InvalidParameterError(
                f"The 'likelihood' parameter of {owner} must be 'histogram' or 'linear'. Got {self.likelihood!r} instead."
            )
        if self.temperature not in ("predictive", "agreement"):
            check_scalar(self.temperature, "temperature", owner, float, 0.0, low_inclusive=False)
        check_scalar(self.temperature_scale, "temperature_scale", owner, float, 0.0, low_inclusive=False)
        taus = np.asarray(self.temperatures, dtype=np.float64) if self.temperature == "predictive" else np.array(
            [float(self.temperature) if not isinstance(self.temperature, str) else 1.0])
        if taus.ndim != 1 or len(taus) == 0 or not np.all(np.isfinite(taus)) or np.any(taus <= 0):
            raise InvalidParameterError(
                f"The 'temperatures' parameter of {owner} must be a non-empty sequence of positive floats. "
                f"Got {self.temperatures!r} instead."
            )
        check_scalar(self.memory, "memory", owner, float, 1.0)
        check_scalar(self.n_bins, "n_bins", owner, int, 4)
        check_scalar(self.prior_strength, "prior_strength", owner, float, 0.0)
        check_scalar(self.hub_threshold, "hub_threshold", owner, float, 0.0)
        check_scalar(self.novelty_cap, "novelty_cap", owner, float, 0.0, low_inclusive=False)
        for name in ("novelty", "jump_evidence"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InvalidParameterError(f"The '{name}' parameter of {owner} must be a bool. "
                                            f"Got {getattr(self, name)!r} instead.")
        n = len(row)
        if isinstance(self.hub, str) or self.hub is None:
            if self.hub not in ("online", None):
                raise InvalidParameterError(
                    f"The 'hub' parameter of {owner} must be 'online', None or an array of one level per place. "
                    f"Got {self.hub!r} instead."
                )
            hub_vector = None
        else:
            hub_vector = check_array(self.hub, f"the 'hub' levels of {owner}", ndim=1)
            if len(hub_vector) != n:
                raise ShapeMismatchError(
                    f"the 'hub' levels of {owner} hold {len(hub_vector)} values but the map has {n} places; "
                    "give one level per place (catgraph.hubs.map_hub_offsets of this map).")
        lams = np.asarray(self.hub_weights, dtype=np.float64) if self.hub is not None else np.array([0.0])
        if lams.ndim != 1 or len(lams) == 0 or not np.all(np.isfinite(lams)):
            raise InvalidParameterError(
                f"The 'hub_weights' parameter of {owner} must be a non-empty sequence of floats. Got {self.hub_weights!r} instead."
            )
        self.n_reference_ = n
        self._taus, self._lams = taus, lams
        self._hub_map = hub_vector
        # the online levels' running total (no array where the levels are not learned)
        self._hub_sum, self._hub_count = np.zeros(n if hub_vector is None and self.hub is not None else 0), 0
        self.score_ = np.zeros((len(taus), len(lams)))
        self._decay = 0.5 ** (1.0 / float(self.memory))
        self._hits, self._trials = 0.0, 0.0
        self._rho_sum, self._rho_n, self.novelty_ = 0.0, 0.0, 1.0
        self._kept = None  # the previous frame's centred row and its sum of squares (novelty weight)
        self._jumps = JumpEvidence().reset() if self.jump_evidence else None
        self.jump_evidence_ = 0.0
        self.agreement_ = 0.5
        first = float(self.temperature_scale) * 0.5 if self.temperature == "agreement" else float(taus[len(taus) // 2])
        self.temperature_, self.hub_weight_ = first, float(lams[0])
        self._pick = (len(taus) // 2, 0)
        if self.likelihood == "histogram":
            sd = float(row.std()) or 1.0
            lo, hi = float(row.min()) - 2.0 * sd, float(row.max()) + 2.0 * sd
            self._edges = np.linspace(lo, hi, self.n_bins + 1)
            centres = 0.5 * (self._edges[1:] + self._edges[:-1])
            self._centres = centres
            # every hub weight has its own histograms (its differences differ)
            self._count_all = np.full((len(lams), self.n_bins), 1e-3)
            self._count_same = np.zeros((len(lams), self.n_bins))
            self._seeded = False
            self._tables = np.tile(-centres, (len(lams), 1))

    def _hub(self, formed: bool = True):
        """The hub correction (:meth:`_hub_excess`), or None; ``formed=False``: where the
        levels are contiguous, ``(level, mean, shrinkage)`` instead of the array."""
        if self._hub_map is not None:
            return self._hub_excess(self._hub_map, formed=formed)
        if isinstance(self.hub, str) and self._hub_count > 1:
            level = self._buffer("_level", len(self._hub_sum))
            ready = self.__dict__.get("_level_ready")
            if ready is not None and ready[0] == self._hub_count:  # formed by the feedback (and its mean)
                return self._hub_excess(level, ready[1], formed)
            np.divide(self._hub_sum, self._hub_count, out=level)
            return self._hub_excess(level, formed=formed)
        return None

    def _add_to_levels(self, row: np.ndarray) -> None:
        """Add a frame to the online hub levels' running total; with a contiguous float64
        row, also form the next frame's levels ``total / count`` and their mean in the
        same pass (:func:`catgraph._observation_kernels.accumulated_levels`: numpy's
        floats), so that :meth:`_hub` reads them instead of dividing again. Where
        :meth:`_prepare_levels` has formed them already for this row, they are taken."""
        prepared = self.__dict__.pop("_prepared", None)
        if prepared is not None and prepared[0] is row and prepared[1] == self._hub_count + 1:
            self._hub_sum, self._next_total = self._next_total, self._hub_sum
            self._hub_count += 1
            self._level_ready = (self._hub_count, prepared[2])
            return
        self._hub_count += 1
        total = self._hub_sum
        if self._hub_count > 1 and _plain_row(row) and len(row) == len(total):
            level = self._buffer("_level", len(total))
            level_sum = _kernels().accumulated_levels(total, row, float(self._hub_count), total, level)
            self._level_ready = (self._hub_count, level_sum / len(level))
        else:
            total += row

    def _prepare_levels(self) -> None:
        """Form the running total and the levels that :meth:`feedback` will make of the
        frame just observed, in spare arrays, ahead of the feedback (the combined model
        calls this on its second thread while the sequence part still works); the
        feedback then only swaps the total in. The same floats as :meth:`_add_to_levels`.
        The levels are written over the frame's own (read by nothing after its
        observation); until the feedback takes them, they are marked stale, so that a
        frame observed without that feedback forms its levels from the total again."""
        row = getattr(self, "_row", None)
        # the histogram likelihood's feedback reads the frame's own levels (its differences
        # are learned as they were observed): they must not be overwritten before it
        if (row is None or self._hub_map is not None or not isinstance(self.hub, str) or self._hub_count < 1
                or not _plain_row(row) or len(row) != len(self._hub_sum) or self.likelihood == "histogram"
                or self.__dict__.get("_blank")):
            return
        n = len(row)
        new_total, level = self._buffer("_next_total", n), self._buffer("_level", n)
        self.__dict__.pop("_level_ready", None)
        count = self._hub_count + 1
        level_sum = _kernels().accumulated_levels(self._hub_sum, row, float(count), new_total, level)
        self._prepared = (row, count, level_sum / n)

    def _hub_excess(self, level: np.ndarray, level_mean: float | None = None, formed: bool = True):
        """The hub correction from reference levels: ``w · (level − mean level)``.

        A hub is a reference whose level is a low outlier among the references': below
        ``median − hub_threshold · 1.4826 · MAD``. The weight ``w = min(1, f / 0.01)``
        grows with the fraction ``f`` of references that are hubs: a map with none
        (Wi-Fi fingerprints, the synthetic world) keeps its levels, which there carry
        place information; a map with a run of flat, textureless frames (Nordland's
        tunnels) has its levels removed. ``level_mean``: ``level.mean()`` where known.
        ``formed=False`` (contiguous levels): the statistics only, ``(level, mean level,
        w)``, for a pass that forms the correction as it reads it.

        The median and the MAD are selected near the previous frame's
        (:class:`_NearMedian`: exact, one pass and a small selection while they move
        little); the other passes are fused (:mod:`catgraph._observation_kernels`).
        """
        work = self._buffer("_select", len(level))
        if not level.flags.c_contiguous:  # a strided level map: numpy's passes
            out = self._buffer("_excess", len(level))
            med = _median(level, work)
            np.subtract(level, med, out=work)
            np.abs(work, out=work)
            mad = 1.4826 * _median(work, work)
            hubs = int(np.count_nonzero(level < med - float(self.hub_threshold) * mad))
            self.n_hubs_ = hubs
            self.hub_shrinkage_ = min(1.0, hubs / (0.01 * len(level)))
            np.subtract(level, level.mean(), out=out)
            if self.hub_shrinkage_ != 1.0:  # a factor of exactly 1 leaves every value as it is
                out *= self.hub_shrinkage_
            return out
        # the same arithmetic, each step one compiled pass (numpy's floats, numpy's sums)
        k = _kernels()
        near = self.__dict__.get("_near")
        if near is None:
            near = self._near = (_NearMedian(), _NearMedian())
        med = near[0].median(level, work)
        spread = near[1].median(level, work, centre=med)
        mad = 1.4826 * spread
        if near[0].width == 0.0 and spread > 0:  # the brackets' first width: a 50th of the spread
            near[0].width = near[1].width = 0.02 * spread
        # level − mean and the hub count in one pass, then the factor (numpy's two roundings)
        mean = level.mean() if level_mean is None else level_mean
        threshold = med - float(self.hub_threshold) * mad
        if not formed:
            hubs = int(k.count_below(level, threshold))
            self.n_hubs_ = hubs
            self.hub_shrinkage_ = min(1.0, hubs / (0.01 * len(level)))
            return level, float(mean), self.hub_shrinkage_
        out = self._buffer("_excess", len(level))  # formed only here (not by the fused pass)
        hubs = int(k.centred_count(level, mean, threshold, out))
        self.n_hubs_ = hubs
        self.hub_shrinkage_ = min(1.0, hubs / (0.01 * len(level)))
        if self.hub_shrinkage_ != 1.0:  # a factor of exactly 1 leaves every value as it is
            out *= self.hub_shrinkage_
        return out

    def _buffer(self, name: str, n: int) -> np.ndarray:
        """A float64 work array of length ``n`` kept between frames (the per-frame
        arithmetic writes into it instead of allocating)."""
        buf = self.__dict__.get(name)
        if buf is None or len(buf) != n:
            buf = np.empty(n)
            setattr(self, name, buf)
        return buf

    def _bins(self, d: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self._edges, d, side="right") - 1, 0, self.n_bins - 1)

    def _base(self, row: np.ndarray) -> list[np.ndarray]:
        """Single-frame log-ratios ``b(d − λ h)`` for every hub weight."""
        h = self._hub()
        out = []
        for m, lam in enumerate(self._lams):
            if self.likelihood == "linear":
                # −(row − λ h) into this weight's own buffer; λ h is h itself when λ = 1
                base = self._buffer(f"_base{m}", len(row))
                if h is None or lam == 0.0:
                    np.negative(row, out=base)
                elif lam == 1.0 and row.flags.c_contiguous:
                    _kernels().negated_difference(row, h, base)  # the two passes below, fused
                else:
                    np.subtract(row, h if lam == 1.0 else lam * h, out=base)
                    np.negative(base, out=base)
                out.append(base)
            else:
                d = row if (h is None or lam == 0.0) else row - lam * h
                out.append(self._tables[m][self._bins(d)])
        return out

    def observe(self, difference_row: np.ndarray) -> Observation:
        row = _check_row(difference_row, getattr(self, "n_reference_", None))
        if not hasattr(self, "n_reference_"):
            self._start(row)
        self._best = None
        self.__dict__.pop("_prepared", None)
        lam = float(self._lams[0])
        if self.likelihood == "linear" and len(self._lams) == 1 and row.flags.c_contiguous and lam in (0.0, 1.0):
            # the single-frame ratios, their tempered product, its maximum and the frame's
            # own best place in one compiled pass (the same arithmetic as below; the hub
            # correction formed in it where the levels are contiguous)
            h = self._hub(formed=False)
            corrected = h is not None and lam != 0.0
            scale = self.temperature_ * self._novelty(row)
            r = _pool(self).take(len(row))
            # the single-frame ratios are read again only by a predictive temperature; not
            # kept, they have no array (the fused passes write each place's ratio over them)
            keep = self.temperature == "predictive"
            if not keep:
                self.__dict__.pop("_base0", None)
            if corrected and isinstance(h, tuple):
                base = self._buffer("_base0", len(row)) if keep else _NOTHING
                top, self._best = _kernels().hub_tempered_ratios(row, *h, scale, keep, base, r)
                return self._tempered(row, [base] if keep else None, r, float(top))
            base = self._buffer("_base0", len(row)) if keep else r
            if isinstance(h, tuple):  # not applied (hub weight 0): formed, as before
                h = None
            top, self._best = _kernels().tempered_ratios(row, h if corrected else row, corrected, scale, base, r)
            return self._tempered(row, [base] if keep else None, r, float(top))
        self._bases = self._base(row)
        i, m = self._pick
        scale = self.temperature_ * self._novelty(row)
        r = np.multiply(scale, self._bases[m])
        return self._tempered(row, self._bases, r, float(r.max()) if self._new_place else 0.0)

    def _takes_standardised(self, s: np.ndarray) -> bool:
        """Whether :meth:`_observe_standardised` may stand for :meth:`observe`: a started
        model of the plain ratio ``−z`` (linear, no hub, no novelty weight, one hub weight,
        a temperature not chosen by the predictive score, no new-place ratio), ``s``
        contiguous and of the model's length."""
        return (getattr(self, "n_reference_", None) == len(s) and s.flags.c_contiguous and not self._new_place
                and self.likelihood == "linear" and self.hub is None and not self.novelty and not self.jump_evidence
                and len(self._lams) == 1
                and self.temperature != "predictive")

    def _observe_standardised(self, scores: np.ndarray, mean: float, sd: float,
                              tau: float) -> tuple[np.ndarray, float]:
        """``observe((scores − mean) / sd).log_ratio * tau`` and its maximum, in one
        compiled pass (:func:`catgraph._observation_kernels.standardised_ratios`: the
        centring, the division, the ratios ``temperature_ · −z``, the factor ``tau``, the
        maximum and the best place; the same floats as the separate passes; the
        standardised scores themselves are not stored: with no hub levels and no
        histograms, :meth:`feedback` does not read the frame's values). Only where
        :meth:`_takes_standardised`; scores whose standardised values are not all finite
        go through :meth:`observe` (which refuses them), formed in a new array."""
        n = len(scores)
        r = _pool(self).take(n)
        scale = self.temperature_ * self._novelty(scores)  # 1: no novelty weight
        top, best, finite = _kernels().standardised_ratios(scores, mean, sd, scale, tau, r)
        if not finite:
            z = np.subtract(scores, mean)
            np.divide(z, sd, out=z)
            r = self.observe(z).log_ratio
            r *= tau
            return r, float(r.max())
        self._best = best
        self._bases = None  # read by feedback only for a predictive temperature or several hub weights
        self._row = scores  # feedback reads only that a frame was observed (no hub levels, no histograms)
        return r, float(top)

    def _tempered(self, row: np.ndarray, bases: list[np.ndarray] | None, r: np.ndarray, top: float) -> Observation:
        """The observation of ratios ``r`` (maximum ``top``), keeping what :meth:`feedback` reads."""
        self._bases = bases
        self._row = row
        if not self._new_place:
            return Observation(r, 0.0, True, jump_evidence=self.jump_evidence_)
        work = self._buffer("_select", len(r))
        np.subtract(r, top, out=work)
        np.exp(work, out=work)
        new = top + math.log(float(np.mean(work)))
        return Observation(r, new, True, None, top, self.jump_evidence_)

    def _novelty(self, row: np.ndarray) -> float:
        """How much of this frame is new: ``(1 − ρ_k) / (1 − ρ̄)``, clipped to
        ``[0, novelty_cap]``, ``ρ_k`` the correlation of this row with the previous one
        and ``ρ̄`` its discounted mean over the frames that are not exact repeats. A
        repeated frame (``ρ_k = 1``) adds nothing; a frame unlike its predecessor
        (after a jump) counts more."""
        # The previous row enters only centred, with its sum of squares: both are kept
        # from its own frame (the same values ``prev − prev.mean()`` would give again).
        # The same correlation gives the frame's jump evidence (``jump_evidence``).
        self._blank = False
        self.jump_evidence_ = 0.0
        if not (self.novelty or self.jump_evidence) or len(row) < 3:  # two places: any two frames correlate ±1
            return 1.0
        first = self._kept is None
        n = len(row)
        a = self._buffer("_centred_a", n)
        mean = row.mean()
        ab = None
        if row.flags.c_contiguous:
            # a = row − mean, numpy's Σ a² and (with the previous centred row b) Σ a b, in
            # one compiled pass, summed in numpy's pairwise order (the same floats)
            other = _NOTHING if first else self._kept[0]
            aa, ab = _kernels().centred_sums(row, mean, other, a)
            aa = np.float64(aa)
        else:
            square = self._buffer("_square", n)
            np.subtract(row, mean, out=a)
            np.multiply(a, a, out=square)
            aa = square.sum()
        if aa <= n * (n * 4e-16 * abs(mean)) ** 2 and _blank_row(row):
            # a blank frame (a constant row: e.g. a textureless image, normalised to 0)
            # holds no measurement: it adds nothing, and the next frame is compared with
            # the last frame that held one
            self._blank = bool(self.novelty)
            self.novelty_ = 0.0
            return 0.0 if self.novelty else 1.0
        # the previous row was kept as a contiguous copy, whose mean numpy may sum in
        # another order than a strided row's
        kept = self._centred_b_next(row, a, aa)
        if first:
            self._kept = kept
            if kept[0] is a:
                self._centred_a = np.empty(n)
            self.novelty_ = 1.0
            return 1.0
        b, bb = self._kept
        den = math.sqrt(float(aa) * float(bb))  # (numpy's floats; an overflow is caught below)
        if ab is None:
            square = self._buffer("_square", n)
            np.multiply(a, b, out=square)
            ab = square.sum()
        if 0.0 < den < math.inf and math.isfinite(float(ab)):
            rho = float(ab) / den
        else:  # the sums under- or overflowed (rows of extreme scale): the same correlation, rescaled
            x, y = a / np.abs(a).max(), b / np.abs(b).max()
            rho = float(np.clip((x @ y) / math.sqrt(float(x @ x) * float(y @ y)), -1.0, 1.0))
        self._kept = kept
        if kept[0] is a:
            # the next frame centres into the previous row's buffer, free from now on
            self._centred_a = b
        if 1.0 - rho > DUPLICATE_TOLERANCE:
            # a frame that repeats its predecessor is no measurement: it adds nothing
            # (ν = 0) and does not dilute the typical change between measurements
            self._rho_sum = self._decay * self._rho_sum + rho
            self._rho_n = self._decay * self._rho_n + 1.0
        mean = self._rho_sum / self._rho_n if self._rho_n > 0 else rho
        self.novelty_ = float(np.clip((1.0 - rho) / max(1.0 - mean, 1e-6), 0.0, self.novelty_cap))
        if self._jumps is not None and 1.0 - rho > DUPLICATE_TOLERANCE:
            # a repeated frame is no measurement of a jump either (its evidence stays 0)
            self.jump_evidence_ = self._jumps.observe(1.0 - rho, a, float(aa))
        return self.novelty_ if self.novelty else 1.0

    def _centred_b_next(self, row: np.ndarray, a: np.ndarray, aa) -> tuple[np.ndarray, float]:
        """This row centred as the next frame will need it, with its sum of squares."""
        if row.flags.c_contiguous:
            return a, aa
        copy = np.ascontiguousarray(row)
        b = copy - copy.mean()
        return b, (b * b).sum()

    def feedback(self, feedback: FilterFeedback) -> None:
        """Score every (temperature, hub weight) on how well the filter predicted the
        frame; learn ``P(d|L)`` from the posterior; update the online hub levels."""
        row = getattr(self, "_row", None)
        if row is None:
            return
        if self.__dict__.get("_blank"):  # a blank frame: nothing to learn from (its best place is arbitrary)
            self._row = None
            return
        if self.temperature == "predictive" or len(self._lams) > 1:
            prior = np.asarray(feedback.prior, dtype=np.float64)
            total = prior.sum()
            log_prior = (np.log(np.maximum(prior / total, 1e-300)) if total > 0
                         else np.full(len(prior), -math.log(len(prior))))
            self.score_ *= self._decay
            for m, b in enumerate(self._bases):
                self.score_[:, m] += _predictive_scores(b, log_prior, self._taus)
        i, m = np.unravel_index(int(np.argmax(self.score_)), self.score_.shape)
        # agreement: how probable is the frame's own best place, relative to the answer?
        best = self.__dict__.get("_best")  # found by observe's compiled pass, or:
        best = int(np.argmax(self._bases[self._pick[1]])) if best is None else int(best)
        post = np.asarray(feedback.posterior)
        top = float(post.max()) if feedback.posterior_max is None else float(feedback.posterior_max)
        hit = float(post[best]) / top if top > 0 else 0.0
        self._hits = self._decay * self._hits + hit
        self._trials = self._decay * self._trials + 1.0
        self.agreement_ = (self._hits + 1.0) / (self._trials + 2.0)
        if self.temperature == "agreement":
            self.temperature_ = float(self.temperature_scale) * self.agreement_
            self._pick = (0, int(m))
        else:
            self._pick = (int(i), int(m))
            self.temperature_ = float(self._taus[i])
        self.hub_weight_ = float(self._lams[m])
        if self.likelihood == "histogram":
            self._learn(row, np.asarray(feedback.posterior, dtype=np.float64), feedback.near)
        if self._hub_map is None and isinstance(self.hub, str):
            self._add_to_levels(row)
        self._row = None

    def _reads_prior(self) -> bool:
        """Only a predictive temperature or several hub weights score the prediction."""
        weights = self.hub_weights if self.hub is not None else (0.0,)
        return self.temperature == "predictive" or len(weights) > 1

    def _learn(self, row: np.ndarray, posterior: np.ndarray, near) -> None:
        h = self._hub()
        confidence = float(posterior[near].sum())
        for m, lam in enumerate(self._lams):
            d = row if (h is None or lam == 0.0) else row - lam * h
            idx = self._bins(d)
            self._count_all[m] += np.bincount(idx, minlength=self.n_bins) / len(d)
            self._count_same[m] += confidence * np.bincount(idx, weights=posterior, minlength=self.n_bins)
        n_seen = self._count_all[0].sum()
        if n_seen < 5:
            return
        from .likelihood import _monotone_tables

        for m in range(len(self._lams)):
            p_all = self._count_all[m] / self._count_all[m].sum()
            start = p_all * np.exp(-self._centres)
            start /= start.sum()
            same = self._count_same[m] + self.prior_strength * start + 1e-3 * p_all
            log_same = np.log(same / same.sum())
            log_all = np.log(p_all)
            log_same, log_all = _monotone_tables(log_same, log_all)
            self._tables[m] = log_same - log_all
