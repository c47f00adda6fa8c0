"""Whole-descriptor differences between query and reference frames.

Metrics (all "smaller = more alike", ``(n_query, n_reference)`` float64):

``sad``      sum of absolute differences (SeqSLAM);
``ssd``      sum of squared differences ``Σ (q − r)²`` (computed directly, no
             cancellation);
``cosine``   ``1 − q·r / (|q| |r|)``, clipped to ``[0, 2]``; a zero vector has
             difference 1 to everything;
``hamming``  number of differing bits (boolean arrays, or ``uint8`` packed bits).

One arithmetic for every path
-----------------------------
A :class:`PreparedReference` holds the reference descriptors validated once, laid out
for the compiled kernels (C-contiguous float32; bits as 0/1 float32) with the norms the
metric needs precomputed. Every difference — one live frame (:meth:`~PreparedReference.row`),
a batch matrix (:func:`difference_matrix`), its blocks (:func:`iter_difference_blocks`),
a reference shard on a Dask worker (:mod:`catgraph.distributed`) — goes through the
same kernel (:mod:`catgraph._diff_kernels`), whose value for a pair ``(q_i, r_j)``
depends on those two descriptors only (float32 terms, summed in SIMD lanes by the
same machine code for every pair). So the streaming and batch paths agree *bit for
bit*, and with a slow float64 reference (``numpy``/``scipy``) to float32 rounding:
``|error| ≤ (d + 3) · 2⁻²⁴ · Σ_k |term_k|`` (a bound; the measured error is far smaller, as
each lane sums only ``d / lanes`` terms). Float32 sums keep the batch path
compute-bound at twice the float64 rate; the streaming row is memory-bound either way.
The kernel runs in parallel over blocks of reference places, so one live frame uses
every core.

Compact layout
--------------
A live difference row reads the whole map once per frame, so its floor is the map's
size divided by the memory bandwidth. ``PreparedReference(..., layout="uint8")`` stores
one byte per value instead of four: each value ``x`` becomes the code
``c = round((x − lo) / s)`` in ``0 … 255`` with ``lo, hi`` the reference's smallest
and largest value and ``s = (hi − lo) / 255`` (``s = 1``, ``lo`` the minimum, when
the values are integers spanning at most 255 — Wi-Fi strengths in whole dB, bits —
and then the codes are the values themselves: no error at all). Query values use the
same ``lo, s``, clipped to ``[lo, hi]``. The kernel sums integer code differences
exactly (64-bit integers; the result is ``s · Σ|c_q − c_r|`` for SAD and
``s² · Σ (c_q − c_r)²`` for SSD), so every path — row, block, matrix, bootstrap —
agrees bit for bit with the slow reference computed on the codes, on any machine. It
sums 64 bytes per vector step (the processor's sum-of-absolute-differences
instruction where it has one; :mod:`catgraph._diff_kernels`), which keeps the row
close to the speed of reading the codes from memory.
Against the float differences of the original values (``e_k = s/2 + s/2`` from the
two roundings, plus ``δ_k``, the distance of a query value outside ``[lo, hi]`` to
that range):

* SAD: ``|D_uint8 − D| ≤ Σ_k (s + δ_k)`` (:meth:`PreparedReference.quantisation_bound`);
* SSD: ``|D_uint8 − D| ≤ Σ_k (2 |q_k − r_k| (s + δ_k) + (s + δ_k)²)``;
* Hamming: exact (bits are codes 0 and 1).

Cosine keeps the float32 layout (its norms do not survive an offset code). The
per-query normalisation divides the common factor ``s`` out again.

Per-query normalisation
-----------------------
:func:`normalise_rows` is paper 1's ``d_ij = (|Q_i − R_j| − μ_i) / σ_i`` with ``μ_i, σ_i``
(population standard deviation) over all reference ``j``, computed in two passes
(mean, then squared deviations) over fixed chunks of values whose partial sums are
added in order — thread-count independent (a long row's passes run on both cores in
runs of whole chunks, a block's in ranges of rows), and reproducible from a sharded
reference. Defined behaviour at the edges, never a warning:

* a row with **zero spread** (every reference equally far, ``σ_i ≤ 1e-12 ·
  max(1, |μ_i|)``: a blank frame, a scan that saw nothing) becomes **all zeros**:
  ``0`` is the normalised difference of an *unrelated* place, so the row is "no
  evidence either way". It cannot look like a confident match: every place ties,
  the margin between best and second best is 0, and a sequence window summing it
  gains nothing;
* a **non-finite** value (``inf``, ``nan``) raises :class:`~catgraph.exceptions.DataError`
  naming the value and where it is (an infinite difference has no place in a mean);
* a row with **no reference places** (shape ``(…, 0)``) raises ``DataError``; zero
  *rows* (shape ``(0, N)``) give an empty result.

Memory
------
:func:`difference_matrix` works block by block (at most ``block_rows`` query rows at
once); :func:`iter_difference_blocks` yields the blocks for callers that never want the
whole ``n_query × N`` matrix; :class:`DifferenceRows` hands such blocks to a consumer
that walks the query frame by frame (the filters' ``run``, single-frame matching), so a
batch command holds one block, not the matrix; the live path holds one row.

Cold start
----------
The kernels compile once per machine on first use (one signature each) and are
cached on disk next to this module; where that folder is read-only numba falls back
to its user cache directory (set ``NUMBA_CACHE_DIR`` to choose one). Measured figures
are in ``benchmarks/results/live.md``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, ShapeMismatchError

__all__ = [
    "LAYOUTS",
    "METRICS",
    "PreparedReference",
    "DifferenceRows",
    "code_scale",
    "difference_matrix",
    "difference_row",
    "iter_difference_blocks",
    "iter_difference_columns",
    "iter_reference_columns",
    "normalise_rows",
]

METRICS = ("sad", "ssd", "cosine", "hamming")
#: Memory layouts of a :class:`PreparedReference` (see "Compact layout" above).
LAYOUTS = ("float32", "uint8")

#: float64 values of scratch per block when the query block size is chosen automatically.
_BLOCK_VALUES = 1 << 22


#: Pair terms (query rows × places × values) per thread below which a kernel call runs
#: on fewer threads: waking a second thread costs more than it saves on small maps,
#: and much more on a busy machine (measured: 288 places, 0.14 ms on one thread,
#: 6.6 ms on two when the cores are shared). The result does not depend on it.
WORK_PER_THREAD = 1 << 24


def _kernels():
    from . import _diff_kernels

    return _diff_kernels


_POOL = None


def _threads_available() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def _pair_block(q: np.ndarray, r: np.ndarray, code: int, out: np.ndarray, step: float | None = None) -> None:
    """The pair kernel over disjoint place ranges, on as many threads as the work is
    worth (the result is the same on any number). ``step`` given: the compact
    (``uint8`` codes) kernel, whose sums are multiplied by ``step``."""
    k = _kernels()
    n = r.shape[0]
    threads = int(max(1, min(_threads_available(), (q.shape[0] * n * r.shape[1]) // WORK_PER_THREAD,
                             -(-n // k.PLACE_BLOCK))))
    if step is None:
        kernel, extra = k.pair_block, (code,)
    else:
        kernel, extra = k.pair_block_codes, (code, float(step))
    if threads == 1:
        kernel(q, r, 0, n, *extra, out)
        return
    blocks = -(-n // k.PLACE_BLOCK)
    edges = [min(n, (blocks * t // threads) * k.PLACE_BLOCK) for t in range(threads + 1)]
    _run_parallel([(kernel, (q, r, lo, hi, *extra, out)) for lo, hi in zip(edges[:-1], edges[1:])])


def _run_parallel(calls: list) -> None:
    """Run ``(kernel, args)`` calls (GIL-releasing, disjoint outputs): the first on the
    calling thread, the others on the shared pool (the caller would only wait for them:
    one thread hand-off fewer per call)."""
    global _POOL
    if len(calls) > 1:
        if _POOL is None or _POOL._max_workers < len(calls) - 1:
            from concurrent.futures import ThreadPoolExecutor

            _POOL = ThreadPoolExecutor(max_workers=len(calls) - 1, thread_name_prefix="catgraph-differences")
        jobs = [_POOL.submit(kernel, *args) for kernel, args in calls[1:]]
    try:
        calls[0][0](*calls[0][1])
    finally:
        for job in jobs if len(calls) > 1 else ():
            job.result()


#: float64 values per thread below which the normalisation passes run on one thread.
NORMALISE_PER_THREAD = 1 << 19


def _split(m: int, n: int, chunk: int) -> list[tuple[int, int, int, int]]:
    """Disjoint pieces ``(row_lo, row_hi, col_lo, col_hi)`` of an ``(m, n)`` array for
    the normalisation passes: whole rows when there are several, else runs of whole
    ``chunk``-value chunks of the one row (every piece stays C-contiguous, and each
    chunk's partial sum is the same whichever piece computes it)."""
    threads = int(max(1, min(_threads_available(), (m * n) // NORMALISE_PER_THREAD)))
    if threads == 1:
        return [(0, m, 0, n)]
    if m > 1:
        threads = min(threads, m)
        return [(m * t // threads, m * (t + 1) // threads, 0, n) for t in range(threads)]
    chunks = -(-n // chunk)
    threads = min(threads, chunks)
    edges = [min(n, (chunks * t // threads) * chunk) for t in range(threads + 1)]
    return [(0, 1, lo, hi) for lo, hi in zip(edges[:-1], edges[1:])]


def _check_finite(x: np.ndarray, name: str, rows: int = 8192, first_row: int = 0) -> None:
    """Finiteness of a float array, checked in row chunks (bounded scratch memory);
    ``first_row``: the row number of ``x[0]`` in the message."""
    if x.dtype.kind != "f":
        return
    for start in range(0, max(x.shape[0], 1), rows):
        part = x[start : start + rows]
        bad = ~np.isfinite(part)
        if bad.any():
            where = np.argwhere(bad)[0]
            value = part[tuple(where)]
            raise DataError(
                f"{name}: {int(bad.sum())}{'+' if x.shape[0] > rows else ''} NaN or infinite values "
                f"(first {value} at row {first_row + start + int(where[0])}); clean or drop those frames before "
                "localising."
            )


class RowSource:
    """Descriptors held outside memory, read a row slice at a time: ``source[a:b]`` is an
    ndarray of rows ``a … b − 1``, ``numpy.asarray(source)`` reads them whole. The compact
    layout (:class:`PreparedReference` with ``layout="uint8"``) codes such a source in row
    chunks and never holds its values whole (:class:`catgraph.io.StoredDescriptors`, a
    map file's descriptors). Whoever makes one has checked its values finite."""

    ndim = 2
    shape: tuple[int, int]
    dtype: np.dtype

    #: Rows :meth:`take` reads at most at once.
    TAKE_ROWS = 2048

    def __len__(self) -> int:
        return int(self.shape[0])

    def take(self, rows) -> np.ndarray:
        """Rows ``rows`` (integers, any order, negative from the end) as an ndarray, read
        in ascending slices of at most :data:`TAKE_ROWS` rows, each ending at a row asked
        for: one pass over the rows, never all of them in memory (a sample of a map's
        frames, :func:`catgraph.hubs.map_hub_offsets`)."""
        rows = np.asarray(rows)
        n = self.shape[0]
        if rows.ndim != 1 or rows.dtype.kind not in "iu":
            raise IndexError(f"take needs a 1-D array of row numbers; got shape {rows.shape}, dtype {rows.dtype}.")
        if rows.size and (int(rows.min()) < -n or int(rows.max()) >= n):
            raise IndexError(f"row numbers must lie in [-{n}, {n}) for {n} rows; got {rows.min()} … {rows.max()}.")
        rows = np.where(rows < 0, rows + n, rows).astype(np.int64)
        order = np.argsort(rows, kind="stable")
        ascending = rows[order]
        out = np.empty((len(rows), self.shape[1]), dtype=self.dtype)
        k = 0
        while k < len(ascending):
            a = int(ascending[k])
            m = int(np.searchsorted(ascending, a + self.TAKE_ROWS, side="left"))
            block = self[a : int(ascending[m - 1]) + 1]
            out[order[k:m]] = block[ascending[k:m] - a]
            k = m
        return out

    def value_range(self) -> tuple[float, float, bool] | None:
        """``(smallest, largest, every value a whole number)`` where already known without
        reading the rows again (the compact layout's code scale, :func:`code_scale`), else
        ``None``."""
        return None


def take_rows(descriptors, rows: np.ndarray) -> np.ndarray:
    """Rows ``rows`` of descriptors in memory or of a :class:`RowSource` (read in one pass,
    :meth:`RowSource.take`), as an ndarray."""
    return descriptors.take(rows) if isinstance(descriptors, RowSource) else np.asarray(descriptors[rows])


def _as_descriptors(x, name: str, metric: str, single: bool = False, convert: bool = True) -> np.ndarray:
    """``(n, d)`` float32 C-contiguous descriptors (bits as 0/1), validated.

    ``convert=False``: validated only, in the caller's dtype (bits still unpacked to
    ``uint8`` 0/1), for the compact layout, which converts in row chunks; a
    :class:`RowSource` of numbers no wider than float32 is returned as it is (its rows
    are read there, a chunk at a time)."""
    if (isinstance(x, RowSource) and not convert and not single and metric != "hamming"
            and x.dtype.kind in "iuf" and x.dtype.itemsize <= 4 and x.shape[0] and x.shape[1]):
        return x
    try:
        arr = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} could not be read as a numeric array: {exc}") from None
    if arr.dtype == object or arr.dtype.kind not in "biuf":
        raise DataError(f"{name} must be a numeric or boolean array; got dtype {arr.dtype}.")
    if single:
        if arr.ndim != 1:
            raise DataError(
                f"{name} must be one descriptor of shape (d,); got shape {arr.shape}. Compare several frames with "
                "difference_matrix, and turn a raw image or scan into a descriptor with its front-end first "
                "(catgraph.live.describe_frame)."
            )
        arr = arr[None, :]
    elif arr.ndim == 1:
        arr = arr[None, :]
    elif arr.ndim == 0:
        raise DataError(f"{name} must have shape (n, d); got a single number.")
    if arr.size == 0:
        raise DataError(f"{name} is empty (shape {arr.shape}); at least one frame with at least one value is needed.")
    if arr.ndim > 2:
        arr = arr.reshape(arr.shape[0], -1)  # (n, h, w) frames: flattened per frame
    if metric == "hamming":
        bits_dtype = np.float32 if convert else np.uint8
        if arr.dtype == bool:
            return np.ascontiguousarray(arr, dtype=bits_dtype)
        if arr.dtype == np.uint8:
            return np.ascontiguousarray(np.unpackbits(arr, axis=1), dtype=bits_dtype)
        raise DataError(f"the hamming metric needs boolean or packed uint8 {name}; got dtype {arr.dtype}.")
    if arr.dtype.kind == "f":
        _check_finite(arr, name)
    if not convert:
        if arr.dtype.kind == "f":
            with np.errstate(over="ignore"):
                big = max(abs(float(np.min(arr))), abs(float(np.max(arr))))
            if big > float(np.finfo(np.float32).max):
                raise DataError(f"{name} hold values too large for float32 (|x| > 3.4e38); rescale them.")
        return arr
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=np.float32)
    if arr.dtype.kind == "f" and arr.dtype != np.float32:
        try:
            _check_finite(out, name)
        except DataError:
            raise DataError(f"{name} hold values too large for float32 (|x| > 3.4e38); rescale them.") from None
    _check_sums_fit(out, name, metric)
    return out


def _check_sums_fit(x: np.ndarray, name: str, metric: str, rows: int = 8192) -> None:
    """The kernels sum a descriptor's ``d`` terms in float32: ``|x|`` (SAD) or ``x²`` (SSD,
    cosine's products and norms). Refuse values whose sum could overflow (an infinite sum
    would turn every difference to NaN): ``d · 2|x|_max`` resp. ``d · |x|_max²`` must stay
    below float32's largest value."""
    d = x.shape[1]
    big = 0.0
    for start in range(0, x.shape[0], rows):
        part = x[start : start + rows]
        big = max(big, abs(float(part.max())), abs(float(part.min())))
    largest = float(np.finfo(np.float32).max)
    if metric in ("ssd", "cosine"):
        fits = big * big * d < largest
        what = f"their squares summed over {d} values"
    else:
        fits = 2.0 * big * d < largest
        what = f"their differences summed over {d} values"
    if not fits:
        raise DataError(f"{name} hold values up to {big:.3g}: {what} overflow float32 (3.4e38) under the "
                        f"{metric} metric; rescale them (e.g. divide by their largest value).")


class PreparedReference:
    """Reference descriptors validated once and laid out for the difference kernels.

    Parameters
    ----------
    descriptors : array_like, shape (N, d)
        Reference descriptors (float, or bool / packed uint8 for ``hamming``).
    metric : {"sad", "ssd", "cosine", "hamming"}
    layout : {"float32", "uint8"}
        ``"uint8"``: one byte per value (see "Compact layout" in the module docstring).
    code_scale : (offset, step), optional
        ``"uint8"`` only: the codes' offset and step instead of the descriptors' own
        range (:func:`code_scale` of the whole map, for shards of one map).

    Attributes
    ----------
    descriptors : ndarray of float32 or uint8, shape (N, d_bits or d)
        C-contiguous kernel layout (Hamming bits unpacked to 0/1; codes for ``"uint8"``).
    offset, step : float
        ``"uint8"``: a code ``c`` stands for ``offset + step · c``.
    norms : ndarray of float64, shape (N,) or None
        ``|r_j|`` (cosine only).
    n_places, dim : int

    Examples
    --------
    >>> import numpy as np
    >>> ref = PreparedReference(np.eye(3), "sad")
    >>> ref.row(np.array([1.0, 0.0, 0.0])).tolist()
    [0.0, 2.0, 2.0]
    """

    def __init__(self, descriptors, metric: str = "sad", layout: str = "float32",
                 code_scale: tuple[float, float] | None = None) -> None:
        if metric not in METRICS:
            raise InvalidParameterError(
                f"Unknown difference metric {metric!r}; choose one of {', '.join(METRICS)}."
            )
        if layout not in LAYOUTS:
            raise InvalidParameterError(
                f"The 'layout' parameter of PreparedReference must be one of {LAYOUTS}. Got {layout!r} instead."
            )
        if layout == "uint8" and metric == "cosine":
            raise InvalidParameterError(
                "the uint8 layout serves the sad, ssd and hamming metrics; cosine needs layout='float32' (its norms "
                "do not survive an offset code)."
            )
        self.metric = metric
        self.layout = layout
        self.norms = None
        self.offset, self.step = 0.0, None
        if layout == "float32":
            self.descriptors = _as_descriptors(descriptors, "reference descriptors", metric)
            if metric == "cosine":
                self.norms = self._self_norms(self.descriptors)
            return
        raw = _as_descriptors(descriptors, "reference descriptors", metric, convert=False)
        if code_scale is None:
            self.offset, self.step = _code_scale(raw, metric)
        else:
            offset, step = (float(v) for v in code_scale)
            if not (np.isfinite(offset) and np.isfinite(step) and step > 0):
                raise InvalidParameterError(f"code_scale must be (offset, step) with finite values and step > 0; "
                                            f"got {code_scale!r}.")
            self.offset, self.step = offset, step
        self.descriptors = np.empty(raw.shape, dtype=np.uint8)
        for start in range(0, raw.shape[0], _CODE_ROWS):
            _encode(raw[start : start + _CODE_ROWS], self.offset, self.step, self.descriptors[start : start + _CODE_ROWS])

    @staticmethod
    def _self_norms(x: np.ndarray) -> np.ndarray:
        # |r|² with the product kernel's arithmetic
        out = np.empty(x.shape[0])
        _kernels().self_products(x, out)
        return np.sqrt(out)

    @property
    def n_places(self) -> int:
        """Number of reference places ``N``."""
        return int(self.descriptors.shape[0])

    @property
    def dim(self) -> int:
        """Values per descriptor (after unpacking bits)."""
        return int(self.descriptors.shape[1])

    @property
    def nbytes(self) -> int:
        """Memory held (descriptors and norms)."""
        return int(self.descriptors.nbytes + (0 if self.norms is None else self.norms.nbytes))

    def prepare_query(self, descriptors, single: bool = False) -> np.ndarray:
        """Query descriptors validated and laid out like the reference, ``(m, d)``
        (float32, or ``uint8`` codes with the reference's ``offset`` and ``step``)."""
        name = "query descriptor" if single else "query descriptors"
        q = _as_descriptors(descriptors, name, self.metric, single, convert=self.layout == "float32")
        if q.shape[1] != self.dim:
            raise ShapeMismatchError(
                f"query descriptors have {q.shape[1]} values per frame but reference descriptors have {self.dim}; "
                "use the same front-end (and image size) for both traverses."
            )
        if self.layout == "uint8":
            codes = np.empty(q.shape, dtype=np.uint8)
            _encode(q, self.offset, self.step, codes)
            return codes
        return q

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """The values that ``uint8`` codes stand for, ``offset + step · codes`` (float64)."""
        if self.layout != "uint8":
            raise InvalidParameterError("decode applies to the uint8 layout; this reference is float32.")
        return self.offset + self.step * np.asarray(codes, dtype=np.float64)

    def quantisation_bound(self, descriptor) -> float:
        """Largest possible ``|D_uint8 − D|`` of one query descriptor's raw SAD row.

        ``D`` is the SAD of the original values (exact arithmetic), ``D_uint8`` what this
        reference computes: ``Σ_k (step + δ_k)``, ``δ_k`` the distance of query value
        ``k`` outside the reference's range (see the module docstring). 0 for the
        float32 layout's quantisation (it has none) and for Hamming.
        """
        if self.layout == "float32" or self.metric == "hamming":
            return 0.0
        if self.metric != "sad":
            raise InvalidParameterError("quantisation_bound is stated for SAD rows; the SSD bound depends on "
                                        "each pair (see the module docstring).")
        q = _as_descriptors(descriptor, "query descriptor", self.metric, True, convert=False).astype(np.float64)
        hi = self.offset + 255 * self.step
        outside = np.maximum(self.offset - q, 0.0) + np.maximum(q - hi, 0.0)
        return float(q.shape[1] * self.step + outside.sum())

    def _raw(self, q: np.ndarray, out: np.ndarray) -> np.ndarray:
        k = _kernels()
        if self.layout == "uint8":
            code = k.SSD if self.metric == "ssd" else k.SAD
            _pair_block(q, self.descriptors, code, out, self.step ** 2 if self.metric == "ssd" else self.step)
        elif self.metric in ("sad", "hamming"):
            _pair_block(q, self.descriptors, k.SAD, out)
        elif self.metric == "ssd":
            _pair_block(q, self.descriptors, k.SSD, out)
        else:
            _pair_block(q, self.descriptors, k.DOT, out)
            qn = self._self_norms(q)
            for i in range(q.shape[0]):  # 1 − dot / (|q| |r|), 1 where a norm is 0
                row = out[i]
                denom = qn[i] * self.norms
                np.divide(row, denom, out=row, where=denom > 0)
                row[denom <= 0] = 0.0
                np.subtract(1.0, row, out=row)
                np.clip(row, 0.0, 2.0, out=row)
        return out

    def block(self, descriptors, normalise: bool = False, out: np.ndarray | None = None) -> np.ndarray:
        """Differences of query descriptors ``(m, d)`` to every place, ``(m, N)`` float64.

        Parameters
        ----------
        descriptors : array_like, shape (m, d)
        normalise : bool
            Apply the per-query normalisation (:func:`normalise_rows`).
        out : ndarray of float64, shape (m, N), optional
            Written in place (no allocation per call).
        """
        q = self.prepare_query(descriptors)
        if out is None:
            out = np.empty((q.shape[0], self.n_places))
        elif out.shape != (q.shape[0], self.n_places) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ShapeMismatchError(f"out must be a C-contiguous float64 array of shape {(q.shape[0], self.n_places)}.")
        return self._fill(q, normalise, out)

    def _fill(self, q: np.ndarray, normalise: bool, out: np.ndarray) -> np.ndarray:
        """Kernel call on prepared query rows (no checks)."""
        self._raw(q, out)
        if normalise:
            _normalise_into(out, out)
        return out

    def row(self, descriptor, normalise: bool = False, out: np.ndarray | None = None) -> np.ndarray:
        """One query descriptor ``(d,)`` against every place → ``(N,)`` float64.

        Equal, bit for bit, to the same row of :meth:`block` / :func:`difference_matrix`.
        """
        q = self.prepare_query(descriptor, single=True)
        if out is None:
            out = np.empty(self.n_places)
        elif out.shape != (self.n_places,) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ShapeMismatchError(f"out must be a C-contiguous float64 array of shape ({self.n_places},).")
        view = out.reshape(1, -1)
        self._raw(q, view)
        if normalise:
            _normalise_into(view, view)
        return out

    def _places(self, lo: int, hi: int) -> "PreparedReference":
        """Places ``lo:hi`` of this reference (views, no copy)."""
        part = object.__new__(PreparedReference)
        part.__dict__.update(self.__dict__)
        part.descriptors = self.descriptors[lo:hi]
        if self.norms is not None:
            part.norms = self.norms[lo:hi]
        return part

    def __repr__(self) -> str:
        return (f"PreparedReference(n_places={self.n_places}, dim={self.dim}, metric={self.metric!r}, "
                f"layout={self.layout!r})")


#: Rows encoded at once by the compact layout (bounds the float scratch memory: about
#: 8 MiB of float64 per 512-value chunk, beside the map being coded).
_CODE_ROWS = 2048


def code_scale(descriptors, metric: str = "sad") -> tuple[float, float]:
    """``(offset, step)`` of the ``uint8`` codes :class:`PreparedReference` gives these
    reference descriptors (read in row chunks: a memory-mapped map is never copied whole).
    Shards of one map pass the whole map's scale (``code_scale=``) so their codes are
    those of the whole map."""
    if metric not in METRICS or metric == "cosine":
        raise InvalidParameterError(f"the uint8 layout serves the sad, ssd and hamming metrics; got {metric!r}.")
    return _code_scale(_as_descriptors(descriptors, "reference descriptors", metric, convert=False), metric)


def _code_scale(x: np.ndarray, metric: str) -> tuple[float, float]:
    """``(offset, step)`` of the uint8 codes for reference values ``x``."""
    if metric == "hamming":
        return 0.0, 1.0
    known = x.value_range() if isinstance(x, RowSource) else None
    lo, hi, integral = known if known is not None else _value_range(x[start : start + _CODE_ROWS]
                                                                    for start in range(0, x.shape[0], _CODE_ROWS))
    if integral and hi - lo <= 255:
        return lo, 1.0
    return lo, (hi - lo) / 255.0 if hi > lo else 1.0


def _value_range(parts, known: tuple[float, float, bool] | None = None) -> tuple[float, float, bool]:
    """``(smallest, largest, every value a whole number)`` over the arrays ``parts``
    (extending ``known``, the range of earlier parts)."""
    lo, hi, integral = known if known is not None else (None, None, True)
    for part in parts:
        p_lo, p_hi = float(part.min()), float(part.max())
        lo = p_lo if lo is None else min(lo, p_lo)
        hi = p_hi if hi is None else max(hi, p_hi)
        if integral and part.dtype.kind == "f":
            integral = bool(np.all(part == np.round(part)))
    return lo, hi, integral


def _encode(x: np.ndarray, offset: float, step: float, out: np.ndarray) -> None:
    """``out = clip(round((x − offset) / step), 0, 255)`` as uint8 (in row chunks)."""
    for start in range(0, x.shape[0], _CODE_ROWS):
        part = np.asarray(x[start : start + _CODE_ROWS], dtype=np.float64)
        codes = np.rint((part - offset) / step)
        np.clip(codes, 0, 255, out=codes)
        out[start : start + _CODE_ROWS] = codes


def _prepared(reference, metric: str) -> PreparedReference:
    if isinstance(reference, PreparedReference):
        if reference.metric != metric:
            raise InvalidParameterError(
                f"the prepared reference uses metric {reference.metric!r}, not {metric!r}; prepare it again with "
                f"PreparedReference(descriptors, {metric!r})."
            )
        return reference
    if metric not in METRICS:
        raise InvalidParameterError(f"Unknown difference metric {metric!r}; choose one of {', '.join(METRICS)}.")
    return PreparedReference(reference, metric)


def _auto_rows(n_places: int) -> int:
    return max(1, _BLOCK_VALUES // max(n_places, 1))


def iter_difference_blocks(
    query: np.ndarray, reference, metric: str = "sad", block_rows: int | None = 256, normalise: bool = False
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(start, block)`` with ``block = D[start:start + block_rows]`` (float64).

    Only one block of ``block_rows × n_reference`` values is held at a time
    (``block_rows=None``: about 32 MiB per block). ``reference`` may be a
    :class:`PreparedReference`.
    """
    ref = _prepared(reference, metric)
    if block_rows is None:
        block_rows = _auto_rows(ref.n_places)
    check_scalar(block_rows, "block_rows", "iter_difference_blocks", int, 1)
    q = ref.prepare_query(query)
    for start in range(0, q.shape[0], block_rows):
        part = q[start : start + block_rows]
        yield start, ref._fill(part, normalise, np.empty((part.shape[0], ref.n_places)))


class DifferenceRows:
    """The ``(n_query, N)`` difference rows of a query, block by block, without the matrix.

    What a consumer that walks the query in order needs (the filters' ``run``, single-frame
    matching): its shape, and ``(start, block)`` pairs, ``block`` the float64 rows
    ``start .. start + len(block) − 1`` in processing order, one block held at a time. The
    rows are computed on each pass by ``blocks_of(block_rows)`` (a callable returning such an
    iterator), so a second pass computes them again; :meth:`matrix` stacks one pass.

    Parameters
    ----------
    n_rows, n_places : int
        The shape of the rows.
    blocks_of : callable
        ``blocks_of(block_rows)`` → iterator of ``(start, block)`` covering every row in
        order (``block_rows=None``: about 32 MiB a block).

    Examples
    --------
    >>> import numpy as np
    >>> d = np.arange(12.0).reshape(4, 3)
    >>> rows = DifferenceRows.of(d)
    >>> len(rows), rows.n_places, [s for s, _ in rows.blocks(3)]
    (4, 3, [0, 3])
    """

    def __init__(self, n_rows: int, n_places: int, blocks_of) -> None:
        self.n_rows, self.n_places, self._blocks_of = int(n_rows), int(n_places), blocks_of

    @classmethod
    def of(cls, matrix: np.ndarray) -> "DifferenceRows":
        """The rows of a matrix already in memory (blocks are views of it)."""
        d = np.asarray(matrix)
        if d.ndim != 2:
            raise DataError(f"the difference matrix must have 2 dimensions; got shape {d.shape}.")

        def blocks_of(block_rows):
            step = _auto_rows(d.shape[1]) if block_rows is None else int(block_rows)
            for start in range(0, d.shape[0], step):
                yield start, d[start:start + step]

        return cls(d.shape[0], d.shape[1], blocks_of)

    def __len__(self) -> int:
        return self.n_rows

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_rows, self.n_places

    def blocks(self, block_rows: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """``(start, block)`` for every block of rows, in order (one pass)."""
        if block_rows is not None:
            check_scalar(block_rows, "block_rows", "DifferenceRows.blocks", int, 1)
        return self._blocks_of(block_rows)

    def checked(self, block_rows: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """:meth:`blocks`, each block checked as it comes (2-D, float64, finite: the errors of
        :func:`~catgraph._validation.check_array`, naming its frames), and the blocks
        checked to follow each other over every row and place they announced
        (:class:`~catgraph.exceptions.ShapeMismatchError` where they do not)."""
        given = 0
        for start, block in self.blocks(block_rows):
            block = check_array(block, f"the difference rows of frames {start}–{start + len(block) - 1}", ndim=2)
            if start != given or block.shape[1] != self.n_places:
                raise ShapeMismatchError(f"the difference rows came as a block of shape {block.shape} from frame "
                                         f"{start}, after {given} rows of {self.n_places} places: blocks must follow "
                                         "each other, every row of every place.")
            given += len(block)
            yield start, block
        if given != self.n_rows:
            raise ShapeMismatchError(f"the difference rows held {given} rows, not the {self.n_rows} they announced.")

    def matrix(self) -> np.ndarray:
        """Every row in one ``(n_query, N)`` float64 matrix (the memory the blocks avoid)."""
        out = np.empty(self.shape)
        for start, block in self.blocks():
            out[start:start + len(block)] = block
        return out

    def __repr__(self) -> str:
        return f"DifferenceRows(n_rows={self.n_rows}, n_places={self.n_places})"


def iter_difference_columns(
    query: np.ndarray, reference, metric: str = "sad", block_places: int | None = None, normalise: bool = False
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(start, block)`` with ``block = D[:, start:start + block_places]`` (float64).

    For many query rows against a large map when the caller reduces over the *query*
    axis (a median per place, say): only ``n_query × block_places`` values are held at
    once, never ``n_query × N``. The blocks equal the columns of
    :func:`difference_matrix`, bit for bit, normalised ones included: the per-row mean
    and spread are gathered first from the fixed-chunk partial sums the normalisation
    adds (``block_places`` is a multiple of the chunk, so they are the same sums), at
    the price of computing the raw differences three times (sums, squared deviations,
    the blocks) instead of once.

    Parameters
    ----------
    query : ndarray, shape (n_query, d)
    reference : ndarray, shape (N, d), or PreparedReference
    metric : str
    block_places : int, optional
        Places per block, rounded up to a multiple of 4096 (default: about 32 MiB per
        block).
    normalise : bool
    """
    ref = _prepared(reference, metric)
    return _iter_columns(ref, ref.prepare_query(query), block_places, normalise, "iter_difference_columns")


def iter_reference_columns(
    reference: "PreparedReference", places, block_places: int | None = None, normalise: bool = False
) -> Iterator[tuple[int, np.ndarray]]:
    """:func:`iter_difference_columns` of the map against itself: the prepared
    reference's own rows ``places`` are the queries (as held: float32 values or
    ``uint8`` codes, never coded twice).

    The statistics a live map keeps of itself (hub levels, bootstrap samples) come from
    here, so they describe the differences its rows are matched with; with the float32
    layout the blocks equal those of :func:`iter_difference_columns` on the original
    descriptors bit for bit.

    Parameters
    ----------
    reference : PreparedReference
    places : array_like of int
        Indices of the places whose rows are wanted.
    block_places : int, optional
        As in :func:`iter_difference_columns`.
    normalise : bool
    """
    if not isinstance(reference, PreparedReference):
        raise InvalidParameterError(f"iter_reference_columns needs a PreparedReference; got {type(reference).__name__}.")
    idx = np.asarray(places)
    if idx.ndim != 1 or idx.size == 0 or idx.dtype.kind not in "iu":
        raise InvalidParameterError("places must be a non-empty 1-D array of place indices.")
    if idx.min() < 0 or idx.max() >= reference.n_places:
        raise InvalidParameterError(f"places must lie in 0 … {reference.n_places - 1}; got {idx.min()} … {idx.max()}.")
    return _iter_columns(reference, reference.descriptors[idx], block_places, normalise, "iter_reference_columns")


def _iter_columns(ref: "PreparedReference", q: np.ndarray, block_places: int | None, normalise: bool,
                  caller: str) -> Iterator[tuple[int, np.ndarray]]:
    """Column blocks of prepared query rows ``q`` against ``ref`` (see
    :func:`iter_difference_columns`)."""
    block_places = _column_block(q.shape[0], block_places, caller)
    if normalise and ref.n_places <= block_places:  # one block: its rows normalised as a whole (the same floats)
        block = _raw_columns(ref, q, 0, block_places)
        yield 0, _normalise_into(block, block)
        return
    mean = std = None
    if normalise:  # the row sums of normalise_rows, chunk by chunk, block by block
        mean = _combine(_column_chunk_sums(ref, q, block_places, None)) / ref.n_places
        std = np.sqrt(_combine(_column_chunk_sums(ref, q, block_places, mean)) / ref.n_places)
        std[_zero_spread(std, mean)] = 0.0
    yield from _scaled_columns(ref, q, block_places, mean, std)


def _column_block(m: int, block_places: int | None, caller: str) -> int:
    """Places per column block of ``m`` query rows (default about 32 MiB of float64), a
    whole number of normalisation chunks."""
    k = _kernels()
    if block_places is None:
        block_places = max(1, _BLOCK_VALUES // max(m, 1))
    check_scalar(block_places, "block_places", caller, int, 1)
    return -(-int(block_places) // k.SUM_CHUNK) * k.SUM_CHUNK


def _raw_columns(ref: "PreparedReference", q: np.ndarray, lo: int, block_places: int) -> np.ndarray:
    """The raw differences of prepared rows ``q`` against places ``lo:lo + block_places``."""
    part = ref._places(lo, lo + block_places)
    return part._raw(q, np.empty((q.shape[0], part.n_places)))


def _column_chunk_sums(ref: "PreparedReference", q: np.ndarray, block_places: int,
                       centre: np.ndarray | None) -> np.ndarray:
    """``(m, ⌈N / SUM_CHUNK⌉)``: the per-chunk partial sums :func:`normalise_rows` adds for
    rows ``q`` against ``ref`` (``centre`` ``None``: of the values; else of the squared
    deviations from it), a column block at a time (``block_places`` a multiple of the
    chunk, so each chunk's sum is the one of the whole row)."""
    k = _kernels()
    m = q.shape[0]
    parts = np.empty((m, -(-ref.n_places // k.SUM_CHUNK)))
    power, centre = (1, np.zeros(m)) if centre is None else (2, centre)
    for lo in range(0, ref.n_places, block_places):
        block = _raw_columns(ref, q, lo, block_places)
        first = lo // k.SUM_CHUNK
        k.chunk_sums(block, centre, power, parts[:, first : first + -(-block.shape[1] // k.SUM_CHUNK)])
    return parts


def _scaled_columns(ref: "PreparedReference", q: np.ndarray, block_places: int, mean: np.ndarray | None,
                    std: np.ndarray | None) -> Iterator[tuple[int, np.ndarray]]:
    """``(lo, block)`` of rows ``q`` against ``ref``, each block scaled by the rows' whole
    ``mean`` and ``std`` (``None``: raw)."""
    for lo in range(0, ref.n_places, block_places):
        block = _raw_columns(ref, q, lo, block_places)
        if mean is not None:
            _kernels().scale_rows(block, mean, std, block)
        yield lo, block


def difference_matrix(
    query: np.ndarray, reference, metric: str = "sad", block_rows: int | None = 256, normalise: bool = False
) -> np.ndarray:
    """Differences between every query and every reference descriptor.

    Parameters
    ----------
    query : ndarray, shape (n_query, d)
        (``(n, h, w)`` frames are flattened per frame.)
    reference : ndarray, shape (n_reference, d), or PreparedReference
    metric : {"sad", "ssd", "cosine", "hamming"}
    block_rows : int or None
        Query rows computed at once (bounds the working memory; ``None``: ~32 MiB).
    normalise : bool
        Apply :func:`normalise_rows` to each block as it is computed.

    Returns
    -------
    ndarray, shape (n_query, n_reference), float64
    """
    ref = _prepared(reference, metric)
    if block_rows is None:
        block_rows = _auto_rows(ref.n_places)
    check_scalar(block_rows, "block_rows", "difference_matrix", int, 1)
    q = ref.prepare_query(query)
    out = np.empty((q.shape[0], ref.n_places), dtype=np.float64)
    for start in range(0, q.shape[0], block_rows):
        ref._fill(q[start : start + block_rows], normalise, out[start : start + block_rows])
    return out


def difference_row(descriptor: np.ndarray, reference, metric: str = "sad", normalise: bool = False) -> np.ndarray:
    """One query descriptor ``(d,)`` against every reference descriptor → ``(n_reference,)``.

    ``reference`` may be a :class:`PreparedReference` — do that when calling once per
    frame: raw descriptors are validated (and, for cosine, their norms computed) on
    every call. Anything but a 1-D descriptor is refused (``DataError``).
    """
    return _prepared(reference, metric).row(descriptor, normalise=normalise)


# ---------------------------------------------------------------------------------------
# per-query normalisation


def _zero_spread(std: np.ndarray, mean: np.ndarray) -> np.ndarray:
    return ~(std > 1e-12 * np.maximum(1.0, np.abs(mean)))


def _combine(partials: np.ndarray) -> np.ndarray:
    """Row totals from per-chunk partial sums ``(m, n_chunks)``, added in chunk order."""
    total = np.zeros(partials.shape[0])
    for c in range(partials.shape[1]):
        total += partials[:, c]
    return total


def row_statistics(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(mean, std)`` per row of a C-contiguous float64 ``(m, N)`` array, as
    :func:`normalise_rows` computes them (``std = 0`` for rows with zero spread)."""
    k = _kernels()
    m, n = d.shape
    n_chunks = -(-n // k.SUM_CHUNK)
    parts = np.empty((m, n_chunks))
    pieces = _split(m, n, k.SUM_CHUNK)

    def sums(centre: np.ndarray, power: int) -> np.ndarray:
        _run_parallel([(k.chunk_sums, (d[a:b, lo:hi], centre[a:b], power,
                                       parts[a:b, lo // k.SUM_CHUNK : -(-hi // k.SUM_CHUNK)]))
                       for a, b, lo, hi in pieces])
        return _combine(parts)

    mean = sums(np.zeros(m), 1) / n
    std = np.sqrt(sums(mean, 2) / n)
    std[_zero_spread(std, mean)] = 0.0
    return mean, std


def _normalise_row_range(d: np.ndarray, out: np.ndarray) -> None:
    """Each row of ``d`` normalised into ``out`` by one call of the row kernel (which
    releases the GIL: row ranges run on threads)."""
    row = _kernels().normalise_row
    for i in range(d.shape[0]):
        row(d[i], out[i])


def _normalise_into(d: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Normalise the rows of ``d`` into ``out`` (may be ``d``). Each row's passes run in
    one compiled call (:func:`catgraph._diff_kernels.normalise_row`: the same chunk sums
    in the same order, the same division, so the same floats), row ranges on threads
    where the work is worth several; only one row too long for one thread takes the
    chunk-sum and scale passes, split into runs of chunks. The live step calls the same
    row kernel: a process that matches live rows and batch blocks compiles one kernel
    for the normalisation instead of three."""
    if d.shape[0] == 0:
        return out
    k = _kernels()
    pieces = _split(*d.shape, k.SUM_CHUNK)
    if len(pieces) == 1:
        _normalise_row_range(d, out)
        return out
    if pieces[0][3] == d.shape[1]:  # whole rows per thread: the row kernel on each (a batch compiles one kernel)
        _run_parallel([(_normalise_row_range, (d[a:b], out[a:b])) for a, b, _, _ in pieces])
        return out
    mean, std = row_statistics(d)
    _run_parallel([(k.scale_rows, (d[a:b, lo:hi], mean[a:b], std[a:b], out[a:b, lo:hi]))
                   for a, b, lo, hi in _split(*d.shape, k.SUM_CHUNK)])
    return out


def normalise_rows(differences: np.ndarray) -> np.ndarray:
    """Per-query normalisation ``(d_ij − μ_i) / σ_i`` over the reference axis.

    Parameters
    ----------
    differences : array_like, shape (N,) or (n_query, N)

    Returns
    -------
    ndarray of float64, same shape
        Rows with zero spread become all zeros ("no evidence", see the module
        docstring); shape ``(0, N)`` gives an empty array.

    Raises
    ------
    DataError
        A value is NaN or infinite, not a real number (complex, text), there are no
        reference places (``N = 0``), or the input is not 1-D or 2-D.

    Examples
    --------
    >>> normalise_rows([1.0, 2.0, 3.0]).round(4).tolist()
    [-1.2247, 0.0, 1.2247]
    >>> normalise_rows([5.0, 5.0, 5.0]).tolist()
    [0.0, 0.0, 0.0]
    """
    try:
        raw = np.asarray(differences)
    except (TypeError, ValueError) as exc:
        raise DataError(f"differences could not be read as a numeric array: {exc}") from None
    if raw.dtype.kind not in "biuf":
        raise DataError(f"differences must be real numbers; got dtype {raw.dtype} (complex, text or objects). "
                        "Pass the difference values themselves, e.g. from difference_matrix.")
    d = raw.astype(np.float64, copy=False)
    if d.ndim not in (1, 2):
        raise DataError(f"differences must be one row (N,) or a matrix (n_query, N); got shape {d.shape}.")
    if d.shape[-1] == 0:
        raise DataError(f"differences have no reference places (shape {d.shape}); normalising needs at least one.")
    bad = ~np.isfinite(d)
    if bad.any():
        where = tuple(int(v) for v in np.argwhere(bad)[0])
        raise DataError(
            f"differences contain {int(bad.sum())} non-finite values (first {d[where]} at index "
            f"{where if d.ndim > 1 else where[0]}); a difference must be a finite number — check the descriptors."
        )
    two = np.ascontiguousarray(d.reshape(-1, d.shape[-1]))
    # a row beyond 1e100 is scaled to its largest |d| first (the normalisation does not change):
    # its squared deviations would overflow, the spread read infinite and the row become zeros
    big = np.abs(two).max(axis=1) > 1e100
    if big.any():
        two = two.copy()
        two[big] /= np.abs(two[big]).max(axis=1, keepdims=True)
    out = np.empty_like(two)
    _normalise_into(two, out)
    return out.reshape(d.shape)
