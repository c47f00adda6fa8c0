"""Front-ends: from a traverse's frames to descriptors and a difference matrix.

1. :func:`describe` turns a traverse's frames into descriptors with the front-end its
   kind calls for — images: the SeqSLAM pipeline (greyscale, optional crop, resize, 4×4
   patch normalisation) compared with SAD; Wi-Fi: strength-above-floor vectors, SAD;
   descriptor arrays: as given, cosine (boolean arrays: Hamming).
2. :func:`differences` computes the query × reference difference matrix, normalised per
   query (paper 1) unless asked otherwise — through a map built in memory
   (:func:`catgraph.io.build_map`, :func:`catgraph.io.query_differences`), the one
   path a saved map takes too.

Running a method on the result is :mod:`catgraph.experiment`'s job.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .differences import METRICS
from ._validation import check_fps
from .exceptions import InvalidParameterError
from .frontends import seqslam_preprocess, wifi_vectors
from .traverse import Traverse

__all__ = ["FrontEnd", "describe", "differences", "METRICS"]

#: Image frames of more pixels than this (after the crop) described at their own size draw
#: a note (:func:`note_large_images`): the SeqSLAM pipeline works on small images.
LARGE_IMAGE_PIXELS = 128 * 128


@dataclass(frozen=True)
class FrontEnd:
    """Front-end settings (stored with results and maps).

    Parameters
    ----------
    size : (width, height) or None
        Image resize target; ``None`` keeps the images' size.
    patch : int
        Patch-normalisation patch side (0 = off).
    crop : (top, bottom, left, right) or None
        Image pixels cut from each side before the resize (e.g. a vehicle's bonnet or a
        sky band); ``None`` keeps the whole image.
    metric : str or None
        Difference metric; ``None`` picks by data kind (images/Wi-Fi: SAD, feature
        vectors: cosine, booleans: Hamming).
    normalise : bool
        Per-query normalisation of the difference matrix (paper 1).
    fps : float or None
        Video inputs only: the frames kept per second (by the frames' timestamps;
        :func:`catgraph.datasets.video.load_video`); ``None`` keeps every frame. A map keeps
        it, and a video query given to the map is read at the same rate.
    """

    size: tuple[int, int] | None = None
    patch: int = 4
    metric: str | None = None
    normalise: bool = True
    crop: tuple[int, int, int, int] | None = None
    fps: float | None = None

    #: the settings' names, as :meth:`as_dict` writes them and configs and maps give them
    KEYS: ClassVar[tuple[str, ...]] = ("size", "patch", "crop", "metric", "normalise", "fps")
    #: the settings that apply to image frames only
    IMAGE_KEYS: ClassVar[tuple[str, ...]] = ("size", "patch", "crop")

    def __post_init__(self) -> None:
        if self.crop is not None:
            crop = tuple(self.crop) if isinstance(self.crop, (tuple, list, np.ndarray)) else ()
            if len(crop) != 4 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                         and 0 <= v <= 100_000 for v in crop):
                raise InvalidParameterError(f"the front-end crop must be (top, bottom, left, right) pixels cut from "
                                            f"each side, each an int in [0, 100000]; got {self.crop!r}.")
            object.__setattr__(self, "crop", tuple(int(v) for v in crop))
        if self.size is not None:
            size = tuple(self.size)
            if len(size) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 0 < v <= 100_000
                                         for v in size):
                raise InvalidParameterError(f"the front-end size must be (width, height) in pixels, each in "
                                            f"[1, 100000]; got {self.size!r}.")
            object.__setattr__(self, "size", (int(size[0]), int(size[1])))
        if isinstance(self.patch, bool) or not isinstance(self.patch, (int, np.integer)) or not 0 <= self.patch <= 10_000:
            raise InvalidParameterError(f"the patch side must be an int in [0, 10000] pixels (0 = off); got {self.patch!r}.")
        if self.metric is not None and self.metric not in METRICS:
            raise InvalidParameterError(f"unknown metric {self.metric!r}; choose one of {', '.join(METRICS)}.")
        if not isinstance(self.normalise, (bool, np.bool_)):
            raise InvalidParameterError(f"normalise must be true or false; got {self.normalise!r}.")
        object.__setattr__(self, "fps", check_fps(self.fps))

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None) -> "FrontEnd":
        """From :meth:`as_dict`'s form (``None`` or ``{}``: the defaults)."""
        values = dict(values or {})
        unknown = sorted(set(values) - set(cls.KEYS))
        if unknown:
            raise InvalidParameterError(f"unknown front-end options {unknown}; allowed: {', '.join(cls.KEYS)}.")
        if isinstance(values.get("crop"), str):
            try:
                values["crop"] = tuple(int(v) for v in values["crop"].split(","))
            except ValueError:
                raise InvalidParameterError(f"write the crop as TOP,BOTTOM,LEFT,RIGHT pixels, e.g. 0,4,0,0; got "
                                            f"{values['crop']!r}.") from None
        if isinstance(values.get("size"), str):
            try:
                w, h = values["size"].lower().split("x")
                values["size"] = (int(w), int(h))
            except ValueError:
                raise InvalidParameterError(f"write the size as WIDTHxHEIGHT, e.g. 32x16; got {values['size']!r}.") from None
        values = {k: v for k, v in values.items() if v is not None or k in ("size", "metric", "crop", "fps")}
        return cls(**values)

    def as_dict(self) -> dict:
        return {"size": list(self.size) if self.size else None, "patch": self.patch,
                "crop": list(self.crop) if self.crop else None, "metric": self.metric, "normalise": self.normalise,
                "fps": self.fps}


