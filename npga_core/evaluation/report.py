"""The files of an `evaluate` report: metrics.csv, summary.md, metrics.png, worst views, problems.txt.

The worst views' difference images are the error heatmap of `compare.py` (the Compare panel's), with its colour
bar. An image that cannot be written is an `ImageWriteError` (one line naming the file)."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from npga_core.errors import shown
from npga_core.evaluation.compare import DEFAULT_VMAX, error_map, heatmap
from npga_core.files.atomic import atomic_write
from npga_core.files.image_file import write_image


@dataclass
class Row:
    """One scored view of the report."""

    frame: int
    camera: str
    psnr: float
    ssim: float
    lpips: float | None
    masked: str


COLOURS = [(66, 135, 245), (245, 105, 66), (60, 180, 75), (200, 60, 200), (240, 200, 40), (40, 200, 200)]


def _fmt(x: float | None, digits: int) -> str:
    return "n/a" if x is None else ("inf" if x == float("inf") else f"{x:.{digits}f}")


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None]
    return None if not vals else float(np.mean(vals))


def write_report(out: Path, rows: list, worst: list, problems: list[str], notes: list[str],
                 protocol: str | None = None, avatar: str = "avatar") -> str:
    """Write the report files into `out`; returns the summary text (also summary.md)."""
    table = io.StringIO(newline="")
    w = csv.writer(table)
    w.writerow(["frame", "camera", "psnr", "ssim", "lpips", "masked"])
    for r in rows:
        w.writerow([r.frame, shown(r.camera), f"{r.psnr:.6f}", f"{r.ssim:.6f}",
                    "" if r.lpips is None else f"{r.lpips:.6f}", r.masked])
    _text(out / "metrics.csv", table.getvalue())
    _text(out / "problems.txt", "".join(shown(p) + "\n" for p in problems))
    lines = ["| camera | views | PSNR (dB) | SSIM | LPIPS |", "|---|---|---|---|---|"]
    for cam in sorted({r.camera for r in rows}):
        sel = [r for r in rows if r.camera == cam]
        lines.append(f"| {cam} | {len(sel)} | {_fmt(_mean([r.psnr for r in sel]), 2)} | "
                     f"{_fmt(_mean([r.ssim for r in sel]), 4)} | {_fmt(_mean([r.lpips for r in sel]), 4)} |")
    overall = (_mean([r.psnr for r in rows]), _mean([r.ssim for r in rows]), _mean([r.lpips for r in rows]))
    lines.append(f"| **all** | {len(rows)} | {_fmt(overall[0], 2)} | {_fmt(overall[1], 4)} | "
                 f"{_fmt(overall[2], 4)} |")
    text = ["# Evaluation", "", *[f"- {n}" for n in notes], f"- masking: {rows[0].masked if rows else 'n/a'}",
            f"- problems: {len(problems)} (problems.txt)", "", *lines]
    if protocol == "npga":
        text += ["", "Laid out like the paper's Table 1 (held-out camera):", "",
                 "| Method | PSNR↑ | SSIM↑ | LPIPS↓ |", "|---|---|---|---|",
                 f"| {Path(avatar).name} | {_fmt(overall[0], 2)} | {_fmt(overall[1], 3)} | {_fmt(overall[2], 3)} |"]
    summary = "\n".join(text) + "\n"
    _text(out / "summary.md", summary)
    if rows:
        write_plot(out / "metrics.png", rows)
    for k, (_, f, c, image, render) in enumerate(worst):
        write_triplet(out, f"worst{k + 1}_frame{f}_cam{c}", image, render)
    return summary


def _text(path: Path, text: str) -> None:
    """UTF-8 text written through the output gate (atomic; a FIFO or folder in its place refused)."""
    data = text.encode("utf-8", "backslashreplace")
    atomic_write(path, lambda fh: fh.write(data))


def _png(path: Path, rgb: np.ndarray) -> None:
    img = np.clip(np.asarray(rgb) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    write_image(path, np.ascontiguousarray(img[..., ::-1]))


def write_triplet(out: Path, stem: str, image: np.ndarray, render: np.ndarray) -> None:
    """capture, render and their difference as PNGs: the error heatmap (mean absolute error over the channels,
    0..`DEFAULT_VMAX` on inferno, with its colour bar) that the Compare panel shows."""
    _png(out / f"{stem}_image.png", image)
    _png(out / f"{stem}_render.png", render)
    _png(out / f"{stem}_diff.png", heatmap(error_map(render, image), DEFAULT_VMAX))


def write_plot(path: Path, rows: list, width: int = 900, panel: int = 240) -> None:
    """PSNR and SSIM over frames, one line per camera, drawn with OpenCV."""
    import cv2
    metrics = [("PSNR (dB)", [r.psnr for r in rows]), ("SSIM", [r.ssim for r in rows])]
    if any(r.lpips is not None for r in rows):
        metrics.append(("LPIPS", [r.lpips for r in rows]))
    canvas = np.full((panel * len(metrics), width, 3), 255, np.uint8)
    frames = sorted({r.frame for r in rows})
    cams = sorted({r.camera for r in rows})
    left, right, top, bottom = 70, 20, 30, 30
    x_of = {f: left + (width - left - right) * (i / max(len(frames) - 1, 1)) for i, f in enumerate(frames)}
    for m, (name, values) in enumerate(metrics):
        y0 = m * panel
        finite = [v for v in values if v is not None and np.isfinite(v)]
        lo, hi = (min(finite), max(finite)) if finite else (0.0, 1.0)
        if hi - lo < 1e-9:
            lo, hi = lo - 0.5 * max(abs(lo), 1e-3), hi + 0.5 * max(abs(hi), 1e-3)
        def y_of(v: float, y0: int = y0, lo: float = lo, hi: float = hi) -> int:
            v = min(max(v, lo), hi)
            return int(y0 + top + (panel - top - bottom) * (1 - (v - lo) / (hi - lo)))
        cv2.rectangle(canvas, (left, y0 + top), (width - right, y0 + panel - bottom), (180, 180, 180), 1)
        cv2.putText(canvas, name, (left, y0 + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
        for v in (lo, hi):
            cv2.putText(canvas, f"{v:.3g}", (5, y_of(v) + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                        cv2.LINE_AA)
        for k, cam in enumerate(cams):
            col = COLOURS[k % len(COLOURS)]
            pts = [(int(x_of[r.frame]), y_of(val)) for r, val in zip(rows, values, strict=True)
                   if r.camera == cam and val is not None and np.isfinite(val)]
            for a, b in zip(pts, pts[1:], strict=False):
                cv2.line(canvas, a, b, col, 2, cv2.LINE_AA)
            for p in pts:
                cv2.circle(canvas, p, 3, col, -1, cv2.LINE_AA)
            if m == 0:
                cv2.putText(canvas, shown(str(cam)), (width - right - 150, y0 + 20 + 16 * k), cv2.FONT_HERSHEY_SIMPLEX,
                            0.45, col, 1, cv2.LINE_AA)
        cv2.putText(canvas, f"frames {frames[0]}..{frames[-1]}", (left, y0 + panel - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, np.ascontiguousarray(canvas[..., ::-1]))
