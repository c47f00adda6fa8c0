"""Rule "punctuated" on the cluster equals the local run (LocalCluster).

The rule reads, beside the decorrelation horizon of rule "spanning", the frames since the
latest break of the query's rows, a function of whole rows' best places: the worker that
keeps the horizon computes both from the whole rows (the local clock,
:class:`catgraph._window_rule._Breaks`) and the client reads them frame by frame. Every field
must equal the local :func:`catgraph.sequence.match_sequences` bit for bit, on a route where
the breaks change the answers.
"""

import numpy as np
import pytest

from catgraph import _window_rule as wr
from catgraph.conditions import Condition
from catgraph.differences import difference_matrix
from catgraph.sequence import match_sequences

distributed = pytest.importorskip("distributed")
from catgraph import distributed as dd  # noqa: E402

FIELDS = ("match", "score", "velocity", "window_length", "confidence")


def fog_map(seed: int = 7, dwell: int = 3):
    """A map whose neighbouring places look alike (each descriptor averaged over 15 places)
    and a query that dwells ``dwell`` frames per place (its rows stay alike for about 20
    frames), crosses the shard edges at 4096 and 8192, jumps twice (the rows break), and
    passes three short stretches of fog (three frames fading into one fixed descriptor and
    out again: the correct line's latest frames there are no better than random places,
    without a break). Returns ``(query, reference)``."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(8200, 16))
    r = np.stack([np.convolve(base[:, c], np.ones(15) / 15, mode="same") for c in range(16)], 1).astype(np.float32)
    places = np.repeat(np.concatenate([np.arange(4040, 4140), np.arange(1000, 1060), np.arange(8150, 8200)]), dwell)
    q = r[places] + (0.4 * r.std()) * rng.normal(size=(places.size, 16)).astype(np.float32)
    fog = r[rng.integers(0, 8200)]
    w = np.array([0.0, 0.5, 1.0, 1.0, 0.5, 0.0])[:, None]
    for a in (120, 250, 380):
        q[a:a + w.shape[0]] = (1 - w) * q[a:a + w.shape[0]] + w * fog
    return q, r


PUNCTUATED = {"rule": "punctuated", "l_min": 2, "l_max": 30, "grid": 5, "velocities": (-1.0, 1.0, 1.0 / 3.0),
              "recent_fraction": 0.3}


@pytest.fixture(scope="module")
def fog():
    return fog_map()


@pytest.fixture(scope="module")
def sharded(client, fog):
    return dd.shard_reference(fog[1], "sad", client, shard_places=4096)


def test_breaks_change_the_answers_on_this_route(fog):
    # the comparison below is not vacuous: without the breaks (or with the spread test on
    # every sub-window, rule "spanning") the local answers differ
    q, r = fog
    local = difference_matrix(q, r, "sad", normalise=True)
    out = match_sequences(local, **PUNCTUATED)
    spanning = match_sequences(local, **{**PUNCTUATED, "rule": "spanning"})
    assert not np.array_equal(out.window_length, spanning.window_length)
    original = wr._Breaks.update

    def no_breaks(self, row, i, spread, centre=None):
        k = original(self, row, i, spread, centre)
        self.since = 10 ** 9
        return k

    wr._Breaks.update = no_breaks
    try:
        unbroken = match_sequences(local, **PUNCTUATED)
    finally:
        wr._Breaks.update = original
    assert not np.array_equal(out.window_length, unbroken.window_length)


@pytest.mark.parametrize("condition, confidence", [
    (Condition("in-order"), "changepoint"),
    (Condition("in-order"), "gap"),
    (Condition("reverse"), "posterior"),
    (Condition("shuffle", seed=1, segment_range=(0.05, 0.2)), "changepoint"),
])
def test_punctuated_equals_the_local_matcher(sharded, fog, condition, confidence):
    # blocks of HORIZON_ROWS + 29 frames: the horizon's chunks cross the blocks, and the
    # clock's latest break travels from chunk to chunk on the worker
    q, r = fog
    q = q[condition.order(len(q))]
    local = difference_matrix(q, r, "sad", normalise=True)
    params = dict(PUNCTUATED, confidence=confidence)
    out = match_sequences(local, **params)
    res = dd.match_adaptive_window(q, sharded, block_rows=dd.HORIZON_ROWS + 29, **params)
    for name in FIELDS:
        assert np.array_equal(getattr(res, name), getattr(out, name)), name


def test_served_breaks_equal_the_local_clock(fog):
    # the worker's chained tasks hand the client each frame's horizon and frames since the
    # latest break, equal to the local clock's, across chunk edges
    q, r = fog
    local = difference_matrix(q, r, "sad", normalise=True)
    clock = wr._Breaks()
    ks, since = [], []
    for i, row in enumerate(local):
        ks.append(clock.update(row, i, row.std()))
        since.append(clock.since)
    state, got_k, got_since = wr._Breaks(), [], []
    for a in range(0, local.shape[0], 50):
        state = dd._horizon_steps(state, a, local[a:a + 50, :4096], local[a:a + 50, 4096:])
        k, s = dd._horizons_of(state)
        got_k.append(k)
        got_since.append(s)
    np.testing.assert_array_equal(np.concatenate(got_k), ks)
    np.testing.assert_array_equal(np.concatenate(got_since), since)
    assert np.sum(np.array(since) == 0) >= 2
