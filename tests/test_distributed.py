"""Dask-sharded batch evaluation equals the local run (on a LocalCluster)."""

import numpy as np
import pytest

from catgraph.differences import difference_matrix
from catgraph.exceptions import InvalidParameterError

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402


def slow_scores(d, window):
    """Obviously correct window scores: direct sums, the edge policy of catgraph.sequence."""
    n_q, n = d.shape
    row_mean = d.mean(1)
    out = np.empty_like(d)
    for i in range(n_q):
        eff = min(window, i + 1)
        total = np.zeros(n)
        for k in range(eff):
            col = np.arange(n) - k
            total += np.where(col >= 0, d[i - k, np.maximum(col, 0)], row_mean[i - k])
        out[i] = total / eff
    return out


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


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
    expected = slow_scores(local, 12)
    got = dd.window_scores(q, ref, 12, block_rows=37)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    res = dd.match_fixed_window(q, ref, 12, radius=5, block_rows=37)
    assert np.array_equal(res.match, expected.argmin(1))  # window spans shard boundaries at 4096
    assert np.all(np.abs(res.match[20:100] - (4050 + np.arange(20, 100))) <= 1)
    best = expected.min(1)
    g = np.arange(r.shape[0])
    second = np.where(np.abs(g[None] - res.match[:, None]) <= 5, np.inf, expected).min(1)
    np.testing.assert_allclose(res.confidence, (second - best) / expected.std(1), rtol=1e-9)


def test_bad_inputs(client, data):
    q, r = data
    with pytest.raises(InvalidParameterError, match="metric"):
        dd.shard_reference(r, "l3", client)
    with pytest.raises(InvalidParameterError, match="scheduler"):
        dd.shard_reference(r, "sad", 42)
    ref = dd.shard_reference(r, "sad", client)
    with pytest.raises(InvalidParameterError, match="window"):
        dd.match_fixed_window(q, ref, dd.SHARD_UNIT + 1)


@pytest.mark.parametrize("condition", ["in-order", "reverse"])
def test_cluster_experiment_equals_the_local_run(client, data, condition):
    import warnings

    from catgraph.conditions import Condition
    from catgraph.experiment import Experiment, prepare, run, run_on_cluster
    from catgraph.traverse import Traverse

    q, r = data
    q = q.copy()
    q[40] = 1.0  # a constant frame: no information, a zero row in both runs
    reference = Traverse(r, meta={"kind": "descriptors"}, name="ref")
    query = Traverse(q, meta={"kind": "descriptors"}, name="query")
    params = {"window": 12, "velocities": [1.0], "hub_correction": False, "exclusion": 5}
    exp = Experiment(query=query, reference=reference, method="sequence", params=params,
                     frontend={"metric": "sad"}, condition=Condition(condition))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local, local_out, _ = run(exp)
        remote, remote_out, _ = run_on_cluster(exp, client, shard_places=4096, block_rows=37)
    assert np.array_equal(remote.query_index, local.query_index)
    # the local matcher keeps its rows as integer codes of a quantum u fixed by the first row
    # (catgraph.sequence, "Precision"): each score within u of the float64 scores the shards compute.
    # So a match may differ only at a near tie (the two places' float64 scores within 2u), and a
    # gap (s2 - s1) / std lies within (2 + |gap|) u / std where the matches agree
    from catgraph.sequence import fixed_window_scores

    d = np.asarray(prepare(exp).differences, dtype=np.float64)  # rows in processing order
    u = 2.0 ** (int(np.frexp(np.abs(d[0]).max())[1]) - 12)

    def exact(i, j):  # float64 window score along v = 1 (edge fill: the row's mean)
        terms = [d[i - t, j - t] if j - t >= 0 else d[i - t].mean() for t in range(min(12, i + 1))]
        return sum(terms) / len(terms)

    same = remote.match == local.match
    assert same.mean() > 0.95
    for i in np.flatnonzero(~same):
        assert abs(exact(i, local.match[i]) - exact(i, remote.match[i])) <= 2 * u
    spread = fixed_window_scores(d, 12).std(axis=1)
    bound = (2 + np.abs(local.confidence)) * u / spread * (1 + 1e-6)
    assert np.all(np.abs(remote.confidence - local.confidence)[same] <= bound[same])
    assert np.array_equal(remote.extra["window_length"], local.extra["window_length"])
    assert remote_out["method"] == local_out["method"] and remote_out["params"] == local_out["params"]


