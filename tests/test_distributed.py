"""Dask-sharded batch evaluation equals the local run (on a LocalCluster)."""

import time

import numpy as np
import pytest

from catgraph.conditions import Condition
from catgraph.differences import difference_matrix
from catgraph.exceptions import InvalidParameterError
from catgraph.sequence import DEFAULT_LINE_RULE, DEFAULT_VELOCITIES, fixed_window_scores, match_sequences
from .conftest import hub_map

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402


def coded(d):
    """The local matcher's stored values, obviously: the quantum of the first row that is not
    all zeros, int16-range codes (round half to even, saturated at ±32767) and each row's
    rounded mean code."""
    peaks = np.abs(d).max(1)
    if not np.any(peaks > 0):
        return 0.0, np.zeros(d.shape, dtype=np.int64), np.zeros(d.shape[0], dtype=np.int64)
    u = 2.0 ** (int(np.frexp(peaks[np.flatnonzero(peaks > 0)[0]])[1]) - 12)
    codes = np.clip(np.rint(d / u), -32767, 32767).astype(np.int64)
    return u, codes, np.rint(codes.sum(1) / d.shape[1]).astype(np.int64)


def slow_sums(d, window, velocity=1.0):
    """Obviously correct integer window sums: direct sums of the codes along the line of
    ``velocity`` (frame t at place j - (pos(i) - pos(t)), pos(i) = floor(v i + 1/2)), the
    row's mean code where that place is off the reference (edge policy of catgraph.sequence)."""
    u, codes, means = coded(d)
    n_q, n = d.shape
    pos = np.floor(velocity * np.arange(n_q) + 0.5).astype(np.int64)
    out = np.empty(d.shape, dtype=np.int64)
    for i in range(n_q):
        eff = min(window, i + 1)
        total = np.zeros(n, dtype=np.int64)
        for t in range(i - eff + 1, i + 1):
            col = np.arange(n) - (pos[i] - pos[t])
            inside = (col >= 0) & (col < n)
            total += np.where(inside, codes[t, np.clip(col, 0, n - 1)], means[t])
        out[i] = total
    return u, out


def slow_scores(d, window, velocity=1.0):
    u, sums = slow_sums(d, window, velocity)
    return sums * u / np.minimum(window, np.arange(1, d.shape[0] + 1))[:, None]


def assert_same_as_local(res, d, window, radius, velocities=(1.0,), confidence="gap"):
    """Matches, scores, velocities and confidences identical to the local fixed-window
    matcher; with one velocity, the gap also within float64 rounding of a direct
    computation from the slow scores."""
    local = match_sequences(d, window=window, velocities=velocities, confidence=confidence, radius=radius)
    assert np.array_equal(res.match, local.match)
    assert np.array_equal(res.score, local.score)
    assert np.array_equal(res.velocity, local.velocity)
    assert np.array_equal(res.confidence, local.confidence)
    if tuple(velocities) != (1.0,) or confidence != "gap":
        return local
    expected = slow_scores(d, window)
    blank = np.ptp(d, axis=1) == 0  # a frame with no information of its own: no output
    assert np.array_equal(res.match, np.where(blank, -1, expected.argmin(1)))
    best = expected.min(1)
    g = np.arange(d.shape[1])
    at = expected.argmin(1)
    second = np.where(np.abs(g[None] - at[:, None]) <= radius, np.inf, expected).min(1)
    spread = expected.std(1)
    gap = (second - best) / np.where(spread > 0, spread, 1.0)
    np.testing.assert_allclose(res.confidence, np.where(blank | (spread == 0), 0.0, gap), rtol=1e-9, atol=1e-12)
    return local


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)
    r = rng.normal(size=(9000, 16)).astype(np.float32)
    q = np.concatenate([r[4050:4150] + 0.3 * rng.normal(size=(100, 16)).astype(np.float32), r[:30], r[8990:]])
    return q, r


@pytest.mark.parametrize("metric", ["sad", "cosine"])
def test_sharded_differences_identical_to_local(client, data, metric):
    q, r = data
    ref = dd.shard_reference(r, metric, client, shard_places=4096)
    assert ref.bounds == [(0, 4096), (4096, 8192), (8192, 9000)]
    for normalise in (False, True):
        got = dd.difference_matrix(q, ref, normalise=normalise, block_rows=50)
        assert np.array_equal(got, difference_matrix(q, r, metric, normalise=normalise))


