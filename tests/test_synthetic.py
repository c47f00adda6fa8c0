"""The seeded synthetic world: determinism, geometry, routes, appearance, ground truth."""

from __future__ import annotations


import numpy as np
import pytest
from scipy.spatial.distance import cdist

from catgraph.datasets.synthetic import CONNECTOR, NEW_PLACE, SyntheticWorld, make_world
from catgraph.differences import difference_matrix
from catgraph.exceptions import InvalidParameterError
from catgraph.frontends import seqslam_preprocess
from catgraph.traverse import MetricTolerance


@pytest.fixture(scope="module")
def world() -> SyntheticWorld:
    return make_world(seed=0)


@pytest.fixture(scope="module")
def image_world() -> SyntheticWorld:
    return make_world(seed=0, as_images=True)


def _arrays(w: SyntheticWorld) -> dict[str, np.ndarray]:
    out = {}
    for side in ("reference", "query"):
        t = getattr(w, side)
        for key in ("frames", "positions", "odometry", "timestamps", "index"):
            out[f"{side}.{key}"] = getattr(t, key)
        for key, value in t.meta.items():
            if isinstance(value, np.ndarray):
                out[f"{side}.meta.{key}"] = value
    return out


def _distance_to_edges_slow(points, roads, keep=lambda data: True):
    """Plain projection onto each street in turn; the nearest street wins."""
    best = np.full(len(points), np.inf)
    for u, v, data in roads.edges(data=True):
        if not keep(data):
            continue
        a = np.asarray(roads.nodes[u]["pos"], dtype=float)
        b = np.asarray(roads.nodes[v]["pos"], dtype=float)
        t = np.clip((points - a) @ (b - a) / np.dot(b - a, b - a), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * (b - a)), axis=1))
    return best


def _single_frame_accuracy(w: SyntheticWorld, query_desc, reference_desc, metric: str) -> float:
    match = difference_matrix(query_desc, reference_desc, metric=metric).argmin(axis=1)
    gt = w.ground_truth()
    idx = w.query.index
    has = gt.has_true_match(idx)
    return float(gt.correct(idx, match)[has].mean())


# ---------------------------------------------------------------------------- determinism


@pytest.mark.parametrize("as_images", [False, True])
def test_same_seed_gives_identical_arrays(as_images):
    a = _arrays(make_world(seed=3, as_images=as_images))
    b = _arrays(make_world(seed=3, as_images=as_images))
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_generator_seed_matches_int_seed():
    a = make_world(seed=np.random.default_rng(5))
    b = make_world(seed=np.random.default_rng(5))
    np.testing.assert_array_equal(a.query.frames, b.query.frames)


def test_different_seeds_differ():
    a, b = make_world(seed=1), make_world(seed=2)
    assert a.reference.frames.shape[1] == b.reference.frames.shape[1]
    n = min(len(a.reference), len(b.reference))
    assert not np.allclose(a.reference.frames[:n], b.reference.frames[:n])
    assert not np.array_equal(a.reference.meta["street"][:n], b.reference.meta["street"][:n]) or not np.allclose(
        a.reference.positions[:n], b.reference.positions[:n]
    )


def test_noise_parameter_leaves_routes_alone():
    a, b = make_world(seed=4), make_world(seed=4, query_noise=0.1)
    np.testing.assert_array_equal(a.query.positions, b.query.positions)
    assert not np.allclose(a.query.frames, b.query.frames)


# ---------------------------------------------------------------------------- roads and routes


def test_road_network_is_a_grid_with_lengths(world):
    g = world.roads
    bx, by = world.params["blocks"]
    extra = world.params["new_place_blocks"]
    assert g.number_of_nodes() == (bx + extra + 1) * (by + 1)
    for u, v, data in g.edges(data=True):
        pu, pv = np.asarray(g.nodes[u]["pos"]), np.asarray(g.nodes[v]["pos"])
        assert data["length"] == pytest.approx(np.linalg.norm(pu - pv))
        assert data["length"] == pytest.approx(world.params["block_length"])
    assert len({d["street"] for _, _, d in g.edges(data=True)}) == g.number_of_edges()


def test_positions_lie_on_the_road_network(world):
    for t in (world.reference, world.query):
        np.testing.assert_allclose(_distance_to_edges_slow(t.positions, world.roads), 0.0, atol=1e-9)
    # the reference never leaves the mapped streets
    off = _distance_to_edges_slow(world.reference.positions, world.roads, keep=lambda d: d["mapped"])
    np.testing.assert_allclose(off, 0.0, atol=1e-9)


