"""Front-ends: turn raw frames into descriptors.

SeqSLAM image pipeline (Milford & Wyeth 2012; paper 1 §IV)
    greyscale → optional crop → resize (e.g. 32×16) → *patch normalisation*: the image
    is cut into non-overlapping P×P patches (edge patches may be smaller) and each patch
    has its mean subtracted and is divided by its standard deviation. A flat patch
    (standard deviation 0 — tunnels, over-exposed sky) becomes all zeros, never NaN.
    Descriptors are flattened to ``(n, h*w) float32`` and compared with SAD.

Wi-Fi fingerprints
    UJI-format received signal strengths in dBm, with ``+100`` meaning "access point
    not detected". Coding "not seen" as +100 would make it the *strongest* signal, so
    :func:`wifi_vectors` maps each reading to its strength above a noise floor
    (``rss − floor_dbm``, clipped at 0) and "not seen" to 0 — the same as a reading at
    the floor. Absent and weak access points then differ little, strong ones a lot.

Frames with no information
    A descriptor whose values are all equal — a black or flat image (all zeros after
    patch normalisation), a Wi-Fi scan that detected no access point, a zero feature
    vector — cannot tell places apart. :func:`informative_frames` finds them and
    :func:`check_information` says so: a query frame with no information gets no match
    (its difference row is treated as ``σ = 0``, see :mod:`catgraph.matching`), a
    reference place with no information is reported because it can never be told
    from its neighbours, and a reference with no informative frame at all is refused.
"""

from __future__ import annotations

import numpy as np

from ._validation import check_array, check_memory, check_scalar
from .exceptions import DataError, InvalidParameterError, warn

__all__ = ["to_greyscale", "resize_images", "patch_normalise", "seqslam_preprocess", "wifi_vectors",
           "informative_frames", "check_information"]


def to_greyscale(images: np.ndarray) -> np.ndarray:
    """``(n, h, w)`` or ``(n, h, w, c)`` → ``(n, h, w) float32`` (ITU-R 601 luma for RGB)."""
    x = np.asarray(images)
    if x.ndim == 3:
        return x.astype(np.float32)
    if x.ndim == 4 and x.shape[-1] in (1, 2, 3, 4):
        if x.shape[-1] in (1, 2):  # grey or grey + alpha
            return x[..., 0].astype(np.float32)
        rgb = x[..., :3].astype(np.float32)
        return rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    raise DataError(f"images must have shape (n, h, w) or (n, h, w, channels); got {x.shape}.")


