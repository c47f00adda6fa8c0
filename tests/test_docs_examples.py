"""The Python examples of README.md and docs/*.md run as written.

Each fenced ``python`` block is executed in a fresh namespace that holds what the text
around it assumes (``reference``, ``query``, a saved ``route.npz`` …, built from the
synthetic world), in a temporary folder. A block that needs what a test cannot have (a
Dask scheduler at an address) is listed with the reason; a new block must be added to
one of the two tables, so that no example is left unchecked by oversight. The defaults
that docs/README.md lists are read from the constants that hold them.
"""

import os
import re
from pathlib import Path

import numpy as np
import pytest

from .conftest import NORDLAND, write_images

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _blocks() -> dict[tuple[str, int], str]:
    out = {}
    for path in DOCS:
        text = path.read_text(encoding="utf-8")
        for k, m in enumerate(re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M)):
            out[(str(path.relative_to(ROOT)), k)] = m.group(1)
    return out


BLOCKS = _blocks()


@pytest.fixture(scope="module")
def world():
    from catgraph.datasets.synthetic import make_world

    return make_world(seed=1, blocks=(2, 2))


@pytest.fixture(scope="module")
def image_world():
    from catgraph.datasets.synthetic import make_world

    return make_world(seed=1, blocks=(2, 2), as_images=True)


def _route_map(image_world, folder: Path) -> None:
    from catgraph.io import build_map, save_map

    save_map(folder / "route.npz", build_map(image_world.reference))


def _readme_experiment(ns, folder, world, image_world):
    if not NORDLAND.is_dir():
        pytest.skip("needs the Nordland data (../shared/data)")
    os.chdir(ROOT)  # the example's paths are relative to the repository


def _readme_live(ns, folder, world, image_world):
    _route_map(image_world, folder)
    ns["camera_image"] = image_world.query.frames[0]


def _experiments_run(ns, folder, world, image_world):
    write_images(folder / "summer", image_world.reference.frames)
    write_images(folder / "winter", image_world.query.frames[:80])


def _experiments_pairs(ns, folder, world, image_world):
    ns.update(np=np, rows=[(0, [0, 1]), (1, []), (2, [5])])


def _check_pairs(ns, folder):
    from catgraph.datasets.ground_truth import load_ground_truth

    gt = load_ground_truth(folder / "pairs.csv", 3, 6)
    np.testing.assert_array_equal(gt.has_true_match(np.arange(3)), [True, False, True])


def _live(ns, folder, world, image_world):
    _route_map(image_world, folder)
    ns["_frame"] = image_world.query.frames[0]


def _check_live(ns, folder):
    place, score, p_new, window = ns["on_frame"](ns["_frame"])
    assert 0 <= place < ns["live_map"].n_places and 0.0 <= p_new <= 1.0


def _map(ns, folder, world, image_world):
    from catgraph.histogram import HistogramLikelihood

    rng = np.random.default_rng(0)
    ns.update(reference=world.reference, query=world.query,
              fitted_histogram_likelihood=HistogramLikelihood().fit(rng.uniform(0, 1, 200), rng.uniform(1, 3, 2000)))


def _filters(ns, folder, world, image_world):
    ns.update(reference=world.reference, query=world.query.take(np.arange(60)))


def _filters_grid(ns, folder, world, image_world):
    from catgraph.graph import PlaceGraph
    from catgraph.pipeline import differences

    query = world.query.take(np.arange(60))
    ns.update(query=query, graph=PlaceGraph.from_traverse(world.reference), D=differences(world.reference, query))


def _report(ns, folder, world, image_world):
    from matplotlib.figure import Figure

    from catgraph.cli.main import main

    for name, window in (("single.json", "1"), ("adaptive.json", "adaptive")):
        assert main(["match", "synthetic:1", "synthetic:1", "--window", window, "-o", str(folder / name), "-q"]) == 0
    ns["fig"] = Figure()
    ns["fig"].add_subplot().plot([0, 1])


def _sequence(ns, folder, world, image_world):
    from catgraph.pipeline import differences

    ns.update(reference=world.reference, query=world.query, D=differences(world.reference, world.query), i=10)


def _nothing(ns, folder, world, image_world):
    pass


