"""A CPU splat rasteriser for training the demo's screen-space refinement (numpy, float64 geometry).

`rasterize_splats` returns the colour image of posed Gaussians and, for every pixel, the Gaussians it blends
with their weights w_i = a_i T_i (a sparse matrix), so that any per-Gaussian quantity, the latent features h in
particular, composites into an image that is differentiable in those quantities (`SplatImage.composite`).

It follows the window's GL renderer (npga_view/rendering/renderer.py and shaders/splat_preprocess.comp,
splat_common.glsl), which follows 3DGS: EWA projection with the Jacobian's t.x/t.z, t.y/t.z clamped to
1.3 tan(fov/2) and 0.3 px added to the covariance diagonal; SH colour max(SH . basis(mean - campos) + 0.5, 0);
alpha = min(0.99, o exp(power)), skipped where power > 0 or alpha < 1/255; Gaussians at depth <= near or with
opacity < 1/255 culled. Like the GL renderer (and unlike 3DGS) every Gaussian is composited: no early stop at
T < 1e-4 and no 16x16-tile rectangles. Blending is by centre depth, front to back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch

from npga_core.camera.cameras import Camera

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
NEAR = 0.01
#: Candidate (Gaussian, pixel) pairs handled at once (bounds the memory of one chunk to a few hundred MB).
CHUNK_PAIRS = 4_000_000


@dataclass
class SplatImage:
    """A rasterised cloud: premultiplied colour and alpha, and the sparse blending weights (sorted by pixel)."""

    height: int
    width: int
    rgb: np.ndarray  # (H, W, 3) float32, C = sum_i c_i w_i (no background)
    alpha: np.ndarray  # (H, W) float32, A = sum_i w_i = 1 - prod_i (1 - a_i)
    pixel: np.ndarray  # (K,) int64 flat pixel index y * W + x
    gaussian: np.ndarray  # (K,) int64 index into the cloud
    weight: np.ndarray  # (K,) float32 a_i T_i (entries below the rasteriser's min_weight dropped)

    def over(self, background: npt.ArrayLike) -> np.ndarray:
        """The colour image over a background colour: C + (1 - A) bg (H, W, 3)."""
        bg = np.asarray(background, np.float32).reshape(1, 1, 3)
        return self.rgb + (1.0 - self.alpha[..., None]) * bg

    def composite(self, values: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Per-Gaussian values (M, C) composited like colour into (H, W, C), differentiable in `values`.

        `values` row j belongs to Gaussian `rows[j]` (all Gaussians, in order, when `rows` is None); Gaussians of
        the sparse list missing from `rows` must not occur.
        """
        if rows is None:
            idx = torch.from_numpy(self.gaussian)
        else:
            lookup = torch.full((int(max(rows.max().item(), self.gaussian.max(initial=0))) + 1,), -1, dtype=torch.long)
            lookup[rows] = torch.arange(len(rows))
            idx = lookup[torch.from_numpy(self.gaussian)]
        w = torch.from_numpy(self.weight).to(values.dtype)
        out = torch.zeros(self.height * self.width, values.shape[1], dtype=values.dtype)
        out = out.index_add(0, torch.from_numpy(self.pixel), values[idx] * w[:, None])
        return out.reshape(self.height, self.width, values.shape[1])


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def sh_colour(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """3DGS SH (N, K, 3) evaluated in unit directions camera -> Gaussian (N, 3): max(. + 0.5, 0)."""
    k = sh.shape[1]
    x, y, z = (dirs[:, i:i + 1] for i in range(3))
    out = SH_C0 * sh[:, 0]
    if k > 1:
        out = out - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        out = (out + SH_C2[0] * x * y * sh[:, 4] + SH_C2[1] * y * z * sh[:, 5]
               + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6] + SH_C2[3] * x * z * sh[:, 7]
               + SH_C2[4] * (xx - yy) * sh[:, 8])
    if k > 9:
        out = (out + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9] + SH_C3[1] * x * y * z * sh[:, 10]
               + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11] + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
               + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13] + SH_C3[5] * z * (xx - yy) * sh[:, 14]
               + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15])
    return np.maximum(out + 0.5, 0.0)


