"""Held-out comparison of the demo's screen-space refinement: raw splats, CNN output and target, with PSNR/SSIM.

``python scripts/refine_images.py [--avatar assets/demo/avatar.npga] [--out docs/images] [--ict PATH]``

Renders the rebuilt demo avatar with the project's GL renderer at the window's default size (550 x 802,
framing the head) for named expressions and held-out random ones (a seed stream the refine stage does not
use) from three directions, refines each image with the same code path as the window and `npga-view render`
(`npga_view.rendering.refinement.refine_frame`), renders the target (the ICT head shaded per pixel,
`npga_core.demo.refine_targets`), prints PSNR (over the head: pixels the target or the splats cover) and SSIM
(whole image) of raw splats and CNN output against the target, and writes comparison images and the latent
views. Needs an OpenGL 4.3 context (EGL is fine) and the ICT-FaceKit data.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from npga_core.camera.cameras import frame_points
from npga_core.demo.canonical import build_canonical
from npga_core.demo.colors import AlbedoModel
from npga_core.demo.expression_map import ExpressionMap
from npga_core.demo.expressions import ExpressionSampler, named_weights
from npga_core.demo.ict import load_ict
from npga_core.demo.refine_stage import psnr, rng_for, ssim
from npga_core.demo.refine_targets import HeadRenderer
from npga_core.demo.sampling import sample_surface
from npga_core.files.loading import DEMO_AVATAR, load_avatar

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "images"
BACKGROUND = (0.93, 0.93, 0.94)
VIEWS = {"front": (0.0, 0.0), "three_quarter": (35.0, 5.0), "left_low": (-25.0, -10.0)}
NAMED = ("neutral", "jaw_open", "smile", "surprise", "blink")
HELD_OUT = 3  # random held-out expressions (seed stream 31)
#: zoomed regions (x0, y0, w, h) of the front view at 550 x 802 for the close-up images
ZOOMS = {"eyes": (115, 240, 320, 120), "mouth": (165, 440, 220, 130)}


def to_u8(img: np.ndarray) -> np.ndarray:
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save(path: Path, img: np.ndarray) -> None:
    cv2.imwrite(str(path), np.ascontiguousarray(to_u8(img)[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])


def label(img: np.ndarray, text: str) -> np.ndarray:
    out = to_u8(img).copy()
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
    return out.astype(np.float32) / 255.0


def metrics(img: np.ndarray, target: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    a = torch.from_numpy(img).permute(2, 0, 1)[None]
    b = torch.from_numpy(target).permute(2, 0, 1)[None]
    return psnr(a, b, torch.from_numpy(mask)[None, None]), ssim(a, b)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--avatar", type=Path, default=DEMO_AVATAR)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--ict", type=Path, default=None)
    p.add_argument("--width", type=int, default=550)
    p.add_argument("--height", type=int, default=802)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    from npga_view.rendering.gl import create_headless_context
    from npga_view.rendering.refinement import Refiner, refine_frame
    from npga_view.rendering.renderer import SplatRenderer

    avatar = load_avatar(args.avatar)
    if avatar.cnn is None or avatar.cloud.latent is None:
        print(f"{args.avatar}: no CNN or latent features (run the refine stage)", file=sys.stderr)
        return 2
    prov = avatar.provenance
    seed, n = int(prov.get("seed", 0)), 20000 if prov.get("quick") else 80000
    head = load_ict(args.ict)
    canon = build_canonical(head, n, rng_for(seed, 1))
    g = rng_for(seed, 1)
    samples = sample_surface(head, n, g)
    target = HeadRenderer(head, canon, AlbedoModel.draw(samples, g))
    emap = ExpressionMap.from_seed(seed, head.expression_names)
    named = named_weights(head.expression_names)
    shots = {k: named[k] for k in NAMED}
    held = ExpressionSampler(head.expression_names).sample(HELD_OUT, rng_for(seed, 31))
    shots |= {f"held_out_{i}": w for i, w in enumerate(held)}
    m = np.asarray(avatar.cloud.means)
    head_pts = m[m[:, 1] > np.percentile(m[:, 1], 12)]
    cams = {k: frame_points(head_pts, args.width, args.height, fov=20.0, direction=d, margin=1.02)
            for k, d in VIEWS.items()}
    ctx = create_headless_context()
    renderer = SplatRenderer(ctx, args.width, args.height)
    refiner = Refiner(ctx)
    refiner.set_avatar(avatar)
    args.out.mkdir(parents=True, exist_ok=True)
    rows, times = [], []
    for name, w in shots.items():
        renderer.set_gaussians(avatar.pose(emap.encode(w)))
        for view, cam in cams.items():
            raw = renderer.render(cam, BACKGROUND)
            timings: dict[str, float] = {}
            cnn = refine_frame(renderer, avatar.cnn, cam, BACKGROUND, rgb=raw, timings=timings)
            times.append(timings["cnn"])
            alpha = renderer.render(cam, mode="alpha")
            t0 = time.perf_counter()
            rgb, cov = target.render(w, cam)
            tgt = rgb + (1.0 - cov[..., None]) * np.asarray(BACKGROUND, np.float32)
            mask = (cov > 0) | (alpha > 1.0 / 255.0)
            (rp, rs), (cp, cs) = metrics(np.clip(raw, 0, 1), tgt, mask), metrics(cnn, tgt, mask)
            rows.append({"expression": name, "view": view, "raw_psnr": round(rp, 2), "cnn_psnr": round(cp, 2),
                         "raw_ssim": round(rs, 4), "cnn_ssim": round(cs, 4)})
            print(json.dumps(rows[-1]), f"(target {time.perf_counter() - t0:.1f} s, CNN {timings['cnn']:.0f} ms)",
                  flush=True)
            if view == "front" and name in ("neutral", "jaw_open", "smile", "surprise", "held_out_0"):
                half = [cv2.resize(label(x, t), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                        for x, t in ((raw, "raw splats"), (cnn, "CNN"), (tgt, "target"))]
                save(args.out / f"refine_{name}.png", np.concatenate(half, axis=1))
                for zname, (x0, y0, zw, zh) in ZOOMS.items():
                    if name not in ("neutral", "jaw_open"):
                        continue
                    crops = [cv2.resize(x[y0:y0 + zh, x0:x0 + zw], None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
                             for x in (raw, cnn, tgt)]
                    save(args.out / f"refine_{name}_{zname}.png", np.concatenate(crops, axis=1))
            if view == "three_quarter" and name == "smile":
                half = [cv2.resize(label(x, t), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                        for x, t in ((raw, "raw splats"), (cnn, "CNN"), (tgt, "target"))]
                save(args.out / f"refine_{name}_{view}.png", np.concatenate(half, axis=1))
    # latent views of the front camera at jaw_open
    renderer.set_gaussians(avatar.pose(emap.encode(named["jaw_open"])))
    lat = [cv2.resize(refiner.latent_view(renderer, cams["front"], (0.0, 0.0, 0.0), v, k), None, fx=0.5, fy=0.5,
                      interpolation=cv2.INTER_AREA) for v, k in (("pca", 0), ("channel", 0), ("channel", 1))]
    save(args.out / "refine_latent.png", np.concatenate(lat, axis=1))
    keys = ("raw_psnr", "cnn_psnr", "raw_ssim", "cnn_ssim")
    groups = {"named": [r for r in rows if not r["expression"].startswith("held")],
              "held_out": [r for r in rows if r["expression"].startswith("held")], "all": rows}
    summary = {g: {k: round(float(np.mean([r[k] for r in rs])), 3) for k in keys} for g, rs in groups.items()}
    summary["cnn_ms_median"] = round(float(np.median(times)), 1)
    print(json.dumps(summary, indent=1))
    refiner.release()
    renderer.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
