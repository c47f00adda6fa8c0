"""Tests for catgraph._window_rule: the decision layer against slow, obviously correct loops.

The kernels' statistics are tested in test_sequence.py; here the window rules are
recomputed per frame from double-loop window scores and compared with the matcher's
choices, in the batch and the streaming form.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import log_ndtr, ndtr

from catgraph._window_rule import EVIDENT_SPREADS, JUMP_ODDS, RIVAL_FRACTION, RIVAL_MARGIN, RIVAL_SPREADS, _on_line
from catgraph.sequence import SequenceMatcher, match_sequences, window_grid

V1 = (1.0,)


def on_grid(d: np.ndarray) -> np.ndarray:
    """Values the matcher sums exactly (multiples of 2**-10, each row's mean an exact
    multiple too), so that its scores equal the float64 loops below to rounding."""
    q = np.rint(np.asarray(d, dtype=np.float64) * 1024.0)
    q[:, -1] -= np.mod(q.sum(axis=1), q.shape[1])
    return q / 1024.0


def slow_scores(d: np.ndarray, length: int) -> np.ndarray:
    """s_ij(L) along the forward diagonal by a double loop (``min(L, i + 1)`` terms; a
    term before the reference's start is its query row's mean)."""
    n_q, n = d.shape
    out = np.empty((n_q, n))
    for i in range(n_q):
        eff = min(length, i + 1)
        for j in range(n):
            out[i, j] = sum(d[i - k, j - k] if j - k >= 0 else d[i - k].mean() for k in range(eff)) / eff
    return out


def slow_choice(d: np.ndarray, grid: np.ndarray, rule: str, fraction: float = 0.0, radius: int = 10,
                with_confidence: bool = False):
    """Per frame: the admitted windows of ``rule`` and the most significant of them (and,
    on request, the confidence "posterior": the gaps of the admitted windows agreeing with
    the match, times the posterior that the current frame lies on the chosen line)."""
    scores = {int(L): slow_scores(d, int(L)) for L in grid}
    match = np.empty(d.shape[0], dtype=int)
    length = np.empty(d.shape[0], dtype=int)
    confidence = np.empty(d.shape[0])
    for i in range(d.shape[0]):
        rows = [scores[int(L)][i] for L in grid]
        best_j = [int(np.argmin(r)) for r in rows]
        log_p = [float(log_ndtr((r.min() - r.mean()) / r.std())) for r in rows]
        admitted = []
        for g in range(len(grid)):
            ok = True
            for h in range(g):  # every shorter length
                sub, own = rows[h][best_j[g]], rows[g][best_j[g]]
                if grid[h] >= fraction * grid[g] and sub > 0.5 * (own + rows[h].mean()):
                    ok = False
                if rule in ("evident", "unrivalled") and sub > rows[h].mean() - EVIDENT_SPREADS * rows[h].std():
                    ok = False
                rival = log_p[h] < -np.log(d.shape[1]) - RIVAL_MARGIN
                if (rule == "unrivalled" and grid[h] >= RIVAL_FRACTION * grid[g] and rival
                        and sub > rows[h].min() + RIVAL_SPREADS * rows[h].std()):
                    ok = False
            if ok or g == 0:
                admitted.append(g)
        g = min(admitted, key=lambda k: (log_p[k], k))
        match[i] = best_j[g]
        length[i] = min(int(grid[g]), i + 1)
        support = 0.0
        for k in admitted:
            if abs(best_j[k] - match[i]) <= radius:
                far = np.abs(np.arange(d.shape[1]) - best_j[k]) > radius
                support += (rows[k][far].min() - rows[k].min()) / rows[k].std()
        z = (d[i, match[i]] - d[i].mean()) / d[i].std()
        mu = (rows[g][match[i]] - d[i].mean()) / d[i].std()
        log_ratio = np.log(np.exp(-0.5 * (z - mu) ** 2) / np.exp(-0.5 * z ** 2))  # on the line vs a random place
        confidence[i] = support / (1.0 + JUMP_ODDS * np.exp(-log_ratio))
    return (match, length, confidence) if with_confidence else (match, length)


def planted(n_q: int, n_ref: int, seed: int, jump_at: int | None = None, strength: float = 1.2,
            echo: float = 0.0) -> np.ndarray:
    """Noise with a diagonal of lower differences (a jump to another place at ``jump_at``;
    after it the old diagonal keeps ``echo`` of the similarity, like repeated scenery)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n_ref))
    truth = np.arange(n_q) + 5
    if jump_at is not None:
        truth[jump_at:] = np.arange(n_q - jump_at) + n_ref // 2
        old = np.arange(jump_at, n_q) + 5
        d[np.arange(jump_at, n_q), old % n_ref] -= echo
    d[np.arange(n_q), truth % n_ref] -= strength
    return on_grid(d)


@pytest.mark.parametrize("rule, fraction, seed, strength", [
    ("evident", 0.0, 0, 1.2), ("evident", 0.3, 1, 1.2), ("evident", 0.05, 2, 1.2), ("consistent", 0.0, 0, 1.2),
    ("consistent", 0.3, 1, 1.2), ("unrivalled", 0.05, 0, 1.2), ("unrivalled", 0.05, 3, 3.0),
    ("unrivalled", 0.0, 4, 3.0), ("unrivalled", 0.3, 5, 2.5)])
