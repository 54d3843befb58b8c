"""H.264 MP4 video (npga_view/video.py), the window recorder's wall-clock stamps and `render --out x.mp4`, each
file read back with PyAV (the library that wrote it; av.open / decode as in PyAV's own docs and tests)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from npga_core.files.sequences import ExpressionSequence
from npga_view.controllers.recording import Recorder
from npga_view.video import VideoError, VideoWriter, even_size, read_video_info


def _frames(n: int, h: int, w: int) -> list[np.ndarray]:
    """Frames whose mean grey level tells them apart after lossy coding (0, 20, 40, ...)."""
    return [np.full((h, w, 3), 20 * i, np.uint8) for i in range(n)]


def _grey_levels(path) -> list[float]:
    import av

    with av.open(str(path)) as c:
        return [float(f.to_ndarray(format="rgb24").mean()) for f in c.decode(video=0)]


def test_constant_rate_file_plays_at_its_fps(tmp_path):
    out = tmp_path / "c.mp4"
    with VideoWriter(out, 64, 48, fps=12.5) as w:
        for f in _frames(10, 48, 64):
            w.write(f)
    info = read_video_info(out)
    assert (info["codec"], info["pix_fmt"], info["width"], info["height"]) == ("h264", "yuv420p", 64, 48)
    assert info["frames"] == 10
    assert info["duration"] == pytest.approx(10 / 12.5, abs=1e-3)
    assert np.allclose(np.diff(info["times"]), 1 / 12.5, atol=1e-3)
    assert np.allclose(_grey_levels(out), [20 * i for i in range(10)], atol=3)  # in order, none lost


def test_colours_come_back_and_the_file_gets_the_usual_permissions(tmp_path):
    """BT.709 conversion and tags agree, so a decoder that reads the tags returns the colours written."""
    import av

    out = tmp_path / "colour.mp4"
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:, :32] = (200, 100, 50)
    rgb[:, 32:] = (30, 160, 220)
    with VideoWriter(out, 64, 48, fps=25) as w:
        w.write(rgb)
    with av.open(str(out)) as c:
        cc = c.streams.video[0].codec_context
        assert (cc.colorspace, cc.color_primaries, cc.color_trc, cc.color_range) == (1, 1, 1, 1)  # BT.709, tv
        back = next(c.decode(video=0)).to_ndarray(format="rgb24").astype(int)
    assert np.abs(back[8:40, 4:28] - (200, 100, 50)).max() <= 4
    assert np.abs(back[8:40, 36:60] - (30, 160, 220)).max() <= 4
    if os.name == "posix":
        mask = os.umask(0)
        os.umask(mask)
        assert out.stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600


def test_odd_sizes_become_even_and_frames_are_cropped_or_padded(tmp_path):
    assert even_size(65, 49) == (64, 48)
    with pytest.raises(ValueError, match="2 x 2"):
        even_size(1, 10)
    out = tmp_path / "odd.mp4"
    with VideoWriter(out, 65, 49, fps=25) as w:
        w.write(np.full((49, 65, 3), 200, np.uint8))  # larger than 64 x 48: cropped
        w.write(np.full((20, 30, 3), 200, np.uint8))  # smaller: padded with black
    info = read_video_info(out)
    assert (info["width"], info["height"], info["frames"]) == (64, 48, 2)
    full, padded = _grey_levels(out)
    assert full > 190 and padded == pytest.approx(200 * (20 * 30) / (64 * 48), abs=8)


def test_variable_rate_stamps_are_the_given_times(tmp_path):
    out = tmp_path / "v.mp4"
    stamps = [0.0, 0.1, 0.35, 0.36, 0.9]
    w = VideoWriter(out, 64, 48)
    for f, t in zip(_frames(5, 48, 64), stamps, strict=True):
        w.write(f, t)
    w.close(end=1.5)
    info = read_video_info(out)
    assert info["codec"] == "h264" and info["frames"] == 5
    assert np.allclose(info["times"], stamps, atol=1e-4)
    assert info["duration"] == pytest.approx(1.5, abs=1e-3)  # the last frame lasts until `end`


def test_equal_stamps_still_increase_and_a_time_is_required(tmp_path):
    w = VideoWriter(tmp_path / "v.mp4", 32, 32)
    with pytest.raises(ValueError, match="time"):
        w.write(np.zeros((32, 32, 3), np.uint8))
    for t in (0.0, 0.0, 0.0):
        w.write(np.zeros((32, 32, 3), np.uint8), t)
    w.close(end=0.1)
    times = read_video_info(tmp_path / "v.mp4")["times"]
    assert len(times) == 3 and np.all(np.diff(times) > 0)


def test_failed_or_aborted_video_leaves_no_file(tmp_path):
    out = tmp_path / "x.mp4"
    with pytest.raises(RuntimeError), VideoWriter(out, 32, 32, fps=10) as w:
        w.write(np.zeros((32, 32, 3), np.uint8))
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(VideoError, match="no frames"):
        VideoWriter(out, 32, 32, fps=10).close()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="frame rate"):
        VideoWriter(out, 32, 32, fps=0)
    with pytest.raises(OSError, match="missing"):
        VideoWriter(tmp_path / "missing" / "x.mp4", 32, 32, fps=10)


def test_previous_file_survives_a_failed_write(tmp_path):
    out = tmp_path / "x.mp4"
    with VideoWriter(out, 32, 32, fps=10) as w:
        w.write(np.zeros((32, 32, 3), np.uint8))
    before = out.read_bytes()
    with pytest.raises(ValueError), VideoWriter(out, 32, 32, fps=10) as w:
        w.write(np.zeros((32, 32), np.uint8))  # not RGB
    assert out.read_bytes() == before


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_recorder_stamps_each_frame_with_its_wall_clock_time(tmp_path):
    """A UI running at an uneven rate: the video's frame times are the times the frames were drawn."""
    clock = _Clock()
    level = [0]
    rec = Recorder(lambda: np.full((61, 81, 3), level[0], np.uint8), folder=tmp_path, clock=clock)
    assert rec.toggle((81, 61)) and rec.recording
    drawn = [0.0, 0.2, 0.25, 1.0, 1.05, 1.1]  # seconds after the start: 5 fps, then 20 fps, after a stall
    for i, t in enumerate(drawn):
        clock.t = 100.0 + t
        level[0] = 30 * i
        rec.frame()
    clock.t = 100.0 + 1.3
    assert rec.stop() == rec.path and not rec.recording and rec.error is None
    info = read_video_info(rec.path)
    assert (info["codec"], info["width"], info["height"], info["frames"]) == ("h264", 80, 60, len(drawn))
    assert np.allclose(info["times"], drawn, atol=1e-4)
    assert info["duration"] == pytest.approx(1.3, abs=1e-3)
    assert np.allclose(_grey_levels(rec.path), [30 * i for i in range(len(drawn))], atol=3)


def test_recorder_reports_a_folder_it_cannot_write(tmp_path):
    rec = Recorder(lambda: np.zeros((8, 8, 3), np.uint8), folder=tmp_path / "gone")
    with pytest.raises(OSError, match="gone"):
        rec.toggle((8, 8))
    assert not rec.recording


def test_render_cli_writes_h264_at_the_sequence_fps(tmp_path, small_npga, small_avatar, ctx):
    from npga_view.cli.main import main

    rng = np.random.default_rng(0)
    codes = (small_avatar.expression.mean + 0.5 * rng.standard_normal((6, small_avatar.code_dim))).astype(np.float32)
    seq = tmp_path / "s.npzseq"
    ExpressionSequence(codes, 8.0, "six").save(seq)
    out = tmp_path / "s.mp4"
    assert main(["render", str(small_npga), "--sequence", str(seq), "--out", str(out),
                 "--width", "63", "--height", "47"]) == 0
    info = read_video_info(out)
    assert (info["codec"], info["pix_fmt"], info["width"], info["height"]) == ("h264", "yuv420p", 62, 46)
    assert info["frames"] == 6
    assert info["duration"] == pytest.approx(6 / 8.0, abs=1e-3)
