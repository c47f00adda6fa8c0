"""numba kernels for difference matrices (imported lazily by :mod:`catgraph.differences`)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, fastmath=True, cache=True)
def sad_block(query: np.ndarray, reference: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[i, j] = Σ_k |query[i, k] − reference[j, k]|`` (float32 inputs)."""
    nq, d = query.shape
    nr = reference.shape[0]
    for i in numba.prange(nq):
        q = query[i]
        for j in range(nr):
            r = reference[j]
            acc = np.float32(0.0)
            for k in range(d):
                acc += abs(q[k] - r[k])
            out[i, j] = acc
