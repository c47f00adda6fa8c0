"""The window rule: from per-window statistics to one decision per query frame.

The compiled kernels of :mod:`catgraph.sequence` summarise, for every query frame,
velocity ``v`` and candidate length ``L``, the distribution of the window scores over
the reference (best and second-best score, mean, spread, mixture components, and the
scores of the best hypothesis over its shorter sub-windows) in a :class:`_Stats`. This
module turns those statistics into the match, the velocity, the window length and the
confidence (the rules and confidences are described in :mod:`catgraph.sequence`). The
code is vectorised over frames, so the streaming and the batch forms run exactly the
same arithmetic. Rule "predictive" is the one rule with a memory from frame to frame
(each candidate length's recent predictive record, a :class:`_Record`): it runs one
small loop over the frames of a block, ``O(G)`` per frame, and its state is carried from
block to block (batch) or from step to step (streaming), so both forms again run the
same arithmetic. It reads only ``G`` (frame, place) values of each difference row and the
row's mean and spread. Rule "decorrelated" keeps the same record, but its horizon is no
constant: a :class:`_Horizon` measures, frame by frame, how many frames the query's rows
take to decorrelate (the row's standardised differences at the best places of the row
``k`` frames back, against those at its own best places, averaged over the recent frames)
and the record scores each line that many frames ahead. Rule "spanning" keeps the tests of
"unrivalled" and reads the same clock: a line shorter than the query's decorrelation time is
about one observation, so only lines that span it may re-choose the velocity at the chosen
window or count as rivals of a longer window. Rule "punctuated" is "spanning"
whose spread test reads a short sub-window only where it spans half that time or holds a
*break* of the rows (a frame decorrelated from each of the few frames before it, read from the
same clock, :class:`_Breaks`). Rule "gated" is "spanning" whose spread test reads
a sub-window shorter than that time only where the window's own line is weak
(:data:`WEAK_LINE_SPREADS`): a strong line survives a few weak frames of a stretch of alike
rows, the old line after a jump does not. Rule "contested" is "gated" where a
weak line (:data:`CONTEST_LINE_SPREADS`) also yields to a rival that spans :data:`CONTEST_SPANS`
horizons and is significant by :data:`CONTEST_MARGIN` nats beyond the best of the random lines
searched: the same statistics, no clock beyond the horizon's. Rule "persistent"
is "contested" whose midpoint test reads a recent sub-window only where it spans the horizon,
where the window's line is weak, or where it holds a break of the rows (the clock of
"punctuated"). Rule "challenged" (the default) is "persistent" whose weak-line rival counts
beyond chance, without the margin and the velocities, where the window's own line is unproven
over its full length (:data:`PROVEN_MARGIN`). The confidence "changepoint"
is the one confidence with a memory: it reads the latest :data:`CHANGE_POINT_FRAMES` rows at
the places the chosen line passes (a :class:`_Recent` carried in the record from block to
block, or from step to step), so both forms again read the same values in the same order.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit, log_ndtr, ndtr

from .exceptions import InvalidParameterError

#: with rule "sustained": the longest admitted window at least this fraction as significant
SUSTAINED_FRACTION = 0.5

#: with rule "evident": how many common score spreads a recent sub-window of the window's
#: best hypothesis must lie below the mean score of random places at its length
EVIDENT_SPREADS = 1.0

#: with rule "unrivalled": a recent sub-window of the window's best line may trail the best line
#: of its own length by at most this many common score spreads ...
RIVAL_SPREADS = 0.5

#: ... where the sub-windows tested are those from this fraction of the window's length on ...
RIVAL_FRACTION = 0.2

#: ... and the best line of that length only counts as a rival when it is significant beyond
#: chance: ``log p < -ln N - RIVAL_MARGIN`` (``N`` reference places; ``-ln N`` is about the
#: log probability of the best of ``N`` random places)
RIVAL_MARGIN = 10.0


#: with rule "spanning": a recent sub-window's best line that spans the query's decorrelation
#: time counts as a rival when it is significant beyond chance by this many nats
#: (``log p < -ln N - SPANNING_MARGIN``; the sub-windows tested are those of the midpoint
#: test, from ``recent_fraction`` of the window on, and :data:`RIVAL_SPREADS` applies)
SPANNING_MARGIN = 6.0


#: with rule "punctuated": a frame *breaks* the query's rows where the clock's ratio (:class:`_Horizon`:
#: the row's mean standardised difference at the best places of the row ``k`` frames back, over
#: that at its own best places) is below :data:`DECORRELATION_LEVEL` at every lag ``k = 1 ..
#: BREAK_LAGS``: the frame has decorrelated from each of the frames just before it
BREAK_LAGS = 3

#: with rule "punctuated": the spread test reads a shorter sub-window only where its length is at
#: least this fraction of the frame's decorrelation horizon, or where the sub-window holds a
#: break of the rows (:data:`BREAK_LAGS`): a shorter stretch of alike rows is about one
#: observation, whose weakness says little about the line
SPREAD_HORIZON_FRACTION = 0.5

#: with rule "gated": the spread test reads a sub-window shorter than the frame's decorrelation
#: horizon only where the window's own line is *weak*: its score lies less than this many common
#: spreads (at the sub-window's length) below the mean of random places. A strong line (a correct
#: one through a stretch of alike rows) survives a few weak recent frames; a weak line (the old
#: line right after a jump) does not. Chosen on the whole condition table (1.5 and 2 measure
#: within 0.001 of it, ``docs/sequence.md``)
WEAK_LINE_SPREADS = 1.75

#: with rule "contested": where the window's own line is weak at a sub-window's length (its score
#: less than this many common spreads at that length below the random places' mean), a line of
#: that length counts as a rival where it spans :data:`CONTEST_SPANS` decorrelation horizons and
#: is significant beyond the best of the ``N V`` random lines searched (``N`` places, ``V``
#: velocities) by :data:`CONTEST_MARGIN` nats: ``log p < -ln(N V) - CONTEST_MARGIN`` ...
CONTEST_LINE_SPREADS = 2.5

#: ... at least this many horizons, so that it holds several independent observations ...
CONTEST_SPANS = 2.0

#: ... and this many nats. All three chosen on the whole condition table and the held-out worlds
#: (``docs/sequence.md``); at ``log p < -ln N`` (the velocities not counted, no margin) the worlds
#: gain more but weak lines of a constant speed in white rows are rejected by chance rivals
CONTEST_MARGIN = 1.0

#: with rule "challenged": the rival of rule "contested" counts beyond chance (``log p < -ln N``,
#: no margin, the velocities not counted), but only where the window's own line is *unproven* at
#: its full length: not significant beyond the best of the ``N V`` random lines searched by this
#: many nats (``log p >= -ln(N V) - PROVEN_MARGIN``). A weak line of a constant speed in white
#: rows is weak over every short stretch but proven over its whole length, so chance rivals of a
#: few frames leave it alone; a wrong long line (straight across a stretch driven at another
#: speed) is not. Chosen on the whole condition table and the held-out worlds
#: (``docs/sequence.md``: 6, 8, 10, 12 and 15 measured)
PROVEN_MARGIN = 10.0


#: with confidences "posterior" and "changepoint": prior odds that the query jumped away from
#: the chosen line at a given frame (against staying on it); chosen on the whole condition table
JUMP_ODDS = 0.3

#: with confidence "changepoint": how many of the latest frames along the chosen line are
#: weighed; every jump time ``t = 1 .. CHANGE_POINT_FRAMES`` frames back is one hypothesis
#: (the frames since it at random places), each at the prior odds :data:`JUMP_ODDS`. With 1
#: it is confidence "posterior" (the current frame alone). Chosen on the whole condition table
#: (``benchmarks/results/window_rules.md``), not per dataset
CHANGE_POINT_FRAMES = 5


#: with rule "predictive": each window's line at frame ``i - PREDICTION_HORIZON`` predicts the
#: place at frame ``i`` ...
PREDICTION_HORIZON = 10

#: ... and the window whose predictions have been best over a discounted recent past wins,
#: the past weighted with this half-life in frames
PREDICTION_HALF_LIFE = 1000.0

#: with rule "decorrelated": the horizon is the first lag ``k`` at which the query's rows have
#: decorrelated, i.e. at which a row's mean standardised difference at the best places of the
#: row ``k`` frames back, over its mean at its own best places, has fallen below this level
#: (averaged over recent frames) ...
DECORRELATION_LEVEL = 0.4

#: ... with this many best places per row ...
DECORRELATION_PLACES = 10

#: ... averaged over frames with this half-life ...
DECORRELATION_HALF_LIFE = 100.0

#: ... and at most this many frames (also the horizon while no lag has decorrelated yet)
HORIZON_MAX = 48


#: the confidences that weigh the admitted windows' agreeing gaps by the rows along the chosen
#: line (the current frame's, or with "changepoint" the latest frames'): with a fixed window
#: they are SeqSLAM's gap
WEIGHED_CONFIDENCES = ("posterior", "support", "changepoint")

#: the rules that choose the window by a predictive record (no sub-window statistics)
RECORD_RULES = ("predictive", "decorrelated")

#: the rules of the sub-window tests that read the query's decorrelation horizon (the clock of
#: rule "decorrelated"): only a line that spans it re-chooses the velocity or counts as a rival
HORIZON_RULES = ("spanning", "punctuated", "gated", "contested", "persistent", "challenged")

#: the rules that also read the breaks of the rows (the clock :class:`_Breaks`: the frames since
#: the latest frame decorrelated from each of the few before it)
BREAK_RULES = ("punctuated", "persistent", "challenged")


#: rule "tracked": a window's best place counts the filter's place posterior within this many
#: places either side (1: the place and its neighbours, which a fractional speed splits mass
#: between; 0, 1, 2, 3 and 5 measured in ``docs/sequence.md``)
TRACK_PLACES = 1


def _needs_sub(cfg: _Config) -> bool:
    return not cfg.fixed and cfg.rule not in ("literal", "tracked") + RECORD_RULES and cfg.grid.shape[0] > 1


def tracking_filter(n_places: int, velocities=None):
    """Rule "tracked"'s filter: the registry's ``filter`` method with its defaults (the
    whole-image model "tempered"; the rigid line beside its motion on maps of at most
    ``methods.RIGID_MAX_PLACES`` places), as the exact grid filter at any size, on the chain
    of the ``n_places`` reference places in order (both directions: the lines the matcher
    searches), its velocity bins ``velocities`` where given: the matcher's, the slopes of
    the lines whose places it weighs. (The registry's dense bins on small maps,
    ``grid.DENSE_VELOCITIES``, follow speeds between those slopes, where no candidate line
    lies, and cost the whole-Nordland adaptive window 5.19 s against 2.06 s.) Neither the
    varying speed's motion nor the twin that stands still through repeated frames
    (``repeat_prior``): the matcher's lines move on through them."""
    from .graph import PlaceGraph
    from .methods import make_filter, observation_model, resolve_params

    given = {} if velocities is None else {"velocity_bins": [float(v) for v in velocities]}
    params = resolve_params("filter", {"mode": "grid", "varying_prior": 0.0, "repeat_prior": 0.0, **given})
    return make_filter(params, PlaceGraph.chain(n_places), observation_model(params, n_places, None))


