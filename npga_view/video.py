"""H.264 video in MP4 through PyAV: the one place npga-view encodes video.

Files play in browsers, on GitHub, in chat apps and slide tools: H.264 (libx264, which PyAV's wheels carry on
Linux, macOS and Windows), 8-bit yuv420p (BT.709, limited range, tagged), even width and height, no
B-frames, the index at the front (`+faststart`). Timestamps are real: a constant-rate writer (`fps`) stamps
frame i at i / fps; a variable-rate writer (`fps=None`) stamps each frame with the time it is given, and every
frame lasts until the next one (the last until `close(end)`), so a recording plays at the speed it was made.

The file is written under a temporary name in the target's folder and renamed when complete, like every save.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_core.files.atomic import move_into_place
from npga_core.files.untrusted import FPS_RANGE, shown

if TYPE_CHECKING:
    from av.container import OutputContainer
    from av.video.stream import VideoStream

CODEC = "libx264"
PIX_FMT = "yuv420p"
#: Clock of variable-rate files (the usual 90 kHz video clock).
VFR_TIME_BASE = Fraction(1, 90000)
BT709, MPEG_RANGE = 1, 1  # FFmpeg's AVCOL_SPC/PRI/TRC_BT709 and AVCOL_RANGE_MPEG (limited)


class VideoError(OSError):
    """The video could not be written (the message names the file)."""


def even_size(width: int, height: int) -> tuple[int, int]:
    """The largest even size within (width, height): yuv420p needs both even."""
    w, h = int(width) // 2 * 2, int(height) // 2 * 2
    if w < 2 or h < 2:
        raise ValueError(f"a video needs at least 2 x 2 pixels, got {width} x {height}")
    return w, h


def _rate(fps: float) -> Fraction:
    lo, hi = FPS_RANGE
    if not (np.isfinite(fps) and lo <= fps <= hi):  # 1e-300 would round to a rate of 0 (Fraction(1, 0))
        raise ValueError(f"video frame rate {fps:.6g}: must be in [{lo:g}, {hi:g}]")
    return Fraction(fps).limit_denominator(1001)


class VideoWriter:
    """Writes RGB frames (top row first, uint8) to an H.264 MP4 at `path`.

    `fps`: constant frame rate (frame i at i / fps); None: variable rate, `write(rgb, t)` with t in seconds.
    Frames larger than the video (its size is (width, height) rounded down to even) are cropped, smaller ones
    padded with black. `preset`/`crf` are libx264's speed/quality settings. Use as a context manager or call
    `close()`; on an error inside the `with` the partial file is removed.
    """

    def __init__(self, path: str | Path, width: int, height: int, fps: float | None = None, *,
                 preset: str = "medium", crf: int = 18):
        import av

        from npga_core.files.atomic import check_output

        self.path = check_output(path, "a video", make_parents=False)  # the output gate: no folder, FIFO, device
        self.size = even_size(width, height)
        self.fps = None if fps is None else _rate(fps)
        self.frames = 0
        self._last_t: int | None = None  # stamp of the newest frame, in time-base ticks
        self._pending: tuple[np.ndarray, int] | None = None  # variable rate: a frame waits for its duration
        # the temp name is ASCII: the encoder refuses names that are not valid UTF-8 (lone surrogates)
        fd, tmp = tempfile.mkstemp(prefix=".npga-video.", suffix=".tmp", dir=self.path.parent)
        os.close(fd)
        self._tmp = Path(tmp)
        try:
            container = av.open(str(self._tmp), "w", format="mp4", options={"movflags": "+faststart"})
            self._container: OutputContainer | None = container
            stream = cast("VideoStream", container.add_stream(CODEC, rate=self.fps or 30))
            stream.width, stream.height = self.size
            stream.pix_fmt = PIX_FMT
            stream.options = {"preset": preset, "crf": str(int(crf)), "bf": "0"}
            cc = stream.codec_context  # BT.709, limited range: what _encode converts to, tagged for players
            cc.colorspace = cc.color_primaries = cc.color_trc = BT709
            cc.color_range = MPEG_RANGE
            self.time_base = (1 / self.fps) if self.fps is not None else VFR_TIME_BASE
            stream.time_base = stream.codec_context.time_base = self.time_base
            self._stream = stream
        except Exception as e:
            self._tmp.unlink(missing_ok=True)
            raise VideoError(f"{shown(self.path)}: cannot write an H.264 video: {shown(str(e))}") from None
        self._durations: dict[int, int] = {}  # pts -> duration of the frames in the encoder
        self._last_duration = 0

    # -- writing ---------------------------------------------------------------------------------------
    def write(self, rgb: np.ndarray, t: float | None = None) -> None:
        """Append a frame; `t` (seconds from the start) is required at a variable rate, ignored otherwise."""
        frame = self._fit(rgb)
        if self.fps is not None:
            self._encode(frame, self.frames, 1)
            return
        if t is None:
            raise ValueError("a variable-rate video needs the time of each frame")
        ticks = round(float(t) / self.time_base)
        if self._last_t is not None:
            ticks = max(ticks, self._last_t + 1)  # strictly increasing
        if self._pending is not None:
            prev, prev_t = self._pending
            self._encode(prev, prev_t, ticks - prev_t)
        self._pending, self._last_t = (frame, ticks), ticks

    def close(self, end: float | None = None) -> Path:
        """Finish the file and move it into place; `end` (seconds) is when a variable-rate video ends (default:
        the last frame lasts as long as the one before it, or 1/30 s). Returns the path."""
        if self._container is None:
            return self.path
        try:
            if self._pending is not None:
                frame, t0 = self._pending
                if end is not None:
                    dur = max(1, round(float(end) / self.time_base) - t0)
                else:
                    dur = self._last_duration or round(Fraction(1, 30) / self.time_base)
                self._encode(frame, t0, dur)
                self._pending = None
            self._mux(self._stream.encode(None))
            self._container.close()
            self._container = None
            if self.frames == 0:
                raise VideoError(f"{shown(self.path)}: no frames were written")
            with open(self._tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            move_into_place(self._tmp, self.path)
        except BaseException as e:
            self._abort()
            if isinstance(e, VideoError | KeyboardInterrupt):
                raise
            raise VideoError(f"{shown(self.path)}: writing the video failed: {shown(str(e))}") from None
        return self.path

    def abort(self) -> None:
        """Stop without keeping the file."""
        self._abort()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abort()

    # -- internals -------------------------------------------------------------------------------------
    def _fit(self, rgb: np.ndarray) -> np.ndarray:
        img = np.asarray(rgb)
        if img.ndim != 3 or img.shape[2] < 3 or img.dtype != np.uint8:
            raise ValueError(f"video frames must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        w, h = self.size
        img = img[:h, :w, :3]
        if img.shape[:2] != (h, w):
            padded = np.zeros((h, w, 3), np.uint8)
            padded[:img.shape[0], :img.shape[1]] = img
            img = padded
        return np.ascontiguousarray(img)

    def _encode(self, rgb: np.ndarray, pts: int, duration: int) -> None:
        import av
        from av.video.reformatter import ColorRange, Colorspace

        frame = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(
            format=PIX_FMT, dst_colorspace=Colorspace.ITU709, dst_color_range=ColorRange.MPEG)
        frame.pts, frame.time_base = pts, self.time_base
        self._durations[pts] = self._last_duration = duration
        try:
            self._mux(self._stream.encode(frame))
        except av.FFmpegError as e:
            self._abort()
            raise VideoError(f"{shown(self.path)}: encoding failed: {shown(str(e))}") from None
        self.frames += 1

    def _mux(self, packets) -> None:
        for p in packets:
            # without B-frames packets come out in order; each carries its frame's real duration (the muxer
            # would otherwise guess the last one)
            if p.pts is not None:
                p.duration = self._durations.pop(p.pts, p.duration)
            container = self._container
            assert container is not None  # packets come only while the file is open
            container.mux(p)

    def _abort(self) -> None:
        if self._container is not None:
            with contextlib.suppress(Exception):
                self._container.close()
            self._container = None
        self._tmp.unlink(missing_ok=True)


def read_video_info(path: str | Path) -> dict:
    """Codec, pixel format, size, frame count, frame times (s) and duration (s) of a video, read back with
    PyAV (what the tests and `npga-view` checks use)."""
    import av

    with av.open(str(path)) as c:
        s = c.streams.video[0]
        times = [float(f.time) for f in c.decode(s)]
        duration = float(s.duration * s.time_base) if s.duration else (c.duration or 0) / av.time_base  # type: ignore[operator]
        return {"codec": s.codec_context.name, "pix_fmt": s.codec_context.pix_fmt, "width": s.width,
                "height": s.height, "frames": len(times), "times": times, "duration": duration}
