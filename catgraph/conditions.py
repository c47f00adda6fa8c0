"""Traversal conditions: the query driven in order, shuffled, reversed, faster or slower.

A method that localises along a route must not depend on the query repeating the
reference in order, forwards, at the reference's frame rate (DESIGN.md §7). A
:class:`Condition` turns a query traverse into the traverse a robot would have recorded
under that condition, by *reordering* its frames:

``in-order``
    The query as loaded.
``shuffle``
    Contiguous segments of ``segment_range`` (fractions of the length, default
    2–20 %) rearranged at random (seeded): out-of-order traversal, paper 1 §IV.
``reverse``
    The query driven backwards: the last frame first.
``speed``
    ``factor`` times the reference's speed: frame ``floor(k · factor)`` for
    ``k = 0, 1, …`` — factor 2 keeps every second frame, 0.5 shows each frame twice.
``vary``
    A speed that changes all the time, as a driver's does: the route is cut into
    stretches of ``segment_range`` of its length (default 2–20 %), a speed is drawn
    log-uniformly from ``speed_range`` (default 0.5–2 times the recorded speed) at each
    stretch's start, and over the stretch the speed moves from that value to the next
    one (geometric interpolation along the stretch), seeded; frame ``floor(x_k)`` at
    position ``x_{k+1} = x_k + v(x_k)`` (:func:`varying_speed_order`).
``stop``
    The query in order, stopping as a vehicle stops at lights or stations: the route is
    cut into stretches of ``segment_range`` of its length (default 2–20 %) and after each
    stretch but the last the query stands still for ``stop_frames`` frames (drawn
    uniformly from 5–50 by default, seeded), its last frame shown again each of them
    (:func:`stopping_order`), as ``speed`` below 1 shows a frame again.

Every per-frame array, ``index`` included, travels with its frame, so ground truth
(which speaks of frames *as loaded*) follows. Odometry is recomputed for the new order:
between frames the condition drives from one to the next — every step of a reversed or
sped-up query, a shuffle's steps inside a segment — it is the route distance between
them (zero for a repeated frame, ``K`` loaded steps at speed ``K``); across a shuffle's
jump, where no motion could connect the frames, each frame keeps the step it had.
Because a condition is only an order, a difference matrix computed once for the loaded
query serves every condition: ``D[condition.order(n)]``.

:func:`condition_table` lists the conditions every default is chosen on: in order;
shuffled in segments of 2–20 % and of 0.5–3 % (five seeds each); reversed; speed 2 and
speed 0.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ._validation import as_generator
from .exceptions import InvalidParameterError
from .traverse import Traverse, segment_order

__all__ = ["Condition", "CONDITION_KINDS", "condition_table", "segment_order", "stopping_order", "varying_speed_order"]

CONDITION_KINDS = ("in-order", "shuffle", "reverse", "speed", "vary", "stop")

#: The range of speed factors (``kind="speed"``): a query driven at most 100 times slower
#: (each frame 100 times) or faster (every 100th frame).
MIN_SPEED, MAX_SPEED = 0.01, 100.0

#: The speeds a ``vary`` condition draws from by default: the condition table's two speeds.
VARY_SPEEDS = (0.5, 2.0)
#: The stretches over which a ``shuffle`` cuts its segments, a ``vary`` changes its speed and
#: a ``stop`` drives between its stops.
SEGMENT_RANGE = (0.02, 0.20)
#: How long a ``stop`` condition stands still, in frames (each stop drawn uniformly from it).
STOP_FRAMES = (5, 50)
#: The longest stop a ``stop`` condition may ask for, in frames.
MAX_STOP_FRAMES = 100_000


def varying_speed_order(n: int, seed: int | np.random.Generator | None, speed_range=VARY_SPEEDS,
                        stretch_range=SEGMENT_RANGE) -> np.ndarray:
    """Frame order of a query driven at a speed that changes all the time (``vary``).

    The route (``n`` loaded frames) is cut into stretches of ``stretch_range`` of ``n``
    (at least one frame), as a shuffle cuts its segments; at each stretch's start a speed
    is drawn log-uniformly from ``speed_range`` (loaded frames per driven frame), and
    along the stretch the speed moves geometrically from it to the next stretch's, so it
    never jumps. Driven frame ``k`` is loaded frame ``floor(x_k)``, ``x_0 = 0``,
    ``x_{k+1} = x_k + v(x_k)``, until the route's end. Same seed, same order.
    """
    rng = as_generator(seed)
    lo, hi = (math.log(float(v)) for v in speed_range)
    frames: list[int] = []
    x, v0 = 0.0, math.exp(rng.uniform(lo, hi))
    last = n - 1
    while n and x <= last + 1e-9:
        start, length = x, max(1.0, rng.uniform(*stretch_range) * n)
        v1 = math.exp(rng.uniform(lo, hi))
        while x - start < length and x <= last + 1e-9:
            frames.append(int(math.floor(x + 1e-9)))
            f = (x - start) / length
            x += v0 ** (1.0 - f) * v1 ** f
        v0 = v1
    return np.minimum(np.asarray(frames, dtype=np.int64), max(last, 0))


def stopping_order(n: int, seed: int | np.random.Generator | None, stop_frames=STOP_FRAMES,
                   stretch_range=SEGMENT_RANGE) -> np.ndarray:
    """Frame order of a query driven in order that stops now and then (``stop``).

    The route (``n`` loaded frames) is cut into stretches of ``stretch_range`` of ``n``
    (at least one frame), as a shuffle cuts its segments; the query drives each stretch
    frame by frame and, after every stretch but the last, stands still for a number of
    frames drawn uniformly from ``stop_frames`` (both ends included), showing the
    stretch's last frame again each of them. Same seed, same order.
    """
    rng = as_generator(seed)
    lo, hi = (int(v) for v in stop_frames)
    frames: list[int] = []
    start = 0
    while start < n:
        end = min(n, start + max(1, int(round(rng.uniform(*stretch_range) * n))))
        frames.extend(range(start, end))
        if end < n:
            frames.extend([end - 1] * int(rng.integers(lo, hi + 1)))
        start = end
    return np.asarray(frames, dtype=np.int64)


def _odometry(odometry: np.ndarray, order: np.ndarray, driven: np.ndarray) -> np.ndarray:
    """Odometry (metres since the previous frame) of the frames ``order``; ``driven[k]``:
    the query is driven from frame ``order[k]`` to ``order[k + 1]`` (else a jump), see the
    module."""
    travelled = np.concatenate([[0.0], np.cumsum(odometry[1:])])  # route distance of each loaded frame
    out = odometry[order].astype(np.float64)
    if len(order) > 1:
        out[1:][driven] = np.abs(travelled[order[1:]] - travelled[order[:-1]])[driven]
    return out


#: the fields each kind reads (the others must be left at their defaults)
_USES = {"in-order": (), "reverse": (), "speed": ("factor",), "shuffle": ("seed", "segment_range"),
         "vary": ("seed", "segment_range", "speed_range"), "stop": ("seed", "segment_range", "stop_frames")}


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _given(value, default) -> bool:
    """Whether a field holds something other than its default (a list equal to it is the default)."""
    if default is None:
        return value is not None
    try:
        return tuple(np.atleast_1d(np.asarray(value, dtype=np.float64))) != tuple(np.atleast_1d(default))
    except (TypeError, ValueError):  # not numbers: not the default
        return True


def _pair(values, name: str, what: str) -> tuple[float, float]:
    """Two real numbers, or a typed error naming ``name`` and ``what`` they must be."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or len(values) != 2 or \
            not all(_is_real(v) for v in values):
        raise InvalidParameterError(f"{name} must be {what}; got {values!r}.")
    return float(values[0]), float(values[1])