def test_sharded_window_scores_and_matches_equal_local(client, data):
    q, r = data
    ref = dd.shard_reference(r, "sad", client, shard_places=1)  # rounded up to one unit
    assert ref.bounds[0] == (0, dd.SHARD_UNIT)
    local = difference_matrix(q, r, "sad", normalise=True)
    for window in (1, 12):
        got = dd.window_scores(q, ref, window, block_rows=37)
        assert np.array_equal(got, slow_scores(local, window))
        assert np.array_equal(got, fixed_window_scores(local, window))
        res = dd.match_fixed_window(q, ref, window, radius=5, velocities=[1.0], confidence="gap", block_rows=37)
        assert_same_as_local(res, local, window, 5)
    assert np.all(np.abs(res.match[20:100] - (4050 + np.arange(20, 100))) <= 1)


@pytest.fixture(scope="module")
def route():
    """A route whose stretches cross the shard edge at 4096 and run off the end of the map
    (shards of 4096, 4096 and 8 places)."""
    rng = np.random.default_rng(5)
    r = rng.normal(size=(8200, 16)).astype(np.float32)
    places = np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)])
    return r[places] + 0.4 * rng.normal(size=(places.size, 16)).astype(np.float32), r


def test_window_scores_along_every_velocity_equal_local(client, route):
    q, r = route
    q = q[::3]  # lines of every velocity cross both shard edges and both ends of the map
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    assert ref.bounds == [(0, 4096), (4096, 8192), (8192, 8200)]
    local = difference_matrix(q, r, "sad", normalise=True)
    for velocity in DEFAULT_VELOCITIES:
        got = dd.window_scores(q, ref, 7, velocity=velocity, block_rows=40)
        assert np.array_equal(got, fixed_window_scores(local, 7, velocity))
        assert np.array_equal(got, slow_scores(local, 7, velocity))


@pytest.mark.parametrize("condition", [Condition("in-order"), Condition("reverse"), Condition("speed", factor=2.0)])
def test_velocity_search_equals_the_local_matcher(client, route, condition):
    q, r = route
    q = q[condition.order(len(q))]
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    res = dd.match_fixed_window(q, ref, 20, block_rows=64)  # the defaults of match_sequences
    out = assert_same_as_local(res, local, 20, 10, DEFAULT_VELOCITIES, "posterior")
    assert len(np.unique(out.velocity)) > 1  # not trivial: several velocities chosen
    expected = {"in-order": 1.0, "reverse": -1.0, "speed": 2.0}[condition.kind]
    assert np.mean(out.velocity[20:] == expected) > 0.8


@pytest.mark.parametrize("confidence", ["gap", "neglogp", "z"])
def test_every_fixed_window_confidence_and_radius_equals_local(client, route, confidence):
    q, r = route
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    # radius 0; one that covers the last shard from the one before it; one beyond a whole shard
    for radius in (0, 30, 5000):
        res = dd.match_fixed_window(q, ref, 9, radius=radius, velocities=(-1.0, 0.5, 1.0, 3.0),
                                    confidence=confidence, block_rows=100)
        assert_same_as_local(res, local, 9, radius, (-1.0, 0.5, 1.0, 3.0), confidence)


def test_halos_from_several_shards_equal_local(client):
    # a window whose lines at |v| = 3 reach over a whole 4096-place shard: the last shard's
    # halo comes from both shards before it, the first shard's from both after it
    rng = np.random.default_rng(8)
    r = rng.normal(size=(8200, 8)).astype(np.float32)
    q = r[2000:3450] + 0.5 * rng.normal(size=(1450, 8)).astype(np.float32)
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    assert dd._halo(np.array([3.0, -3.0]), 0, 1450, 1400) == (4200, 4200)
    local = difference_matrix(q, r, "sad", normalise=True)
    for velocity in (3.0, -3.0):
        assert np.array_equal(dd.window_scores(q, ref, 1400, velocity=velocity, block_rows=1000),
                              fixed_window_scores(local, 1400, velocity))
    res = dd.match_fixed_window(q, ref, 1400, velocities=(-3.0, 0.5, 3.0), block_rows=1000)
    assert_same_as_local(res, local, 1400, 10, (-3.0, 0.5, 3.0), "posterior")


