"""Two images of one view shown against each other: side by side, a wipe, a blend, or a difference heatmap.

Used by the window's Compare panel (capture vs render, avatar A vs avatar B) and by `evaluate`'s worst-view
triplets. Images are float (H, W, 3) in [0, 1]; every mode returns an image of the same kind, so the window
presents it like any other image and a test reads it back pixel for pixel.

The heatmap shows the per-pixel error |a - b| averaged over the colour channels, mapped linearly from 0 to
`vmax` onto the perceptually ordered "inferno" colour map (dark: equal; yellow: `vmax` or more), with a colour bar
on the left edge labelled 0 and `vmax`. A fixed `vmax` (not the image's own maximum) keeps frames comparable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Mode = Literal["a", "b", "side", "wipe", "blend", "difference"]
MODES: tuple[Mode, ...] = ("a", "b", "side", "wipe", "blend", "difference")
#: the default top of the heatmap's scale: a mean absolute error of 0.25 (of the 0..1 range) shows as yellow
DEFAULT_VMAX = 0.25
BAR_WIDTH = 0.06  # of the image width
MIN_BAR_IMAGE = (160, 100)  # smaller images get no colour bar


@dataclass(frozen=True)
class CompareSettings:
    """How two images are composed: `mode`, the wipe divider / blend weight `t` in [0, 1], the heatmap's top."""

    mode: Mode = "wipe"
    t: float = 0.5
    vmax: float = DEFAULT_VMAX

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown compare mode {self.mode!r}; one of {', '.join(MODES)}")
        if not (np.isfinite(self.t) and 0.0 <= self.t <= 1.0):
            raise ValueError(f"compare position must be in [0, 1], got {self.t!r}")
        if not (np.isfinite(self.vmax) and self.vmax > 0.0):
            raise ValueError(f"heatmap top must be positive, got {self.vmax!r}")


def _inferno() -> np.ndarray:
    """OpenCV's inferno table as (256, 3) RGB floats."""
    import cv2
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_INFERNO)[:, 0, ::-1]
    return lut.astype(np.float32) / 255.0


def error_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel mean absolute error over the colour channels, (H, W) float32."""
    _check(a, b)
    return np.mean(np.abs(np.asarray(a, np.float32) - np.asarray(b, np.float32)), axis=2)


def heatmap(err: np.ndarray, vmax: float = DEFAULT_VMAX, bar: bool = True) -> np.ndarray:
    """`err` (H, W) coloured with inferno over [0, vmax]; with `bar`, a labelled colour bar on the left edge."""
    idx = np.clip(np.rint(np.asarray(err, np.float32) / vmax * 255.0), 0, 255).astype(np.intp)
    out = _inferno()[idx]
    if bar:
        _draw_bar(out, vmax)
    return out


def _draw_bar(img: np.ndarray, vmax: float) -> None:
    """A vertical colour bar (0 at the bottom, vmax at the top) with its two labels, drawn into `img`."""
    import cv2
    h, w = img.shape[:2]
    bw = max(4, int(w * BAR_WIDTH))
    top, bottom = max(2, h // 20), h - max(2, h // 20)
    if w < MIN_BAR_IMAGE[0] or h < MIN_BAR_IMAGE[1]:  # a thumbnail: the bar would hide the image
        return
    x0 = max(2, w // 100)  # at the left edge (the window's statistics overlay sits top right)
    ramp = np.linspace(255, 0, bottom - top).astype(np.intp)
    img[top:bottom, x0:x0 + bw] = _inferno()[ramp][:, None, :]
    img[top:bottom, x0 - 1] = img[top:bottom, x0 + bw] = 1.0
    scale = max(0.3, h / 900)
    outline, fill = np.zeros((h, w), np.uint8), np.zeros((h, w), np.uint8)  # putText draws on 8-bit images only
    for text, y in ((f"{vmax:g}", top + int(14 * scale)), ("0", bottom - 3)):
        (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        org = (min(x0 + bw + 4, w - tw), y)
        cv2.putText(outline, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, 3, cv2.LINE_AA)
        cv2.putText(fill, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, 1, cv2.LINE_AA)
    img *= 1.0 - outline[..., None] / 255.0  # black outline, white letters: readable on any colour
    img += fill[..., None] / 255.0 * (1.0 - img)


def divider_column(width: int, t: float) -> int:
    """The first column of the wipe's right-hand image: columns < it show `a`, the rest `b`."""
    return int(round(np.clip(t, 0.0, 1.0) * width))


def compose(a: np.ndarray, b: np.ndarray, settings: CompareSettings = CompareSettings()) -> np.ndarray:
    """`a` and `b` (H, W, 3) composed as `settings.mode` says; float32 (H, W, 3), or (H, 2W, 3) side by side.

    a/b: one image alone. side: a | b. wipe: a left of the divider at `t` of the width, b right of it, the
    divider line drawn white. blend: (1 - t) a + t b. difference: the error heatmap with its colour bar."""
    _check(a, b)
    a32, b32 = np.asarray(a, np.float32), np.asarray(b, np.float32)
    mode, t = settings.mode, settings.t
    if mode == "a":
        return a32.copy()
    if mode == "b":
        return b32.copy()
    if mode == "side":
        return np.concatenate([a32, b32], axis=1)
    if mode == "blend":
        return (1.0 - t) * a32 + t * b32
    if mode == "difference":
        return heatmap(error_map(a32, b32), settings.vmax)
    out = b32.copy()
    x = divider_column(a32.shape[1], t)
    out[:, :x] = a32[:, :x]
    if 0 < x < out.shape[1]:
        out[:, x - 1:x + 1 if x + 1 <= out.shape[1] else x] = 1.0
    return out


def _check(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"images must both be (H, W, 3) of one size, got {a.shape} and {b.shape}")
