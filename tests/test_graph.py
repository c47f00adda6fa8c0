"""PlaceGraph: building, compiling to CSR, networkx round trips, junction finding."""

import numpy as np
import pytest

from catgraph.exceptions import DataError, InvalidParameterError, MapFileError
from catgraph.graph import EDGE_KINDS, PlaceGraph, load_graph
from catgraph.traverse import Traverse


def _csr_reference(graph):
    """Slow, obviously-correct adjacency: dict place -> set of (target, length)."""
    out = {v: set() for v in range(graph.n_places)}
    for a, b, ln in zip(graph.source, graph.target, graph.length):
        out[int(a)].add((int(b), float(ln)))
    return out


def test_chain_structure_and_csr():
    g = PlaceGraph.chain(5, bidirectional=False)
    assert g.n_edges == 4
    assert list(g.out_ptr) == [0, 1, 2, 3, 4, 4]
    assert list(g.target[g.out_edges(2)]) == [3]
    assert len(g.out_edges(4)) == 0
    assert np.all(g.reverse == -1)
    # straight continuation of 0->1 is 1->2; of 3->4 there is none
    e01 = g.out_edges(0)[0]
    assert g.target[g.straight[e01]] == 2
    assert g.straight[g.out_edges(3)[0]] == -1


def test_bidirectional_chain_has_reverse_edges():
    g = PlaceGraph.chain(4, bidirectional=True)
    assert g.n_edges == 6
    for e in range(g.n_edges):
        r = g.reverse[e]
        assert r >= 0 and g.source[r] == g.target[e] and g.target[r] == g.source[e]
    # straight after 2->1 is 1->0
    e21 = [e for e in g.out_edges(2) if g.target[e] == 1][0]
    assert (g.source[g.straight[e21]], g.target[g.straight[e21]]) == (1, 0)


