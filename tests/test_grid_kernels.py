"""The grid filter's line path stays bit-identical when it is made faster.

Whole runs of :class:`~catgraph.grid.GridLocalizer` on line graphs (the fast path:
float32 prediction, factored update, fused passes) against digests of the outputs the
filter produced before the step's passes were fused: every frame's answer, confidence,
log-odds, score, new-place probability and place posterior, and the final state,
likelihood, velocity marginal and jump rate, bit for bit. The runs: random rows with a
moving track on a map of several blocks (one thread), the same on a map large enough
for the blocks to be shared among threads, frames the model finds uninformative or
impossible (the update's other branches), and a stretch of the real Nordland
difference matrix with the tempered whole-image model (whose feedback reads the
posterior every frame). The pieces of the fused passes are also tested against the
numpy they replace."""

import numpy as np
import pytest

from catgraph import grid
from catgraph.graph import PlaceGraph
from catgraph.grid import GridLocalizer
from catgraph.observation import Observation, TemperedObservation

from .conftest import NORDLAND, assert_recorded, needs_nordland
from .conftest import array_digest as _digest


def _run(loc, d) -> str:
    """Digest of every frame's outputs and of the filter's final state."""
    res = loc.run(d, return_posterior=True)
    out = [res.place, res.confidence, res.new_place_probability, res.log_odds, res.score, res.posterior,
           loc._state, loc._like, loc._velocity, loc.prior_, loc.place_posterior_, np.array([loc.recovery_])]
    return _digest(out)


def _track_rows(n_q, n, seed, speed=1):
    """Random rows with one place per frame (at ``speed`` places per frame) clearly best."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_q, n))
    for i in range(n_q):
        d[i, (n // 3 + speed * i) % n] -= 5.0
        d[i, (n // 3 + speed * i + 1) % n] -= 3.0
    return d


class _Scripted:
    """A model replaying fixed log-ratios; ``None`` rows are uninformative frames."""

    def __init__(self, ratios, new_place=-1.0):
        self.ratios, self.new_place, self.k = ratios, new_place, 0

    def reset(self):
        self.k = 0

    def observe(self, row):
        r = self.ratios[self.k % len(self.ratios)]
        self.k += 1
        if r is None:
            return Observation(np.zeros(len(row)), 0.0, False)
        return Observation(r, self.new_place, True)

    def feedback(self, feedback):
        pass


def _scripted_ratios(n, seed):
    """Log-ratios with a moving peak, two uninformative frames and one frame no place of
    which is possible (every ratio −inf: the update keeps the prediction)."""
    rng = np.random.default_rng(seed)
    ratios = []
    for i in range(40):
        r = rng.normal(size=n)
        r[(n // 2 + 2 * i) % n] += 6.0
        ratios.append(r)
    ratios[7] = None
    ratios[8] = None
    ratios[20] = np.full(n, -np.inf)
    return ratios


#: digests of the outputs before the passes were fused (the code of the commit that added this file)
_DIGESTS = {"random tempered": "65df66da61ac163f", "random tempered double speed": "199a06dd72faec44",
            "scripted branches": "82c69d651eaf6f6b", "threaded": "29988694c919ce9d", "nordland": "fb6bb5dbe77f855a"}
#: the same outputs on processors that round otherwise, recorded on them (Zen 4 at f19e3aa; Zen 3
#: at 8cb4901, the digests the code of the commit that added this file gives there)
_OWN_DIGESTS = {"znver4": {"random tempered": "09f689e4c19db928", "random tempered double speed": "f83d741cf13d6469",
                           "scripted branches": "32d699e47c291bdc", "threaded": "304ab749d593ad99",
                           "nordland": "bf17990bcde5de7c"},
                "znver3": {"random tempered": "e848977549f83570", "random tempered double speed": "d0d22f67738a1357",
                           "scripted branches": "94f71625a8e63e1c", "threaded": "afa5806ae4479d08",
                           "nordland": "9bc178ae12f8475b"}}


def _recorded_model() -> TemperedObservation:
    """The whole-image model as the digests were recorded (before its jump evidence)."""
    return TemperedObservation(jump_evidence=False)


def _cases():
    yield "random tempered", lambda: (GridLocalizer(PlaceGraph.chain(5000), _recorded_model()),
                                      _track_rows(60, 5000, 0))
    yield "random tempered double speed", lambda: (GridLocalizer(PlaceGraph.chain(5000), _recorded_model()),
                                                   _track_rows(60, 5000, 1, speed=2))
    yield "scripted branches", lambda: (GridLocalizer(PlaceGraph.chain(3000), _Scripted(_scripted_ratios(3000, 2))),
                                        np.zeros((40, 3000)))
    yield "threaded", lambda: (GridLocalizer(PlaceGraph.chain(60_000), _recorded_model()),
                               _track_rows(12, 60_000, 3))


@pytest.mark.filterwarnings("ignore:invalid value encountered")
@pytest.mark.parametrize("name", [c[0] for c in _cases()])
def test_line_path_outputs_are_those_before_the_fusion(name):
    make = dict(_cases())[name]
    loc, d = make()
    assert_recorded(_run(loc, d), _DIGESTS, _OWN_DIGESTS, name)


def _nordland_rows(n_q=300):
    """The first query frames' normalised difference rows of Nordland (summer map, winter query)."""
    from catgraph.datasets import load_traverse
    from catgraph.pipeline import differences
    from catgraph.traverse import Traverse

    ref = load_traverse(NORDLAND / "summer")
    query = load_traverse(NORDLAND / "winter")
    return differences(ref, Traverse(query.frames[:n_q]))