def _kind(traverse: Traverse) -> str:
    kind = traverse.meta.get("kind")
    if kind:
        return kind
    return "images" if traverse.frames.ndim >= 3 else "descriptors"


def describe(traverse: Traverse, frontend: FrontEnd = FrontEnd()) -> tuple[np.ndarray, str]:
    """Descriptors ``(n, d)`` for a traverse and the metric to compare them with."""
    descriptors, metric = _describe(traverse, frontend)
    if metric == "hamming" and descriptors.dtype not in (np.bool_, np.uint8):
        raise InvalidParameterError(
            f"the hamming metric compares binary descriptors (boolean, or bits packed in uint8), but "
            f"{traverse.name or 'this traverse'} gives {descriptors.dtype} descriptors ({_kind(traverse)}); "
            "choose sad, ssd or cosine.")
    return descriptors, metric


def check_image_options(traverse: Traverse, given: set[str]) -> None:
    """Refuse the image front-end's options ``given`` (``size``, ``patch``, ``crop``) for a
    traverse of other frames (Wi-Fi scans, descriptors), which they would not touch."""
    kind = _kind(traverse)
    given = [f"--{k} ({k})" for k in FrontEnd.IMAGE_KEYS if k in given]
    if kind == "images" or traverse.meta.get("described") or not given:
        return
    both = len(given) > 1
    raise InvalidParameterError(f"{' and '.join(given)} appl{'y' if both else 'ies'} to image frames only; "
                                f"{traverse.name or 'this traverse'} holds {kind}. Leave {'them' if both else 'it'} out.")


def note_large_images(traverse: Traverse, frontend: FrontEnd) -> None:
    """A :class:`~catgraph.exceptions.CatgraphWarning` where image frames of more than
    :data:`LARGE_IMAGE_PIXELS` pixels (after the crop) are described at their own size (no
    ``size`` given): every difference then reads every pixel, while the SeqSLAM pipeline
    (paper 1) is run on small images, 32 × 16 or 64 × 32, at a fraction of the time and
    memory. Nothing changes; a ``size`` equal to the frames' own silences the note."""
    if frontend.size is not None or traverse.frames.ndim < 3:
        return
    height, width = traverse.frames.shape[1:3]
    if frontend.crop is not None:
        top, bottom, left, right = frontend.crop
        height, width = height - top - bottom, width - left - right
    if height * width <= LARGE_IMAGE_PIXELS:
        return
    from .exceptions import warn

    warn(
        f"{traverse.name or 'the traverse'}: its {width}×{height} frames are compared at full size, "
        f"{width * height:,} values each (no size given). The SeqSLAM pipeline works on small images, 32×16 or "
        f"64×32 (at 64×32, {width * height // 2048}× fewer values). Give --size 64x32 (FrontEnd(size=(64, 32))), "
        f"or --size {width}x{height} to keep this size without this note.")


def _describe(traverse: Traverse, frontend: FrontEnd) -> tuple[np.ndarray, str]:
    kind = _kind(traverse)
    # a value other than the default was given (the experiment layer also knows a default given explicitly)
    check_image_options(traverse, {k for k, on in (("size", frontend.size is not None),
                                                   ("patch", frontend.patch not in (0, FrontEnd.patch)),
                                                   ("crop", frontend.crop is not None)) if on})
    if kind == "images":
        note_large_images(traverse, frontend)
        return seqslam_preprocess(traverse.frames, size=frontend.size, patch=frontend.patch, crop=frontend.crop), \
            frontend.metric or "sad"
    if kind == "wifi":
        return wifi_vectors(traverse.frames, not_detected=traverse.meta.get("not_detected", 100.0)), \
            frontend.metric or "sad"
    frames = traverse.frames.reshape(len(traverse), -1)
    if frames.dtype == bool:
        return frames, frontend.metric or "hamming"
    if frames.dtype == np.uint8 and frontend.metric == "hamming":  # bits packed in bytes, compared as bits
        return frames, "hamming"
    from ._validation import check_array

    return check_array(frames, f"descriptors of {traverse.name or 'the traverse'}", dtype=np.float32), \
        frontend.metric or "cosine"


def differences(reference: Traverse, query: Traverse, frontend: FrontEnd = FrontEnd()) -> np.ndarray:
    """The ``(n_query, n_reference)`` difference matrix, in the query's processing order."""
    from .io import build_map, query_differences

    return query_differences(build_map(reference, frontend, graph=False), query)
