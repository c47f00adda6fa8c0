import numpy as np
import pytest

from catgraph.datasets import load_array, load_image_folder, load_traverse, load_uji
from catgraph.exceptions import DataError, DataNotFoundError

from .conftest import NORDLAND, UJI, needs_nordland, needs_uji, write_images, write_uji


def test_image_folder_sorted_by_number_not_text(tmp_path, rng):
    imgs = rng.integers(0, 255, (3, 8, 12))
    write_images(tmp_path / "f", imgs, names=["a-100.png", "a-20.png", "a-3.png"])
    t = load_image_folder(tmp_path / "f")
    np.testing.assert_array_equal(t.ids, [3, 20, 100])
    np.testing.assert_array_equal(t.frames[0], imgs[2])
    assert t.frames.shape == (3, 8, 12) and t.meta["kind"] == "images"


def test_rgb_images_kept_and_grey_rgb_collapsed(tmp_path, rng):
    rgb = rng.integers(0, 255, (2, 4, 5, 3))
    write_images(tmp_path / "rgb", rgb)
    assert load_image_folder(tmp_path / "rgb").frames.shape == (2, 4, 5, 3)
    grey = np.repeat(rng.integers(0, 255, (2, 4, 5, 1)), 3, axis=3)
    write_images(tmp_path / "grey", grey, suffix=".jpg")
    assert load_traverse(tmp_path / "grey").frames.ndim in (3, 4)


@pytest.mark.parametrize("colour_at", [0, 2, 4])
def test_grey_and_colour_frames_in_one_folder(tmp_path, rng, colour_at):
    """Grey frames (8-bit, 16-bit, a grey palette) beside a colour one become RGB, each grey
    value in all three channels, wherever the colour frame stands."""
    from PIL import Image

    grey = rng.integers(0, 256, (5, 6, 7), dtype=np.uint8)
    colour = rng.integers(0, 256, (6, 7, 3), dtype=np.uint8)
    folder = tmp_path / "f"
    folder.mkdir()
    for k in range(5):
        name = folder / f"img-{k:03d}.png"
        if k == colour_at:
            Image.fromarray(colour).save(name)
        elif k == 1:
            Image.fromarray(grey[k].astype(np.uint16) * 257).save(name)  # 16-bit
        elif k == 3:
            Image.fromarray(grey[k]).convert("P").save(name)  # a palette of greys
        else:
            Image.fromarray(grey[k]).save(name)
    frames = load_image_folder(folder).frames
    expected = np.repeat(grey[..., None], 3, axis=3)
    expected[colour_at] = colour
    assert frames.shape == (5, 6, 7, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames, expected)


def test_missing_and_empty_folder(tmp_path):
    with pytest.raises(DataNotFoundError, match="does not exist"):
        load_traverse(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataNotFoundError, match="no PNG or JPG"):
        load_traverse(tmp_path / "empty")


def test_corrupt_image_named(tmp_path, rng):
    write_images(tmp_path / "f", rng.integers(0, 255, (2, 4, 4)))
    (tmp_path / "f" / "img-00030.png").write_bytes(b"not a png at all")
    with pytest.raises(DataError, match="img-00030.png"):
        load_image_folder(tmp_path / "f")


def test_images_of_different_sizes(tmp_path, rng):
    write_images(tmp_path / "f", [rng.integers(0, 255, (4, 4))], names=["a1.png"])
    write_images(tmp_path / "f", [rng.integers(0, 255, (5, 4))], names=["a2.png"])
    with pytest.raises(DataError, match="differ in size"):
        load_image_folder(tmp_path / "f")


def test_uji_roundtrip_and_not_detected(tmp_path):
    rss = np.array([[100, -60, -80], [-70, 100, 100]])
    prefix = write_uji(tmp_path / "db" / "trn01", rss, crd=[[1.0, 2.0, 3], [4.0, 5.0, 3]],
                       tms=[20160101120000000, 20160101120001500], ids=[7, 8])
    t = load_uji(prefix)
    np.testing.assert_array_equal(t.frames, rss)
    np.testing.assert_allclose(t.positions, [[1, 2], [4, 5]])
    np.testing.assert_array_equal(t.floors, [3, 3])
    np.testing.assert_allclose(t.timestamps, [0, 1.5])
    np.testing.assert_array_equal(t.ids, [7, 8])
    assert load_traverse(prefix).meta["kind"] == "wifi"


def test_uji_missing_column(tmp_path):
    prefix = write_uji(tmp_path / "trn01", np.array([[100, -60], [-70, 100]]))
    (tmp_path / "trn01crd.csv").write_text("1.0,2.0,3\n4.0,5.0\n")
    with pytest.raises(DataError, match=r"trn01crd.csv, line 2: expected 3"):
        load_uji(prefix)
    (tmp_path / "trn01rss.csv").write_text("100,-60\n-70\n")
    with pytest.raises(DataError, match="missing column"):
        load_uji(prefix)


def test_uji_row_count_mismatch(tmp_path):
    prefix = write_uji(tmp_path / "trn01", np.array([[100, -60], [-70, 100]]), crd=[[1.0, 2.0, 3]])
    with pytest.raises(DataError, match="1 rows but the RSS file has 2"):
        load_uji(prefix)


