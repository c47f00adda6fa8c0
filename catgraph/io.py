"""Saved maps: one versioned, checksummed ``.npz`` file per reference route.

A *map* is everything localisation needs from the reference traverse, computed once:
the reference descriptors (after the front-end), the front-end settings and the metric
that produced them, the place graph the particle filter moves on, what the reference
knew about its frames (positions, floors, ids) and, optionally, learned histogram
models of ``P(d|L)`` and ``P(d|¬L)``. :func:`save_map` writes a :class:`CatgraphMap`,
:func:`load_map` reads it back bit for bit.

File layout
-----------
A plain NumPy ``.npz`` archive (a zip of ``.npy`` members), readable with
``numpy.load(path, allow_pickle=False)`` — nothing in it is ever unpickled:

=====================  ===============================================================
member                 content
=====================  ===============================================================
``__format__``         ``"catgraph-map"`` (0-d unicode array)
``__version__``        format version, 0-d int64 (:data:`FORMAT_VERSION`)
``__metadata__``       UTF-8 JSON as a uint8 array: name, metric, front-end, graph and
                       histogram parameters, user metadata
``__sha256__``         hex SHA-256 digest (0-d unicode array), see below
``descriptors``        ``(N, D)`` reference descriptors
``positions`` …        optional ``(N, 2|3)`` positions, ``(N,)`` floors, ``(N,)`` ids
``graph.*``            place graph as flat arrays: ``source``, ``target``, ``length``,
                       ``kind`` ``(E,)``, ``route_distance`` ``(N,)``, optional
                       ``positions`` ``(N, 2|3)``
``histogram.NAME.*``   learned state of histogram model ``NAME``: arrays such as
                       ``counts_same_``, ``bin_edges_``, and 0-d arrays for scalars
=====================  ===============================================================

The graph is stored as its edge list and rebuilt with
:meth:`~catgraph.graph.PlaceGraph.from_edges`, which recomputes the CSR offsets and the
``reverse``/``straight`` edge tables; the edge list is already sorted and de-duplicated,
so the rebuilt graph equals the saved one array for array.

Integrity
---------
The digest is SHA-256 over the metadata bytes and then, for every other member in
sorted name order, its name, dtype, shape and raw bytes (C order)::

    h = sha256(b"catgraph-map\\0" + version + metadata)
    for name in sorted(arrays): h.update(name, dtype.str, shape, array.tobytes())

so any change to an array or to the metadata — a flipped byte, an array replaced by
``numpy.savez``, an edited parameter — is detected on load, on top of the zip
container's own CRC-32 per member (which catches most accidental corruption). The
checksum detects modification, it does not authenticate the author: anyone can write
a valid map.

Writing is atomic: the archive is written to a temporary file in the destination
folder, flushed to disk and renamed over the destination (``os.replace``), so a crash
never leaves a half-written map under the final name.

Descriptors read in blocks
--------------------------
``load_map(path, descriptors="stream")`` leaves the descriptors in the file: the
checksum and their finiteness are checked reading them once in row blocks, and
``CatgraphMap.descriptors`` is a :class:`StoredDescriptors` that reads row slices from
the file again where they are used. :class:`catgraph.live.LiveMap` with
``layout="uint8"`` codes them that way, so a live process never holds the float map
whole (at 10⁶ places × 512 values, the 1.9 GiB of float32 it never allocates; ``docs/live.md``).

Versions
--------
:data:`FORMAT_VERSION` grows by one whenever the layout changes incompatibly. A reader
refuses files from a newer version with a message that says to upgrade catgraph, and
keeps reading every older version it knows.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._atomic import atomic_open
from .differences import RowSource
from .exceptions import DataError, DataNotFoundError, MapFileError

if TYPE_CHECKING:  # pragma: no cover
    from .differences import DifferenceRows
    from .graph import PlaceGraph
    from .pipeline import FrontEnd
    from .traverse import Traverse

__all__ = [
    "CatgraphMap",
    "save_map",
    "load_map",
    "build_map",
    "reference_from_map",
    "describe_query",
    "query_differences",
    "query_difference_rows",
    "place_graph",
    "FORMAT_NAME",
    "FORMAT_VERSION",
]

#: Value of the ``__format__`` member of every map file.
FORMAT_NAME = "catgraph-map"
#: Version of the layout this catgraph writes (and the newest it reads).
FORMAT_VERSION = 1

_RESERVED = ("__format__", "__version__", "__metadata__", "__sha256__")
_GRAPH_ARRAYS = ("source", "target", "length", "kind", "route_distance")


@dataclass(frozen=True, eq=False)
class CatgraphMap:
    """A reference route ready for localisation.

    Parameters
    ----------
    descriptors : ndarray, shape (N, D)
        Reference descriptors after the front-end (float32 for images and Wi-Fi,
        bool for binary descriptors); a :class:`StoredDescriptors` where
        :func:`load_map` left them in the file.
    metric : str
        Difference metric the descriptors are compared with (``"sad"``, ``"cosine"`` …).
    frontend : dict
        Front-end settings, as :meth:`catgraph.pipeline.FrontEnd.as_dict` gives them.
    graph : PlaceGraph, optional
        The place graph over the ``N`` reference places.
    positions : ndarray, shape (N, 2|3), optional
        Metric positions of the reference frames.
    floors : ndarray of int64, shape (N,), optional
    ids : ndarray, shape (N,), optional
        Identifiers from the source (numbers or strings; never objects).
    histograms : dict of str → HistogramLikelihood
        Learned histogram models, by name (e.g. ``"image"``).
    name : str
        Human-readable name (the reference's).
    meta : dict
        JSON-ready extra information (source path, data kind …).
    """

    descriptors: np.ndarray
    metric: str
    frontend: dict
    graph: "PlaceGraph | None" = None
    positions: np.ndarray | None = None
    floors: np.ndarray | None = None
    ids: np.ndarray | None = None
    histograms: dict = field(default_factory=dict)
    name: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        from .differences import METRICS, _check_finite

        stored = isinstance(self.descriptors, RowSource)  # checked by whoever made it (load_map)
        d = self.descriptors if stored else np.asarray(self.descriptors)
        if d.ndim != 2:
            raise DataError(f"map descriptors must have shape (N, D), one row per place; got shape {d.shape}.")
        if d.dtype.kind not in "biuf":
            raise DataError(f"map descriptors must be numeric or boolean; got dtype {d.dtype}.")
        if not stored:
            _check_finite(d, "map descriptors")
        if self.metric not in METRICS:
            raise DataError(f"map metric {self.metric!r} is not one of {METRICS}.")
        object.__setattr__(self, "descriptors", d)
        n = d.shape[0]
        for key in ("positions", "floors", "ids"):
            value = getattr(self, key)
            if value is None:
                continue
            value = np.asarray(value)
            if value.dtype == object:
                value = value.astype(str)
            if value.shape[0] != n:
                raise DataError(f"map {key} has {value.shape[0]} rows for {n} places; give one per place.")
            object.__setattr__(self, key, value)
        if self.graph is not None and self.graph.n_places != n:
            raise DataError(f"the place graph has {self.graph.n_places} places but the map {n}; build it from the "
                            "same reference.")

    @property
    def n_places(self) -> int:
        """Number of reference places ``N``."""
        return int(self.descriptors.shape[0])

    def frontend_settings(self) -> "FrontEnd":
        """The stored front-end settings as a :class:`~catgraph.pipeline.FrontEnd`."""
        from .pipeline import FrontEnd

        f = dict(self.frontend)
        if f.get("size"):
            f["size"] = tuple(f["size"])
        return FrontEnd(**f)

    def __repr__(self) -> str:
        return (f"CatgraphMap(name={self.name!r}, n_places={self.n_places}, descriptor_dim={self.descriptors.shape[1]}, "
                f"metric={self.metric!r}, graph={self.graph is not None}, histograms={sorted(self.histograms)})")


# ---------------------------------------------------------------------------- building
def build_map(reference: "Traverse", frontend: "FrontEnd | None" = None, *, junction_radius_m: float | None = None,
              graph: bool = True, histograms: dict | None = None, meta: dict | None = None) -> CatgraphMap:
    """Describe a reference traverse and build its map.

    Parameters
    ----------
    reference : Traverse
        The reference (images, Wi-Fi or descriptors).
    frontend : FrontEnd, optional
        Front-end settings (default ``FrontEnd()``).
    junction_radius_m : float, optional
        Add junction edges between places within this many metres (needs positions);
        see :meth:`catgraph.graph.PlaceGraph.from_traverse`.
    graph : bool
        Build the place graph (default ``True``).
    histograms : dict of str → HistogramLikelihood, optional
        Learned models to store with the map.
    meta : dict, optional
        Extra JSON-ready metadata.

    Returns
    -------
    CatgraphMap
    """
    from .pipeline import FrontEnd, _kind, describe

    from .exceptions import InvalidParameterError
    from .frontends import check_information
    from .traverse import Traverse

    if not isinstance(reference, Traverse):
        raise InvalidParameterError(f"build_map describes a Traverse (catgraph.datasets.load_traverse, or "
                                    f"Traverse(frames) for an array); got a {type(reference).__name__}.")
    frontend = FrontEnd() if frontend is None else frontend
    descriptors, metric = describe(reference, frontend)
    check_information(descriptors, "reference")
    the_graph = place_graph(reference, junction_radius_m) if graph else None
    info = {"kind": _kind(reference), "n_frames": len(reference)}
    if info["kind"] == "images":  # (h, w): images of another shape may hold as many pixels
        info["image_shape"] = [int(v) for v in reference.frames.shape[1:3]]
    if "source" in reference.meta:
        info["source"] = str(reference.meta["source"])
    info.update(meta or {})
    return CatgraphMap(np.ascontiguousarray(descriptors), metric, frontend.as_dict(), the_graph,
                       reference.positions, reference.floors, reference.ids, dict(histograms or {}),
                       reference.name, info)


def place_graph(reference: "Traverse", junction_radius_m: float | None = None) -> "PlaceGraph":
    """The place graph of a reference traverse, as every map has it: the chain (lengths
    from odometry, else positions, else frames), reverse edges, and junctions within
    ``junction_radius_m`` metres where the reference has positions."""
    from .graph import PlaceGraph

    return PlaceGraph.from_traverse(reference, junction_radius_m=junction_radius_m)


def reference_from_map(catgraph_map: CatgraphMap) -> "Traverse":
    """The map's reference as a :class:`~catgraph.traverse.Traverse` of descriptors.

    Its frames are the stored descriptors, already through the front-end; compare a
    query with them through :func:`query_differences` (which applies the map's
    front-end to the query only), not through :func:`catgraph.pipeline.differences`.
    Positions, floors and ids come along, so metric ground truth works as with the
    original reference.
    """
    from .traverse import Traverse

    meta = dict(catgraph_map.meta)
    meta.update({"kind": "descriptors", "described": True, "metric": catgraph_map.metric,
                 "frontend": dict(catgraph_map.frontend)})
    return Traverse(catgraph_map.descriptors, positions=catgraph_map.positions, floors=catgraph_map.floors,
                    ids=catgraph_map.ids, name=catgraph_map.name, meta=meta)


def describe_query(catgraph_map: CatgraphMap, query: "Traverse") -> tuple[np.ndarray, np.ndarray]:
    """A query through a map's front-end: ``(descriptors (n_query, d), informative (n_query,) bool)``.

    ``informative`` is false for frames with no information
    (:func:`catgraph.frontends.check_information`), whose normalised difference rows
    are zeros ("no evidence").
    """
    from .exceptions import ShapeMismatchError
    from .frontends import check_information
    from .pipeline import describe

    frontend = catgraph_map.frontend_settings()
    kind = catgraph_map.meta.get("kind")
    check_query_kind(kind, query)
    check_image_shape(catgraph_map.meta, frontend, query.frames.shape[1:3] if kind == "images" else None, "query images")
    q, _ = describe(query, frontend)
    packing = {q.dtype, catgraph_map.descriptors.dtype}
    if catgraph_map.metric == "hamming" and packing == {np.dtype(bool), np.dtype(np.uint8)}:
        packed = "the map's" if catgraph_map.descriptors.dtype == np.uint8 else "the query's"
        raise ShapeMismatchError(
            f"{packed} bits are packed in uint8 and the other's are booleans; give both alike (np.packbits(bits, "
            "axis=1) packs booleans, np.unpackbits(codes, axis=1) unpacks them).")
    if q.shape[1] != catgraph_map.descriptors.shape[1]:
        raise ShapeMismatchError(
            f"query frames give {q.shape[1]} values per descriptor but the map holds {catgraph_map.descriptors.shape[1]}; "
            f"the map was built with front-end {catgraph_map.frontend}: use query data of the same kind and size."
        )
    return q, check_information(q, "query")


def check_image_shape(meta: dict, frontend, shape, what: str) -> None:
    """Refuse images of another ``(h, w)`` than the map's where the front-end keeps the
    images' own size (``size=None``): a transposed 16×32 image holds as many pixels as a
    32×16 one, and was compared pixel for pixel. Maps saved without ``image_shape`` (and
    any ``shape`` of ``None``) are not checked.

    Raises
    ------
    ShapeMismatchError
    """
    from .exceptions import ShapeMismatchError

    expected = meta.get("image_shape")
    if shape is None or expected is None or getattr(frontend, "size", None) is not None:
        return
    if tuple(int(v) for v in shape) != tuple(int(v) for v in expected):
        h, w = (int(v) for v in shape)
        raise ShapeMismatchError(
            f"{what} are {w}×{h} (width × height) but the map's are {int(expected[1])}×{int(expected[0])}, and the "
            "map keeps the images' own size: give images of the map's size, or build the map with --size W×H "
            "(both are then resized to it).")


def query_differences(catgraph_map: CatgraphMap, query: "Traverse", described: tuple | None = None) -> np.ndarray:
    """The ``(n_query, N)`` difference matrix of a query against a map.

    The query goes through the map's front-end (:func:`describe_query`, or ``described``,
    what it gave for this query); the stored metric and normalisation are used, so the
    result equals :func:`catgraph.pipeline.differences` on the original reference.
    """
    from ._validation import check_memory
    from .differences import difference_matrix

    frontend = catgraph_map.frontend_settings()
    q, informative = describe_query(catgraph_map, query) if described is None else described
    n_query, n_places = len(q), len(catgraph_map.descriptors)
    check_memory(8.0 * n_query * n_places, f"the ({n_query}, {n_places}) float64 difference matrix",
                 "use a shorter query or reference")
    d = difference_matrix(q, catgraph_map.descriptors, catgraph_map.metric, normalise=frontend.normalise)
    return no_information_rows(d, informative, frontend.normalise)


def query_difference_rows(catgraph_map: CatgraphMap, query: "Traverse",
                          described: tuple | None = None) -> "DifferenceRows":
    """The rows of :func:`query_differences`, block by block, never the whole matrix.

    The query goes through the map's front-end once (its descriptors are small; or
    ``described``, what :func:`describe_query` gave for this query); each pass over the
    blocks computes the rows again against the map, prepared once (the same kernels: the
    rows equal :func:`query_differences`'s, bit for bit). Memory: one block of about 32 MiB
    of float64 at a time, whatever the query's length.
    """
    from .differences import DifferenceRows, PreparedReference, iter_difference_blocks

    frontend = catgraph_map.frontend_settings()
    q, informative = describe_query(catgraph_map, query) if described is None else described
    reference = PreparedReference(catgraph_map.descriptors, catgraph_map.metric)

    def blocks_of(block_rows):
        for start, block in iter_difference_blocks(q, reference, catgraph_map.metric, block_rows,
                                                   normalise=frontend.normalise):
            yield start, no_information_rows(block, informative[start:start + len(block)], frontend.normalise)

    return DifferenceRows(len(q), catgraph_map.n_places, blocks_of)


def check_query_kind(kind: str | None, query: "Traverse") -> None:
    """Refuse a query of another data kind than the map's ``kind`` (``None``: not checked)."""
    from .pipeline import _kind

    if kind is not None and _kind(query) != kind:
        raise DataError(f"the map holds {kind} but the query holds {_kind(query)}; compare like with like.")


def no_information_rows(d: np.ndarray, informative: np.ndarray, normalise: bool) -> np.ndarray:
    """Difference rows ``d`` (in place) with the rows of frames that carry no information made
    constant: a frame with no information says nothing about where it is (σ = 0, no match,
    :mod:`catgraph.matching`): 0 where the rows are normalised, else the row's mean."""
    d[~informative] = 0.0 if normalise else d[~informative].mean(axis=1, keepdims=True)
    return d


# ---------------------------------------------------------------------------- encoding
def _histogram_state(model: Any) -> tuple[dict, dict[str, np.ndarray]]:
    """Constructor parameters (JSON) and learned state (arrays) of a histogram model."""
    params = model.get_params()
    params = {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()}
    arrays: dict[str, np.ndarray] = {}
    for key, value in vars(model).items():
        if not key.endswith("_") or key.startswith("_"):
            continue
        if isinstance(value, np.ndarray):
            arrays[key] = value
        elif isinstance(value, (bool, int, float, np.integer, np.floating, np.bool_)):
            arrays[key] = np.asarray(value)
        else:
            raise MapFileError(f"cannot store the learned attribute {key!r} of {type(model).__name__} "
                               f"(type {type(value).__name__}); only arrays and numbers are stored.")
    return {"class": type(model).__name__, "params": params}, arrays


def _histogram_from_state(info: dict, arrays: dict[str, np.ndarray], name: str) -> Any:
    from . import likelihood

    cls = getattr(likelihood, str(info.get("class")), None)
    if cls is None:
        raise MapFileError(f"histogram model {name!r} has unknown class {info.get('class')!r}; "
                           "it may need a newer catgraph.")
    params = dict(info.get("params") or {})
    if isinstance(params.get("range"), list):
        params["range"] = tuple(params["range"])
    model = cls(**params)
    for key, value in arrays.items():
        setattr(model, key, value.item() if value.ndim == 0 else value)
    return model


def _encode(m: CatgraphMap) -> tuple[dict, dict[str, np.ndarray]]:
    arrays: dict[str, np.ndarray] = {"descriptors": m.descriptors}
    for key in ("positions", "floors", "ids"):
        value = getattr(m, key)
        if value is not None:
            arrays[key] = value
    metadata: dict[str, Any] = {"name": m.name, "metric": m.metric, "frontend": m.frontend,
                                "n_places": m.n_places, "meta": m.meta}
    if m.graph is not None:
        g = m.graph
        for key in _GRAPH_ARRAYS:
            arrays[f"graph.{key}"] = getattr(g, key)
        if g.positions is not None:
            arrays["graph.positions"] = g.positions
        metadata["graph"] = {"n_places": g.n_places, "unit": g.unit}
    else:
        metadata["graph"] = None
    metadata["histograms"] = {}
    for name, model in m.histograms.items():
        if "." in name or not name:
            raise MapFileError(f"histogram names must be non-empty and contain no '.'; got {name!r}.")
        info, state = _histogram_state(model)
        info["arrays"] = sorted(state)
        metadata["histograms"][name] = info
        arrays.update({f"histogram.{name}.{k}": v for k, v in state.items()})
    for key, value in arrays.items():
        if value.dtype == object:
            raise MapFileError(f"map array {key!r} holds Python objects; store numbers or strings.")
    return metadata, arrays


def _metadata_bytes(metadata: dict) -> bytes:
    try:
        text = json.dumps(metadata, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise MapFileError(f"map metadata must be JSON-ready (no NaN, no objects): {exc}") from None
    return text.encode("utf-8")


def _digest(version: int, metadata: bytes, arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    h.update(FORMAT_NAME.encode() + b"\0" + str(int(version)).encode() + b"\0")
    h.update(len(metadata).to_bytes(8, "little") + metadata)
    for name in sorted(arrays):
        stored = isinstance(arrays[name], StoredDescriptors)
        a = arrays[name] if stored else np.require(arrays[name], requirements="C")
        header = f"{name}\0{a.dtype.str}\0{a.shape}\0".encode()
        h.update(len(header).to_bytes(8, "little") + header)
        h.update(a.nbytes.to_bytes(8, "little"))
        if stored:  # its bytes block by block, in order: the same digest
            for block in a.blocks():
                h.update(block)
        else:
            h.update(a)  # the array's own buffer (C-contiguous): its bytes without a copy of them
    return h.hexdigest()


def save_map(path: str | os.PathLike, catgraph_map: CatgraphMap, compress: bool = True) -> Path:
    """Write a map atomically to ``path`` (conventionally ``*.npz``).

    Parameters
    ----------
    path : str or PathLike
        Destination; its folder is created if needed. Written exactly under this name
        (no suffix is added).
    catgraph_map : CatgraphMap
    compress : bool
        Deflate the archive members (smaller, slower to write).

    Returns
    -------
    Path
        The path written.
    """
    from ._atomic import check_writable
    from .exceptions import InvalidParameterError

    if not isinstance(catgraph_map, CatgraphMap):
        raise InvalidParameterError(f"save_map writes a CatgraphMap (from build_map); got a "
                                    f"{type(catgraph_map).__name__}.")
    path = check_writable(path, "map file")
    metadata, arrays = _encode(catgraph_map)
    meta_bytes = _metadata_bytes(metadata)
    members = {
        "__format__": np.array(FORMAT_NAME),
        "__version__": np.array(FORMAT_VERSION, dtype=np.int64),
        "__metadata__": np.frombuffer(meta_bytes, dtype=np.uint8),
        "__sha256__": np.array(_digest(FORMAT_VERSION, meta_bytes, arrays)),
    }
    members.update({k: np.require(v, requirements="C") for k, v in arrays.items()})
    with atomic_open(path, "wb") as fh:
        (np.savez_compressed if compress else np.savez)(fh, **members)
    return path


# ---------------------------------------------------------------------------- decoding
class StoredDescriptors(RowSource):
    """A map file's descriptors left in the file and read in row blocks.

    What :func:`load_map` with ``descriptors="stream"`` gives as
    ``CatgraphMap.descriptors``: ``d[a:b]`` reads rows ``a … b − 1`` (consecutive slices
    from one open stream of the archive member: a deflated member is inflated once per
    pass), ``d[rows]`` (row numbers) reads those rows in one pass (:meth:`take`), :meth:`blocks`
    reads every row in order, ``numpy.asarray(d)`` reads them whole.
    Rows are checked finite when first read (a map file whose checksum holds may still
    have been written by other code), so no read hands out a NaN; the first pass over
    them (the checksum's) also takes their range (:meth:`value_range`), so the compact
    layout's code scale needs no pass of its own. The file stays open
    while the descriptors live, so a map file replaced on disk after loading does not
    change what is read; :meth:`close` closes it.

    Attributes
    ----------
    shape : (int, int)
    dtype : numpy.dtype
    path : Path
    """

    #: Rows per block of :meth:`blocks` (4 MiB of float32 at 512 values: the reading's
    #: own scratch stays small beside the map it reads).
    BLOCK_ROWS = 2048

    def __init__(self, fh, path: Path, member: str = "descriptors.npy") -> None:
        self.path = path
        archive = zipfile.ZipFile(fh)
        with archive.open(member) as f:
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0)):
                raise MapFileError(f"{path}: its descriptors are stored as .npy format {version}, which this reader "
                                   "does not stream; load the map whole (descriptors='memory').")
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read(f)
            self._start = f.tell()
        if len(shape) != 2 or fortran or dtype.hasobject:
            raise MapFileError(f"{path} holds descriptors of shape {shape} ({'Fortran' if fortran else 'C'} order, "
                               f"dtype {dtype}), not (N, D) rows in C order as save_map writes them; rebuild it with "
                               "`catgraph build-map`.")
        self.shape, self.dtype = (int(shape[0]), int(shape[1])), np.dtype(dtype)
        self._fh, self._zip, self._member = fh, archive, member  # the file is this reader's from here on
        self._stream, self._row = None, 0
        self._read_rows = 0  # rows 0 … this − 1 read once: checked finite, their range taken
        self._range = None

    @property
    def nbytes(self) -> int:
        return self.shape[0] * self.shape[1] * self.dtype.itemsize

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def _rows(self, a: int, b: int) -> np.ndarray:
        out = np.empty((max(b - a, 0), self.shape[1]), dtype=self.dtype)
        if not out.size:
            return out
        if self._stream is None or a < self._row:  # behind the open stream: open it again, skip to ``a``
            if self._stream is not None:
                self._stream.close()
            self._stream = self._zip.open(self._member)
            self._stream.seek(self._start + a * self.shape[1] * self.dtype.itemsize)
        elif a > self._row:  # ahead of it: the open stream skips the rows between (an archive member is
            # read from its start on every seek of a stream opened again)
            self._stream.seek(self._start + a * self.shape[1] * self.dtype.itemsize)
        view, got = memoryview(out).cast("B"), 0
        while got < len(view):
            n = self._stream.readinto(view[got:])
            if not n:
                raise MapFileError(f"{self.path} is truncated: its descriptors end before row {b}; rebuild it with "
                                   "`catgraph build-map`.")
            got += n
        self._row = b
        if b > self._read_rows:  # rows not read before: checked finite
            from .differences import _check_finite, _value_range

            first = max(a, self._read_rows)
            try:
                _check_finite(out[first - a :], "map descriptors", first_row=first)
            except DataError as exc:
                raise MapFileError(f"{self.path} holds an inconsistent map: {exc}") from None
            if a <= self._read_rows:  # the rows that follow those read in order: their range taken too
                self._range = _value_range([out[first - a :]], self._range)
                self._read_rows = b
        return out

    def value_range(self) -> tuple[float, float, bool] | None:
        """``(smallest, largest, every value a whole number)`` once every row has been read
        (:func:`load_map` reads them all for the checksum), else ``None``."""
        return self._range if self._read_rows == self.shape[0] else None

    def __getitem__(self, key):
        if isinstance(key, slice) and key.step in (None, 1):
            a, b, _ = key.indices(self.shape[0])
            return self._rows(a, max(a, b))
        if isinstance(key, (list, np.ndarray)) and np.asarray(key).dtype.kind in "iu" and np.ndim(key) == 1:
            return self.take(key)  # rows by number: read in one pass, not whole
        return np.asarray(self)[key]

    def __array__(self, dtype=None, copy=None):
        whole = self._rows(0, self.shape[0])
        return whole if dtype is None else whole.astype(dtype, copy=False)

    def blocks(self, rows: int | None = None):
        """Every row in order, ``rows`` (default :data:`BLOCK_ROWS`) at a time."""
        rows = int(rows or self.BLOCK_ROWS)
        for a in range(0, self.shape[0], rows):
            yield self._rows(a, min(a + rows, self.shape[0]))

    def __reduce__(self):
        # a copy or a pickle (a Dask task) carries the values, not the open file
        return (np.asarray, (np.asarray(self),))

    def close(self) -> None:
        """Close the map file (a later read raises ``ValueError``); done when the
        descriptors are garbage-collected too."""
        if self._stream is not None:
            self._stream.close()
        self._zip.close()
        self._fh.close()

    def __del__(self) -> None:
        fh = getattr(self, "_fh", None)  # (a reader whose construction failed holds no file)
        if fh is not None and not fh.closed:
            self.close()

    def __repr__(self) -> str:
        return f"StoredDescriptors({str(self.path)!r}, shape={self.shape}, dtype={self.dtype})"


def _read_members(path: Path, stream: bool = False) -> dict[str, np.ndarray]:
    """The archive's members; ``stream``: the descriptors as a :class:`StoredDescriptors`
    (the file then stays open, held by it)."""
    try:  # the file is opened here so that it is closed even when the archive is unreadable
        fh = open(path, "rb")
    except IsADirectoryError:
        raise MapFileError(f"{path} is a folder, not a map file; give the .npz that `catgraph build-map` wrote.") \
            from None
    kept = False
    try:
        members = _read_open_members(fh, path, skip=("descriptors",) if stream else ())
        names = members.pop("__names__")  # (the archive's members, those skipped too)
        if stream and "descriptors" in names:
            try:
                members["descriptors"] = StoredDescriptors(fh, path)
            except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
                raise MapFileError(f"{path} is corrupt or truncated ({exc}); rebuild it with `catgraph build-map`.") \
                    from None
            kept = True
        return members
    finally:
        if not kept:
            fh.close()


def _read_open_members(fh, path: Path, skip: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    from .datasets.loaders import numpy_file_kind

    kind = numpy_file_kind(fh)
    if kind != "npz":
        raise MapFileError(f"{path} is not a catgraph map: " + ("it holds a single array (.npy)" if kind == "npy" else
                           "it is not a .npz archive") + "; build one with `catgraph build-map`.")
    try:
        archive = np.load(fh, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise MapFileError(f"{path} is not a readable map file (corrupt or truncated: {exc}); "
                           "rebuild it with `catgraph build-map`.") from None
    if isinstance(archive, np.ndarray):
        raise MapFileError(f"{path} holds a single array, not a catgraph map; build one with `catgraph build-map`.")
    try:
        with archive:
            names = list(archive.files)
            if "__format__" not in names:
                raise MapFileError(f"{path} is not a catgraph map (it holds arrays {sorted(names)[:8]}); "
                                   "build one with `catgraph build-map`.")
            return {"__names__": names, **{name: archive[name] for name in names if name not in skip}}
    except MapFileError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise MapFileError(f"{path} contains pickled objects, which catgraph never loads; "
                               "it was not written by catgraph.") from None
        raise MapFileError(f"{path} is corrupt ({exc}); rebuild it with `catgraph build-map`.") from None
    except (OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, KeyError) as exc:
        raise MapFileError(f"{path} is corrupt or truncated ({exc}); rebuild it with `catgraph build-map`.") from None


def _scalar(members: dict, name: str, path: Path, kind: str):
    value = members.get(name)
    if value is None or value.ndim != 0 or value.dtype.kind != kind:
        raise MapFileError(f"{path} has a malformed {name} entry; it was not written by catgraph or is damaged.")
    return value.item()


def load_map(path: str | os.PathLike, descriptors: str = "memory", graph: bool = True) -> CatgraphMap:
    """Read a map written by :func:`save_map`, checking format, version and checksum.

    Parameters
    ----------
    path : str or PathLike
    descriptors : {"memory", "stream"}
        ``"memory"``: the descriptors are read into memory. ``"stream"``: they stay in the
        file, read in row blocks where they are used (:class:`StoredDescriptors`; the
        checksum and their finiteness are checked reading them once on load) — for
        :class:`catgraph.live.LiveMap` with ``layout="uint8"``, which codes them block by
        block and so never holds the float map.
    graph : bool
        ``False``: the place graph's arrays are checked (the checksum) but no graph is
        built (``CatgraphMap.graph`` is ``None``, as for a map built with ``--no-graph``):
        for matching alone, which never reads it (a cluster run's client,
        :func:`catgraph.experiment.run_on_cluster`). Saved again, such a map has no graph.

    Raises
    ------
    DataNotFoundError
        ``path`` does not exist.
    MapFileError
        The file is not a map, is corrupt, truncated or modified since it was written,
        or was written by a newer catgraph.
    """
    from .exceptions import InvalidParameterError

    if descriptors not in ("memory", "stream"):
        raise InvalidParameterError(f"The 'descriptors' parameter of load_map must be 'memory' or 'stream'. "
                                    f"Got {descriptors!r} instead.")
    path = Path(path)
    if not path.exists():
        raise DataNotFoundError(f"map file {path} does not exist; build one with `catgraph build-map REFERENCE "
                                f"--out {path.name}`.")
    if path.is_dir():
        raise MapFileError(f"{path} is a folder, not a map file.")
    members = _read_members(path, stream=descriptors == "stream")
    stored = members.get("descriptors")
    try:
        return _load_members(members, path, graph=bool(graph))
    except BaseException:
        if isinstance(stored, StoredDescriptors):
            stored.close()
        raise


def _load_members(members: dict, path: Path, graph: bool = True) -> CatgraphMap:
    fmt = _scalar(members, "__format__", path, "U")
    if fmt != FORMAT_NAME:
        raise MapFileError(f"{path} is a {fmt!r} file, not a catgraph map.")
    version = _scalar(members, "__version__", path, "i")
    if version > FORMAT_VERSION:
        raise MapFileError(f"{path} was written by a newer catgraph (format {version} > {FORMAT_VERSION}); "
                           "upgrade catgraph to read it.")
    if version < 1:
        raise MapFileError(f"{path} has an invalid format version {version}.")
    meta_raw = members.get("__metadata__")
    if meta_raw is None or meta_raw.dtype != np.uint8 or meta_raw.ndim != 1:
        raise MapFileError(f"{path} has no readable metadata; it is damaged.")
    meta_bytes = meta_raw.tobytes()
    stored = _scalar(members, "__sha256__", path, "U")
    arrays = {k: v for k, v in members.items() if k not in _RESERVED}
    if _digest(version, meta_bytes, arrays) != stored:
        raise MapFileError(f"{path} failed its checksum: the arrays or metadata were modified after it was written "
                           "(tampered or corrupted); rebuild it with `catgraph build-map`.")
    try:
        metadata = json.loads(meta_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapFileError(f"{path} has unreadable metadata ({exc}).") from None
    if not graph:  # checked with the rest, then dropped
        arrays = {k: v for k, v in arrays.items() if not k.startswith("graph.")}
        metadata = {**metadata, "graph": None}
    return _decode(metadata, arrays, path)


def _decode(metadata: dict, arrays: dict[str, np.ndarray], path: Path) -> CatgraphMap:
    if not isinstance(metadata, dict) or not isinstance(metadata.get("meta") or {}, dict):
        raise MapFileError(f"{path} holds an inconsistent map: its metadata is not a settings table; rebuild it with "
                           "`catgraph build-map`.")
    kind = (metadata.get("meta") or {}).get("kind")
    if kind is not None and kind not in ("images", "wifi", "descriptors"):
        raise MapFileError(f"{path} holds an inconsistent map: data kind {kind!r} is not images, wifi or descriptors; "
                           "rebuild it with `catgraph build-map`.")
    try:
        graph = None
        if metadata.get("graph") is not None:
            from .graph import PlaceGraph

            g = {k: arrays[f"graph.{k}"] for k in _GRAPH_ARRAYS}
            graph = PlaceGraph.from_edges(
                int(metadata["graph"]["n_places"]), np.stack([g["source"], g["target"]], axis=1).reshape(-1, 2),
                g["length"], g["kind"], positions=arrays.get("graph.positions"),
                route_distance=g["route_distance"], unit=metadata["graph"]["unit"],
            )
            # the saved lengths exactly: from_edges floors them at 1e-6 times their mean, and the
            # mean of lengths floored once is a little larger (a floor that moved on every reload)
            same = all(np.array_equal(getattr(graph, k), g[k]) for k in ("source", "target", "kind"))
            if same and np.all(np.isfinite(g["length"])) and np.all(g["length"] > 0):
                object.__setattr__(graph, "length", np.array(g["length"], dtype=np.float64))
        histograms = {}
        for name, info in (metadata.get("histograms") or {}).items():
            state = {k: arrays[f"histogram.{name}.{k}"] for k in info.get("arrays", [])}
            histograms[name] = _histogram_from_state(info, state, name)
        if not isinstance(metadata["frontend"], dict) or not isinstance(metadata["metric"], str):
            raise MapFileError(f"{path} holds an inconsistent map: its front-end settings or metric are not those "
                               "of a map (a settings table and a metric name); rebuild it with `catgraph build-map`.")
        the_map = CatgraphMap(arrays["descriptors"], metadata["metric"], metadata["frontend"], graph,
                              arrays.get("positions"), arrays.get("floors"), arrays.get("ids"), histograms,
                              metadata.get("name", ""), metadata.get("meta") or {})
        the_map.frontend_settings()  # a map whose settings make no front-end could describe no query
        return the_map
    except MapFileError:
        raise
    except KeyError as exc:
        raise MapFileError(f"{path} lacks the entry {exc}; it is incomplete.") from None
    except (DataError, TypeError, ValueError) as exc:
        raise MapFileError(f"{path} holds an inconsistent map: {exc}") from None