def resize_images(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize greyscale ``(n, h, w)`` images to ``size = (width, height)`` (area filter)."""
    from PIL import Image

    width, height = int(size[0]), int(size[1])
    if width < 1 or height < 1:
        raise DataError(f"resize size must be two positive ints (width, height); got {size}.")
    x = np.asarray(images, dtype=np.float32)
    check_memory(4.0 * x.shape[0] * width * height, f"resizing {x.shape[0]} images to {width}×{height}",
                 "choose a smaller size")
    if x.shape[1:] == (height, width):
        return x
    out = np.empty((x.shape[0], height, width), dtype=np.float32)
    for k, img in enumerate(x):
        out[k] = np.asarray(Image.fromarray(img, mode="F").resize((width, height), Image.Resampling.BOX))
    return out


#: Images normalised at once by :func:`patch_normalise` (its temporaries are this many images).
_PATCH_IMAGES = 1024


def patch_normalise(images: np.ndarray, patch: int = 4) -> np.ndarray:
    """Normalise each non-overlapping ``patch × patch`` block to zero mean, unit std.

    Parameters
    ----------
    images : ndarray, shape (n, h, w)
    patch : int
        Patch side in pixels. Edge patches are smaller where ``h`` or ``w`` is not a
        multiple of ``patch``.

    Returns
    -------
    ndarray, shape (n, h, w), float32
        Flat patches (std 0) are all zeros.
    """
    check_scalar(patch, "patch", "patch_normalise", int, 1)
    x = np.asarray(images, dtype=np.float64)
    if x.ndim != 3:
        raise DataError(f"patch_normalise expects greyscale images (n, h, w); got shape {x.shape}.")
    out = np.empty_like(x)
    _, h, w = x.shape
    if patch > max(h, w):
        raise DataError(
            f"the patch side {patch} is larger than the images ({w}×{h} pixels); choose a patch of at most "
            f"{max(h, w)} pixels (4 is the SeqSLAM default), or switch patch normalisation off with the front-end's "
            f"patch 0 (--patch 0)."
        )
    # the whole patches at once: a strided view (n, rows, cols, patch, patch) whose
    # reductions run over each patch's values in the same order as one patch's own
    hf, wf = h - h % patch, w - w % patch
    if hf and wf:
        s0, s1, s2 = x.strides
        blocks = np.lib.stride_tricks.as_strided(x, (x.shape[0], hf // patch, wf // patch, patch, patch),
                                                 (s0, patch * s1, patch * s2, s1, s2), writeable=False)
        target = np.lib.stride_tricks.as_strided(out, blocks.shape, (s0, patch * s1, patch * s2, s1, s2))
        for i in range(0, x.shape[0], _PATCH_IMAGES):  # bounded temporaries on a long traverse
            _normalise_blocks(blocks[i : i + _PATCH_IMAGES], (3, 4), target[i : i + _PATCH_IMAGES])
    for r in range(0, h, patch):  # the smaller patches at the right and bottom edges
        for c in range(wf if r < hf else 0, w, patch):
            _normalise_blocks(x[:, r : r + patch, c : c + patch], (1, 2), out[:, r : r + patch, c : c + patch])
    return out.astype(np.float32)


def _normalise_blocks(block: np.ndarray, axes: tuple[int, int], out: np.ndarray) -> None:
    """``out = (block − mean) / std`` over ``axes`` (0 where the spread is 0)."""
    mean = block.mean(axis=axes, keepdims=True)
    std = block.std(axis=axes, keepdims=True)
    centred = block - mean
    safe = np.where(std > 1e-12 * np.maximum(1.0, np.abs(mean)), std, np.inf)
    np.divide(centred, safe, out=out)


#: Bytes of greyscale float32 frames :func:`seqslam_preprocess` works on at once: a traverse
#: of camera-size colour frames is described a block of frames at a time, so its float
#: temporaries (float32 colour, float64 patches) stay this size, not a multiple of the frames'.
_FRONTEND_BLOCK_BYTES = 32 << 20


def seqslam_preprocess(
    images: np.ndarray,
    size: tuple[int, int] | None = None,
    patch: int | None = 4,
    crop: tuple[int, int, int, int] | None = None,
) -> np.ndarray:
    """The SeqSLAM image front-end: greyscale, crop, resize, patch-normalise, flatten.

    Each frame is described on its own, a block of frames at a time (about
    :data:`_FRONTEND_BLOCK_BYTES` of greyscale floats), so the memory is the frames' and
    the descriptors', whatever the frames' size.

    Parameters
    ----------
    images : ndarray, shape (n, h, w) or (n, h, w, c)
    size : (width, height), optional
        Resize target; ``None`` keeps the size.
    patch : int or None
        Patch side for patch normalisation; ``None`` or 0 skips it.
    crop : (top, bottom, left, right), optional
        Pixels to cut from each side before resizing.

    Returns
    -------
    ndarray, shape (n, height*width), float32
    """
    x = check_array(images, "images", ndim=(3, 4), dtype=None)
    if x.ndim == 4 and x.shape[-1] not in (1, 2, 3, 4):
        raise DataError(f"images must have shape (n, h, w) or (n, h, w, channels); got {x.shape}.")
    h, w = x.shape[1:3]
    top = bottom = left = right = 0
    if crop is not None:
        values = tuple(crop) if isinstance(crop, (tuple, list, np.ndarray)) else ()
        if len(values) != 4 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in values):
            raise InvalidParameterError(f"crop must be (top, bottom, left, right): four whole numbers of pixels to cut; "
                                        f"got {crop!r}.")
        top, bottom, left, right = (int(v) for v in values)
        if min(top, bottom, left, right) < 0 or top + bottom >= h or left + right >= w:
            raise DataError(f"crop {crop} does not fit images of size {w}×{h}; give (top, bottom, left, right) pixels.")
    out_h, out_w = h - top - bottom, w - left - right
    if size is not None:
        out_w, out_h = int(size[0]), int(size[1])
        if out_w < 1 or out_h < 1:
            raise DataError(f"resize size must be two positive ints (width, height); got {size}.")
    n = x.shape[0]
    if 4.0 * n * out_h * out_w > _FRONTEND_BLOCK_BYTES:  # a live frame's is never: no read of the memory there
        check_memory(4.0 * n * out_h * out_w, f"the descriptors of {n} images of {out_w}×{out_h}",
                     "choose a smaller size (--size)")
    out = np.empty((n, out_h * out_w), dtype=np.float32)
    block = max(1, _FRONTEND_BLOCK_BYTES // (4 * h * w))
    for i in range(0, n, block):
        part = to_greyscale(x[i : i + block])[:, top : h - bottom, left : w - right]
        if size is not None:
            part = resize_images(part, size)
        if patch:
            part = patch_normalise(part, patch)
        out[i : i + block] = part.reshape(part.shape[0], -1)
    return out


def wifi_vectors(rss: np.ndarray, not_detected: float = 100.0, floor_dbm: float = -105.0) -> np.ndarray:
    """Received-signal-strength fingerprints → non-negative strength vectors.

    Parameters
    ----------
    rss : ndarray, shape (n, n_access_points)
        dBm readings; ``not_detected`` marks an access point that was not seen.
    not_detected : float
        The code for "not seen" (UJI: +100).
    floor_dbm : float
        Noise floor: readings at or below it count as not seen.

    Returns
    -------
    ndarray, shape (n, n_access_points), float32
        ``max(rss − floor_dbm, 0)``, and 0 where not detected.
    """
    x = check_array(rss, "Wi-Fi RSS readings", ndim=2)
    seen = x != not_detected
    if np.any(x[seen] > 0):
        raise DataError(
            f"Wi-Fi readings must be dBm (≤ 0) or {not_detected:g} for 'not detected'; "
            f"found {np.count_nonzero(x[seen] > 0)} positive values. Set not_detected to the code your data uses."
        )
    out = np.where(seen, np.maximum(x - floor_dbm, 0.0), 0.0)
    return out.astype(np.float32)


def informative_frames(descriptors: np.ndarray) -> np.ndarray:
    """Which descriptors carry information: not every value equal.

    Parameters
    ----------
    descriptors : ndarray, shape (n, d) (or (n, ...), flattened per frame)

    Returns
    -------
    ndarray of bool, shape (n,)
        ``False`` for constant descriptors (black or flat images, scans with no access
        point detected, zero vectors).

    Examples
    --------
    >>> informative_frames(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2.0, 2.0, 2.0]]))
    array([False,  True, False])
    """
    x = np.asarray(descriptors)
    if x.ndim == 0 or x.shape[0] == 0:
        return np.zeros(0 if x.ndim == 0 else x.shape[0], dtype=bool)
    x = x.reshape(x.shape[0], -1)
    if x.shape[1] == 0:
        return np.zeros(x.shape[0], dtype=bool)
    return np.any(x != x[:, :1], axis=1)


def check_information(descriptors: np.ndarray, role: str) -> np.ndarray:
    """Report the frames of a traverse that carry no information; return the mask.

    Parameters
    ----------
    descriptors : ndarray, shape (n, d)
    role : {"reference", "query"}

    Returns
    -------
    ndarray of bool, shape (n,)
        :func:`informative_frames`.

    Warns
    -----
    CatgraphWarning
        Some frames carry no information (the count and the first one).

    Raises
    ------
    DataError
        No reference frame carries information (a map of black frames cannot
        localise anything).
    """
    mask = informative_frames(descriptors)
    n, bad = mask.size, int(mask.size - mask.sum())
    if n and bad == n and role == "reference":
        raise DataError(
            f"none of the {n} reference frames carries information: every descriptor is constant (black or flat "
            "images, scans with no access point detected, zero vectors). Check the reference data."
        )
    if bad:
        first = int(np.flatnonzero(~mask)[0])
        consequence = ("they get no match from a matcher, and a filter answers them from its prediction"
                       if role == "query" else "matches to them say nothing; check or drop them")
        warn(
            f"{bad} of {n} {role} frames carry no information (constant descriptors: black or flat images, "
            f"no access point detected, zero vectors; first at frame {first}); {consequence}."
        )
    return mask
