"""Jump evidence from the change between frames (catgraph.jumps), and the filters that read it."""

import math

import numpy as np
import pytest

from catgraph.exceptions import InvalidParameterError
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.jumps import JUMP_RATE_CAP, JumpEvidence, frame_jump_rate
from catgraph.observation import CombinedObservation, TemperedObservation


def _reference_evidence(rows: np.ndarray, n_bins: int, apart: int, memory: float, prior: float) -> np.ndarray:
    """Each frame's evidence recomputed from every earlier sample, weighted by its age:
    the histograms written out from the module docstring's definition."""
    decay = 0.5 ** (1.0 / memory)

    def corr(a, b):
        a, b = a - a.mean(), b - b.mean()
        return float(a @ b) / math.sqrt(float(a @ a) * float(b @ b))

    def bin_of(s):
        return min(max(int(s * 0.5 * n_bins), 0), n_bins - 1)

    step_samples, jump_samples = [], []  # (counted frame at which it entered, bin)
    out = np.zeros(len(rows))
    kept, age, counted = None, 0, 0
    for k in range(1, len(rows)):
        s = 1.0 - corr(rows[k], rows[k - 1])
        if s <= 1e-9:
            continue  # a repeat: no measurement
        hist = []
        for samples in (step_samples, jump_samples):
            h = np.full(n_bins, prior / n_bins) * decay ** counted
            for t, b in samples:
                h[b] += decay ** (counted - 1 - t)
            hist.append(h / h.sum())
        b = bin_of(s)
        out[k] = max(0.0, math.log(hist[1][b]) - math.log(hist[0][b]))
        step_samples.append((counted, b))
        age += 1
        if kept is not None and age >= apart:
            jump_samples.append((counted, bin_of(1.0 - corr(rows[k], kept))))
        if kept is None or age >= 2 * apart:
            kept, age = rows[k].copy(), 0
        counted += 1
    return out


def _bump_rows(places: np.ndarray, n: int, rng, width: float = 4.0, noise: float = 0.3) -> np.ndarray:
    """Rows low around each frame's place (a smooth bump): consecutive frames of a route
    correlate, frames of distant places do not."""
    j = np.arange(n)
    rows = -np.exp(-0.5 * ((j[None, :] - places[:, None]) / width) ** 2) + noise * rng.standard_normal((len(places), n))
    return (rows - rows.mean(1, keepdims=True)) / rows.std(1, keepdims=True)


def _jumping_places(n: int, rng, segments: int = 12, length: int = 25) -> tuple[np.ndarray, np.ndarray]:
    starts = rng.integers(10, n - length - 10, size=segments)
    places = np.concatenate([s + np.arange(length) for s in starts])
    jumps = np.zeros(len(places), dtype=bool)
    jumps[length::length] = True
    return places, jumps


