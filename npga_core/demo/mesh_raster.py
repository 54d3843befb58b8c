"""A small CPU triangle rasteriser (numpy) for the refinement targets: which triangle each pixel sees and where.

`rasterize_mesh` projects with an OpenCV `Camera` (pixel centres at i + 0.5), tests every pixel centre in each
triangle's bounding box against the triangle (edge functions, both windings), keeps the nearest per pixel
(a z-buffer) and returns perspective-correct barycentrics. `supersampled` renders at s x s samples per pixel for
antialiased images (`box_filter` brings them back). Triangles with a corner at depth <= near are dropped (the
views used here never clip the head).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.demo.splat_raster import box_pixels, chunk_slices, pixel_ranges

NEAR = 0.01


@dataclass
class MeshFragments:
    """Per pixel: the nearest triangle (-1 where none), perspective-correct barycentrics and camera depth."""

    triangle: np.ndarray  # (H, W) int64
    bary: np.ndarray  # (H, W, 3) float64
    depth: np.ndarray  # (H, W) float64, inf where empty

    @property
    def covered(self) -> np.ndarray:
        return self.triangle >= 0


def rasterize_mesh(vertices: np.ndarray, faces: np.ndarray, camera: Camera, near: float = NEAR,
                   chunk: int = 4_000_000) -> MeshFragments:
    """Rasterise triangles `faces` (T, 3) of `vertices` (V, 3) (world space); `triangle` indexes `faces`."""
    width, height = camera.width, camera.height
    t = np.asarray(vertices, np.float64) @ camera.rotation.T + camera.translation
    z = t[:, 2]
    zs = np.where(z > near, z, 1.0)
    uv = np.stack([camera.fx * t[:, 0] / zs + camera.cx, camera.fy * t[:, 1] / zs + camera.cy], 1)
    faces = np.asarray(faces, np.int64)
    tri = np.flatnonzero((z[faces] > near).all(axis=1))
    fu = uv[faces[tri]]  # (T, 3, 2)
    x0, x1 = pixel_ranges(fu[..., 0].min(1), fu[..., 0].max(1), width)
    y0, y1 = pixel_ranges(fu[..., 1].min(1), fu[..., 1].max(1), height)
    e1, e2 = fu[:, 1] - fu[:, 0], fu[:, 2] - fu[:, 0]
    area = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    ok = (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-12)
    tri, fu, x0, x1, y0, y1, e1, e2, area = (a[ok] for a in (tri, fu, x0, x1, y0, y1, e1, e2, area))
    inv_z = 1.0 / z[faces[tri]]  # (T, 3)
    count = (x1 - x0 + 1) * (y1 - y0 + 1)
    best_depth = np.full(width * height, np.inf)
    best_tri = np.full(width * height, -1, np.int64)
    best_bary = np.zeros((width * height, 3))
    for sl in chunk_slices(count, chunk):
        item, x, y = box_pixels(x0[sl], x1[sl], y0[sl], y1[sl])
        item += sl.start
        px, py = x + 0.5 - fu[item, 0, 0], y + 0.5 - fu[item, 0, 1]
        l1 = (px * e2[item, 1] - e2[item, 0] * py) / area[item]
        l2 = (e1[item, 0] * py - px * e1[item, 1]) / area[item]
        l0 = 1.0 - l1 - l2
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        item, x, y = item[inside], x[inside], y[inside]
        lam = np.stack([l0[inside], l1[inside], l2[inside]], 1) * inv_z[item]
        s = lam.sum(axis=1)
        depth = 1.0 / s
        pix = y * width + x
        order = np.lexsort((depth, pix))
        pix, depth, item, lam, s = pix[order], depth[order], item[order], lam[order], s[order]
        first = np.r_[True, pix[1:] != pix[:-1]]
        pix, depth, item, lam, s = pix[first], depth[first], item[first], lam[first], s[first]
        closer = depth < best_depth[pix]
        pix = pix[closer]
        best_depth[pix] = depth[closer]
        best_tri[pix] = tri[item[closer]]
        best_bary[pix] = lam[closer] / s[closer, None]
    return MeshFragments(best_tri.reshape(height, width), best_bary.reshape(height, width, 3),
                         best_depth.reshape(height, width))


def supersampled(camera: Camera, factor: int) -> Camera:
    """The camera with `factor` x `factor` samples per pixel (sample j of pixel i at (i + (j + 0.5) / factor))."""
    return Camera(camera.world_to_camera.copy(), camera.fx * factor, camera.fy * factor, camera.cx * factor,
                  camera.cy * factor, camera.width * factor, camera.height * factor)


def box_filter(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean over `factor` x `factor` blocks of an (H*f, W*f, ...) image."""
    h, w = image.shape[0] // factor, image.shape[1] // factor
    return image.reshape(h, factor, w, factor, *image.shape[2:]).mean(axis=(1, 3))


def crop_camera(camera: Camera, x0: int, y0: int, width: int, height: int) -> Camera:
    """The window [x0, x0 + width) x [y0, y0 + height) of `camera`'s image as a camera of its own."""
    return Camera(camera.world_to_camera.copy(), camera.fx, camera.fy, camera.cx - x0, camera.cy - y0, width, height)
