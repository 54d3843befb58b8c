"""`Playback`: which sequence frame to show, following the wall clock or stepping every frame.

Pure logic (no window): the app calls `advance(dt, shown)` once per UI frame and asks the engine for the
returned frame's code. Frames that the clock passes before the dynamics could show them count as skipped.
"""

from __future__ import annotations

import math
from collections import deque

from npga_view.state import Timeline


class Playback:
    """Tracks the current frame, the achieved display rate and the skipped count."""

    def __init__(self, n_frames: int, fps: float):
        self.n_frames = n_frames
        self.fps = fps
        self.skipped = 0
        self._last_shown: int | None = None
        self._shown_times: deque[float] = deque(maxlen=120)
        self._clock = 0.0

    def frame_at(self, time_s: float) -> int:
        return min(self.n_frames - 1, max(0, int(math.floor(time_s * self.fps + 1e-6))))

    def advance(self, tl: Timeline, dt: float, last_frame_shown: bool) -> int:
        """Move `tl.time_s` by dt (if playing) and return the frame to request.

        In every-frame mode the time moves one frame only once the previous frame was shown.
        """
        duration = self.n_frames / self.fps
        if tl.playing:
            if tl.every_frame:
                if last_frame_shown:
                    tl.time_s = (self.frame_at(tl.time_s) + 1) / self.fps
            else:
                tl.time_s += dt * tl.speed
            if tl.time_s >= duration:
                if tl.loop:
                    tl.time_s %= duration
                else:
                    tl.time_s = (self.n_frames - 1) / self.fps
                    tl.playing = False
            elif tl.time_s < 0:
                tl.time_s = duration + tl.time_s if tl.loop else 0.0
        return self.frame_at(tl.time_s)

    def shown(self, frame: int, now: float, playing: bool) -> None:
        """Record that `frame` reached the screen at time `now` (seconds, monotonic)."""
        if playing and self._last_shown is not None:
            step = (frame - self._last_shown) % self.n_frames
            if step > 1:
                self.skipped += step - 1
        if playing:
            self._shown_times.append(now)
        self._last_shown = frame

    def achieved_fps(self) -> float:
        """Distinct sequence frames shown per second over the last couple of seconds."""
        t = self._shown_times
        if len(t) < 2 or t[-1] - t[0] <= 0:
            return 0.0
        return (len(t) - 1) / (t[-1] - t[0])

    def reset_stats(self) -> None:
        self.skipped = 0
        self._shown_times.clear()
        self._last_shown = None
