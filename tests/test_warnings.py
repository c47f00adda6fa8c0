"""Every CatgraphWarning is reported at the caller's own line, whatever path led to it.

:func:`catgraph.exceptions.warn` reports a warning at the first frame outside the catgraph
package. Each case calls a public function from this file and checks the warning's file
and line: a fixed ``stacklevel`` would name a line inside catgraph for one of the paths
(the same loader is reached directly and through a command's layers)."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

from catgraph.exceptions import CatgraphWarning, warn


def _line_after(frame_info) -> int:
    return frame_info.lineno + 1


def _caught(call):
    """The CatgraphWarnings of ``call()``, every one recorded (no registry dedup)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        call()
    return [w for w in caught if issubclass(w.category, CatgraphWarning)]


def test_a_direct_call_is_reported_at_its_own_line():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        here = _line_after(inspect.getframeinfo(inspect.currentframe()))
        warn("a note")
    assert len(caught) == 1 and caught[0].filename == __file__ and caught[0].lineno == here
    assert caught[0].category is CatgraphWarning and str(caught[0].message) == "a note"


def test_evaluate_without_true_matches_points_at_the_caller():
    from catgraph.metrics import evaluate
    from catgraph.traverse import FrameTolerance

    here = []

    def call():
        here.append(_line_after(inspect.getframeinfo(inspect.currentframe())))
        evaluate(np.arange(3), np.array([0, 1, 2]), np.ones(3), FrameTolerance(3, 0, offset=10))

    found = _caught(call)
    assert [w.filename for w in found] == [__file__] and found[0].lineno == here[0]


def test_a_loader_warning_points_at_the_caller_by_every_path(tmp_path):
    """The UJI loader's timestamp warning, reached through ``load_uji`` and through
    ``load_traverse`` (one layer more): both name this file's calling line."""
    from catgraph.datasets import load_traverse
    from catgraph.datasets.loaders import load_uji
    from tests.conftest import write_uji

    prefix = write_uji(tmp_path / "trn01", np.array([[100, -60], [-70, 100], [-50, -50]]))
    (tmp_path / "trn01tms.csv").write_text("x\ny\nz")
    for load in (load_uji, load_traverse):
        here = []

        def call(load=load):
            here.append(_line_after(inspect.getframeinfo(inspect.currentframe())))
            load(prefix)

        found = _caught(call)
        assert found, load.__name__
        assert {(w.filename, w.lineno) for w in found} == {(__file__, here[0])}, load.__name__


def test_the_large_image_note_points_at_the_caller():
    from catgraph.pipeline import describe
    from catgraph.traverse import Traverse

    big = Traverse(np.random.default_rng(0).uniform(0, 255, (3, 150, 200)), name="camera")
    here = []

    def call():
        here.append(_line_after(inspect.getframeinfo(inspect.currentframe())))
        describe(big)

    found = _caught(call)
    assert len(found) == 1 and found[0].filename == __file__ and found[0].lineno == here[0]


def test_warnings_as_errors_raise_the_catgraph_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CatgraphWarning, match="a note"):
            warn("a note")
