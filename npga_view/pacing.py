"""`FramePacing`: the window loop's clock: UI frames stepped and drawn, the UI rate, whether a frame needs drawing
at all, and how long a quiet loop waits for input."""

from __future__ import annotations

import time


class FramePacing:
    """`idle_wait_s`: how long the frame after a quiet one waits for input (0: the loop spins)."""

    def __init__(self, idle_wait_s: float = 1.0 / 30.0) -> None:
        self.idle_wait_s = idle_wait_s
        self.was_quiet = False  # the last frame had nothing to draw until something arrives
        self.frames = 0  # UI frames stepped
        self.presented = 0  # frames drawn into the window (the others were the frame on screen)
        self.fps = 0.0  # UI frames per second over the last second
        self._last_t = time.perf_counter()
        self._times: list[float] = []
        self._key: tuple | None = None  # what the frame on screen showed
        self._drawn_t = -1e9  # when it was drawn

    def wait_s(self) -> float:
        """How long this frame waits for input before it starts."""
        return self.idle_wait_s if self.was_quiet else 0.0

    def tick(self) -> float:
        """A UI frame starts: seconds since the last one (the UI rate is updated)."""
        now = time.perf_counter()
        dt, self._last_t = now - self._last_t, now
        self._times = [t for t in self._times if now - t < 1.0] + [now]
        self.fps = len(self._times) / max(1e-6, now - self._times[0]) if len(self._times) > 1 else 0.0
        return dt

    def due(self, key: tuple | None, always: bool, at_least_s: float) -> bool:
        """Whether to draw a frame showing `key` (None: changes every frame): unless it is the frame on screen,
        drawn less than `at_least_s` ago, and nothing asks for every frame (`always`: recording). A frame to draw
        is counted as drawn."""
        now = time.perf_counter()
        if key is not None and key == self._key and not always and now - self._drawn_t < at_least_s:
            return False
        self._key, self._drawn_t = key, now
        self.presented += 1
        return True
