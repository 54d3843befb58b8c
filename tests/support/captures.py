"""A NeRSemble-style capture written from known images (what the evaluate and Compare tests read), and an
SSIM written out from its definition (Wang et al. 2004) to check the metric and the reports against."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from npga_core.camera.cameras import Camera, frame_points

SERIALS = ("220700191", "222200037")


FRAMES = (0, 3)


NOISE = 0.01


def capture_cameras(avatar) -> dict[str, Camera]:
    base = frame_points(avatar.cloud.means, 40, 56)
    side = base.world_to_camera.copy()
    side[0, 3] += 0.015
    return {SERIALS[0]: Camera(side, base.fx, base.fy, base.cx, base.cy, 40, 56), SERIALS[1]: base}


def write_capture(root: Path, cams: dict[str, Camera], images: dict[str, tuple[np.ndarray, np.ndarray]],
                   shift_cx: float = 0.0) -> None:
    c = next(iter(cams.values()))
    k = [[c.fx, 0, c.cx + shift_cx], [0, c.fy, c.cy], [0, 0, 1]]
    (root / "camera_params.json").write_text(json.dumps({
        "world_2_cam": {s: cam.world_to_camera.tolist() for s, cam in cams.items()}, "intrinsics": k,
        "image_size": [c.width, c.height]}))
    rng = np.random.default_rng(7)
    for t in FRAMES:
        folder = root / "timesteps" / f"frame_{t:05d}"
        (folder / "images").mkdir(parents=True, exist_ok=True)
        (folder / "alpha_map").mkdir(exist_ok=True)
        for s, (rgb, alpha) in images.items():
            noisy = np.clip(rgb + rng.normal(0, NOISE, rgb.shape), 0, 1)
            cv2.imwrite(str(folder / "images" / f"cam_{s}.png"), (noisy * 255 + 0.5).astype(np.uint8)[..., ::-1])
            cv2.imwrite(str(folder / "alpha_map" / f"cam_{s}.png"), (alpha * 255 + 0.5).astype(np.uint8))
def ssim_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Wang et al. 2004: Gaussian window sigma 1.5 truncated at 3.5 sigma (radius 5), population moments,
    C1 = (0.01)^2, C2 = (0.03)^2, mean over the valid (border-free) region and the channels."""
    c1, c2, r = 0.01 ** 2, 0.03 ** 2, 5
    x = np.arange(-r, r + 1)
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    k = np.outer(g, g) / np.outer(g, g).sum()
    vals = []

    def f(z: np.ndarray) -> np.ndarray:
        return np.einsum("ijkl,kl->ij", np.lib.stride_tricks.sliding_window_view(z, k.shape), k)

    for c in range(3):
        p, q = a[..., c], b[..., c]
        mp, mq = f(p), f(q)
        vp, vq, cpq = f(p * p) - mp ** 2, f(q * q) - mq ** 2, f(p * q) - mp * mq
        s = ((2 * mp * mq + c1) * (2 * cpq + c2)) / ((mp ** 2 + mq ** 2 + c1) * (vp + vq + c2))
        vals.append(s.mean())
    return float(np.mean(vals))
