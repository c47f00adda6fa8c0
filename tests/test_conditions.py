import numpy as np
import pytest

from catgraph.conditions import Condition, condition_table
from catgraph.exceptions import InvalidParameterError
from catgraph.traverse import FrameTolerance, Traverse, shuffle_segments


def _traverse(n=20):
    steps = np.arange(1.0, n + 1.0)  # odometry[i]: metres since frame i-1 (odometry[0] unused)
    return Traverse(frames=np.arange(n * 3, dtype=float).reshape(n, 3), odometry=steps,
                    positions=np.column_stack([np.cumsum(steps), np.zeros(n)]))


def test_orders():
    assert Condition().order(4).tolist() == [0, 1, 2, 3]
    assert Condition("reverse").order(4).tolist() == [3, 2, 1, 0]
    assert Condition("speed", factor=2).order(5).tolist() == [0, 2, 4]
    assert Condition("speed", factor=0.5).order(3).tolist() == [0, 0, 1, 1, 2, 2]
    assert Condition("speed", factor=3).order(7).tolist() == [0, 3, 6]
    order = Condition("shuffle", seed=3, segment_range=(0.1, 0.3)).order(50)
    assert sorted(order.tolist()) == list(range(50)) and order.tolist() != list(range(50))


def test_shuffle_is_shuffle_segments():
    t = _traverse(40)
    a = Condition("shuffle", seed=7).apply(t)
    b = shuffle_segments(t, seed=7)
    np.testing.assert_array_equal(a.index, b.index)
    assert a.meta["segments"] == b.meta["segments"]


def test_ground_truth_follows_frames():
    t = _traverse(30)
    gt = FrameTolerance(30, 0)
    for cond in condition_table(seeds=[0, 1]):
        q = cond.apply(t)
        # frame k of the conditioned query is loaded frame q.index[k]: matching it to that reference is correct
        assert gt.correct(q.index, q.index).all()
        np.testing.assert_array_equal(q.frames, t.frames[q.index])


def test_odometry_is_route_distance():
    t = _traverse(10)
    rev = Condition("reverse").apply(t)
    # driven backwards, the step into loaded frame i from frame i+1 is odometry[i+1]
    np.testing.assert_allclose(rev.odometry[1:], t.odometry[1:][::-1])
    fast = Condition("speed", factor=2).apply(t)
    np.testing.assert_allclose(fast.odometry[1:], t.odometry[1:-1:2] + t.odometry[2::2])
    slow = Condition("speed", factor=0.5).apply(t)
    np.testing.assert_allclose(slow.odometry[1::2], 0.0)
    np.testing.assert_allclose(slow.odometry[2::2], t.odometry[1:])


def test_parse_round_trip_and_errors():
    for text in ("in-order", "reverse", "speed:2", "speed:0.5", "speed:0.01", "speed:100", "shuffle:3",
                 "shuffle:1:0.005:0.03", "vary:0", "vary:4:0.25:3", "stop:0", "stop:2:1:1", "stop:3:10:200"):
        c = Condition.parse(text)
        assert Condition.from_dict(c.as_dict()) == c
    for bad in ("sideways", "speed:0", "speed:-1", "speed:x", "speed:1e-9", "speed:0.009", "speed:101", "speed:inf",
                "shuffle", "shuffle:-1", "shuffle:1:0.3:0.1", "shuffle:1:0:0.1", "reverse:2", "vary", "vary:-1",
                "vary:0:2:1", "vary:0:0:1", "vary:0:0.5", "vary:0:0.5:inf", "vary:1.5", "stop", "stop:-1",
                "stop:0:0:5", "stop:0:6:5", "stop:0:2.5:5", "stop:0:5", "stop:0:1:inf", "stop:0:1:100001", "stop:0.5"):
        with pytest.raises(InvalidParameterError):
            Condition.parse(bad)


def test_table():
    table = condition_table()
    assert len(table) == 14
    assert len({c.label for c in table}) == 14


def test_odometry_at_any_speed_is_the_route_driven_and_a_shuffle_jump_keeps_its_step():
    """The slow reference: the distance along the route between consecutive driven frames,
    except across a shuffle's jump (the frame's own loaded step). Frames more than three
    loaded steps apart (speed 4 and above) were taken for jumps before."""
    t = _traverse(60)
    travelled = np.concatenate([[0.0], np.cumsum(t.odometry[1:])])
    for factor in (1.5, 2, 3, 4, 7.5, 0.3):
        c = Condition("speed", factor=factor)
        order = c.order(len(t))
        expected = [t.odometry[order[0]]] + [abs(travelled[b] - travelled[a]) for a, b in zip(order[:-1], order[1:])]
        np.testing.assert_allclose(c.apply(t).odometry, expected, rtol=1e-12, atol=1e-12)
    c = Condition("shuffle", seed=2, segment_range=(0.1, 0.2))
    order, out = c.order(len(t)), c.apply(t).odometry
    for k in range(1, len(order)):
        want = abs(travelled[order[k]] - travelled[order[k - 1]]) if order[k] == order[k - 1] + 1 else \
            t.odometry[order[k]]
        assert out[k] == pytest.approx(want, abs=1e-12)