def test_cluster_experiment_refuses_what_it_cannot_match_locally(client, data):
    from catgraph.experiment import Experiment, run_on_cluster
    from catgraph.traverse import Traverse

    q, r = data
    kw = {"query": Traverse(q, meta={"kind": "descriptors"}), "reference": Traverse(r, meta={"kind": "descriptors"})}
    with pytest.raises(InvalidParameterError, match="--velocities 1.*--no-hub-correction"):
        run_on_cluster(Experiment(method="sequence", params={"window": 12}, **kw), client)
    with pytest.raises(InvalidParameterError, match="fixed --window"):
        run_on_cluster(Experiment(method="sequence", params={"window": "adaptive", "velocities": [1.0],
                                                             "hub_correction": False}, **kw), client)
    with pytest.raises(InvalidParameterError, match="fixed-window sequence"):
        run_on_cluster(Experiment(method="single-frame", **kw), client)


def test_match_command_with_scheduler_writes_the_local_results(client, data, tmp_path, capsys):
    import json

    from catgraph.cli.main import main

    q, r = data
    np.save(tmp_path / "ref.npy", r)
    np.save(tmp_path / "query.npy", q)
    common = [str(tmp_path / "ref.npy"), str(tmp_path / "query.npy"), "--metric", "sad", "--window", "12",
              "--velocities", "1", "--no-hub-correction", "--tolerance", "2", "-q"]
    assert main(["match", *common, "-o", str(tmp_path / "local.json")]) == 0
    assert main(["match", *common, "--scheduler", client.scheduler.address, "-o", str(tmp_path / "cluster.json")]) == 0
    local, cluster = (json.loads((tmp_path / f"{k}.json").read_text()) for k in ("local", "cluster"))
    assert cluster["frames"]["match"] == local["frames"]["match"]
    # integer codes of a quantum u locally (see test_cluster_experiment_equals_the_local_run): a gap
    # within (2 + |gap|) u / std of the float64 one
    from catgraph.experiment import Experiment, prepare
    from catgraph.sequence import fixed_window_scores
    from catgraph.traverse import Traverse

    d = np.asarray(prepare(Experiment(query=Traverse(q, meta={"kind": "descriptors"}),
                                      reference=Traverse(r, meta={"kind": "descriptors"}),
                                      frontend={"metric": "sad"})).differences, dtype=np.float64)
    u = 2.0 ** (int(np.frexp(np.abs(d[0]).max())[1]) - 12)
    conf = np.array(local["frames"]["confidence"])
    bound = (2 + np.abs(conf)) * u / fixed_window_scores(d, 12).std(axis=1) * (1 + 1e-6)
    assert np.all(np.abs(np.array(cluster["frames"]["confidence"]) - conf) <= bound)
    assert cluster["metrics"]["auc"] == pytest.approx(local["metrics"]["auc"])
    common.remove("--no-hub-correction")
    assert main(["match", *common, "--scheduler", client.scheduler.address]) == 1
    assert "--no-hub-correction" in capsys.readouterr().err


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
    res = dd.match_fixed_window(q, ref, 12, radius=5, block_rows=37)
    assert np.all(np.abs(res.match[20:100] - (4050 + np.arange(20, 100))) <= 1)
    with pytest.raises(InvalidParameterError, match="layout"):
        dd.shard_reference(r, "sad", client, layout="int4")
    with pytest.raises(InvalidParameterError, match="step > 0"):
        PreparedReference(r, "sad", layout="uint8", code_scale=(0.0, 0.0))
