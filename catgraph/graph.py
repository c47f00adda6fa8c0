"""Topological place graph: built with networkx, compiled to flat arrays.

A *place graph* is the map the particle filter lives on. Its nodes are the reference
places ``0 .. N-1`` (one per reference frame), optionally with a metric position
(metres) and a distance along the route. Its directed edges carry a length: metres
where the reference has odometry or positions, otherwise one unit per frame.

Building
--------
:meth:`PlaceGraph.from_traverse` makes the route a chain ``0 → 1 → … → N-1`` and adds

* *reverse* chain edges ``i+1 → i`` when ``bidirectional=True`` (the default), so a query
  may drive a street in the other direction. A particle's direction of travel is simply
  the direction of the edge it is on; no separate direction state is needed;
* *junction* edges, both ways, between places of different parts of the route that are
  the same physical place: pairs the user gives, or pairs found from positions — places
  within ``junction_radius_m`` metres of each other whose distance along the route is
  larger than ``junction_exclusion_m`` (route neighbours are not junctions), kept only
  when they are mutual nearest candidates (one edge per crossing, not a clique).

Edge lengths: ``edge_length="auto"`` uses cumulative odometry if the traverse has it, else
the Euclidean distance between consecutive positions, else 1 per frame. A junction edge
gets the distance between its two places (1 per frame graphs: ``0``). Lengths are floored
at ``1e-6`` times the mean chain length so that no motion step loops forever on zero-length
edges (repeated samples at one position, as in Wi-Fi fingerprints).

networkx is the exchange format: :meth:`PlaceGraph.to_networkx` /
:meth:`PlaceGraph.from_networkx`, and :meth:`PlaceGraph.save` / :func:`load_graph` write and
read node-link JSON or GraphML.

Compiled form
-------------
The hot loop never touches networkx. Edges are sorted by source into CSR arrays::

    source, target, length : (E,)      edge e goes source[e] → target[e]
    out_ptr               : (N+1,)    out-edges of node v are edges out_ptr[v]:out_ptr[v+1]
    reverse               : (E,)      the edge target[e] → source[e], or -1
    straight              : (E,)      the route's continuation after e (same direction), or -1

``straight`` is what the motion model's continue-straight preference picks: after the
chain edge ``i → i+1`` it is ``i+1 → i+2``, after ``i → i-1`` it is ``i-1 → i-2``; after a
junction edge there is none.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ._validation import check_array, check_scalar
from .exceptions import DataError, InvalidParameterError, MapFileError

__all__ = ["PlaceGraph", "load_graph", "EDGE_KINDS"]

#: Edge kinds, by code: 0 chain (route order), 1 reverse chain, 2 junction.
EDGE_KINDS = ("chain", "reverse", "junction")
_CHAIN, _REVERSE, _JUNCTION = 0, 1, 2


def _kind_codes(kinds: Any) -> np.ndarray:
    """Edge kinds as int8 codes: integer codes as given (an array of them without a loop:
    the constructors' and a saved map's), names looked up in :data:`EDGE_KINDS`; a
    :class:`DataError` for an unknown name or a code outside them."""
    codes = np.asarray(kinds)
    if codes.dtype.kind not in "iu":
        names = [k for k in kinds if isinstance(k, str) and k not in EDGE_KINDS]
        if names:
            raise DataError(f"edge kind {names[0]!r} is not one of {EDGE_KINDS}.")
        codes = np.array([EDGE_KINDS.index(k) if isinstance(k, str) else int(k) for k in kinds])
    if codes.size and (codes.min() < 0 or codes.max() >= len(EDGE_KINDS)):
        raise DataError(f"edge kinds must be one per edge, each one of {EDGE_KINDS}.")
    return codes.reshape(-1).astype(np.int8)


def _edge_tables(n_places: int, src: np.ndarray, dst: np.ndarray, kind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``reverse`` and ``straight`` (see :class:`PlaceGraph`) of distinct edges ``src → dst``.

    Each edge is looked up by its key ``source · N + target`` among the sorted keys
    (``O(E log E)``, no Python loop over the edges; keys are exact in int64 up to about
    3·10⁹ places). ``straight`` of a chain or reverse-chain edge ``a → b`` is the edge
    ``b → 2b − a`` where that is an edge of the same kind (a junction is not the route)."""
    n = np.int64(n_places)
    keys = src * n + dst
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]

    def find(a: np.ndarray, b: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """The index of edge ``a → b`` where ``valid`` and it exists, else -1."""
        wanted = np.where(valid, a * n + b, -1)
        at = np.minimum(np.searchsorted(sorted_keys, wanted), max(len(keys) - 1, 0))  # (no edges: none wanted)
        return np.where(valid & (sorted_keys[at] == wanted), order[at], -1)

    reverse = find(dst, src, np.ones(len(src), dtype=bool))
    ahead = 2 * dst - src
    route = ((kind == _CHAIN) | (kind == _REVERSE)) & (ahead >= 0) & (ahead < n)
    nxt = find(dst, ahead, route)
    straight = np.where((nxt >= 0) & (kind[np.maximum(nxt, 0)] == kind), nxt, -1).astype(np.int64)
    return reverse, straight


@dataclass(frozen=True, eq=False)
class PlaceGraph:
    """A directed place graph, compiled to CSR arrays.

    Use the constructors :meth:`from_traverse`, :meth:`from_edges` or
    :meth:`from_networkx` rather than building the arrays by hand.

    Attributes
    ----------
    n_places : int
        Number of places ``N`` (nodes ``0 .. N-1``).
    source, target : ndarray of int64, shape (E,)
        Edge end points, sorted by source.
    length : ndarray of float64, shape (E,)
        Edge lengths (``unit``), all positive.
    kind : ndarray of int8, shape (E,)
        Codes into :data:`EDGE_KINDS`.
    out_ptr : ndarray of int64, shape (N+1,)
        CSR offsets: the out-edges of node ``v`` are ``out_ptr[v]:out_ptr[v+1]``.
    reverse : ndarray of int64, shape (E,)
        Index of the opposite edge, or ``-1`` (formed on first use, as ``straight``:
        only the particle filter's motion reads them).
    straight : ndarray of int64, shape (E,)
        Index of the route continuation after each edge, or ``-1``.
    positions : ndarray of float64, shape (N, 2|3) or None
        Metric positions of the places.
    route_distance : ndarray of float64, shape (N,)
        Distance along the route from place 0 (``unit``).
    unit : str
        ``"m"`` or ``"frame"``.
    """

    n_places: int
    source: np.ndarray
    target: np.ndarray
    length: np.ndarray
    kind: np.ndarray
    out_ptr: np.ndarray
    positions: np.ndarray | None
    route_distance: np.ndarray
    unit: str = "frame"

    # ------------------------------------------------------------------ building
    @classmethod
    def from_edges(
        cls,
        n_places: int,
        edges: Any,
        lengths: Any = None,
        kinds: Any = None,
        positions: Any = None,
        route_distance: Any = None,
        unit: str = "frame",
    ) -> "PlaceGraph":
        """Compile a graph from an edge list.

        Parameters
        ----------
        n_places : int
            Number of places.
        edges : array-like of int, shape (E, 2)
            Directed ``(source, target)`` pairs; duplicates keep the first.
        lengths : array-like of float, shape (E,), optional
            Edge lengths (default 1).
        kinds : array-like, shape (E,), optional
            Edge kinds: codes or names from :data:`EDGE_KINDS` (default ``"chain"``).
        positions : array-like, shape (N, 2|3), optional
        route_distance : array-like, shape (N,), optional
            Defaults to the place index (times the mean edge length).
        unit : {"m", "frame"}

        Returns
        -------
        PlaceGraph
        """
        check_scalar(n_places, "n_places", "PlaceGraph", int, 1)
        e = np.asarray(edges)
        if e.size == 0:
            e = np.zeros((0, 2), dtype=np.int64)
        if e.ndim != 2 or e.shape[1] != 2 or e.dtype.kind not in "iu":
            raise DataError(f"edges must be an integer array of shape (E, 2); got shape {e.shape} and dtype {e.dtype}.")
        e = e.astype(np.int64)
        if e.size and (e.min() < 0 or e.max() >= n_places):
            raise DataError(f"edges name places outside 0..{n_places - 1}; give place indices of the reference.")
        if np.any(e[:, 0] == e[:, 1]):
            raise DataError("edges contain self-loops (source == target); remove them.")
        n_edges = len(e)
        ln = np.ones(n_edges) if lengths is None else check_array(lengths, "edge lengths", ndim=1, allow_empty=True)
        if len(ln) != n_edges:
            raise DataError(f"{len(ln)} edge lengths given for {n_edges} edges; give one per edge.")
        if np.any(ln < 0):
            raise DataError("edge lengths must be non-negative.")
        if kinds is None:
            kd = np.zeros(n_edges, dtype=np.int8)
        else:
            kd = _kind_codes(kinds)
            if len(kd) != n_edges:
                raise DataError(f"edge kinds must be one per edge, each one of {EDGE_KINDS}.")
        if unit not in ("m", "frame"):
            raise InvalidParameterError(f"The 'unit' parameter of PlaceGraph must be 'm' or 'frame'. Got {unit!r} instead.")
        # drop duplicate (source, target) pairs, keep the first
        if n_edges:
            _, first = np.unique(e[:, 0] * n_places + e[:, 1], return_index=True)
            first.sort()
            e, ln, kd = e[first], ln[first], kd[first]
        chain_lengths = ln[kd == _CHAIN]
        scale = float(chain_lengths.mean()) if chain_lengths.size and chain_lengths.mean() > 0 else 1.0
        ln = np.maximum(ln, 1e-6 * scale)
        order = np.lexsort((kd, e[:, 0]))  # by source, chain edges first
        e, ln, kd = e[order], ln[order], kd[order]
        src, dst = e[:, 0].copy(), e[:, 1].copy()
        out_ptr = np.zeros(n_places + 1, dtype=np.int64)
        np.cumsum(np.bincount(src, minlength=n_places), out=out_ptr[1:])
        pos = None
        if positions is not None:
            pos = check_array(positions, "place positions", ndim=2)
            if len(pos) != n_places:
                raise DataError(f"{len(pos)} positions given for {n_places} places; give one per place.")
            if pos.shape[1] not in (2, 3):
                raise DataError(f"place positions have {pos.shape[1]} coordinates; give (x, y) or (x, y, z) per place.")
        if route_distance is None:
            rd = np.arange(n_places, dtype=np.float64) * scale
        else:
            rd = check_array(route_distance, "route distance", ndim=1)
            if len(rd) != n_places:
                raise DataError(f"{len(rd)} route distances given for {n_places} places; give one per place.")
        return cls(n_places, src, dst, ln, kd, out_ptr, pos, rd, unit)

    @classmethod
    def chain(cls, n_places: int, bidirectional: bool = True, spacing: float = 1.0) -> "PlaceGraph":
        """A plain route ``0 → 1 → … → N-1`` with edges of length ``spacing``."""
        check_scalar(n_places, "n_places", "PlaceGraph.chain", int, 1)
        check_scalar(spacing, "spacing", "PlaceGraph.chain", float, 0.0, low_inclusive=False)
        i = np.arange(n_places - 1)
        edges = [np.stack([i, i + 1], 1)]
        kinds = [np.full(len(i), _CHAIN)]
        if bidirectional:
            edges.append(np.stack([i + 1, i], 1))
            kinds.append(np.full(len(i), _REVERSE))
        e = np.concatenate(edges).astype(np.int64)
        return cls.from_edges(
            n_places, e, np.full(len(e), float(spacing)), np.concatenate(kinds),
            route_distance=np.arange(n_places) * float(spacing), unit="frame" if spacing == 1.0 else "m",
        )

    @classmethod
    def from_traverse(
        cls,
        traverse: Any,
        junctions: Iterable[tuple[int, int]] | np.ndarray | None = None,
        junction_radius_m: float | None = None,
        bidirectional: bool = True,
        edge_length: str = "auto",
        junction_exclusion_m: float | None = None,
    ) -> "PlaceGraph":
        """Build the map of a reference traverse: a chain plus junction edges.

        Parameters
        ----------
        traverse : Traverse
            The reference; its ``positions`` and ``odometry`` are used where present.
        junctions : array-like of int, shape (J, 2), optional
            Pairs of places that are the same physical place (added both ways).
        junction_radius_m : float, optional
            Also find junctions from positions: places within this many metres (on the
            same floor, where the traverse has floors).
        bidirectional : bool
            Add reverse chain edges so particles may travel the route backwards.
        edge_length : {"auto", "odometry", "positions", "frames"}
            Where chain lengths come from (see the module docstring).
        junction_exclusion_m : float, optional
            Pairs closer than this *along the route* are route neighbours, not junctions
            (default ``3 * junction_radius_m``).

        Returns
        -------
        PlaceGraph
        """
        n = len(traverse)
        positions = getattr(traverse, "positions", None)
        odometry = getattr(traverse, "odometry", None)
        if edge_length not in ("auto", "odometry", "positions", "frames"):
            raise InvalidParameterError(
                "The 'edge_length' parameter of PlaceGraph.from_traverse must be one of "
                f"'auto', 'odometry', 'positions', 'frames'. Got {edge_length!r} instead."
            )
        mode = edge_length
        if mode == "auto":
            mode = "odometry" if odometry is not None else "positions" if positions is not None else "frames"
        if mode == "odometry":
            if odometry is None:
                raise DataError("edge_length='odometry' needs a reference traverse with odometry.")
            step = np.asarray(odometry, dtype=np.float64)[1:]
        elif mode == "positions":
            if positions is None:
                raise DataError("edge_length='positions' needs a reference traverse with positions.")
            step = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        else:
            step = np.ones(n - 1)
        unit = "frame" if mode == "frames" else "m"
        route = np.concatenate([[0.0], np.cumsum(step)])
        i = np.arange(n - 1)
        edges = [np.stack([i, i + 1], 1)]
        lengths = [step]
        kinds = [np.full(n - 1, _CHAIN)]
        if bidirectional:
            edges.append(np.stack([i + 1, i], 1))
            lengths.append(step)
            kinds.append(np.full(n - 1, _REVERSE))
        pairs = []
        if junctions is not None:
            j = np.asarray(junctions)
            if j.size:
                if j.ndim != 2 or j.shape[1] != 2 or j.dtype.kind not in "iu":
                    raise DataError(f"junctions must be integer pairs of shape (J, 2); got shape {j.shape}.")
                if j.min() < 0 or j.max() >= n:
                    raise DataError(f"junctions name places outside 0..{n - 1}.")
                pairs.append(j.astype(np.int64))
        if junction_radius_m is not None:
            check_scalar(junction_radius_m, "junction_radius_m", "PlaceGraph.from_traverse", float, 0.0, low_inclusive=False)
            if positions is None:
                raise DataError("junction_radius_m needs positions in the reference traverse; give junctions explicitly.")
            if junction_exclusion_m is not None:
                check_scalar(junction_exclusion_m, "junction_exclusion_m", "PlaceGraph.from_traverse", float, 0.0)
            exclusion = 3.0 * junction_radius_m if junction_exclusion_m is None else float(junction_exclusion_m)
            route_m = route if unit == "m" else np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
            pairs.append(_find_junctions(np.asarray(positions), route_m, junction_radius_m, exclusion,
                                         getattr(traverse, "floors", None)))
        if pairs:
            jp = np.unique(np.sort(np.concatenate(pairs), axis=1), axis=0)
            jp = jp[jp[:, 0] != jp[:, 1]]
            if unit == "m" and positions is not None:
                jl = np.linalg.norm(positions[jp[:, 0]] - positions[jp[:, 1]], axis=1)
            else:
                jl = np.zeros(len(jp))
            edges += [jp, jp[:, ::-1]]
            lengths += [jl, jl]
            kinds += [np.full(len(jp), _JUNCTION)] * 2
        return cls.from_edges(
            n, np.concatenate(edges).astype(np.int64), np.concatenate(lengths), np.concatenate(kinds),
            positions=positions, route_distance=route, unit=unit,
        )

    # ------------------------------------------------------------------ queries
    @property
    def reverse(self) -> np.ndarray:
        """``(E,)`` index of the opposite edge, or -1."""
        return self._edge_tables()[0]

    @property
    def straight(self) -> np.ndarray:
        """``(E,)`` index of the route's continuation after each edge, or -1."""
        return self._edge_tables()[1]

    def _edge_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """``(reverse, straight)``, formed on first use and kept: only the particle
        filter's motion reads them, so a graph the grid filter runs on never holds them
        (``2 E`` int64: 3 MiB at 10⁵ places)."""
        cached = self.__dict__.get("_tables")
        if cached is None:
            cached = _edge_tables(self.n_places, self.source, self.target, self.kind)
            object.__setattr__(self, "_tables", cached)
        return cached

    @property
    def frame_spacing(self) -> float:
        """Mean length of the chain edges (1 on a frame graph): one frame's travel."""
        cached = self.__dict__.get("_frame_spacing")
        if cached is None:
            chain = self.length[self.kind == _CHAIN]
            cached = float(chain.mean()) if chain.size else 1.0
            object.__setattr__(self, "_frame_spacing", cached)
        return cached

    @property
    def hop_length(self) -> np.ndarray:
        """``(E,)`` edge lengths in *places*: 1 for every edge, as the grid filter moves
        its mass one place per hop (a junction edge included). Motion without odometry
        counts places with these, whatever the metres between them: a metric route
        surveyed several times at one point (Wi-Fi) has many zero-length chain edges,
        and a query that advances one sample per frame advances one place, not one
        mean spacing in metres."""
        cached = self.__dict__.get("_hop_length")
        if cached is None:
            cached = np.ones(self.n_edges)
            cached.setflags(write=False)
            object.__setattr__(self, "_hop_length", cached)
        return cached

    @property
    def n_edges(self) -> int:
        """Number of directed edges ``E``."""
        return int(len(self.source))

    def out_edges(self, place: int) -> np.ndarray:
        """Indices of the edges leaving ``place``."""
        return np.arange(self.out_ptr[place], self.out_ptr[place + 1])

    def junction_pairs(self) -> np.ndarray:
        """``(J, 2)`` sorted place pairs joined by junction edges."""
        m = self.kind == _JUNCTION
        p = np.sort(np.stack([self.source[m], self.target[m]], 1), axis=1)
        return np.unique(p, axis=0) if len(p) else p.reshape(0, 2)

    def __repr__(self) -> str:
        return (
            f"PlaceGraph(n_places={self.n_places}, n_edges={self.n_edges}, "
            f"junctions={len(self.junction_pairs())}, unit={self.unit!r}, positions={self.positions is not None})"
        )

    # ------------------------------------------------------------------ networkx and files
    def to_networkx(self):
        """A ``networkx.DiGraph``: node attributes ``route_distance`` (and ``x``, ``y``
        [, ``z``]), edge attributes ``length`` and ``kind``; graph attribute ``unit``."""
        import networkx as nx

        g = nx.DiGraph(unit=self.unit)
        for v in range(self.n_places):
            attrs = {"route_distance": float(self.route_distance[v])}
            if self.positions is not None:
                attrs.update({c: float(x) for c, x in zip("xyz", self.positions[v])})
            g.add_node(v, **attrs)
        for a, b, ln, k in zip(self.source, self.target, self.length, self.kind):
            g.add_edge(int(a), int(b), length=float(ln), kind=EDGE_KINDS[k])
        return g

    @classmethod
    def from_networkx(cls, g) -> "PlaceGraph":
        """Compile a ``networkx`` (Di)Graph whose nodes are ``0 .. N-1``.

        An undirected graph gets both directions of every edge. Missing attributes get
        defaults (length 1, kind ``"chain"``, no positions).
        """
        nodes = sorted(g.nodes)
        n = len(nodes)
        if n == 0 or nodes != list(range(n)):
            raise MapFileError("a place graph's nodes must be the integers 0 .. N-1 (reference frame indices).")
        directed = g.is_directed()
        edges, lengths, kinds = [], [], []
        for a, b, data in g.edges(data=True):
            pairs = [(a, b)] if directed else [(a, b), (b, a)]
            for s, t in pairs:
                edges.append((int(s), int(t)))
                length = data.get("length", 1.0)
                try:
                    lengths.append(float(length))
                except (TypeError, ValueError):
                    raise MapFileError(f"the place graph's edge {s} → {t} has length {length!r}; an edge length "
                                       "must be a number (graph units).") from None
                kinds.append(data.get("kind", "chain"))
        has_xy = all("x" in g.nodes[v] and "y" in g.nodes[v] for v in nodes)
        positions = None
        rd = None
        try:
            if has_xy:
                cols = "xyz" if all("z" in g.nodes[v] for v in nodes) else "xy"
                positions = np.array([[g.nodes[v][c] for c in cols] for v in nodes], dtype=np.float64)
            if all("route_distance" in g.nodes[v] for v in nodes):
                rd = np.array([g.nodes[v]["route_distance"] for v in nodes], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise MapFileError(f"the place graph's node positions or route distances are not numbers: {exc}") from None
        try:
            return cls.from_edges(
                n, np.array(edges, dtype=np.int64).reshape(-1, 2), np.array(lengths), kinds,
                positions=positions, route_distance=rd, unit=g.graph.get("unit", "frame"),
            )
        except (DataError, InvalidParameterError) as exc:
            raise MapFileError(f"the place graph could not be compiled: {exc}") from None

    def save(self, path: str | PathLike) -> None:
        """Write node-link JSON (``.json``) or GraphML (``.graphml``)."""
        import networkx as nx

        p = Path(path)
        g = self.to_networkx()
        if p.suffix == ".json":
            p.write_text(json.dumps(nx.node_link_data(g, edges="links")))
        elif p.suffix == ".graphml":
            nx.write_graphml(g, p)
        else:
            raise InvalidParameterError(f"a place graph is saved as .json or .graphml; got {p.name!r}.")


def load_graph(path: str | PathLike) -> PlaceGraph:
    """Read a place graph written by :meth:`PlaceGraph.save` (node-link JSON or GraphML)."""
    import networkx as nx

    p = Path(path)
    if not p.exists():
        from .exceptions import DataNotFoundError

        raise DataNotFoundError(f"no place graph at {str(p)!r}.")
    try:
        if p.suffix == ".json":
            g = nx.node_link_graph(json.loads(p.read_text()), edges="links")
        elif p.suffix == ".graphml":
            g = nx.read_graphml(p, node_type=int)
        else:
            raise InvalidParameterError(f"a place graph is read from .json or .graphml; got {p.name!r}.")
    except (ValueError, KeyError, TypeError) as exc:
        if isinstance(exc, InvalidParameterError):
            raise
        raise MapFileError(f"{str(p)!r} is not a readable place graph: {exc}") from None
    return PlaceGraph.from_networkx(g)


def _find_junctions(positions: np.ndarray, route: np.ndarray, radius: float, exclusion: float,
                    floors: np.ndarray | None = None) -> np.ndarray:
    """Mutual-nearest place pairs within ``radius`` metres, on the same floor where
    ``floors`` are given, and further than ``exclusion`` apart along the route (among
    equally near places, the one of the smallest index). Returns ``(J, 2)`` int64."""
    from scipy.spatial import cKDTree

    tree = cKDTree(positions)
    cand = tree.query_pairs(radius, output_type="ndarray")
    if len(cand) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    keep = np.abs(route[cand[:, 0]] - route[cand[:, 1]]) > exclusion
    if floors is not None:  # two floors of a building, one above the other, are not one place
        floors = np.asarray(floors)
        keep &= floors[cand[:, 0]] == floors[cand[:, 1]]
    cand = cand[keep]
    if len(cand) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dist = np.linalg.norm(positions[cand[:, 0]] - positions[cand[:, 1]], axis=1)
    n = len(positions)
    both = np.concatenate([cand, cand[:, ::-1]])
    dd = np.concatenate([dist, dist])
    order = np.lexsort((both[:, 1], dd, both[:, 0]))  # by place, then distance, then the partner's index
    first = np.ones(len(order), dtype=bool)
    first[1:] = both[order[1:], 0] != both[order[:-1], 0]
    nearest = np.full(n, -1)
    nearest[both[order[first], 0]] = both[order[first], 1]
    mutual = (nearest[cand[:, 0]] == cand[:, 1]) & (nearest[cand[:, 1]] == cand[:, 0])
    return cand[mutual].astype(np.int64)
