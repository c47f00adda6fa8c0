"""Values the models hand on instead of recomputing them are the values recomputed.

The online hub levels ``total / count`` and their mean are formed by the feedback while
the frame is added to the running total (one pass), and read by the next frame's hub
statistic instead of dividing again: checked against the recomputed values, frame by
frame, bit for bit.
"""

import numpy as np
import pytest

from catgraph.observation import FilterFeedback, TemperedObservation


def _rows(rng, n_frames, n_places, hubs=True):
    rows = rng.standard_normal((n_frames, n_places))
    if hubs:
        rows[:, 40:48] -= 2.5  # places that look like every frame
    return rows


@pytest.mark.parametrize("prepare", [False, True])
@pytest.mark.parametrize("n_places", [300, 4099])
def test_levels_formed_by_the_feedback_are_the_divided_levels(n_places, prepare):
    """``prepare``: the next levels formed ahead of the feedback (as on the combined
    model's second thread), the feedback swapping them in."""
    rng = np.random.default_rng(n_places)
    fast, slow = TemperedObservation(), TemperedObservation()
    for k, row in enumerate(_rows(rng, 30, n_places)):
        slow.__dict__.pop("_level_ready", None)  # the levels divided again, their mean by numpy
        a, b = fast.observe(row), slow.observe(row.copy())
        if prepare:
            fast._prepare_levels()
            assert ("_prepared" in fast.__dict__) == (k > 0)
        assert np.array_equal(a.log_ratio, b.log_ratio), k
        assert a.new_place_log_ratio == b.new_place_log_ratio and a.log_ratio_max == b.log_ratio_max
        assert (fast.__dict__.get("n_hubs_"), fast.__dict__.get("hub_shrinkage_")) == (
            slow.__dict__.get("n_hubs_"), slow.__dict__.get("hub_shrinkage_"))
        posterior = np.exp(a.log_ratio - a.log_ratio.max())
        posterior /= posterior.sum()
        best = int(np.argmax(posterior))
        near = slice(max(0, best - 3), best + 4)
        fast.feedback(FilterFeedback(None, posterior, near))
        slow.feedback(FilterFeedback(None, posterior.copy(), near))
        assert np.array_equal(fast._hub_sum, slow._hub_sum) and fast._hub_count == slow._hub_count
        assert fast.temperature_ == slow.temperature_
        if k > 0:
            count, mean = fast._level_ready
            level = fast._hub_sum / fast._hub_count
            assert count == fast._hub_count and np.array_equal(fast._level, level) and mean == level.mean()


def test_levels_prepared_but_not_taken_are_formed_again():
    """The prepared levels are written over the frame's own: a frame whose feedback never
    comes is followed by levels divided from the total again, the values of a model that
    never prepared them."""
    rng = np.random.default_rng(11)
    rows = _rows(rng, 16, 1500)
    fast, slow = TemperedObservation(), TemperedObservation()
    for k, row in enumerate(rows):
        a, b = fast.observe(row), slow.observe(row.copy())
        assert np.array_equal(a.log_ratio, b.log_ratio), k
        assert a.new_place_log_ratio == b.new_place_log_ratio and a.log_ratio_max == b.log_ratio_max
        fast._prepare_levels()
        if k % 3 == 2:  # this frame's feedback does not come
            continue
        posterior = np.full(rows.shape[1], 1.0 / rows.shape[1])
        fast.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        slow.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        assert np.array_equal(fast._hub_sum, slow._hub_sum) and fast._hub_count == slow._hub_count, k


def test_only_the_arrays_read_are_kept():
    """A started model whose single-frame ratios nobody reads (no predictive temperature)
    keeps no array for them, nor for a hub correction formed inside the ratios' pass."""
    rng = np.random.default_rng(4)
    model = TemperedObservation()
    for row in _rows(rng, 6, 700):
        model.observe(row)
        model._prepare_levels()
        model.feedback(FilterFeedback(None, np.full(700, 1.0 / 700), slice(0, 5)))
    assert not {"_base0", "_excess", "_next_level"} & set(model.__dict__)


def test_a_strided_frame_adds_to_the_levels_by_numpy():
    rng = np.random.default_rng(5)
    rows = _rows(rng, 12, 401)
    strided = np.asfortranarray(rows)  # each frame a strided view
    fast, slow = TemperedObservation(), TemperedObservation()
    for k in range(len(rows)):
        a, b = fast.observe(rows[k]), slow.observe(strided[k])
        assert np.array_equal(a.log_ratio, b.log_ratio), k
        posterior = np.full(rows.shape[1], 1.0 / rows.shape[1])
        fast.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        slow.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        assert "_level_ready" not in slow.__dict__ or slow._level_ready[0] != slow._hub_count or k == 0


