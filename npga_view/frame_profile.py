"""`FrameProfile`: where the window's UI frames spend their wall time, section by section.

`ViewerApp.step` marks the end of each section; the stats overlay shows the averages over the last second and
`npga-view bench --window` reports the medians while orbiting and playing. Sections, in frame order:

- wait: glfw's events, and after a quiet frame the wait for input (idle time, not work: `lines` show it apart);
- panels: imgui's new frame, the side panel's widgets, the actions they sent, edits and keyframes;
- posing: Live Link, the pose controller (worker results, previews, playback), inspection refreshes;
- splats: clearing, the budgeted splat draw (`DrawScheduler.frame`), the CNN refinement or the Compare view, and
  presenting the image into the window;
- stats: the display snapshot, the stats overlay's widgets, the recorder;
- ui: imgui's draw lists rendered (on a software GL only queued: drawn at the swap);
- swap: the buffers swapped; on llvmpipe this draws what was queued (the image presented, imgui) and copies the
  window's pixels to the X server.
"""

from __future__ import annotations

import time
from collections import deque

SECTIONS = ("wait", "panels", "posing", "splats", "stats", "ui", "swap")
IDLE = "wait"  # the section that is idle time, not work


class FrameProfile:
    """Milliseconds per section of the last UI frame (`last`) and of the frames of the last `window_s` seconds."""

    def __init__(self, window_s: float = 1.0) -> None:
        self.window_s = window_s
        self.last: dict[str, float] = {}
        self._current: dict[str, float] = {}
        self._t = 0.0
        self._recent: deque[tuple[float, dict[str, float]]] = deque()

    def start(self) -> None:
        """A UI frame begins."""
        self._t = time.perf_counter()
        self._current = {}

    def mark(self, section: str) -> None:
        """The time since the last mark (or the start) belongs to `section`."""
        now = time.perf_counter()
        self._current[section] = self._current.get(section, 0.0) + (now - self._t) * 1e3
        self._t = now

    def end(self) -> None:
        """The frame ends: it becomes `last` and joins the recent frames."""
        self.last = self._current
        now = time.perf_counter()
        self._recent.append((now, self._current))
        while self._recent and now - self._recent[0][0] > self.window_s:
            self._recent.popleft()

    def averages(self) -> dict[str, float]:
        """Mean milliseconds per section over the recent frames (sections in frame order; empty before a frame)."""
        frames = [f for _, f in self._recent]
        if not frames:
            return {}
        return {s: sum(f.get(s, 0.0) for f in frames) / len(frames) for s in SECTIONS}

    def lines(self) -> list[str]:
        """Two short lines for the stats overlay (as narrow as its other lines): the mean work of a UI frame and
        the wait for input, then the work by section, e.g. ['UI frame 31.2 ms + 0.1 ms waiting for input',
        'panels 2.0 posing 0.2 splats 19.0 stats 0.1 ui 0.3 swap 9.5']; none before a frame."""
        avg = self.averages()
        if not avg:
            return []
        work = {s: v for s, v in avg.items() if s != IDLE}
        return [f"UI frame {sum(work.values()):.1f} ms + {avg[IDLE]:.1f} ms waiting for input",
                " ".join(f"{s} {v:.1f}" for s, v in work.items())]