def _jumping_rows(seed: int, n: int, noise: float = 0.3, **segments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(places, jumps, rows)`` of a query jumping between stretches of an ``n``-place route."""
    rng = np.random.default_rng(seed)
    places, jumps = _jumping_places(n, rng, **segments)
    return places, jumps, _bump_rows(places, n, rng, noise=noise)


def test_frame_jump_rate_is_bayes_rule_on_the_odds():
    assert frame_jump_rate(0.01, 0.0) == 0.01
    rates = [frame_jump_rate(0.01, e) for e in np.linspace(0.0, 3.0, 7)]
    assert all(a < b for a, b in zip(rates, rates[1:]))  # more evidence, a higher rate
    lam = 4.0
    assert frame_jump_rate(0.01, math.log(lam)) == pytest.approx(0.01 * lam / (0.01 * lam + 0.99), rel=1e-12)
    assert frame_jump_rate(0.01, 50.0) == JUMP_RATE_CAP  # never more than half the mass
    assert frame_jump_rate(0.8, 5.0) == 0.8  # a larger prior rate is kept, not cut to the cap
    arr = frame_jump_rate(np.array([0.01, 1e-12]), math.log(3.0))
    np.testing.assert_allclose(arr, [0.03 / 1.02, 3e-12 / (3e-12 + 1 - 1e-12)], rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_evidence_matches_the_histograms_written_out(seed):
    rng = np.random.default_rng(seed)
    n = 120
    places, _ = _jumping_places(n, rng, segments=8, length=20)
    rows = _bump_rows(places, n, rng)
    rows[30] = rows[29]  # a repeat: no measurement
    je = JumpEvidence(n_bins=10, apart=7, memory=40.0, prior_frames=3.0).reset()
    got = np.zeros(len(rows))
    for k in range(1, len(rows)):
        a, b = rows[k] - rows[k].mean(), rows[k - 1] - rows[k - 1].mean()
        s = 1.0 - float(a @ b) / math.sqrt(float(a @ a) * float(b @ b))
        if s > 1e-9:
            got[k] = je.observe(s, a, float(a @ a))
    want = _reference_evidence(rows, 10, 7, 40.0, 3.0)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert got[30] == 0.0 and np.all(got >= 0.0)


def test_evidence_is_zero_until_both_kinds_of_change_are_seen_and_then_finds_the_jumps():
    places, jumps, rows = _jumping_rows(3, 400, segments=16, length=30)
    model = TemperedObservation()
    evidence = np.array([model.observe(r).jump_evidence for r in rows])
    assert np.all(evidence[:2] == 0.0)  # the first frames: the histograms are still even
    late = np.arange(len(rows)) >= 150
    assert np.median(evidence[jumps & late]) > 1.0
    assert np.median(evidence[~jumps & late]) == 0.0


def test_no_jump_evidence_where_switched_off_or_nothing_changes():
    rows = _jumping_rows(4, 200)[2]
    off = TemperedObservation(jump_evidence=False)
    assert all(off.observe(r).jump_evidence == 0.0 for r in rows)
    on, plain = TemperedObservation(), TemperedObservation(jump_evidence=False)
    for r in rows:  # the ratios themselves do not depend on it
        a, b = on.observe(r), plain.observe(r)
        np.testing.assert_array_equal(a.log_ratio, b.log_ratio)
    repeated = TemperedObservation()
    assert all(repeated.observe(rows[0]).jump_evidence == 0.0 for _ in range(5))
    with pytest.raises(InvalidParameterError, match="jump_evidence"):
        TemperedObservation(jump_evidence="yes").observe(rows[0])
    with pytest.raises(InvalidParameterError, match="apart"):
        JumpEvidence(apart=0).reset()


def test_combined_model_hands_on_the_whole_image_models_evidence():
    rows = _jumping_rows(5, 300, segments=10, length=30)[2]
    alone = TemperedObservation()
    combined = CombinedObservation([TemperedObservation(), TemperedObservation(jump_evidence=False)], reliability=None)
    for r in rows:
        assert combined.observe(r).jump_evidence == alone.observe(r).jump_evidence


def _frames_to_relocalise(places, jumps, answers, tolerance=2) -> np.ndarray:
    starts = np.flatnonzero(jumps)
    ends = list(starts[1:]) + [len(places)]
    out = []
    for a, b in zip(starts, ends):
        ok = np.abs(answers[a:b] - places[a:b]) <= tolerance
        out.append(int(np.argmax(ok)) if ok.any() else b - a)
    return np.array(out)


def test_the_grid_filter_follows_a_jump_sooner_with_the_evidence():
    n = 500
    places, jumps, rows = _jumping_rows(8, n, noise=1.2, segments=24, length=30)
    lags = []
    for evidence in (False, True):
        loc = GridLocalizer(PlaceGraph.chain(n), TemperedObservation(jump_evidence=evidence))
        res = loc.run(rows)
        lags.append(_frames_to_relocalise(places, jumps, res.place)[8:])  # after the histograms have filled
    assert lags[1].mean() < lags[0].mean()
    assert np.median(lags[1]) <= np.median(lags[0])
