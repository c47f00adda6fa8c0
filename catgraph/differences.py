"""Whole-descriptor differences between query and reference frames.

Metrics (all "smaller = more alike", ``(n_query, n_reference)``):

``sad``      sum of absolute differences (SeqSLAM), compiled with numba;
``ssd``      sum of squared differences, ``|q|² + |r|² − 2 q·r`` clipped at 0;
``cosine``   ``1 − q·r / (|q| |r|)``; a zero vector has difference 1 to everything;
``hamming``  number of differing bits (boolean arrays, or ``uint8`` packed bits).

:func:`difference_matrix` works block by block: at most ``block_rows`` query rows are
compared at once, so the working memory beyond the result is bounded
(``block_rows × n_reference``); :func:`iter_difference_blocks` yields the blocks for
callers that never want the whole matrix, and :func:`difference_row` is the streaming
form (one query frame against every reference place).

:func:`normalise_rows` is paper 1's per-query normalisation
``d_ij = (|Q_i − R_j| − μ_i) / σ_i`` with ``μ_i, σ_i`` over all reference ``j``; a row
with ``σ_i = 0`` (every reference equally far) becomes all zeros.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError

__all__ = ["METRICS", "difference_matrix", "difference_row", "iter_difference_blocks", "normalise_rows"]

METRICS = ("sad", "ssd", "cosine", "hamming")


def _prepare(x, name: str, metric: str) -> np.ndarray:
    arr = np.asarray(x)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        arr = arr.reshape(arr.shape[0], -1) if arr.ndim > 2 else arr
    if metric == "hamming":
        if arr.dtype == bool:
            return arr
        if arr.dtype == np.uint8:
            return np.unpackbits(arr, axis=1).astype(bool)
        raise DataError(f"the hamming metric needs boolean or packed uint8 {name}; got dtype {arr.dtype}.")
    return check_array(arr, name, ndim=2, dtype=np.float32)


def _check_pair(query, reference, metric: str) -> tuple[np.ndarray, np.ndarray]:
    if metric not in METRICS:
        raise InvalidParameterError(f"Unknown difference metric {metric!r}; choose one of {', '.join(METRICS)}.")
    q = _prepare(query, "query descriptors", metric)
    r = _prepare(reference, "reference descriptors", metric)
    if q.shape[1] != r.shape[1]:
        raise ShapeMismatchError(
            f"query descriptors have {q.shape[1]} values per frame but reference descriptors have {r.shape[1]}; "
            "use the same front-end (and image size) for both traverses."
        )
    return q, r


def _block(q: np.ndarray, r: np.ndarray, metric: str, r_sq: np.ndarray | None) -> np.ndarray:
    if metric == "sad":
        from ._diff_kernels import sad_block

        out = np.empty((q.shape[0], r.shape[0]), dtype=np.float32)
        sad_block(np.ascontiguousarray(q), np.ascontiguousarray(r), out)
        return out.astype(np.float64)
    if metric == "ssd":
        q64 = q.astype(np.float64)
        out = (q64 * q64).sum(1)[:, None] + r_sq[None, :] - 2.0 * (q64 @ r.astype(np.float64).T)
        return np.maximum(out, 0.0)
    if metric == "cosine":
        q64 = q.astype(np.float64)
        qn = np.linalg.norm(q64, axis=1)
        denom = qn[:, None] * r_sq[None, :]
        dot = q64 @ r.astype(np.float64).T
        with np.errstate(invalid="ignore", divide="ignore"):
            sim = np.where(denom > 0, dot / np.where(denom > 0, denom, 1.0), 0.0)
        return np.clip(1.0 - sim, 0.0, 2.0)
    # hamming on booleans: q(1-r) + (1-q) r
    qf = q.astype(np.float32)
    rf = r.astype(np.float32)
    return (qf @ (1.0 - rf).T + (1.0 - qf) @ rf.T).astype(np.float64)


def _reference_aux(r: np.ndarray, metric: str) -> np.ndarray | None:
    if metric == "ssd":
        r64 = r.astype(np.float64)
        return (r64 * r64).sum(1)
    if metric == "cosine":
        return np.linalg.norm(r.astype(np.float64), axis=1)
    return None


def iter_difference_blocks(
    query: np.ndarray, reference: np.ndarray, metric: str = "sad", block_rows: int = 256
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(start, block)`` with ``block = D[start:start + block_rows]`` (float64).

    Only one block of ``block_rows × n_reference`` values is held at a time.
    """
    check_scalar(block_rows, "block_rows", "iter_difference_blocks", int, 1)
    q, r = _check_pair(query, reference, metric)
    aux = _reference_aux(r, metric)
    for start in range(0, q.shape[0], block_rows):
        yield start, _block(q[start : start + block_rows], r, metric, aux)


def difference_matrix(
    query: np.ndarray, reference: np.ndarray, metric: str = "sad", block_rows: int = 256, normalise: bool = False
) -> np.ndarray:
    """Differences between every query and every reference descriptor.

    Parameters
    ----------
    query : ndarray, shape (n_query, d)
    reference : ndarray, shape (n_reference, d)
    metric : {"sad", "ssd", "cosine", "hamming"}
    block_rows : int
        Query rows computed at once (bounds the working memory).
    normalise : bool
        Apply :func:`normalise_rows` to each block as it is computed.

    Returns
    -------
    ndarray, shape (n_query, n_reference), float64
    """
    q, r = _check_pair(query, reference, metric)
    out = np.empty((q.shape[0], r.shape[0]), dtype=np.float64)
    for start, block in iter_difference_blocks(q, r, metric, block_rows):
        out[start : start + block.shape[0]] = normalise_rows(block) if normalise else block
    return out


def difference_row(descriptor: np.ndarray, reference: np.ndarray, metric: str = "sad") -> np.ndarray:
    """One query descriptor ``(d,)`` against every reference descriptor → ``(n_reference,)``."""
    q, r = _check_pair(np.asarray(descriptor)[None, ...].reshape(1, -1), reference, metric)
    return _block(q, r, metric, _reference_aux(r, metric))[0]


def normalise_rows(differences: np.ndarray) -> np.ndarray:
    """Per-query normalisation ``(d_ij − μ_i) / σ_i`` over the reference axis.

    Works on ``(n_reference,)`` rows or ``(n_query, n_reference)`` matrices; rows with
    zero spread become zeros (not NaN).
    """
    d = np.asarray(differences, dtype=np.float64)
    mean = d.mean(axis=-1, keepdims=True)
    std = d.std(axis=-1, keepdims=True)
    ok = std > 1e-12 * np.maximum(1.0, np.abs(mean))
    return np.where(ok, (d - mean) / np.where(ok, std, 1.0), 0.0)
