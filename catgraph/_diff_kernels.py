"""numba kernels for difference rows and matrices (imported lazily by :mod:`catgraph.differences`).

Two kernels serve every metric, the single streaming row and the batch matrix alike,
so a row computed for one live frame equals, bit for bit, the same row of a batch
matrix, of any block of it, and of any shard of the reference on another machine:

:func:`pair_block`
    ``out[i, j] = Σ_k f(q_ik, r_jk)`` for ``f`` = ``|q − r|`` (SAD, and Hamming on 0/1
    values), ``(q − r)²`` (SSD) or ``q · r`` (dot product, for cosine). Inputs are
    float32, terms and sums float32 (vectorised: the compiler keeps one partial sum per
    SIMD lane, which is also more accurate than one running sum), the result stored
    as float64. The loop over ``k`` is the same machine code for every pair, so the
    value of ``out[i, j]`` depends on ``q_i`` and ``r_j`` only — never on which other
    rows are in the block, how the reference is cut or how many threads run. (The
    compiler vectorises the sum as its model of the target CPU chooses: compiled for
    another CPU, the last bits can differ; ``NUMBA_CPU_NAME`` fixes the target,
    ``docs/evaluation.md``.) It releases the
    GIL and works on a range of places, so :mod:`catgraph.differences` runs it from a
    small thread pool on disjoint ranges — one query row (a live frame) uses every
    core — and within a range it walks blocks of :data:`PLACE_BLOCK` references
    (256 × 512 float32 = 512 KiB stay in cache while all query rows of a batch pass).
:func:`chunk_sums`, :func:`scale_rows`
    Per-row ``(d − μ) / σ`` with ``μ, σ`` over the row. Sums run over fixed chunks of
    :data:`SUM_CHUNK` values, whose partial sums are then added in chunk order, so a
    reference shard that is a multiple of ``SUM_CHUNK`` places can return its chunks'
    partial sums for the same result (:mod:`catgraph.distributed`). These passes are
    serial: they cost a few ms at a million places, less than waking the threads on
    a busy machine.
:func:`normalise_row`
    The same passes for one row in one call (the live step's row, and the rows of a
    batch block, row ranges on threads: no Python between the passes), the same floats;
    it releases the GIL.

One signature each (float32 descriptors or uint8 codes, float64 output, C-contiguous),
compiled on first use and cached on disk (:func:`catgraph._jit.njit`: a writable cache
folder even where the package folder is read-only). None uses numba's ``parallel=True``:
measured on this project's 2-core machine, compiling the parallel form of
:func:`pair_block` took 10.5 s with an empty cache and loading it from the cache 1.2 s
(the threading layer starts), against a fraction of a second for the serial form
threaded from Python.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit

#: Reference places per parallel task of :func:`pair_block`.
PLACE_BLOCK = 256
#: Values per partial sum in :func:`normalise_block` (and per shard unit of the
#: distributed normalisation).
SUM_CHUNK = 4096

SAD, SSD, DOT = 0, 1, 2


@njit(nogil=True, fastmath=True)
def pair_block(query, reference, lo, hi, code, out):  # pragma: no cover - compiled
    """``out[i, j] = Σ_k f(query[i, k], reference[j, k])`` for places ``lo <= j < hi``
    (see the module docstring).

    ``query (m, d)`` and ``reference (n, d)`` float32, ``out (m, n)`` float64, all
    C-contiguous; ``code``: 0 = absolute, 1 = squared difference, 2 = product. Releases
    the GIL: threads run it on disjoint place ranges at once.
    """
    m, d = query.shape
    for b in range(lo, hi, PLACE_BLOCK):
        stop = min(hi, b + PLACE_BLOCK)
        for i in range(m):
            q = query[i]
            for j in range(b, stop):
                r = reference[j]
                acc = np.float32(0.0)
                if code == SAD:
                    for k in range(d):
                        acc += abs(q[k] - r[k])
                elif code == SSD:
                    for k in range(d):
                        t = q[k] - r[k]
                        acc += t * t
                else:
                    for k in range(d):
                        acc += q[k] * r[k]
                out[i, j] = acc


#: Bytes per vector step of :func:`pair_block_codes` (one 512-bit register; the
#: compiler splits it into two or four narrower ones where the machine has no 512-bit
#: vectors).
CODE_LANES = 64


def _code_block_intrinsic(squared: bool, groups: int = 1):
    """A numba intrinsic ``f(a, ia, b, ib) → int64``: ``Σ_{t<64 groups} g(a[ia+t] − b[ib+t])``
    over ``64 · groups`` consecutive ``uint8`` values of two C-contiguous arrays (flat
    offsets), ``g`` = ``|·|`` or ``(·)²``.

    Written as plain vector IR — load 64 bytes, widen, subtract, absolute value (or
    square), add the lanes — which LLVM's instruction selection turns into the
    machine's sum-of-absolute-differences instruction (``vpsadbw`` on x86-64: 64
    byte pairs in one instruction) or its widening multiply-add (``vpmaddwd``), and
    into the equivalent vector code on other processors. The scalar loop this
    replaces was vectorised by widening every byte to 64 bits (four per 256-bit
    register), which made the row compute-bound at a sixth of the memory speed.
    Every sum is an exact integer (at most ``64 · 255² < 2³¹``).

    With ``groups > 1`` the ``groups`` vectors of terms are added lane by lane before the
    one reduction across the lanes (at most ``8 · 255² < 2³¹`` per lane for 8 groups),
    so a 512-value descriptor costs one horizontal sum instead of eight: the same
    integer, about a tenth less time per place (measured at ``N = 10^5``, one thread).
    """
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic

    lanes = CODE_LANES

    def declare(module, name, ret, args):
        if name in module.globals:
            return module.globals[name]
        return ir.Function(module, ir.FunctionType(ret, args), name=name)

    @intrinsic
    def block_sum(typingctx, a, ia, b, ib):
        for array in (a, b):  # raw pointer arithmetic: C-contiguous uint8 only
            if not (isinstance(array, types.Array) and array.layout == "C" and array.dtype == types.uint8):
                return None
        sig = types.int64(a, ia, b, ib)

        def codegen(context, builder, signature, args):
            i8v = ir.VectorType(ir.IntType(8), lanes)
            i32v = ir.VectorType(ir.IntType(32), lanes)
            data = [context.make_array(ty)(context, builder, array).data
                    for array, ty in ((args[0], signature.args[0]), (args[2], signature.args[2]))]
            total = None
            for group in range(groups):
                values = []
                for base, offset in ((data[0], args[1]), (data[1], args[3])):
                    at = builder.add(offset, ir.Constant(offset.type, group * lanes)) if group else offset
                    pointer = builder.bitcast(builder.gep(base, [at]), i8v.as_pointer())
                    values.append(builder.zext(builder.load(pointer, align=1), i32v))
                diff = builder.sub(values[0], values[1])
                if squared:
                    terms = builder.mul(diff, diff)
                else:
                    absolute = declare(builder.module, f"llvm.abs.v{lanes}i32", i32v, [i32v, ir.IntType(1)])
                    terms = builder.call(absolute, [diff, ir.Constant(ir.IntType(1), 0)])
                total = terms if total is None else builder.add(total, terms)
            reduce = declare(builder.module, f"llvm.vector.reduce.add.v{lanes}i32", ir.IntType(32), [i32v])
            return builder.zext(builder.call(reduce, [total]), ir.IntType(64))

        return sig, codegen

    return block_sum


_sad_lanes = _code_block_intrinsic(squared=False)
_ssd_lanes = _code_block_intrinsic(squared=True)
#: Vector steps summed lane by lane before one horizontal sum (:func:`_code_block_intrinsic`).
CODE_GROUPS = 8
_sad_groups = _code_block_intrinsic(squared=False, groups=CODE_GROUPS)
_ssd_groups = _code_block_intrinsic(squared=True, groups=CODE_GROUPS)


@njit(nogil=True)
def pair_block_codes(query, reference, lo, hi, code, step, out):  # pragma: no cover - compiled
    """:func:`pair_block` for the compact layout: ``uint8`` codes, integer sums.

    ``out[i, j] = step · Σ_k f(q_ik − r_jk)`` with ``f`` = ``|·|`` (``code`` 0) or
    ``(·)²`` (``code`` 1) on the integer code differences, summed exactly in 64-bit
    integers, then one float64 multiplication by ``step``. The values run in steps of
    ``CODE_GROUPS · CODE_LANES`` = 512 bytes (one horizontal sum each), then of
    :data:`CODE_LANES` bytes (:func:`_code_block_intrinsic`: one ``vpsadbw`` per 64
    byte pairs on x86-64), the last ``d mod 64`` in a scalar loop. Integer addition is
    associative, so the result is exact and the same on any machine, for any vector
    width or thread count. A quarter of the bytes of :func:`pair_block` per place,
    read at close to memory speed.
    """
    m, d = query.shape
    full = d - d % CODE_LANES
    wide = d - d % (CODE_LANES * CODE_GROUPS)
    for b in range(lo, hi, PLACE_BLOCK):
        stop = min(hi, b + PLACE_BLOCK)
        for i in range(m):
            qi = i * d
            for j in range(b, stop):
                rj = j * d
                acc = np.int64(0)
                if code == SAD:
                    for k in range(0, wide, CODE_LANES * CODE_GROUPS):
                        acc += _sad_groups(query, qi + k, reference, rj + k)
                    for k in range(wide, full, CODE_LANES):
                        acc += _sad_lanes(query, qi + k, reference, rj + k)
                    for k in range(full, d):
                        acc += abs(np.int64(query[i, k]) - np.int64(reference[j, k]))
                else:
                    for k in range(0, wide, CODE_LANES * CODE_GROUPS):
                        acc += _ssd_groups(query, qi + k, reference, rj + k)
                    for k in range(wide, full, CODE_LANES):
                        acc += _ssd_lanes(query, qi + k, reference, rj + k)
                    for k in range(full, d):
                        t = np.int64(query[i, k]) - np.int64(reference[j, k])
                        acc += t * t
                out[i, j] = step * acc


@njit(nogil=True, fastmath=True)
def self_products(x, out):  # pragma: no cover - compiled
    """``out[j] = Σ_k x[j, k]²`` (float32 sums, as the product of :func:`pair_block`)."""
    d = x.shape[1]
    for j in range(x.shape[0]):
        r = x[j]
        acc = np.float32(0.0)
        for k in range(d):
            acc += r[k] * r[k]
        out[j] = acc


#: Chunks summed side by side by :func:`_chunk_group` (independent running sums: the
#: processor overlaps their additions instead of waiting for each in turn).
CHUNK_GROUP = 4


@njit(inline="always")
def _chunk_group(row, lo, mu, power):  # pragma: no cover - compiled
    """The sums of :data:`CHUNK_GROUP` whole chunks of ``row`` from ``lo`` (``(row[j] − mu)``
    or its square), each left to right from 0 as :func:`chunk_sums` adds one chunk: the
    same floats, four chains in flight instead of one."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    a = row[lo:lo + SUM_CHUNK]
    b = row[lo + SUM_CHUNK:lo + 2 * SUM_CHUNK]
    c = row[lo + 2 * SUM_CHUNK:lo + 3 * SUM_CHUNK]
    d = row[lo + 3 * SUM_CHUNK:lo + 4 * SUM_CHUNK]
    if power == 1:
        for t in range(SUM_CHUNK):
            s0 += a[t] - mu
            s1 += b[t] - mu
            s2 += c[t] - mu
            s3 += d[t] - mu
    else:
        for t in range(SUM_CHUNK):
            v0 = a[t] - mu
            v1 = b[t] - mu
            v2 = c[t] - mu
            v3 = d[t] - mu
            s0 += v0 * v0
            s1 += v1 * v1
            s2 += v2 * v2
            s3 += v3 * v3
    return s0, s1, s2, s3


