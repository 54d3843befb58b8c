"""The teeth GaussianAvatars adds to FLAME: 120 vertices from the outer lip ring, 168 triangles.

Facts about their mesh, written down from their description (ShenhanQian/GaussianAvatars,
`flame_model/flame.py`, `FlameHead.add_teeth` and `FlameMask.create_custom_mask`) so that a Gaussian's `binding`
names the same triangle; tests/files/test_gaussian_avatars_reference.py checks them against that file when a copy is
at hand. The teeth are 8 rows of 15 vertices placed from the template's outer lip ring (ring point i of the upper
and lower lip): upper root, lower root, upper edge, lower edge, upper root back, upper edge back, lower root
back, lower edge back. Upper rows follow the neck joint, lower rows the jaw; their shape directions are the
mean of the two ring points' (shape components only); no expression, pose corrective or regressor weight.
"""

from __future__ import annotations

import numpy as np

#: FLAME vertex ids of the outer lip ring, upper and lower lip, left to right (15 each).
LIP_RING_UPPER = (1713, 1715, 1716, 1735, 1696, 1694, 1657, 3543, 2774, 2811, 2813, 2850, 2833, 2832, 2830)
LIP_RING_LOWER = (1576, 1577, 1773, 1774, 1795, 1802, 1865, 3503, 2948, 2905, 2898, 2881, 2880, 2713, 2712)
RING = 15
ROWS = 8
N_TEETH_VERTICES = RING * ROWS
#: Rows (of 15) of the upper teeth (move with the neck joint) and of the lower (with the jaw).
UPPER_ROWS = (0, 2, 4, 5)
LOWER_ROWS = (1, 3, 6, 7)
NECK, JAW = 1, 2

# Each strip joins row a to row b with two triangles per column i (corners A = a_i, A1 = a_(i+1), B = b_i,
# B1 = b_(i+1)); the diagonal turns at the middle column (i >= 7), so each strip has two patterns.
_P = (("A", "B1", "B"), ("A", "A1", "B1"))
_Q = (("A", "A1", "B"), ("A1", "B1", "B"))
_R = (("A", "B", "B1"), ("A", "B1", "A1"))
_S = (("A", "B", "A1"), ("A1", "B", "B1"))
#: (row a, row b, pattern for i < 7, pattern for i >= 7), upper strips then lower strips.
STRIPS = ((0, 2, _P, _Q), (4, 5, _R, _S), (5, 2, _S, _R),
          (3, 1, _Q, _P), (6, 7, _P, _Q), (7, 3, _Q, _P))
MIDDLE = 7


def teeth_faces() -> np.ndarray:
    """(168, 3) triangles over the teeth vertices (0 .. 119, add the FLAME vertex count), their order."""
    out = []
    for a, b, before, after in STRIPS:
        for i in range(RING - 1):
            corner = {"A": a * RING + i, "A1": a * RING + i + 1, "B": b * RING + i, "B1": b * RING + i + 1}
            for tri in before if i < MIDDLE else after:
                out.append([corner[c] for c in tri])
    return np.array(out, np.int64)


def teeth_vertices(template: np.ndarray) -> np.ndarray:
    """(120, 3) teeth vertices placed from the template's lip ring (float64)."""
    up = np.asarray(template, np.float64)[list(LIP_RING_UPPER)]
    low = np.asarray(template, np.float64)[list(LIP_RING_LOWER)]
    gap = float(np.linalg.norm(up - low, axis=1).mean())
    mid = (up + low) / 2
    mid[:, 1] = mid[:, 1].mean()
    mid[:, 2] -= 1.5 * gap
    lift = np.array([0.0, gap, 0.0])
    upper_edge = mid + 0.1 * lift
    upper_root = upper_edge + 2 * lift
    lower_edge = mid - 0.1 * lift - np.array([0.0, 0.0, 0.4 * gap])
    lower_root = lower_edge - 2 * lift
    back = np.array([0.0, 0.0, gap])  # thickness
    rows = [upper_root, lower_root, upper_edge, lower_edge, upper_root - back, upper_edge - back,
            lower_root - back, lower_edge - back]
    return np.concatenate(rows, axis=0)


def teeth_rows(kind: tuple[int, ...]) -> np.ndarray:
    """Teeth vertex indices (0 .. 119) of the given rows."""
    return np.concatenate([np.arange(r * RING, (r + 1) * RING) for r in kind])


def ring_mean(per_vertex: np.ndarray) -> np.ndarray:
    """Per teeth vertex (120, ...) the mean of its column's upper and lower ring values (`per_vertex` (V, ...))."""
    mean = (per_vertex[list(LIP_RING_UPPER)] + per_vertex[list(LIP_RING_LOWER)]) / 2
    return np.concatenate([mean] * ROWS, axis=0)
