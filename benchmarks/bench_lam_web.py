"""An exported LAM web avatar in LAM's own web player against npga-view's renders (masked PSNR per expression).

    python benchmarks/bench_lam_web.py AVATAR.zip [--source demo] [--json out.json] [--images DIR]

AVATAR.zip is what `npga-view export SOURCE --format lam-zip --out AVATAR.zip` wrote (its AVATAR.fidelity.json
gives the translation into LAM's frame). For each expression (neutral, jaw open, smile, blink with brows up) the
page npga_view/web/ plays the zip in headless chromium (tests/support/web_player.py: the player from npm,
SwiftShader WebGL) from a frontal camera 0.62 m away, and the frame is compared, over the pixels either image
covers, with `npga-view render` of the zip (the two renderers), of SOURCE without its CNN (what the export loses
plus the renderers) and with it. Needs chromium and npm (skips with a message, exit 0, without them).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WIDTH, HEIGHT = 400, 500
CAMERA = {"position": [0.0, 1.65, 0.62], "target": [0.0, 1.65, 0.0]}
EXPRESSIONS: dict[str, dict[str, float]] = {
    "neutral": {},
    "jaw open": {"jawOpen": 0.8},
    "smile": {"mouthSmileLeft": 0.9, "mouthSmileRight": 0.9, "cheekSquintLeft": 0.3, "cheekSquintRight": 0.3},
    "blink, brows up": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0, "browInnerUp": 0.8, "browOuterUpLeft": 0.6,
                        "browOuterUpRight": 0.6},
}


def _render(avatar: str, camera: dict, weights: dict[str, float], out: Path, cnn: bool = False) -> np.ndarray:
    import imageio.v3 as iio

    from npga_view.cli.main import main

    cam = out.with_suffix(".camera.json")
    cam.write_text(json.dumps(camera))
    argv = ["render", avatar, "--camera", str(cam), "--background", "1,1,1", "--no-legend", "--out", str(out)]
    argv += [] if cnn else ["--no-cnn"]
    # all weights 0 for the neutral face: without --expr, render poses at the mean code of the expression space
    argv += ["--expr", ",".join(f"{k}={v}" for k, v in (weights or {"jawOpen": 0.0}).items())]
    if main(argv) != 0:
        raise SystemExit(f"render {avatar} failed")
    return iio.imread(out)[..., :3]


def main() -> int:
    import _pytest.outcomes
    import imageio.v3 as iio

    from tests.support.web_player import masked_psnr, opencv_camera, shoot

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("zip", type=Path)
    p.add_argument("--source", default="demo", help="the avatar the zip was exported from (default demo)")
    p.add_argument("--json", type=Path)
    p.add_argument("--images", type=Path, help="write player | render of SOURCE without CNN | with CNN per expression")
    args = p.parse_args()
    report = args.zip.with_name(args.zip.stem + ".fidelity.json")
    shift = np.asarray(json.loads(report.read_text())["translation_m"]) if report.is_file() else np.zeros(3)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        for i, (label, weights) in enumerate(EXPRESSIONS.items()):
            try:
                shot = shoot(args.zip, weights, CAMERA, WIDTH, HEIGHT, t / f"profile{i}", timeout_s=400)
            except _pytest.outcomes.Skipped as e:
                print(f"skipped: {e.msg}")
                return 0
            cam = opencv_camera(shot, WIDTH, HEIGHT)
            back = np.eye(4)
            back[:3, 3] = shift  # LAM's frame = the source's frame + shift
            source_cam = dict(cam, world_to_camera=(np.asarray(cam["world_to_camera"]) @ back).tolist())
            zip_img = _render(str(args.zip), cam, weights, t / f"zip{i}.png")
            plain = _render(args.source, source_cam, weights, t / f"plain{i}.png")
            refined = _render(args.source, source_cam, weights, t / f"cnn{i}.png", cnn=True)
            player = shot["image"]
            row = {"expression": label, "weights": weights, "seconds": round(shot["seconds"], 1),
                   "stable": shot["stable"], "player_vs_render_of_zip_db": masked_psnr(player, zip_img)[0],
                   "player_vs_source_no_cnn_db": masked_psnr(player, plain)[0],
                   "player_vs_source_cnn_db": masked_psnr(player, refined)[0],
                   "render_of_zip_vs_source_no_cnn_db": masked_psnr(zip_img, plain)[0]}
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.images:
                args.images.mkdir(parents=True, exist_ok=True)
                iio.imwrite(args.images / f"lam_web_{i}.png", np.concatenate([player, plain, refined], axis=1))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
