"""`SequenceCodes`: the open sequence's codes as the Timeline panel smooths them, recomputed when the sequence
or the smoothing changes; `key` says what they are of (a bake is usable only while its key is current)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from npga_core.files.sequences import ExpressionSequence
from npga_core.posing.smoothing import Smoothing, SmoothingFilter, jitter
from npga_view.state import ViewerState


class SequenceCodes:
    """Handed the viewer state and a getter of the open sequence (None without one)."""

    def __init__(self, state: ViewerState, sequence: Callable[[], ExpressionSequence | None]):
        self._state = state
        self._sequence = sequence
        self.codes: np.ndarray | None = None  # the sequence's smoothed codes
        self.smooth_key: tuple | None = None  # what `codes` were smoothed from and how
        self.jitter_raw = self.jitter_smoothed = 0.0  # before and after smoothing

    def forget(self) -> None:
        """The sequence was closed or replaced."""
        self.codes = None
        self.smooth_key = None

    def get(self) -> np.ndarray:
        """The open sequence's codes, smoothed as the Timeline panel says (recomputed when that changes)."""
        tl, seq = self._state.timeline, self._sequence()
        if seq is None:
            raise ValueError("no sequence is open")
        settings = Smoothing.of(tl)
        key = (id(seq), settings)
        if key != self.smooth_key or self.codes is None:
            self.codes = SmoothingFilter(settings).run(seq.codes, seq.fps)
            self.jitter_raw = jitter(seq.codes)
            self.jitter_smoothed = jitter(self.codes)
            self.smooth_key = key
        return self.codes

    def key(self) -> tuple | None:
        """What a bake of the timeline would be of (sequence and smoothing), None without a sequence."""
        if self._sequence() is None:
            return None
        self.get()
        return self.smooth_key