class _Tracker:
    """Rule "tracked": an exact grid filter over the reference's places, run beside the
    matcher on the same difference rows (before the matcher's hub correction: the filter's
    model corrects hubs itself).

    The filter is :func:`tracking_filter` with the matcher's velocities as its velocity
    bins, made at the first frame, when ``N`` is known.
    Per frame: one filter step (in the streaming step, on the calling thread while the
    matcher's kernels run on the others), and each candidate window's mass, the place
    posterior summed within ±:data:`TRACK_PLACES` of the window's best place. Memory and
    time are the filter's: ``O(N)`` per frame (the rigid line, on small maps, doubles its grid).
    """

    def __init__(self, velocities=None):
        self.velocities = velocities  # the filter's velocity bins: the matcher's velocities
        self.filter = None
        self.stepped = False  # the filter has taken the current frame's row (the streaming step's ``beside``)

    def step(self, raw_row: np.ndarray) -> None:
        """Step the filter on the current frame's row (it reads nothing of the matcher, so the
        streaming step runs it beside the matcher's kernels)."""
        if self.filter is None:
            self.filter = tracking_filter(raw_row.shape[0], self.velocities)
        self.filter.step(raw_row)
        self.stepped = True

    def masses(self, places: np.ndarray) -> np.ndarray:
        """``(len(places),)``: the current frame's posterior mass near each place."""
        self.stepped = False
        posterior = self.filter.place_posterior_
        out = np.empty(places.shape[0])
        for k, j in enumerate(places):
            out[k] = posterior[max(int(j) - TRACK_PLACES, 0):int(j) + TRACK_PLACES + 1].sum()
        return out


