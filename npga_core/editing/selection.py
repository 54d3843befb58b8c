"""Selecting Gaussians: pure numpy functions that return boolean masks of shape (N,).

Screen-space tools (`in_rect`, `in_lasso`, `in_brush`) take an OpenCV `Camera` (pixel coordinates, u right, v
down, pixel centres at +0.5) and only ever select Gaussians in front of the camera. 3D tools (`in_sphere`,
`in_box`) and `in_range` work on positions or per-Gaussian values. `grow`/`shrink` are dilation and erosion
along the (symmetrised) kNN graph from `npga_core.inspection.graph.knn`; `combine` merges a new mask into the current
selection. `attribute_values` gives the per-Gaussian quantities the range tool and its histogram offer.
"""

from __future__ import annotations

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import SH_C0, GaussianCloud, sigmoid

#: How a new mask is merged into the current selection.
COMBINE_MODES: tuple[str, ...] = ("replace", "add", "subtract", "intersect")

#: Near limit (camera-space z, world units) below which a Gaussian counts as behind the camera.
NEAR_Z = 1e-4


def _means(means: np.ndarray) -> np.ndarray:
    m = np.asarray(means, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f"means must be (N, 3), got shape {m.shape}")
    return m


def project_front(camera: Camera, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) of every centre and the mask of those in front of the camera."""
    view = camera.world_to_view(_means(means))
    front = view[:, 2] > NEAR_Z
    z = np.where(front, view[:, 2], 1.0)
    uv = np.stack([camera.fx * view[:, 0] / z + camera.cx, camera.fy * view[:, 1] / z + camera.cy], axis=1)
    return uv, front


def in_rect(camera: Camera, means: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Gaussians in front of the camera whose centre projects into the pixel rectangle (corners in any order)."""
    uv, front = project_front(camera, means)
    lx, hx = sorted((float(x0), float(x1)))
    ly, hy = sorted((float(y0), float(y1)))
    return front & (uv[:, 0] >= lx) & (uv[:, 0] <= hx) & (uv[:, 1] >= ly) & (uv[:, 1] <= hy)


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule test of 2D points (N, 2) against a closed polygon (M, 2), M >= 3."""
    pts = np.asarray(points, dtype=np.float64)
    poly = np.asarray(polygon, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2:
        raise ValueError(f"polygon must be (M, 2), got shape {poly.shape}")
    inside = np.zeros(len(pts), dtype=bool)
    if len(poly) < 3 or len(pts) == 0:
        return inside
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    cand = np.flatnonzero(np.all((pts >= lo) & (pts <= hi), axis=1))
    x, y = pts[cand, 0], pts[cand, 1]
    hit = np.zeros(len(cand), dtype=bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (ay > y) != (by > y)
        if not crosses.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = ax + (y - ay) * (bx - ax) / (by - ay)
        hit ^= crosses & (x < x_at)
    inside[cand] = hit
    return inside


def in_lasso(camera: Camera, means: np.ndarray, polygon_px: np.ndarray) -> np.ndarray:
    """Gaussians in front of the camera whose centre projects inside the lasso polygon (pixels, even-odd)."""
    uv, front = project_front(camera, means)
    return front & points_in_polygon(uv, polygon_px)


def in_brush(camera: Camera, means: np.ndarray, centre_px: tuple[float, float] | np.ndarray,
             radius_px: float) -> np.ndarray:
    """Gaussians in front of the camera whose centre projects within `radius_px` of `centre_px`."""
    uv, front = project_front(camera, means)
    d2 = ((uv - np.asarray(centre_px, dtype=np.float64)) ** 2).sum(axis=1)
    return front & (d2 <= float(radius_px) ** 2)


def in_sphere(means: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Centres within `radius` of `centre` (boundary included)."""
    d = _means(means) - np.asarray(centre, dtype=np.float64).reshape(3)
    return np.einsum("ij,ij->i", d, d) <= float(radius) ** 2


def in_box(means: np.ndarray, lo: np.ndarray, hi: np.ndarray, transform: np.ndarray | None = None) -> np.ndarray:
    """Centres inside the axis-aligned box [lo, hi] (boundary included).

    With `transform` (4x4, box space -> world), the box is [lo, hi] in its own frame, placed (rotated, moved,
    scaled) in the world by that matrix; points are taken into box space by its inverse.
    """
    m = _means(means)
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    hi = np.asarray(hi, dtype=np.float64).reshape(3)
    if transform is not None:
        t = np.asarray(transform, dtype=np.float64)
        if t.shape != (4, 4):
            raise ValueError(f"box transform must be 4x4, got shape {t.shape}")
        inv = np.linalg.inv(t)
        m = m @ inv[:3, :3].T + inv[:3, 3]
    return np.all((m >= np.minimum(lo, hi)) & (m <= np.maximum(lo, hi)), axis=1)


