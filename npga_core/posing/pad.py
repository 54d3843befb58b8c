"""The expression pad: a point (u, v) in the unit square blends four corner codes bilinearly.

Corners in the order top-left, top-right, bottom-left, bottom-right; u runs left to right, v top to bottom:

    z(u, v) = (1-u)(1-v) z_tl + u(1-v) z_tr + (1-u) v z_bl + u v z_br

so a corner gives its own code and the centre the mean of the four (as on the NPGA project page's pad).
"""

from __future__ import annotations

import numpy as np

CORNERS = ("top left", "top right", "bottom left", "bottom right")


def weights(u: float, v: float) -> np.ndarray:
    """The four corner weights at (u, v), clamped to the square; they sum to 1."""
    u, v = float(np.clip(u, 0.0, 1.0)), float(np.clip(v, 0.0, 1.0))
    return np.array([(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v], np.float64)


def blend(corners: np.ndarray, u: float, v: float) -> np.ndarray:
    """The code at (u, v) of four corner codes (4, D), computed in float64, returned as float32."""
    c = np.asarray(corners, np.float64)
    if c.ndim != 2 or c.shape[0] != 4:
        raise ValueError(f"the pad needs 4 corner codes, got shape {c.shape}")
    return (weights(u, v) @ c).astype(np.float32)