@pytest.mark.parametrize("condition", [Condition("in-order"), Condition("reverse"), Condition("speed", factor=2.0)])
def test_adaptive_window_equals_the_local_matcher(client, route, condition):
    # the library's matcher with the cluster's default rule (sequence.DEFAULT_LINE_RULE; the local
    # default "tracked" runs a filter the shards cannot), confidence sequence.DEFAULT_CONFIDENCE,
    # every velocity,
    # on a shorter grid so that the test stays fast; the route also jumps (a second stretch)
    q, r = route
    q = q[condition.order(len(q))]
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    params = {"l_max": 64, "grid": 6}
    res = dd.match_adaptive_window(q, ref, block_rows=100, **params)
    out = match_sequences(local, rule=DEFAULT_LINE_RULE, **params)
    for name in ("match", "score", "velocity", "window_length", "confidence"):
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
    assert len(np.unique(out.window_length[70:])) > 2  # not trivial: several lengths chosen


def test_adaptive_window_with_every_default_equals_local(client, route):
    # match_sequences' defaults as they are (13 lengths from 5 to 500, every velocity) but the
    # rule, the cluster's (sequence.DEFAULT_LINE_RULE), on a query whose frames are fewer than the
    # longest window
    q, r = route
    q = q[60:]  # a jump to the map's end at frame 140
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    res = dd.match_adaptive_window(q, ref)
    out = match_sequences(local, rule=DEFAULT_LINE_RULE)
    for name in ("match", "score", "velocity", "window_length", "confidence"):
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


@pytest.mark.parametrize("params", [{"confidence": "support", "rule": "evident"}, {"rule": "consistent"},
                                    {"rule": "sustained", "confidence": "neglogp"}, {"rule": "literal",
                                                                                     "confidence": "z"}])
def test_adaptive_rules_and_confidences_equal_local(client, route, params):
    q, r = route
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    params = {"l_min": 3, "l_max": 40, "grid": 5, "radius": 6, "velocities": (-1.0, 0.5, 1.0, 2.0), **params}
    res = dd.match_adaptive_window(q, ref, block_rows=90, **params)
    out = match_sequences(local, **params)
    for name in ("match", "score", "velocity", "window_length", "confidence"):
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_adaptive_window_with_frames_without_information(client, route):
    q, r = route
    blank = np.zeros(len(q), dtype=bool)
    blank[[0, 57]] = True
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    local[blank] = 0.0
    res = dd.match_adaptive_window(q, ref, l_max=30, grid=4, block_rows=128, no_information=blank)
    out = match_sequences(local, l_max=30, grid=4, rule=DEFAULT_LINE_RULE)
    for name in ("match", "score", "velocity", "window_length", "confidence"):
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


@pytest.mark.parametrize("window", [20, "adaptive"])
def test_hub_correction_equals_local(client, window):
    # flat frames (hubs) in every shard; the offsets from the map against itself (a sample of
    # its frames); rows corrected and normalised again as apply_hub_offsets does it
    from catgraph.hubs import hub_offsets

    r, q = hub_map(np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)]))
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    offsets = hub_offsets(difference_matrix(r[::7], r, "sad", normalise=True), rows=np.arange(0, 8200, 7))
    assert np.count_nonzero(offsets) == 3
    if window == "adaptive":
        res = dd.match_adaptive_window(q, ref, l_max=60, grid=5, block_rows=100, hub_offsets=offsets)
        out = match_sequences(local, l_max=60, grid=5, hub_offsets=offsets, rule=DEFAULT_LINE_RULE)
        plain = match_sequences(local, l_max=60, grid=5, rule=DEFAULT_LINE_RULE)
    else:
        res = dd.match_fixed_window(q, ref, window, block_rows=64, hub_offsets=offsets)
        out = match_sequences(local, window=window, hub_offsets=offsets)
        plain = match_sequences(local, window=window)
    for name in ("match", "score", "velocity", "window_length", "confidence"):
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
    assert not np.array_equal(plain.confidence, out.confidence)  # not trivial: the correction changes them
    with pytest.raises(InvalidParameterError, match="hub_offsets.*one offset per reference place"):
        dd.match_fixed_window(q, ref, 5, hub_offsets=offsets[:-1])


