"""An independent numpy (float64) re-implementation of the 3DGS forward rasterizer, for tests.

It follows diff-gaussian-rasterization (preprocessCUDA, computeCov2D, computeColorFromSH, renderCUDA) and
imports nothing from the GL renderer:

- 3D covariance R S S^T R^T; camera-space mean t; Jacobian with t.x/t.z, t.y/t.z clamped to
  +-1.3 tan(fov/2) per axis (tan(fov_x/2) = W / (2 fx)); 2D covariance J W Sigma W^T J^T + 0.3 I.
- Projected mean in OpenCV pixels u = fx t.x/t.z + cx (pixel centres at i + 0.5). 3DGS writes the mean as
  ndc2Pix(ndc, W) = ((ndc + 1) W - 1) / 2 = u - 0.5 for cx = W/2 and compares it with integer pixel
  indices, so both put pixel i's centre at u = i + 0.5.
- Radius ceil(3 sqrt(lambda_max)) and the 16x16-tile bounding rectangle decide which pixels may see a
  Gaussian (as 3DGS getRect); colour = max(SH . basis(normalize(mean - campos)) + 0.5, 0).
- Per pixel, front to back by depth: alpha = min(0.99, o exp(power)), skipped when power > 0 or
  alpha < 1/255; stop before the Gaussian that would bring T below 1e-4; out = C + T bg.

`near` replaces 3DGS's fixed 0.2 frustum cull (the viewer keeps close-up Gaussians).
"""

from __future__ import annotations

import numpy as np

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)
BLOCK = 16
CHUNK = 256  # Gaussians composited at once per tile (a tile whose pixels all ended skips the rest)


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """(N,4) unit quaternions (w, x, y, z) to (N,3,3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def sh_to_rgb(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Evaluate 3DGS SH (N,K,3) in unit directions (N,3); returns max(. + 0.5, 0) (N,3)."""
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


