"""Per-Gaussian measures and masks for inspection: scale and depth values, frustum counts, histograms,
value ranges, clipping boxes and planes, and the recolouring (highlight, filter) applied before upload."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import SH_C0, PosedGaussians, rgb_to_sh0

# --- per-attribute values ---------------------------------------------------------------------------------
SCALE_MEASURES: tuple[str, ...] = ("size", "anisotropy")


def scale_values(scales: np.ndarray, measure: str = "size") -> np.ndarray:
    """size: largest axis (1 sigma, world units); anisotropy: largest / smallest axis (>= 1)."""
    s = np.asarray(scales, dtype=np.float64)
    if measure == "size":
        return s.max(axis=1).astype(np.float32)
    if measure == "anisotropy":
        return (s.max(axis=1) / np.maximum(s.min(axis=1), 1e-30)).astype(np.float32)
    raise ValueError(f"unknown scale measure {measure!r}; choose from {', '.join(SCALE_MEASURES)}")


def depth_values(means: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-space z of every centre (N,) float32."""
    return camera.world_to_view(means)[:, 2].astype(np.float32)


# --- counts ------------------------------------------------------------------------------------------------
def in_frustum(camera: Camera, means: np.ndarray, near: float = 0.01) -> np.ndarray:
    """Centres in front of the near plane (z > near) that project inside the image [0, W) x [0, H)."""
    view = camera.world_to_view(means)
    z = view[:, 2]
    front = z > near
    zs = np.where(front, z, 1.0)
    u = camera.fx * view[:, 0] / zs + camera.cx
    v = camera.fy * view[:, 1] / zs + camera.cy
    return front & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)


@dataclass
class Counts:
    """How many Gaussians there are, are in the view frustum and are drawn, overall and per body part."""

    total: int
    in_frustum: int
    drawn: int | None  # None: unknown (no renderer)
    parts: list[tuple[str, int, int, int | None]] = field(default_factory=list)  # (name, total, frustum, drawn)


def count_gaussians(camera: Camera, means: np.ndarray, part_ids: np.ndarray | None = None,
                    part_names: list[str] | None = None, drawn: np.ndarray | int | None = None,
                    near: float = 0.01) -> Counts:
    """Counts for a camera. `drawn` is the renderer's drawn mask (N,) (per-part counts too) or its count."""
    frustum = in_frustum(camera, means, near)
    mask = np.asarray(drawn, bool) if isinstance(drawn, np.ndarray) else None
    total_drawn = int(mask.sum()) if mask is not None else (None if drawn is None else int(drawn))
    counts = Counts(len(frustum), int(frustum.sum()), total_drawn)
    if part_ids is not None and part_names:
        ids = np.asarray(part_ids)
        labelled = [(name, ids == i) for i, name in enumerate(part_names)]
        if np.any(ids < 0):
            labelled.append(("(no part)", ids < 0))
        for name, m in labelled:
            counts.parts.append((name, int(m.sum()), int((m & frustum).sum()),
                                 None if mask is None else int((m & mask).sum())))
    return counts


# --- histograms, ranges, clipping --------------------------------------------------------------------------
def histogram(values: np.ndarray, bins: int = 64,
              value_range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(counts (bins,), edges (bins + 1,)) of the finite values over `value_range` (default: min..max)."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if value_range is None:
        value_range = (float(v.min()), float(v.max())) if v.size else (0.0, 1.0)
    lo, hi = value_range
    if hi <= lo:
        hi = lo + 1e-9
    return np.histogram(v, bins=bins, range=(lo, hi))


def in_range(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """lo <= values <= hi (NaN is outside)."""
    v = np.asarray(values)
    return (v >= min(lo, hi)) & (v <= max(lo, hi))


def clip_box(means: np.ndarray, lo: npt.ArrayLike, hi: npt.ArrayLike) -> np.ndarray:
    """Centres inside the axis-aligned box [lo, hi] (world units, boundary included): the ones kept."""
    m = np.asarray(means, dtype=np.float64)
    a, b = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return np.all((m >= np.minimum(a, b)) & (m <= np.maximum(a, b)), axis=1)


def clip_plane(means: np.ndarray, point: npt.ArrayLike, normal: npt.ArrayLike) -> np.ndarray:
    """Centres on the side of the plane through `point` that `normal` points to (boundary included): kept."""
    n = np.asarray(normal, np.float64)
    if not np.linalg.norm(n) > 0:
        raise ValueError("the clipping plane's normal is zero")
    return (np.asarray(means, np.float64) - np.asarray(point, np.float64)) @ n >= 0.0


DIM_OPACITY = 0.15  # opacity factor of Gaussians outside a highlighted range


def recolour(posed: PosedGaussians, rgb: np.ndarray | None = None, visible: np.ndarray | None = None,
             highlight: np.ndarray | None = None) -> PosedGaussians:
    """What to upload: SH replaced by degree-0 `rgb` (if given); opacity 0 where not `visible`; where not in
    `highlight`, grey (the colour's luminance, halved towards mid grey) and opacity times DIM_OPACITY."""
    out = replace(posed)
    if rgb is not None:
        out.sh = rgb_to_sh0(rgb)[:, None, :]
    if highlight is not None:
        dim = ~np.asarray(highlight, bool)
        base = rgb if rgb is not None else np.clip(posed.sh[:, 0] * SH_C0 + 0.5, 0.0, 1.0)
        grey = 0.25 + 0.5 * (np.asarray(base)[dim] @ np.array([0.299, 0.587, 0.114], np.float32))
        sh = np.array(out.sh, dtype=np.float32, copy=True)
        sh[dim] = 0.0
        sh[dim, 0] = rgb_to_sh0(np.repeat(grey[:, None], 3, axis=1))
        out.sh = sh
        out.opacities = np.where(dim, posed.opacities * DIM_OPACITY, posed.opacities).astype(np.float32)
    if visible is not None:
        out.opacities = np.where(np.asarray(visible, bool), out.opacities, 0.0).astype(np.float32)
    return out
