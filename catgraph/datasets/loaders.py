"""Loaders for the formats users have.

* **Image folders** (``.png``, ``.jpg``, ``.jpeg``): frames sorted by the (last) number in
  the file name, so ``images-00010.png`` < ``images-00100.png`` whatever the zero
  padding; greyscale stays ``(n, h, w)``, colour becomes ``(n, h, w, 3)``. ``ids`` holds
  the file numbers. Nordland's ``32x16/summer`` is such a folder.
* **UJI Wi-Fi sets**: four CSV files sharing a prefix, e.g. ``db/01/trn01`` →
  ``trn01rss.csv`` (one column per access point, dBm, +100 = not detected),
  ``trn01crd.csv`` (x, y, floor), ``trn01tms.csv`` (``yyyymmddHHMMSSfff``, or
  ``yyyymmddHHMMSS`` at seconds resolution), ``trn01ids.csv``. Only ``rss`` is required;
  ``crd`` is used where present and must have one row per fingerprint. Timestamps and ids
  are metadata no method needs: a problem with them (a malformed stamp, a wrong row
  count) is a :class:`~catgraph.exceptions.CatgraphWarning` and the field is dropped,
  never a reason to refuse the fingerprints.
* **Video files** (``.mp4``, ``.mkv``, ``.avi`` …): every frame, or ``fps`` of them per
  second (:mod:`catgraph.datasets.video`; needs PyAV, ``pip install "catgraph[video]"``).
* **Descriptor arrays**: ``.npy`` (one ``(n, d)`` array) or ``.npz`` with ``descriptors``
  (or ``frames``) and optional ``positions``, ``floors``, ``timestamps``, ``ids``,
  ``odometry``; both read with ``allow_pickle=False``.

:func:`load_traverse` picks the loader from the path. Every failure is a typed
:class:`~catgraph.exceptions.CatgraphError` naming the file and the fix.
"""

from __future__ import annotations

import os
import re
import zipfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..exceptions import DataError, DataNotFoundError, InvalidParameterError, warn
from ..traverse import Traverse