@needs_nordland
def test_nordland_run_gives_the_outputs_before_the_fusion():
    d = _nordland_rows()
    loc = GridLocalizer(PlaceGraph.chain(d.shape[1]), _recorded_model())
    assert_recorded(_run(loc, d), _DIGESTS, _OWN_DIGESTS, "nordland")


@pytest.mark.parametrize("n", [1, 777, 4096, 10_001])
def test_fused_update_pass_equals_the_kernel_and_numpy_it_replaces(n):
    """The update's sums (:func:`grid._evidence_sums`) are :func:`grid._likelihood`'s;
    the writes of :func:`grid._posterior_pass` are its likelihood and place masses, the
    place posterior numpy's product, the answer ``np.argmax`` (ties: the first)."""
    rng = np.random.default_rng(n)
    e = rng.random(n)
    e[rng.random(n) < 0.1] = 0.0
    prior = rng.random(n) / n
    prior[n // 2] = prior[n // 3] = 1.0  # two equal largest masses where e is equal too
    e[n // 2] = e[n // 3] = 1.0
    like, velocity, mass = np.empty(n), np.zeros(10), np.empty(n)
    total, like_mean = grid._likelihood(np.zeros((10, n), np.float32), e, prior, like, velocity, mass, True)
    sums = np.zeros(2)
    grid._evidence_sums(e, prior, 0, n, sums)
    assert sums[1] == total and sums[0] / n == like_mean
    got_like, got_mass, got_post = np.empty(n), np.empty(n), np.empty(n)
    best = grid._posterior_pass(e, 1.0 / total, prior, got_like, got_mass, got_post, 0.75)
    assert np.array_equal(got_like, like) and np.array_equal(got_mass, mass)
    assert np.array_equal(got_post, np.multiply(mass, 0.75))
    assert best == int(np.argmax(mass))


def test_posterior_pass_answer_with_nan_is_numpys():
    mass_like = np.array([0.1, 0.5, np.nan, 0.9, np.nan])
    out = [np.empty(5) for _ in range(3)]
    assert grid._posterior_pass(np.ones(5), 1.0, mass_like, *out, 1.0) == int(np.argmax(mass_like)) == 2


@pytest.mark.parametrize("load, two, sixteen", [(0.0, 2, 16), (1.0, 2, 16), (1.6, 1, 15), (5.0, 1, 12)])
def test_line_kernel_threads_leave_the_cores_other_processes_hold(monkeypatch, load, two, sixteen):
    """The cores less the load beyond this process's own (one core's worth), at least one."""
    monkeypatch.setattr(grid, "_LOAD", [-np.inf, 0.0])
    monkeypatch.setattr(grid.os, "getloadavg", lambda: (load, load, load))
    assert grid._free_cores(2) == two
    assert grid._free_cores(16) == sixteen


@pytest.mark.parametrize("kwargs", [dict(rigid_prior=0.05), dict(velocity_stay=1.0, reverse_probability=0.0)])
def test_line_path_keeps_its_normaliser_when_most_mass_runs_off_the_route(kwargs):
    """A track driven to the route's end, then a jump back: almost all of a component's
    mass leaves at the end, and ``total_in − lost`` cancelled (the rigid component's
    prediction summed to 0.003 or 0 in the float32 line storage, its weight off 100×).
    The line path against the general path (``grid.predict``) on the same filter."""
    from catgraph.grid import GridLocalizer, route_neighbours

    from .conftest import FixedLogRatio

    n = 40
    graph = PlaceGraph.chain(n)
    truth = np.r_[np.arange(n), np.arange(5, 25)]
    rows = np.full((len(truth), n), -30.0) + np.random.default_rng(0).normal(size=(len(truth), n))
    rows[np.arange(len(truth)), truth] = 0.0
    line = GridLocalizer(graph, FixedLogRatio(-5.0), smooth_feedback=False, **kwargs)
    general = GridLocalizer(graph, FixedLogRatio(-5.0), smooth_feedback=False, **kwargs)
    line.reset()
    general.reset()
    assert line._line
    general._line, general._neighbours = False, route_neighbours(graph)
    for k, row in enumerate(rows):
        a, b = line.step(row), general.step(row)
        np.testing.assert_allclose(line.place_posterior_, general.place_posterior_, atol=1e-6, err_msg=f"frame {k}")
        assert abs(a.new_place_probability - b.new_place_probability) < 1e-6
        for c in line._components or [dict(prior_=line.prior_)]:
            assert abs(c["prior_"].sum() - 1.0) < 1e-4