#: block → (set-up, check after it ran or None)
RUN = {
    ("README.md", 0): (_readme_experiment, None),
    ("README.md", 1): (_readme_live, None),
    ("docs/experiments.md", 0): (_experiments_run, None),
    ("docs/experiments.md", 1): (_experiments_pairs, _check_pairs),
    ("docs/live.md", 0): (_live, _check_live),
    ("docs/maps_and_sweeps.md", 0): (_map, None),
    ("docs/particle_filter.md", 0): (_filters, None),
    ("docs/particle_filter.md", 1): (_filters_grid, None),
    ("docs/report.md", 0): (_report, None),
    ("docs/sequence.md", 0): (_sequence, None),
    ("docs/synthetic.md", 0): (_nothing, None),
}

#: blocks a test cannot run as written, and why (their calls are tested elsewhere)
NOT_RUN = {
    ("docs/live.md", 1): "connects to a Dask scheduler at an address (tests/test_distributed.py runs the same "
                         "calls on a LocalCluster)",
    ("docs/maps_and_sweeps.md", 1): "connects to a Dask scheduler at an address (tests/test_sweep.py runs "
                                    "run_sweep locally and on a LocalCluster)",
}


def test_every_example_is_run_or_named_with_a_reason():
    assert set(BLOCKS) == set(RUN) | set(NOT_RUN), "add the new example to RUN (or NOT_RUN, with the reason)"
    assert not set(RUN) & set(NOT_RUN)


@pytest.mark.parametrize("key", sorted(RUN), ids=lambda k: f"{k[0]}#{k[1]}")
def test_example_runs(key, world, image_world, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    setup, check = RUN[key]
    ns = {"__name__": "__main__"}
    setup(ns, tmp_path, world, image_world)
    exec(compile(BLOCKS[key], f"{key[0]} (example {key[1]})", "exec"), ns)
    if check is not None:
        check(ns, tmp_path)


def test_the_defaults_docs_readme_lists_are_the_codes():
    """docs/README.md lists today's defaults; each value it states is read here from the
    constant that holds it, so a default changed without the list fails."""
    import inspect

    from catgraph import methods, sequence
    from catgraph.grid import DEFAULT_VELOCITIES as GRID_VELOCITIES
    from catgraph.localizer import Localizer

    text = " ".join((ROOT / "docs" / "README.md").read_text(encoding="utf-8").split())
    params = methods.resolve_params("filter", {})
    lengths = inspect.signature(sequence.match_sequences).parameters
    owned = [
        (methods.GRID_MAX_PLACES == 100_000, "up to `GRID_MAX_PLACES` = 10⁵ places"),
        (inspect.signature(Localizer).parameters["n_particles"].default == 2000 and params["n_particles"] is None,
         "particle filter (2,000 particles)"),
        (params["model"] == "tempered" and params["mode"] == "auto", "`tempered`: per-query normalised differences"),
        (methods.DENSE_VELOCITY_MAX_PLACES == 10_000, "on maps of at most 10⁴ places every tenth from 0.9 to 4"),
        (sorted({abs(v) for v in GRID_VELOCITIES}) == [0.5, 1.0, 2.0, 3.0], "else ±0.5, 1, 2, 3"),
        (methods.HOME_SPEED_ODDS == 3.0, "three times as likely as each other"),
        (methods.RIGID_PRIOR == 0.05 and methods.RIGID_MAX_PLACES == 10_000,
         "a rigid line (one speed, no jump, prior 0.05) and a varying speed, on maps of at most 10⁴ places"),
        (methods.JUMP_GRID_MAX_PLACES == 5_000, "jump grid on maps of at most 5,000 places"),
        (methods.OUTLIER_PROBABILITY == 0.01, "outlier frames at 1 %"),
        (methods.REPEAT_PRIOR == 0.1, "`REPEAT_PRIOR` = 0.1"),
        (params["confidence_radius"] == 2, "(±2 mean spacings along the route"),
        (sorted(abs(v) for v in sequence.DEFAULT_VELOCITIES) == [0.5, 0.5, 1, 1, 2, 2, 3, 3],
         "velocities ±0.5, 1, 2, 3 places per frame (`DEFAULT_VELOCITIES`)"),
        (sequence.DEFAULT_GRID == 13 and (lengths["l_min"].default, lengths["l_max"].default) == (5, 500),
         "13 window lengths from 5 to 500 frames"),
        (sequence.DEFAULT_RULE == "tracked", "| the window rule | `tracked`"),
        (sequence.DEFAULT_LINE_RULE == "challenged", "`challenged` (`DEFAULT_LINE_RULE`)"),
    ]
    for holds, phrase in owned:
        assert phrase in text, f"docs/README.md no longer says {phrase!r}"
        assert holds, f"the code's default is no longer what docs/README.md says: {phrase!r}"
