"""Temporal smoothing of expression-code sequences and a jitter measure.

Both filters are causal and run over the whole table at once (T x D is small), so scrubbing a smoothed
sequence shows exactly what playback shows.
"""

from __future__ import annotations

import math

import numpy as np


def exponential(codes: np.ndarray, alpha: float) -> np.ndarray:
    """y_t = alpha x_t + (1 - alpha) y_{t-1}; alpha in (0, 1], 1 = no smoothing."""
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must be in (0, 1], got {alpha}")
    x = np.asarray(codes, np.float64)
    y = np.empty_like(x)
    if len(x):
        y[0] = x[0]
    for t in range(1, len(x)):
        y[t] = alpha * x[t] + (1.0 - alpha) * y[t - 1]
    return y.astype(np.float32)


def _alpha(cutoff: float | np.ndarray, dt: float) -> float | np.ndarray:
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


def one_euro(codes: np.ndarray, fps: float, min_cutoff: float = 1.0, beta: float = 0.5,
             d_cutoff: float = 1.0) -> np.ndarray:
    """The 1-euro filter (Casiez et al. 2012) per dimension: the cutoff rises with the speed of change,
    so slow jitter is removed while fast motion keeps little lag."""
    if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0 or fps <= 0:
        raise ValueError("one_euro needs min_cutoff > 0, d_cutoff > 0, beta >= 0, fps > 0")
    x = np.asarray(codes, np.float64)
    y = np.empty_like(x)
    if not len(x):
        return y.astype(np.float32)
    dt = 1.0 / fps
    y[0] = x[0]
    dx = np.zeros(x.shape[1])
    a_d = _alpha(d_cutoff, dt)
    for t in range(1, len(x)):
        raw_dx = (x[t] - y[t - 1]) / dt
        dx = a_d * raw_dx + (1.0 - a_d) * dx
        a = _alpha(min_cutoff + beta * np.abs(dx), dt)
        y[t] = a * x[t] + (1.0 - a) * y[t - 1]
    return y.astype(np.float32)


def jitter(codes: np.ndarray) -> float:
    """RMS norm of the second difference per frame (0 for codes moving linearly)."""
    x = np.asarray(codes, np.float64)
    if len(x) < 3:
        return 0.0
    acc = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return float(np.sqrt(np.mean(np.sum(acc * acc, axis=1))))


METHODS = ("none", "exponential", "one_euro")
#: Range of a bake's memory budget in MB accepted from a file (0 made the viewer wait for a bake forever).
BAKE_BUDGET_MB = (16.0, float(1 << 20))


def check_playback(timeline: object) -> None:
    """ValueError for playback settings read from a file (a session's timeline: `smoothing`, `smooth_alpha`,
    `euro_min_cutoff`, `euro_beta`, `bake_budget_mb`) that `smooth` or the bake would refuse later."""
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


def smooth(codes: np.ndarray, method: str, fps: float, alpha: float = 0.5, min_cutoff: float = 1.0,
           beta: float = 0.5) -> np.ndarray:
    """Dispatch by name: "none", "exponential" or "one_euro"."""
    if method == "none":
        return np.asarray(codes, np.float32)
    if method == "exponential":
        return exponential(codes, alpha)
    if method == "one_euro":
        return one_euro(codes, fps, min_cutoff, beta)
    raise ValueError(f"unknown smoothing {method!r}")


class OneEuro:
    """The 1-euro filter of `one_euro` one sample at a time, for live streams with uneven intervals: `step`
    takes a sample (K,) and the seconds since the last one; `reset` forgets the past."""

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.5, d_cutoff: float = 1.0):
        if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0:
            raise ValueError("OneEuro needs min_cutoff > 0, d_cutoff > 0, beta >= 0")
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self.reset()

    def reset(self) -> None:
        self._y: np.ndarray | None = None
        self._dx: np.ndarray | None = None

    def step(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if self._y is None or self._dx is None or not dt > 0:
            self._y, self._dx = x.copy(), np.zeros_like(x)
            return self._y.astype(np.float32)
        raw_dx = (x - self._y) / dt
        a_d = _alpha(self.d_cutoff, dt)
        self._dx = a_d * raw_dx + (1.0 - a_d) * self._dx
        a = _alpha(self.min_cutoff + self.beta * np.abs(self._dx), dt)
        self._y = a * x + (1.0 - a) * self._y
        return self._y.astype(np.float32)
