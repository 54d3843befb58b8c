"""Where a fitted LAM web avatar loses against the exact pose without the CNN, attribute by attribute, in npga-view's
own renderer (no browser: the player's own difference is bench_lam_web.py's).

    python benchmarks/bench_lam_web_loss.py [AVATAR] [--frames N] [--json out.json] [--images DIR]

AVATAR (default demo) is fitted as `export --format lam-zip` fits it (generated training frames). For the
expressions of bench_lam_web.py, from the front and 30 degrees to the side at 0.62 m (400 x 500, white), the exact
pose (b) is compared (masked PSNR) with: the export (fitted centres, every other attribute at the neutral face,
the colour baked from the front, 8-bit), and the exact pose with one attribute replaced by the export's (centres
fitted; scales, rotations, opacity or colour held at the neutral face; colour baked from the front from its own SH).
Then static colours other than the neutral one (all with fitted centres and neutral shapes, 8-bit): the
visibility-weighted least squares over the training frames, half neutral and half the per-Gaussian mid-range of
the training frames' colours, and an oracle that knows the four test expressions (the mean of their own colours).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_lam_web import EXPRESSIONS  # noqa: E402

W, H, DISTANCE = 400, 500, 0.62
EYES_YAW, EYES_PITCH = (-30, 0, 30), (-15, 0, 15)


def visible(means: np.ndarray, eye: np.ndarray, mid: np.ndarray, px: float = 0.003, tau: float = 0.004) -> np.ndarray:
    """Centres within `tau` of the nearest centre in their `px`-sized cell as seen from `eye` (a point z-buffer)."""
    f = (mid - eye) / np.linalg.norm(mid - eye)
    r = np.cross(f, [0.0, 1.0, 0.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    v = means - eye
    z = v @ f
    ix = np.round((v @ r) / z * DISTANCE / px).astype(int)
    iy = np.round((v @ u) / z * DISTANCE / px).astype(int)
    ix -= ix.min()
    iy -= iy.min()
    key = iy * (ix.max() + 1) + ix
    zb = np.full(key.max() + 1, np.inf)
    np.minimum.at(zb, key, z)
    return z <= zb[key] + tau


def seen_colour(sh: np.ndarray, means: np.ndarray, eye: np.ndarray) -> np.ndarray:
    from npga_core.model.sh import sh_basis

    d = means - eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1
    return np.clip(np.einsum("nk,nkc->nc", sh_basis(d, degree), sh) + 0.5, 0.0, 1.0)


def eye_at(mid: np.ndarray, yaw: float, pitch: float = 0.0) -> np.ndarray:
    y, p = np.radians(yaw), np.radians(pitch)
    return mid + DISTANCE * np.array([np.sin(y) * np.cos(p), np.sin(p), np.cos(y) * np.cos(p)])


def training_colours(pose, rows: np.ndarray, mid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(least-squares colour weighted by visibility x opacity over 9 views, per-Gaussian mid-range of the colours
    seen from 3 frontal views) over the training frames; NaN where never seen."""
    acc, wsum = np.zeros((n, 3)), np.zeros(n)
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    for row in rows:
        p = pose(row)
        means = p.means.astype(np.float64)
        for yaw in EYES_YAW:
            for pitch in EYES_PITCH:
                eye = eye_at(mid, yaw, pitch)
                seen = visible(means, eye, mid)
                col = seen_colour(p.sh, means, eye)
                v = seen * p.opacities
                acc += v[:, None] * col
                wsum += v
                if pitch == 0:
                    s = seen & (p.opacities > 0.05)
                    lo[s], hi[s] = np.minimum(lo[s], col[s]), np.maximum(hi[s], col[s])
    with np.errstate(invalid="ignore", divide="ignore"):
        return acc / wsum[:, None], (lo + hi) / 2.0


