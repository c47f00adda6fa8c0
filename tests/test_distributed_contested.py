"""Rules "contested", "persistent" and "challenged" on the cluster equal the local run (LocalCluster).

The rule reads what rule "gated" reads (the decorrelation horizon of rule "spanning" and the
window statistics of the summaries); its second rival is a function of those statistics alone.
Every field must equal the local :func:`catgraph.sequence.match_sequences` bit for bit, on a
route where the contested rival changes the answers.
"""

import numpy as np
import pytest

from catgraph.conditions import Condition
from catgraph.differences import difference_matrix
from catgraph.sequence import match_sequences

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402

FIELDS = ("match", "score", "velocity", "window_length", "confidence")

CONTESTED = {"rule": "contested", "l_min": 2, "l_max": 40, "grid": 6, "velocities": (-1.0, 1.0, 2.0),
             "recent_fraction": 0.3}


def repeated_map(seed: int = 0, noise: float = 2.0, copy: float = 0.8):
    """A map of independent places whose stretch 6000-6199 is a weaker copy of 4000-4199
    (repeated scenery), and a noisy query that drives 4000-4199 at a speed changing from frame
    to frame (one or two places), jumps to 1000 and then crosses the shard edge at 8192.
    Returns ``(query, reference)``."""
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(8200, 16)).astype(np.float32)
    r[6000:6200] = copy * r[4000:4200] + np.sqrt(1 - copy ** 2) * rng.normal(size=(200, 16)).astype(np.float32)
    first = 4000 + np.cumsum(rng.choice([1, 1, 2], size=150))
    places = np.concatenate([first, 1000 + np.cumsum(rng.choice([1, 2], size=60)), 8100 + np.arange(90)])
    q = r[places] + noise * rng.normal(size=(places.size, 16)).astype(np.float32)
    return q, r


@pytest.fixture(scope="module")
def repeated():
    return repeated_map()


@pytest.fixture(scope="module")
def sharded(client, repeated):
    return dd.shard_reference(repeated[1], "sad", client, shard_places=4096)


def test_contest_changes_the_answers_on_this_route(repeated):
    # the comparison below is not vacuous: with rule "gated" the local answers differ
    q, r = repeated
    local = difference_matrix(q, r, "sad", normalise=True)
    out = match_sequences(local, **CONTESTED)
    gated = match_sequences(local, **{**CONTESTED, "rule": "gated"})
    assert np.sum(out.window_length != gated.window_length) >= 3


@pytest.mark.parametrize("condition, confidence", [
    (Condition("in-order"), "changepoint"),
    (Condition("in-order"), "gap"),
    (Condition("reverse"), "posterior"),
    (Condition("shuffle", seed=1, segment_range=(0.05, 0.2)), "changepoint"),
])
def test_contested_equals_the_local_matcher(sharded, repeated, condition, confidence):
    # blocks of HORIZON_ROWS + 29 frames: the horizon's chunks cross the blocks
    q, r = repeated
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(CONTESTED, confidence=confidence)
    out = match_sequences(local, **params)
    res = dd.match_adaptive_window(q, sharded, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


PERSISTENT = {"rule": "persistent", "l_min": 2, "l_max": 60, "grid": 6, "velocities": (-1.0, 1.0, 1.0 / 3.0),
              "recent_fraction": 0.05}


@pytest.fixture(scope="module")
def fog():
    from tests.test_distributed_punctuated import fog_map

    return fog_map()


@pytest.fixture(scope="module")
def fog_sharded(client, fog):
    return dd.shard_reference(fog[1], "sad", client, shard_places=4096)


def test_midpoint_gate_changes_the_answers_on_the_fog_route(fog):
    # rule "persistent" reads the breaks of the rows (as "punctuated"); on this route its answers
    # differ from rule "contested"'s, so the comparison below is not vacuous
    q, r = fog
    local = difference_matrix(q, r, "sad", normalise=True)
    out = match_sequences(local, **PERSISTENT)
    contested = match_sequences(local, **{**PERSISTENT, "rule": "contested"})
    assert np.sum(out.window_length != contested.window_length) >= 5


@pytest.mark.parametrize("condition, confidence", [
    (Condition("in-order"), "changepoint"),
    (Condition("reverse"), "posterior"),
    (Condition("shuffle", seed=1, segment_range=(0.05, 0.2)), "changepoint"),
])
def test_persistent_equals_the_local_matcher(fog_sharded, fog, condition, confidence):
    q, r = fog
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(PERSISTENT, confidence=confidence)
    out = match_sequences(local, **params)
    res = dd.match_adaptive_window(q, fog_sharded, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


CHALLENGED = {**CONTESTED, "rule": "challenged"}


def test_unproven_rival_changes_the_answers_on_the_repeated_route(repeated):
    # rule "challenged" reads what "persistent" reads; on this route its answers differ from
    # rule "persistent"'s, so the comparison below is not vacuous
    q, r = repeated
    local = difference_matrix(q, r, "sad", normalise=True)
    out = match_sequences(local, **CHALLENGED)
    persistent = match_sequences(local, **{**CHALLENGED, "rule": "persistent"})
    assert np.sum(out.window_length != persistent.window_length) >= 5


@pytest.mark.parametrize("condition, confidence", [
    (Condition("in-order"), "changepoint"),
    (Condition("reverse"), "posterior"),
    (Condition("shuffle", seed=1, segment_range=(0.05, 0.2)), "changepoint"),
])
def test_challenged_equals_the_local_matcher(sharded, repeated, condition, confidence):
    q, r = repeated
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(CHALLENGED, confidence=confidence)
    out = match_sequences(local, **params)
    res = dd.match_adaptive_window(q, sharded, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_challenged_equals_the_local_matcher_on_the_fog_route(fog_sharded, fog):
    # the breaks of the rows travel from block to block as for "punctuated"
    q, r = fog
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(PERSISTENT, rule="challenged", confidence="changepoint")
    out = match_sequences(local, **params)
    res = dd.match_adaptive_window(q, fog_sharded, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