@pytest.mark.parametrize("n", [1, 7, 8, 100, 128, 129, 4096, 4100, 8200, 9001])
def test_row_moments_are_numpys(n):
    # numpy's pairwise sum, cut at shards of 4096 places: every subtree inside a shard summed
    # there, blocks across an edge gathered; the result is row.mean() and row.std() exactly
    rng = np.random.default_rng(n)
    rows = rng.normal(size=(3, n)) * 10.0 ** rng.integers(-4, 5, size=(3, n))
    bounds = [(lo, min(n, lo + 4096)) for lo in range(0, n, 4096)]
    tree, whole, pieces = dd._pairwise_plan(n, bounds)
    parts = [dd._pairwise_parts(rows[:, lo:hi], whole[s], pieces[s], None) for s, (lo, hi) in enumerate(bounds)]
    mean = dd._pairwise_sum(tree, parts, parts) / n
    parts = [dd._pairwise_parts(rows[:, lo:hi], whole[s], pieces[s], mean) for s, (lo, hi) in enumerate(bounds)]
    std = np.sqrt(dd._pairwise_sum(tree, parts, parts) / n)
    for t in range(3):
        assert mean[t] == rows[t].mean() and std[t] == rows[t].std()
    if n >= 8200:  # not trivial: adding the shards' own sums gives another float somewhere
        assert any(sum(rows[t, lo:hi].sum() for lo, hi in bounds) != rows[t].sum() for t in range(3))


def test_saturated_codes_equal_local(client, data):
    # a far place (every later row's largest difference, ~85 spreads) and a first frame whose row
    # spans only ±4 spreads: its quantum is 2^-9, so the far place's codes saturate at 32767 u ≈ 64
    q, r = data
    r, q = r.copy(), q.copy()
    r[6000] += 40
    q[0] = 20
    local = difference_matrix(q, r, "sad", normalise=True)
    u, codes, _ = coded(local)
    assert u == 2.0**-9 and np.abs(local[0]).max() < 8
    assert np.sum(np.abs(codes) == 32767) > 100 and np.abs(local).max() > 80
    assert not np.array_equal(slow_sums(np.clip(local, -60, 60), 12)[1], slow_sums(local, 12)[1])  # not trivial
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    assert np.array_equal(dd.window_scores(q, ref, 12, block_rows=50), fixed_window_scores(local, 12))
    for window in (3, 12):
        assert_same_as_local(dd.match_fixed_window(q, ref, window, radius=5, velocities=[1.0], confidence="gap",
                                                    block_rows=50), local, window, 5)


def test_first_frame_without_information(client, data):
    # a blank first frame: a zero row leaves the quantum to the next row (it was 2^-12, and every
    # later difference beyond ±8 saturated), as locally
    q, r = data
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    blank = np.zeros(q.shape[0], dtype=bool)
    blank[[0, 40]] = True
    local = difference_matrix(q, r, "sad", normalise=True)
    local[blank] = 0.0
    assert coded(local)[0] == 2.0 ** (int(np.frexp(np.abs(local[1]).max())[1]) - 12) > 2.0**-12
    res = dd.match_fixed_window(q, ref, 12, radius=5, velocities=[1.0], confidence="gap", block_rows=64,
                                 no_information=blank)
    assert_same_as_local(res, local, 12, 5)
    res = dd.match_fixed_window(q, ref, 12, radius=5, block_rows=64, no_information=blank)  # every velocity
    assert_same_as_local(res, local, 12, 5, DEFAULT_VELOCITIES, "posterior")


def test_spread_beyond_exact_float64_sums_within_the_stated_bound(client):
    # a smooth route and a blank first frame (quantum 2^-12): sum_j (S_ij - shift_i)^2 passes 2^53
    # on most rows, where the local kernel's float64 moments round in their own order. Matches and
    # scores stay identical (integer sums); a confidence is within the relative bound of
    # match_fixed_window's docstring: 1.5 N 2^-53 (1 + mean(y)^2 / var(y)), y = S - shift
    rng = np.random.default_rng(3)
    r = np.cumsum(rng.normal(size=(9000, 16)), axis=0).astype(np.float32)
    q = np.concatenate([np.ones((1, 16), np.float32),
                        r[3000:3240] + 0.3 * rng.normal(size=(240, 16)).astype(np.float32)])
    blank = np.zeros(len(q), dtype=bool)
    blank[0] = True
    d = difference_matrix(q, r, "sad", normalise=True)
    d[blank] = 0.0
    window = 200
    eff = np.minimum(window, np.arange(1, len(q) + 1))[:, None]
    sums = np.rint(fixed_window_scores(d, window) * eff / 2.0**-12)  # the exact integer sums
    y = sums - np.concatenate([[0.0], sums[:-1, -1]])[:, None]  # shift: the previous row's last sum
    assert np.sum((y**2).sum(1) >= 2.0**53) > 50
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    res = dd.match_fixed_window(q, ref, window, radius=5, velocities=[1.0], confidence="gap", block_rows=64,
                                 no_information=blank)
    local = match_sequences(d, window=window, velocities=[1.0], confidence="gap", radius=5)
    assert np.array_equal(res.match, local.match) and np.array_equal(res.score, local.score)
    spread = y.var(1)
    ratio = np.where(spread > 0, y.mean(1) ** 2 / np.where(spread > 0, spread, 1.0), 0.0)
    bound = 1.5 * d.shape[1] * 2.0**-53 * (1 + ratio)
    assert np.all(np.abs(res.confidence - local.confidence) <= bound * np.abs(local.confidence))