def main() -> int:
    import imageio.v3 as iio

    from npga_core.camera.cameras import look_at
    from npga_core.files.loading import load_avatar
    from npga_core.model.gaussians import PosedGaussians, rgb_to_sh0
    from npga_core.posing import lam_fit
    from npga_view.rendering.factory import create_renderer
    from npga_view.rendering.gl import create_headless_context
    from tests.support.web_player import masked_psnr

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("avatar", nargs="?", default="demo")
    p.add_argument("--frames", type=int, default=240, help="training frames of the fit (default 240, as export)")
    p.add_argument("--json", type=Path)
    p.add_argument("--images", type=Path, help="per expression: exact | export | |difference| x 4")
    args = p.parse_args()
    a = load_avatar(args.avatar)
    names = lam_fit.target_names(a)
    train, _ = lam_fit.plan_frames([], None, names, args.frames, 4)
    web, shift, _ = lam_fit.fit_web_avatar(a, names, train)

    def pose(w: np.ndarray) -> PosedGaussians:
        return a.pose(lam_fit.frame_vectors(a, names, np.asarray(w)[None])[0])

    def vec(e: dict) -> np.ndarray:
        return np.array([e.get(n, 0.0) for n in names])

    p0 = pose(np.zeros(len(names)))
    rest = p0.means.astype(np.float64)
    mid = (rest.max(axis=0) + rest.min(axis=0)) / 2.0
    neutral = lam_fit.baked_rgb(p0.sh, rest).astype(np.float64)
    ls, midrange = training_colours(pose, train.weights[:: max(1, len(train.weights) // 60)], mid, len(a))
    poses = {k: pose(vec(e)) for k, e in EXPRESSIONS.items()}
    oracle = np.mean([seen_colour(q.sh, q.means.astype(np.float64), eye_at(mid, 0)) for q in poses.values()], 0)
    colours = {"neutral (the export)": neutral, "least squares over training": np.where(np.isnan(ls), neutral, ls),
               "half neutral, half training mid-range": 0.5 * neutral + 0.5 * np.where(np.isnan(midrange), neutral,
                                                                                         midrange),
               "oracle: mean of the 4 test expressions": oracle}
    r = create_renderer(create_headless_context(), W, H)
    cams = {yaw: look_at(eye_at(mid, yaw), mid, fov_y_deg=40, width=W, height=H) for yaw in (0, 30)}

    def draw(q: PosedGaussians, yaw: int) -> np.ndarray:
        r.set_gaussians(q)
        return (np.clip(r.render(cams[yaw], (1.0, 1.0, 1.0), "rgb"), 0, 1) * 255 + 0.5).astype(np.uint8)

    def sh_of(rgb: np.ndarray) -> np.ndarray:
        q8 = np.floor(np.clip(rgb, 0.0, 1.0) * 255.0) / 255.0  # as the player stores it
        return np.ascontiguousarray(rgb_to_sh0(q8)[:, None, :], np.float32)

    rows = []
    for label, e in EXPRESSIONS.items():
        q = poses[label]
        fitted = np.float32(web.centres(e) - shift)
        own = sh_of(lam_fit.baked_rgb(q.sh, q.means))
        attrs = {"export": dict(means=fitted, quats=p0.quats, scales=p0.scales, opacities=p0.opacities,
                                sh=sh_of(neutral)),
                 "centres fitted": dict(means=fitted), "scales neutral": dict(scales=p0.scales),
                 "rotations neutral": dict(quats=p0.quats), "opacity neutral": dict(opacities=p0.opacities),
                 "colour neutral": dict(sh=sh_of(neutral)), "colour baked from its own SH": dict(sh=own)}
        attrs.update({f"static colour: {k}": dict(means=fitted, quats=p0.quats, scales=p0.scales,
                                                  opacities=p0.opacities, sh=sh_of(c)) for k, c in colours.items()})
        for yaw in cams:
            exact = draw(q, yaw)
            row: dict = {"expression": label, "yaw": yaw}
            for k, change in attrs.items():
                fields = dict(means=q.means, quats=q.quats, scales=q.scales, opacities=q.opacities, sh=q.sh)
                img = draw(PosedGaussians(**{**fields, **change}), yaw)
                row[k] = round(masked_psnr(exact, img)[0], 2)
                if args.images and yaw == 0 and k == "export":
                    args.images.mkdir(parents=True, exist_ok=True)
                    diff = np.clip(np.abs(exact.astype(int) - img.astype(int)) * 4, 0, 255).astype(np.uint8)
                    iio.imwrite(args.images / f"loss_{label.split(',')[0].replace(' ', '_')}.png",
                                np.concatenate([exact, img, diff], axis=1))
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
