"""Image metrics: PSNR, SSIM (scikit-image, Wang et al.'s Gaussian settings) and optional LPIPS.

Images are float arrays (H, W, 3) in [0, 1]. Masking follows the paper and the GaussianAvatars/GHA evaluation
code: outside the mask both the capture and the render are set to the same background colour
(`composite_background`), then the metrics are taken over the whole image, so masked-out pixels count as exact
matches. Unmasked scores compare every pixel as captured.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

#: AlexNet weights torchvision caches for LPIPS' default backbone; LPIPS is only used when this is present
ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"


def _check(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"images must both be (H, W, 3), got {a.shape} and {b.shape}")


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB for data range 1 (inf for identical images)."""
    _check(image, reference)
    mse = float(np.mean((np.asarray(image, np.float64) - np.asarray(reference, np.float64)) ** 2))
    return float("inf") if mse == 0.0 else float(-10.0 * np.log10(mse))


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean SSIM over the colour channels: Gaussian window sigma 1.5, K1 0.01, K2 0.03, data range 1."""
    from skimage.metrics import structural_similarity
    _check(image, reference)
    return float(structural_similarity(
        np.asarray(image, np.float64), np.asarray(reference, np.float64), data_range=1.0, channel_axis=2,
        gaussian_weights=True, sigma=1.5, use_sample_covariance=False))


def composite_background(image: np.ndarray, mask: np.ndarray, background: npt.ArrayLike = (1.0, 1.0,
                         1.0)) -> np.ndarray:
    """`image` inside `mask` (H, W) in [0, 1], `background` outside: image * m + bg * (1 - m)."""
    m = np.clip(np.asarray(mask, np.float64), 0.0, 1.0)[..., None]
    return np.asarray(image, np.float64) * m + np.asarray(background, np.float64) * (1.0 - m)


def lpips_status() -> tuple[bool, str]:
    """Whether LPIPS can run without any download, and why not when it cannot."""
    if importlib.util.find_spec("lpips") is None:
        return False, "LPIPS unavailable: the 'lpips' package is not installed (pip install 'npga-view[lpips]')"
    import torch
    weights = Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_WEIGHTS
    if not weights.is_file():
        return False, f"LPIPS unavailable: AlexNet weights not found at {weights} (nothing is downloaded)"
    return True, "LPIPS (AlexNet)"


class Lpips:
    """LPIPS (AlexNet) on the CPU, built only from weights already on the machine (see `lpips_status`)."""

    def __init__(self) -> None:
        ok, why = lpips_status()
        if not ok:
            raise RuntimeError(why)
        import lpips
        self.net = lpips.LPIPS(net="alex", verbose=False).eval()

    def __call__(self, image: np.ndarray, reference: np.ndarray) -> float:
        import torch
        _check(image, reference)

        def t(x: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.asarray(x, np.float32)).permute(2, 0, 1)[None] * 2.0 - 1.0

        with torch.no_grad():
            return float(self.net(t(image), t(reference)).item())


@dataclass
class Scores:
    """One image pair's scores; lpips is None when LPIPS is unavailable."""

    psnr: float
    ssim: float
    lpips: float | None
    masked: bool


def score(render: np.ndarray, capture: np.ndarray, mask: np.ndarray | None = None, background: npt.ArrayLike = (1.0,
          1.0, 1.0),
          lpips_net: Lpips | None = None) -> Scores:
    """PSNR, SSIM (and LPIPS) of `render` against `capture`; with `mask`, both composited on `background`."""
    if mask is not None:
        render, capture = composite_background(render, mask, background), composite_background(capture, mask,
                                                                                                 background)
    lp = lpips_net(render, capture) if lpips_net is not None else None
    return Scores(psnr(render, capture), ssim(render, capture), lp, mask is not None)