def _tracked(st: _Stats, cfg: _Config, frame_index: np.ndarray, want_curves: bool, raw_rows: np.ndarray | None,
             record: _Record):
    """Rule "tracked": of the candidate lengths, each at its own most significant velocity,
    the one whose best place holds the most of the tracking filter's place posterior
    (:class:`_Tracker`; the longest of equals); confidence "tracked", that mass as
    log-odds. Frames in order, one filter step each."""
    if raw_rows is None:
        raise InvalidParameterError("rule 'tracked' runs a filter on the difference rows beside the matcher; it runs "
                                    "in match_sequences and SequenceMatcher only. Choose another rule here.")
    n, _, g_count = st.best_s.shape
    rows = np.arange(n)
    log_p = _log_p(st)
    v_each = np.argmin(log_p, axis=1)  # (n, G): each length's most significant velocity
    places = np.take_along_axis(st.best_j, v_each[:, None, :], axis=1)[:, 0, :]
    tracker = record.tracker
    mass = np.empty((n, g_count))
    for t in range(n):
        if not tracker.stepped:  # else the streaming step has stepped it on this row already
            tracker.step(raw_rows[t])
        mass[t] = tracker.masses(places[t])
    g = g_count - 1 - np.argmax(mass[:, ::-1], axis=1)
    v = v_each[rows, g]
    held = np.clip(mass[rows, g], 1e-300, 1.0 - 1e-16)
    conf = np.log(held) - np.log1p(-held)
    length = np.minimum(cfg.grid[g], frame_index + 1)
    return (st.best_j[rows, v, g], st.best_s[rows, v, g], conf, length, cfg.velocities[v],
            log_p[rows, v] if want_curves else None)


def _position(v: float, i) -> np.ndarray:
    """``pos_v(i) = floor(v * i + 1/2)`` as int64 (the kernels' :func:`position`)."""
    return np.floor(v * np.asarray(i, dtype=np.float64) + 0.5).astype(np.int64)


class _Record:
    """Rules "predictive" and "decorrelated": the state carried from one frame to the next.

    For the last ``capacity`` frames (at least the horizon), the line each candidate length
    chose (its offset ``c = j* - pos_v(i)`` and the frame's velocity ``v``), and per
    candidate length the discounted sum of its prediction losses and the discounted count
    of losses, with the decay of the half-life. ``O(G K)`` numbers, whatever the number of
    places. With a ``clock`` (a :class:`_Horizon`, rule "decorrelated") the horizon of each
    frame is the clock's; without, the constant ``horizon``.
    """

    def __init__(self, g_count: int, horizon: int = PREDICTION_HORIZON, half_life: float = PREDICTION_HALF_LIFE,
                 clock: _Horizon | None = None):
        self.horizon = int(horizon)
        self.clock = clock
        capacity = self.horizon if clock is None else clock.capacity
        self.decay = 2.0 ** (-1.0 / float(half_life))
        self.offsets = np.zeros((capacity, g_count), dtype=np.int64)
        self.velocity = np.zeros(capacity)
        self.total = np.zeros(g_count)
        self.weight = 0.0
        self.recent: _Recent | None = None  # confidence "changepoint": the latest rows

    def loss(self, row: np.ndarray, i: int) -> np.ndarray | None:
        """``(G,)``: the standardised difference of ``row`` (frame ``i``) at the place each
        length's line of frame ``i - K`` predicts, ``0`` (a random place's expectation)
        where the line has left the reference or the row is flat; ``None`` before frame ``K``.
        With a clock, the clock first reads the row and sets ``K``."""
        spread = row.std()
        horizon = self.horizon if self.clock is None else self.clock.update(row, i, spread)
        if i < horizon:
            return None
        slot = (i - horizon) % self.offsets.shape[0]
        places = self.offsets[slot] + _position(self.velocity[slot], i)
        inside = (places >= 0) & (places < row.shape[0])
        if not spread > 0:
            return np.zeros(places.shape[0])
        return np.where(inside, (row[np.where(inside, places, 0)] - row.mean()) / spread, 0.0)

    def choose(self, loss: np.ndarray | None) -> int:
        """Add the frame's losses to the record; the length with the best record (ties: the longer)."""
        if loss is not None:
            self.total = self.decay * self.total + loss
            self.weight = self.decay * self.weight + 1.0
        if self.weight == 0.0:
            return self.total.shape[0] - 1
        mean = self.total / self.weight
        return self.total.shape[0] - 1 - int(np.argmin(mean[::-1]))

    def remember(self, i: int, best_j: np.ndarray, velocity: float) -> None:
        """Store frame ``i``'s lines (``best_j``: each length's best place at ``velocity``)."""
        slot = i % self.offsets.shape[0]
        self.offsets[slot] = best_j - _position(velocity, i)
        self.velocity[slot] = velocity


class _Horizon:
    """Rule "decorrelated": the horizon from the query's own rows, frame by frame.

    Each row ``i`` standardised, ``z_i = (d_i - mean d_i) / std d_i``, and its
    :data:`DECORRELATION_PLACES` best (smallest) places ``B_i`` kept for the last
    :data:`HORIZON_MAX` frames. For every lag ``k`` the ratio
    ``r_k(i) = mean_{j in B_{i-k}} z_i[j] / mean_{j in B_i} z_i[j]`` (1 while the places that
    matched frame ``i - k`` still match frame ``i`` as well as its own best; about 0 once they
    are random places for it) is averaged over the frames with the half-life
    :data:`DECORRELATION_HALF_LIFE`, and the horizon is the first lag whose average is below
    :data:`DECORRELATION_LEVEL` (:data:`HORIZON_MAX` while none is). A query shown at half
    the speed keeps its rows alike twice as long, and so doubles the horizon. A flat row (no
    spread, e.g. a frame without information) has no best places: it adds no ratio, and
    later frames add none at its lag. ``O(K m)`` numbers of state and ``O(N + K m)`` work
    per frame.

    The row is never standardised as a whole: ``z`` rises with ``d`` (``std > 0``), so the
    ``m`` best places are the row's ``m`` smallest values, found in one compiled pass
    (:func:`catgraph._sequence_kernels.smallest_places`, ascending by value, then place),
    and ``z`` is formed only at the ``(K + 1) m`` places read, with the same floats as the
    whole standardised row. Where the ``m``-th and ``(m + 1)``-th smallest tie in ``z`` the
    set is not unique, and the places are those of ``np.argpartition`` of the standardised
    row, as a whole. Either way the set is that of ``np.argpartition``; its order, in
    which the ``m`` values are summed, may differ from the partition's own (which depends
    on the processor's vector instructions), so the averages may differ in their last
    bits (``tests/test_live_horizon.py`` keeps the partition as the reference).
    """

    def __init__(self, capacity: int = HORIZON_MAX, places: int = DECORRELATION_PLACES,
                 half_life: float = DECORRELATION_HALF_LIFE, level: float = DECORRELATION_LEVEL):
        self.capacity = int(capacity)
        self.places = int(places)
        self.level = float(level)
        self.decay = 2.0 ** (-1.0 / float(half_life))
        self.best = np.zeros((self.capacity, self.places), dtype=np.int64)
        self.filled = np.zeros(self.capacity, dtype=bool)
        self.total = np.zeros(self.capacity)  # lag k at index k - 1
        self.weight = np.zeros(self.capacity)

    def update(self, row: np.ndarray, i: int, spread: float, centre: float | None = None) -> int:
        """Read frame ``i``'s row (``spread``: its standard deviation; ``centre``: its mean,
        ``row.mean()`` where not given); the horizon ``K >= 1``."""
        slot = i % self.capacity
        ratio = np.zeros(self.capacity)
        seen = np.zeros(self.capacity)
        if spread > 0:
            centre = row.mean() if centre is None else centre
            best = self._best_places(row, centre, spread)
            m = best.shape[0]
            own = ((row[best] - centre) / spread).mean()
            lags = np.arange(1, min(i, self.capacity) + 1)
            if own < 0 and lags.size:
                back = (i - lags) % self.capacity
                known = self.filled[back]
                past = (row[self.best[back, :m]] - centre) / spread
                ratio[: lags.size] = np.where(known, past.mean(axis=1) / own, 0.0)
                seen[: lags.size] = known
            self.best[slot, :m] = best
        self.filled[slot] = spread > 0
        self.total = self.decay * self.total + ratio
        self.weight = self.decay * self.weight + seen
        with np.errstate(divide="ignore", invalid="ignore"):
            below = (self.weight > 0) & (self.total / self.weight < self.level)
        return int(np.argmax(below)) + 1 if below.any() else self.capacity

    def _best_places(self, row: np.ndarray, centre: float, spread: float) -> np.ndarray:
        """The row's :attr:`places` best places (``spread > 0``), as the set of
        ``np.argpartition`` of the standardised row."""
        n = row.shape[0]
        m = min(self.places, n)
        if m >= n:
            return np.arange(m)
        if row.dtype == np.float64 and row.flags.c_contiguous:
            from ._sequence_kernels import smallest_places

            idx, val = np.empty(m + 1, dtype=np.int64), np.empty(m + 1)
            smallest_places(row, idx, val)
            edge = (row[idx[m - 1:]] - centre) / spread
            if edge[0] < edge[1]:  # the m-th best strictly below every other place: one set
                return idx[:m]
        return np.argpartition((row - centre) / spread, m - 1)[:m]