def test_conditions_built_in_python_give_typed_errors():
    for bad in (dict(kind="speed", factor="abc"), dict(kind="shuffle", seed="abc"), dict(kind="shuffle", seed=2.0),
                dict(kind="shuffle", seed=True), dict(kind="shuffle", seed=0, segment_range=0.1),
                dict(kind="shuffle", seed=0, segment_range=("a", 0.2)), dict(kind=5), dict(seed=1),
                dict(kind="reverse", factor=2.0), dict(kind="speed", factor=2.0, seed=1),
                dict(kind="vary"), dict(kind="vary", seed=0, speed_range=(0.5,)),
                dict(kind="vary", seed=0, speed_range="0.5:2"), dict(kind="speed", factor=2.0, speed_range=(1, 3)),
                dict(kind="stop"), dict(kind="stop", seed=0, stop_frames=(5,)), dict(kind="stop", seed=0, stop_frames="5:50"),
                dict(kind="stop", seed=0, stop_frames=(0, 5)), dict(kind="vary", seed=0, stop_frames=(1, 2)),
                dict(kind="shuffle", seed=0, stop_frames=(1, 2))):
        with pytest.raises(InvalidParameterError):
            Condition(**bad)
    for bad in ({"seed": 1}, 123, {"kind": "speed", "factor": "abc"}, {"kind": "shuffle", "seed": 0, "speed": 2}):
        with pytest.raises(InvalidParameterError):
            Condition.from_dict(bad)
    assert Condition("shuffle", seed=np.int64(2)).seed == 2 and Condition("speed", factor=np.float32(2)).factor == 2.0


@pytest.mark.parametrize("condition", [Condition("reverse"), Condition("speed", factor=2.0),
                                       Condition("speed", factor=0.5), Condition("shuffle", seed=3),
                                       Condition("vary", seed=1), Condition("stop", seed=2)])
