import hashlib
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NORDLAND = DATA / "nordland" / "32x16"
UJI = DATA / "uji-lib" / "db"

needs_nordland = pytest.mark.skipif(not NORDLAND.exists(), reason="../shared/data/nordland not present")
needs_uji = pytest.mark.skipif(not UJI.exists(), reason="../shared/data/uji-lib not present")


class FixedLogRatio:
    """An observation model whose log-ratio is ``−τ d`` of each row: the same model for
    the particle filter and the grid filter it is compared with."""

    def __init__(self, tau):
        self.tau = tau

    def reset(self):
        pass

    def observe(self, row):
        from catgraph.observation import Observation

        return Observation(-self.tau * np.asarray(row, dtype=float), 0.0)


def survey_graph(n_points=15, repeats=3):
    """A metric route sampled several times at each point (zero-length chain edges)."""
    from catgraph.graph import PlaceGraph
    from catgraph.traverse import Traverse

    points = np.stack([5.0 * np.arange(n_points), np.zeros(n_points)], 1)
    ref = Traverse(np.zeros((n_points * repeats, 2)), positions=np.repeat(points, repeats, axis=0))
    return PlaceGraph.from_traverse(ref)


def hub_map(places):
    """8200 random 16-d references with flat frames (hubs) at 100, 5000 and 8195 (one in
    every shard of 4096), and a noisy query of ``places``."""
    rng = np.random.default_rng(5)
    r = rng.normal(size=(8200, 16)).astype(np.float32)
    r[[100, 5000, 8195]] *= 0.05
    q = r[places] + 0.4 * rng.normal(size=(places.size, 16)).astype(np.float32)
    return r, q


def alike_map():
    """A map whose neighbouring places look alike (each descriptor averaged over 15
    places), so that the query's rows take several frames to decorrelate, and a query
    driven at a varying speed (1, 2, 1/2, backwards) that crosses the shard edges at
    4096 and 8192, jumps, and runs off the end of the map (three shards of 4096).
    Returns ``(query, reference)``."""
    rng = np.random.default_rng(7)
    base = rng.normal(size=(8200, 16))
    r = np.stack([np.convolve(base[:, c], np.ones(15) / 15, mode="same") for c in range(16)], 1).astype(np.float32)
    places = np.concatenate([np.arange(4000, 4090), np.arange(4090, 4190, 2), np.repeat(np.arange(1000, 1040), 2),
                             np.arange(2040, 2000, -1), np.arange(8150, 8200)])
    q = r[places] + (0.6 * r.std()) * rng.normal(size=(places.size, 16)).astype(np.float32)
    return q, r


def hub_case(client, dd):
    """The cluster's hub case: :func:`hub_map` of a route crossing a shard edge and the map's
    end, three blank query frames, sharded in 4096 places, the local normalised rows (blank
    frames zeroed) and the map's hub offsets. Returns ``(query, sharded, local, blank,
    offsets)``."""
    from catgraph.differences import difference_matrix
    from catgraph.hubs import hub_offsets

    r, q = hub_map(np.concatenate([np.arange(3990, 4120), np.arange(8150, 8200)]))
    blank = np.zeros(len(q), dtype=bool)
    blank[[0, 15, 100]] = True
    ref = dd.shard_reference(r, "sad", client, shard_places=4096)
    local = difference_matrix(q, r, "sad", normalise=True)
    local[blank] = 0.0
    offsets = hub_offsets(difference_matrix(r[::7], r, "sad", normalise=True), rows=np.arange(0, 8200, 7))
    return q, ref, local, blank, offsets


@pytest.fixture(scope="module")
def client():
    """A Dask client on a two-worker in-process cluster (skips without dask.distributed)."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def jump_route():
    """Differences of a 200-frame query over a 400-place route that jumps at frame 100
    (places 50-149, then 300-399), each frame's true place 1.5 spreads closer: ``(d, truth)``."""
    rng = np.random.default_rng(5)
    d = rng.normal(size=(200, 400))
    truth = np.r_[np.arange(50, 150), np.arange(300, 400)]
    d[np.arange(200), truth] -= 1.5
    return d, truth


def write_images(folder: Path, images, names=None, suffix=".png"):
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    for k, img in enumerate(images):
        name = names[k] if names else f"img-{(k + 1) * 10:05d}{suffix}"
        Image.fromarray(np.asarray(img, dtype=np.uint8)).save(folder / name)
    return folder


def write_uji(prefix: Path, rss, crd=None, tms=None, ids=None):
    prefix.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(f"{prefix}rss.csv", rss, delimiter=",", fmt="%d")
    if crd is not None:
        np.savetxt(f"{prefix}crd.csv", crd, delimiter=",", fmt="%.4f")
    if tms is not None:
        np.savetxt(f"{prefix}tms.csv", np.asarray(tms)[:, None], delimiter=",", fmt="%d")
    if ids is not None:
        np.savetxt(f"{prefix}ids.csv", np.asarray(ids)[:, None], delimiter=",", fmt="%d")
    return prefix


def host_processor() -> str:
    """This processor as llvmlite names it: kernels compiled with ``fastmath`` may round
    otherwise on another processor (AVX-512 fuses other multiply-adds)."""
    import llvmlite.binding

    return llvmlite.binding.get_host_cpu_name()


#: the processor the kernels' digests were first recorded on (several Intel processors gave
#: the same bits)
RECORDED_ON = "cascadelake"
#: processors whose fastmath kernels round otherwise than the machines the digests were first
#: recorded on, each named with the processor whose digests it gives (Zen 5 gives Zen 4's bits:
#: the same AVX-512 fusions; Zen 3, without AVX-512, its own), recorded on them from the reference
#: code each digest names
ROUNDS_LIKE = {"znver3": "znver3", "znver4": "znver4", "znver5": "znver4"}
#: processors where the particle filter's fastmath kernels and their references fuse other
#: multiply-adds (equal within 1e-14 a step there, not bit for bit: ``test_localizer_identity``)
ROUNDS_OTHERWISE = ("znver4", "znver5")


def assert_recorded(digest: str, digests: dict, per_processor: dict, name) -> None:
    """``digest`` is the digest ``name`` as recorded (``digests[name]``), or, on a processor
    that rounds otherwise, as recorded on a processor that rounds like it
    (``per_processor[ROUNDS_LIKE[host_processor()]][name]``). On a processor none was
    recorded on, a digest other than the first machines' skips the comparison: fastmath
    kernels round per processor, and the reference code each digest names, run there, gives
    that processor's digests to record."""
    processor = host_processor()
    if processor in ROUNDS_LIKE:
        assert digest == per_processor[ROUNDS_LIKE[processor]][name]
    elif processor == RECORDED_ON or digest == digests[name]:
        assert digest == digests[name]
    else:
        pytest.skip(f"no digests recorded on this processor ({processor}): fastmath kernels round per processor; "
                    "run the reference code the digests name here and record its digests in ROUNDS_LIKE")


def array_digest(arrays) -> str:
    """A short digest of arrays' dtypes, shapes and bytes: answers recorded from a reference
    version of a kernel, compared bit for bit after it is made faster."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]
