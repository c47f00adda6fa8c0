"""Video files as traverses (:mod:`catgraph.datasets.video`): the frames a folder of the same
frames gives, frames kept by time, the answers of the folder, and every refusal typed."""

import json
import sys
import warnings
from fractions import Fraction

import numpy as np
import pytest

from catgraph.cli.main import main
from catgraph.datasets import load_traverse
from catgraph.datasets.video import load_video
from catgraph.exceptions import (CatgraphWarning, DataError, DataNotFoundError, InsufficientMemoryError,
                                 InvalidParameterError, MissingDependencyError)

from .conftest import write_images

av = pytest.importorskip("av")


def write_video(path, frames, rate=10):
    """A lossless video (FFV1, planar RGB): it decodes to exactly ``frames``."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("ffv1", rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "bgr0"
        for array in frames:
            rgb = array if array.ndim == 3 else np.repeat(array[..., None], 3, axis=2)
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb, np.uint8), "rgb24")))
        container.mux(stream.encode())
    return path


@pytest.fixture
def route(tmp_path):
    """A reference and a noisier query of one route, each as a folder of PNG frames and as a video."""
    rng = np.random.default_rng(4)
    base = rng.integers(0, 256, (36, 12, 20, 3), dtype=np.uint8)
    noisy = np.clip(base + rng.normal(0, 25, base.shape), 0, 255).astype(np.uint8)
    return {"ref": write_images(tmp_path / "ref", base), "qry": write_images(tmp_path / "qry", noisy),
            "ref_video": write_video(tmp_path / "ref.mkv", base), "qry_video": write_video(tmp_path / "qry.mkv", noisy),
            "frames": base}


def test_a_video_gives_the_frames_of_its_folder(route):
    video, folder = load_traverse(route["ref_video"]), load_traverse(route["ref"])
    assert video.frames.dtype == np.uint8 and video.frames.shape == (36, 12, 20, 3)
    np.testing.assert_array_equal(video.frames, folder.frames)
    np.testing.assert_array_equal(video.ids, np.arange(36))
    np.testing.assert_allclose(video.timestamps, np.arange(36) / 10)
    assert video.meta["kind"] == "images" and video.meta["video"] == {"fps": None, "rate": 10.0, "frames_read": 36}


def test_grey_video_frames_are_grey(tmp_path):
    grey = np.random.default_rng(0).integers(0, 256, (5, 8, 10), dtype=np.uint8)
    t = load_video(write_video(tmp_path / "g.mkv", grey))
    assert t.frames.shape == (5, 8, 10)
    np.testing.assert_array_equal(t.frames, grey)


@pytest.mark.parametrize("rate, fps", [(10, 2.5), (10, 3), (25, 7), (10, 10), (10, 40), (30, 0.5)])
def test_fps_keeps_the_first_frame_of_each_interval(tmp_path, rate, fps):
    frames = np.random.default_rng(rate).integers(0, 256, (61, 4, 6, 3), dtype=np.uint8)
    t = load_video(write_video(tmp_path / "v.mkv", frames, rate), fps=fps)
    # the slow reference, in exact fractions: frame k (time k / rate) is kept where it is the
    # first frame at or after a multiple of 1 / fps
    step, times = 1 / Fraction(fps), [Fraction(k, rate) for k in range(61)]
    kept = [k for k in range(61) if k == 0 or (times[k] // step) > (times[k - 1] // step)]
    np.testing.assert_array_equal(t.ids, kept)
    np.testing.assert_array_equal(t.frames, frames[kept])
    np.testing.assert_allclose(t.timestamps, [float(times[k]) for k in kept])
    assert t.meta["video"]["fps"] == fps and t.meta["video"]["frames_read"] == 61


def test_video_refusals_are_typed(tmp_path, route, monkeypatch):
    with pytest.raises(DataNotFoundError, match="does not exist"):
        load_traverse(tmp_path / "none.mp4")
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 20)
    with pytest.raises(DataError, match="cannot read the video"):
        load_traverse(tmp_path / "junk.mp4")
    for fps in (0, -1, float("nan"), float("inf"), "2", True):
        with pytest.raises(InvalidParameterError, match="fps"):
            load_traverse(route["ref_video"], fps=fps)
    with pytest.raises(InvalidParameterError, match="picks the frames of a video"):
        load_traverse(route["ref"], fps=2)  # a folder of frames has no time to pick them by
    monkeypatch.setitem(sys.modules, "av", None)  # PyAV not installed
    with pytest.raises(MissingDependencyError, match=r"catgraph\[video\]"):
        load_traverse(route["ref_video"])


def test_a_video_too_large_for_memory_is_refused_before_it_is_read(route, monkeypatch):
    import catgraph._validation as validation

    monkeypatch.setattr(validation, "available_memory", lambda: 20_000)  # bytes: about 27 frames of 12 x 20 x 3
    with pytest.raises(InsufficientMemoryError, match="--fps"):
        load_video(route["ref_video"])
    assert len(load_video(route["ref_video"], fps=2)) == 8  # 3.6 s at 2 per second fits


def test_the_commands_answer_a_video_as_its_folder(route, tmp_path):
    runs = {}
    for kind, (ref, qry) in {"folder": (route["ref"], route["qry"]),
                             "video": (route["ref_video"], route["qry_video"])}.items():
        out = tmp_path / f"{kind}.json"
        assert main(["localize", str(ref), str(qry), "--tolerance", "1", "-o", str(out), "-q"]) == 0
        runs[kind] = json.loads(out.read_text())
    assert runs["video"]["frames"] == runs["folder"]["frames"]
    assert runs["video"]["metrics"] == runs["folder"]["metrics"]


def test_a_map_keeps_its_fps_and_reads_a_video_query_at_it(route, tmp_path, capsys):
    map_file = tmp_path / "m.npz"
    assert main(["build-map", str(route["ref_video"]), "--fps", "5", "-o", str(map_file), "-q"]) == 0
    from catgraph.io import load_map

    assert load_map(map_file).frontend["fps"] == 5.0 and load_map(map_file).n_places == 18
    out = tmp_path / "q.json"
    assert main(["match", "--map", str(map_file), str(route["qry_video"]), "--window", "3", "-o", str(out),
                 "-q"]) == 0
    assert json.loads(out.read_text())["frames"]["query_index"] == list(range(18))  # every other frame, as the map
    capsys.readouterr()
    # --fps where no input is a video, and on a saved map, is one line and exit 1
    assert main(["localize", str(route["ref"]), str(route["qry"]), "--fps", "2", "-q"]) == 1
    assert "picks the frames of a video" in capsys.readouterr().err
    assert main(["localize", "--map", str(map_file), str(route["qry_video"]), "--fps", "2", "-q"]) == 1
    assert "does not apply to a saved map" in capsys.readouterr().err
    assert main(["build-map", "synthetic:0", "--fps", "2", "-o", str(tmp_path / "s.npz"), "-q"]) == 1
    assert "not one" in capsys.readouterr().err


def test_a_sweep_reads_its_videos_at_the_configured_fps(route, tmp_path):
    config = tmp_path / "videos.toml"
    config.write_text(f'''
[[dataset]]
name = "drive"
reference = "{route['ref_video'].name}"
query = "{route['qry_video'].name}"
tolerance = 1
frontend = {{ fps = 5 }}

[[method]]
method = "single-frame"
''')
    out = tmp_path / "out"
    assert main(["bench", str(config), "--out", str(out), "--processes", "1", "--quiet"]) == 0
    (run,) = [json.loads(p.read_text()) for p in out.glob("*.json") if p.name != "summary.json"]
    assert run["spec"]["frontend"] == {"fps": 5} and run["metrics"]["n_queries"] == 18


def test_a_video_cut_short_warns_and_keeps_its_frames(tmp_path):
    """A Matroska file cut in half decodes up to the cut without an FFmpeg error; the loader
    says so (the file declares 10 s) and returns the frames before the cut, unchanged."""
    frames = np.random.default_rng(0).integers(0, 256, (100, 12, 20, 3), dtype=np.uint8)
    whole = write_video(tmp_path / "whole.mkv", frames, rate=10)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.warns(CatgraphWarning, match=r"declares 10\.00 s; it may be cut short"):
        t = load_video(cut)
    assert 0 < len(t.frames) < 100
    np.testing.assert_array_equal(t.frames, frames[: len(t.frames)])
    with pytest.warns(CatgraphWarning, match="cut short"):  # also when fps keeps fewer of them
        assert len(load_video(cut, fps=2).frames) < len(t.frames)


def test_a_whole_video_does_not_warn(tmp_path):
    frames = np.random.default_rng(1).integers(0, 256, (30, 12, 20, 3), dtype=np.uint8)
    for rate in (10, Fraction(30000, 1001)):
        path = write_video(tmp_path / f"v{float(rate):.0f}.mkv", frames, rate=rate)
        with warnings.catch_warnings():
            warnings.simplefilter("error", CatgraphWarning)
            assert len(load_video(path).frames) == 30 and len(load_video(path, fps=3).frames) > 0


def test_a_folder_of_videos_names_them(tmp_path):
    """A folder given where a video was meant: the error names the video to give instead."""
    frames = np.random.default_rng(2).integers(0, 256, (4, 12, 20, 3), dtype=np.uint8)
    one = tmp_path / "one"
    one.mkdir()
    write_video(one / "drive.mkv", frames)
    with pytest.raises(DataNotFoundError, match=r"holds no PNG or JPG images.*It holds the video drive\.mkv: give "
                                                r"that file itself"):
        load_traverse(one)
    for name in ("a.mp4", "b.mkv", "c.webm", "d.avi"):
        (one / name).write_bytes(b"")
    with pytest.raises(DataNotFoundError, match=r"It holds 5 videos \(a\.mp4, b\.mkv, c\.webm …\)"):
        load_traverse(one)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DataNotFoundError, match=r"holds no PNG or JPG images; give a folder of frames\.$"):
        load_traverse(empty)
