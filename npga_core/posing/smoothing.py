"""Temporal smoothing of expression codes, for whole sequences and live streams alike, and a jitter measure.

One causal filter (`SmoothingFilter`) does both: `step` takes one sample and the seconds since the last one (a
Live Link stream, whose packets come at uneven intervals), `run` takes a whole (T, D) table at a fixed rate by
stepping through its rows (a sequence on the timeline: T x D is small, so scrubbing a smoothed sequence shows
exactly what playback shows). `Smoothing` says how (`METHODS`: none, exponential, the 1-euro filter) and
`Smoothing.of` reads it from the window's timeline settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The smoothing methods, in the order the window offers them.
METHODS = ("none", "exponential", "one_euro")
#: Range of a bake's memory budget in MB accepted from a file (0 made the viewer wait for a bake forever).
BAKE_BUDGET_MB = (16.0, float(1 << 20))


def _within(value: float, lo: float, hi: float, default: float) -> float:
    """`value` as a float clamped to [lo, hi]; `default` when it is not a finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return min(max(v, lo), hi) if math.isfinite(v) else default


@dataclass(frozen=True)
class Smoothing:
    """How codes are smoothed: `method` (one of `METHODS`); exponential: y_t = alpha x_t + (1 - alpha) y_{t-1},
    alpha in (0, 1] (1 = no smoothing); one_euro (Casiez et al. 2012): the cutoff `min_cutoff` Hz rises by `beta`
    times the speed of change (whose own low-pass cutoff is `d_cutoff`), so slow jitter goes while fast motion
    keeps little lag. Hashable: equal settings are one key (a bake is of a sequence and its smoothing)."""

    method: str = "none"
    alpha: float = 0.5
    min_cutoff: float = 1.0
    beta: float = 0.5
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown smoothing {self.method!r}; one of {', '.join(METHODS)}")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if not (self.min_cutoff > 0 and self.d_cutoff > 0 and self.beta >= 0):
            raise ValueError("one_euro needs min_cutoff > 0, d_cutoff > 0, beta >= 0")

    @classmethod
    def of(cls, timeline: object) -> Smoothing:
        """The window's timeline settings (`smoothing`, `smooth_alpha`, `euro_min_cutoff`, `euro_beta`), each
        clamped into its valid range (a value typed into a slider may lie outside it), so that the frame loop
        never fails on them; an unknown method is "none"."""
        method = getattr(timeline, "smoothing", "none")
        return cls(method if method in METHODS else "none",
                   _within(getattr(timeline, "smooth_alpha", 0.5), 1e-3, 1.0, 0.5),
                   _within(getattr(timeline, "euro_min_cutoff", 1.0), 1e-6, 1e4, 1.0),
                   _within(getattr(timeline, "euro_beta", 0.5), 0.0, 1e4, 0.5))


def _alpha(cutoff: float | np.ndarray, dt: float) -> float | np.ndarray:
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class SmoothingFilter:
    """The causal filter of `settings`, one sample at a time (`step`) or over a whole table (`run`); the state is
    float64, every output float32. `reset` forgets the past; so does a sample with `dt <= 0` (the stream restarted,
    e.g. its clock jumped) or of another shape than the last."""

    def __init__(self, settings: Smoothing = Smoothing()) -> None:
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        self._y: np.ndarray | None = None  # the last output
        self._dx: np.ndarray | None = None  # one_euro: the low-passed speed of change

    def step(self, x: np.ndarray, dt: float) -> np.ndarray:
        """The filtered sample (K,) float32 for sample `x` (K,) taken `dt` seconds after the last one."""
        x = np.asarray(x, np.float64)
        s = self.settings
        if s.method == "none":
            return x.astype(np.float32)
        if self._y is None or self._dx is None or self._y.shape != x.shape or not dt > 0:
            self._y, self._dx = x.copy(), np.zeros_like(x)
            return self._y.astype(np.float32)
        if s.method == "exponential":
            self._y = s.alpha * x + (1.0 - s.alpha) * self._y
            return self._y.astype(np.float32)
        raw_dx = (x - self._y) / dt
        a_d = _alpha(s.d_cutoff, dt)
        self._dx = a_d * raw_dx + (1.0 - a_d) * self._dx
        a = _alpha(s.min_cutoff + s.beta * np.abs(self._dx), dt)
        self._y = a * x + (1.0 - a) * self._y
        return self._y.astype(np.float32)

    def run(self, codes: np.ndarray, fps: float) -> np.ndarray:
        """A whole (T, D) table sampled at `fps`, from a fresh start: (T, D) float32, row t = `step(codes[t],
        1 / fps)` (so a sequence smoothed at once equals the same frames streamed at its rate)."""
        if self.settings.method == "none":
            return np.array(codes, np.float32)
        if not fps > 0:
            raise ValueError(f"smoothing needs fps > 0, got {fps}")
        x = np.asarray(codes, np.float64)
        self.reset()
        out = np.empty(x.shape, np.float32)
        for t in range(len(x)):
            out[t] = self.step(x[t], 1.0 / fps)
        self.reset()
        return out


def jitter(codes: np.ndarray) -> float:
    """RMS norm of the second difference per frame (0 for codes moving linearly)."""
    x = np.asarray(codes, np.float64)
    if len(x) < 3:
        return 0.0
    acc = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return float(np.sqrt(np.mean(np.sum(acc * acc, axis=1))))


def check_playback(timeline: object) -> None:
    """ValueError for playback settings read from a file (a session's timeline: `smoothing`, `smooth_alpha`,
    `euro_min_cutoff`, `euro_beta`, `bake_budget_mb`) that the smoothing or the bake would refuse later."""
    method = getattr(timeline, "smoothing", "none")
    if method not in METHODS:
        raise ValueError(f"timeline.smoothing {str(method)[:40]!r} is not one of {', '.join(METHODS)}")
    alpha, cutoff, beta = (float(getattr(timeline, k, d)) for k, d in
                           (("smooth_alpha", 0.5), ("euro_min_cutoff", 1.0), ("euro_beta", 0.5)))
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"timeline.smooth_alpha {alpha:.4g} is not in (0, 1]")
    if not (0.0 < cutoff <= 1e4 and 0.0 <= beta <= 1e4):
        raise ValueError(f"timeline.euro_min_cutoff {cutoff:.4g} must be in (0, 1e4], euro_beta {beta:.4g} in [0, 1e4]")
    budget = float(getattr(timeline, "bake_budget_mb", BAKE_BUDGET_MB[0]))
    if not BAKE_BUDGET_MB[0] <= budget <= BAKE_BUDGET_MB[1]:
        raise ValueError(f"timeline.bake_budget_mb {budget:.4g} is not in [{BAKE_BUDGET_MB[0]:g}, "
                         f"{BAKE_BUDGET_MB[1]:g}]")
