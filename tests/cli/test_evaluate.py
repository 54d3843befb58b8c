"""`npga-view evaluate` against a capture made of known renders: the demo avatar drawn by the independent
reference rasterizer (tests/support/reference_rasterizer.py) through a NeRSemble-style rig, plus known noise.

Layout as the NeRSemble data manager names it (nersemble `data_manager/multi_view_data.py`,
`get_image_file_name_format`: `timesteps/frame_{t:05d}/images/cam_{serial}.png`;
`get_robust_matting_alpha_image_path`: `timesteps/frame_{t:05d}/alpha_map/cam_{serial}.png`), the rig as
`camera_params.json` with `world_2_cam` per serial and shared `intrinsics` (nersemble-benchmark
`data/benchmark_data.py`, `CameraParams`)."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from npga_view.cli.main import main
from tests.support.captures import FRAMES, SERIALS, capture_cameras, ssim_reference, write_capture
from tests.support.reference_rasterizer import rasterize
from tests.support.takes import write_csv

pytestmark = pytest.mark.slow  # a module fixture takes over 10 s


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    from npga_core import load_avatar
    avatar = load_avatar("demo")
    p = avatar.pose(None)
    cams = capture_cameras(avatar)
    images = {}
    for s, cam in cams.items():
        o = rasterize(p.means, p.quats, p.scales, p.opacities, p.sh, cam, (1.0, 1.0, 1.0))
        images[s] = (o["rgb"], o["alpha"])
    root = tmp_path_factory.mktemp("capture")
    write_capture(root, cams, images)
    shifted = tmp_path_factory.mktemp("shifted")
    write_capture(shifted, cams, images, shift_cx=1.0)
    return root


def _csv(out: Path) -> list[dict]:
    with open(out / "metrics.csv") as fh:
        return list(csv.DictReader(fh))


def _read(path: Path, grey: bool = False) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float64) / 255.0
    return img if grey else img[..., ::-1]


def _run(capture: Path, out: Path, *extra: str) -> int:
    return main(["evaluate", "demo", "--capture", str(capture), "--out", str(out), "--no-cnn", "--save-renders",
                 *extra])


def test_scores_equal_an_independent_computation(capture, tmp_path):
    out = tmp_path / "report"
    assert _run(capture, out, "--mask", "alpha") == 0
    rows = _csv(out)
    assert len(rows) == len(FRAMES) * len(SERIALS)
    for r in rows:
        folder = capture / "timesteps" / f"frame_{int(r['frame']):05d}"
        image = _read(folder / "images" / f"cam_{r['camera']}.png")
        m = _read(folder / "alpha_map" / f"cam_{r['camera']}.png", grey=True)[..., None]
        render = np.load(out / "renders" / f"{r['frame']}_{r['camera']}.npy").astype(np.float64)
        a, b = render * m + (1 - m), image * m + (1 - m)  # masked as documented: both on the white background
        assert r["masked"] == "alpha"
        assert float(r["psnr"]) == pytest.approx(-10 * np.log10(np.mean((a - b) ** 2)), abs=0.01)
        assert float(r["ssim"]) == pytest.approx(ssim_reference(a, b), abs=1e-4)
        # the render is the reference rasterizer's image: PSNR near the known noise (plus GL differences)
        assert float(r["psnr"]) > 30.0
    summary = (out / "summary.md").read_text()
    assert "**all**" in summary and SERIALS[0] in summary and "LPIPS" in summary
    assert (out / "metrics.png").is_file() and list(out.glob("worst1_*_diff.png"))


def test_unmasked_scores_use_every_pixel(capture, tmp_path):
    out = tmp_path / "report"
    assert _run(capture, out, "--mask", "none", "--frames", "0", "--cameras", SERIALS[1]) == 0
    (r,) = _csv(out)
    image = _read(capture / "timesteps" / "frame_00000" / "images" / f"cam_{SERIALS[1]}.png")
    render = np.load(out / "renders" / f"0_{SERIALS[1]}.npy").astype(np.float64)
    assert r["masked"] == "none"
    assert float(r["psnr"]) == pytest.approx(-10 * np.log10(np.mean((render - image) ** 2)), abs=0.01)


def test_a_camera_one_pixel_off_scores_lower(capture, tmp_path):
    shifted = [p for p in capture.parent.iterdir() if p.name.startswith("shifted")][0]
    good, bad = tmp_path / "good", tmp_path / "bad"
    assert _run(capture, good, "--frames", "0") == 0
    assert _run(shifted, bad, "--frames", "0") == 0
    for g, b in zip(_csv(good), _csv(bad), strict=True):
        assert float(b["psnr"]) < float(g["psnr"]) - 1.0


def test_missing_and_unreadable_files_are_one_line_each(capture, tmp_path, capsys):
    import shutil
    broken = tmp_path / "broken"
    shutil.copytree(capture, broken)
    (broken / "timesteps" / "frame_00000" / "images" / f"cam_{SERIALS[0]}.png").unlink()
    (broken / "timesteps" / "frame_00003" / "alpha_map" / f"cam_{SERIALS[1]}.png").write_bytes(b"not a png")
    out = tmp_path / "report"
    assert _run(broken, out, "--mask", "alpha") == 0
    problems = (out / "problems.txt").read_text().splitlines()
    assert len(problems) == 2, problems
    assert any("frame_00000" in p and f"cam_{SERIALS[0]}" in p and "missing" in p for p in problems)
    assert any("frame_00003" in p and "alpha_map" in p and "unreadable" in p for p in problems)
    assert len(_csv(out)) == len(FRAMES) * len(SERIALS) - 2


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert main(["evaluate", "demo", "--capture", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path) in err[0]


def test_a_take_through_a_basis_scores_as_its_codes(capture, tmp_path):
    """`--sequence take.csv` is read through the avatar's basis (the demo's own, or `--basis`): the scores equal
    those of the codes that basis gives for the take's frames."""
    from npga_core import load_avatar
    from npga_core.files.basis_file import attach_basis, bundled_demo_basis, save_basis
    from npga_core.files.loading import load_sequence_for
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.blendshapes import BlendshapeBasis

    take = tmp_path / "take.csv"
    write_csv(take, [(f"00:00:00:{2 * k:02d}.000", {"JawOpen": 0.2 * k, "EyeBlinkLeft": 0.9 - 0.2 * k})
                     for k in range(5)])
    demo = bundled_demo_basis()
    other = BlendshapeBasis(demo.names, 0.5 * demo.matrix, demo.offset, "half the demo's")
    save_basis(other, tmp_path / "half.npz")
    for extra, basis in (((), None), (("--basis", str(tmp_path / "half.npz")), tmp_path / "half.npz")):
        avatar = load_avatar("demo")
        if basis is not None:
            attach_basis(avatar, basis)
        codes = load_sequence_for(avatar, take).codes
        ExpressionSequence(codes, 30.0, "take codes").save(tmp_path / "codes.npzseq")
        a, b = tmp_path / f"take{len(extra)}", tmp_path / f"codes{len(extra)}"
        assert _run(capture, a, "--sequence", str(take), *extra) == 0
        assert _run(capture, b, "--sequence", str(tmp_path / "codes.npzseq")) == 0
        ta, tb = _csv(a), _csv(b)
        assert ta and [r["psnr"] for r in ta] == [r["psnr"] for r in tb]
    assert _csv(tmp_path / "take0")[0]["psnr"] != _csv(tmp_path / "take2")[0]["psnr"]  # the basis was used