def test_meta_street_and_heading_agree_with_positions(world):
    g = world.roads
    by_id = {d["street"]: (u, v) for u, v, d in g.edges(data=True)}
    for t in (world.reference, world.query):
        street, direction, heading = t.meta["street"], t.meta["direction"], t.meta["heading"]
        np.testing.assert_allclose(np.linalg.norm(heading, axis=1), 1.0)
        for k in range(0, len(t), 7):
            u, v = sorted(by_id[int(street[k])])
            a, b = np.asarray(g.nodes[u]["pos"]), np.asarray(g.nodes[v]["pos"])
            along = (b - a) / np.linalg.norm(b - a)
            np.testing.assert_allclose(heading[k], direction[k] * along, atol=1e-12)
            # the frame is on that street
            s = np.dot(t.positions[k] - a, along)
            assert -1e-9 <= s <= np.linalg.norm(b - a) + 1e-9
            np.testing.assert_allclose(a + s * along, t.positions[k], atol=1e-9)


def test_reference_covers_every_mapped_street(world):
    mapped = {d["street"] for _, _, d in world.roads.edges(data=True) if d["mapped"]}
    assert set(np.unique(world.reference.meta["street"])) == mapped


def test_query_revisits_reference_streets_out_of_order(world):
    q, r = world.query, world.reference
    known = q.meta["section"] != NEW_PLACE
    nearest = cdist(q.positions[known], r.positions).argmin(axis=1)
    jumps = np.diff(nearest)
    # large backward jumps of the nearest reference frame: the query goes back in the route
    assert np.sum(jumps < -50) >= 3
    # and it really visits reference streets: every known-place street is a reference street
    assert set(np.unique(q.meta["street"][known])) <= set(np.unique(r.meta["street"]))


def test_query_drives_some_streets_the_other_way(world):
    q, r = world.query, world.reference
    ref_pairs = set(zip(r.meta["street"].tolist(), r.meta["direction"].tolist()))
    q_pairs = set(zip(q.meta["street"].tolist(), q.meta["direction"].tolist()))
    mapped = {d["street"] for _, _, d in world.roads.edges(data=True) if d["mapped"]}
    against = {(s, d) for s, d in q_pairs if s in mapped and (s, d) not in ref_pairs}
    assert len(against) >= 2
    # the heading of the nearest reference frame points the other way on those frames
    nearest = cdist(q.positions, r.positions).argmin(axis=1)
    opposite = np.einsum("nd,nd->n", q.meta["heading"], r.meta["heading"][nearest]) < -0.9
    assert opposite.mean() > 0.05
    assert q.meta["reversed"].any() and (q.meta["section"][q.meta["reversed"]] >= 0).all()


def test_reverse_fraction_zero_drives_every_chunk_forwards():
    w = make_world(seed=0, reverse_fraction=0.0)
    assert not w.query.meta["reversed"].any()


def test_frame_spacing_varies_within_its_range(world):
    lo, hi = world.params["spacing"]
    for t, odo in ((world.reference, world.reference.odometry), (world.query, world.query.meta["true_odometry"])):
        step = odo[1:]
        assert step.min() >= lo - 1e-9 and step.max() <= hi + 1e-9
        assert step.std() > 0.25 * (hi - lo) / np.sqrt(12) * 2  # about uniform: std (hi-lo)/sqrt(12)
        # odometry is arc length: never shorter than the straight line between frames, and
        # equal to it while the route goes straight on along one street (no turn, no U-turn)
        chord = np.linalg.norm(np.diff(t.positions, axis=0), axis=1)
        assert np.all(step >= chord - 1e-9)
        same = (t.meta["street"][1:] == t.meta["street"][:-1]) & (t.meta["direction"][1:] == t.meta["direction"][:-1])
        assert same.mean() > 0.8
        np.testing.assert_allclose(step[same], chord[same], atol=1e-9)


def test_query_odometry_is_noisy_but_unbiased(world):
    q = world.query
    true, noisy = q.meta["true_odometry"][1:], q.odometry[1:]
    assert np.all(noisy >= 0) and q.odometry[0] == 0
    assert not np.allclose(noisy, true)
    assert abs(noisy.sum() / true.sum() - 1) < 0.02
    np.testing.assert_array_equal(world.reference.odometry[0], 0.0)


