"""O(N) back-to-front depth sort of Gaussians for alpha blending.

Two key schemes, both sorted with numpy's stable argsort, which is an LSD radix sort for 16-bit integers:

- `quantized`: one uint16 key per Gaussian. The core depth range (the 1..99 percentile range,
  estimated on a subsample, widened by half its width on each side, so a normal distribution loses only
  points beyond 4.6 sigma) gets 63487 of the 65536 codes, linearly in z; the few Gaussians outside it are
  pinned into 1024-code bands at either end, spaced by log depth, so far outliers keep their coarse order
  and cannot destroy the precision of the rest.
- `exact` (default): the float32 bit pattern of a positive depth is monotone in the depth, so two stable 16-bit radix
  passes (low half, then high half) give exactly the float order, at about twice the cost.

Ties (equal keys) keep ascending index order, like `np.argsort(-z, kind="stable")`.
"""

from __future__ import annotations

import numpy as np

KEY_LEVELS = 65536
OUTLIER_CODES = 1024
PERCENTILES = (1.0, 99.0)
CORE_PADDING = 0.5  # the core range is the 1..99 percentile range widened by half its width on both sides
_SAMPLE = 8192


def view_depths(means: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:
    """Camera-space z (float32, (N,)) of world points (N,3) for a 4x4 OpenCV world-to-camera matrix."""
    row = np.asarray(world_to_camera, dtype=np.float64)[2]
    return means @ row[:3].astype(np.float32) + np.float32(row[3])


def depth_keys(z: np.ndarray) -> np.ndarray:
    """uint16 keys, ascending = far to near, for positive depths z (see module doc for the robust mapping)."""
    z = np.asarray(z, dtype=np.float32)
    n = z.shape[0]
    if n == 0:
        return np.zeros(0, np.uint16)
    step = max(1, n // _SAMPLE)
    lo, hi = (float(v) for v in np.percentile(z[::step], PERCENTILES))
    pad = CORE_PADDING * (hi - lo)
    zmin, zmax = max(float(z.min()), 1e-30), float(z.max())
    lo, hi = max(lo - pad, zmin), min(hi + pad, zmax)
    core_first, core_last = OUTLIER_CODES, KEY_LEVELS - 1 - OUTLIER_CODES
    if hi <= lo:  # (nearly) all equal
        hi = lo + max(abs(lo), 1.0) * 1e-6
    scale = (core_last - core_first) / (hi - lo)
    keys = (np.float32(hi) - z) * np.float32(scale) + np.float32(core_first)
    far = z > hi
    near = z < lo
    if far.any() or near.any():
        idx = np.flatnonzero(far)
        if idx.size:  # (hi, zmax] -> [0, OUTLIER_CODES): by log depth, the farthest at 0
            lz = np.log(z[idx].astype(np.float64))
            span = max(np.log(zmax) - np.log(hi), 1e-12)
            keys[idx] = (OUTLIER_CODES - 1) * (np.log(zmax) - lz) / span
        idx = np.flatnonzero(near)
        if idx.size:  # [zmin, lo) -> (core_last, KEY_LEVELS - 1]: the nearest at the top
            lz = np.log(np.maximum(z[idx].astype(np.float64), zmin))
            span = max(np.log(lo) - np.log(zmin), 1e-12)
            keys[idx] = core_last + 1 + (OUTLIER_CODES - 1) * (np.log(lo) - lz) / span
    np.clip(keys, 0, KEY_LEVELS - 1, out=keys)
    return keys.astype(np.uint16)


def _exact_order(z: np.ndarray) -> np.ndarray:
    """Stable descending order of positive float32 depths via two 16-bit radix passes on the bit pattern."""
    bits = ~np.ascontiguousarray(z, dtype=np.float32).view(np.uint32)  # inverted: ascending = far first
    low = (bits & 0xFFFF).astype(np.uint16)
    order = np.argsort(low, kind="stable")
    high = (bits[order] >> 16).astype(np.uint16)
    return order[np.argsort(high, kind="stable")]


def sort_back_to_front(z: np.ndarray, near: float = 0.01, exact: bool = True) -> np.ndarray:
    """Indices (uint32) of the Gaussians with z > near, farthest first.

    `z` is the camera-space depth of each Gaussian centre; Gaussians at or behind the near plane are culled.
    `exact` (default) gives the stable float order; False sorts the 16-bit `depth_keys` (one radix pass).
    """
    z = np.asarray(z, dtype=np.float32)
    if z.shape[0] == 0:
        return np.zeros(0, np.uint32)
    visible = None
    if not float(z.min()) > near:
        visible = np.flatnonzero(z > near)
        z = z[visible]
        if z.shape[0] == 0:
            return np.zeros(0, np.uint32)
    order = _exact_order(z) if exact else np.argsort(depth_keys(z), kind="stable")
    if visible is not None:
        order = visible[order]
    return order.astype(np.uint32)
