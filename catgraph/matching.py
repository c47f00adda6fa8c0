"""Best match and its confidence from a row of scores (smaller = more alike).

The confidence follows SeqSLAM: the margin between the best score and the best score
*outside a neighbourhood* of ``± exclusion`` places around it (the second-best
hypothesis from another location). With per-query normalised differences the margin is
in units of the row's standard deviation, so one threshold serves any dataset.
"""

from __future__ import annotations

import numpy as np

__all__ = ["best_matches"]


def best_matches(scores: np.ndarray, exclusion: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Per row: ``argmin`` and margin to the best score outside ``± exclusion``.

    Parameters
    ----------
    scores : ndarray, shape (n, n_reference)
        Non-finite entries (``inf``, ``nan``) are ignored. A row with no finite
        entry has no output (match ``-1``, confidence ``-inf``).
    exclusion : int
        Half-width of the neighbourhood around the best match that does not count as
        "another place".

    Returns
    -------
    match : ndarray of int, shape (n,)
    confidence : ndarray of float, shape (n,)
        ``second_best_outside − best`` (≥ 0); ``inf``-free: where every other place is
        inside the neighbourhood the margin is 0.
    """
    s = np.asarray(scores, dtype=np.float64)
    if s.ndim == 1:
        s = s[None, :]
    s = np.where(np.isfinite(s), s, np.inf)
    n, n_ref = s.shape
    match = np.argmin(s, axis=1)
    best = s[np.arange(n), match]
    cols = np.arange(n_ref)
    near = np.abs(cols[None, :] - match[:, None]) <= exclusion
    second = np.where(near, np.inf, s).min(axis=1)
    none = ~np.isfinite(best)
    confidence = np.where(np.isfinite(second), second - best, 0.0)
    match = np.where(none, -1, match)
    confidence = np.where(none, -np.inf, confidence)
    return match.astype(np.int64), confidence
