"""The streaming step's row handling: the row checked once, the window rule's reads of the
row formed beside the kernels' other threads, every output as the plain serial order gives."""

import numpy as np
import pytest

from catgraph import _sequence_kernels, sequence
from catgraph._window_rule import _decide, _row_reads
from catgraph.exceptions import DataError
from catgraph.observation import CheckedRow


def _rows(seed=3, n_q=90, n=700):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n))
    start = int(rng.integers(0, n - n_q))
    d[np.arange(n_q), start + np.arange(n_q)] -= 2.0  # a line to find
    return d


def _stream(rows, **kwargs):
    m = sequence.SequenceMatcher(l_max=40, **kwargs)
    out = [m.step(r) for r in rows]
    return [(o.match, o.score, o.confidence, o.window_length, o.velocity) for o in out]


def _serial_stream(rows, **kwargs):
    """The step in the plain order: the kernels, then every read of the window rule."""
    m = sequence.SequenceMatcher(l_max=40, **kwargs)
    out = []
    for r in rows:
        row = np.ascontiguousarray(r, dtype=np.float64)
        if not hasattr(m, "_ring"):
            m._start(row.shape[0])
        cfg, st, i = m._cfg, m._stats, m.n_steps_
        s, work, resp = m._buffers
        _sequence_kernels.run_batch(row[None, :], i, m._sums, m._ring, m._mring, m._state, cfg.velocities, cfg.grid,
                                    cfg.approx_code, sequence.EM_ITERATIONS, sequence._em_stride(m.n_reference_),
                                    cfg.radius, st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights,
                                    st.locs, st.scales, st.sub, s, work, resp)
        m.n_steps_ = i + 1
        match, score, conf, length, velocity, _ = _decide(st, cfg, np.array([i]), False, row[None, :], m._record)
        out.append((int(match[0]), float(score[0]), float(conf[0]), int(length[0]), float(velocity[0])))
    return out


@pytest.mark.parametrize("rule, confidence", [("challenged", "changepoint"), ("punctuated", "support"),
                                              ("spanning", "posterior"), ("decorrelated", "gap"),
                                              ("consistent", "z")])
@pytest.mark.parametrize("threads", [False, True])
def test_reads_beside_the_kernels_equal_the_serial_order(rule, confidence, threads, monkeypatch):
    if threads:
        monkeypatch.setattr(_sequence_kernels, "WORK_PER_THREAD", 1)  # a second thread even on this small map
    d = _rows()
    fast = _stream(d, rule=rule, confidence=confidence)
    slow = _serial_stream(d, rule=rule, confidence=confidence)
    assert [tuple(map(repr, x)) for x in fast] == [tuple(map(repr, x)) for x in slow]


@pytest.mark.parametrize("threads", [1, 1 << 62])
def test_beside_runs_once_on_the_calling_thread(threads, monkeypatch):
    import threading

    monkeypatch.setattr(_sequence_kernels, "WORK_PER_THREAD", threads)
    m = sequence.SequenceMatcher(l_max=20)
    d = _rows(n_q=30, n=400)
    m.step(d[0])
    calls = []
    cfg, st, i = m._cfg, m._stats, m.n_steps_
    s, work, resp = m._buffers
    _sequence_kernels.run_batch(d[1][None, :], i, m._sums, m._ring, m._mring, m._state, cfg.velocities, cfg.grid,
                                cfg.approx_code, sequence.EM_ITERATIONS, sequence._em_stride(400), cfg.radius,
                                st.best_j, st.best_s, st.second_s, st.mean, st.std, st.weights, st.locs, st.scales,
                                st.sub, s, work, resp, beside=lambda: calls.append(threading.get_ident()))
    assert calls == [threading.get_ident()]


def test_row_reads_move_the_clock_once():
    d = _rows(n_q=40)
    # a rule with the horizon's clock (rule "tracked", the default, reads no clock)
    a = sequence.SequenceMatcher(l_max=40, rule=sequence.DEFAULT_LINE_RULE)
    b = sequence.SequenceMatcher(l_max=40, rule=sequence.DEFAULT_LINE_RULE)
    for r in d[:20]:
        a.step(r)
        b.step(r)
    reads = _row_reads(a._cfg, np.array([20]), d[20][None, :], a._record)
    assert reads[1] is not None and reads[0][1][0] == d[20].std()
    # the other matcher's step forms the same reads itself
    b_reads = _row_reads(b._cfg, np.array([20]), d[20][None, :], b._record)
    assert reads[1].tolist() == b_reads[1].tolist() and reads[2].tolist() == b_reads[2].tolist()


def test_checked_rows_and_other_inputs_give_the_same_answers():
    d = _rows(n_q=50)
    plain = _stream(d)
    checked = _stream([r.view(CheckedRow) for r in d])
    lists = _stream([r.tolist() for r in d])
    f32 = d.astype(np.float32).astype(np.float64)
    assert plain == checked == lists
    assert _stream(list(f32)) == _stream([r.astype(np.float32) for r in f32])


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_row_is_refused(bad):
    m = sequence.SequenceMatcher(l_max=20)
    row = _rows(n_q=2, n=300)[0]
    m.step(row)
    row[17] = bad
    with pytest.raises(DataError, match="difference row"):
        m.step(row)
    with pytest.raises(DataError, match="difference row"):
        m.step(row.astype(np.float32))
    with pytest.raises(DataError, match="dimensions"):
        m.step(np.zeros((2, 300)))


def test_the_streaming_step_imports_no_filter_module():
    """The matcher alone (no filter: a rule other than "tracked") imports neither the
    observation models nor the filters: their import and compiled checks would lengthen its
    first step."""
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "import catgraph.sequence as s\n"
            "m = s.SequenceMatcher(l_max=20, rule=s.DEFAULT_LINE_RULE)\n"
            "for r in np.random.default_rng(0).normal(size=(3, 200)):\n"
            "    m.step(r)\n"
            "print(sorted(k for k in ('catgraph.observation', 'catgraph.localizer') if k in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


@pytest.fixture
def scanned(monkeypatch):
    """One entry per row the matcher scans (its ``check_array``)."""
    calls = []
    original = sequence.check_array

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(sequence, "check_array", counting)
    return calls


def test_a_checked_row_is_not_scanned_again(scanned):
    """A row a filter has checked is handed to the kernels as it is; any other row is checked."""
    d = _rows(n_q=4, n=300)
    m = sequence.SequenceMatcher(l_max=20)
    m.step(d[0].view(CheckedRow))
    assert scanned == []
    m.step(d[1])
    assert scanned == [1]


def test_the_sequence_model_hands_its_checked_row_on(scanned):
    """The filter's sequence model checks the row once (or takes the filter's check) and its
    matcher does not scan it again; a row that fails the check is still refused."""
    from catgraph.observation import SequenceObservation

    d = _rows(n_q=6, n=300)
    model = SequenceObservation(matcher_params={"l_max": 20})
    for r in d[:3]:
        model.observe(r)  # a plain row: the model checks it
    for r in d[3:]:
        model.observe(r.view(CheckedRow))  # a filter's row: nobody checks it again
    assert scanned == []
    bad = d[0].copy()
    bad[5] = np.nan
    with pytest.raises(DataError):
        model.observe(bad)