def project_splats(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, opacities: np.ndarray, camera: Camera,
                   near: float = NEAR,
                   fov_camera: Camera | None = None) -> dict[str, np.ndarray]:
    """Screen quantities of the Gaussians the renderer keeps: index, depth, centre (u, v), conic, opacity and
    the half extent (px) of the bounding box of the ellipse where alpha reaches 1/255. The Jacobian clamp uses
    the field of view of `fov_camera` (default `camera`; the whole image when `camera` is a crop of it)."""
    rot, trans = camera.rotation, camera.translation
    means = np.asarray(means, np.float64)
    opac = np.asarray(opacities, np.float64).reshape(-1)
    t = means @ rot.T + trans
    keep = (t[:, 2] > near) & (opac >= MIN_ALPHA)
    # cheap early cull: centre farther off the image than a bound of the splat's extent (3.33 sigma of the
    # largest axis through a Jacobian of norm <= 2 f / z within the clamped field of view, plus the 0.3 px)
    zs = np.where(keep, t[:, 2], 1.0)
    reach = 3.4 * (2.0 * max(camera.fx, camera.fy) * np.asarray(scales, np.float64).max(axis=1) / zs + 1.0)
    u0, v0 = camera.fx * t[:, 0] / zs + camera.cx, camera.fy * t[:, 1] / zs + camera.cy
    keep &= (u0 > -reach) & (v0 > -reach) & (u0 < camera.width + reach) & (v0 < camera.height + reach)
    keep = np.flatnonzero(keep)
    t, opac = t[keep], opac[keep]
    tz = t[:, 2]
    r = _quat_to_matrix(np.asarray(quats, np.float64)[keep])
    m = r * np.asarray(scales, np.float64)[keep][:, None, :]
    cov3 = m @ m.transpose(0, 2, 1)
    fc = fov_camera or camera
    limx, limy = 1.3 * fc.width / (2 * fc.fx), 1.3 * fc.height / (2 * fc.fy)
    tx = np.clip(t[:, 0] / tz, -limx, limx) * tz
    ty = np.clip(t[:, 1] / tz, -limy, limy) * tz
    jac = np.zeros((len(t), 2, 3))
    jac[:, 0, 0] = camera.fx / tz
    jac[:, 0, 2] = -camera.fx * tx / tz**2
    jac[:, 1, 1] = camera.fy / tz
    jac[:, 1, 2] = -camera.fy * ty / tz**2
    tm = jac @ rot
    cov2 = tm @ cov3 @ tm.transpose(0, 2, 1)
    a, b, c = cov2[:, 0, 0] + 0.3, cov2[:, 0, 1], cov2[:, 1, 1] + 0.3
    det = a * c - b * b
    u = camera.fx * t[:, 0] / tz + camera.cx
    v = camera.fy * t[:, 1] / tz + camera.cy
    radius = np.sqrt(2.0 * np.log(255.0 * opac))
    half = radius[:, None] * np.sqrt(np.maximum(np.stack([a, c], 1), 0.0))
    ok = (det > 0) & (u + half[:, 0] >= 0) & (v + half[:, 1] >= 0) & (u - half[:, 0] <= camera.width) \
        & (v - half[:, 1] <= camera.height)
    det = np.where(det > 0, det, 1.0)
    conic = np.stack([c / det, -b / det, a / det], 1)
    return {"index": keep[ok], "depth": tz[ok], "uv": np.stack([u, v], 1)[ok], "conic": conic[ok],
            "opacity": opac[ok], "half": half[ok]}


