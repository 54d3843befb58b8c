"""Scenes, cameras and the reference images the GL renderer tests share: a random cloud, an off-centre camera
with fx != fy, the independent rasterizer's image (tests/support/reference_rasterizer.py) and PSNR."""

from __future__ import annotations

import numpy as np

from npga_core.camera.cameras import Camera, look_at
from npga_core.model.gaussians import PosedGaussians, normalize_quats
from tests.support.reference_rasterizer import rasterize

W, H = 128, 160
#: how far the renderer's colour images may be from float blending: its colour target keeps 16 bits at half
#: scale (npga_view/rendering/targets.py), a step of 3e-5 rounded at every blended layer
COLOUR_ATOL = 3e-4


def random_cloud(n: int, seed: int = 0, sh_degree: int = 0, spread: float = 0.5, scale=(0.01, 0.12),
                 sh_rest: float = 0.3, latent_dim: int = 0, centre=(0.0, 0.0, 0.0)) -> PosedGaussians:
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    sh = rng.normal(0.0, 0.7, (n, k, 3))
    sh[:, 1:] *= sh_rest / 0.7
    return PosedGaussians(
        means=(rng.normal(0.0, spread, (n, 3)) + centre).astype(np.float32),
        quats=normalize_quats(rng.normal(size=(n, 4))),
        scales=np.exp(rng.uniform(np.log(scale[0]), np.log(scale[1]), (n, 3))).astype(np.float32),
        opacities=rng.uniform(0.05, 1.0, n).astype(np.float32),
        sh=sh.astype(np.float32),
        latent=rng.normal(size=(n, latent_dim)).astype(np.float32) if latent_dim else None,
    )


def reference(g: PosedGaussians, camera: Camera, **kw) -> dict[str, np.ndarray]:
    return rasterize(g.means, g.quats, g.scales, g.opacities, g.sh, camera, latent=g.latent, **kw)


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    mse = float(np.mean((np.clip(a, 0, peak) - np.clip(b, 0, peak)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(peak * peak / mse)


def off_centre_camera(eye, target=(0.0, 0.0, 0.0), fov=40.0) -> Camera:
    """A look_at camera with fx != fy and a principal point away from the image centre."""
    cam = look_at(eye, target, (0.0, 1.0, 0.0), fov, W, H)
    return Camera(cam.world_to_camera, cam.fx * 1.07, cam.fy, W / 2 + 5.3, H / 2 - 3.7, W, H)


def accumulated(renderer) -> np.ndarray:
    """The renderer's finished image (RGBA float, premultiplied, before `present`), a copy."""
    return renderer.front_rgba().copy()