__all__ = ["IMAGE_SUFFIXES", "load_image_folder", "load_uji", "load_array", "load_traverse", "source_paths",
           "uji_files"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: The files of a UJI Wi-Fi set, ``PREFIX + part + ".csv"``.
UJI_PARTS = ("rss", "crd", "tms", "ids")
_NUMBER = re.compile(r"(\d+)")


def _image_files(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]


def _sort_key(path: Path) -> tuple[int, int, str]:
    numbers = _NUMBER.findall(path.stem)
    return (0, int(numbers[-1]), path.name) if numbers else (1, 0, path.name)


def _as_path(source, owner: str) -> Path:
    if isinstance(source, (str, os.PathLike)) and not isinstance(source, bytes):
        text = os.fspath(source)
        if isinstance(text, str) and text.strip() and "\x00" not in text:
            return Path(text)
    raise InvalidParameterError(
        f"{owner} needs a path (str or pathlib.Path) to an image folder, a UJI prefix or a .npy/.npz file; "
        f"got {source!r} of type {type(source).__name__}."
    )


def load_image_folder(path: str | Path, progress: bool = False) -> Traverse:
    """Load every PNG/JPG image of a folder, sorted by the number in the file name.

    16-bit greyscale frames are brought to the 8-bit scale (``round(v / 257)``).

    Returns
    -------
    Traverse
        ``frames`` ``(n, h, w)`` uint8 (greyscale) or ``(n, h, w, 3)`` (colour),
        ``ids`` = the file numbers (or positions in sorted order where a name has none),
        ``meta = {"kind": "images", "files": [...]}``.
    """
    from PIL import Image, UnidentifiedImageError

    folder = _as_path(path, "load_image_folder")
    if not folder.exists():
        raise DataNotFoundError(f"image folder {folder} does not exist; check the path.")
    if not folder.is_dir():
        raise DataError(f"{folder} is not a folder; give a folder of PNG/JPG images.")
    files = sorted(_image_files(folder), key=_sort_key)
    if not files:
        from .video import is_video

        videos = sorted(p.name for p in folder.iterdir() if p.is_file() and is_video(p))
        hint = f" It holds the video {videos[0]}: give that file itself." if len(videos) == 1 else (
            f" It holds {len(videos)} videos ({', '.join(videos[:3])}{' …' if len(videos) > 3 else ''}): give one of "
            "those files itself." if videos else "")
        raise DataNotFoundError(f"{folder} holds no PNG or JPG images; give a folder of frames.{hint}")
    iterator = files
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(files, desc=f"loading {folder.name}", unit="img", leave=False)
    frames = None  # filled in place: the traverse's memory is its frames', never twice theirs
    for k, file in enumerate(iterator):
        try:
            with Image.open(file) as img:
                img.load()
                if img.mode == "I" or img.mode.startswith("I;16"):
                    array = _eight_bits(np.asarray(img))
                else:
                    mode = "L" if img.mode in ("L", "1", "P") and _is_grey(img) else "RGB"
                    array = np.asarray(img.convert(mode))
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
            raise DataError(f"cannot read image {file}: {exc}. Remove or replace the corrupt file.") from None
        if frames is None:
            frames = np.empty((len(files), *array.shape), dtype=np.uint8)
        elif array.shape[:2] != frames.shape[1:3]:
            raise DataError(
                f"images in {folder} differ in size ({files[0].name}: {frames.shape[2]}×{frames.shape[1]}, "
                f"{file.name}: {array.shape[1]}×{array.shape[0]}); resize them to one size first."
            )
        if array.ndim != frames.ndim - 1:  # mixed grey and colour: grey becomes RGB
            if array.ndim == 3:
                frames = np.repeat(frames[..., None], 3, axis=3)
            else:
                array = np.repeat(array[..., None], 3, axis=2)
        frames[k] = array
    frames = grey_if_equal(frames)
    numbers = [_NUMBER.findall(f.stem) for f in files]
    _warn_ambiguous_order(folder, files, numbers)
    ids = np.array([int(n[-1]) if n else k for k, n in enumerate(numbers)], dtype=np.int64)
    return Traverse(frames, ids=ids, name=folder.name, meta={"kind": "images", "source": str(folder),
                                                              "files": [f.name for f in files]})


def grey_if_equal(frames: np.ndarray) -> np.ndarray:
    """RGB frames ``(n, h, w, 3)`` whose three channels are equal everywhere (grey stored as
    colour) as ``(n, h, w)``; any other frames as they are."""
    if frames.ndim == 4 and np.array_equal(frames[..., 0], frames[..., 1]) and np.array_equal(frames[..., 1], frames[..., 2]):
        return np.ascontiguousarray(frames[..., 0])
    return frames


def _warn_ambiguous_order(folder: Path, files: list[Path], numbers: list[list[str]]) -> None:
    """Frames are ordered by the last number in their names: say so where that order is a
    guess (two files with one number, or files without a number beside numbered ones)."""
    seen: dict[int, str] = {}
    for file, found in zip(files, numbers):
        if not found:
            continue
        number = int(found[-1])
        if number in seen:
            warn(f"{folder}: {seen[number]} and {file.name} carry the same frame number {number}; their "
                 "order is by name. Rename one if they are not the same frame.")
            break
        seen[number] = file.name
    unnumbered = [file.name for file, found in zip(files, numbers) if not found]
    if unnumbered and len(unnumbered) < len(files):
        warn(f"{folder}: {len(unnumbered)} image(s) without a frame number in the name (first: "
             f"{unnumbered[0]}) are loaded after the numbered frames; move them out if they are not frames.")


def _eight_bits(grey: np.ndarray) -> np.ndarray:
    """A 16-bit greyscale frame (Pillow's ``I;16`` modes, or ``I`` as 16-bit PNGs open in
    some versions) on the 8-bit scale of every other frame: ``round(v / 257)``, so 65535 is
    255 (Pillow's own ``convert("L")`` clips every value above 255 to white)."""
    values = np.clip(grey.astype(np.float64), 0.0, 65535.0)
    return np.rint(values / 257.0).astype(np.uint8)


def _is_grey(img) -> bool:
    if img.mode != "P":
        return True
    palette = np.asarray(img.convert("RGB"))
    return bool(np.all(palette[..., 0] == palette[..., 1]) and np.all(palette[..., 1] == palette[..., 2]))


def _read_csv(file: Path, name: str, columns: int | None = None) -> np.ndarray:
    try:
        rows = [line.strip() for line in file.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read {file} as comma-separated text: {exc}") from None
    if not rows:
        raise DataError(f"{file} is empty; every UJI set needs at least one fingerprint.")
    split = [row.split(",") for row in rows]
    width = columns if columns is not None else len(split[0])
    for line_no, cells in enumerate(split, start=1):
        if len(cells) != width or any(c.strip() == "" for c in cells):
            found = len([c for c in cells if c.strip() != ""])
            raise DataError(
                f"{file}, line {line_no}: expected {width} comma-separated {name} values, found {found}; "
                "the file has a missing column or a malformed row."
            )
    try:
        return np.array(split, dtype=np.float64)
    except ValueError:
        raise DataError(f"{file} holds non-numeric {name} values; expected numbers only.") from None


def load_uji(prefix: str | Path) -> Traverse:
    """Load a UJI-format Wi-Fi set from its common prefix (e.g. ``db/01/trn01``).

    Returns
    -------
    Traverse
        ``frames`` = raw RSS ``(n, n_access_points)`` in dBm (+100 = not detected),
        ``positions`` (x, y metres) and ``floors`` from ``crd``, ``timestamps`` (seconds
        since the first fingerprint) from ``tms``, ``ids`` from ``ids``;
        ``meta = {"kind": "wifi", ...}``.
    """
    prefix = _as_path(prefix, "load_uji")
    rss_file, crd_file, tms_file, ids_file = uji_files(prefix).values()
    if not rss_file.exists():
        raise DataNotFoundError(
            f"no UJI Wi-Fi set at {prefix}: {rss_file.name} not found in {rss_file.parent}. "
            "Give the common prefix of the rss/crd/tms/ids files, e.g. db/01/trn01."
        )
    rss = _read_csv(rss_file, "RSS")
    n = rss.shape[0]
    kwargs: dict = {}
    if crd_file.exists():
        crd = _read_csv(crd_file, "coordinate (x, y, floor)", columns=3)
        _check_rows(crd, n, crd_file)
        if not np.all(np.isfinite(crd)) or np.any(np.abs(crd[:, 2]) > 2**31):
            raise DataError(f"{crd_file} holds NaN, infinite or out-of-range coordinates; fix or drop those rows.")
        kwargs["positions"] = crd[:, :2]
        kwargs["floors"] = np.rint(crd[:, 2]).astype(np.int64)
    if tms_file.exists():
        seconds = _optional_metadata(lambda: _uji_seconds(_read_stamps(tms_file), tms_file), n, tms_file)
        if seconds is not None:
            kwargs["timestamps"] = seconds
    if ids_file.exists():
        ids = _optional_metadata(lambda: _read_ids(ids_file), n, ids_file)
        if ids is not None:
            kwargs["ids"] = ids
    return Traverse(rss, name=prefix.name, meta={"kind": "wifi", "source": str(prefix), "not_detected": 100.0},
                    **kwargs)


def uji_files(prefix: str | Path) -> dict[str, Path]:
    """The files of the UJI Wi-Fi set at ``prefix`` (whether or not they exist), by part."""
    return {part: Path(f"{prefix}{part}.csv") for part in UJI_PARTS}


def source_paths(source: str | Path) -> list[Path]:
    """The existing files and folders that :func:`load_traverse` reads for ``source`` (the
    path itself, or the files of a UJI prefix); none for a name that is not a path
    (``synthetic:SEED``). What a command that writes must never overwrite."""
    path = Path(source)
    if path.exists():
        return [path]
    return [file for file in uji_files(path).values() if file.exists()]


def _read_ids(file: Path) -> np.ndarray:
    """A UJI ``ids`` column as int64; whole numbers only."""
    values = _read_csv(file, "id", columns=1)[:, 0]
    if not (np.all(np.isfinite(values)) and np.all(values == np.rint(values)) and np.all(np.abs(values) < 2**62)):
        raise DataError(f"{file} holds ids that are not whole numbers (NaN, fractions or out of range).")
    return values.astype(np.int64)


def _check_rows(values: np.ndarray, n: int, file: Path) -> None:
    if values.shape[0] != n:
        raise DataError(f"{file} has {values.shape[0]} rows but the RSS file has {n}; the set is incomplete.")


def _optional_metadata(read, n: int, file: Path) -> np.ndarray | None:
    """Read a metadata column no method needs; on any problem warn and return ``None``."""
    try:
        values = read()
        _check_rows(values, n, file)
    except DataError as exc:
        warn(f"{exc} Ignoring {file.name}; the fingerprints are loaded without it.")
        return None
    return values


def _read_stamps(file: Path) -> list[str]:
    """Timestamp cells as text: 17-digit stamps do not fit a float64 exactly."""
    try:
        rows = [line.strip() for line in file.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read {file}: {exc}.") from None
    return [row.split(",")[0].strip() for row in rows]


def _uji_seconds(stamps, file: Path) -> np.ndarray:
    """``yyyymmddHHMMSSfff`` (or ``yyyymmddHHMMSS``) → seconds since the first stamp.

    Read as one clock without time zone or daylight saving (UTC), whatever the machine's
    zone, and a logger's second 60 as the next minute's 0 (UJI 02/tst03 and 06/tst04 hold
    one each)."""
    out = np.empty(len(stamps))
    for k, stamp in enumerate(stamps):
        text = str(stamp).strip()
        if text.endswith(".0"):  # written through a float
            text = text[:-2]
        try:
            if not text.isdigit() or len(text) not in (14, 17):
                raise ValueError(text)
            seconds = int(text[12:14])
            if seconds > 60:
                raise ValueError(text)
            minute = datetime.strptime(text[:12], "%Y%m%d%H%M").replace(tzinfo=timezone.utc)
            out[k] = minute.timestamp() + seconds + (int(text[14:]) / 1000.0 if len(text) == 17 else 0.0)
        except ValueError:
            raise DataError(
                f"{file}, line {k + 1}: {text!r} is not a yyyymmddHHMMSSfff (17-digit) or yyyymmddHHMMSS "
                "(14-digit) timestamp."
            ) from None
    return out - out[0] if len(out) else out


_NPZ_FIELDS = ("positions", "floors", "timestamps", "ids", "odometry")


def load_array(path: str | Path) -> Traverse:
    """Load descriptors from ``.npy`` or ``.npz`` (never unpickling).

    The file is opened here and closed on every path, a corrupt or truncated one
    included (``numpy.load`` given a path leaves the file open when the archive is
    unreadable).
    """
    path = _as_path(path, "load_array")
    if not path.exists():
        raise DataNotFoundError(f"descriptor file {path} does not exist; check the path.")
    try:
        with open(path, "rb") as fh:
            frames, fields, main = _read_arrays(fh, path)
    except IsADirectoryError:
        raise DataError(f"{path} is a folder, not a .npy/.npz file.") from None
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    if frames.ndim < 2:
        what = "" if main is None else f" (array {main!r})"
        raise DataError(
            f"{path} holds an array{what} of shape {frames.shape}; descriptors need one row per frame, "
            "shape (n_frames, n_values)."
        )
    return Traverse(frames, name=path.stem, meta={"kind": "descriptors", "source": str(path)}, **fields)


def numpy_file_kind(fh) -> str | None:
    """``"npy"`` or ``"npz"`` by the first bytes of an open binary file (left at its start),
    ``None`` for anything else (which numpy would try to unpickle)."""
    head = fh.read(6)
    fh.seek(0)
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        return "npz"
    return None


def _read_arrays(fh, path: Path) -> tuple[np.ndarray, dict, str | None]:
    """``(frames, optional fields, name of the frames array)`` from an open .npy/.npz file."""
    if numpy_file_kind(fh) is None:
        raise DataError(f"{path} is not a .npy or .npz file (it does not begin as one); save descriptors with "
                        "numpy.save or numpy.savez.")
    try:
        loaded = np.load(fh, allow_pickle=False)
    except ValueError as exc:
        if "pickle" not in str(exc).lower():
            raise DataError(f"{path} is truncated or corrupt ({exc}); write the file again.") from None
        raise DataError(f"{path} cannot be loaded without pickle ({exc}); save plain numeric arrays.") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise DataError(f"{path} is not a readable .npy/.npz file: {exc}") from None
    if isinstance(loaded, np.ndarray):
        return loaded, {}, None
    with loaded:
        keys = list(loaded.files)
        if "__format__" in keys:
            raise DataError(f"{path} is a saved map (catgraph build-map), not a traverse; give it as --map {path} "
                            "(from Python: catgraph.io.load_map).")
        main = next((k for k in ("descriptors", "frames") if k in keys), None)
        if main is None:
            if len(keys) != 1:
                raise DataError(
                    f"{path} holds arrays {keys}; name the descriptor array 'descriptors' (optional: "
                    f"{', '.join(_NPZ_FIELDS)})."
                )
            main = keys[0]
        try:
            fields = {k: loaded[k] for k in _NPZ_FIELDS if k in keys}
            frames = loaded[main]
        except ValueError as exc:
            raise DataError(f"{path} cannot be loaded without pickle ({exc}); save plain numeric arrays.") from None
        except (OSError, zipfile.BadZipFile, EOFError, KeyError) as exc:
            raise DataError(f"{path} is truncated or corrupt ({exc}); write the file again.") from None
    return frames, fields, main


def load_traverse(source: str | Path, progress: bool = False, fps: float | None = None) -> Traverse:
    """Load a traverse from an image folder, a video file, a UJI prefix or a ``.npy``/``.npz``
    file. ``fps``: a video's frames kept per second (:func:`catgraph.datasets.video.load_video`);
    refused for every other source."""
    from .._validation import check_fps
    from .video import VIDEO_SUFFIXES, is_video, load_video

    path = _as_path(source, "load_traverse")
    if is_video(path):
        return load_video(path, fps)
    if check_fps(fps) is not None:
        raise InvalidParameterError(f"fps (--fps) picks the frames of a video; {path} is not one ("
                                    f"{', '.join(VIDEO_SUFFIXES)}). Leave it out.")
    if path.suffix.lower() in (".npy", ".npz"):
        return load_array(path)
    if path.is_dir():
        return load_image_folder(path, progress=progress)
    if uji_files(path)["rss"].exists():
        return load_uji(path)
    if path.exists():
        raise DataError(f"{path} is not a folder of images, a video, a UJI prefix or a .npy/.npz file.")
    raise DataNotFoundError(
        f"{path} does not exist: give a folder of images, a video file, a UJI prefix (e.g. db/01/trn01) or a "
        ".npy/.npz file."
    )