class _Breaks(_Horizon):
    """Rule "punctuated": the clock of :class:`_Horizon` that also marks the *breaks* of the rows.

    After :meth:`_Horizon.update` has read frame ``i``'s row, the frame breaks the rows where
    its ratio at every lag ``k = 1 .. lags`` (:data:`BREAK_LAGS`) is below the clock's level,
    :data:`DECORRELATION_LEVEL`: its best places are random places for each of the ``lags``
    rows before it, so the query has just moved to another scene (or jumped). The ratios are
    the clock's own: the same best places and the same floats, read at ``lags`` more places
    sets (``O(lags m)`` work). A frame is no break where its row is flat, where its own best
    places are not below its mean, where a row within the lags was flat, or before frame
    ``lags``. :attr:`broke` says whether the frame last read broke the rows and :attr:`since`
    how many frames ago the latest break was (0 at a breaking frame; more than any window
    before the first break).
    """

    def __init__(self, *args, lags: int = BREAK_LAGS, **kwargs):
        super().__init__(*args, **kwargs)
        self.lags = int(lags)
        self.last = -(10 ** 9)  # the frame of the latest break
        self.broke = False
        self.since = 10 ** 9

    def update(self, row: np.ndarray, i: int, spread: float, centre: float | None = None) -> int:
        k = super().update(row, i, spread, centre)
        self.broke = False
        if spread > 0 and i >= self.lags:
            centre = row.mean() if centre is None else centre
            m = min(self.places, row.shape[0])
            own = ((row[self.best[i % self.capacity, :m]] - centre) / spread).mean()
            back = (i - np.arange(1, self.lags + 1)) % self.capacity
            if own < 0 and self.filled[back].all():
                past = (row[self.best[back, :m]] - centre) / spread
                self.broke = bool(np.all(past.mean(axis=1) / own < self.level))
        if self.broke:
            self.last = i
        self.since = i - self.last
        return k


class _Recent:
    """Confidence "changepoint": the latest frames' rows and moments, carried from block to block.

    The confidence of frame ``i`` reads the standardised differences of frames ``i - 1 ..
    i - T + 1`` (``T`` = :data:`CHANGE_POINT_FRAMES`) at the places the frame's chosen line
    passes; that line is known only at frame ``i``, so the whole rows are kept: the last
    ``T - 1`` rows (copies, float64) with their means and spreads, ``8 (T - 1) (N + 3)``
    bytes (32 MB at ``N = 10^6`` with ``T = 5``, against the matcher's own int16 ring of
    ``2 (l_max + 1) N`` bytes, 1 GB). A block of frames reads its own earlier rows from the
    block and only the frames before it from here. Rows handed as something other than an
    array (the cluster's :class:`catgraph.distributed._Rows`, which serves the values
    itself) keep only their moments.
    """

    def __init__(self, frames: int | None = None):
        self.frames = int(CHANGE_POINT_FRAMES if frames is None else frames)
        slots = max(0, self.frames - 1)
        self.index = np.full(slots, -1, dtype=np.int64)  # the frame held in each slot (frame % slots)
        self.rows: np.ndarray | None = None  # (slots, N), from the first block handed as an array
        self.centres = np.zeros(slots)
        self.spreads = np.zeros(slots)

    def keep(self, frame_index: np.ndarray, rows_d, moments: tuple[np.ndarray, np.ndarray]) -> None:
        """Remember the last ``T - 1`` frames of a block (``frame_index`` consecutive)."""
        slots = self.index.shape[0]
        copy = isinstance(rows_d, np.ndarray)
        if copy and slots and self.rows is None:
            self.rows = np.zeros((slots, rows_d.shape[1]))
        for t in range(max(0, frame_index.shape[0] - slots), frame_index.shape[0]):
            i = int(frame_index[t])
            slot = i % slots
            self.index[slot] = i
            if copy:
                self.rows[slot] = rows_d[t]
            self.centres[slot], self.spreads[slot] = moments[0][t], moments[1][t]


