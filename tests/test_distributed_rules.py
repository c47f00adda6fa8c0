"""The window rules that read the difference rows, on the cluster, equal the local run (LocalCluster)."""

import numpy as np
import pytest

from catgraph.conditions import Condition
from catgraph.differences import difference_matrix
from catgraph.exceptions import InvalidParameterError
from catgraph.sequence import match_sequences
from .conftest import alike_map, hub_case

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402
from catgraph import _window_rule as wr  # noqa: E402

FIELDS = ("match", "score", "velocity", "window_length", "confidence")


@pytest.fixture(scope="module")
def route():
    """A route that crosses the shard edge at 4096, jumps, and runs off the end of the map
    (shards of 4096, 4096 and 8 places)."""
    rng = np.random.default_rng(11)
    r = rng.normal(size=(8200, 16)).astype(np.float32)
    places = np.concatenate([np.arange(4000, 4130), np.arange(2000, 2040), np.arange(8150, 8200)])
    return r[places] + 0.5 * rng.normal(size=(places.size, 16)).astype(np.float32), r


@pytest.fixture(scope="module")
def sharded(client, route):
    return dd.shard_reference(route[1], "sad", client, shard_places=4096)


CONDITIONS = [Condition("in-order"), Condition("reverse"), Condition("shuffle", seed=1, segment_range=(0.05, 0.2)),
              Condition("speed", factor=2.0)]


