"""`Recorder`: the View panel's "Record MP4": writes what the splat view shows, one video frame per UI frame."""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable

import numpy as np


class Recorder:
    """Records the splat view; `read_view` returns the view's RGB pixels (top row first)."""

    def __init__(self, read_view: Callable[[], np.ndarray]):
        self._read_view = read_view
        self._writer = None
        self._size = (0, 0)
        self.path: str | None = None

    @property
    def recording(self) -> bool:
        return self._writer is not None

    def toggle(self, size: tuple[int, int]) -> bool:
        """Start recording a view of `size` (w, h) or stop the recording; returns whether it now records."""
        import cv2

        if self._writer is not None:
            self.stop()
            return False
        w, h = size[0] // 2 * 2, size[1] // 2 * 2
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        self.path = f"npga-view-{stamp}.mp4"
        self._writer = cv2.VideoWriter(self.path, cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (w, h))
        self._size = (w, h)
        return True

    def frame(self) -> None:
        """Append the view as drawn this frame."""
        if self._writer is None:
            return
        img = self._read_view()
        w, h = self._size
        self._writer.write(np.ascontiguousarray(img[:h, :w, ::-1]))

    def stop(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