def test_per_frame_meta_travels_with_its_frames(condition):
    """An image folder's file names and the synthetic world's per-frame flags stay with
    their frames under every condition (they stayed in the loaded order); what describes
    the whole traverse is kept as it is."""
    n = 40
    t = Traverse(np.arange(n, dtype=float)[:, None] * np.ones((1, 3)), name="q",
                 meta={"files": [f"{k:04d}.png" for k in range(n)], "new_place": np.arange(n) % 7 == 0,
                       "street": np.arange(n) // 5, "kind": "images", "source": "folder", "tags": ["a", "b"]})
    out = condition.apply(t)
    loaded = out.index  # the frame as loaded, per frame driven
    assert out.meta["files"] == [f"{k:04d}.png" for k in loaded]
    np.testing.assert_array_equal(out.meta["new_place"], loaded % 7 == 0)
    np.testing.assert_array_equal(out.meta["street"], loaded // 5)
    assert out.meta["kind"] == "images" and out.meta["source"] == "folder" and out.meta["tags"] == ["a", "b"]
    assert out.meta["traversal"] == condition.as_dict()
    # the library's own whole-traverse entries are never read as per frame
    again = shuffle_segments(out, seed=1, min_fraction=0.5, max_fraction=0.5)
    assert again.meta["traversal"] == condition.as_dict()
    assert t.meta["files"][0] == "0000.png"  # the loaded traverse is left as it was


def test_shuffle_segments_carries_per_frame_meta():
    n = 30
    t = Traverse(np.zeros((n, 2)), meta={"files": [str(k) for k in range(n)], "new_place": np.arange(n)})
    out = shuffle_segments(t, seed=0)
    np.testing.assert_array_equal(out.meta["new_place"], out.index)
    assert out.meta["files"] == [str(k) for k in out.index]


def _varying_reference(n, seed, speed_range=(0.5, 2.0), stretch_range=(0.02, 0.2)):
    """The definition written out: draw each stretch's length and end speed in turn (the
    same generator calls), and step ``x`` by the speed interpolated along the stretch."""
    rng = np.random.default_rng(seed)
    lo, hi = np.log(speed_range[0]), np.log(speed_range[1])
    speed, x, out = np.exp(rng.uniform(lo, hi)), 0.0, []
    while x <= n - 1 + 1e-9:
        start, length = x, max(1.0, rng.uniform(*stretch_range) * n)
        end = np.exp(rng.uniform(lo, hi))
        while x - start < length and x <= n - 1 + 1e-9:
            out.append(int(np.floor(x + 1e-9)))
            f = (x - start) / length
            x += np.exp((1 - f) * np.log(speed) + f * np.log(end))
        speed = end
    return out


@pytest.mark.parametrize("n,seed,speeds", [(200, 0, (0.5, 2.0)), (1000, 3, (0.25, 4.0)), (57, 9, (1.0, 1.0)),
                                           (300, 1, (2.0, 3.0))])
def test_varying_speed_order_is_the_definition(n, seed, speeds):
    c = Condition("vary", seed=seed, speed_range=speeds)
    order = c.order(n)
    assert order.tolist() == _varying_reference(n, seed, speeds)
    np.testing.assert_array_equal(order, Condition("vary", seed=seed, speed_range=speeds).order(n))  # seeded
    steps = np.diff(order)
    # driven forwards along the whole route at speeds within the range, never jumping
    assert order[0] == 0 and order[-1] >= n - 1 - np.ceil(speeds[1]) and (steps >= 0).all()
    assert steps.max() <= np.ceil(speeds[1]) and len(order) == pytest.approx((n - 1) / np.sqrt(np.prod(speeds)),
                                                                              rel=0.6)
    if speeds[0] == speeds[1]:  # one speed: the speed condition's frames
        np.testing.assert_array_equal(order, Condition("speed", factor=speeds[0]).order(n)[:len(order)])


def test_varying_speed_changes_and_stays_in_its_range():
    n = 5000
    order = Condition("vary", seed=2).order(n)
    local = np.convolve(np.diff(order), np.ones(50) / 50, mode="valid")  # speed over 50 driven frames
    assert local.min() >= 0.5 - 0.05 and local.max() <= 2.0 + 0.05
    assert local.max() - local.min() > 0.5  # it does vary
    assert not np.array_equal(order[:500], Condition("vary", seed=3).order(n)[:500])


def test_varying_speed_odometry_is_the_route_driven():
    t = _traverse(80)
    travelled = np.concatenate([[0.0], np.cumsum(t.odometry[1:])])
    c = Condition("vary", seed=5, segment_range=(0.1, 0.3))
    order, out = c.order(len(t)), c.apply(t)
    np.testing.assert_allclose(out.odometry[1:], np.abs(np.diff(travelled[order])), atol=1e-12)
    assert out.meta["traversal"] == {"kind": "vary", "seed": 5, "segment_range": [0.1, 0.3], "speed_range": [0.5, 2.0]}
    assert c.label == "varying speed 0.5–2, stretches 10–30 % (seed 5)"
    assert Condition("vary", seed=1).label == "varying speed 0.5–2 (seed 1)"


def _stopping_reference(n, seed, stop_frames=(5, 50), stretch_range=(0.02, 0.2)):
    """The definition written out: a stretch's length, then (unless it reaches the end)
    its stop's length, in turn from one generator; each stop repeats the stretch's last frame."""
    rng = np.random.default_rng(seed)
    out, start = [], 0
    while start < n:
        length = max(1, int(round(rng.uniform(*stretch_range) * n)))
        end = min(n, start + length)
        out += list(range(start, end))
        if end < n:
            out += [end - 1] * int(rng.integers(stop_frames[0], stop_frames[1] + 1))
        start = end
    return out


@pytest.mark.parametrize("n,seed,stops,stretches", [(200, 0, (5, 50), (0.02, 0.2)), (1000, 3, (1, 1), (0.02, 0.2)),
                                                    (57, 9, (2, 7), (0.1, 0.5)), (3, 1, (5, 50), (0.02, 0.2))])
def test_stopping_order_is_the_definition(n, seed, stops, stretches):
    c = Condition("stop", seed=seed, stop_frames=stops, segment_range=stretches)
    order = c.order(n)
    assert order.tolist() == _stopping_reference(n, seed, stops, stretches)
    np.testing.assert_array_equal(order, Condition("stop", seed=seed, stop_frames=stops,
                                                   segment_range=stretches).order(n))  # seeded
    # every frame once in order, the stops in between: each a run of one frame of a length in range
    np.testing.assert_array_equal(np.unique(order), np.arange(n))
    steps = np.diff(order)
    assert set(steps.tolist()) <= {0, 1} and order[0] == 0 and order[-1] == n - 1
    edges = np.flatnonzero(np.diff(np.r_[0, (steps == 0).astype(int), 0]))
    runs = edges[1::2] - edges[::2]  # stop lengths
    assert ((runs >= stops[0]) & (runs <= stops[1])).all()
    assert len(order) - n == runs.sum()


def test_stops_stand_still_on_the_route_and_ground_truth_follows():
    t = _traverse(120)
    c = Condition("stop", seed=4, stop_frames=(3, 9), segment_range=(0.1, 0.3))
    order, out = c.order(len(t)), c.apply(t)
    stopped = np.r_[False, np.diff(order) == 0]
    assert stopped.sum() >= 3
    np.testing.assert_allclose(out.odometry[1:][stopped[1:]], 0.0)  # standing still: no distance
    np.testing.assert_allclose(out.odometry[1:][~stopped[1:]], t.odometry[order[1:][~stopped[1:]]])
    np.testing.assert_array_equal(out.index, order)  # ground truth speaks of frames as loaded
    np.testing.assert_array_equal(out.frames, t.frames[order])
    assert out.meta["traversal"] == {"kind": "stop", "seed": 4, "segment_range": [0.1, 0.3], "stop_frames": [3, 9]}
    assert c.label == "stops of 3–9 frames, every 10–30 % (seed 4)"
    assert Condition("stop", seed=1).label == "stops of 5–50 frames (seed 1)"
    assert not np.array_equal(Condition("stop", seed=1).order(2000), Condition("stop", seed=2).order(2000))