@njit(inline="always")
def _one_chunk(row, lo, hi, mu, power):  # pragma: no cover - compiled
    """One chunk's sum ``Σ_{lo ≤ j < hi} (row[j] − mu)**power``, left to right from 0."""
    s = 0.0
    if power == 1:
        for j in range(lo, hi):
            s += row[j] - mu
    else:
        for j in range(lo, hi):
            v = row[j] - mu
            s += v * v
    return s


@njit
def chunk_sums(d, centre, power, out):  # pragma: no cover - compiled
    """``out[i, c] = Σ_{j in chunk c} (d[i, j] − centre[i])**power`` (power 1 or 2),
    chunks of :data:`SUM_CHUNK` values, each summed left to right (whole chunks of a
    row :data:`CHUNK_GROUP` at a time, side by side: the same floats)."""
    m, n = d.shape
    n_chunks = out.shape[1]
    for i in range(m):
        row = d[i]
        mu = centre[i]
        c = 0
        while (c + CHUNK_GROUP) * SUM_CHUNK <= n and c + CHUNK_GROUP <= n_chunks:
            out[i, c], out[i, c + 1], out[i, c + 2], out[i, c + 3] = _chunk_group(row, c * SUM_CHUNK, mu, power)
            c += CHUNK_GROUP
        while c < n_chunks:
            out[i, c] = _one_chunk(row, c * SUM_CHUNK, min(n, c * SUM_CHUNK + SUM_CHUNK), mu, power)
            c += 1


