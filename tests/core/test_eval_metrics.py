"""Metrics against independent computations written here (PSNR to 0.01 dB, SSIM to 1e-4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from npga_core.evaluation.metrics import composite_background, lpips_status, psnr, score, ssim
from tests.support.captures import ssim_reference


def _pair(seed: int = 0, h: int = 40, w: int = 52) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    ref = gaussian_filter(rng.random((h, w, 3)), (2, 2, 0))
    img = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1)
    return img, ref


def test_psnr_matches_the_definition():
    img, ref = _pair()
    mse = np.mean((img - ref) ** 2)
    assert psnr(img, ref) == pytest.approx(10 * np.log10(1 / mse), abs=0.01)
    assert psnr(ref, ref) == float("inf")


def test_ssim_matches_an_independent_computation():
    for seed in (0, 1):
        img, ref = _pair(seed)
        assert ssim(img, ref) == pytest.approx(ssim_reference(img, ref), abs=1e-4)
    assert ssim(ref, ref) == pytest.approx(1.0, abs=1e-9)


def test_masked_scores_composite_both_images_on_the_background():
    img, ref = _pair(2)
    mask = np.zeros(img.shape[:2])
    mask[10:30, 12:40] = 1.0
    s = score(img, ref, mask, background=(1, 1, 1))
    inside = (img - ref)[10:30, 12:40]
    assert s.masked and s.psnr == pytest.approx(10 * np.log10(1 / (np.sum(inside ** 2) / img.size)), abs=0.01)
    out = composite_background(img, mask, (1, 1, 1))
    assert np.all(out[0, 0] == 1.0) and np.allclose(out[15, 20], img[15, 20])
    # a difference only outside the mask does not count
    other = ref.copy()
    other[:5] = 0.0
    assert score(other, ref, mask).psnr == float("inf")
    assert score(other, ref).psnr < 30


def test_lpips_status_says_why_when_unavailable():
    ok, why = lpips_status()
    assert isinstance(ok, bool) and why
    if not ok:
        assert why.startswith("LPIPS unavailable")