def test_arrays_npy_npz_and_no_pickle(tmp_path, rng):
    x = rng.random((5, 3))
    np.save(tmp_path / "a.npy", x)
    np.testing.assert_array_equal(load_traverse(tmp_path / "a.npy").frames, x)
    np.savez(tmp_path / "b.npz", descriptors=x, positions=rng.random((5, 2)))
    t = load_array(tmp_path / "b.npz")
    assert t.positions.shape == (5, 2)
    np.save(tmp_path / "o.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="pickle"):
        load_array(tmp_path / "o.npy")
    np.save(tmp_path / "nan.npy", np.array([[1.0, np.nan]]))
    with pytest.raises(DataError, match="NaN"):
        load_array(tmp_path / "nan.npy")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(DataError):
        load_array(tmp_path / "bad.npz")


@needs_nordland
def test_nordland_folder():
    t = load_traverse(NORDLAND / "summer")
    assert t.frames.shape == (3576, 16, 32)
    assert t.ids[0] == 10 and t.ids[-1] == 35760


@needs_uji
def test_uji_real_set():
    t = load_traverse(UJI / "01" / "trn01")
    assert t.frames.shape[1] == 620 and len(t) == len(t.positions)


def test_uji_timestamps_with_14_or_17_digits(tmp_path):
    rss = np.array([[100, -60], [-70, 100], [-50, -50]])
    prefix = write_uji(tmp_path / "a" / "trn01", rss, tms=[20160101120000, 20160101120002, 20160101120103])
    np.testing.assert_allclose(load_uji(prefix).timestamps, [0, 2, 63])
    # 17 digits are read as text: a float64 could not hold the milliseconds exactly
    prefix = write_uji(tmp_path / "b" / "trn01", rss, tms=[20160602155217232, 20160602155220780, 20160602155224321])
    np.testing.assert_allclose(load_uji(prefix).timestamps, [0, 3.548, 7.089], atol=1e-6)


def test_uji_timestamps_read_alike_in_every_time_zone_and_with_a_second_60(tmp_path, monkeypatch):
    """A logger's second 60 (UJI 02/tst03 and 06/tst04 hold one) is the next minute's 0, and
    a stamp across a daylight-saving change counts the seconds that passed on one clock,
    whatever the machine's time zone (it counted an hour more under Europe/Madrid)."""
    import time

    rss = np.array([[100, -60], [-70, 100], [-50, -50]])
    stamps = [20161030015958000, 20161030015960000, 20161030030001000]  # 2016-10-30: Madrid falls back at 03:00
    prefix = write_uji(tmp_path / "c" / "trn01", rss, tms=stamps)
    for zone in ("UTC", "Europe/Madrid", "America/New_York"):
        monkeypatch.setenv("TZ", zone)
        if hasattr(time, "tzset"):
            time.tzset()
        np.testing.assert_allclose(load_uji(prefix).timestamps, [0, 2, 3603])
    monkeypatch.delenv("TZ")
    if hasattr(time, "tzset"):
        time.tzset()


@pytest.mark.parametrize("stamps", ["201601011200,201601011201,201601011202", "x,y,z", "20160101120000\n",
                                    "20161301120000,20160101120002,20160101120003"])
def test_uji_bad_timestamps_warn_and_keep_the_fingerprints(tmp_path, stamps):
    from catgraph.exceptions import CatgraphWarning

    prefix = write_uji(tmp_path / "trn01", np.array([[100, -60], [-70, 100], [-50, -50]]))
    (tmp_path / "trn01tms.csv").write_text(stamps.replace(",", "\n"))
    with pytest.warns(CatgraphWarning, match="trn01tms.csv"):
        t = load_uji(prefix)
    assert len(t) == 3 and t.timestamps is None


def test_uji_bad_ids_warn(tmp_path):
    from catgraph.exceptions import CatgraphWarning

    prefix = write_uji(tmp_path / "trn01", np.array([[100, -60], [-70, 100]]), ids=[1])
    with pytest.warns(CatgraphWarning, match="1 rows but the RSS file has 2"):
        assert load_uji(prefix).ids is None


@pytest.mark.parametrize("source", [5, None, 3.5, b"bytes", "", ["a"]])
def test_load_traverse_needs_a_path(source):
    from catgraph.exceptions import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="needs a path"):
        load_traverse(source)


@pytest.mark.parametrize("array, message", [
    (np.array(np.inf), "shape"), (np.array(3.0), "shape"), (np.zeros(4), "shape"), (np.zeros((0, 3)), "empty"),
    (np.ones((3, 2), dtype=complex), "complex"), (np.array([["a", "b"]]), "numeric"),
    (np.array([[1.0, np.inf]]), "infinite"),
])
def test_odd_arrays_refused_with_a_reason(tmp_path, array, message):
    np.save(tmp_path / "x.npy", array)
    with pytest.raises(DataError, match=message):
        load_traverse(tmp_path / "x.npy")
    np.savez(tmp_path / "x.npz", descriptors=array)
    with pytest.raises(DataError, match=message):
        load_traverse(tmp_path / "x.npz")


def test_truncated_npz_member(tmp_path, rng):
    np.savez(tmp_path / "x.npz", descriptors=rng.random((50, 40)))
    data = (tmp_path / "x.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError):
        load_traverse(tmp_path / "t.npz")


def test_truncated_npz_leaves_no_file_open(tmp_path, rng):
    import gc
    import warnings

    np.savez(tmp_path / "x.npz", descriptors=rng.random((50, 40)))
    data = (tmp_path / "x.npz").read_bytes()
    for cut in (100, len(data) // 2, len(data) - 10):
        (tmp_path / "t.npz").write_bytes(data[:cut])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(DataError):
                load_traverse(tmp_path / "t.npz")
            gc.collect()
        assert not [w for w in caught if issubclass(w.category, ResourceWarning)]
