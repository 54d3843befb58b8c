"""Capture readers without rendering: GHA's preprocessed folders (GaussianHeadAvatar `lib/dataset/Dataset.py`
reads `images/NNNN/image_CAM.jpg`, `mask_CAM.jpg` and `cameras/NNNN/camera_CAM.npz` with `extrinsic` and
`intrinsic`; its __getitem__ resizes each image to `original_resolution` (2048, config/config.py L38) before using the
intrinsic, L216 and L232-243, so the intrinsic is in pixels of a 2048x2048 image), the image cache budget, the
frame -> code correspondence and the paper's 550x802 framing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.evaluation.capture import GHA, code_index, load_capture
from npga_core.evaluation.views import protocol_view
from npga_core.files.sequences import ExpressionSequence


def _gha(root, frames=(0, 1), cams=("00", "01")):
    for f in frames:
        (root / "images" / f"{f:04d}").mkdir(parents=True)
        (root / "cameras" / f"{f:04d}").mkdir(parents=True)
        for c in cams:
            cv2.imwrite(str(root / "images" / f"{f:04d}" / f"image_{c}.jpg"), np.full((32, 24, 3), 128, np.uint8))
            cv2.imwrite(str(root / "images" / f"{f:04d}" / f"mask_{c}.jpg"), np.full((32, 24), 255, np.uint8))
            np.savez(root / "cameras" / f"{f:04d}" / f"camera_{c}.npz", extrinsic=np.eye(4)[:3],
                     intrinsic=np.array([[2560.0, 0, 1024], [0, 2560, 1024], [0, 0, 1]]))


def test_gha_folders_are_read_and_problems_listed(tmp_path):
    _gha(tmp_path)
    (tmp_path / "cameras" / "0001" / "camera_01.npz").unlink()
    cap = load_capture(tmp_path, budget_bytes=32 * 24 * 3 * 4 + 1)
    assert cap.layout == GHA and cap.frames == [0, 1] and len(cap.views) == 3
    assert len(cap.problems) == 1 and "camera_01.npz" in cap.problems[0] and "missing" in cap.problems[0]
    v = cap.views[(0, "00")]
    # K of a 2048x2048 image scaled to the 24x32 file as GHA's resize to 2048 implies
    c = v.camera
    assert (c.width, c.height, c.fx, c.fy, c.cx, c.cy) == (24, 32, 2560 * 24 / 2048, 2560 * 32 / 2048, 12.0, 16.0)
    assert cap.image(v.image_path).shape == (32, 24, 3) and cap.image(v.mask_path, grey=True).max() == 1.0
    cap.image(cap.views[(1, "00")].image_path)
    assert cap.cached_bytes <= 32 * 24 * 3 * 4 + 1  # the budget holds one colour image: the older one left


def test_not_a_capture_is_one_error_naming_the_folder(tmp_path):
    with pytest.raises(AvatarFileError, match=str(tmp_path)):
        load_capture(tmp_path)


def test_frame_to_code():
    seq = ExpressionSequence(np.zeros((5, 3), np.float32))
    assert code_index(seq, 3, 0) == 3 and code_index(seq, 9, 1) == 1
    named = ExpressionSequence(np.zeros((2, 3), np.float32), frame_names=["frame_00010", "frame_00012"])
    assert code_index(named, 12, 0) == 1 and code_index(named, 11, 0) is None


def test_protocol_framing_downsamples_to_cover_and_crops_the_centre():
    cam = Camera(np.eye(4), 2000.0, 2000.0, 1100.0, 1604.0, 2200, 3208)
    img = np.zeros((3208, 2200, 3), np.float32)
    img[:, 1100:] = 1.0
    c, out, mask = protocol_view(cam, img, None)
    assert out.shape == (802, 550, 3) and mask is None
    assert (c.width, c.height, c.fx, c.cx, c.cy) == (550, 802, 500.0, 275.0, 401.0)
    # a square 1024 image (GHA): scaled to cover 550x802 and cropped left and right
    sq = Camera(np.eye(4), 1000.0, 1000.0, 512.0, 512.0, 1024, 1024)
    c2, out2, _ = protocol_view(sq, np.zeros((1024, 1024, 3), np.float32), None)
    s = 802 / 1024
    assert out2.shape == (802, 550, 3)
    assert c2.fx == pytest.approx(1000 * s, rel=1e-3) and c2.cx == pytest.approx(512 * s - (round(1024 * s) - 550) // 2)
    # a world point lands on the same pixel relative to the image content
    p = np.array([[0.1, -0.05, 2.0]])
    u0, u1 = sq.project(p)[0], c2.project(p)[0]
    assert u1[1] == pytest.approx(u0[1] * 802 / 1024, abs=0.6)