def test_csr_matches_edge_list():
    rng = np.random.default_rng(0)
    n = 30
    edges = rng.integers(0, n, size=(120, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    lengths = rng.uniform(0.5, 3.0, len(edges))
    g = PlaceGraph.from_edges(n, edges, lengths)
    ref = {v: set() for v in range(n)}
    seen = set()
    for (a, b), ln in zip(edges, lengths):
        if (a, b) not in seen:  # duplicates keep the first
            seen.add((a, b))
            ref[int(a)].add((int(b), float(ln)))
    assert _csr_reference(g) == ref
    for v in range(n):
        assert np.all(g.source[g.out_ptr[v]:g.out_ptr[v + 1]] == v)


def test_from_traverse_lengths_and_user_junctions():
    pos = np.array([[0, 0], [1, 0], [3, 0], [3, 2], [1, 0.1]], float)
    t = Traverse(frames=np.zeros((5, 4)), positions=pos)
    g = PlaceGraph.from_traverse(t, junctions=[(1, 4)], bidirectional=False)
    assert g.unit == "m"
    np.testing.assert_allclose(g.route_distance, [0, 1, 3, 5, 5 + np.hypot(2, 1.9)])
    assert g.junction_pairs().tolist() == [[1, 4]]
    e14 = [e for e in g.out_edges(1) if g.target[e] == 4][0]
    assert EDGE_KINDS[g.kind[e14]] == "junction"
    assert g.length[e14] == pytest.approx(0.1)
    # odometry wins over positions under "auto"
    odo = np.array([0, 2, 2, 2, 2], float)
    g2 = PlaceGraph.from_traverse(Traverse(frames=np.zeros((5, 4)), positions=pos, odometry=odo))
    np.testing.assert_allclose(g2.route_distance, [0, 2, 4, 6, 8])
    # no positions: one unit per frame
    g3 = PlaceGraph.from_traverse(Traverse(frames=np.zeros((5, 4))))
    assert g3.unit == "frame" and np.all(g3.length == 1)


def test_junctions_found_from_positions_exclude_route_neighbours():
    # a square loop driven twice on its bottom edge: places 0..9 along x, up, back, along x again
    x = np.arange(10.0)
    leg1 = np.stack([x, np.zeros(10)], 1)
    leg2 = np.stack([np.full(5, 9.0), np.arange(1, 6.0)], 1)
    leg3 = np.stack([np.arange(8, -1, -1.0), np.full(9, 5.0)], 1)
    leg4 = np.stack([np.zeros(4), np.arange(4, 0, -1.0)], 1)
    leg5 = np.stack([x + 0.1, np.full(10, 0.05)], 1)  # the bottom edge again
    pos = np.concatenate([leg1, leg2, leg3, leg4, leg5])
    t = Traverse(frames=np.zeros((len(pos), 2)), positions=pos)
    g = PlaceGraph.from_traverse(t, junction_radius_m=0.5)
    pairs = g.junction_pairs()
    assert len(pairs) == 10  # each bottom place joins its second pass, once
    assert np.all(pairs[:, 0] < 10) and np.all(pairs[:, 1] >= len(pos) - 10)
    # route neighbours (1 m apart) are not junctions even within a larger radius
    g_big = PlaceGraph.from_traverse(t, junction_radius_m=1.5, junction_exclusion_m=4.0)
    jp = g_big.junction_pairs()
    assert np.all(np.abs(g_big.route_distance[jp[:, 0]] - g_big.route_distance[jp[:, 1]]) > 4.0)


def test_zero_length_edges_are_floored():
    pos = np.array([[0, 0], [0, 0], [1, 0]], float)
    g = PlaceGraph.from_traverse(Traverse(frames=np.zeros((3, 2)), positions=pos))
    assert np.all(g.length > 0)


@pytest.mark.parametrize("suffix", [".json", ".graphml"])
def test_networkx_and_file_round_trip(tmp_path, suffix):
    pos = np.random.default_rng(1).normal(size=(12, 2))
    t = Traverse(frames=np.zeros((12, 3)), positions=pos)
    g = PlaceGraph.from_traverse(t, junctions=[(2, 9), (0, 11)])
    g_nx = PlaceGraph.from_networkx(g.to_networkx())
    path = tmp_path / f"map{suffix}"
    g.save(path)
    g_file = load_graph(path)
    for h in (g_nx, g_file):
        assert _csr_reference(h) == _csr_reference(g)
        np.testing.assert_array_equal(h.kind, g.kind)
        np.testing.assert_allclose(h.positions, g.positions)
        np.testing.assert_allclose(h.route_distance, g.route_distance)
        assert h.unit == g.unit


def test_bad_inputs_raise_typed_errors(tmp_path):
    with pytest.raises(DataError, match="outside"):
        PlaceGraph.from_edges(3, [[0, 5]])
    with pytest.raises(DataError, match="self-loops"):
        PlaceGraph.from_edges(3, [[1, 1]])
    with pytest.raises(DataError, match="junctions"):
        PlaceGraph.from_traverse(Traverse(frames=np.zeros((4, 2))), junctions=[(0, 7)])
    with pytest.raises(DataError, match="positions"):
        PlaceGraph.from_traverse(Traverse(frames=np.zeros((4, 2))), junction_radius_m=1.0)
    import networkx as nx

    with pytest.raises(MapFileError):
        PlaceGraph.from_networkx(nx.path_graph(["a", "b"]))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(MapFileError):
        load_graph(bad)
    import json

    saved = tmp_path / "g.json"
    PlaceGraph.chain(3).save(saved)
    for value, where in (("abc", "links"), (None, "links"), ("north", "nodes")):
        data = json.loads(saved.read_text())
        if where == "links":
            data["links"][0]["length"] = value
        else:
            for node in data["nodes"]:
                node["x"], node["y"] = value, 0.0
        saved.write_text(json.dumps(data))
        with pytest.raises(MapFileError, match="length|positions"):
            load_graph(saved)
        PlaceGraph.chain(3).save(saved)


def test_hop_length_counts_places_whatever_the_metres():
    from catgraph.traverse import Traverse

    positions = np.repeat(np.stack([3.0 * np.arange(5), np.zeros(5)], 1), 4, axis=0)  # 4 samples per point
    g = PlaceGraph.from_traverse(Traverse(np.zeros((20, 2)), positions=positions))
    assert g.unit == "m" and np.sum(g.length < 1e-3) > 0
    np.testing.assert_array_equal(g.hop_length, np.ones(g.n_edges))
    assert not g.hop_length.flags.writeable


def test_junctions_join_places_of_one_floor_and_break_ties_by_index():
    from catgraph.traverse import Traverse

    # an out-and-back corridor walked on floor 0, then the same corridor on floor 1 above it
    x = np.r_[np.arange(10.0), np.arange(10.0)]
    positions = np.stack([x, np.zeros(20)], axis=1)
    walk = Traverse(np.zeros((20, 2)), positions=positions, floors=np.r_[np.zeros(10), np.ones(10)].astype(int))
    assert PlaceGraph.from_traverse(walk, junction_radius_m=0.5).junction_pairs().size == 0  # one floor per place
    flat = Traverse(np.zeros((20, 2)), positions=positions)
    assert len(PlaceGraph.from_traverse(flat, junction_radius_m=0.5).junction_pairs()) == 10  # without floors: joined
    # a figure-eight whose crossing is passed three times at the very same point (frames 0, 8, 16)
    t = np.linspace(0, 2 * np.pi, 17)
    eight = np.stack([10 * np.sin(t), 10 * np.sin(t) * np.cos(t)], axis=1)
    eight[[0, 8, 16]] = 0.0
    pairs = PlaceGraph.from_traverse(Traverse(np.zeros((17, 2)), positions=eight), junction_radius_m=0.5,
                                     junction_exclusion_m=5.0).junction_pairs()
    assert [0, 8] in pairs.tolist()  # ties: the nearest of the smallest index (no junction at all before)


def test_junction_exclusion_must_be_a_distance():
    from catgraph.traverse import Traverse

    walk = Traverse(np.zeros((5, 2)), positions=np.stack([np.arange(5.0), np.zeros(5)], axis=1))
    for bad in (float("nan"), -1.0, "far"):
        with pytest.raises(InvalidParameterError, match="junction_exclusion_m"):
            PlaceGraph.from_traverse(walk, junction_radius_m=1.0, junction_exclusion_m=bad)


def test_straight_continues_along_the_route_never_onto_a_junction():
    """``straight`` is the route's continuation: an edge of the same kind, not a junction
    edge that happens to run the same way (a hand-built graph; from_traverse never makes one)."""
    g = PlaceGraph.from_edges(3, np.array([(0, 1), (1, 2)]), kinds=["chain", "junction"])
    assert g.straight.tolist() == [-1, -1]
    g = PlaceGraph.from_edges(3, np.array([(0, 1), (1, 2)]), kinds=["chain", "chain"])
    assert g.straight.tolist() == [1, -1]
    chain = PlaceGraph.chain(6)
    forward = chain.kind == EDGE_KINDS.index("chain")
    assert np.all(chain.straight[forward][:-1] >= 0)


def _edge_tables_reference(graph):
    """Slow, obviously correct ``reverse`` and ``straight``: a dict of the edges."""
    key = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(graph.source, graph.target))}
    reverse = [key.get((int(b), int(a)), -1) for a, b in zip(graph.source, graph.target)]
    straight = []
    for a, b, c in zip(graph.source, graph.target, graph.kind):
        nxt = key.get((int(b), 2 * int(b) - int(a)), -1) if c in (0, 1) else -1
        straight.append(nxt if nxt >= 0 and graph.kind[nxt] == c else -1)
    return reverse, straight


