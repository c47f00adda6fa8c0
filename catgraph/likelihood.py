r"""Training-free probability models for whole-image differences (paper 2).

A whole-image descriptor compares two frames with a single number, the difference
``d`` (SAD, cosine, Hamming …; smaller = more alike). Whether two frames show the same
place ``L`` or different places ``¬L`` changes the *distribution* of ``d``, and that
distribution is simple enough to learn from the data as it arrives.

Model
-----
Two histograms over the same ``s`` bins (``n_bins``, paper: 100) count differences
between frames of the same place, ``P(d ∧ L)``, and of different places, ``P(d ∧ ¬L)``.
Each is smoothed by mixing in the uniform distribution with weight ``ε``
(``smoothing``; additive smoothing with pseudo-counts ``α = ε N / ((1 − ε) s)``
proportional to the sample size ``N``):

.. math::

    P(b \mid L) = (1 − ε) \frac{c^L_b}{N_L} + \frac{ε}{s}, \qquad
    P(b \mid ¬L) = (1 − ε) \frac{c^{¬L}_b}{N_{¬L}} + \frac{ε}{s},

so an empty bin has a small positive probability and no ``log 0`` ever appears, and a
histogram with no samples at all is uniform (``1/s``). Because the pseudo-counts scale
with ``N``, a bin that is empty in *both* histograms carries no evidence
(``P(b|L) = P(b|¬L)``, log-likelihood ratio 0) however unequal ``N_L`` and ``N_{¬L}``
are; fixed Dirichlet pseudo-counts would instead favour the class with fewer samples
there. Densities divide by the bin
width (``P(d|L) = P(b(d)|L) / w_b``), so each integrates to one; every *ratio* below is
independent of the widths. With the prior ``P(L)`` (``prior_same``; by default the
fraction of samples that were "same place", the paper's frequency estimate)

.. math::

    P(d) = P(d \mid L) P(L) + P(d \mid ¬L) P(¬L), \qquad
    P(L \mid d) = P(d \mid L) P(L) / P(d).

Localisation against ``n`` places uses the paper's eq. (2) for each hypothesis ``i``:

.. math::

    P(L_k = L_i \mid Z^k) ∝ \frac{P(d_{ki} \mid L)}{P(d_{ki})} P(L_k = L_i \mid Z^{k-1}),

the denominator depends on ``i`` and is *not* a normalising constant. Everything is
computed in log space; :meth:`HistogramLikelihood.log_likelihood_ratio` returns
``log P(d|L) − log P(d)`` for arrays of any shape, which is what a particle filter adds
to its log-weights. The "new place" hypothesis (CAT-Graph's new-location particle) is
weighted by the average of ``P(d_s|L)/P(d_s)`` over samples ``d_s`` drawn from
``P(d|¬L)`` (eq. 10), computed either by Monte Carlo or exactly as the expectation over
the ``¬L`` histogram (:meth:`HistogramLikelihood.new_place_log_likelihood`).

Monotone likelihood ratio
-------------------------
``d`` is a difference, so a smaller value should never be less evidence of the same
place: the ratio ``P(d|L) / P(d|¬L)`` is non-increasing. With ``monotone=True`` (default)
adjacent bins that violate this are pooled: weighted isotonic regression, by pooling
adjacent violators, of ``q_b = P(b|L) / (P(b|L) + P(b|¬L))`` with weights
``P(b|L) + P(b|¬L)`` on the smoothed tables; inside a block the ratio is
``Σ P(b|L) / Σ P(b|¬L)`` and each block keeps its mass under both classes. The pooling
does not depend on ``P(L)``, and it acts only on evaluation (the counts are unchanged).

Bins and range
--------------
``range=(lo, hi)`` fixes ``s`` equal bins over ``[lo, hi]``; values outside are clipped
into the edge bins, both when learning and when evaluating. ``range=None`` (default)
adapts the range to the data *exactly reproducibly*: bins have width ``2**e`` and edges
at integer multiples of ``2**e``; ``e`` is the smallest integer (at least
``log2(min_bin_width)``) for which all differences seen so far fit into ``s`` consecutive
bins, and the window starts at the bin of the smallest difference. When new data fall
outside, ``e`` grows and neighbouring bins merge exactly (dyadic bins nest), so
``partial_fit`` in any chunks gives bit-for-bit the histogram of one ``fit`` of all the
data; between ``s/2`` and ``s`` bins carry data. Differences outside the learned window
are clipped into the edge bins when evaluated. Constant input (every ``d`` identical)
uses one bin of width ``min_bin_width``.

Three ways to learn it
----------------------
* **online, training-free** (paper §III.D, :class:`HistogramPlaceRecogniser` with the
  default ``n_init=100``): for the first ``T_init`` frames the smallest difference of
  the frame, ``d_min``, is added to ``¬L`` only (nothing is localised); afterwards each
  frame adds ``d_min`` to ``L`` and the smallest difference *outside* ``± exclusion_radius``
  reference indices of the best match (the "second-smallest difference not from the same
  location") to ``¬L``, and then localises with the histograms of that moment. The
  reference map is given, so ``d_min`` is over all reference places. By default each
  frame also adds the differences to ``n_random_different`` places drawn at random
  outside the match's location to ``¬L``: eq. (2) weighs every place, most of which have
  typical differences, and the second-smallest difference alone only describes the low
  tail of ``P(d|¬L)``. With ``reference_positions`` the match's location is every place
  within a distance of it (routes that pass a place twice) instead of an index radius.
* **trained** (:func:`labelled_samples`): ``L`` from every (query, reference) pair the
  ground truth calls a true match, ``¬L`` from a seeded subsample of the other pairs.
* **bootstrapped** from the reference map (:func:`reference_samples`): ``¬L`` from
  reference-vs-reference differences of frames more than ``gap`` indices apart; ``L`` is
  left empty (uniform: a weak prior) unless ``same_radius > 0`` asks for near-neighbour
  reference pairs. Adjacent reference frames are far more alike than the same place seen
  under other conditions, so near-neighbour ``L`` is optimistic; the default lets the
  online updates learn ``L`` from the query itself from its first frame.
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

__all__ = [
    "HistogramLikelihood",
    "HistogramPlaceRecogniser",
    "OnlineSamples",
    "Recognition",
    "Recognitions",
    "labelled_samples",
    "online_samples",
    "reference_samples",
]

_OWNER = "HistogramLikelihood"


def _as_values(values: Any, name: str) -> np.ndarray:
    """Flatten user differences to a finite float64 vector (empty allowed)."""
    if values is None:
        return np.empty(0, dtype=np.float64)
    out = check_array(values, name, dtype=np.float64, allow_empty=True)
    return out.ravel()


def _scaled_floor(x: float, e: int) -> int:
    """``floor(x / 2**e)`` exactly, also where the quotient underflows to zero."""
    q = math.ldexp(x, -e)
    return -1 if (q == 0.0 and x < 0.0) else math.floor(q)


def _smallest_exponent(lo: float, hi: float, n_bins: int, start: int) -> int:
    """Smallest ``e`` at least ``start`` (and at least ``exponent(max|x|) − 60``, so
    that ``x / 2**e`` cannot overflow) with ``floor(hi/2**e) − floor(lo/2**e) <= n_bins − 1``.

    Both lower bounds only grow as data are added, and the condition is monotone in
    ``e``, so the result is the same whether the data arrive at once or in chunks.
    """
    e = max(start, math.frexp(max(abs(lo), abs(hi)))[1] - 60)
    span = hi - lo
    if span / n_bins > 0:
        e = max(e, math.floor(math.log2(span / n_bins)))
    while _scaled_floor(hi, e) - _scaled_floor(lo, e) > n_bins - 1:
        e += 1
    return e


def _monotone_tables(log_same: np.ndarray, log_diff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pool adjacent bins until ``P(b|L)/P(b|¬L)`` is non-increasing in ``b``.

    Weighted isotonic (non-increasing) regression, by pooling adjacent violators, of
    ``q_b = f_b / (f_b + g_b)`` with weights ``m_b = f_b + g_b`` (``f = P(b|L)``,
    ``g = P(b|¬L)``, both smoothed, so every ``m_b > 0``); then
    ``f'_b = q'_b m_b`` and ``g'_b = (1 − q'_b) m_b``. Inside a pooled block the ratio
    is the block's ``Σf / Σg``; each block keeps its mass under both classes, so both
    tables still sum to one. Inputs and outputs are ``(n_bins,)`` logs.
    """
    f, g = np.exp(log_same), np.exp(log_diff)
    # blocks as (Σf, Σg, size); q of a block = Σf / (Σf + Σg), its weight Σf + Σg
    blocks: list[list[float]] = []
    for fb, gb in zip(f.tolist(), g.tolist()):
        blocks.append([fb, gb, 1])
        while len(blocks) > 1 and blocks[-2][0] * blocks[-1][1] < blocks[-1][0] * blocks[-2][1]:
            f2, g2, n2 = blocks.pop()
            blocks[-1][0] += f2
            blocks[-1][1] += g2
            blocks[-1][2] += n2
    sums = np.asarray(blocks, dtype=np.float64)
    sizes = sums[:, 2].astype(np.intp)
    log_m = np.log(f + g)
    log_q = np.repeat(np.log(sums[:, 0]) - np.log(sums[:, 0] + sums[:, 1]), sizes)
    log_1mq = np.repeat(np.log(sums[:, 1]) - np.log(sums[:, 0] + sums[:, 1]), sizes)
    return log_q + log_m, log_1mq + log_m