def test_bad_inputs(client, data):
    q, r = data
    with pytest.raises(InvalidParameterError, match="metric"):
        dd.shard_reference(r, "l3", client)
    with pytest.raises(InvalidParameterError, match="scheduler"):
        dd.shard_reference(r, "sad", 42)
    ref = dd.shard_reference(r, "sad", client)
    with pytest.raises(InvalidParameterError, match="window"):
        dd.match_fixed_window(q, ref, dd.SHARD_UNIT + 1)
    with pytest.raises(InvalidParameterError, match="velocities"):
        dd.match_fixed_window(q, ref, 12, velocities=[1.0, 1.0])
    with pytest.raises(InvalidParameterError, match="confidence"):
        dd.match_fixed_window(q, ref, 12, confidence="margin")
    with pytest.raises(InvalidParameterError, match="velocities"):
        dd.window_scores(q, ref, 12, velocity=float("nan"))
    with pytest.raises(InvalidParameterError, match="approximation.*gaussian"):
        dd.match_adaptive_window(q, ref, approximation="robust")
    with pytest.raises(InvalidParameterError, match="l_max"):
        dd.match_adaptive_window(q, ref, l_max=dd.SHARD_UNIT + 1)
    with pytest.raises(InvalidParameterError, match="rule.*one machine"):
        dd.match_adaptive_window(q, ref, rule="longest")


@pytest.mark.parametrize("condition,velocities,window", [("in-order", [1.0], 12), ("reverse", [1.0], 12),
                                                         ("in-order", None, 12), ("reverse", None, 12),
                                                         ("in-order", None, "adaptive"), ("reverse", None, "adaptive")])
def test_cluster_experiment_equals_the_local_run(client, data, condition, velocities, window):
    import warnings

    from catgraph.conditions import Condition
    from catgraph.experiment import Experiment, run, run_on_cluster
    from catgraph.traverse import Traverse

    q, r = data
    q = q.copy()
    q[40] = 1.0  # a constant frame: no information, a zero row in both runs
    reference = Traverse(r, meta={"kind": "descriptors"}, name="ref")
    query = Traverse(q, meta={"kind": "descriptors"}, name="query")
    params = {"window": window, "hub_correction": window == 12, "exclusion": 5}  # both, corrected or not
    if velocities is not None:  # else the registry's default velocities
        params["velocities"] = velocities
    if window == "adaptive":  # a shorter grid than the default, for speed; the cluster's rule
        params.update({"l_max": 50, "grid": 6, "rule": DEFAULT_LINE_RULE})
    exp = Experiment(query=query, reference=reference, method="sequence", params=params,
                     frontend={"metric": "sad"}, condition=Condition(condition))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local, local_out, _ = run(exp)
        remote, remote_out, _ = run_on_cluster(exp, client, shard_places=4096, block_rows=37)
    assert np.array_equal(remote.query_index, local.query_index)
    assert np.array_equal(remote.match, local.match)
    assert np.array_equal(remote.confidence, local.confidence)
    assert np.array_equal(remote.extra["window_length"], local.extra["window_length"])
    assert remote_out["method"] == local_out["method"] and remote_out["params"] == local_out["params"]


def test_cluster_experiment_refuses_what_it_cannot_match_locally(client, data):
    from catgraph.experiment import Experiment, run_on_cluster
    from catgraph.traverse import Traverse

    q, r = data
    kw = {"query": Traverse(q, meta={"kind": "descriptors"}), "reference": Traverse(r, meta={"kind": "descriptors"})}
    with pytest.raises(InvalidParameterError, match="approximation.*gaussian"):
        run_on_cluster(Experiment(method="sequence", params={"window": "adaptive", "approximation": "robust",
                                                             "rule": DEFAULT_LINE_RULE, "hub_correction": False},
                                  **kw), client)
    with pytest.raises(InvalidParameterError, match="rule 'tracked'.*challenged"):  # the local default
        run_on_cluster(Experiment(method="sequence", params={"window": "adaptive", "hub_correction": False}, **kw),
                       client)
    with pytest.raises(InvalidParameterError, match="l_min.*longer than the query"):
        run_on_cluster(Experiment(method="sequence", params={"window": "adaptive", "l_min": 400, "l_max": 500,
                                                             "rule": DEFAULT_LINE_RULE, "hub_correction": False},
                                  **kw), client)
    with pytest.raises(InvalidParameterError, match="does sequence matching"):
        run_on_cluster(Experiment(method="single-frame", **kw), client)