@pytest.mark.parametrize("rule", ["predictive", "decorrelated"])
@pytest.mark.parametrize("condition", CONDITIONS)
def test_record_rules_equal_the_local_matcher(sharded, route, condition, rule):
    q, r = route
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = {"rule": rule, "l_max": 48, "grid": 5}
    # blocks shorter than the horizon's reach, so that the record crosses block edges
    res = dd.match_adaptive_window(q, sharded, block_rows=37, **params)
    out = match_sequences(local, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_predictive_rule_reads_the_rows(sharded, route):
    # not trivial: the record chooses several lengths, and its choices are not those of the
    # same statistics read without the rows' values (all losses zero: always the longest)
    q, r = route
    local = difference_matrix(q, r, "sad", normalise=True)
    params = {"rule": "predictive", "l_max": 48, "grid": 5, "confidence": "gap", "velocities": (-1.0, 1.0, 2.0)}
    res = dd.match_adaptive_window(q, sharded, block_rows=64, **params)
    out = match_sequences(local, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
    assert len(np.unique(out.window_length[60:])) > 1
    assert np.any(out.window_length[wr.PREDICTION_HORIZON:] < 48)


def test_predicted_places_match_a_direct_replay(route):
    # the lookups planned before the rule runs equal, frame by frame, the places
    # _Record.loss reads when it is replayed on whole rows
    q, r = route
    d = difference_matrix(q, r, "sad", normalise=True)
    rng = np.random.default_rng(0)
    n_q, n = d.shape
    st = wr._Stats(n_q, 2, 3, 1, with_sub=False)
    st.best_j[...] = rng.integers(0, n, size=st.best_j.shape)
    st.best_j[::3] = rng.integers(0, 15, size=st.best_j[::3].shape)  # lines that leave the map's start ...
    st.best_j[1::3] = rng.integers(n - 15, n, size=st.best_j[1::3].shape)  # ... and its end
    st.best_s[...] = rng.normal(size=st.best_s.shape)
    st.mean[...], st.std[...] = 0.0, 1.0
    st.weights[...], st.locs[...], st.scales[...] = 1.0, 0.0, 1.0
    cfg = type("Cfg", (), {"velocities": np.array([-1.0, 2.0]), "grid": np.array([5, 10, 20])})()
    velocity = np.argmin(wr._log_p(st).sum(axis=2), axis=1)
    planned, record = [], wr._Record(3)
    for start in range(0, n_q, 23):  # blocks, the record carried over as _match carries it
        stop = min(n_q, start + 23)
        sub = wr._Stats(stop - start, 2, 3, 1, with_sub=False)
        for name in ("best_j", "best_s", "mean", "std", "weights", "locs", "scales"):
            getattr(sub, name)[...] = getattr(st, name)[start:stop]
        planned.append(dd._predicted_places(sub, cfg, record, start, n))
        for t in range(stop - start):
            i = start + t
            record.remember(i, st.best_j[i, velocity[i]], float(cfg.velocities[velocity[i]]))
    planned = np.concatenate(planned)
    replay = wr._Record(3)
    for i in range(n_q):
        if i >= replay.horizon:
            slot = (i - replay.horizon) % replay.horizon
            places = replay.offsets[slot] + wr._position(replay.velocity[slot], i)
            expected = np.where((places >= 0) & (places < n), places, 0)
            assert np.array_equal(planned[i], expected), i
        else:
            assert np.all(planned[i] == -1)
        replay.remember(i, st.best_j[i, velocity[i]], float(cfg.velocities[velocity[i]]))
    assert np.any(planned[replay.horizon:] == 0)  # some lines left the map


@pytest.mark.parametrize("rule", ["predictive", "decorrelated", "spanning"])
def test_record_rules_with_hubs_and_frames_without_information(client, rule):
    # flat frames (hubs) in every shard, blank query frames: the rows the rule reads are
    # corrected and normalised again on the shards, as locally
    q, ref, local, blank, offsets = hub_case(client, dd)
    params = {"rule": rule, "l_max": 30, "grid": 4}
    res = dd.match_adaptive_window(q, ref, block_rows=50, no_information=blank, hub_offsets=offsets, **params)
    out = match_sequences(local, hub_offsets=offsets, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_decorrelated_horizon_moves_and_crosses_blocks(client):
    # the horizon is not constant on this route (so the lookups follow it), the horizon
    # tasks are chained across blocks and across HORIZON_ROWS chunks within a block, and
    # the shards are three (rows put together from three workers' columns)
    # a map whose neighbouring places look alike (each descriptor averaged over 9 places):
    # the query's rows take several frames to decorrelate
    rng = np.random.default_rng(7)
    base = rng.normal(size=(8200, 16))
    r = np.stack([np.convolve(base[:, c], np.ones(9) / 9, mode="same") for c in range(16)], 1).astype(np.float32)
    places = np.concatenate([np.arange(4000, 4130), np.arange(2000, 2040), np.arange(8150, 8200)])
    q = r[places] + (0.3 * r.std()) * rng.normal(size=(places.size, 16)).astype(np.float32)
    local = difference_matrix(q, r, "sad", normalise=True)
    clock = wr._Horizon()
    ks = np.array([clock.update(row, i, row.std()) for i, row in enumerate(local)])
    assert len(np.unique(ks)) > 2 and ks.min() < wr.HORIZON_MAX
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    assert len(ref.bounds) == 3
    params = {"rule": "decorrelated", "l_max": 30, "grid": 4, "confidence": "gap", "velocities": (-1.0, 1.0, 2.0)}
    res = dd.match_adaptive_window(q, ref, block_rows=dd.HORIZON_ROWS + 29, **params)
    out = match_sequences(local, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_every_rule_is_exact_on_the_cluster(sharded, route):
    from catgraph.sequence import RULES

    assert set(dd.EXACT_RULES) <= set(RULES)
    for rule in sorted(set(RULES) - set(dd.EXACT_RULES)) + ["longest"]:  # any other rule is refused
        with pytest.raises(InvalidParameterError, match="rule.*one machine"):
            dd.match_adaptive_window(route[0], sharded, rule=rule)


def test_cluster_experiment_with_rule_decorrelated_equals_the_local_run(client):
    # the registry's adaptive method through run_on_cluster: the rule, hub correction and a
    # frame without information, as the experiment layer hands them to the matcher
    import warnings

    from catgraph.conditions import Condition
    from catgraph.experiment import Experiment, run, run_on_cluster
    from catgraph.traverse import Traverse

    rng = np.random.default_rng(7)
    base = rng.normal(size=(8200, 16))
    r = np.stack([np.convolve(base[:, c], np.ones(9) / 9, mode="same") for c in range(16)], 1).astype(np.float32)
    places = np.concatenate([np.arange(4040, 4160), np.arange(600, 660)])
    q = r[places] + (0.3 * r.std()) * rng.normal(size=(places.size, 16)).astype(np.float32)
    q[30] = 1.0  # a constant frame: no information
    params = {"window": "adaptive", "rule": "decorrelated", "l_max": 40, "grid": 4, "hub_correction": True}
    exp = Experiment(query=Traverse(q, meta={"kind": "descriptors"}, name="query"),
                     reference=Traverse(r, meta={"kind": "descriptors"}, name="ref"), method="sequence",
                     params=params, frontend={"metric": "sad"}, condition=Condition("reverse"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local, _, _ = run(exp)
        remote, _, _ = run_on_cluster(exp, client, shard_places=4096, block_rows=45)
    assert np.array_equal(remote.match, local.match)
    assert np.array_equal(remote.confidence, local.confidence)
    assert np.array_equal(remote.extra["window_length"], local.extra["window_length"])


@pytest.fixture(scope="module")
def alike():
    """:func:`conftest.alike_map`."""
    return alike_map()


SPANNING = {"rule": "spanning", "l_max": 30, "grid": 4, "velocities": (-1.0, 1.0, 2.0)}


def _run_with_clock(local, params, k):
    """The local run with the horizon held at ``k`` on every frame (a wrong clock)."""
    original = wr._Horizon.update
    wr._Horizon.update = lambda self, row, i, spread, centre=None: k
    try:
        return match_sequences(local, **params)
    finally:
        wr._Horizon.update = original


@pytest.mark.parametrize("condition, confidence, wrong_clocks", [
    (Condition("in-order"), "posterior", (1, wr.HORIZON_MAX)),
    (Condition("reverse"), "gap", (1, wr.HORIZON_MAX)),
    (Condition("shuffle", seed=1, segment_range=(0.05, 0.2)), "posterior", (1, wr.HORIZON_MAX)),
    (Condition("speed", factor=2.0), "gap", (wr.HORIZON_MAX,)),
])
def test_spanning_rule_reads_the_horizon_and_equals_the_local_matcher(client, alike, condition, confidence,
                                                                      wrong_clocks):
    # on this route the horizon decides: a clock that says every line spans it (1), or
    # that none does (HORIZON_MAX, longer than every window), gives other answers; the
    # cluster's horizon, computed on shard 0's worker from whole rows in chunks that
    # cross blocks, gives the local ones. With confidence "gap" the rule reads no row
    # moments at all (no moment rounds): only the horizon.
    q, r = alike
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(SPANNING, confidence=confidence)
    out = match_sequences(local, **params)
    for k in wrong_clocks:
        wrong = _run_with_clock(local, params, k)
        assert any(not np.array_equal(getattr(wrong, name), getattr(out, name)) for name in FIELDS), k
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    res = dd.match_adaptive_window(q, ref, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_spanning_rule_asks_no_lookups(client, alike, monkeypatch):
    # rule "spanning" reads only the record's clock: the G lookups of the record rules are
    # never planned, and with confidence "gap" no row moments are reduced
    q, r = alike
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    calls = {"places": 0, "moments": 0}
    planned, moments = dd._predicted_places, dd._row_moments

    def count(name, fn):
        def wrapped(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(dd, "_predicted_places", count("places", planned))
    monkeypatch.setattr(dd, "_row_moments", count("moments", moments))
    dd.match_adaptive_window(q[:80], ref, confidence="gap", block_rows=40, **{**SPANNING, "velocities": (1.0,)})
    assert calls == {"places": 0, "moments": 0}
    dd.match_adaptive_window(q[:80], ref, block_rows=40, **{**SPANNING, "velocities": (1.0,)})
    assert calls == {"places": 0, "moments": 2}  # the default confidence's rounds, one per block


def _with_rule_default(monkeypatch, fn, rule):
    """``fn`` with its ``rule`` parameter's default set to ``rule``."""
    import inspect

    names = [p.name for p in inspect.signature(fn).parameters.values() if p.default is not inspect.Parameter.empty]
    defaults = list(fn.__defaults__)
    defaults[names.index("rule")] = rule
    monkeypatch.setattr(fn, "__defaults__", tuple(defaults))


def test_default_rule_is_the_libraries_line_rule_and_runs_exactly(client, alike):
    import inspect

    from catgraph import sequence

    rule = inspect.signature(dd.match_adaptive_window).parameters["rule"].default
    assert rule == sequence.DEFAULT_LINE_RULE
    assert rule in dd.EXACT_RULES
    # the local default (a filter beside the matcher) is refused, naming the cluster's rule
    assert sequence.DEFAULT_RULE == inspect.signature(match_sequences).parameters["rule"].default == "tracked"
    q, r = alike
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    with pytest.raises(InvalidParameterError, match="rule 'tracked'.*'challenged'"):
        dd.match_adaptive_window(q, ref, rule=sequence.DEFAULT_RULE, l_max=30, grid=4)


@pytest.mark.parametrize("rule", ["spanning", "punctuated", "gated", "contested", "persistent", "challenged",
                                  "unrivalled"])
def test_default_call_equals_the_local_default_call(client, alike, monkeypatch, rule):
    # whichever rule is the library's default (sequence.DEFAULT_RULE, read by both
    # functions' defaults), the cluster's default call gives the local default call's answers
    from catgraph import sequence

    _with_rule_default(monkeypatch, match_sequences, rule)
    _with_rule_default(monkeypatch, dd.match_adaptive_window, rule)
    monkeypatch.setattr(sequence, "DEFAULT_RULE", rule)
    q, r = alike
    local = difference_matrix(q, r, "sad", normalise=True)
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    out = match_sequences(local, l_max=30, grid=4)
    assert np.array_equal(out.window_length, match_sequences(local, l_max=30, grid=4, rule=rule).window_length)
    res = dd.match_adaptive_window(q, ref, l_max=30, grid=4, block_rows=100)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
