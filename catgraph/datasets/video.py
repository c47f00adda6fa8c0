"""Video files as traverses: a camera's recording read frame by frame.

A video (``.mp4``, ``.mkv``, ``.avi``, ``.mov``, ``.webm`` …, any codec FFmpeg decodes) is
read with PyAV, an optional dependency (``pip install "catgraph[video]"``). Its frames are
the traverse's frames, as an image folder's would be: RGB ``(n, h, w, 3)`` uint8, or
``(n, h, w)`` where every frame is grey, so a video and its frames written out as PNG images
are described alike (the image front-end, :func:`catgraph.frontends.seqslam_preprocess`).

A camera records 25–60 frames per second, consecutive frames nearly alike; ``fps`` keeps
fewer: the first frame at or after each multiple of ``1 / fps`` seconds from the first
frame, by the frames' own timestamps (so a variable frame rate is sampled evenly in time).
The frames are held as decoded (three bytes per pixel); a video that would not fit in
memory is refused before it is read, with the ``fps`` that would fit.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._validation import check_fps
from ..exceptions import DataError, DataNotFoundError, MissingDependencyError, warn
from ..traverse import Traverse

__all__ = ["VIDEO_SUFFIXES", "load_video", "is_video"]

#: File suffixes read as videos (:func:`catgraph.datasets.load_traverse`).
VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".avi", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts")


def is_video(source) -> bool:
    """Whether ``source`` (a path) names a video file, by its suffix (:data:`VIDEO_SUFFIXES`)."""
    return isinstance(source, (str, Path)) and Path(source).suffix.lower() in VIDEO_SUFFIXES


def _open(path: Path):
    try:
        import av
    except ImportError:
        raise MissingDependencyError(f'reading the video {path.name} needs PyAV, an optional dependency: '
                                     'pip install "catgraph[video]" (or write its frames out as PNG images).') from None
    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read the video {path}: {exc}. Check that the file is a whole video.") from None
    if not container.streams.video:
        container.close()
        raise DataError(f"{path} holds no video stream; give a video file (or a folder of frames).")
    return av, container


def load_video(path: str | Path, fps: float | None = None) -> Traverse:
    """Load a video file's frames, every frame or ``fps`` of them per second.

    Parameters
    ----------
    path : str or Path
        The video file (its first video stream is read).
    fps : float, optional
        Frames kept per second: the first frame at or after each multiple of ``1 / fps``
        seconds from the first frame (by the frames' timestamps). ``None``: every frame.

    Returns
    -------
    Traverse
        ``frames`` ``(n, h, w, 3)`` uint8 (``(n, h, w)`` where every frame is grey), ``ids`` =
        the frames' numbers in the video (from 0, every frame counted), ``timestamps`` =
        seconds from the first frame, ``meta = {"kind": "images", "source": ..., "video":
        {"fps": ..., "rate": ..., "frames_read": ...}}``.

    Raises
    ------
    MissingDependencyError
        PyAV is not installed.
    DataNotFoundError, DataError
        No such file; not a video, a damaged one, or one without frames.
    InsufficientMemoryError
        The frames kept would not fit in memory (the message gives an ``fps`` that would).

    Warns
    -----
    CatgraphWarning
        The frames end more than two frame intervals before the length the file declares: a
        file cut short (an interrupted copy or recording), which FFmpeg decodes up to the cut
        without an error. The frames that decode are returned.
    """
    from .loaders import _as_path, grey_if_equal

    path = _as_path(path, "load_video")
    fps = check_fps(fps)
    if not path.is_file():
        raise DataNotFoundError(f"video {path} does not exist; check the path.")
    av, container = _open(path)
    with container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"  # FFmpeg's own frame and slice threads
        rate = float(stream.average_rate) if stream.average_rate else None
        declared = _declared_seconds(stream, container)
        _check_memory(path, stream, declared, rate, fps)
        frames: list[np.ndarray] = []
        numbers, times = [], []
        first, last, next_bucket, read = None, None, 0, 0
        try:
            for k, frame in enumerate(container.decode(stream)):
                t = frame.time if frame.time is not None else (k / rate if rate else None)
                if t is None:
                    raise DataError(f"{path}: its frames carry no timestamps and the stream no frame rate, so fps "
                                    "cannot pick frames by time; leave fps out (every frame).")
                first, last, read = (t if first is None else first), t, k + 1
                if fps is not None:
                    bucket = math.floor((t - first) * fps + 1e-9)
                    if bucket < next_bucket:
                        continue
                    next_bucket = bucket + 1
                array = frame.to_ndarray(format="rgb24")
                if frames and array.shape != frames[0].shape:
                    raise DataError(f"{path}: frame {k} is {array.shape[1]}×{array.shape[0]} but the first is "
                                    f"{frames[0].shape[1]}×{frames[0].shape[0]}; re-encode the video at one size.")
                frames.append(array)
                numbers.append(k)
                times.append(t - first)
        except av.FFmpegError as exc:
            raise DataError(f"cannot decode the video {path} after {len(numbers)} frames: {exc}. The file may be "
                            "damaged or cut short.") from None
    if not frames:
        raise DataError(f"{path} holds no frames that decode; give a video with at least one frame.")
    _warn_if_cut_short(path, declared, rate, last - first, read)
    out = np.empty((len(frames), *frames[0].shape), dtype=np.uint8)
    for k in range(len(frames)):  # each frame freed as it is copied: never twice the frames in memory
        out[k], frames[k] = frames[k], None
    return Traverse(grey_if_equal(out), timestamps=np.asarray(times, dtype=np.float64),
                    ids=np.asarray(numbers, dtype=np.int64), name=path.name,
                    meta={"kind": "images", "source": str(path),
                          "video": {"fps": fps, "rate": rate, "frames_read": read}})


def _declared_seconds(stream, container) -> float | None:
    """The video stream's length as the file declares it (its own duration, else the
    container's), in seconds; ``None`` where the file does not say."""
    if stream.duration is not None and stream.time_base is not None:
        return float(stream.duration * stream.time_base)
    if container.duration is not None:
        return container.duration / 1_000_000  # microseconds (FFmpeg's AV_TIME_BASE)
    return None


def _warn_if_cut_short(path: Path, declared: float | None, rate: float | None, span: float, read: int) -> None:
    """Warn where the decoded frames end well before the length the file declares: a file cut
    short (an interrupted copy or recording) whose container still decodes up to the cut, which
    FFmpeg does not report as an error. More than two frame intervals missing counts."""
    if not declared or not rate:
        return
    covered = span + 1.0 / rate  # the last frame lasts one interval
    if covered < declared - 2.0 / rate:
        warn(f"{path}: the frames decoded end at {covered:.2f} s ({read} frames) but the file declares "
             f"{declared:.2f} s; it may be cut short (an interrupted copy or recording). The frames read are "
             "used; copy or record the video again for the rest.")


def _check_memory(path: Path, stream, seconds: float | None, rate: float | None, fps: float | None) -> None:
    """Refuse, before reading, a video whose kept frames would not fit in memory (where its
    length is known), naming an ``fps`` that would fit."""
    from .._validation import available_memory, check_memory

    width, height = stream.codec_context.width, stream.codec_context.height
    if not seconds or not rate or not width or not height:
        return
    kept = min(rate, fps) if fps is not None else rate
    frame_bytes = 3.0 * width * height
    available = available_memory()
    fix = "keep fewer frames per second (--fps, load_video(fps=...))"
    if available is not None:
        from .._validation import MEMORY_FRACTION

        fits = MEMORY_FRACTION * available / (frame_bytes * seconds)
        fix += f": at most about {max(fits, 0.0):.3g} of them fit" if fits < kept else ""
    check_memory(frame_bytes * (seconds * kept + 1), f"the frames of the video {path.name} ({seconds:.0f} s at "
                 f"{kept:.3g} frames per second, {width}×{height})", fix)