def _new_record(cfg: _Config) -> _Record | None:
    """The state a rule carries from frame to frame (rules "predictive" and "decorrelated";
    rules "spanning", "gated" and "contested" read only the record's clock, rules "punctuated",
    "persistent" and "challenged" only the clock that also marks the breaks, :class:`_Breaks`; confidence "changepoint" keeps the latest
    rows in the record's :class:`_Recent`, whatever the rule; rule "tracked" keeps its filter, a :class:`_Tracker`)."""
    if cfg.fixed:
        return None
    if cfg.rule == "tracked":
        record = _Record(cfg.grid.shape[0])
        record.tracker = _Tracker(cfg.velocities)
        return record
    recent = _Recent() if cfg.confidence == "changepoint" else None
    if cfg.rule in BREAK_RULES:
        record = _Record(cfg.grid.shape[0], clock=_Breaks())
    elif cfg.rule == "decorrelated" or cfg.rule in HORIZON_RULES:
        record = _Record(cfg.grid.shape[0], clock=_Horizon())
    elif cfg.rule in RECORD_RULES or recent is not None:
        record = _Record(cfg.grid.shape[0])
    else:
        return None
    record.recent = recent
    return record


def _predictive_choice(st: _Stats, cfg: _Config, frame_index: np.ndarray, rows_d: np.ndarray, v: np.ndarray,
                       record: _Record) -> np.ndarray:
    """``(n,)`` chosen length index per frame, in order, updating ``record``."""
    g = np.empty(frame_index.shape[0], dtype=np.int64)
    for t, i in enumerate(frame_index):
        g[t] = record.choose(record.loss(rows_d[t], int(i)))
        record.remember(int(i), st.best_j[t, v[t]], float(cfg.velocities[v[t]]))
    return g



class _Stats:
    """Per-frame, per-velocity, per-window statistics produced by the kernels."""

    def __init__(self, n: int, v: int, g: int, k: int, with_sub: bool = True):
        self.best_j = np.zeros((n, v, g), dtype=np.int64)
        self.best_s = np.zeros((n, v, g))
        self.second_s = np.zeros((n, v, g))
        self.mean = np.zeros((n, v, g))
        self.std = np.zeros((n, v, g))
        self.weights = np.zeros((n, v, g, k))
        self.locs = np.zeros((n, v, g, k))
        self.scales = np.zeros((n, v, g, k))
        self.sub = np.zeros((n, v, g, g if with_sub else 0))


def _common_std(st: _Stats) -> np.ndarray:
    """``(n, 1, G)``: the widest score spread over the velocities at each window length."""
    return st.std.max(axis=1, keepdims=True)


