"""Ground truth from a file, in the forms datasets publish it.

:func:`load_ground_truth` reads

``.csv`` / ``.txt``
    One true ``query,reference`` index pair per row (indices of the frames *as loaded*,
    from 0); a header row is optional; a query with several true references has several
    rows; a query with none has none (it then has no true match, and recall does not
    count it).
``.npy`` / ``.npz``
    A boolean or soft ``(n_query, n_reference)`` matrix (entry ``[i, j]`` > 0: reference
    ``j`` is a true match of query ``i``; soft values count where positive). An ``.npz``
    holds one array, or names it ``ground_truth``. Loaded without pickle.

Other published forms convert in a few lines, e.g. an object array of
``[query, [references…]]`` rows (loaded once, with ``allow_pickle=True``, from a source
you trust)::

    pairs = [(q, r) for q, refs in rows for r in refs]
    np.savetxt("pairs.csv", pairs, fmt="%d", delimiter=",", header="query,reference", comments="")

or a per-query list of positive references ``gt[q]``::

    m = np.zeros((n_query, n_reference), bool)
    for q, refs in enumerate(gt): m[q, refs] = True
    np.save("gt.npy", m)
"""

from __future__ import annotations

import csv
import zipfile
from pathlib import Path

import numpy as np

from ..exceptions import DataError, DataNotFoundError
from ..traverse import ExplicitGroundTruth

__all__ = ["load_ground_truth"]


def _pairs_from_csv(path: Path, n_query: int, n_reference: int) -> np.ndarray:
    rows = []
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            for k, row in enumerate(csv.reader(fh)):
                cells = [c.strip() for c in row if c.strip() != ""]
                if not cells or cells[0].startswith("#"):
                    continue
                try:
                    values = [int(c) for c in cells]
                except ValueError:
                    if k == 0 and not rows:  # a header
                        continue
                    raise DataError(f"{path}: row {k + 1} is not two integer indices 'query,reference': "
                                    f"{','.join(cells)!r}.") from None
                if len(values) != 2:
                    raise DataError(f"{path}: row {k + 1} has {len(values)} values; each row is one "
                                    "'query,reference' pair.")
                if not (0 <= values[0] < n_query and 0 <= values[1] < n_reference):
                    raise DataError(f"{path}: row {k + 1}, pair {values[0]},{values[1]}, lies outside the "
                                    f"{n_query} query × {n_reference} reference frames as loaded (indices from "
                                    "0); give 0-based indices of this query and reference.")
                rows.append(values)
    except UnicodeDecodeError:
        raise DataError(f"{path} is not a text file of 'query,reference' pairs.") from None
    if not rows:
        raise DataError(f"{path} lists no 'query,reference' pairs.")
    return np.asarray(rows, dtype=np.int64)


def _matrix(path: Path) -> np.ndarray:
    try:
        loaded = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise DataError(f"{path} cannot be loaded without pickle ({exc}); save a plain boolean or float "
                        "matrix.") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise DataError(f"{path} is not a readable .npy/.npz file: {exc}") from None
    if isinstance(loaded, np.ndarray):
        return loaded
    with loaded:
        keys = list(loaded.files)
        name = "ground_truth" if "ground_truth" in keys else keys[0] if len(keys) == 1 else None
        if name is None:
            raise DataError(f"{path} holds arrays {keys}; name the matrix 'ground_truth'.")
        try:
            return loaded[name]
        except ValueError as exc:
            raise DataError(f"{path} cannot be loaded without pickle ({exc}).") from None


def load_ground_truth(path: str | Path, n_query: int, n_reference: int) -> ExplicitGroundTruth:
    """Ground truth from a pairs CSV or a matrix file (see the module docstring).

    Parameters
    ----------
    path : str or Path
    n_query, n_reference : int
        Frames of the query and the reference as loaded; the file must fit them.

    Returns
    -------
    ExplicitGroundTruth
    """
    path = Path(path)
    if path.is_dir():
        raise DataError(f"ground-truth file {path} is a folder; give a .csv of query,reference pairs or a "
                        ".npy/.npz matrix.")
    if not path.is_file():
        raise DataNotFoundError(f"ground-truth file {path} does not exist; give a .csv of query,reference pairs "
                                "or a .npy/.npz matrix.")
    suffix = path.suffix.lower()
    if suffix in (".csv", ".txt"):
        return ExplicitGroundTruth.from_pairs(_pairs_from_csv(path, n_query, n_reference), n_query, n_reference)
    if suffix not in (".npy", ".npz"):
        raise DataError(f"{path}: a ground-truth file is a .csv of query,reference pairs or a .npy/.npz matrix.")
    m = _matrix(path)
    if m.ndim != 2 or m.shape != (n_query, n_reference):
        raise DataError(f"{path} holds a matrix of shape {m.shape}, but the query has {n_query} frames and the "
                        f"reference {n_reference}: it must be (n_query, n_reference) = ({n_query}, {n_reference}).")
    if m.dtype.kind not in "buif":
        raise DataError(f"{path} holds {m.dtype} values; a ground-truth matrix is boolean or real.")
    if m.dtype.kind == "f" and not np.all(np.isfinite(m)):
        raise DataError(f"{path}: the ground-truth matrix contains NaN or infinite values.")
    return ExplicitGroundTruth(m)