def test_timestamps_increase(world):
    for t in (world.reference, world.query):
        assert np.all(np.diff(t.timestamps) > 0)


# ---------------------------------------------------------------------------- appearance


def test_descriptors_finite_with_the_requested_dimension(world):
    for t in (world.reference, world.query):
        assert t.frames.dtype == np.float32
        assert t.frames.shape == (len(t), world.params["descriptor_dim"])
        assert np.isfinite(t.frames).all()
    w = make_world(seed=1, descriptor_dim=64, new_place_blocks=0)
    assert w.query.frames.shape[1] == 64


def test_descriptors_are_spatially_smooth(world):
    r = world.reference
    d = cdist(r.frames, r.frames, "cosine")
    p = cdist(r.positions, r.positions)
    same_dir = (r.meta["heading"] @ r.meta["heading"].T) > 0.9
    near = d[(p > 0) & (p <= 8) & same_dir].mean()
    middle = d[(p > 15) & (p <= 40) & same_dir].mean()
    far = d[p > 200].mean()
    assert near < 0.5 * middle
    assert middle < far + 0.05


def test_appearance_changes_between_day_and_night(world):
    q, r = world.query, world.reference
    dq = cdist(q.frames, r.frames, "cosine")
    p = cdist(q.positions, r.positions)
    same_dir = (q.meta["heading"] @ r.meta["heading"].T) > 0.9
    same_place = dq[(p <= 3) & same_dir].mean()
    dr = cdist(r.frames, r.frames, "cosine")
    pr = cdist(r.positions, r.positions)
    neighbours = dr[(pr > 0) & (pr <= 8) & ((r.meta["heading"] @ r.meta["heading"].T) > 0.9)].mean()
    random_pairs = dq[p > 100].mean()
    assert neighbours < same_place < random_pairs


def test_the_same_place_looks_different_driven_the_other_way():
    w = make_world(seed=0, query_noise=0.0, night_mixing=0.0, night_offset=0.0, night_contrast=1.0, reference_noise=0.0)
    q, r = w.query, w.reference
    d = cdist(q.frames, r.frames, "cosine")
    p = cdist(q.positions, r.positions)
    cos_heading = q.meta["heading"] @ r.meta["heading"].T
    along = d[(p <= 1.5) & (cos_heading > 0.9)].mean()
    against = d[(p <= 1.5) & (cos_heading < -0.9)].mean()
    assert along < 0.1 < against < 0.9  # different, but still partly shared (the street itself)


def test_single_frame_matching_is_moderately_accurate(world):
    accuracy = _single_frame_accuracy(world, world.query.frames, world.reference.frames, "cosine")
    assert 0.3 < accuracy < 0.75


def test_sequences_have_room_to_help(world):
    # a five-frame window summed along the forward diagonal and the backward anti-diagonal
    d = difference_matrix(world.query.frames, world.reference.frames, metric="cosine")
    n_q, n_r = d.shape
    length = 5
    forward = np.full_like(d, np.inf)
    backward = np.full_like(d, np.inf)
    forward[length - 1 :, length - 1 :] = sum(
        d[length - 1 - k : n_q - k, length - 1 - k : n_r - k] for k in range(length)
    )
    backward[length - 1 :, : n_r - length + 1] = sum(
        d[length - 1 - k : n_q - k, k : n_r - length + 1 + k] for k in range(length)
    )
    match = np.minimum(forward, backward).argmin(axis=1)
    gt = world.ground_truth()
    idx = np.arange(length - 1, n_q)
    has = gt.has_true_match(idx)
    sequence = gt.correct(idx, match[length - 1 :])[has].mean()
    single = _single_frame_accuracy(world, world.query.frames, world.reference.frames, "cosine")
    assert sequence > single + 0.15


def test_image_mode_renders_small_greyscale_images(image_world):
    h, w = image_world.params["image_shape"]
    for t in (image_world.reference, image_world.query):
        assert t.frames.dtype == np.uint8 and t.frames.shape == (len(t), h, w)
        saturated = np.mean((t.frames == 0) | (t.frames == 255))
        assert saturated < 0.02
    # night is darker
    assert image_world.query.frames.mean() < image_world.reference.frames.mean() - 20
    # same routes as the descriptor world with the same seed
    plain = make_world(seed=0)
    np.testing.assert_array_equal(image_world.query.positions, plain.query.positions)