@pytest.mark.parametrize("hub_places", [0, 2, 40])
def test_correction_formed_in_the_ratios_pass_is_the_formed_array(hub_places):
    """The fast path forms ``w · (level − mean)`` inside the ratios' pass; a model made to
    form the array first (as before) gives the same ratios, hub statistics and best place."""
    rng = np.random.default_rng(hub_places)
    n_places = 2000
    rows = rng.standard_normal((25, n_places))
    rows[:, 100:100 + hub_places] -= 4.0  # a few chance hubs only, a few more, two percent (w = 1)
    fast, slow = TemperedObservation(), TemperedObservation()
    slow._hub = lambda formed=True: TemperedObservation._hub(slow, True)
    for k, row in enumerate(rows):
        a, b = fast.observe(row), slow.observe(row)
        assert np.array_equal(a.log_ratio, b.log_ratio), k
        assert a.new_place_log_ratio == b.new_place_log_ratio
        assert fast.__dict__.get("hub_shrinkage_") == slow.__dict__.get("hub_shrinkage_")
        assert fast.__dict__.get("n_hubs_") == slow.__dict__.get("n_hubs_") and fast._best == slow._best
        posterior = np.full(n_places, 1.0 / n_places)
        fast.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        slow.feedback(FilterFeedback(None, posterior, slice(0, 5)))
        assert fast.temperature_ == slow.temperature_
    assert (fast.hub_shrinkage_ == 1.0) == (hub_places == 40)  # a factor applied (w < 1) and not (w = 1)


def test_standardised_scores_that_are_not_finite_are_refused_as_before():
    """The sequence part's fused pass does not store ``z``; where a ``z`` is not finite
    it forms them and hands them to ``observe``, which refuses them (as before)."""
    from catgraph.exceptions import CatgraphError

    model = TemperedObservation(hub=None, novelty=False, jump_evidence=False, temperature_scale=4.0)
    model._new_place = False
    scores = np.random.default_rng(3).standard_normal(50)
    model.observe(-scores)  # started
    assert model._takes_standardised(scores)
    r, top = model._observe_standardised(scores, float(scores.mean()), float(scores.std()), 0.5)
    assert np.array_equal(r, model.observe((scores - scores.mean()) / scores.std()).log_ratio * 0.5)
    bad = scores.copy()
    bad[7] = np.inf
    with pytest.raises(CatgraphError):
        model._observe_standardised(bad, float(scores.mean()), float(scores.std()), 0.5)


def _combined_run(n_places, rows, mode="grid"):
    from catgraph.graph import PlaceGraph
    from catgraph.methods import make_filter, observation_model, resolve_params

    extra = {"n_particles": 300, "seed": 0} if mode == "particles" else {}
    p = resolve_params("filter", {"model": "combined", "mode": mode, **extra})
    loc = make_filter(p, PlaceGraph.chain(n_places), observation_model(p, n_places, None))
    loc.reset()
    out = []
    for row in rows:
        e = loc.step(row)
        out.append((e.place, e.confidence, e.new_place_probability, e.score, loc.place_posterior_.tobytes()))
    return out


@pytest.mark.parametrize("mode", ["grid", "particles"])
def test_parts_observed_on_two_threads_are_the_parts_observed_in_turn(monkeypatch, mode):
    import catgraph.grid
    import catgraph.observation as observation

    rng = np.random.default_rng(21)
    n_places = 1500
    rows = _rows(rng, 40, n_places)
    rows[np.arange(40), np.arange(300, 340)] -= 3.0
    in_turn = _combined_run(n_places, rows, mode)
    threads = []
    monkeypatch.setattr(observation, "PARALLEL_PARTS_PLACES", 1)
    monkeypatch.setattr(catgraph.grid, "_free_cores", lambda cores: 2)
    observe = TemperedObservation.observe

    def observe_noting_thread(self, row):
        import threading

        threads.append(threading.current_thread().name)
        return observe(self, row)

    monkeypatch.setattr(TemperedObservation, "observe", observe_noting_thread)
    assert _combined_run(n_places, rows, mode) == in_turn
    assert any(name.startswith("catgraph-parts") for name in threads)  # the first part did run on the second thread


def test_an_error_of_the_part_on_the_second_thread_reaches_the_caller(monkeypatch):
    import catgraph.grid
    import catgraph.observation as observation
    from catgraph.observation import CombinedObservation, SequenceObservation

    monkeypatch.setattr(observation, "PARALLEL_PARTS_PLACES", 1)
    monkeypatch.setattr(catgraph.grid, "_free_cores", lambda cores: 2)
    model = CombinedObservation([TemperedObservation(), SequenceObservation()])
    model.observe(np.random.default_rng(0).standard_normal(50))

    def broken(row):
        raise ValueError("the first part failed")

    model.models[0].observe = broken
    with pytest.raises(ValueError, match="first part failed"):
        model.observe(np.random.default_rng(1).standard_normal(50))