def test_match_command_with_scheduler_writes_the_local_results(client, data, tmp_path, capsys):
    import json

    from catgraph.cli.main import main

    q, r = data
    np.save(tmp_path / "ref.npy", r)
    np.save(tmp_path / "query.npy", q)
    common = [str(tmp_path / "ref.npy"), str(tmp_path / "query.npy"), "--metric", "sad", "--window", "12",
              "--tolerance", "2", "-q"]  # the default velocities, with the hub correction
    assert main(["match", *common, "-o", str(tmp_path / "local.json")]) == 0
    assert main(["match", *common, "--scheduler", client.scheduler.address, "-o", str(tmp_path / "cluster.json")]) == 0
    local, cluster = (json.loads((tmp_path / f"{k}.json").read_text()) for k in ("local", "cluster"))
    assert cluster["frames"]["match"] == local["frames"]["match"]
    assert cluster["frames"]["confidence"] == local["frames"]["confidence"]
    assert cluster["metrics"] == local["metrics"]
    common[common.index("12")] = "adaptive"
    assert main(["match", *common, "--l-max", "20", "--scheduler", client.scheduler.address, "--approximation",
                 "robust", "--rule", DEFAULT_LINE_RULE]) == 1
    assert "gaussian" in capsys.readouterr().err
    # the local default rule: refused, the cluster's rule named
    assert main(["match", *common, "--l-max", "20", "--scheduler", client.scheduler.address]) == 1
    assert f"choose rule {DEFAULT_LINE_RULE!r}" in capsys.readouterr().err


def test_uint8_shards_equal_the_local_compact_reference(client, data):
    from catgraph.differences import PreparedReference, code_scale

    q, r = data
    ref = dd.shard_reference(r, "sad", client, shard_places=4096, layout="uint8")
    assert ref.code_scale == code_scale(r, "sad")
    local = PreparedReference(r, "sad", layout="uint8")
    assert (local.offset, local.step) == ref.code_scale
    for normalise in (False, True):
        got = dd.difference_matrix(q, ref, normalise=normalise, block_rows=50)
        assert np.array_equal(got, difference_matrix(q, local, "sad", normalise=normalise))
    res = dd.match_fixed_window(q, ref, 12, radius=5, velocities=[1.0], confidence="gap", block_rows=37)
    assert_same_as_local(res, difference_matrix(q, local, "sad", normalise=True), 12, 5)
    assert np.all(np.abs(res.match[20:100] - (4050 + np.arange(20, 100))) <= 1)
    with pytest.raises(InvalidParameterError, match="layout"):
        dd.shard_reference(r, "sad", client, layout="int4")
    with pytest.raises(InvalidParameterError, match="step > 0"):
        PreparedReference(r, "sad", layout="uint8", code_scale=(0.0, 0.0))


@pytest.mark.parametrize("layout", ["float32", "uint8"])
def test_shards_from_a_map_file_read_it_a_shard_at_a_time(client, data, tmp_path, monkeypatch, layout):
    """A map file's descriptors left in the file are sharded without being read whole,
    and give the differences of the array itself."""
    from catgraph.differences import PreparedReference
    from catgraph.io import CatgraphMap, StoredDescriptors, load_map, save_map

    q, r = data
    path = save_map(tmp_path / "map.npz", CatgraphMap(r, "sad", {"size": None, "patch": 0, "metric": "sad",
                                                                 "normalise": True}))
    stored = load_map(path, descriptors="stream").descriptors
    monkeypatch.setattr(StoredDescriptors, "__array__", lambda self, dtype=None, copy=None: 1 / 0)
    ref = dd.shard_reference(stored, "sad", client, shard_places=4096, layout=layout)
    monkeypatch.undo()
    local = PreparedReference(r, "sad", layout=layout)
    assert ref.code_scale == (None if layout == "float32" else (local.offset, local.step))
    got = dd.difference_matrix(q, ref, normalise=True, block_rows=50)
    assert np.array_equal(got, difference_matrix(q, local, "sad", normalise=True))