@dataclass(frozen=True)
class Condition:
    """How the query is driven. See the module docstring.

    Parameters
    ----------
    kind : {"in-order", "shuffle", "reverse", "speed", "vary", "stop"}
    seed : int, optional
        The shuffle's, the varying speed's or the stops' seed (``kind="shuffle"``,
        ``"vary"`` or ``"stop"``).
    segment_range : (float, float)
        Shuffle segment lengths, the stretches over which a varying speed moves from one
        drawn speed to the next, or the stretches driven between stops, as fractions of
        the query length (``kind="shuffle"``, ``"vary"`` or ``"stop"``).
    factor : float
        Speed relative to the recorded query (``kind="speed"``), in ``[0.01, 100]``
        (:data:`MIN_SPEED`, :data:`MAX_SPEED`).
    speed_range : (float, float)
        The speeds a varying speed draws from (``kind="vary"``; default 0.5–2), in
        ``[0.01, 100]``.
    stop_frames : (int, int)
        How many frames each stop lasts, drawn uniformly from ``MIN``–``MAX`` (``kind="stop"``;
        default 5–50), ``1 ≤ MIN ≤ MAX ≤`` :data:`MAX_STOP_FRAMES`.
    """

    kind: str = "in-order"
    seed: int | None = None
    segment_range: tuple[float, float] = SEGMENT_RANGE
    factor: float = 1.0
    speed_range: tuple[float, float] = VARY_SPEEDS
    stop_frames: tuple[int, int] = STOP_FRAMES

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or self.kind not in CONDITION_KINDS:
            raise InvalidParameterError(f"unknown condition {self.kind!r}; choose one of {', '.join(CONDITION_KINDS)}.")
        unused = [name for name, default in (("seed", None), ("segment_range", SEGMENT_RANGE), ("factor", 1.0),
                                             ("speed_range", VARY_SPEEDS), ("stop_frames", STOP_FRAMES))
                  if name not in _USES[self.kind] and _given(getattr(self, name), default)]
        if unused:
            raise InvalidParameterError(f"{', '.join(unused)} do{'es' if len(unused) == 1 else ''} not apply to the "
                                        f"condition {self.kind!r}; leave {'it' if len(unused) == 1 else 'them'} out.")
        if self.kind in ("shuffle", "vary", "stop"):
            what = {"shuffle": "a shuffle", "vary": "a varying speed", "stop": "a stopping query"}[self.kind]
            if not _is_int(self.seed) or self.seed < 0:
                raise InvalidParameterError(f"{what} needs a seed ≥ 0 (an int); got {self.seed!r}.")
            object.__setattr__(self, "seed", int(self.seed))
            lo, hi = _pair(self.segment_range, "the segment range", "two fractions (MIN, MAX) of the query")
            if not (0.0 < lo <= hi <= 1.0):
                raise InvalidParameterError(
                    f"the segment range must satisfy 0 < MIN ≤ MAX ≤ 1 (fractions of the query); got {lo}:{hi}.")
            object.__setattr__(self, "segment_range", (lo, hi))
        if self.kind == "vary":
            lo, hi = _pair(self.speed_range, "the speed range", "two speeds (MIN, MAX)")
            if not (math.isfinite(lo) and math.isfinite(hi) and MIN_SPEED <= lo <= hi <= MAX_SPEED):
                raise InvalidParameterError(
                    f"the speed range must satisfy {MIN_SPEED:g} ≤ MIN ≤ MAX ≤ {MAX_SPEED:g} (times the recorded "
                    f"speed); got {lo}:{hi}.")
            object.__setattr__(self, "speed_range", (lo, hi))
        if self.kind == "stop":
            lo, hi = _pair(self.stop_frames, "the stop lengths", "two whole numbers of frames (MIN, MAX)")
            if not (1 <= lo <= hi <= MAX_STOP_FRAMES and lo == int(lo) and hi == int(hi)):
                raise InvalidParameterError(
                    f"the stop lengths must be whole numbers of frames with 1 ≤ MIN ≤ MAX ≤ {MAX_STOP_FRAMES}; got "
                    f"{self.stop_frames[0]:g}:{self.stop_frames[1]:g}.")
            object.__setattr__(self, "stop_frames", (int(lo), int(hi)))
        if self.kind == "speed":
            if not _is_real(self.factor):
                raise InvalidParameterError(f"the speed factor must be a number; got {self.factor!r}.")
            f = float(self.factor)
            if not (math.isfinite(f) and MIN_SPEED <= f <= MAX_SPEED):
                raise InvalidParameterError(
                    f"the speed factor must be in [{MIN_SPEED:g}, {MAX_SPEED:g}] (at slowest each frame {1 / MIN_SPEED:g} "
                    f"times, at fastest every {MAX_SPEED:g}th frame); got {self.factor!r}.")
            object.__setattr__(self, "factor", f)

    # -- construction ---------------------------------------------------------------
    @classmethod
    def parse(cls, text: str) -> "Condition":
        """From ``in-order``, ``reverse``, ``speed:F``, ``shuffle:SEED``, ``shuffle:SEED:MIN:MAX``,
        ``vary:SEED``, ``vary:SEED:SLOWEST:FASTEST`` (the speed range), ``stop:SEED`` or
        ``stop:SEED:MIN:MAX`` (the stop lengths in frames)."""
        parts = str(text).strip().split(":")
        kind, args = parts[0], parts[1:]
        shapes = {"in-order": (0,), "reverse": (0,), "speed": (1,), "shuffle": (1, 3), "vary": (1, 3), "stop": (1, 3)}
        try:
            if kind in shapes and len(args) in shapes[kind]:
                numbers = [int(args[0])] + [float(v) for v in args[1:]] if kind in ("shuffle", "vary", "stop") else \
                    [float(v) for v in args]
            else:
                numbers = None
        except ValueError:
            numbers = None
        if numbers is None:
            raise InvalidParameterError(
                f"cannot read condition {text!r}; write in-order, reverse, speed:FACTOR, shuffle:SEED, "
                "shuffle:SEED:MIN:MAX, vary:SEED, vary:SEED:SLOWEST:FASTEST, stop:SEED or stop:SEED:MIN:MAX.")
        if kind == "shuffle":
            return cls("shuffle", seed=numbers[0], segment_range=tuple(numbers[1:]) or SEGMENT_RANGE)
        if kind == "vary":
            return cls("vary", seed=numbers[0], speed_range=tuple(numbers[1:]) or VARY_SPEEDS)
        if kind == "stop":
            return cls("stop", seed=numbers[0], stop_frames=tuple(numbers[1:]) or STOP_FRAMES)
        if kind == "speed":
            return cls("speed", factor=numbers[0])
        return cls(kind)

    @classmethod
    def from_dict(cls, values: dict | None) -> "Condition":
        """Inverse of :meth:`as_dict` (``None`` = in order)."""
        if not values:
            return cls()
        if not isinstance(values, dict):
            raise InvalidParameterError("a condition is a dict (kind, seed, segment_range, factor, speed_range, "
                                        f"stop_frames) or a string such as 'shuffle:0'; got {values!r}.")
        unknown = set(values) - {"kind", "seed", "segment_range", "factor", "speed_range", "stop_frames"}
        if unknown:
            raise InvalidParameterError(f"unknown condition keys {sorted(unknown)}; allowed: kind, seed, "
                                        "segment_range, factor, speed_range, stop_frames.")
        v = dict(values)
        for key in ("segment_range", "speed_range", "stop_frames"):
            if key in v and isinstance(v[key], list):
                v[key] = tuple(v[key])
        return cls(**v)

    def as_dict(self) -> dict:
        """JSON-ready; only the fields the kind uses."""
        if self.kind == "shuffle":
            return {"kind": "shuffle", "seed": int(self.seed), "segment_range": list(self.segment_range)}
        if self.kind == "speed":
            return {"kind": "speed", "factor": self.factor}
        if self.kind == "vary":
            return {"kind": "vary", "seed": int(self.seed), "segment_range": list(self.segment_range),
                    "speed_range": list(self.speed_range)}
        if self.kind == "stop":
            return {"kind": "stop", "seed": int(self.seed), "segment_range": list(self.segment_range),
                    "stop_frames": list(self.stop_frames)}
        return {"kind": self.kind}

    @property
    def label(self) -> str:
        """Short human-readable name, e.g. ``shuffled 2–20 % (seed 0)``."""
        if self.kind == "shuffle":
            lo, hi = (100 * v for v in self.segment_range)
            return f"shuffled {lo:g}–{hi:g} % (seed {self.seed})"
        if self.kind == "speed":
            return f"speed {self.factor:g}"
        if self.kind == "vary":
            lo, hi = self.speed_range
            stretches = "" if self.segment_range == SEGMENT_RANGE else \
                f", stretches {100 * self.segment_range[0]:g}–{100 * self.segment_range[1]:g} %"
            return f"varying speed {lo:g}–{hi:g}{stretches} (seed {self.seed})"
        if self.kind == "stop":
            lo, hi = self.stop_frames
            stretches = "" if self.segment_range == SEGMENT_RANGE else \
                f", every {100 * self.segment_range[0]:g}–{100 * self.segment_range[1]:g} %"
            return f"stops of {lo}–{hi} frames{stretches} (seed {self.seed})"
        return {"in-order": "in order", "reverse": "reversed"}[self.kind]

    # -- application ----------------------------------------------------------------
    def order(self, n: int) -> np.ndarray:
        """Indices (into the loaded query of ``n`` frames) in the order they are driven."""
        if self.kind == "in-order":
            return np.arange(n, dtype=np.int64)
        if self.kind == "reverse":
            return np.arange(n - 1, -1, -1, dtype=np.int64)
        if self.kind == "speed":
            count = int(math.ceil(n / self.factor - 1e-9)) if n else 0
            return np.minimum(np.floor(np.arange(count) * self.factor + 1e-9).astype(np.int64), max(n - 1, 0))
        if self.kind == "vary":
            return varying_speed_order(n, self.seed, self.speed_range, self.segment_range)
        if self.kind == "stop":
            return stopping_order(n, self.seed, self.stop_frames, self.segment_range)
        return segment_order(n, self.seed, *self.segment_range)[0]

    def apply(self, traverse: Traverse) -> Traverse:
        """The traverse driven under this condition (see the module docstring)."""
        if self.kind == "in-order":
            return traverse
        order = self.order(len(traverse))
        out = traverse.take(order)
        meta = dict(out.meta)
        meta["traversal"] = self.as_dict()
        if self.kind == "shuffle":
            meta["segments"] = segment_order(len(traverse), self.seed, *self.segment_range)[1]
        # a shuffle drives its segments one frame at a time and jumps between them; a reversed,
        # sped-up or varying query is driven all the way (at speed K, K loaded steps per frame)
        driven = np.diff(order) == 1 if self.kind == "shuffle" else np.ones(max(len(order) - 1, 0), dtype=bool)
        odometry = None if traverse.odometry is None else _odometry(traverse.odometry, order, driven)
        return replace(out, odometry=odometry, meta=meta, name=f"{traverse.name} ({self.label})")


def condition_table(seeds=range(5)) -> list[Condition]:
    """The conditions every default is chosen on (DESIGN.md §7), in reporting order."""
    seeds = list(seeds)
    return ([Condition()]
            + [Condition("shuffle", seed=s) for s in seeds]
            + [Condition("shuffle", seed=s, segment_range=(0.005, 0.03)) for s in seeds]
            + [Condition("reverse"), Condition("speed", factor=2.0), Condition("speed", factor=0.5)])