def test_rule_matches_slow_reference(rule, fraction, seed, strength):
    d = planted(36, 40, seed, jump_at=20, strength=strength, echo=0.6 * strength)
    grid = window_grid(3, 24, 7)
    result = match_sequences(d, "adaptive", rule=rule, grid=7, l_min=3, l_max=24, velocities=V1,
                             recent_fraction=fraction)
    match, length = slow_choice(d, grid, rule, fraction)
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_array_equal(result.window_length, length)


def test_evident_rule_differs_from_consistent_somewhere():
    """The extra test must bite on noisy data (else the comparison above proves nothing)."""
    d = planted(36, 40, 3, jump_at=20)
    grid = window_grid(3, 24, 7)
    evident, _ = slow_choice(d, grid, "evident")
    consistent, _ = slow_choice(d, grid, "consistent")
    assert np.any(evident != consistent)


def test_unrivalled_rule_differs_from_evident_somewhere():
    """The rival test must bite where the old line keeps an echo of the similarity."""
    grid = window_grid(3, 24, 7)
    differs = 0
    for seed in (3, 4, 5):
        d = planted(36, 40, seed, jump_at=20, strength=3.0, echo=1.8)
        differs += int(np.sum(slow_choice(d, grid, "unrivalled")[0] != slow_choice(d, grid, "evident")[0]))
    assert differs > 0


@pytest.mark.parametrize("rule, fraction, seed, strength, radius", [
    ("unrivalled", 0.05, 0, 1.2, 3), ("unrivalled", 0.05, 3, 3.0, 5), ("evident", 0.0, 1, 2.0, 2),
    ("consistent", 0.3, 2, 1.5, 4)])
def test_posterior_confidence_matches_slow_reference(rule, fraction, seed, strength, radius):
    d = planted(36, 40, seed, jump_at=20, strength=strength, echo=0.6 * strength)
    grid = window_grid(3, 24, 7)
    result = match_sequences(d, "adaptive", rule=rule, grid=7, l_min=3, l_max=24, velocities=V1,
                             recent_fraction=fraction, radius=radius, confidence="posterior")
    match, length, confidence = slow_choice(d, grid, rule, fraction, radius, with_confidence=True)
    np.testing.assert_array_equal(result.match, match)
    np.testing.assert_allclose(result.confidence, confidence, rtol=1e-9, atol=1e-12)


def test_on_line_posterior_follows_the_likelihood_ratio():
    z = np.linspace(-4.0, 3.0, 15)
    # single frames that say nothing (the line no better than a random place): the prior
    np.testing.assert_allclose(_on_line(z, np.zeros_like(z)), 1.0 / (1.0 + JUMP_ODDS), rtol=1e-12)
    # a distinctive line: a current frame like a random place is a likely jump, far below
    # what Phi(-z) gives it; a frame at the line's own mean is on the line
    mu = np.full_like(z, -3.0)
    p = _on_line(z, mu)
    at_random = np.argmin(np.abs(z))  # z = 0
    assert p[at_random] < 0.05 and ndtr(-z[at_random]) == pytest.approx(0.5)
    assert p[np.argmin(np.abs(z - mu))] > 0.98
    assert np.all(np.diff(p) < 0)  # the worse the current frame, the less likely on the line


@pytest.mark.parametrize("confidence", ["posterior", "support"])
@pytest.mark.parametrize("rule", ["evident", "unrivalled"])
def test_evident_streaming_equals_batch(rule, confidence):
    d = planted(60, 50, 4, jump_at=30, strength=2.5, echo=1.5)
    kwargs = dict(rule=rule, l_min=3, l_max=30, grid=6, confidence=confidence)
    batch = match_sequences(d, **kwargs)
    matcher = SequenceMatcher(**kwargs)
    steps = [matcher.step(row) for row in d]
    np.testing.assert_array_equal(batch.match, [s.match for s in steps])
    np.testing.assert_array_equal(batch.window_length, [s.window_length for s in steps])
    np.testing.assert_allclose(batch.confidence, [s.confidence for s in steps], rtol=1e-12, atol=0)


def test_evident_rule_drops_the_old_alignment_after_a_jump(jump_route):
    """After a jump to another part of the route the rule finds the new alignment within
    a few frames, where the literal rule holds on to the old one for dozens."""
    d, truth = jump_route  # a jump at frame 100
    common = dict(window="adaptive", l_min=5, l_max=100, grid=16, velocities=V1)
    evident = match_sequences(d, rule="evident", **common)
    literal = match_sequences(d, rule="literal", **common)
    after = slice(100, 200)

    def first_correct(res):
        return int(np.flatnonzero(res.match[after] == truth[after])[0])

    assert first_correct(evident) <= 10 < first_correct(literal)
    assert np.mean(evident.match[after] == truth[after]) >= 0.85
    assert np.mean(evident.match[:100] == truth[:100]) >= 0.85