def test_a_cluster_without_workers_is_waited_for_then_refused(monkeypatch):
    """A cluster with no worker (one still starting) gets WORKER_WAIT_S seconds, then a
    clear error, not a division by zero or a hang."""
    distributed = pytest.importorskip("distributed")
    monkeypatch.setattr(dd, "WORKER_WAIT_S", 0.5)
    cluster = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None)
    client = distributed.Client(cluster)
    try:
        start = time.perf_counter()
        with pytest.raises(InvalidParameterError, match="no workers .none joined in 0.5 s"):
            dd.shard_reference(np.ones((10, 4), np.float32), "sad", client)
        assert time.perf_counter() - start >= 0.5
    finally:
        client.close()
        cluster.close()


@pytest.mark.parametrize("max_rows", [None, 200, 3000])
def test_hub_offsets_on_the_cluster_equal_the_maps(client, max_rows):
    """The offsets from the shards: every frame, a sample normalised locally as one block
    (200 rows), and a sample in several column blocks; the same floats as
    ``hubs.map_hub_offsets``."""
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import CatgraphMap

    r, _ = hub_map(np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)]))
    the_map = CatgraphMap(r, "sad", {"size": None, "patch": 0, "metric": "sad", "normalise": True})
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    kw = {} if max_rows is None else {"max_rows": max_rows}
    local = map_hub_offsets(the_map, **kw)
    assert np.count_nonzero(local) == 3  # not trivial: the hubs are found
    assert np.array_equal(dd.map_hub_offsets(ref, r, **kw), local)
    raw = dd.map_hub_offsets(ref, r, normalise=False, **kw)
    plain = CatgraphMap(r, "sad", {"size": None, "patch": 0, "metric": "sad", "normalise": False})
    assert np.array_equal(raw, map_hub_offsets(plain, **kw))


def test_hub_offsets_of_uint8_shards_and_of_a_map_file(client, tmp_path, monkeypatch):
    from catgraph.differences import PreparedReference
    from catgraph.hubs import map_hub_offsets
    from catgraph.io import CatgraphMap, StoredDescriptors, load_map, save_map
    from catgraph.live import reference_hub_offsets

    r, _ = hub_map(np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)]))
    coded_ref = dd.shard_reference(r, "sad", client, shard_places=4096, layout="uint8")
    compact = reference_hub_offsets(PreparedReference(r, "sad", layout="uint8"), max_rows=500)
    assert np.count_nonzero(compact) == 3
    assert np.array_equal(dd.map_hub_offsets(coded_ref, r, max_rows=500), compact)
    the_map = CatgraphMap(r, "sad", {"size": None, "patch": 0, "metric": "sad", "normalise": True})
    stored = load_map(save_map(tmp_path / "map.npz", the_map), descriptors="stream").descriptors
    monkeypatch.setattr(StoredDescriptors, "__array__", lambda self, dtype=None, copy=None: 1 / 0)
    ref = dd.shard_reference(stored, "sad", client, shard_places=4096)
    assert np.array_equal(dd.map_hub_offsets(ref, stored, max_rows=500), map_hub_offsets(the_map, max_rows=500))
    with pytest.raises(InvalidParameterError, match="descriptors hold 8199 places but the shards 8200"):
        dd.map_hub_offsets(ref, r[:-1])
    with pytest.raises(InvalidParameterError, match="max_rows"):
        dd.map_hub_offsets(ref, stored, max_rows=0)
    stored.close()


def test_a_cluster_run_on_a_map_file_never_reads_it_whole(client, tmp_path, monkeypatch):
    """``run_on_cluster`` (``catgraph match --map FILE --scheduler``) leaves the map's
    descriptors in the file (shards and hub offsets read what they need) and gives the
    local run's answers."""
    from catgraph.experiment import Experiment, run, run_on_cluster
    from catgraph.io import StoredDescriptors, build_map, save_map
    from catgraph.pipeline import FrontEnd
    from catgraph.traverse import Traverse

    r, q = hub_map(np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)]))
    positions = np.stack([np.arange(len(r), dtype=float), np.zeros(len(r))], axis=1)
    reference = Traverse(r, positions=positions, meta={"kind": "descriptors"}, name="ref")
    path = save_map(tmp_path / "map.npz", build_map(reference, FrontEnd(metric="sad")))
    query = Traverse(q, positions=positions[np.concatenate([np.arange(3990, 4190), np.arange(8120, 8200)])],
                     meta={"kind": "descriptors"}, name="query")
    exp = Experiment(query=query, map=path, method="sequence", params={"window": 20, "hub_correction": True},
                     tolerance_m=2.0)
    local, local_out, _ = run(exp)
    monkeypatch.setattr(StoredDescriptors, "__array__", lambda self, dtype=None, copy=None: 1 / 0)
    opened = []
    init = StoredDescriptors.__init__
    monkeypatch.setattr(StoredDescriptors, "__init__", lambda self, *a, **k: (opened.append(1), init(self, *a, **k))[1])
    from catgraph.graph import PlaceGraph

    monkeypatch.setattr(PlaceGraph, "from_edges", lambda *a, **k: 1 / 0)  # nor its graph built
    remote, remote_out, _ = run_on_cluster(exp, client, shard_places=4096, block_rows=64)
    assert opened == [1]  # the map's descriptors were left in the file
    assert np.array_equal(remote.match, local.match)
    assert np.array_equal(remote.confidence, local.confidence)
    assert remote_out["metrics"] == local_out["metrics"] and local_out["metrics"]["auc"] > 0.5


