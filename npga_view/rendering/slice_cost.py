"""`SliceCost`: how many sorted splats the next slice of a budgeted draw may take, from what they will cost.

A slice's time on a software GL is vertex work per splat plus fragment work per covered pixel, and both vary
along the sorted order: a head's back-to-front order meets the large shoulder and hair splats first and the
small facial ones later. Sizing the next slice from the rate of the last one (the earlier rule) therefore
overshot a 25 ms budget by 2-3x where the order turned from small splats to large ones (measured on a LAM
avatar: slices of 8k splats took 60-80 ms, p90 of the UI frame's splat section 78 ms).

Per image, `begin` takes each visible splat's estimated screen footprint in sorted order (the 3-sigma extent
of its largest axis projected at its depth, clipped to the image: computed on the CPU in O(N) from what the
sort already has). The time of a slice is modelled as ``ms = a * splats + b * megapixels`` (footprints summed),
fitted by least squares with forgetting over the slices drawn (`record`); `count` returns the longest run of the
order predicted to fit the remaining budget.
"""

from __future__ import annotations

import numpy as np

#: Fewest splats in a slice (a draw call's own cost); most (the renderer's buffers).
MIN_SLICE, MAX_SLICE = 512, 1 << 24
FORGET = 0.85  # weight of the history at each new slice
_PRIOR = np.array([2e-3, 8.0])  # ms per splat, ms per megapixel: llvmpipe on 2 cores, before any slice is timed
#: the same for the latent pass (quads into two to eight float targets; the demo's two: ~30 ms per megapixel)
LATENT_PRIOR = (2e-3, 32.0)


def footprints(z: np.ndarray, radius: np.ndarray, fx: float, fy: float, width: int, height: int) -> np.ndarray:
    """Estimated pixels covered by splats at view depths `z` with largest standard deviation `radius` (world
    units): the 3-sigma square's area, clipped to the image."""
    inv = 6.0 / np.maximum(z, 1e-6)
    w = np.minimum(radius * (fx * inv), 2.0 * width) + 1.0
    h = np.minimum(radius * (fy * inv), 2.0 * height) + 1.0
    return np.minimum(w * h, float(width * height))


class SliceCost:
    """See the module docstring. One per pass of a renderer; `begin` per image, `count` before and `record` after
    a slice. `prior`: (ms per splat, ms per megapixel) before any slice is timed."""

    def __init__(self, prior: tuple[float, float] | None = None) -> None:
        start = _PRIOR if prior is None else np.array(prior, dtype=np.float64)
        self._gram = np.diag([1e6, 1e-2]) * 1e-3  # weighted normal equations of (splats, Mpx) -> ms, a weak prior
        self._rhs = self._gram @ start
        self.coef = start.copy()
        self._cum: np.ndarray | None = None  # cumulative Mpx along the sorted order (len N + 1)
        self._cost: np.ndarray | None = None  # predicted ms of positions 0..i (len N + 1), for the current coef

    def begin(self, pixels: np.ndarray | None) -> None:
        """A new image whose sorted splats cover `pixels` each (None: unknown, slices by count alone)."""
        self._cum = None if pixels is None else np.concatenate([[0.0], np.cumsum(pixels, dtype=np.float64) / 1e6])
        self._cost = None

    def _predicted(self) -> np.ndarray | None:
        if self._cum is None:
            return None
        if self._cost is None:
            self._cost = self.coef[0] * np.arange(len(self._cum)) + self.coef[1] * self._cum
        return self._cost

    def count(self, first: int, total: int, budget_ms: float) -> int:
        """Splats from sorted position `first` predicted to take `budget_ms` (at least `MIN_SLICE`)."""
        cost = self._predicted()
        left = total - first
        if cost is None or len(cost) != total + 1:
            n = int(max(budget_ms, 0.0) / max(self.coef[0] + self.coef[1] * 1e-4, 1e-6))
        else:
            n = int(np.searchsorted(cost, cost[first] + max(budget_ms, 0.0), side="right")) - 1 - first
        return int(min(left, MAX_SLICE, max(MIN_SLICE, n)))

    def record(self, first: int, count: int, ms: float) -> None:
        """A slice of `count` splats from `first` took `ms`: refit the model."""
        if self._cum is None or first + count >= len(self._cum) or count <= 0 or not ms > 0:
            return
        x = np.array([float(count), self._cum[first + count] - self._cum[first]])
        self._gram = FORGET * self._gram + np.outer(x, x)
        self._rhs = FORGET * self._rhs + x * ms
        try:
            coef = np.linalg.solve(self._gram, self._rhs)
        except np.linalg.LinAlgError:
            return
        if np.all(np.isfinite(coef)):
            self.coef = np.maximum(coef, [1e-5, 0.0])
            self._cost = None

    def predict(self, first: int, count: int) -> float | None:
        """Predicted ms of a slice (None without footprints)."""
        cost = self._predicted()
        if cost is None or first + count >= len(cost):
            return None
        return float(cost[first + count] - cost[first])
