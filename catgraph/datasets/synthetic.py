"""A seeded synthetic world: city blocks, two drives, day and night.

:func:`make_world` builds, from one seed, everything a localisation experiment needs —
a road network, a reference traverse, a query traverse and their ground truth — in a
fraction of a second, so that the demo and most tests run without real data.

Road network
    A grid of ``blocks = (bx, by)`` square blocks of side ``block_length`` metres, i.e.
    ``(bx + 1) × (by + 1)`` intersections at ``(i·L, j·L)``, plus ``new_place_blocks``
    extra columns of blocks to the east: the *new district*, which the reference never
    drives. It is a :class:`networkx.Graph` (``world.roads``): node ids are ints with
    attributes ``pos`` (metres) and ``grid`` ``(i, j)``; edges carry ``length`` (m),
    ``street`` (an int id) and ``mapped`` (driven by the reference).

Routes and frames
    The *reference route* is a greedy covering walk over the mapped streets: from the
    current intersection it takes a random street not yet driven, and when none is left
    it drives the shortest way to the nearest intersection that still has one. Every
    mapped street is driven at least once, some twice (the way a survey car covers a
    district). The *query route* cuts the reference route into chunks of
    ``chunk_streets`` consecutive streets, keeps a fraction ``query_coverage`` of them,
    shuffles their order, drives a fraction ``reverse_fraction`` of them in the opposite
    direction and links consecutive chunks by shortest paths over mapped streets. When
    ``new_place_blocks > 0`` it also makes one excursion into the new district
    (``(2·new_place_blocks + 1)·L`` metres: out, across one block, back).
    Frames are sampled along each route at *variable* spacing: arc-length increments
    are drawn i.i.d. uniform in ``spacing`` (metres), one per frame.

Appearance (descriptors)
    A frame at position ``p`` with unit heading ``h`` sees three things: the street
    itself (road, skyline — the same in either direction) at ``p``, and the façades on
    its left and right, at ``q_L = p + w·left(h)`` and ``q_R = p + w·right(h)`` with
    ``w = street_half_width``. Each is a smooth random field built from random Fourier
    features (Rahimi & Recht 2007),

    ``φ(x) = sqrt(2/F) · cos(Ω x + b)``,   ``Ω_f ~ N(0, I/ℓ²)``,  ``b_f ~ U[0, 2π)``,

    whose linear read-out ``φ(x) W`` (``W`` i.i.d. N(0, 1)) is, per output dimension, a
    sample of a Gaussian process with squared-exponential covariance of length scale
    ``ℓ = length_scale`` and unit variance. A façade is a mix of a unique field and a
    *periodic* one whose frequencies are integer multiples of ``2π/L`` — every block
    has the same façade pattern, the perceptual aliasing of repeated city blocks —
    weighted ``sqrt(1 − a)`` and ``sqrt(a)`` with ``a = aliasing``. The descriptor is

    ``x = sqrt(1 − v)·φ_C(p) W_C + sqrt(v/2)·(φ_F(q_L) W_L + φ_F(q_R) W_R)``

    with ``v = direction_weight``. Driving a street the other way swaps which façade is
    seen through ``W_L`` and which through ``W_R``, so the same place looks different
    in the two directions but still shares the ``φ_C`` part.

Condition change (query only: day → night)
    ``x' = c·M x + o + ε``: a fixed random mixing ``M ∝ (1 − m) I + m G/√d`` (``G``
    i.i.d. N(0, 1), ``m = night_mixing``, scaled to keep the mean squared norm), lower
    contrast ``c = night_contrast``, a fixed offset ``o ~ N(0, night_offset²)`` per dimension and i.i.d.
    noise ``ε ~ N(0, query_noise²)``. The reference gets i.i.d. ``N(0,
    reference_noise²)`` noise only.

Images (``as_images=True``)
    The same fields are read out by matrices whose columns are spatially smooth
    ``h × w`` patterns (white noise blurred over the pixel grid): the left façade in
    the left of the image, the right façade in the right, the street in the middle,
    over a fixed sky-to-road brightness gradient. Night images are darker, have less
    contrast, a headlight glow at the bottom centre, are softer (``M`` is a blend
    ``(1 − m)·x + m·blur(x)`` of the image with a Gaussian-blurred copy, σ = 1.5 px)
    and have pixel noise; both are ``uint8`` ``(n, h, w)``.

Odometry and ground truth
    ``odometry[k]`` is the distance driven since frame ``k − 1`` (0 for the first
    frame): exact for the reference, ``d·(1 + N(0, σ_m²)) + N(0, σ_a²)`` clipped at 0
    for the query. Ground truth is metric: a match is correct within ``tolerance_m``
    metres (:meth:`SyntheticWorld.ground_truth`). Query frames farther than the
    tolerance from every mapped street are flagged ``query.meta["new_place"]``; they
    have no true match.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from .._validation import as_generator, check_scalar
from ..exceptions import InvalidParameterError
from ..traverse import MetricTolerance, Traverse

__all__ = ["SyntheticWorld", "make_world"]

#: ``query.meta["section"]`` codes other than chunk numbers (chunks are 0, 1, …).
CONNECTOR = -1
NEW_PLACE = -2

# tuned so that single-frame nearest-neighbour matching is right about half the time
_DEFAULT_QUERY_NOISE = 1.8
_DEFAULT_QUERY_NOISE_IMAGES = 0.6


# --------------------------------------------------------------------------------------
# world container
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SyntheticWorld:
    """A seeded synthetic world (see the module docstring for the model).

    Attributes
    ----------
    roads : networkx.Graph
        Intersections (int ids; ``pos`` in metres, ``grid`` ``(i, j)``) and streets
        (``length`` m, ``street`` id, ``mapped`` bool).
    reference : Traverse
        Day drive covering every mapped street. ``frames`` are ``(n, descriptor_dim)
        float32`` descriptors, or ``(n, h, w) uint8`` images. ``positions (n, 2)``
        metres, ``odometry (n,)`` metres since the previous frame (exact),
        ``timestamps (n,)`` seconds. ``meta``: ``street (n,) int``, ``direction (n,)
        int`` (+1 when driven from the lower to the higher node id, −1 otherwise),
        ``heading (n, 2)`` unit vectors, ``condition`` ``"day"``.
    query : Traverse
        Night drive over the same streets out of order, some in the other direction,
        with a new-place excursion; noisy odometry. ``meta`` as the reference plus
        ``new_place (n,) bool`` (no mapped street within ``tolerance_m``), ``section
        (n,) int`` (chunk number; ``-1`` connector; ``-2`` new district),
        ``true_odometry (n,)`` and ``reversed (n,) bool`` (frame lies in a chunk driven
        against the reference's direction).
    tolerance_m : float
        Default ground-truth tolerance (metres).
    junction_radius_m : float
        Default radius for :meth:`reference_junctions`.
    seed : int or None
        The seed the world was made from.
    params : dict
        Every parameter of :func:`make_world`, JSON-ready.
    """

    roads: nx.Graph
    reference: Traverse
    query: Traverse
    tolerance_m: float
    junction_radius_m: float
    seed: int | None = None
    params: dict = field(default_factory=dict)

    def ground_truth(self, metres: float | None = None) -> MetricTolerance:
        """Metric ground truth between query and reference.

        Parameters
        ----------
        metres : float, optional
            Tolerance in metres; default ``self.tolerance_m``.
        """
        return MetricTolerance.between(self.query, self.reference, self.tolerance_m if metres is None else metres)

    def reference_junctions(self, radius_m: float | None = None) -> np.ndarray:
        """Pairs of reference frames where the route passes the same intersection twice.

        For every intersection, the reference frames within ``radius_m`` of it are
        split into *passes* (runs of consecutive frame indices); each pass is
        represented by its frame nearest the intersection, and every pair of passes
        gives one pair ``(i, j)``, ``i < j``. A place graph can join these frames with
        junction edges.

        Parameters
        ----------
        radius_m : float, optional
            Default ``self.junction_radius_m``.

        Returns
        -------
        ndarray of int64, shape (k, 2)
            Sorted rows ``(i, j)`` with ``i < j``, reference indices as loaded.
        """
        radius = self.junction_radius_m if radius_m is None else radius_m
        check_scalar(radius, "radius_m", "SyntheticWorld.reference_junctions", float, 0.0, low_inclusive=False)
        positions = np.empty_like(self.reference.positions)
        positions[self.reference.index] = self.reference.positions
        pairs = []
        for node in sorted(self.roads.nodes):
            centre = np.asarray(self.roads.nodes[node]["pos"])
            dist = np.linalg.norm(positions - centre, axis=1)
            near = np.flatnonzero(dist <= radius)
            if len(near) < 2:
                continue
            cuts = np.flatnonzero(np.diff(near) > 1) + 1
            reps = [int(run[np.argmin(dist[run])]) for run in np.split(near, cuts)]
            pairs.extend((a, b) for k, a in enumerate(reps) for b in reps[k + 1 :])
        if not pairs:
            return np.zeros((0, 2), dtype=np.int64)
        out = np.sort(np.asarray(pairs, dtype=np.int64), axis=1)
        return out[np.lexsort((out[:, 1], out[:, 0]))]

    def __repr__(self) -> str:
        return (
            f"SyntheticWorld(seed={self.seed}, streets={self.roads.number_of_edges()}, "
            f"reference={len(self.reference)} frames, query={len(self.query)} frames, "
            f"tolerance_m={self.tolerance_m})"
        )


# --------------------------------------------------------------------------------------
# road network and routes
# --------------------------------------------------------------------------------------


def _build_roads(bx: int, by: int, extra: int, block_length: float) -> nx.Graph:
    g = nx.Graph()
    nx_cols = bx + extra + 1
    node = lambda i, j: j * nx_cols + i  # noqa: E731
    for j in range(by + 1):
        for i in range(nx_cols):
            g.add_node(node(i, j), pos=(i * block_length, j * block_length), grid=(i, j))
    street = 0
    for j in range(by + 1):
        for i in range(nx_cols):
            if i + 1 < nx_cols:
                g.add_edge(node(i, j), node(i + 1, j), length=block_length, street=street, mapped=i + 1 <= bx)
                street += 1
            if j + 1 <= by:
                g.add_edge(node(i, j), node(i, j + 1), length=block_length, street=street, mapped=i <= bx)
                street += 1
    return g


def _mapped_subgraph(roads: nx.Graph) -> nx.Graph:
    return roads.edge_subgraph([(u, v) for u, v, m in roads.edges(data="mapped") if m]).copy()


def _covering_walk(mapped: nx.Graph, start: int, rng: np.random.Generator) -> list[int]:
    """Greedy walk that drives every edge of ``mapped`` at least once."""
    todo = {frozenset(e) for e in mapped.edges}
    route = [start]
    while todo:
        here = route[-1]
        fresh = sorted(v for v in mapped.neighbors(here) if frozenset((here, v)) in todo)
        if fresh:
            nxt = fresh[rng.integers(len(fresh))]
            todo.discard(frozenset((here, nxt)))
            route.append(nxt)
            continue
        dist, paths = nx.single_source_dijkstra(mapped, here, weight="length")
        targets = [v for v in sorted(dist) if any(frozenset((v, w)) in todo for w in mapped.neighbors(v))]
        best = min(dist[v] for v in targets)
        closest = [v for v in targets if dist[v] == best]
        target = closest[rng.integers(len(closest))]
        route.extend(paths[target][1:])
    return route


def _query_route(
    mapped: nx.Graph,
    reference_route: list[int],
    rng: np.random.Generator,
    chunk_streets: tuple[int, int],
    query_coverage: float,
    reverse_fraction: float,
    extra: int,
    bx: int,
    by: int,
) -> tuple[list[int], list[int], list[bool]]:
    """Node path of the query, with a section code and a reversed flag per street."""
    m = len(reference_route) - 1
    bounds = [0]
    while bounds[-1] < m:
        bounds.append(min(m, bounds[-1] + int(rng.integers(chunk_streets[0], chunk_streets[1] + 1))))
    chunks = [reference_route[a : b + 1] for a, b in zip(bounds[:-1], bounds[1:])]
    n_keep = max(2, int(round(query_coverage * len(chunks))))
    keep = np.sort(rng.choice(len(chunks), size=min(n_keep, len(chunks)), replace=False))
    order = rng.permutation(keep)
    if np.all(np.diff(order) > 0):  # make sure the order really is shuffled
        order[[0, -1]] = order[[-1, 0]]
    flips = rng.random(len(order)) < reverse_fraction
    if reverse_fraction > 0 and not flips.any():
        flips[rng.integers(len(flips))] = True
    excursion_after = int(rng.integers(len(order) // 3, max(len(order) // 3 + 1, 2 * len(order) // 3))) if extra else -1

    nodes: list[int] = []
    section: list[int] = []
    rev: list[bool] = []

    def drive(path: list[int], code: int, reversed_: bool) -> None:
        if not nodes:
            nodes.append(path[0])
        elif nodes[-1] != path[0]:
            link = nx.shortest_path(mapped, nodes[-1], path[0], weight="length")
            nodes.extend(link[1:])
            section.extend([CONNECTOR] * (len(link) - 1))
            rev.extend([False] * (len(link) - 1))
        nodes.extend(path[1:])
        section.extend([code] * (len(path) - 1))
        rev.extend([reversed_] * (len(path) - 1))

    cols = bx + extra + 1
    for k, (c, flip) in enumerate(zip(order, flips)):
        path = chunks[c][::-1] if flip else chunks[c]
        drive(path, int(c), bool(flip))
        if k == excursion_after:
            j = int(rng.integers(by))
            out = [j * cols + i for i in range(bx, bx + extra + 1)]
            back = [(j + 1) * cols + i for i in range(bx + extra, bx - 1, -1)]
            drive(out + back, NEW_PLACE, False)
    return nodes, section, rev


def _sample_route(
    roads: nx.Graph, nodes: list[int], spacing: tuple[float, float], rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Frames along a node path at i.i.d. uniform arc-length increments."""
    pts = np.array([roads.nodes[v]["pos"] for v in nodes], dtype=np.float64)
    seg = np.diff(pts, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    total = cum[-1]
    n_max = int(np.ceil(total / spacing[0])) + 2
    steps = rng.uniform(spacing[0], spacing[1], size=n_max)
    steps[0] = rng.uniform(0.0, spacing[1])  # random start offset along the first street
    s = np.cumsum(steps)
    s = s[s <= total]
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    alpha = (s - cum[k]) / seg_len[k]
    positions = pts[k] + alpha[:, None] * seg[k]
    heading = seg[k] / seg_len[k][:, None]
    u = np.asarray(nodes[:-1])[k]
    v = np.asarray(nodes[1:])[k]
    street = np.array([roads.edges[a, b]["street"] for a, b in zip(u, v)], dtype=np.int64)
    direction = np.where(u < v, 1, -1).astype(np.int64)
    odometry = np.concatenate([[0.0], np.diff(s)])
    return {"positions": positions, "heading": heading, "street": street, "direction": direction,
            "odometry": odometry, "route_edge": k}


def _distance_to_streets(points: np.ndarray, roads: nx.Graph, mapped_only: bool = True) -> np.ndarray:
    """``(n,)`` distance from each point to the nearest (mapped) street segment."""
    a = []
    b = []
    for u, v, m in roads.edges(data="mapped"):
        if m or not mapped_only:
            a.append(roads.nodes[u]["pos"])
            b.append(roads.nodes[v]["pos"])
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ab = b - a
    t = np.einsum("nkd,kd->nk", points[:, None, :] - a[None], ab) / np.einsum("kd,kd->k", ab, ab)
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)


# --------------------------------------------------------------------------------------
# appearance
# --------------------------------------------------------------------------------------


class _FourierField:
    """Random Fourier features ``φ(x) = sqrt(2/F) cos(Ω x + b)`` of 2-D points."""

    def __init__(self, omega: np.ndarray, rng: np.random.Generator) -> None:
        self.omega = omega
        self.phase = rng.uniform(0.0, 2.0 * np.pi, size=len(omega))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return np.sqrt(2.0 / len(self.omega)) * np.cos(points @ self.omega.T + self.phase)


def _smooth_readout(rng: np.random.Generator, n_features: int, shape: tuple[int, int], mask: np.ndarray) -> np.ndarray:
    """``(n_features, h*w)`` read-out whose rows are blurred noise images times ``mask``."""
    from scipy.ndimage import gaussian_filter

    noise = rng.standard_normal((n_features, *shape))
    blurred = gaussian_filter(noise, sigma=(0.0, 2.0, 2.0), mode="wrap")
    blurred /= blurred.std(axis=0, keepdims=True) + 1e-12
    return (blurred * mask).reshape(n_features, -1)


class _Appearance:
    """The world's appearance: fields, read-outs, and the night transform."""

    def __init__(self, rng: np.random.Generator, *, n_out: int, length_scale: float, block_length: float,
                 aliasing: float, direction_weight: float, street_half_width: float, n_features: int,
                 image_shape: tuple[int, int] | None) -> None:
        self.half_width = street_half_width
        self.centre = _FourierField(rng.standard_normal((n_features, 2)) / length_scale, rng)
        self.unique = _FourierField(rng.standard_normal((n_features, 2)) / length_scale, rng)
        # periodic façade field: integer wave vectors, period = one block in x and y
        kmax = block_length / (2.0 * np.pi * length_scale)
        k = np.rint(rng.standard_normal((n_features, 2)) * kmax)
        zero = ~k.any(axis=1)
        k[zero, 0] = rng.choice([-1.0, 1.0], size=int(zero.sum()))
        self.periodic = _FourierField(2.0 * np.pi * k / block_length, rng)
        self.w_alias = np.sqrt(aliasing)
        self.w_unique = np.sqrt(1.0 - aliasing)
        self.w_centre = np.sqrt(1.0 - direction_weight)
        self.w_side = np.sqrt(direction_weight / 2.0)
        f2 = 2 * n_features
        if image_shape is None:
            self.read_centre = rng.standard_normal((n_features, n_out))
            self.read_left = rng.standard_normal((f2, n_out))
            self.read_right = rng.standard_normal((f2, n_out))
        else:
            h, w = image_shape
            col = (np.arange(w) + 0.5) / w
            left = np.clip(1.6 - 3.2 * col, 0.0, 1.0)
            right = left[::-1]
            centre = np.sqrt(np.clip(1.0 - left**2 - right**2, 0.0, 1.0))
            # normalise so that every column has unit total weight before the mixing weights
            tot = np.sqrt(left**2 + right**2 + centre**2)
            left, right, centre = left / tot, right / tot, centre / tot
            # the side weights already carry 1/sqrt(2): undo it in the image (one façade per side)
            self.read_centre = _smooth_readout(rng, n_features, image_shape, np.broadcast_to(centre, (h, w)))
            self.read_left = _smooth_readout(rng, f2, image_shape, np.sqrt(2.0) * np.broadcast_to(left, (h, w)))
            self.read_right = _smooth_readout(rng, f2, image_shape, np.sqrt(2.0) * np.broadcast_to(right, (h, w)))

    def _facade(self, points: np.ndarray) -> np.ndarray:
        return np.concatenate([self.w_unique * self.unique(points), self.w_alias * self.periodic(points)], axis=1)

    def __call__(self, positions: np.ndarray, heading: np.ndarray) -> np.ndarray:
        left_dir = np.stack([-heading[:, 1], heading[:, 0]], axis=1)
        q_left = positions + self.half_width * left_dir
        q_right = positions - self.half_width * left_dir
        return (self.w_centre * self.centre(positions) @ self.read_centre
                + self.w_side * (self._facade(q_left) @ self.read_left + self._facade(q_right) @ self.read_right))


def _random_mixing(rng: np.random.Generator, d: int, mixing: float) -> np.ndarray:
    """``M = (1 − m) I + m G/√d`` (``G`` i.i.d. N(0, 1)), rescaled to keep the mean squared norm."""
    m = (1.0 - mixing) * np.eye(d) + mixing * rng.standard_normal((d, d)) / np.sqrt(d)
    return m / np.sqrt(np.mean(np.sum(m**2, axis=0)))


def _blur_mixing(x: np.ndarray, shape: tuple[int, int], mixing: float) -> np.ndarray:
    """Images: ``(1 − m)·x + m·blur(x)`` — the softer look of a low-light exposure."""
    from scipy.ndimage import gaussian_filter

    blurred = gaussian_filter(x.reshape(-1, *shape), sigma=(0.0, 1.5, 1.5), mode="nearest").reshape(x.shape)
    return (1.0 - mixing) * x + mixing * blurred


# --------------------------------------------------------------------------------------
# public entry point
# --------------------------------------------------------------------------------------


def _check_pair(value, name: str, kind, low, high=None) -> tuple:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise InvalidParameterError(f"The '{name}' parameter of make_world must be a pair (low, high). Got {value!r} instead.")
    a = check_scalar(value[0], name, "make_world", kind, low, high)
    b = check_scalar(value[1], name, "make_world", kind, low, high)
    if b < a:
        raise InvalidParameterError(
            f"The '{name}' parameter of make_world must be a pair (low, high) with low <= high. Got {value!r} instead."
        )
    return a, b


def make_world(
    seed: int | np.random.Generator | None = 0,
    *,
    blocks: tuple[int, int] = (4, 4),
    block_length: float = 100.0,
    new_place_blocks: int = 1,
    spacing: tuple[float, float] = (3.0, 8.0),
    query_spacing: tuple[float, float] | None = None,
    chunk_streets: tuple[int, int] = (2, 5),
    query_coverage: float = 0.8,
    reverse_fraction: float = 0.35,
    descriptor_dim: int = 128,
    as_images: bool = False,
    image_shape: tuple[int, int] = (16, 32),
    length_scale: float = 12.0,
    aliasing: float = 0.8,
    direction_weight: float = 0.5,
    street_half_width: float = 8.0,
    n_features: int = 256,
    reference_noise: float = 0.2,
    query_noise: float | None = None,
    night_contrast: float = 0.7,
    night_mixing: float = 0.3,
    night_offset: float = 0.3,
    odometry_scale_noise: float = 0.05,
    odometry_noise: float = 0.3,
    frame_rate: float = 1.0,
    tolerance_m: float = 10.0,
    junction_radius_m: float = 10.0,
) -> SyntheticWorld:
    """Make a seeded synthetic city: road network, day reference, night query.

    See the module docstring for the model. Same seed, same parameters → identical
    arrays.

    Parameters
    ----------
    seed : int, numpy.random.Generator or None
        Seed of everything random.
    blocks : (int, int)
        Mapped blocks in x and y.
    block_length : float
        Side of a block (metres).
    new_place_blocks : int
        Columns of unmapped blocks east of the mapped area; the query makes one
        excursion of ``(2·new_place_blocks + 1)·block_length`` metres into them.
        0 disables the new district.
    spacing : (float, float)
        Range of the reference's frame spacing (metres, uniform per frame).
    query_spacing : (float, float), optional
        The query's; default ``spacing``.
    chunk_streets : (int, int)
        Range of the number of streets per query chunk.
    query_coverage : float in (0, 1]
        Fraction of reference chunks the query drives.
    reverse_fraction : float in [0, 1]
        Probability that a chunk is driven in the opposite direction (at least one is
        when positive).
    descriptor_dim : int
        Descriptor dimension (ignored with ``as_images``).
    as_images : bool
        Give ``(n, h, w) uint8`` greyscale images instead of descriptors.
    image_shape : (int, int)
        ``(h, w)`` of images.
    length_scale : float
        Length scale of the appearance fields (metres).
    aliasing : float in [0, 1]
        Share of the façade variance that repeats in every block.
    direction_weight : float in [0, 1]
        Share of the descriptor variance from the façades (direction-dependent).
    street_half_width : float
        Distance from the camera to each façade (metres).
    n_features : int
        Random Fourier features per field.
    reference_noise : float
        Standard deviation of the reference's i.i.d. noise (descriptor units: the
        noise-free field has unit variance per dimension; images: the same units,
        before the brightness mapping).
    query_noise : float, optional
        The query's; default 1.8 for descriptors and 0.6 for images, tuned so that
        single-frame nearest-neighbour matching is right about half the time (see
        ``docs/synthetic.md``).
    night_contrast, night_mixing, night_offset : float
        The day → night transform ``x' = c·M x + o`` (images: ``M`` blends in a
        blurred copy instead of mixing channels).
    odometry_scale_noise, odometry_noise : float
        Query odometry noise: multiplicative (fraction) and additive (metres) standard
        deviations.
    frame_rate : float
        Frames per second (timestamps are ``k / frame_rate``).
    tolerance_m : float
        Default ground-truth tolerance (metres).
    junction_radius_m : float
        Default radius of :meth:`SyntheticWorld.reference_junctions`.

    Returns
    -------
    SyntheticWorld

    Examples
    --------
    >>> world = make_world(seed=0)
    >>> world.reference.frames.shape[1]
    128
    >>> bool(world.query.meta["new_place"].any())
    True
    """
    owner = "make_world"
    bx, by = _check_pair(blocks, "blocks", int, 1)
    check_scalar(block_length, "block_length", owner, float, 0.0, low_inclusive=False)
    check_scalar(new_place_blocks, "new_place_blocks", owner, int, 0)
    spacing = _check_pair(spacing, "spacing", float, 1e-3)
    query_spacing = spacing if query_spacing is None else _check_pair(query_spacing, "query_spacing", float, 1e-3)
    if max(spacing[1], query_spacing[1]) >= block_length:
        raise InvalidParameterError(
            f"frame spacing must be shorter than a block; got spacing up to {max(spacing[1], query_spacing[1])} m "
            f"for blocks of {block_length} m. Use smaller spacing or longer blocks."
        )
    chunk_streets = _check_pair(chunk_streets, "chunk_streets", int, 1)
    check_scalar(query_coverage, "query_coverage", owner, float, 0.0, 1.0, low_inclusive=False)
    check_scalar(reverse_fraction, "reverse_fraction", owner, float, 0.0, 1.0)
    check_scalar(descriptor_dim, "descriptor_dim", owner, int, 1)
    if query_noise is None:
        query_noise = _DEFAULT_QUERY_NOISE_IMAGES if as_images else _DEFAULT_QUERY_NOISE
    if not isinstance(as_images, (bool, np.bool_)):
        raise InvalidParameterError(f"The 'as_images' parameter of make_world must be a bool. Got {as_images!r} instead.")
    image_shape = _check_pair(image_shape, "image_shape", int, 2)
    check_scalar(length_scale, "length_scale", owner, float, 0.0, low_inclusive=False)
    check_scalar(aliasing, "aliasing", owner, float, 0.0, 1.0)
    check_scalar(direction_weight, "direction_weight", owner, float, 0.0, 1.0)
    check_scalar(street_half_width, "street_half_width", owner, float, 0.0)
    check_scalar(n_features, "n_features", owner, int, 1)
    for name, value in (("reference_noise", reference_noise), ("query_noise", query_noise),
                        ("night_offset", night_offset), ("odometry_scale_noise", odometry_scale_noise),
                        ("odometry_noise", odometry_noise)):
        check_scalar(value, name, owner, float, 0.0)
    check_scalar(night_contrast, "night_contrast", owner, float, 0.0, low_inclusive=False)
    check_scalar(night_mixing, "night_mixing", owner, float, 0.0, 1.0)
    check_scalar(frame_rate, "frame_rate", owner, float, 0.0, low_inclusive=False)
    check_scalar(tolerance_m, "tolerance_m", owner, float, 0.0)
    check_scalar(junction_radius_m, "junction_radius_m", owner, float, 0.0, low_inclusive=False)

    params = {
        "blocks": [bx, by], "block_length": block_length, "new_place_blocks": new_place_blocks,
        "spacing": list(spacing), "query_spacing": list(query_spacing), "chunk_streets": list(chunk_streets),
        "query_coverage": query_coverage, "reverse_fraction": reverse_fraction, "descriptor_dim": descriptor_dim,
        "as_images": bool(as_images), "image_shape": list(image_shape), "length_scale": length_scale,
        "aliasing": aliasing, "direction_weight": direction_weight, "street_half_width": street_half_width,
        "n_features": n_features, "reference_noise": reference_noise, "query_noise": query_noise,
        "night_contrast": night_contrast, "night_mixing": night_mixing, "night_offset": night_offset,
        "odometry_scale_noise": odometry_scale_noise, "odometry_noise": odometry_noise,
        "frame_rate": frame_rate, "tolerance_m": tolerance_m, "junction_radius_m": junction_radius_m,
    }
    rng = as_generator(seed)
    # independent streams, so that changing e.g. the query noise leaves the routes alone
    route_rng, frame_rng, look_rng, noise_rng = (np.random.default_rng(s) for s in rng.integers(0, 2**63, size=4))

    roads = _build_roads(bx, by, new_place_blocks, block_length)
    mapped = _mapped_subgraph(roads)
    start = sorted(mapped.nodes)[int(route_rng.integers(mapped.number_of_nodes()))]
    ref_nodes = _covering_walk(mapped, start, route_rng)
    q_nodes, q_section, q_reversed = _query_route(
        mapped, ref_nodes, route_rng, chunk_streets, query_coverage, reverse_fraction,
        new_place_blocks, bx, by,
    )
    ref = _sample_route(roads, ref_nodes, spacing, frame_rng)
    qry = _sample_route(roads, q_nodes, query_spacing, frame_rng)

    n_out = image_shape[0] * image_shape[1] if as_images else descriptor_dim
    look = _Appearance(look_rng, n_out=n_out, length_scale=length_scale, block_length=block_length,
                       aliasing=aliasing, direction_weight=direction_weight, street_half_width=street_half_width,
                       n_features=n_features, image_shape=image_shape if as_images else None)
    offset = look_rng.normal(0.0, night_offset, size=n_out)
    x_ref = look(ref["positions"], ref["heading"])
    x_qry = look(qry["positions"], qry["heading"])
    if as_images:
        x_qry = _blur_mixing(x_qry, image_shape, night_mixing)
    else:
        x_qry = x_qry @ _random_mixing(look_rng, n_out, night_mixing).T
    x_ref = x_ref + noise_rng.normal(0.0, reference_noise, size=x_ref.shape)
    x_qry = night_contrast * x_qry + offset + noise_rng.normal(0.0, query_noise, size=x_qry.shape)
    if as_images:
        h, w = image_shape
        rows = (np.arange(h) + 0.5) / h
        sky = np.repeat((170.0 - 90.0 * rows)[:, None], w, axis=1).ravel()  # bright sky, dark road
        cols = (np.arange(w) + 0.5) / w
        glow = (np.exp(-(((cols[None] - 0.5) / 0.2) ** 2) - (((rows[:, None] - 1.0) / 0.3) ** 2))).ravel()
        ref_frames = np.clip(sky + 28.0 * x_ref, 0, 255)
        qry_frames = np.clip(0.45 * sky + 14.0 * x_qry + 60.0 * glow + 10.0, 0, 255)
        ref_frames = np.rint(ref_frames).astype(np.uint8).reshape(-1, h, w)
        qry_frames = np.rint(qry_frames).astype(np.uint8).reshape(-1, h, w)
    else:
        ref_frames = x_ref.astype(np.float32)
        qry_frames = x_qry.astype(np.float32)

    true_odo = qry["odometry"]
    noisy = true_odo * (1.0 + noise_rng.normal(0.0, odometry_scale_noise, size=len(true_odo)))
    noisy = np.maximum(0.0, noisy + noise_rng.normal(0.0, odometry_noise, size=len(true_odo)))
    noisy[0] = 0.0
    section = np.asarray(q_section, dtype=np.int64)[qry["route_edge"]]
    rev = np.asarray(q_reversed, dtype=bool)[qry["route_edge"]]
    new_place = _distance_to_streets(qry["positions"], roads, mapped_only=True) > tolerance_m

    reference = Traverse(
        frames=ref_frames, positions=ref["positions"], timestamps=np.arange(len(ref_frames)) / frame_rate,
        ids=np.arange(len(ref_frames)), odometry=ref["odometry"], name="synthetic reference (day)",
        meta={"street": ref["street"], "direction": ref["direction"], "heading": ref["heading"], "condition": "day"},
    )
    query = Traverse(
        frames=qry_frames, positions=qry["positions"], timestamps=np.arange(len(qry_frames)) / frame_rate,
        ids=np.arange(len(qry_frames)), odometry=noisy, name="synthetic query (night)",
        meta={"street": qry["street"], "direction": qry["direction"], "heading": qry["heading"],
              "condition": "night", "new_place": new_place, "section": section, "reversed": rev,
              "true_odometry": true_odo},
    )
    return SyntheticWorld(roads=roads, reference=reference, query=query, tolerance_m=float(tolerance_m),
                          junction_radius_m=float(junction_radius_m),
                          seed=seed if isinstance(seed, (int, np.integer)) else None, params=params)