def _log_p(st: _Stats) -> np.ndarray:
    """``log p_i(L, v)``, ``(n, V, G)``: log probability of a draw at most the best score.

    Each velocity's approximation is widened to the common spread (:func:`_common_std`):
    lines at different velocities average differently many distinct places, so their
    spreads differ, and a narrow spread alone would make a mediocre line look
    significant. With one velocity this is the approximation itself.
    """
    common = _common_std(st)
    with np.errstate(divide="ignore", invalid="ignore"):
        widen = np.where(st.std > 0, common / st.std, 1.0)[..., None]
    best = st.best_s[..., None]
    scales = st.scales * widen
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(scales > 0, (best - st.locs) / scales, np.where(best < st.locs, -np.inf, np.inf))
        terms = np.log(st.weights) + log_ndtr(z)
    if terms.shape[-1] == 1:
        return terms[..., 0]
    top = terms.max(axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    return (top + np.log(np.exp(terms - top).sum(axis=-1, keepdims=True)))[..., 0]


def _row_moments(rows) -> tuple[np.ndarray, np.ndarray]:
    """``(n,)`` each row's mean and ``(n,)`` its standard deviation, one row at a time (the
    arithmetic of ``row.mean()`` and ``row.std()``, so that the streaming and the batch forms,
    and the cluster's rows, agree): read once per frame by the horizon and the confidence."""
    n = rows.shape[0]
    centres, spreads = np.empty(n), np.empty(n)
    whole = isinstance(rows, np.ndarray)
    for t in range(n):
        row = rows[t]
        centres[t] = row.mean()
        # numpy's std with the mean handed in skips summing the row again: the same floats
        spreads[t] = row.std(mean=centres[t]) if whole else row.std()
    return centres, spreads


def _horizons(cfg: _Config, frame_index: np.ndarray, rows_d, record: _Record | None,
              moments: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(n,)``: the decorrelation horizon of each frame (rules "spanning" and "punctuated"),
    in order, from the record's clock (:class:`_Horizon`, the one of rule "decorrelated"),
    and ``(n,)`` the frames since the latest break of the rows (rule "punctuated",
    :class:`_Breaks`); ``None`` where the rule reads neither. ``moments``:
    :func:`_row_moments` of ``rows_d``."""
    if cfg.fixed or cfg.rule not in HORIZON_RULES:
        return None, None
    centres, spreads = moments
    out = np.empty(frame_index.shape[0], dtype=np.int64)
    since = np.empty(frame_index.shape[0], dtype=np.int64) if cfg.rule in BREAK_RULES else None
    for t, i in enumerate(frame_index):
        out[t] = record.clock.update(rows_d[t], int(i), spreads[t], centres[t])
        if since is not None:
            since[t] = record.clock.since
    return out, since


def _admissible(st: _Stats, cfg: _Config, log_p: np.ndarray | None = None, n_places: int = 1,
                horizon: np.ndarray | None = None, since: np.ndarray | None = None) -> np.ndarray:
    """``(n, V, G)``: windows whose best hypothesis is supported by its own recent frames.

    Rules "consistent", "sustained" and "evident": every shorter sub-window of the window's
    best hypothesis from ``recent_fraction * L`` on lies closer to the window's own score
    than to the mean score of random places at that length. Rule "evident" also asks
    *every* shorter sub-window to lie at least :data:`EVIDENT_SPREADS` common spreads below
    that mean: a recent stretch that is not clearly better than a random place is no
    evidence that the line still holds, however weak the window's own average is. Rule
    "unrivalled" adds a third test: over every recent sub-window from
    :data:`RIVAL_FRACTION` of the window on, the window's best line may trail the best line
    of that length (same velocity) by at most :data:`RIVAL_SPREADS` common spreads, unless
    that best line is no more significant than chance (``log_p`` at that length not below
    ``-ln n_places - RIVAL_MARGIN``). A long line that drifts off a route driven at a varying
    speed, or that runs along repeated scenery, is then rejected as soon as a clearly
    significant shorter line explains its recent frames better; a weak stretch where no
    short line is significant (most of Nordland's) leaves it alone. Rule "spanning" tests the
    rival on the sub-windows of the midpoint test (from ``recent_fraction * L`` on), at the
    smaller margin :data:`SPANNING_MARGIN`, and counts a rival only when its length is at least
    the frame's decorrelation ``horizon`` (``(n,)``): a shorter line is about one observation,
    whose Gaussian significance says little (on Nordland, whose rows stay alike for about 20
    frames, the best 5-frame line of a hard stretch looks significant by chance). Rule
    "punctuated" is "spanning" with the spread test read only on the sub-windows that span
    :data:`SPREAD_HORIZON_FRACTION` of the horizon or hold a break of the rows (``since``,
    ``(n,)``: frames since the latest break, :class:`_Breaks`; the sub-window of length ``l``
    holds it where ``since < l``): within a stretch of alike rows a correct line's recent
    frames are about one observation and may be no better than random places, but right
    after the rows break they are evidence again. Rule "gated" is "spanning" with the spread
    test read on the sub-windows that span the horizon, and on a shorter one only where the
    window's own line is weak (its score less than :data:`WEAK_LINE_SPREADS` common spreads at
    the sub-window's length below the random places' mean there): a strong line survives a
    weak recent stretch of alike rows, a weak one (the old line after a jump) does not. Rule
    "contested" is "gated" with a second kind of rival: where the window's own line is weak at
    a recent sub-window's length (less than :data:`CONTEST_LINE_SPREADS` common spreads below
    the random places' mean there), a line of that length that spans :data:`CONTEST_SPANS`
    horizons counts as a rival where it is significant beyond the best of the ``N V`` random
    lines searched by :data:`CONTEST_MARGIN` nats (not :data:`SPANNING_MARGIN` beyond the best
    of ``N``): where rows decorrelate within a few frames, a wrong long line (through repeated
    scenery, or straight across a stretch driven at another speed) is weak, and a short line of
    several independent observations that beats it over its recent frames is evidence. Rule
    "persistent" is "contested" with the midpoint test read only on the recent sub-windows that
    span the horizon, where the window's own line is weak (:data:`CONTEST_LINE_SPREADS`), or that
    hold a break of the rows (``since``, as for "punctuated"): a strong line survives a recent
    stretch of a horizon or less that lies more than half way to random places, unless the rows
    broke within it. Rule "challenged" is "persistent" whose weak-line rival counts beyond chance
    (``log p < -ln n_places``, no margin) where the window's own line is unproven at its full
    length (``log p >= -ln(N V) - PROVEN_MARGIN``): a line proven over its whole length keeps the
    tests of "persistent" alone.
    """
    n, v_count, g_count = st.best_s.shape
    if not _needs_sub(cfg):
        return np.ones((n, v_count, g_count), dtype=bool)
    lengths = cfg.grid.astype(np.float64)
    shorter = lengths[None, :] < lengths[:, None]  # (G, H)
    recent = shorter & (lengths[None, :] >= cfg.recent_fraction * lengths[:, None])
    # the common spread (the widest over the velocities) at each sub-window's length, the
    # sub-windows' lengths and the window's own line's level at them, each formed once
    common = _common_std(st)[:, :, None, :]  # (n, 1, 1, H)
    l4 = lengths[None, None, None, :]
    sub_mean = st.mean[:, :, None, :]  # (n, V, 1, H)
    level = None
    if cfg.rule in ("persistent", "challenged", "gated", "contested"):
        level = (sub_mean - st.best_s[..., None]) / np.where(common > 0, common, 1.0)  # (n, V, G, H)
    if cfg.rule in HORIZON_RULES:
        reach = horizon.astype(np.float64)[:, None, None, None]
    # every recent shorter sub-window of the best hypothesis (same line) must lie closer to
    # the window's own score than to the mean of random places at that length
    mid = 0.5 * (st.best_s[..., None] + sub_mean)  # (n, V, G, H)
    if cfg.rule in ("persistent", "challenged"):
        # only on the sub-windows that span the horizon, where the window's own line is weak,
        # or that hold a break of the rows
        read = (l4 >= reach) | (level < CONTEST_LINE_SPREADS) | (since.astype(np.float64)[:, None, None, None] < l4)
        ok = (st.sub <= mid) | ~(recent[None, None] & read)
    else:
        ok = (st.sub <= mid) | ~recent
    if cfg.rule in ("evident", "unrivalled", "spanning"):
        # and every shorter sub-window must stand out from random places at its length: at
        # least EVIDENT_SPREADS common spreads (the widest over the velocities) below their mean
        ok &= (st.sub <= sub_mean - EVIDENT_SPREADS * common) | ~shorter
    if cfg.rule == "punctuated":
        # the same, on the sub-windows that span half the horizon or hold a break of the rows
        spans = (l4 >= SPREAD_HORIZON_FRACTION * reach) | (since.astype(np.float64)[:, None, None, None] < l4)
        ok &= (st.sub <= sub_mean - EVIDENT_SPREADS * common) | ~(shorter[None, None] & spans)
    if cfg.rule in ("gated", "contested", "persistent", "challenged"):
        # the same, on the sub-windows that span the horizon, and on shorter ones where the
        # window's own line is weak
        spans = (l4 >= reach) | (level < WEAK_LINE_SPREADS)
        ok &= (st.sub <= sub_mean - EVIDENT_SPREADS * common) | ~(shorter[None, None] & spans)
    if cfg.rule == "unrivalled":
        # and no significant line of a recent sub-window's length may beat the window's
        # line over those frames by more than RIVAL_SPREADS common spreads
        tested = shorter & (lengths[None, :] >= RIVAL_FRACTION * lengths[:, None])
        rival = log_p < -np.log(n_places) - RIVAL_MARGIN  # (n, V, H)
        beaten = st.sub > st.best_s[:, :, None, :] + RIVAL_SPREADS * common  # (n, V, G, H)
        ok &= ~(beaten & rival[:, :, None, :]) | ~tested
    if cfg.rule in HORIZON_RULES:
        # a rival: a significant line of a recent sub-window's length that spans the horizon
        rival = (log_p < -np.log(n_places) - SPANNING_MARGIN) & (lengths[None, None, :] >= horizon[:, None, None])
        beaten = st.sub > st.best_s[:, :, None, :] + RIVAL_SPREADS * common  # (n, V, G, H)
        ok &= ~(beaten & rival[:, :, None, :]) | ~recent
        if cfg.rule in ("contested", "persistent"):
            # and, where the window's own line is weak at the sub-window's length, a line that
            # spans CONTEST_SPANS horizons and is significant beyond the best of N V random lines
            contender = (log_p < -np.log(float(n_places) * v_count) - CONTEST_MARGIN) & (
                lengths[None, None, :] >= CONTEST_SPANS * reach[:, :, :, 0])  # (n, V, H)
            weak = level < CONTEST_LINE_SPREADS  # (n, V, G, H), the spread test's level
            ok &= ~(beaten & contender[:, :, None, :] & weak) | ~recent
        elif cfg.rule == "challenged":
            # where the window's own line is weak at the sub-window's length and unproven at its
            # full length, a line that spans CONTEST_SPANS horizons and is beyond chance
            contender = (log_p < -np.log(float(n_places))) & (
                lengths[None, None, :] >= CONTEST_SPANS * reach[:, :, :, 0])  # (n, V, H)
            unproven = log_p >= -np.log(float(n_places) * v_count) - PROVEN_MARGIN  # (n, V, G), the window's
            weak = level < CONTEST_LINE_SPREADS  # (n, V, G, H)
            ok &= ~(beaten & contender[:, :, None, :] & weak & unproven[..., None]) | ~recent
    admissible = np.all(ok, axis=3)
    admissible[:, :, 0] = True
    return admissible


def _current_z(rows: np.ndarray, match: np.ndarray, score: np.ndarray | None = None,
               moments: tuple[np.ndarray, np.ndarray] | None = None):
    """``(n,)``: each frame's own difference at its match, standardised over its row.

    With ``score`` (the window score of each match) also returns that score standardised
    with the same row's mean and spread: the chosen line's mean standardised difference
    per frame. One row at a time, so that the streaming and the batch forms do the same
    arithmetic. ``moments``: :func:`_row_moments` of ``rows`` where already read.
    """
    centres, spreads = _row_moments(rows) if moments is None else moments
    out = np.zeros(match.shape[0])
    line = np.zeros(match.shape[0])
    for t in range(match.shape[0]):
        row = rows[t]
        spread = spreads[t]
        if spread > 0:
            centre = centres[t]
            out[t] = (row[match[t]] - centre) / spread
            if score is not None:
                line[t] = (score[t] - centre) / spread
    return out if score is None else (out, line)


def _on_line(z: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """``(n,)``: the posterior probability that the current frame still lies on the chosen line.

    Two hypotheses for the current frame's standardised difference ``z`` at the match: the
    frame lies on the line (a unit normal around the line's mean standardised difference
    ``mu``) or the query jumped and the match is a random place (a standard normal), with
    prior odds :data:`JUMP_ODDS` of a jump. The log likelihood ratio is
    ``(z^2 - (z - mu)^2) / 2``; the probability is its logistic less ``ln JUMP_ODDS``.
    Where single frames say little (``mu`` near 0) it stays near its prior; where they are
    distinctive it follows the current frame.
    """
    return expit((z * z - (z - mu) ** 2) / 2.0 - np.log(JUMP_ODDS))


def _line_places(match: np.ndarray, velocity: np.ndarray, frame_index: np.ndarray, frames: int):
    """``(n, T)`` places of each frame's chosen line at frames ``i, i - 1, .. i - T + 1``
    (``match_i - (pos_v(i) - pos_v(i - f))``, the kernels' lines) and ``(n, T)`` which of
    those frames exist (``i - f >= 0``)."""
    f = np.arange(frames)
    i = frame_index[:, None]
    earlier = i - f[None, :]
    v = np.asarray(velocity, dtype=np.float64)[:, None]
    places = match[:, None] - (_position(v, i) - _position(v, np.maximum(earlier, 0)))
    return places, earlier >= 0


def _line_z(rows_d, moments: tuple[np.ndarray, np.ndarray], frame_index: np.ndarray, match: np.ndarray,
            velocity: np.ndarray, recent: _Recent) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The standardised differences along each frame's chosen line over its latest ``T`` frames.

    Returns ``z`` (``(n, T)``: ``(d_{i-f}[place] - mean d_{i-f}) / std d_{i-f}`` at the line's
    place of frame ``i - f``; 0 where not read), ``counts`` (``(n, T)``: the place lies on the
    reference and the row has a spread: the term enters the likelihood ratio) and ``exists``
    (``(n, T)``: frame ``i - f`` exists, a jump time that is a hypothesis). Frames of the block
    are read from ``rows_d`` (moments: :func:`_row_moments` of it), earlier ones from
    ``recent``; rows that serve their own values (``line_values``, the cluster's) are asked
    for every place at once.
    """
    n_rows = rows_d.shape[1]
    places, exists = _line_places(match, velocity, frame_index, recent.frames)
    inside = exists & (places >= 0) & (places < n_rows)
    f = np.arange(recent.frames)[None, :]
    rel = np.arange(match.shape[0])[:, None] - f  # block row of frame i - f
    mine = rel >= 0
    take = np.where(mine, rel, 0)
    slots = recent.index.shape[0]
    back = exists & ~mine  # frames before the block: from the carried rows
    slot = np.where(back, (frame_index[:, None] - f) % max(slots, 1), 0)
    before = back.any()
    centres = np.where(mine, moments[0][take], recent.centres[slot] if before else 0.0)
    spreads = np.where(mine, moments[1][take], recent.spreads[slot] if before else 0.0)
    spreads = np.where(exists, spreads, 0.0)
    counts = inside & (spreads > 0)
    if hasattr(rows_d, "line_values"):
        values = np.zeros(places.shape)
        if counts.any():
            values[counts] = rows_d.line_values(rel[counts], places[counts])
    else:
        at = np.where(counts, places, 0)
        values = rows_d[take, at]
        if before:
            values = np.where(mine, values, recent.rows[slot, at])
    safe = np.where(counts, spreads, 1.0)
    z = np.where(counts, (values - centres) / safe, 0.0)
    return z, counts, exists


def _on_line_since(z: np.ndarray, counts: np.ndarray, exists: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """``(n,)``: confidence "changepoint", the posterior probability that the query has not
    jumped off the chosen line within its latest ``T`` frames.

    Confidence "posterior" (:func:`_on_line`) weighs the current frame alone. Here every jump
    time ``t = 1 .. T`` frames back (``T`` = :data:`CHANGE_POINT_FRAMES`, fewer at the
    query's start) is a hypothesis at the prior odds :data:`JUMP_ODDS`: the ``t`` frames since
    the jump lie at random places (their standardised differences ``z`` at the line a standard
    normal), the frames before it on the line (a unit normal around the line's mean
    standardised difference ``mu`` of the current frame). The log likelihood ratio of "no
    jump" against "a jump ``t`` frames back" is ``LLR_t = sum_{f < t} (z_f^2 - (z_f - mu)^2) / 2``
    over the latest ``t`` frames (a term is 0 where the line has left the reference or the row
    is flat: ``counts``), and ``P = 1 / (1 + JUMP_ODDS sum_t exp(-LLR_t))``, computed as
    ``e^{-m} / (e^{-m} + JUMP_ODDS sum_t e^{-LLR_t - m})`` with ``m = max(0, max_t -LLR_t)``.
    The running sums and the sum over ``t`` are added one frame at a time, in order (the same
    floats in the streaming and the batch forms). With ``T = 1`` it equals "posterior".
    """
    llr = np.where(counts, (z * z - (z - mu[:, None]) ** 2) / 2.0, 0.0)
    cumulative = np.empty_like(llr)
    running = np.zeros(llr.shape[0])
    for f in range(llr.shape[1]):
        running = running + llr[:, f]
        cumulative[:, f] = running
    top = np.maximum(0.0, np.where(exists, -cumulative, -np.inf).max(axis=1))
    total = np.zeros(llr.shape[0])
    for f in range(llr.shape[1]):
        total = total + np.where(exists[:, f], np.exp(-cumulative[:, f] - top), 0.0)
    keep = np.exp(-top)
    return keep / (keep + JUMP_ODDS * total)


def _row_reads(cfg: _Config, frame_index: np.ndarray, rows_d, record: _Record | None):
    """What :func:`_decide` reads of the rows alone, before any statistic of the kernels:
    ``(moments, horizon, since)``, each row's mean and spread (:func:`_row_moments`, read
    once by the horizon and the confidence; ``None`` where neither reads them) and
    :func:`_horizons` (the record's clock moved on by these frames). The streaming step
    forms them while the kernels' other threads work (:func:`_sequence_kernels.run_batch`,
    ``beside``)."""
    reads = cfg.rule in HORIZON_RULES or cfg.confidence in WEIGHED_CONFIDENCES
    moments = _row_moments(rows_d) if reads and not cfg.fixed else None
    horizon, since = _horizons(cfg, frame_index, rows_d, record, moments)
    return moments, horizon, since


def _decide(st: _Stats, cfg: _Config, frame_index: np.ndarray, want_curves: bool, rows_d: np.ndarray,
            record: _Record | None = None, reads=None, raw_rows: np.ndarray | None = None,
            blank: np.ndarray | None = None):
    """Each frame's answer from the kernels' statistics ``st``: ``(match, score, confidence,
    length, velocity, log_p)``. ``reads``: :func:`_row_reads` of these frames where already
    formed (the record's clock moved on once, by whichever call formed them). ``raw_rows``:
    the rows before the hub correction (rule "tracked" only).

    A frame whose own row has no information (constant: a blank frame,
    :mod:`catgraph.matching`) gets no output, match :data:`~catgraph.matching.NO_MATCH` and
    confidence :data:`~catgraph.matching.NO_OUTPUT_CONFIDENCE`, as with a single frame;
    the window's statistics go on as computed. ``blank``: those frames, where ``rows_d``
    is not an array of the rows (a cluster's, which knows them from its normalisation)."""
    if cfg.rule == "tracked" and not cfg.fixed:
        answer = _tracked(st, cfg, frame_index, want_curves, raw_rows, record)
    else:
        answer = _decide_window(st, cfg, frame_index, want_curves, rows_d, record, reads)
    if blank is None:
        blank = np.ptp(rows_d, axis=1) == 0
    if blank.any():
        from .matching import NO_MATCH, NO_OUTPUT_CONFIDENCE

        match, score, conf, *rest = answer
        match, conf = np.where(blank, NO_MATCH, match), np.where(blank, NO_OUTPUT_CONFIDENCE, conf)
        answer = (match, score, conf, *rest)
    return answer


def _decide_window(st: _Stats, cfg: _Config, frame_index: np.ndarray, want_curves: bool, rows_d: np.ndarray,
                   record: _Record | None = None, reads=None):
    """:func:`_decide` for every rule but "tracked"."""
    n, v_count, g_count = st.best_s.shape
    rows = np.arange(n)
    log_p = _log_p(st)
    # the velocity: the one whose windows are the most significant summed over every length
    v = np.argmin(log_p.sum(axis=2), axis=1)
    lp = log_p[rows, v]  # (n, G)
    moments, horizon, since = _row_reads(cfg, frame_index, rows_d, record) if reads is None else reads
    every = _admissible(st, cfg, log_p, rows_d.shape[1], horizon, since)  # (n, V, G)
    admissible = every[rows, v]
    masked = np.where(admissible, lp, np.inf)
    if cfg.rule == "sustained" and not cfg.fixed:
        # the longest admitted window at least SUSTAINED_FRACTION as significant (in log p)
        # as the most significant admitted one; the argmin itself always qualifies
        floor = SUSTAINED_FRACTION * masked.min(axis=1, keepdims=True)
        qualified = admissible & (lp <= floor)
        g = g_count - 1 - np.argmax(qualified[:, ::-1], axis=1)
    elif cfg.rule in RECORD_RULES and not cfg.fixed:
        g = _predictive_choice(st, cfg, frame_index, rows_d, v, record)
    else:
        g = np.argmin(masked, axis=1)
    if horizon is not None:
        # rules "spanning" and "punctuated": a chosen window that spans the decorrelation time identifies its own
        # velocity; the velocity is re-chosen at that length (the window stays admitted)
        v = np.where(cfg.grid[g] >= horizon, np.argmin(log_p[rows, :, g], axis=1), v)
        lp = log_p[rows, v]
        admissible = every[rows, v]
        admissible[rows, g] = True
    best = st.best_s[rows, v, g]
    std = _common_std(st)[rows, 0, g]
    match = st.best_j[rows, v, g]
    if cfg.confidence == "gap" or (cfg.confidence in WEIGHED_CONFIDENCES and cfg.fixed):
        with np.errstate(divide="ignore", invalid="ignore"):
            conf = np.where(std > 0, (st.second_s[rows, v, g] - best) / std, 0.0)
        conf = np.where(np.isfinite(conf), conf, 0.0)
    elif cfg.confidence in WEIGHED_CONFIDENCES:
        # the gaps of every admitted window (chosen velocity) whose best place agrees
        stds = _common_std(st)[:, 0, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            gaps = np.where(stds > 0, (st.second_s[rows, v] - st.best_s[rows, v]) / stds, 0.0)
        gaps = np.where(np.isfinite(gaps), gaps, 0.0)
        agree = admissible & (np.abs(st.best_j[rows, v] - match[:, None]) <= cfg.radius)
        conf = np.where(agree, gaps, 0.0).sum(axis=1)
        if cfg.confidence == "support":
            conf = conf * ndtr(-_current_z(rows_d, match, moments=moments))
        elif cfg.confidence == "changepoint":
            _, mu = _current_z(rows_d, match, best, moments)
            recent = record.recent
            conf = conf * _on_line_since(*_line_z(rows_d, moments, frame_index, match, cfg.velocities[v], recent), mu)
            recent.keep(frame_index, rows_d, moments)
        else:
            conf = conf * _on_line(*_current_z(rows_d, match, best, moments))
    elif cfg.confidence == "neglogp":
        conf = -lp[rows, g]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            conf = np.where(std > 0, (st.mean[rows, v, g] - best) / std, 0.0)
    length = np.minimum(cfg.grid[g], frame_index + 1)
    return match, best, conf, length, cfg.velocities[v], (lp if want_curves else None)