def project(means, quats, scales, opacities, sh, camera, near: float = 0.01) -> dict[str, np.ndarray]:
    """Per-Gaussian screen quantities as 3DGS preprocessCUDA computes them (float64)."""
    w2c = np.asarray(camera.world_to_camera, dtype=np.float64)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    means = np.asarray(means, np.float64)
    t = means @ rot.T + trans
    tz = t[:, 2]
    valid = tz > near
    tz_safe = np.where(valid, tz, 1.0)
    r = quat_to_rotation(np.asarray(quats, np.float64))
    m = r * np.asarray(scales, np.float64)[:, None, :]  # R S
    cov3 = m @ m.transpose(0, 2, 1)
    fx, fy = camera.fx, camera.fy
    limx = 1.3 * camera.width / (2 * fx)
    limy = 1.3 * camera.height / (2 * fy)
    tx = np.clip(t[:, 0] / tz_safe, -limx, limx) * tz_safe
    ty = np.clip(t[:, 1] / tz_safe, -limy, limy) * tz_safe
    jac = np.zeros((len(t), 2, 3))
    jac[:, 0, 0] = fx / tz_safe
    jac[:, 0, 2] = -fx * tx / tz_safe**2
    jac[:, 1, 1] = fy / tz_safe
    jac[:, 1, 2] = -fy * ty / tz_safe**2
    tm = jac @ rot
    cov2 = tm @ cov3 @ tm.transpose(0, 2, 1)
    a = cov2[:, 0, 0] + 0.3
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + 0.3
    det = a * c - b * b
    valid &= det > 0
    det_safe = np.where(det > 0, det, 1.0)
    conic = np.stack([c / det_safe, -b / det_safe, a / det_safe], 1)
    mid = 0.5 * (a + c)
    root = np.sqrt(np.maximum(0.1, mid * mid - det))
    radius = np.ceil(3.0 * np.sqrt(np.maximum(mid + root, mid - root)))
    u = fx * t[:, 0] / tz_safe + camera.cx
    v = fy * t[:, 1] / tz_safe + camera.cy
    centre = -rot.T @ trans
    dirs = means - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rgb = sh_to_rgb(np.asarray(sh, np.float64), dirs)
    # 3DGS getRect on the 3DGS pixel coordinate (u - 0.5), in tiles, clipped to the grid
    grid = ((camera.width + BLOCK - 1) // BLOCK, (camera.height + BLOCK - 1) // BLOCK)
    rect = np.zeros((len(t), 4), dtype=np.int64)  # x0, y0, x1, y1 in tiles
    for axis, (p, g) in enumerate(((u - 0.5, grid[0]), (v - 0.5, grid[1]))):
        lo = np.trunc((p - radius) / BLOCK)
        hi = np.trunc((p + radius + BLOCK - 1) / BLOCK)
        rect[:, axis] = np.minimum(g, np.maximum(0, np.nan_to_num(lo, posinf=g, neginf=0)))
        rect[:, axis + 2] = np.minimum(g, np.maximum(0, np.nan_to_num(hi, posinf=g, neginf=0)))
    valid &= (rect[:, 2] > rect[:, 0]) & (rect[:, 3] > rect[:, 1])
    return {"depth": tz, "uv": np.stack([u, v], 1), "conic": conic, "radius": radius, "rgb": rgb,
            "opacity": np.asarray(opacities, np.float64), "valid": valid, "rect": rect}


def _pixel_boxes(p: dict[str, np.ndarray], tile_rect: bool) -> np.ndarray:
    """Per Gaussian, the pixels it may touch as (x0, y0, x1, y1), unclipped: its tile rectangle (3DGS), or the box
    where its alpha can reach 1/255 (`tile_rect=False`)."""
    if tile_rect:
        return p["rect"] * BLOCK
    ca, cb, cc = p["conic"].T
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.sqrt(2 * np.log(np.maximum(255 * p["opacity"], 1.0)))[:, None] * np.sqrt(
            np.stack([cc, ca], 1) / (ca * cc - cb**2)[:, None])
    lo, hi = np.floor(p["uv"] - reach), np.ceil(p["uv"] + reach)
    big = 2.0**40
    return np.clip(np.concatenate([lo, hi], 1), -big, big).astype(np.int64)


def rasterize(means, quats, scales, opacities, sh, camera, background=(0.0, 0.0, 0.0), latent=None,
              near: float = 0.01, early_stop: bool = True, tile_rect: bool = True) -> dict[str, np.ndarray]:
    """Render like 3DGS. Returns rgb (H,W,3) = C + T bg, depth (H,W) = sum w_i z_i, alpha (H,W) = 1 - T,
    and latent (H,W,Hdim) composited like colour (no background) when `latent` (N,Hdim) is given.

    As renderCUDA, tile by tile: the tile's Gaussians front to back, each pixel's transmittance the running product
    of (1 - alpha) over the Gaussians that hit it (power <= 0, alpha >= 1/255), its walk ending before the one that
    would bring it below 1e-4. `early_stop=False` composites every Gaussian (what blending computes);
    `tile_rect=False` lets a Gaussian reach every pixel where its alpha >= 1/255 instead of only those in its tile
    rectangle.
    """
    p = project(means, quats, scales, opacities, sh, camera, near)
    width, height = camera.width, camera.height
    feats = [p["rgb"], p["depth"][:, None]]
    if latent is not None:
        feats.append(np.asarray(latent, np.float64))
    feats = np.concatenate(feats, 1)
    acc = np.zeros((height, width, feats.shape[1]))
    trans = np.ones((height, width))
    order = np.flatnonzero(p["valid"])
    order = order[np.argsort(p["depth"][order], kind="stable")]
    box = _pixel_boxes(p, tile_rect)[order]
    for y0 in range(0, height, BLOCK):
        for x0 in range(0, width, BLOCK):
            x1, y1 = min(x0 + BLOCK, width), min(y0 + BLOCK, height)
            ys, xs = np.mgrid[y0:y1, x0:x1]
            xs, ys = xs.ravel(), ys.ravel()
            on = (box[:, 0] < x1) & (box[:, 2] > x0) & (box[:, 1] < y1) & (box[:, 3] > y0)
            t, c, alive = np.ones(len(xs)), np.zeros((len(xs), feats.shape[1])), np.ones(len(xs), bool)
            for part in np.array_split(np.flatnonzero(on), max(1, int(on.sum()) // CHUNK)):
                if len(part) == 0 or not alive.any():
                    continue
                g, b = order[part], box[part]
                dx = xs[None, :] + 0.5 - p["uv"][g, 0:1]
                dy = ys[None, :] + 0.5 - p["uv"][g, 1:2]
                ca, cb, cc = (p["conic"][g, k:k + 1] for k in range(3))
                power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                alpha = np.minimum(0.99, p["opacity"][g, None] * np.exp(power))
                inside = (xs >= b[:, 0:1]) & (xs < b[:, 2:3]) & (ys >= b[:, 1:2]) & (ys < b[:, 3:4])
                hit = inside & (power <= 0) & (alpha >= 1.0 / 255.0) & alive
                a = np.where(hit, alpha, 0.0)
                after = t * np.cumprod(1 - a, axis=0)  # the transmittance after each Gaussian
                before = np.concatenate([t[None], after[:-1]])
                if early_stop:  # the walk ends before the first Gaussian that would bring T below 1e-4
                    ended = np.logical_or.accumulate(hit & (after < 1e-4), axis=0)
                    a = np.where(ended, 0.0, a)
                    alive &= ~ended[-1]
                c += (a * before).T @ feats[g]
                t = t * np.prod(1 - a, axis=0)
            acc[ys, xs] = c
            trans[ys, xs] = t
    bg = np.asarray(background, np.float64).reshape(3)
    out = {"rgb": acc[..., :3] + trans[..., None] * bg, "depth": acc[..., 3], "alpha": 1.0 - trans}
    if latent is not None:
        out["latent"] = acc[..., 4:]
    return out