@njit(inline="always")
def _row_total(d, mu, power):  # pragma: no cover - compiled
    """``Σ_c chunk_c`` of one row, the chunks' sums (:func:`chunk_sums`) added in chunk order."""
    n = d.shape[0]
    n_chunks = (n + SUM_CHUNK - 1) // SUM_CHUNK
    total = 0.0
    c = 0
    while (c + CHUNK_GROUP) * SUM_CHUNK <= n:
        s0, s1, s2, s3 = _chunk_group(d, c * SUM_CHUNK, mu, power)
        total += s0
        total += s1
        total += s2
        total += s3
        c += CHUNK_GROUP
    while c < n_chunks:
        total += _one_chunk(d, c * SUM_CHUNK, min(n, c * SUM_CHUNK + SUM_CHUNK), mu, power)
        c += 1
    return total


@njit
def scale_rows(d, mean, std, out):  # pragma: no cover - compiled
    """``out[i, j] = (d[i, j] − mean[i]) / std[i]``, or 0 where ``std[i] == 0``."""
    m, n = d.shape
    n_chunks = (n + SUM_CHUNK - 1) // SUM_CHUNK
    for t in range(m * n_chunks):
        i = t // n_chunks
        c = t - i * n_chunks
        lo = c * SUM_CHUNK
        hi = min(n, lo + SUM_CHUNK)
        mu = mean[i]
        sd = std[i]
        if sd > 0.0:
            for j in range(lo, hi):
                out[i, j] = (d[i, j] - mu) / sd
        else:
            for j in range(lo, hi):
                out[i, j] = 0.0


@njit(nogil=True)
def normalise_row(d, out):  # pragma: no cover - compiled
    """One row's ``(d − μ) / σ`` into ``out`` (may be ``d``) in one call: the arithmetic of
    :func:`chunk_sums` (both powers), the chunk totals added in chunk order, the zero
    spread test and :func:`scale_rows`, so the same floats as the three passes run one
    by one (:func:`catgraph.differences.normalise_rows`) without their calls per frame.
    Returns ``(mean, std)`` (``std = 0`` for a row with no spread: it becomes zeros)."""
    n = d.shape[0]
    mean = _row_total(d, 0.0, 1) / n
    std = np.sqrt(_row_total(d, mean, 2) / n)
    size = abs(mean)
    if not (std > 1e-12 * (size if size > 1.0 else 1.0)) or mean != mean:
        std = 0.0
    if std > 0.0:
        for j in range(n):
            out[j] = (d[j] - mean) / std
    else:
        for j in range(n):
            out[j] = 0.0
    return mean, std
