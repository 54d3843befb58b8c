"""The exported LAM zip in a real browser: npga_view/web/ drives LAM's own web player (npm
gaussian-splat-renderer-for-lam 0.0.8, installed at test time into .web-player/) in headless chromium (SwiftShader
WebGL) at given ARKit weights and a fixed camera; its frame is compared with `npga-view render --no-cnn` of the same
pose and camera (PSNR over the pixels either image covers). Skips with a reason where chromium or npm is missing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from npga_view.cli.main import main
from tests.support.lam_layout import big_jaw, write_lam_zip
from tests.support.lam_player import lam_data
from tests.support.web_player import masked_psnr, opencv_camera, shoot

WIDTH, HEIGHT = 320, 400
CAMERA = {"position": [0.0, 1.65, 0.55], "target": [0.0, 1.65, 0.0]}


def render(zip_path: Path, weights: dict[str, float], shot: dict, out: Path) -> np.ndarray:
    """`npga-view render ZIP --no-cnn` at the player's camera and the same weights, on the player's white."""
    import imageio.v3 as iio

    cam = out.with_suffix(".camera.json")
    cam.write_text(json.dumps(opencv_camera(shot, WIDTH, HEIGHT)))
    expr = ",".join(f"{k}={v}" for k, v in (weights or {"jawOpen": 0.0}).items())  # all 0, not the mean code
    argv = ["render", str(zip_path), "--no-cnn", "--camera", str(cam), "--background", "1,1,1", "--no-legend",
            "--out", str(out), "--expr", expr]
    assert main(argv) == 0
    return iio.imread(out)[..., :3]


@pytest.mark.slow
def test_page_plays_an_exported_zip_as_npga_view_renders_it(tmp_path: Path) -> None:
    """A LAM-layout avatar exported by `export --format lam-zip`, played by LAM's player at weights with a rescaled
    channel (jawOpen x1.2 in the player) and one beyond 1: the frame matches npga-view's render of the same zip at
    the same weights (>= 28 dB), and is farther from a render at 1.2 x jawOpen (the player's scale applied twice,
    as a reused weights object would do)."""
    src = write_lam_zip(tmp_path / "src.zip", n=3000, tamper_arrays=big_jaw)
    out = tmp_path / "web.zip"
    assert main(["export", str(src), "--format", "lam-zip", "--out", str(out)]) == 0
    weights = {"jawOpen": 0.9, "eyeBlinkLeft": 1.2, "mouthClose": 0.5}
    shot = shoot(out, weights, CAMERA, WIDTH, HEIGHT, tmp_path / "profile")
    assert shot["stable"], "the player's frames did not settle"
    assert all(r in ("/index.html", "/page.js", "/avatar.zip", "/favicon.ico") or r.startswith("/player/")
               for r in shot["requests"])
    ours = render(out, weights, shot, tmp_path / "ours.png")
    right, covered = masked_psnr(shot["image"], ours)
    twice = render(out, {**weights, "jawOpen": 0.9 * 1.2}, shot, tmp_path / "twice.png")
    wrong, _ = masked_psnr(shot["image"], twice)
    assert covered > 0.05
    assert right >= 28.0 and right > wrong + 3.0, (right, wrong)  # measured 30.5 and 24.5 dB


@pytest.mark.parametrize("weights", [{}, {"jawOpen": 0.8, "mouthSmileLeft": 0.6}])
def test_real_p2_1_plays_the_same_after_import_and_export(weights: dict, tmp_path: Path) -> None:
    """aigc3d/LAM_WebRender's p2-1.zip, imported and exported: the player shows the export as it shows the original
    (>= 40 dB), and as npga-view renders it (>= 35 dB)."""
    src = lam_data("p2-1.zip")
    npga, out = tmp_path / "p2-1.npga", tmp_path / "p2-1.zip"
    assert main(["import", "lam", str(src), "--out", str(npga)]) == 0
    assert main(["export", str(npga), "--format", "lam-zip", "--out", str(out)]) == 0
    original = shoot(src, weights, CAMERA, WIDTH, HEIGHT, tmp_path / "profile1")
    exported = shoot(out, weights, CAMERA, WIDTH, HEIGHT, tmp_path / "profile2")
    same, _ = masked_psnr(original["image"], exported["image"])
    ours, _ = masked_psnr(exported["image"], render(out, weights, exported, tmp_path / "ours.png"))
    assert same >= 40.0 and ours >= 35.0, (same, ours)
