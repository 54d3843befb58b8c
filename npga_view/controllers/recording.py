"""`Recorder`: the View panel's "Record MP4": what the splat view shows, as an H.264 MP4 that plays at the
speed it was recorded.

Each UI frame is read from the window and stamped with its wall-clock time since the first recorded frame
(variable frame rate: a frame lasts until the next one, the last one until Stop), so a recording made while
the UI draws 5 frames a second plays as long as one made at 60. Encoding runs in a thread (PyAV releases the
GIL while it encodes); when it falls more than `MAX_QUEUED` frames behind, the newest frame is dropped, which
only lets the previous one stay on screen longer: the timing stays right.
"""

from __future__ import annotations

import datetime as _dt
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from npga_view.video import VideoWriter, even_size

MAX_QUEUED = 16  # frames waiting for the encoder (~21 MB at 550 x 802)
_STOP = None


class Recorder:
    """Records the splat view; `read_view` returns the view's RGB pixels (top row first)."""

    def __init__(self, read_view: Callable[[], np.ndarray], folder: str | Path = ".",
                 clock: Callable[[], float] = time.perf_counter):
        self._read_view = read_view
        self._folder = Path(folder)
        self._clock = clock
        self._writer: VideoWriter | None = None
        self._queue: queue.Queue = queue.Queue(MAX_QUEUED)
        self._thread: threading.Thread | None = None
        self._t0: float | None = None
        self._error: BaseException | None = None
        self.path: str | None = None
        self.error: str | None = None  # why the last recording failed
        self.frames = 0  # frames handed to the encoder
        self.dropped = 0  # frames dropped because the encoder was behind

    @property
    def recording(self) -> bool:
        return self._writer is not None

    def toggle_reported(self, size: tuple[int, int], report) -> None:
        """`toggle`, its errors (and the encoder's) as one line each to `report` (the window's error list)."""
        try:
            self.toggle(size)
        except (OSError, ValueError) as e:
            report(f"Record MP4: {e}")
        if self.error:
            report(f"Record MP4: {self.error}")
            self.error = None

    def toggle(self, size: tuple[int, int]) -> bool:
        """Start recording a view of `size` (w, h) or stop the recording; returns whether it now records.

        Raises OSError (with the file named) when the video cannot be written."""
        if self._writer is not None:
            self.stop()
            return False
        w, h = even_size(*size)
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        path = self._folder / f"npga-view-{stamp}.mp4"
        self._writer = VideoWriter(path, w, h, fps=None, preset="veryfast")
        self.path, self.frames, self.dropped, self._error, self.error = str(path), 0, 0, None, None
        self._queue = queue.Queue(MAX_QUEUED)
        self._thread = threading.Thread(target=self._encode, args=(self._writer, self._queue), daemon=True,
                                        name="npga-recorder")
        self._thread.start()
        self._t0 = None  # the video starts with its first frame
        return True

    def frame(self) -> None:
        """Append the view as drawn this frame, stamped with the time since the first recorded frame."""
        if self._writer is None:
            return
        now = self._clock()
        if self._t0 is None:
            self._t0 = now
        t = now - self._t0
        try:
            self._queue.put_nowait((self._read_view(), t))
            self.frames += 1
        except queue.Full:
            self.dropped += 1

    def stop(self) -> str | None:
        """Finish the video (waits for the encoder); returns its path, or None when it failed (`error` says
        why, naming the file)."""
        if self._writer is None:
            return None
        end = self._clock() - self._t0 if self._t0 is not None else 0.0
        self._queue.put((_STOP, end))
        thread = self._thread
        assert thread is not None  # started with the writer
        thread.join()
        self._writer, self._thread = None, None
        if self._error is not None:
            self.error = str(self._error)
            return None
        return self.path

    def _encode(self, writer: VideoWriter, q: queue.Queue) -> None:
        failed = False
        while True:
            img, t = q.get()
            if img is _STOP:
                break
            if failed:
                continue
            try:
                writer.write(img, t)
            except (OSError, ValueError) as e:
                self._error, failed = e, True
                writer.abort()
        if not failed:
            try:
                writer.close(end=t)
            except OSError as e:
                self._error = e
