"""The combined model reads the adaptive matcher's window scores, never its confidence.

``filter + combined`` (:func:`catgraph.methods.observation_model`, ``model="combined"``)
feeds the grid filter the matcher's scores along the lines of its chosen window and
velocity. The matcher's confidence (how it ranks its own answers) is a separate output:
a change of the sequence method's confidence must leave the combined model, and so the
filter's answers and scores, exactly as they are. Checked by running the model with every
confidence the matcher offers and comparing the ratios bit for bit, while the matcher's
own confidences do differ between the runs (so the comparison could fail)."""

from __future__ import annotations

import numpy as np
import pytest

from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.observation import CombinedObservation, SequenceObservation, TemperedObservation
from catgraph.sequence import CONFIDENCES as ALL_CONFIDENCES

#: every confidence the default rule reads ("tracked" is rule "tracked"'s own, refused with any other)
CONFIDENCES = tuple(c for c in ALL_CONFIDENCES if c != "tracked")


def _rows(n_frames: int, n_places: int, seed: int) -> np.ndarray:
    """A query along the route that jumps once half-way (the window grows, shrinks, grows)."""
    rng = np.random.default_rng(seed)
    truth = np.concatenate([np.arange(5, 5 + n_frames // 2), np.arange(150, 150 + n_frames - n_frames // 2)])
    d = rng.normal(size=(n_frames, n_places))
    d[np.arange(n_frames), truth] -= 2.0
    return (d - d.mean(1, keepdims=True)) / d.std(1, keepdims=True)


def _combined(confidence: str | None) -> CombinedObservation:
    """The registry's combined model (its sequence part's settings), the matcher's confidence set."""
    matcher = {"l_min": 2, "l_max": 40}
    if confidence is not None:
        matcher["confidence"] = confidence
    part = SequenceObservation(window="adaptive", matcher_params=matcher, calibration="agreement",
                               temperature="longest", agreement_scale=1.0)
    return CombinedObservation([TemperedObservation(), part], reliability=None)


def test_the_sequence_part_never_reads_the_matchers_confidence():
    d = _rows(90, 260, 3)
    models = {c: _combined(c) for c in (None, *CONFIDENCES)}
    confidences = {c: [] for c in models}
    for row in d:
        ratios, new = {}, {}
        for c, m in models.items():
            obs = m.observe(row)
            ratios[c], new[c] = np.array(obs.log_ratio), obs.new_place_log_ratio
            confidences[c].append(m.models[1].last_match_.confidence)
        for c in CONFIDENCES:
            np.testing.assert_array_equal(ratios[c], ratios[None])
            assert new[c] == new[None]
    # the matcher's own confidences differ between the settings: the comparison could fail
    distinct = {tuple(np.round(v, 12)) for v in confidences.values()}
    assert len(distinct) >= 3


def test_the_filters_answers_do_not_depend_on_the_matchers_confidence():
    d = _rows(80, 200, 5)
    graph = PlaceGraph.chain(200)
    runs = [GridLocalizer(graph, _combined(c)).run(d) for c in (None, "gap", "z")]
    for r in runs[1:]:
        np.testing.assert_array_equal(r.place, runs[0].place)
        np.testing.assert_array_equal(r.score, runs[0].score)


def test_the_sequence_part_asks_its_matcher_for_the_unread_confidence():
    """Unless ``matcher_params`` name one, the part's matcher forms the cheapest confidence
    (which keeps no rows), not the matcher's own default; a confidence or rule given is kept."""
    from catgraph.observation import UNREAD_CONFIDENCE
    from catgraph.sequence import DEFAULT_CONFIDENCE

    assert UNREAD_CONFIDENCE != DEFAULT_CONFIDENCE  # else the check below could not fail
    row = _rows(4, 200, 1)[0]
    plain = SequenceObservation(matcher_params={"l_min": 2, "l_max": 20})
    plain.observe(row)
    assert plain.matcher_.confidence == UNREAD_CONFIDENCE
    assert plain.matcher_._cfg.confidence == UNREAD_CONFIDENCE
    named = SequenceObservation(matcher_params={"l_min": 2, "l_max": 20, "confidence": "gap"})
    named.observe(row)
    assert named.matcher_._cfg.confidence == "gap"
    tracked = SequenceObservation(matcher_params={"l_min": 2, "l_max": 20, "rule": "tracked"})
    tracked.observe(row)  # the rule's own confidence: no other is forced on it
    assert tracked.matcher_._cfg.confidence == "tracked"
