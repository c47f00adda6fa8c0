from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NORDLAND = DATA / "nordland" / "32x16"
UJI = DATA / "uji-lib" / "db"

needs_nordland = pytest.mark.skipif(not NORDLAND.exists(), reason="../shared/data/nordland not present")
needs_uji = pytest.mark.skipif(not UJI.exists(), reason="../shared/data/uji-lib not present")


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