class HistogramLikelihood:
    """Histogram model of ``P(d|L)``, ``P(d|¬L)`` and ``P(d)`` for whole-image differences.

    Parameters
    ----------
    n_bins : int, default 100
        Number of bins ``s``.
    range : (float, float) or None, default None
        Fixed ``(lo, hi)``: equal bins, values outside clipped into the edge bins.
        ``None``: dyadic bins that adapt to the data exactly (see the module docstring).
    smoothing : float in (0, 1], default 0.01
        Weight ``ε`` of the uniform distribution mixed into both histograms, so that
        no bin has probability 0 (see the module docstring).
    prior_same : float or None, default None
        ``P(L)`` in ``(0, 1)``. ``None``: the fraction of samples that were "same place"
        (``N_L / (N_L + N_¬L)``; ``0.5`` before any sample).
    min_bin_width : float, default 1e-6
        Smallest bin width of the adaptive range (used when every difference is equal).
    monotone : bool, default True
        Constrain the likelihood ratio ``P(d|L)/P(d|¬L)`` to be non-increasing in ``d``
        (a smaller difference is never less evidence of the same place) by pooling
        adjacent violating bins (see the module docstring). ``False``: the raw
        smoothed histograms, as in the paper.

    Attributes
    ----------
    counts_same_, counts_different_ : ndarray, shape (n_bins,), float64
        Sample counts per bin (without the pseudo-counts).
    bin_edges_ : ndarray, shape (n_bins + 1,)
        Bin edges.
    n_same_, n_different_ : int
        Number of samples seen of each kind.
    bin_exponent_, bin_offset_ : int
        Adaptive range only: bins are ``[(m + b)·2**e, (m + b + 1)·2**e)`` for
        ``b = 0 … n_bins − 1``, ``e = bin_exponent_``, ``m = bin_offset_``.
    data_min_, data_max_ : float
        Adaptive range only: smallest and largest difference seen.

    Examples
    --------
    >>> import numpy as np
    >>> model = HistogramLikelihood(n_bins=10, range=(0.0, 1.0)).fit([0.05, 0.1], [0.7, 0.8, 0.9])
    >>> bool(model.log_likelihood_ratio(0.07) > 0 > model.log_likelihood_ratio(0.8))
    True
    """

    def __init__(
        self,
        n_bins: int = 100,
        range: tuple[float, float] | None = None,  # noqa: A002 - numpy.histogram's name
        smoothing: float = 0.01,
        prior_same: float | None = None,
        min_bin_width: float = 1e-6,
        monotone: bool = True,
    ) -> None:
        self.n_bins = n_bins
        self.range = range
        self.smoothing = smoothing
        self.prior_same = prior_same
        self.min_bin_width = min_bin_width
        self.monotone = monotone

    # ------------------------------------------------------------------ parameters
    def get_params(self) -> dict[str, Any]:
        """Constructor parameters (scikit-learn convention)."""
        return {k: getattr(self, k) for k in ("n_bins", "range", "smoothing", "prior_same", "min_bin_width", "monotone")}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    def _validate_params(self) -> None:
        check_scalar(self.n_bins, "n_bins", _OWNER, int, 2)
        check_scalar(self.smoothing, "smoothing", _OWNER, float, 0.0, 1.0, False, True)
        if self.prior_same is not None:
            check_scalar(self.prior_same, "prior_same", _OWNER, float, 0.0, 1.0, False, False)
        check_scalar(self.min_bin_width, "min_bin_width", _OWNER, float, 0.0, low_inclusive=False)
        if not isinstance(self.monotone, (bool, np.bool_)):
            raise InvalidParameterError(
                f"The 'monotone' parameter of {_OWNER} must be a bool. Got {self.monotone!r} instead."
            )
        if self.range is not None:
            ok = (
                isinstance(self.range, (tuple, list, np.ndarray))
                and len(self.range) == 2
                and all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in self.range)
                and all(np.isfinite(float(v)) for v in self.range)
                and float(self.range[0]) < float(self.range[1])
            )
            if not ok:
                raise InvalidParameterError(
                    f"The 'range' parameter of {_OWNER} must be None or a pair of finite floats (lo, hi) "
                    f"with lo < hi. Got {self.range!r} instead."
                )

    # ------------------------------------------------------------------ learning
    def _is_fitted(self) -> bool:
        return hasattr(self, "counts_same_")

    def _check_fitted(self) -> None:
        if not self._is_fitted():
            raise NotFittedError(
                f"This {_OWNER} has no learned histograms yet; call fit(d_same, d_different) or "
                "partial_fit(...) first."
            )

    def _initialise(self) -> None:
        self._validate_params()
        n = self.n_bins
        self.counts_same_ = np.zeros(n, dtype=np.float64)
        self.counts_different_ = np.zeros(n, dtype=np.float64)
        self.n_same_ = 0
        self.n_different_ = 0
        self.data_min_ = math.inf
        self.data_max_ = -math.inf
        if self.range is None:
            self.bin_exponent_ = math.ceil(math.log2(self.min_bin_width))
            self.bin_offset_ = 0
        self._update_edges()

    def _update_edges(self) -> None:
        if self.range is None:
            m, e = self.bin_offset_, self.bin_exponent_
            self.bin_edges_ = np.ldexp(np.arange(m, m + self.n_bins + 1, dtype=np.float64), e)
        else:
            self.bin_edges_ = np.linspace(float(self.range[0]), float(self.range[1]), self.n_bins + 1)

    def _rebin(self, lo: float, hi: float) -> None:
        """Grow the adaptive window (exactly) so that ``[lo, hi]`` fits."""
        new_min, new_max = min(self.data_min_, lo), max(self.data_max_, hi)
        if self.n_same_ + self.n_different_ == 0:
            e_old = None
            e = _smallest_exponent(new_min, new_max, self.n_bins, self.bin_exponent_)
        else:
            e_old = self.bin_exponent_
            e = _smallest_exponent(new_min, new_max, self.n_bins, e_old)
        m = _scaled_floor(new_min, e)
        if e_old is not None and (e != e_old or m != self.bin_offset_):
            absolute = np.arange(self.bin_offset_, self.bin_offset_ + self.n_bins, dtype=np.int64)
            target = np.right_shift(absolute, min(e - e_old, 63)) - m  # floor division by 2**(e - e_old)
            keep = (self.counts_same_ > 0) | (self.counts_different_ > 0)
            # every bin holding data lands inside the new window by construction
            self.counts_same_ = np.bincount(target[keep], self.counts_same_[keep], self.n_bins).astype(np.float64)
            self.counts_different_ = np.bincount(target[keep], self.counts_different_[keep], self.n_bins).astype(
                np.float64
            )
        self.bin_exponent_, self.bin_offset_ = e, m
        self.data_min_, self.data_max_ = new_min, new_max
        self._update_edges()

    def _eval_index(self, d: np.ndarray) -> np.ndarray:
        """Bin used to *evaluate* a difference: clipped into the range of the samples seen."""
        if self.data_min_ <= self.data_max_:
            d = np.clip(d, self.data_min_, self.data_max_)
        return self._bin_index(d)

    def _bin_index(self, d: np.ndarray) -> np.ndarray:
        """Bin of each difference, clipped into ``[0, n_bins)`` (trusts its input)."""
        if self.range is None:
            q = np.ldexp(d, -self.bin_exponent_)
            # a negative quotient that underflows to 0 still lies in bin −1
            idx = np.where((q == 0) & (d < 0), -1.0, np.floor(q)) - self.bin_offset_
        else:
            lo, hi = float(self.range[0]), float(self.range[1])
            idx = np.floor((d - lo) * (self.n_bins / (hi - lo)))
        return np.clip(idx, 0, self.n_bins - 1).astype(np.intp)

    def fit(self, d_same: Any, d_different: Any) -> "HistogramLikelihood":
        """Learn both histograms from scratch.

        Parameters
        ----------
        d_same : array_like, any shape
            Differences between frames of the same place (``L``).
        d_different : array_like, any shape
            Differences between frames of different places (``¬L``).

        Returns
        -------
        self
        """
        self._initialise()
        return self.partial_fit(d_same, d_different)

    def partial_fit(self, d_same: Any = None, d_different: Any = None) -> "HistogramLikelihood":
        """Add samples to the histograms (online learning); either argument may be ``None``.

        Calling it on chunks of the data gives exactly the model of one :meth:`fit`.
        """
        if not self._is_fitted():
            self._initialise()
        same = _as_values(d_same, "d_same (same-place differences)")
        different = _as_values(d_different, "d_different (different-place differences)")
        if same.size + different.size:
            both = np.concatenate([same, different])
            lo, hi = float(both.min()), float(both.max())
            if self.range is None and (lo < self.data_min_ or hi > self.data_max_):
                self._rebin(lo, hi)
            self.data_min_, self.data_max_ = min(self.data_min_, lo), max(self.data_max_, hi)
        if same.size:
            self.counts_same_ += np.bincount(self._bin_index(same), minlength=self.n_bins)
            self.n_same_ += int(same.size)
        if different.size:
            self.counts_different_ += np.bincount(self._bin_index(different), minlength=self.n_bins)
            self.n_different_ += int(different.size)
        return self

    # ------------------------------------------------------------------ probabilities
    @property
    def prior_same_(self) -> float:
        """``P(L)`` in use: ``prior_same`` or the fraction of same-place samples."""
        self._check_fitted()
        if self.prior_same is not None:
            return float(self.prior_same)
        total = self.n_same_ + self.n_different_
        return 0.5 if total == 0 else self.n_same_ / total

    def _log_bin_probabilities(self, counts: np.ndarray, total: int) -> np.ndarray:
        """``log((1 − ε)·c_b/N + ε/s)``; uniform when ``N = 0``."""
        eps, s = float(self.smoothing), self.n_bins
        if total == 0:
            return np.full(s, -math.log(s))
        return np.log((1.0 - eps) * (counts / total) + eps / s)

    def _log_class_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Smoothed per-bin ``log P(b|L)``, ``log P(b|¬L)`` (pooled when ``monotone``)."""
        log_same = self._log_bin_probabilities(self.counts_same_, self.n_same_)
        log_diff = self._log_bin_probabilities(self.counts_different_, self.n_different_)
        if self.monotone and self.n_same_ and self.n_different_:
            log_same, log_diff = _monotone_tables(log_same, log_diff)
        return log_same, log_diff

    def _log_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per-bin ``log P(b|L)``, ``log P(b|¬L)``, ``log P(b)`` and ``log w_b`` (cached
        until the counts, bins or parameters change)."""
        self._check_fitted()
        p = self.prior_same_
        key = (
            self.n_same_, self.n_different_, p, bool(self.monotone), float(self.smoothing),
            float(self.bin_edges_[0]), float(self.bin_edges_[-1]),
        )
        cached = getattr(self, "_tables_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        log_same, log_diff = self._log_class_tables()
        if p <= 0.0:
            log_marg = log_diff
        elif p >= 1.0:
            log_marg = log_same
        else:
            log_marg = np.logaddexp(log_same + math.log(p), log_diff + math.log1p(-p))
        log_width = np.log(np.diff(self.bin_edges_))
        tables = (log_same, log_diff, log_marg, log_width)
        self._tables_cache = (key, tables)
        return tables

    def _lookup(self, d: Any, which: int, per_density: bool) -> np.ndarray | float:
        tables = self._log_tables()
        arr = check_array(d, "differences", dtype=np.float64, allow_empty=True)
        idx = self._eval_index(arr)
        out = tables[which][idx]
        if per_density:
            out = out - tables[3][idx]
        return float(out) if out.ndim == 0 else out

    def log_prob_same(self, d: Any) -> np.ndarray | float:
        """``log P(d|L)`` (density), same shape as ``d``."""
        return self._lookup(d, 0, True)

    def log_prob_different(self, d: Any) -> np.ndarray | float:
        """``log P(d|¬L)`` (density), same shape as ``d``."""
        return self._lookup(d, 1, True)

    def log_prob(self, d: Any) -> np.ndarray | float:
        """``log P(d) = log(P(d|L)P(L) + P(d|¬L)P(¬L))`` (density), same shape as ``d``."""
        return self._lookup(d, 2, True)

    def log_likelihood_ratio(self, d: Any) -> np.ndarray | float:
        """``log P(d|L) − log P(d)`` for every difference, same shape as ``d``.

        The term a hypothesis' log-weight gains from difference ``d`` (eq. 2, eq. 8).
        Bounded above by ``−log P(L)``.
        """
        log_same, _, log_marg, _ = self._log_tables()
        arr = check_array(d, "differences", dtype=np.float64, allow_empty=True)
        out = (log_same - log_marg)[self._eval_index(arr)]
        return float(out) if out.ndim == 0 else out

    def prob_same_given(self, d: Any) -> np.ndarray | float:
        """``P(L|d) = P(d|L)P(L)/P(d)``: probability that one pair with difference ``d``
        shows the same place, same shape as ``d``."""
        llr = self.log_likelihood_ratio(d)
        return np.exp(llr + math.log(self.prior_same_)) if self.prior_same_ > 0 else llr * 0.0

    def new_place_log_likelihood(self, n_samples: int | None = None, rng: Any = None) -> float:
        """``log`` of the mean of ``P(d_s|L)/P(d_s)`` over ``d_s ~ P(d|¬L)`` (eq. 10).

        Parameters
        ----------
        n_samples : int or None
            ``None`` (default): the exact expectation over the smoothed ``¬L``
            histogram, ``Σ_b P(b|¬L)·P(b|L)/P(b)``. An int: the Monte Carlo mean of that
            many samples, as CAT-Graph draws them.
        rng : seed or numpy.random.Generator
            Used only when ``n_samples`` is given.
        """
        log_same, log_diff, log_marg, _ = self._log_tables()
        ratio = log_same - log_marg
        if n_samples is None:
            return float(logsumexp(log_diff + ratio))
        check_scalar(n_samples, "n_samples", "new_place_log_likelihood", int, 1)
        gen = as_generator(rng)
        bins = gen.choice(self.n_bins, size=n_samples, p=np.exp(log_diff - logsumexp(log_diff)))
        return float(logsumexp(ratio[bins]) - math.log(n_samples))

    def log_posterior(
        self,
        differences: Any,
        log_prior: Any = None,
        new_place_prior: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray | float]:
        """Per-hypothesis posterior of eq. (2), with an optional "new place" hypothesis.

        Parameters
        ----------
        differences : array_like, shape (..., n_places)
            Difference of the current frame to every place (last axis).
        log_prior : array_like, shape (..., n_places), optional
            ``log P(L_k = L_i | Z^{k−1})`` (need not be normalised); default uniform.
        new_place_prior : float in [0, 1), optional
            Prior probability of a place not in the map. ``None`` or 0: no new-place
            hypothesis. Otherwise places share ``1 − new_place_prior`` (scaled from
            ``log_prior``) and the new place is weighted by
            :meth:`new_place_log_likelihood` (exact expectation).

        Returns
        -------
        log_post : ndarray, shape (..., n_places)
            ``log P(L_k = L_i | Z^k)``.
        log_post_new : ndarray, shape (...), or float
            ``log P(new place | Z^k)`` (``-inf`` without a new-place hypothesis).
        """
        d = check_array(differences, "differences", dtype=np.float64)
        if d.ndim == 0:
            d = d[None]
        log_w = self.log_likelihood_ratio(d)
        if log_prior is None:
            prior = np.full(d.shape, -math.log(d.shape[-1]))
        else:
            prior = check_array(log_prior, "log_prior", dtype=np.float64, finite=False)
            if prior.shape != d.shape:
                raise ShapeMismatchError(
                    f"log_prior has shape {prior.shape} but differences have shape {d.shape}; give one per place."
                )
            if np.isnan(prior).any() or np.isposinf(prior).any():
                raise DataError("log_prior contains NaN or +inf; give finite log-probabilities (−inf allowed).")
            prior = prior - logsumexp(prior, axis=-1, keepdims=True)
        log_w = log_w + prior
        if new_place_prior:
            check_scalar(new_place_prior, "new_place_prior", "log_posterior", float, 0.0, 1.0, True, False)
            log_w = log_w + math.log1p(-new_place_prior)
            log_new = math.log(new_place_prior) + self.new_place_log_likelihood()
            log_new = np.broadcast_to(log_new, d.shape[:-1])
            total = np.logaddexp(logsumexp(log_w, axis=-1), log_new)
            post_new = log_new - total
        else:
            total = logsumexp(log_w, axis=-1)
            post_new = np.full(d.shape[:-1], -np.inf)
        post = log_w - np.expand_dims(total, -1)
        return post, (float(post_new) if np.ndim(post_new) == 0 else post_new)


# ---------------------------------------------------------------------- sample selection
@dataclass(frozen=True)
class OnlineSamples:
    """The paper's online choice of samples for one frame.

    Attributes
    ----------
    best : int
        Reference index of the smallest difference.
    d_min : float
        The smallest difference (to ``L`` after initialisation, else to ``¬L``).
    d_other : float
        Smallest difference outside ``best ± exclusion_radius`` (to ``¬L``); NaN when
        every place lies in that neighbourhood.
    d_random : tuple of float
        Differences to places drawn uniformly outside that neighbourhood (also to
        ``¬L``; empty unless the recogniser asks for them).
    """

    best: int
    d_min: float
    d_other: float
    d_random: tuple[float, ...] = ()


def online_samples(
    differences: np.ndarray, exclusion_radius: int, same_place: np.ndarray | None = None
) -> OnlineSamples:
    """``d_min`` and the smallest difference not from the same location, O(n_ref).

    Parameters
    ----------
    differences : ndarray, shape (n_ref,)
        One frame's difference to every reference place (trusted: finite, 1-D).
    exclusion_radius : int
        Reference indices ``best ± exclusion_radius`` count as the same location.
    same_place : ndarray of int, optional
        Indices of the places that count as the best match's location (e.g. every place
        within some metres of it); replaces ``exclusion_radius`` when given.
    """
    best = int(np.argmin(differences))
    if same_place is not None:
        rest = np.delete(differences, same_place)
        other = rest.min() if rest.size else math.nan
        return OnlineSamples(best, float(differences[best]), float(other))
    lo, hi = max(0, best - exclusion_radius), best + exclusion_radius + 1
    left, right = differences[:lo], differences[hi:]
    other = min(left.min() if left.size else np.inf, right.min() if right.size else np.inf)
    return OnlineSamples(best, float(differences[best]), float(other) if np.isfinite(other) else math.nan)


def labelled_samples(
    differences: Any,
    ground_truth: Any,
    query_index: Any = None,
    max_different: int | None = 100_000,
    seed: int | np.random.Generator | None = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Same- and different-place differences from a labelled traverse ("trained" mode).

    Parameters
    ----------
    differences : array_like, shape (n_query, n_reference)
        Difference matrix; column ``j`` is reference frame ``j`` as loaded.
    ground_truth : catgraph.traverse.GroundTruth
        Decides which ``(query, reference)`` pairs show the same place.
    query_index : array_like of int, shape (n_query,), optional
        Loaded index of each query row (``Traverse.index``); default ``arange(n_query)``.
    max_different : int or None
        Keep at most this many ``¬L`` samples, drawn without replacement with ``seed``
        (``None``: keep all).
    seed : int, Generator or None

    Returns
    -------
    d_same, d_different : ndarray, float64
        Pass to ``HistogramLikelihood.fit``.
    """
    d = check_array(differences, "differences", ndim=2)
    n_query, n_ref = d.shape
    q = np.arange(n_query) if query_index is None else np.asarray(query_index)
    if q.shape != (n_query,):
        raise ShapeMismatchError(f"query_index has shape {q.shape} but differences have {n_query} rows.")
    if max_different is not None:
        check_scalar(max_different, "max_different", "labelled_samples", int, 1)
    columns = np.arange(n_ref)
    same_mask = np.zeros(d.shape, dtype=bool)
    for row in range(n_query):
        same_mask[row] = ground_truth.correct(np.full(n_ref, q[row], dtype=np.int64), columns)
    d_same = d[same_mask]
    d_diff = d[~same_mask]
    if max_different is not None and d_diff.size > max_different:
        d_diff = d_diff[as_generator(seed).choice(d_diff.size, size=max_different, replace=False)]
    return d_same, d_diff


def reference_samples(
    reference_differences: Any,
    gap: int,
    max_different: int = 100_000,
    same_radius: int = 0,
    seed: int | np.random.Generator | None = 0,
    reference_positions: Any = None,
    min_distance: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Bootstrap samples from the reference map alone (reference vs reference).

    Parameters
    ----------
    reference_differences : array_like, shape (n_reference, n_reference)
        Differences between reference frames (same metric and normalisation as the
        query differences will have).
    gap : int
        Pairs ``(j, j')`` with ``|j − j'| > gap`` count as different places.
    max_different : int
        Number of ``¬L`` pairs drawn (seeded, with replacement among eligible pairs).
    same_radius : int
        ``0`` (default): no ``L`` samples, ``P(d|L)`` starts uniform (a weak prior) and
        is learned online. ``r > 0``: the pairs with ``1 ≤ |j − j'| ≤ r`` are ``L``.
    seed : int, Generator or None
    reference_positions : array_like, shape (n_reference, n_dims), optional
        Metric positions; with ``min_distance``, pairs closer than that are never
        ``¬L`` (a route that passes a place twice is far apart in index there).
    min_distance : float, optional
        Needed with ``reference_positions``.

    Returns
    -------
    d_same, d_different : ndarray, float64
    """
    r = check_array(reference_differences, "reference differences", ndim=2)
    n = r.shape[0]
    if r.shape[1] != n:
        raise ShapeMismatchError(f"reference differences must be square (n_reference, n_reference); got {r.shape}.")
    check_scalar(gap, "gap", "reference_samples", int, 0, n - 2)
    check_scalar(max_different, "max_different", "reference_samples", int, 1)
    check_scalar(same_radius, "same_radius", "reference_samples", int, 0, gap)
    rng = as_generator(seed)
    # draw the offset |j − j'| in (gap, n) weighted by how many pairs have it, then j
    offsets = np.arange(gap + 1, n)
    weights = (n - offsets).astype(np.float64)
    k = rng.choice(offsets, size=max_different, p=weights / weights.sum())
    j = np.floor(rng.random(max_different) * (n - k)).astype(np.int64)
    flip = rng.random(max_different) < 0.5
    rows, cols = np.where(flip, j + k, j), np.where(flip, j, j + k)
    if reference_positions is not None:
        pos = check_array(reference_positions, "reference_positions", ndim=2)
        if pos.shape[0] != n:
            raise ShapeMismatchError(f"reference_positions has {pos.shape[0]} rows for {n} reference frames.")
        if min_distance is None:
            raise InvalidParameterError("reference_samples with reference_positions needs min_distance.")
        check_scalar(min_distance, "min_distance", "reference_samples", float, 0.0)
        keep = np.linalg.norm(pos[rows] - pos[cols], axis=1) > min_distance
        # top up with further seeded draws among far pairs, a bounded number of rounds
        for _ in range(50):
            if keep.sum() >= max_different:
                break
            k2 = rng.choice(offsets, size=max_different, p=weights / weights.sum())
            j2 = np.floor(rng.random(max_different) * (n - k2)).astype(np.int64)
            far = np.linalg.norm(pos[j2] - pos[j2 + k2], axis=1) > min_distance
            rows, cols = np.concatenate([rows[keep], j2[far]]), np.concatenate([cols[keep], (j2 + k2)[far]])
            keep = np.ones(rows.size, dtype=bool)
        rows, cols = rows[keep][:max_different], cols[keep][:max_different]
        if rows.size == 0:
            raise DataError(
                f"no reference pairs are more than {min_distance} apart and {gap} frames apart; lower min_distance."
            )
    d_diff = r[rows, cols]
    if same_radius:
        parts = [np.diagonal(r, o) for o in range(1, same_radius + 1)] + [
            np.diagonal(r, -o) for o in range(1, same_radius + 1)
        ]
        d_same = np.concatenate(parts)
    else:
        d_same = np.empty(0, dtype=np.float64)
    return d_same, d_diff


# ---------------------------------------------------------------------- recogniser
@dataclass(frozen=True)
class Recognition:
    """The answer for one query frame.

    Attributes
    ----------
    match : int
        Best reference index (smallest difference).
    confidence : float
        Posterior probability (eq. 2) that the frame is within ``± confidence_radius``
        of ``match``; 0 while initialising.
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

    def _update(self, row: np.ndarray) -> OnlineSamples:
        best = int(np.argmin(row))
        same_place = self._same_location(best)
        samples = online_samples(row, self.exclusion_radius, same_place)
        if self.learn:
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
        samples = self._update(row)
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
        differences : array_like, shape (n_query, n_ref)

        Returns
        -------
        Recognitions
        """
        d = check_array(differences, "differences", ndim=2)
        out = [self.step(row) for row in d]
        return Recognitions(
            match=np.array([r.match for r in out], dtype=np.int64),
            confidence=np.array([r.confidence for r in out]),
            new_place_probability=np.array([r.new_place_probability for r in out]),
            prob_same=np.array([r.prob_same for r in out]),
            d_min=np.array([r.d_min for r in out]),
            initialising=np.array([r.initialising for r in out], dtype=bool),
        )
