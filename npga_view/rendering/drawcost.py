"""Which colour-pass path draws an image cheaper: GL points (a quarter of the vertex work, no triangle set-up) or
instanced quads (fewer fragments: a point shades the axis-aligned square around its splat's ellipse, a quad only the
oriented rectangle).

On llvmpipe points win where vertex work dominates (small images: the demo at 240x225, 28 vs 56 ms) and up to
about full HD for the demo (1360x900: 104 vs 128 ms); quads win where fragments dominate (a synthetic 100k avatar
at 2560x1440: 335 vs 398 ms; docs/PERFORMANCE.md). The cross-over depends on the splats' sizes on screen and the
machine, so the choice follows the measured cost of earlier images of about the same size (pixel counts within a
factor of sqrt 2), per visible splat, and every `EXPLORE`-th image of a size tries the path that is not taken so
that a change (an avatar, a zoom) is noticed; the path not yet measured is first tried there too (it was the second
image of a size: the window's first stop after opening, whose image then took the slower path). The images of both
paths are the same.
"""

from __future__ import annotations

import math

#: Below this many pixels an unmeasured size starts with points, above with quads (about the measured cross-over).
PRIOR_PIXELS = 2_000_000
#: Every this many images of a size, the path not taken is drawn once to refresh its cost.
EXPLORE = 12


class PathCosts:
    """Measured draw cost (ms per visible splat, an exponential average) per path and image size."""

    def __init__(self) -> None:
        self.cost: dict[tuple[int, bool], float] = {}
        self._images: dict[int, int] = {}

    @staticmethod
    def bucket(width: int, height: int) -> int:
        """Image sizes within a factor of sqrt 2 in pixels share a bucket."""
        return round(2 * math.log2(max(1, width * height)))

    def choose(self, width: int, height: int) -> bool:
        """True to draw an image of this size with points, False with quads (counts the image)."""
        b = self.bucket(width, height)
        n = self._images.get(b, 0)
        self._images[b] = n + 1
        points, quads = self.cost.get((b, True)), self.cost.get((b, False))
        if points is None and quads is None:
            return width * height < PRIOR_PIXELS
        explore = n % EXPLORE == EXPLORE - 1
        if points is None or quads is None:  # the measured one, the other once in EXPLORE images to compare
            return (points is None) == explore
        cheaper = points <= quads
        return not cheaper if explore else cheaper

    def record(self, width: int, height: int, points: bool, draw_ms: float, splats: int) -> None:
        """The measured draw time of a finished image (synchronous timings only) of `splats` visible splats."""
        if splats <= 0 or not math.isfinite(draw_ms) or draw_ms <= 0:
            return
        key = (self.bucket(width, height), points)
        per = draw_ms / splats
        old = self.cost.get(key)
        self.cost[key] = per if old is None else 0.5 * old + 0.5 * per