def in_range(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """lo <= values <= hi (bounds in any order; NaN is never in range)."""
    v = np.asarray(values)
    a, b = sorted((float(lo), float(hi)))
    return (v >= a) & (v <= b)


def _check_graph(mask: np.ndarray, nbrs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = np.asarray(mask, dtype=bool)
    g = np.asarray(nbrs, dtype=np.int64)
    if g.ndim != 2 or g.shape[0] != m.shape[0]:
        raise ValueError(f"neighbour list has shape {g.shape}, the mask has {m.shape[0]} rows")
    return m, g


def grow(mask: np.ndarray, nbrs: np.ndarray, steps: int = 1) -> np.ndarray:
    """Add every Gaussian linked to a selected one in the kNN graph (either direction), `steps` times."""
    m, g = _check_graph(mask, nbrs)
    m = m.copy()
    for _ in range(max(int(steps), 0)):
        new = m | m[g].any(axis=1)  # one of my neighbours is selected
        new[g[m].reshape(-1)] = True  # I am a neighbour of a selected one
        m = new
    return m


def shrink(mask: np.ndarray, nbrs: np.ndarray, steps: int = 1) -> np.ndarray:
    """Drop every selected Gaussian linked to an unselected one (the dual of `grow`), `steps` times."""
    m, g = _check_graph(mask, nbrs)
    return ~grow(~m, g, steps)


def combine(current: np.ndarray, new: np.ndarray, mode: str = "replace") -> np.ndarray:
    """Merge `new` into `current`: replace, add (or), subtract (and not), intersect (and)."""
    cur = np.asarray(current, dtype=bool)
    new = np.asarray(new, dtype=bool)
    if cur.shape != new.shape:
        raise ValueError(f"masks differ in shape: {cur.shape} and {new.shape}")
    if mode == "replace":
        return new.copy()
    if mode == "add":
        return cur | new
    if mode == "subtract":
        return cur & ~new
    if mode == "intersect":
        return cur & new
    raise ValueError(f"unknown selection mode {mode!r}; choose from {', '.join(COMBINE_MODES)}")


def attribute_names(cloud: GaussianCloud) -> list[str]:
    """The attributes `attribute_values` offers for this cloud."""
    names = ["opacity", "max_scale", "min_scale", "red", "green", "blue", "brightness"]
    names += [f"feature_{k}" for k in range(cloud.feature_dim)]
    if cloud.part_ids is not None:
        names.append("part")
    return names


def attribute_values(cloud: GaussianCloud, name: str) -> np.ndarray:
    """Per-Gaussian values (N,) float32 of a named canonical attribute, in activated units.

    opacity (0..1), max_scale / min_scale (world units), red/green/blue/brightness (DC colour 0..1 before
    clamping), feature_K (channel K of the per-Gaussian features), part (part id, -1 = none).
    """
    if name == "opacity":
        return sigmoid(cloud.opacity_logits)
    if name in ("max_scale", "min_scale"):
        ls = np.asarray(cloud.log_scales, dtype=np.float32)
        return np.exp(ls.max(axis=1) if name == "max_scale" else ls.min(axis=1)).astype(np.float32)
    if name in ("red", "green", "blue", "brightness"):
        rgb = np.asarray(cloud.sh[:, 0, :], dtype=np.float32) * SH_C0 + 0.5
        if name == "brightness":
            return (rgb @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float32)
        return np.ascontiguousarray(rgb[:, ("red", "green", "blue").index(name)])
    if name.startswith("feature_"):
        try:
            k = int(name[len("feature_"):])
        except ValueError:
            k = -1
        if not 0 <= k < cloud.feature_dim:
            raise ValueError(f"no feature channel {name[len('feature_'):]!r}; the cloud has {cloud.feature_dim}")
        return np.asarray(cloud.features[:, k], dtype=np.float32).copy()
    if name == "part" and cloud.part_ids is not None:
        return np.asarray(cloud.part_ids, dtype=np.float32)
    raise ValueError(f"unknown attribute {name!r}; choose from {', '.join(attribute_names(cloud))}")