def test_image_mode_single_frame_matching_is_moderate(image_world):
    q = seqslam_preprocess(image_world.query.frames, patch=4)
    r = seqslam_preprocess(image_world.reference.frames, patch=4)
    accuracy = _single_frame_accuracy(image_world, q, r, "sad")
    assert 0.3 < accuracy < 0.75


# ---------------------------------------------------------------------------- ground truth


def test_ground_truth_is_metric_with_the_default_tolerance(world):
    gt = world.ground_truth()
    assert isinstance(gt, MetricTolerance) and gt.metres == world.tolerance_m
    strict = world.ground_truth(metres=1.0)
    idx = world.query.index
    assert strict.has_true_match(idx).sum() < gt.has_true_match(idx).sum()


def test_new_place_section_has_no_true_match(world):
    q = world.query
    new = q.meta["new_place"]
    assert new.sum() >= 20
    gt = world.ground_truth()
    assert not gt.has_true_match(q.index[new]).any()
    # new-place frames are exactly the ones far from every mapped street
    far = _distance_to_edges_slow(q.positions, world.roads, keep=lambda d: d["mapped"]) > world.tolerance_m
    np.testing.assert_array_equal(new, far)
    assert (q.meta["section"][new] == NEW_PLACE).all()
    # one contiguous excursion
    assert np.count_nonzero(np.diff(new.astype(int)) == 1) == 1
    # every other frame has a match
    assert gt.has_true_match(q.index[~new]).all()


def test_no_new_district_means_every_query_frame_has_a_match():
    w = make_world(seed=2, new_place_blocks=0)
    assert not w.query.meta["new_place"].any()
    assert w.ground_truth().has_true_match(w.query.index).all()
    assert (w.query.meta["section"] >= CONNECTOR).all()


# ---------------------------------------------------------------------------- junctions


def test_reference_junctions_pair_different_passes_of_one_intersection(world):
    pairs = world.reference_junctions()
    r = world.reference
    assert pairs.dtype == np.int64 and pairs.ndim == 2 and pairs.shape[1] == 2
    assert np.all(pairs[:, 0] < pairs[:, 1])
    assert len(np.unique(pairs, axis=0)) == len(pairs)
    nodes = np.array([world.roads.nodes[v]["pos"] for v in sorted(world.roads.nodes)])
    radius = world.junction_radius_m
    for i, j in pairs:
        di = np.linalg.norm(nodes - r.positions[i], axis=1)
        dj = np.linalg.norm(nodes - r.positions[j], axis=1)
        assert np.any((di <= radius) & (dj <= radius))
        # different passes: some frame between them is away from that intersection
        node = np.argmin(di + dj)
        between = np.linalg.norm(r.positions[i : j + 1] - nodes[node], axis=1)
        assert between.max() > radius


def test_reference_junctions_find_every_repeated_intersection(world):
    """Slow reference: count the passes through each intersection directly."""
    r = world.reference
    expected = 0
    for v in world.roads.nodes:
        near = np.linalg.norm(r.positions - np.asarray(world.roads.nodes[v]["pos"]), axis=1) <= 10.0
        passes = int(near[0]) + int(np.sum(near[1:] & ~near[:-1]))
        expected += passes * (passes - 1) // 2
    assert expected > 0
    assert len(world.reference_junctions(radius_m=10.0)) == expected
    assert len(world.reference_junctions(radius_m=20.0)) >= expected


# ---------------------------------------------------------------------------- parameters and speed


@pytest.mark.parametrize(
    "kwargs",
    [
        {"blocks": (0, 4)},
        {"blocks": 4},
        {"spacing": (8.0, 3.0)},
        {"spacing": (3.0, 150.0)},
        {"query_coverage": 0.0},
        {"reverse_fraction": 1.5},
        {"descriptor_dim": 0},
        {"as_images": "yes"},
        {"aliasing": -0.1},
        {"query_noise": -1.0},
        {"tolerance_m": float("nan")},
        {"seed": -1},
    ],
)
def test_bad_parameters_raise_typed_errors(kwargs):
    with pytest.raises(InvalidParameterError):
        make_world(**kwargs)


def test_repr_and_params_are_informative(world):
    assert "seed=0" in repr(world)
    assert world.params["descriptor_dim"] == 128 and world.params["query_noise"] > 0