@pytest.mark.parametrize("seed", range(12))
def test_edge_tables_equal_the_dict_reference(seed):
    """The sorted-key lookup gives the dict's tables: random edges of every kind, with
    duplicates, edges both ways, continuations ``2b − a`` outside the map (whose keys would
    alias other places' edges), places without edges."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 40))
    e = rng.integers(0, n, (int(rng.integers(0, 4 * n)), 2))
    e = e[e[:, 0] != e[:, 1]]
    if seed % 2:  # a route as well: chains and continuations in both directions
        i = np.arange(n - 1)
        e = np.concatenate([e, np.stack([i, i + 1], 1), np.stack([i + 1, i], 1)])
    kinds = rng.integers(0, len(EDGE_KINDS), len(e))
    g = PlaceGraph.from_edges(n, e, kinds=kinds)
    reverse, straight = _edge_tables_reference(g)
    assert g.reverse.tolist() == reverse and g.straight.tolist() == straight
    assert g.reverse.dtype == g.straight.dtype == np.int64
    assert g.out_ptr.tolist() == [0, *np.cumsum(np.bincount(g.source, minlength=n)).tolist()]
    named = PlaceGraph.from_edges(n, e, kinds=[EDGE_KINDS[k] for k in kinds])
    assert named.kind.tolist() == g.kind.tolist() and named.straight.tolist() == straight


def test_edge_kind_codes_outside_the_kinds_are_refused():
    with pytest.raises(DataError, match="edge kinds"):
        PlaceGraph.from_edges(3, [[0, 1], [1, 2]], kinds=[0, 3])
    with pytest.raises(DataError, match="edge kinds"):
        PlaceGraph.from_edges(3, [[0, 1], [1, 2]], kinds=np.array([0, 300]))
    with pytest.raises(DataError, match="'turn'"):
        PlaceGraph.from_edges(3, [[0, 1], [1, 2]], kinds=["chain", "turn"])
