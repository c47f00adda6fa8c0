"""Confidence "changepoint" on the cluster equals the local run (LocalCluster).

The confidence reads the latest ``T`` rows at the places along each frame's chosen line,
which the client learns only once the rule has chosen the line; the shards that hold those
places serve them (a line can cross a shard edge, and its earlier frames can lie in the
previous block). Every field must equal the local :func:`catgraph.sequence.match_sequences`
bit for bit.
"""

import numpy as np
import pytest

from catgraph import _window_rule as wr
from catgraph.conditions import Condition
from catgraph.differences import difference_matrix
from catgraph.sequence import match_sequences
from .conftest import alike_map, hub_case

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402

FIELDS = ("match", "score", "velocity", "window_length", "confidence")


@pytest.fixture(scope="module")
def alike():
    """:func:`conftest.alike_map`."""
    return alike_map()


@pytest.fixture(scope="module")
def sharded(client, alike):
    return dd.shard_reference(alike[1], "sad", client, shard_places=4096)


CHANGEPOINT = {"rule": "spanning", "l_max": 30, "grid": 4, "velocities": (-1.0, 1.0, 2.0), "confidence": "changepoint"}


@pytest.mark.parametrize("condition", [Condition("in-order"), Condition("reverse"), Condition("speed", factor=2.0),
                                       Condition("shuffle", seed=1, segment_range=(0.05, 0.2))])
def test_changepoint_equals_the_local_matcher(sharded, alike, condition):
    # blocks of 37 frames: the latest rows of a block's first frames lie in the previous block
    q, r = alike
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    out = match_sequences(local, **CHANGEPOINT)
    res = dd.match_adaptive_window(q, sharded, block_rows=37, **CHANGEPOINT)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name
    # not the current frame alone: the confidence differs from "posterior" at the same matches
    posterior = match_sequences(local, **{**CHANGEPOINT, "confidence": "posterior"})
    assert np.array_equal(posterior.match, out.match)
    assert not np.array_equal(posterior.confidence, out.confidence)


@pytest.mark.parametrize("rule", ["unrivalled", "predictive", "decorrelated"])
def test_changepoint_with_other_rules_and_hubs(client, rule):
    # flat frames (hubs) in every shard, blank query frames, the rule's own lookups beside the lines'
    q, ref, local, blank, offsets = hub_case(client, dd)
    params = {"rule": rule, "l_max": 30, "grid": 4, "confidence": "changepoint"}
    res = dd.match_adaptive_window(q, ref, block_rows=50, no_information=blank, hub_offsets=offsets, **params)
    out = match_sequences(local, hub_offsets=offsets, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_changepoint_lines_cross_shards_and_blocks(sharded, alike, monkeypatch):
    # the values are served by more than one shard, for frames before the block too, in one
    # round per block, T - 1 values per frame at most (the current frame's is served with
    # the summaries)
    q, r = alike
    served = []
    original = dd._Lines.serve

    def serve(self, rel, places):
        served.append((rel.copy(), places.copy()))
        return original(self, rel, places)

    monkeypatch.setattr(dd._Lines, "serve", serve)
    res = dd.match_adaptive_window(q, sharded, block_rows=37, **CHANGEPOINT)
    blocks = -(-len(q) // 37)
    assert len(served) == blocks
    rel = np.concatenate([s[0] for s in served])
    places = np.concatenate([s[1] for s in served])
    assert rel.min() < 0  # frames of the previous block
    assert {int(p) // 4096 for p in places} >= {0, 1}  # several shards
    assert rel.size <= (wr.CHANGE_POINT_FRAMES - 1) * len(q)
    assert res.match.shape == (len(q),)
