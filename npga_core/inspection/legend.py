"""Pictures of renders for people: a render mode's image as an 8-bit picture (`to_display`) and the legend strip
under an inspection picture (`legend_strip`: label, colour bar and range, or notes), with the one number format
of colour-map values (`format_value`, also the Inspect panel's). Used by `npga-view render`."""

from __future__ import annotations

import numpy as np

from npga_core.inspection.colouring import colour_map

LEGEND_HEIGHT = 64


def to_display(image: np.ndarray, mode: str, alpha: np.ndarray | None = None) -> np.ndarray:
    """An (H,W,3) uint8 RGB picture of a render: colour clipped; depth (surface depth = expected depth / alpha)
    near-bright over its range; alpha grey; latent's first three channels scaled by their range."""
    if mode == "rgb":
        rgb = image
    elif mode == "depth":
        surface = image / np.maximum(alpha, 1e-6) if alpha is not None else image
        mask = (alpha > 0.5) if alpha is not None else image > 0
        rgb = np.zeros(image.shape + (3,), np.float32)
        if mask.any():
            lo, hi = np.percentile(surface[mask], [1, 99])
            norm = 1.0 - np.clip((surface - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
            rgb[:] = np.where(mask, 0.1 + 0.9 * norm, 0.0)[..., None]
    elif mode == "alpha":
        rgb = np.repeat(image[..., None], 3, axis=2)
    else:
        chans = image[..., :3]
        if chans.shape[2] < 3:
            chans = np.concatenate([chans, np.zeros(chans.shape[:2] + (3 - chans.shape[2],), np.float32)], 2)
        lo = chans.reshape(-1, 3).min(0)
        hi = chans.reshape(-1, 3).max(0)
        rgb = (chans - lo) / np.maximum(hi - lo, 1e-9)
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def format_value(v: float) -> str:
    """A colour-map value as shown: 3 significant digits, exponent notation outside [1e-3, 1e4)."""
    return f"{v:.3g}" if v == 0 or 1e-3 <= abs(v) < 1e4 else f"{v:.2e}"


def _wrap(text: str, width_px: int, scale: float) -> list[str]:
    import cv2

    lines, line = [], ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width_px:
            lines.append(line)
            line = word
        else:
            line = trial
    return lines + ([line] if line else [])


def legend_strip(width: int, label: str, cmap: str | None = None, lo: float = 0.0, hi: float = 1.0,
                 notes: tuple[str, ...] = (), height: int = LEGEND_HEIGHT) -> np.ndarray:
    """An (height, width, 3) uint8 RGB legend: the label, then a colour bar from lo to hi with their values (when
    `cmap` is given) or the notes as text."""
    import cv2

    strip = np.full((height, width, 3), 24, np.uint8)
    font, scale, white = cv2.FONT_HERSHEY_SIMPLEX, 0.38, (235, 235, 235)
    y = 14
    for line in _wrap(label, width - 16, scale)[:2]:
        cv2.putText(strip, line, (8, y), font, scale, white, 1, cv2.LINE_AA)
        y += 14
    if cmap is not None:
        bar = colour_map(np.linspace(0.0, 1.0, width - 16), cmap)
        y0 = min(y - 6, height - 30)
        strip[y0:y0 + 12, 8:width - 8] = (bar * 255 + 0.5).astype(np.uint8)[None]
        ty = y0 + 26
        cv2.putText(strip, format_value(lo), (8, ty), font, scale, white, 1, cv2.LINE_AA)
        mid = format_value(0.5 * (lo + hi))
        tw = cv2.getTextSize(mid, font, scale, 1)[0][0]
        cv2.putText(strip, mid, ((width - tw) // 2, ty), font, scale, white, 1, cv2.LINE_AA)
        tw = cv2.getTextSize(format_value(hi), font, scale, 1)[0][0]
        cv2.putText(strip, format_value(hi), (width - 8 - tw, ty), font, scale, white, 1, cv2.LINE_AA)
    else:
        for note in notes:
            for line in _wrap(note, width - 16, scale):
                if y < height - 2:
                    cv2.putText(strip, line, (8, y), font, scale, (190, 190, 190), 1, cv2.LINE_AA)
                y += 14
    return strip
