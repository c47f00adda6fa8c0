"""The histogram model of paper 2: ``P(d|L)``, ``P(d|¬L)`` and ``P(d)`` for whole-image
differences, smoothed, with a monotone likelihood ratio and exactly reproducible adaptive
bins. The mathematics is in :mod:`catgraph.likelihood`; this module holds the model.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
from scipy.special import logsumexp

from ._validation import as_generator, check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, NotFittedError, ShapeMismatchError

__all__ = ["HistogramLikelihood"]

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
    if not math.isfinite(span):  # values near ±float max: the span in halves (the same exponent)
        e = max(e, math.floor(math.log2((hi / 2 - lo / 2) / n_bins)) + 1)
    elif span / n_bins > 0:
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
        self._tables_cache = None  # a model fitted again: the tables of the last fit are not its own
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
            with np.errstate(over="ignore"):  # samples near ±float max: an edge beyond it is ±inf
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
        else:  # by the edges themselves: a value on an edge opens its bin (the scaled floor can round below it)
            idx = np.searchsorted(self.bin_edges_, d, side="right") - 1
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
            if np.isneginf(prior).all(axis=-1).any():
                raise DataError("log_prior gives no place any mass (every entry −inf in a row); give at least one "
                                "finite log-probability per row.")
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
