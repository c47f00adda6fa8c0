"""Compiled helpers of the tempered whole-image model (imported lazily: numba)."""

from __future__ import annotations

import math

import numpy as np

from ._jit import njit


@njit
def predictive_scores(base, log_prior, taus):  # pragma: no cover - compiled
    """For each ``τ``: ``log Σ_j e^{log_prior_j + τ b_j} − log mean_j e^{τ b_j}``."""
    n = base.shape[0]
    nt = taus.shape[0]
    top = -np.inf
    for j in range(n):
        if base[j] > top:
            top = base[j]
    num = np.zeros(nt)
    den = np.zeros(nt)
    for j in range(n):
        x = base[j] - top
        p = math.exp(log_prior[j]) if log_prior[j] > -700.0 else 0.0
        for t in range(nt):
            e = math.exp(taus[t] * x)
            den[t] += e
            num[t] += e * p
    out = np.empty(nt)
    for t in range(nt):
        out[t] = math.log(num[t] + 1e-300) - math.log(den[t] / n)
    return out
