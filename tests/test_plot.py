"""Plot functions: small arrays in, the expected artists out; no pyplot, no eager import."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from catgraph import plot
from catgraph.exceptions import DataError, InvalidParameterError, ShapeMismatchError
from catgraph.metrics import auc, evaluate
from catgraph.results import RunResult
from catgraph.traverse import FrameTolerance


def make_payload(rng, n=60, n_reference=50, name="run", noise=0.3, extra=None) -> dict:
    """A real result payload: frames 0..n-1, the last n - n_reference without a true match."""
    q = np.arange(n)
    good = rng.random(n) > noise
    match = np.where(good, np.minimum(q, n_reference - 1), rng.integers(0, n_reference, n))
    match[rng.random(n) < 0.1] = -1
    confidence = rng.random(n) + good
    result = RunResult(name, {"window": 3}, q, match, confidence, extra=extra or {})
    return result.to_dict(result.evaluate(FrameTolerance(n_reference, tolerance=1)))


def area_under_line(line) -> float:
    x, y = line.get_xdata(), line.get_ydata()
    return float(np.sum(np.diff(x) * (y[1:] + y[:-1]) / 2.0))


def test_import_catgraph_does_not_import_matplotlib():
    code = ("import sys, catgraph, catgraph.plot, catgraph.report, catgraph.cli.main; "
            "catgraph.cli.main.build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_plots_use_no_pyplot_state():
    code = ("import sys, numpy as np, io; from catgraph import plot; "
            "ax = plot.plot_pr_curves([(np.array([.5, 1.]), np.array([1., .5]))]); "
            "ax.figure.savefig(io.BytesIO(), format='png'); "
            "print('matplotlib.pyplot' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_pr_curves_one_line_per_method_and_area_is_the_reported_auc():
    rng = np.random.default_rng(0)
    payloads = [make_payload(rng, name=f"m{k}", noise=0.2 * k) for k in range(3)]
    ax = plot.plot_pr_curves(payloads)
    assert len(ax.lines) == 3
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["m0", "m1", "m2"]
    for line, payload in zip(ax.lines, payloads):
        assert area_under_line(line) == pytest.approx(payload["metrics"]["auc"], abs=1e-12)


def test_pr_curve_from_result_matches_evaluate_with_frames_lacking_a_true_match():
    rng = np.random.default_rng(1)
    n, n_reference = 80, 50
    q = np.arange(n)
    match = np.minimum(q, n_reference - 1)
    match[::7] = 3
    conf = rng.random(n)
    ev = evaluate(q, match, conf, FrameTolerance(n_reference, 0))
    payload = RunResult("m", {}, q, match, conf).to_dict(ev)
    recall, precision = plot.pr_curve_from_result(payload)
    np.testing.assert_allclose(recall, ev.curve.recall)
    np.testing.assert_allclose(precision, ev.curve.precision)
    # an explicit has_true_match field wins over the recovery from the accuracy
    payload["frames"]["has_true_match"] = [True] * n
    recall_all, _ = plot.pr_curve_from_result(payload)
    np.testing.assert_allclose(recall_all, ev.curve.recall * ev.has_true_match.sum() / n)


def test_pr_curves_accept_arrays_and_prcurve_and_reuse_ax():
    rng = np.random.default_rng(2)
    ev = evaluate(np.arange(20), np.arange(20), rng.random(20), FrameTolerance(20, 0))
    ax = plot.new_axes()
    same = plot.plot_pr_curves([ev.curve, (np.array([0.5, 1.0]), np.array([1.0, 0.5]))], labels=["a", "b"], ax=ax)
    assert same is ax and len(ax.lines) == 2
    assert area_under_line(ax.lines[0]) == pytest.approx(auc(ev.curve))


def test_pr_curves_errors():
    rng = np.random.default_rng(3)
    payload = make_payload(rng)
    with pytest.raises(ShapeMismatchError, match="labels"):
        plot.plot_pr_curves([payload], labels=["a", "b"])
    unevaluated = dict(payload, frames={k: v for k, v in payload["frames"].items() if k != "correct"})
    with pytest.raises(DataError, match="ground truth"):
        plot.plot_pr_curves([unevaluated])
    with pytest.raises(DataError, match="PR curve"):
        plot.plot_pr_curves([42])


def test_metric_bars_heights_labels_and_missing_values():
    rng = np.random.default_rng(4)
    payloads = [make_payload(rng, name=f"m{k}", noise=0.2 * k) for k in range(4)]
    payloads.append({"method": "unevaluated", "params": {}, "metrics": None, "frames": {}})
    ax = plot.plot_metric_bars(payloads, "mtl")
    assert len(ax.patches) == 5
    heights = [p.get_height() for p in ax.patches]
    assert heights[:4] == [p["metrics"]["mtl"] for p in payloads[:4]] and heights[4] == 0
    assert [t.get_text() for t in ax.get_xticklabels()] == ["m0", "m1", "m2", "m3", "unevaluated"]
    annotations = [t.get_text() for t in ax.texts]
    assert annotations[-1] == "–" and annotations[0] == str(payloads[0]["metrics"]["mtl"])
    ax = plot.plot_metric_bars({"L=10": 0.5, "adaptive": 0.75}, "auc")
    assert [p.get_height() for p in ax.patches] == [0.5, 0.75]


def test_difference_matrix_overlays_truth_and_matches():
    rng = np.random.default_rng(5)
    d = rng.random((30, 20))
    truth = np.r_[np.arange(20), -np.ones(10, dtype=int)]
    match = rng.integers(-1, 20, 30)
    correct = (match == truth) & (match >= 0)
    ax = plot.plot_difference_matrix(d, true_match=truth, match=match, correct=correct, colorbar=False)
    assert len(ax.images) == 1 and ax.images[0].get_array().shape == (20, 30)
    by_label = {c.get_label(): c for c in ax.collections}
    assert len(by_label["ground truth"].get_offsets()) == 20
    assert len(by_label["correct match"].get_offsets()) == correct.sum()
    assert len(by_label["wrong match"].get_offsets()) == ((match >= 0) & ~correct).sum()
    mask = np.zeros((30, 20), bool)
    mask[3, 4] = mask[5, 6] = True
    ax = plot.plot_difference_matrix(d, true_match=mask)
    np.testing.assert_array_equal(ax.collections[0].get_offsets(), [[3, 4], [5, 6]])
    with pytest.raises(ShapeMismatchError):
        plot.plot_difference_matrix(d, match=np.zeros(29, int))
    with pytest.raises(DataError):
        plot.plot_difference_matrix(np.zeros(5))


def test_window_length_and_curves():
    rng = np.random.default_rng(6)
    lengths = [rng.integers(10, 500, 40), rng.integers(10, 500, 35).tolist()]
    ax = plot.plot_window_length(lengths, labels=["gauss", "robust"], log_scale=True)
    assert len(ax.lines) == 2 and ax.get_yscale() == "log"
    np.testing.assert_array_equal(ax.lines[1].get_ydata(), lengths[1])
    single = plot.plot_window_length([10, 20, None, 40])
    assert len(single.lines) == 1 and np.isnan(single.lines[0].get_ydata()[2]) and single.get_legend() is None
    grid = np.array([10, 20, 50, 100, 200, 500])
    log_p = rng.normal(size=(12, 6))
    log_p[0, 3:] = np.inf
    ax = plot.plot_window_curves(grid, log_p, frames=[0, 5])
    curves = [line for line in ax.lines if line.get_label().startswith("frame")]
    assert len(curves) == 2 and len(ax.lines) == 4  # each curve and its minimum
    minimum = ax.lines[3]
    assert minimum.get_xdata()[0] == grid[np.argmin(log_p[5])]
    with pytest.raises(ShapeMismatchError):
        plot.plot_window_curves(grid, log_p[:, :5])
    with pytest.raises(InvalidParameterError):
        plot.plot_window_curves(grid, log_p, frames=[12])


def test_posterior_and_new_place_probability():
    rng = np.random.default_rng(7)
    posterior = rng.dirichlet(np.ones(15), size=25)
    truth = np.r_[np.arange(20) % 15, -np.ones(5)]
    ax = plot.plot_posterior(posterior, estimate=posterior.argmax(1), true_place=truth, log=True)
    assert ax.images[0].get_array().shape == (15, 25)
    assert ax.images[0].get_array().max() <= 0.0  # log10 of probabilities
    by_label = {c.get_label(): c for c in ax.collections}
    assert len(by_label["true place"].get_offsets()) == 20
    np.testing.assert_array_equal(by_label["estimate"].get_offsets()[:, 1], posterior.argmax(1))
    with pytest.raises(ShapeMismatchError):
        plot.plot_posterior(posterior, estimate=np.zeros(3, int))

    is_new = np.zeros(40, bool)
    is_new[5:10] = is_new[30:] = True
    ax = plot.plot_new_place_probability([rng.random(40), rng.random(40)], labels=["a", "b"],
                                         is_new_place=is_new, threshold=0.5)
    assert len(ax.lines) == 3  # two runs and the threshold
    assert len(ax.patches) == 2  # one shaded span per stretch of new places


def test_localisation_timeline_codes():
    ax = plot.plot_localisation_timeline([np.array([True, False, True]), np.array([False, True])], labels=["a", "b"])
    codes = np.asarray(ax.images[0].get_array())
    np.testing.assert_array_equal(codes, [[2, 1, 2], [1, 2, -1]])
    payload = {"method": "m", "frames": {"correct": [True, False, False], "match": [1, None, 3]}}
    codes = np.asarray(plot.plot_localisation_timeline([payload]).images[0].get_array())
    np.testing.assert_array_equal(codes, [[2, 0, 1]])


def test_likelihood_densities_integrate_to_one():
    rng = np.random.default_rng(8)
    edges = np.linspace(-2.0, 3.0, 26)
    same = np.histogram(rng.normal(-1, 0.4, 500), edges)[0]
    different = np.histogram(rng.normal(1, 0.8, 500), edges)[0]
    ax = plot.plot_likelihood(edges, same, different)
    assert len(ax.patches) == 2
    for patch in ax.patches:
        values, patch_edges = patch.get_data()[:2]
        assert np.sum(values * np.diff(patch_edges)) == pytest.approx(1.0)
    counts = plot.plot_likelihood(edges, same, different, normalize=False)
    np.testing.assert_array_equal(counts.patches[0].get_data()[0], same)
    with pytest.raises(ShapeMismatchError):
        plot.plot_likelihood(edges, same[:-1], different)
    with pytest.raises(DataError):
        plot.plot_likelihood(edges[::-1], same, different)


def test_place_graph_edges_nodes_and_highlight():
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    positions = np.c_[np.cos(t), np.sin(t), np.zeros(12)]
    chain = np.c_[np.arange(11), np.arange(1, 12)]
    edges = np.r_[chain, chain[:, ::-1], [[11, 0]]]  # both directions + closing the loop
    ax = plot.plot_place_graph(positions, edges, highlight=[2, 3], place_weights=np.linspace(0, 1, 12),
                               true_position=positions[2])
    from matplotlib.collections import LineCollection

    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(lines) == 1 and len(lines[0].get_segments()) == 12  # each undirected edge once
    by_label = {c.get_label(): c for c in ax.collections}
    np.testing.assert_allclose(by_label["estimate"].get_offsets(), positions[[2, 3], :2])
    np.testing.assert_allclose(by_label["true position"].get_offsets(), positions[[2], :2])
    with pytest.raises(DataError, match="outside"):
        plot.plot_place_graph(positions, [[0, 12]])
    with pytest.raises(DataError, match="highlight"):
        plot.plot_place_graph(positions, edges, highlight=40)


def test_place_graph_from_a_place_graph():
    graph_module = pytest.importorskip("catgraph.graph")
    positions = np.c_[np.arange(6.0), np.zeros(6)]
    graph = graph_module.PlaceGraph.chain(6)
    ax = plot.plot_place_graph(positions, np.column_stack([graph.source, graph.target]), highlight=int(graph.target[0]))
    undirected = np.unique(np.sort(np.c_[graph.source, graph.target], 1), axis=0)
    assert len(ax.collections[0].get_segments()) == len(undirected)


def test_difference_matrix_draws_the_truth_on_top_of_the_matches():
    d = np.random.default_rng(6).random((30, 20))
    truth = np.arange(30) % 20
    ax = plot.plot_difference_matrix(d, true_match=truth, match=truth, correct=np.ones(30, bool), colorbar=False)
    by_label = {c.get_label(): c for c in ax.collections}
    assert by_label["ground truth"].get_zorder() > by_label["correct match"].get_zorder()
    assert ax.collections[-1].get_label() == "ground truth"


def test_localisation_timeline_hatches_the_initialisation_stage():
    rng = np.random.default_rng(7)
    ax = plot.plot_localisation_timeline([rng.random(50) > 0.5, rng.random(50) > 0.5], labels=["a", "b"],
                                         initialisation=[0, 20])
    hatched = [p for p in ax.patches if p.get_hatch()]
    assert len(hatched) == 1 and hatched[0].get_width() == 20 and hatched[0].get_y() == 0.5
    with pytest.raises(ShapeMismatchError):
        plot.plot_localisation_timeline([rng.random(50) > 0.5], initialisation=[1, 2])
