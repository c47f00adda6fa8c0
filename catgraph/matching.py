"""Best match and its confidence from a row of scores (smaller = more alike).

The confidence follows SeqSLAM: the margin between the best score and the best score
*outside a neighbourhood* of ``± exclusion`` places around it (the second-best
hypothesis from another location). With per-query normalised differences the margin is
in units of the row's standard deviation, so one threshold serves any dataset.

Frames with no information
    A row whose finite scores are all equal (a constant, black or all-undetected query
    frame: every reference place is equally far, ``σ = 0``) or that has no finite score
    at all says nothing about where the frame was taken. It gets **no output**: match
    ``-1`` and confidence ``0.0`` — the lowest confidence a margin can have, finite so
    that the arrays are safe to average, sort and save. Evaluation
    (:mod:`catgraph.metrics`) reads no confidence where there is no output, and result
    files (:mod:`catgraph.results`) write ``null`` for both; a frame with no
    information is therefore never a confident answer.
"""

from __future__ import annotations

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError

__all__ = ["NO_MATCH", "NO_OUTPUT_CONFIDENCE", "best_matches", "has_information"]

#: The match of a frame with no output.
NO_MATCH = -1
#: The confidence stored for a frame with no output (never read by evaluation).
NO_OUTPUT_CONFIDENCE = 0.0


def has_information(scores: np.ndarray) -> np.ndarray:
    """Per row: does it tell reference places apart (some finite scores differ)?

    Parameters
    ----------
    scores : ndarray, shape (n, n_reference) or (n_reference,)

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    s = np.asarray(scores, dtype=np.float64)
    if s.ndim == 1:
        s = s[None, :]
    finite = np.isfinite(s)
    hi = np.where(finite, s, -np.inf).max(axis=1, initial=-np.inf)
    lo = np.where(finite, s, np.inf).min(axis=1, initial=np.inf)
    scale = np.maximum(1.0, np.maximum(np.abs(np.where(np.isfinite(hi), hi, 0.0)),
                                       np.abs(np.where(np.isfinite(lo), lo, 0.0))))
    with np.errstate(invalid="ignore", over="ignore"):
        half_spread = hi / 2 - lo / 2  # halves: no overflow for scores near ±float max
    return np.isfinite(half_spread) & (half_spread > 0.5e-12 * scale)


def best_matches(scores: np.ndarray, exclusion: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Per row: ``argmin`` and margin to the best score outside ``± exclusion``.

    Parameters
    ----------
    scores : ndarray, shape (n, n_reference) or (n_reference,)
        Non-finite entries (``inf``, ``nan``) are ignored. A row with no information
        (no finite entry, or all finite entries equal) has no output.
    exclusion : int
        Half-width of the neighbourhood around the best match that does not count as
        "another place".

    Returns
    -------
    match : ndarray of int, shape (n,)
        ``-1`` (:data:`NO_MATCH`) where there is no output.
    confidence : ndarray of float, shape (n,)
        ``second_best_outside − best`` (≥ 0, always finite): where every other place is
        inside the neighbourhood the margin is 0; where there is no output it is
        :data:`NO_OUTPUT_CONFIDENCE` (0).

    Raises
    ------
    DataError
        ``scores`` is not a numeric 1-D or 2-D array, or has no reference column.
    InvalidParameterError
        ``exclusion`` is not an int ≥ 0.

    Examples
    --------
    >>> best_matches([[3.0, 0.0, 2.0, 5.0], [1.0, 1.0, 1.0, 1.0]], exclusion=1)
    (array([ 1, -1]), array([5., 0.]))
    """
    check_scalar(exclusion, "exclusion", "best_matches", int, 0)
    s = check_array(scores, "scores", ndim=(1, 2), dtype=np.float64, allow_empty=True, finite=False)
    if s.ndim == 1:
        s = s[None, :]
    n, n_ref = s.shape
    if n_ref == 0:
        raise DataError("scores have no reference column; a match needs at least one reference place.")
    match = np.empty(n, dtype=np.int64)
    confidence = np.empty(n, dtype=np.float64)
    # rows in blocks: the temporaries below are a few times their input's size, and a
    # large map's whole difference matrix must not be copied several times over
    rows = max(1, _BLOCK_VALUES // n_ref)
    for lo in range(0, n, rows):
        match[lo : lo + rows], confidence[lo : lo + rows] = _best_block(s[lo : lo + rows], exclusion)
    return match, confidence


#: values per block of rows in :func:`best_matches` (8 MiB of float64)
_BLOCK_VALUES = 1 << 20


def _best_block(s: np.ndarray, exclusion: int) -> tuple[np.ndarray, np.ndarray]:
    n, n_ref = s.shape
    informative = has_information(s)
    s = np.where(np.isfinite(s), s, np.inf)
    match = np.argmin(s, axis=1)
    best = s[np.arange(n), match]
    cols = np.arange(n_ref)
    near = np.abs(cols[None, :] - match[:, None]) <= exclusion
    second = np.where(near, np.inf, s).min(axis=1, initial=np.inf)
    with np.errstate(invalid="ignore", over="ignore"):
        half_margin = second / 2 - best / 2
    big = np.finfo(np.float64).max
    confidence = np.where(np.isfinite(half_margin), np.minimum(2 * np.minimum(half_margin, big / 2), big), 0.0)
    # one reference place is informative on its own only if its score is finite
    has_output = informative | ((n_ref == 1) & np.isfinite(best))
    has_output &= np.isfinite(best)
    return np.where(has_output, match, NO_MATCH), np.where(has_output, confidence, NO_OUTPUT_CONFIDENCE)
