"""Frames that come again: the twin reading that stands still through them.

A query frame equal to the one before (the same difference row, with no odometry) does not
say whether the robot moved: a vehicle stopped at lights shows it, and so does a camera that
froze or a scanner that delivered its last scan again while the robot went on. From the
first such frame on, a filter runs a *twin* (a copy of itself) that advances on the frames
that are not repeats only, beside itself, which moves on through them; each reading is
weighed by its evidence frame by frame (Bayes' rule over the two readings of the whole
query, from the prior ``repeat_prior``), the answer is their mixture, and once keeping one
reading moves that mixture by no more than what the filter can tell (the grid filter:
round-off, :attr:`TwinReadings.TWIN_AGREEMENT`; the particle filter: one particle's share of
its cloud) the heavier one goes on alone until the next repeat. The grid filter
(:class:`catgraph.grid.GridLocalizer`) and the particle filter
(:class:`catgraph.localizer.Localizer`) share this class; each says when its two readings
agree (``_agrees``). The design and its measurements: ``docs/particle_filter.md``, "Frames
that come again".
"""

from __future__ import annotations

import copy
import math

import numpy as np


def logistic(x: float) -> float:
    """``1 / (1 + e^{−x})`` without overflow (``±inf`` give 1 and 0)."""
    return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))


def prior_log_odds(q: float) -> float:
    """``log(q / (1 − q))``: the odds that the query stands still through its repeats, from
    the prior ``q`` (``±inf`` at 1 and 0)."""
    q = float(q)
    return math.log(q) - math.log1p(-q) if 0.0 < q < 1.0 else (math.inf if q == 1.0 else -math.inf)


def mixed_answer(w_held: float, own_posterior: np.ndarray, own_p_new: float, twin_posterior: np.ndarray,
                 twin_p_new: float) -> tuple[np.ndarray, float, np.ndarray, int, float, float]:
    """The two readings' mixture, the twin's at weight ``w_held``: ``(place posterior, P(new),
    place masses given the map, best place, log P(map), log P(new))``."""
    posterior = w_held * twin_posterior + (1.0 - w_held) * own_posterior
    p_new = w_held * twin_p_new + (1.0 - w_held) * own_p_new
    mass = posterior / (1.0 - p_new) if p_new < 1.0 else posterior
    log_new = math.log(p_new) if p_new > 0.0 else -math.inf
    return posterior, p_new, mass, int(np.argmax(mass)), math.log1p(-p_new), log_new


class TwinReadings:
    """The twin of a filter that takes frames that come again (``repeat_prior``).

    The filter calls :meth:`_reset_twin` when it starts, :meth:`_repeated` with each frame,
    :meth:`_fork` at the first repeat while no twin lives, :meth:`_weigh_twin` after both
    readings took a frame that is not a repeat, answers with :func:`mixed_answer` while a
    twin lives, and calls :meth:`_settle` after that answer. It sets ``frame_log_evidence_``
    (the latest frame's log evidence) and ``repeat_prior``; it defines ``_agrees``.
    """

    #: The two readings become one once that moves the answer's posterior by at most this:
    #: the lighter reading's weight in the mixture times the total variation distance
    #: between the two posteriors (over everything the filter holds, and ``P(new)``).
    TWIN_AGREEMENT = 1e-12

    #: What the filter keeps of its own when it takes the twin's reading (:meth:`_settle`):
    #: the repeats it watches for, the odds of the two readings, its frame count and the
    #: frame's answer (the mixture's posterior).
    _OWN_WHEN_SETTLED: tuple[str, ...] = ("repeat_prior", "_last_row", "repeat_log_odds_", "n_steps_",
                                          "place_posterior_")

    #: Attributes the twin shares with the filter instead of copying (read only after
    #: ``reset``); the model and the graph are always shared.
    _FORK_SHARED: tuple[str, ...] = ()

    def _reset_twin(self) -> None:
        self._last_row = None  # the previous frame's row (repeat_prior > 0)
        self._twin = None  # from the first repeat on: the filter of a query that stood still through its repeats
        # log-odds of "the query stood still through its repeats" against "it moved on"
        self.repeat_log_odds_ = prior_log_odds(self.repeat_prior)
        self.frame_log_evidence_ = 0.0

    def _repeated(self, row: np.ndarray, odometry: float | None) -> bool:
        """Whether this frame repeats the previous one (``repeat_prior``; the same row and
        no odometry, which would tell whether the robot moved)."""
        if not self.repeat_prior > 0.0:
            return False
        if odometry is not None:
            self._last_row = None
            return False
        last = self._last_row
        if last is None:
            self._last_row = np.array(row, dtype=np.float64)
            return False
        if row[0] == last[0] and row[-1] == last[-1] and np.array_equal(row, last):
            return True
        np.copyto(last, row)
        return False

    def _fork(self):
        """The filter of a query that stands still through its repeats: a copy of this one
        now (its posterior the robot where the run began), sharing the observation model
        and the graph; it advances on the frames that are not repeats only."""
        memo = {id(self.model): self.model, id(self.graph): self.graph}
        for name in (*self._FORK_SHARED, "_last_row"):
            value = self.__dict__.get(name)
            if value is not None:
                memo[id(value)] = value
        twin = copy.deepcopy(self, memo)
        twin._twin, twin._last_row = None, None
        twin.repeat_prior = 0.0
        return twin

    def _weigh_twin(self, twin) -> None:
        """Bayes' rule over the two readings, after both took the same frame."""
        change = twin.frame_log_evidence_ - self.frame_log_evidence_
        if math.isfinite(change):
            self.repeat_log_odds_ += change

    def _settle(self, twin) -> None:
        """Keep one reading where the mixture is it to within :data:`TWIN_AGREEMENT`: the
        filter drops the twin, or, where the twin's reading outweighs its own, takes the
        twin's state (and what it learned) as its own. Either way the twin is forked anew
        at the next repeat, the odds of the two readings kept."""
        w_held, w_own = logistic(self.repeat_log_odds_), logistic(-self.repeat_log_odds_)
        if not self._agrees(twin, min(w_held, w_own)):
            return
        self._twin = None
        if w_held > w_own:
            own = {name: self.__dict__[name] for name in self._OWN_WHEN_SETTLED}
            self.__dict__.update(twin.__dict__)  # the twin's own twin is None: none is kept
            self.__dict__.update(own)

    def _agrees(self, twin, weight: float) -> bool:  # pragma: no cover - each filter defines it
        raise NotImplementedError