def pixel_ranges(lo: np.ndarray, hi: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """First and last pixel index whose centre (i + 0.5) lies in [lo, hi], clipped to the image."""
    first = np.clip(np.ceil(lo - 0.5), 0, size).astype(np.int64)
    last = np.clip(np.floor(hi - 0.5), -1, size - 1).astype(np.int64)
    return first, last


def box_pixels(x0: np.ndarray, x1: np.ndarray, y0: np.ndarray, y1: np.ndarray) -> tuple[np.ndarray, np.ndarray,
               np.ndarray]:
    """All (item, x, y) of the boxes [x0, x1] x [y0, y1] (inclusive), one row per covered pixel."""
    wb = np.maximum(x1 - x0 + 1, 0)
    hb = np.maximum(y1 - y0 + 1, 0)
    count = wb * hb
    item = np.repeat(np.arange(len(count)), count)
    start = np.cumsum(count) - count
    local = np.arange(int(count.sum())) - start[item]
    return item, x0[item] + local % wb[item], y0[item] + local // wb[item]


def chunk_slices(count: np.ndarray, limit: int) -> list[slice]:
    """Consecutive slices of items whose counts sum to at most `limit` (at least one item each)."""
    out, start, acc = [], 0, 0
    for i, c in enumerate(count.tolist()):
        if acc and acc + c > limit:
            out.append(slice(start, i))
            start, acc = i, 0
        acc += c
    out.append(slice(start, len(count)))
    return out


def rasterize_splats(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, opacities: np.ndarray,
                     sh: np.ndarray, camera: Camera, near: float = NEAR,
                     min_weight: float = 1e-4, fov_camera: Camera | None = None) -> SplatImage:
    """Rasterise posed, activated Gaussians (as `PosedGaussians` holds them) from `camera`; see the module docstring.

    The colour and alpha images include every contribution; the sparse list keeps weights >= `min_weight`. For a
    crop (`mesh_raster.crop_camera`) pass the whole image's camera as `fov_camera` to get the crop of its image.
    """
    width, height = camera.width, camera.height
    p = project_splats(means, quats, scales, opacities, camera, near, fov_camera)
    idx = p["index"]
    centre = -camera.rotation.T @ camera.translation
    dirs = np.asarray(means, np.float64)[idx] - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    colour = sh_colour(np.asarray(sh, np.float64)[idx], dirs)
    uv, half = p["uv"], p["half"]
    x0, x1 = pixel_ranges(uv[:, 0] - half[:, 0], uv[:, 0] + half[:, 0], width)
    y0, y1 = pixel_ranges(uv[:, 1] - half[:, 1], uv[:, 1] + half[:, 1], height)
    count = np.maximum(x1 - x0 + 1, 0) * np.maximum(y1 - y0 + 1, 0)
    pix_l, g_l, a_l = [], [], []
    for sl in chunk_slices(count, CHUNK_PAIRS):
        item, x, y = box_pixels(x0[sl], x1[sl], y0[sl], y1[sl])
        item += sl.start
        dx = x + 0.5 - uv[item, 0]
        dy = y + 0.5 - uv[item, 1]
        ca, cb, cc = p["conic"][item].T
        power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
        alpha = np.minimum(MAX_ALPHA, p["opacity"][item] * np.exp(np.minimum(power, 0.0)))
        hit = (power <= 0.0) & (alpha >= MIN_ALPHA)
        pix_l.append((y * width + x)[hit])
        g_l.append(item[hit])
        a_l.append(alpha[hit])
    pix = np.concatenate(pix_l)
    item = np.concatenate(g_l)
    alpha = np.concatenate(a_l)
    order = np.lexsort((p["depth"][item], pix))  # per pixel, front to back
    pix, item, alpha = pix[order], item[order], alpha[order]
    # transmittance before each entry: exp of the exclusive cumulative sum of log(1 - a) within its pixel
    log_t = np.log1p(-alpha)
    cum = np.cumsum(log_t)
    first = np.r_[True, pix[1:] != pix[:-1]]
    seg_start = np.maximum.accumulate(np.where(first, np.arange(len(pix)), 0))
    before = cum - log_t - (cum[seg_start] - log_t[seg_start])
    weight = alpha * np.exp(before)
    n_pix = width * height
    rgb = np.stack([np.bincount(pix, weight * colour[item, c], minlength=n_pix) for c in range(3)], 1)
    acc = np.bincount(pix, weight, minlength=n_pix)
    keep = weight >= min_weight
    return SplatImage(height, width, rgb.reshape(height, width, 3).astype(np.float32),
                      acc.reshape(height, width).astype(np.float32), pix[keep], idx[item[keep]],
                      weight[keep].astype(np.float32))