@pytest.mark.parametrize("layout", ["float32", "uint8"])
def test_a_shard_larger_than_a_piece_is_sent_in_pieces(client, data, tmp_path, monkeypatch, layout):
    """Shards sent a piece at a time (the client reads no more than a piece of a map file at
    once) hold the array's own rows: the same differences, nothing left behind on the workers."""
    from catgraph.differences import PreparedReference
    from catgraph.io import CatgraphMap, StoredDescriptors, load_map, save_map

    q, r = data
    path = save_map(tmp_path / "map.npz", CatgraphMap(r, "sad", {"size": None, "patch": 0, "metric": "sad",
                                                                 "normalise": True}))
    stored = load_map(path, descriptors="stream").descriptors
    piece_rows = 1000  # 9 pieces or parts of them per 4096-place shard
    monkeypatch.setattr(dd, "SHARD_PIECE_BYTES", piece_rows * r.shape[1] * r.itemsize)
    reads = []
    rows_of = StoredDescriptors._rows
    monkeypatch.setattr(StoredDescriptors, "_rows", lambda self, a, b: (reads.append(b - a), rows_of(self, a, b))[1])
    ref = dd.shard_reference(stored, "sad", client, shard_places=4096, layout=layout)
    distributed.wait(ref.shards)
    assert max(reads) == piece_rows and sum(reads) == len(r)
    def left():  # the pieces and the rows they were written into, once the shards are prepared
        return [k for keys in client.has_what().values() for k in keys
                if str(k).startswith(("_empty_rows", "_write_rows", "_filled"))]

    deadline = time.monotonic() + 10.0
    while left() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert left() == []
    local = PreparedReference(r, "sad", layout=layout)
    got = dd.difference_matrix(q, ref, normalise=True, block_rows=50)
    assert np.array_equal(got, difference_matrix(q, local, "sad", normalise=True))
    stored.close()


def test_match_command_shards_as_asked(client, data, tmp_path, monkeypatch, capsys):
    """``--shard-places`` and ``--layout`` reach the sharding; without ``--scheduler`` they
    are refused with the fix named."""
    import json

    from catgraph.cli.main import main

    q, r = data
    np.save(tmp_path / "ref.npy", r)
    np.save(tmp_path / "query.npy", q)
    common = [str(tmp_path / "ref.npy"), str(tmp_path / "query.npy"), "--metric", "sad", "--window", "12",
              "--tolerance", "2", "-q"]
    asked = []
    shard = dd.shard_reference
    monkeypatch.setattr(dd, "shard_reference", lambda *a, **k: (asked.append((a[3], k["layout"])), shard(*a, **k))[1])
    address = client.scheduler.address
    assert main(["match", *common, "--scheduler", address, "-o", str(tmp_path / "f32.json")]) == 0
    assert main(["match", *common, "--scheduler", address, "--shard-places", "4096", "--layout", "uint8",
                 "-o", str(tmp_path / "u8.json")]) == 0
    assert asked == [(None, "float32"), (4096, "uint8")]
    f32, u8 = (json.loads((tmp_path / f"{k}.json").read_text()) for k in ("f32", "u8"))
    assert u8["frames"]["confidence"] != f32["frames"]["confidence"]  # the compact layout's differences
    assert np.mean(np.equal(u8["frames"]["match"], f32["frames"]["match"])) > 0.9  # nearly the same places
    capsys.readouterr()
    for flags in (["--shard-places", "4096"], ["--layout", "uint8"]):
        assert main(["match", *common, *flags]) == 1
        assert f"{flags[0]} sets how a cluster run shards the map; add --scheduler" in capsys.readouterr().err
