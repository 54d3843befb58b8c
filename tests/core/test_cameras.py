"""Camera model: OpenCV conventions, JSON files, framing, the OpenGL projection."""

from __future__ import annotations

import json

import numpy as np
import pytest

from npga_core.camera.cameras import Camera, frame_points, look_at
from npga_core.errors import AvatarFileError
from npga_core.files.rig import load_camera


def test_look_at_opencv_axes():
    cam = look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 200, 300)
    np.testing.assert_allclose(cam.camera_center, [0, 0, 5], atol=1e-12)
    rot = cam.rotation
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    uv = cam.project(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    np.testing.assert_allclose(uv[0], [100.0, 150.0])
    assert uv[1, 0] > 100.0  # +x is on the right for a camera in front (+z) of a head looking along +z
    assert uv[2, 1] < 150.0  # +y (up) is towards the top row
    assert cam.fov_y_deg == pytest.approx(30.0)
    assert cam.world_to_view(np.array([[0.0, 0.0, 0.0]]))[0, 2] == pytest.approx(5.0)  # z forward


def test_look_at_rejects_degenerate():
    with pytest.raises(ValueError):
        look_at((0, 0, 1), (0, 0, 1))
    with pytest.raises(ValueError):
        look_at((0, 2, 0), (0, 0, 0), (0, 1, 0))


def test_project_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    cam = look_at((0.3, 0.2, 1.5), (0.0, 0.05, 0.0), fov_y_deg=25, width=550, height=802)
    cam = Camera(cam.world_to_camera, cam.fx * 1.01, cam.fy, 270.3, 410.8, 550, 802)
    pts = np.random.default_rng(0).normal(0, 0.1, (20, 3))
    rvec, _ = cv2.Rodrigues(cam.rotation)
    expected, _ = cv2.projectPoints(pts, rvec, cam.translation, cam.intrinsics(), None)
    np.testing.assert_allclose(cam.project(pts), expected.reshape(-1, 2), atol=1e-9)


def test_opengl_projection_agrees_with_intrinsics():
    cam = Camera(look_at((0.2, 0.1, 2.0), (0, 0, 0)).world_to_camera, 900.0, 880.0, 260.0, 420.0, 550, 802)
    pts = np.random.default_rng(1).normal(0, 0.2, (10, 3))
    uv = cam.project(pts)
    view = cam.world_to_view(pts)
    hom = np.c_[view, np.ones(len(view))]
    for flip in (False, True):
        clip = hom @ cam.opengl_projection(0.01, 100.0, flip_y=flip).T
        ndc = clip[:, :3] / clip[:, 3:]
        np.testing.assert_allclose((ndc[:, 0] + 1) * cam.width / 2, uv[:, 0], atol=1e-9)
        v = (ndc[:, 1] + 1) * cam.height / 2
        np.testing.assert_allclose(cam.height - v if flip else v, uv[:, 1], atol=1e-9)
    p = cam.opengl_projection(0.1, 10.0)
    for z, expected in ((0.1, -1.0), (10.0, 1.0)):
        clip = p @ [0.0, 0.0, z, 1.0]
        assert clip[2] / clip[3] == pytest.approx(expected)


def test_json_round_trip(tmp_path):
    cam = Camera(look_at((0.1, 0.2, 1.0), (0, 0, 0)).world_to_camera, 1000.5, 1001.0, 274.0, 400.5, 550, 802)
    path = tmp_path / "cam.json"
    cam.to_json(path)
    back = load_camera(path)
    np.testing.assert_array_equal(back.world_to_camera, cam.world_to_camera)
    assert (back.fx, back.fy, back.cx, back.cy, back.width, back.height) == (1000.5, 1001.0, 274.0, 400.5, 550, 802)
    assert set(json.loads(path.read_text())) == {"width", "height", "fx", "fy", "cx", "cy", "world_to_camera"}


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (None, "no such file"),
        ("{not json", "not valid JSON"),
        ("[1, 2]", "expected an object, got a list"),
        ('{"width": 10, "height": 10}', "object missing required field `fx`"),
        ('{"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": [[1, 0], [0, 1]]}',
         "world_to_camera: expected a list of length 4, got 2"),
        ('{"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": "eye"}',
         "world_to_camera: expected a list, got a string"),
        ('{"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": '
         '[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, "1", 1]]}', "world_to_camera[3][2]: expected a number"),
        ('{"width": 10.5, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": '
         "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}", "width: expected an integer, got a number"),
        ('{"width": 10, "height": 10, "fx": "1", "fy": 1, "cx": 5, "cy": 5, "world_to_camera": '
         "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}", "fx: expected a number, got a string"),
        ('{"width": 10, "height": 10, "fx": -1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": '
         "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}", "focal"),
        ('{"width": 0, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_camera": '
         "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}", "width: expected an integer >= 1, got 0"),
    ],
)
def test_bad_json_names_file_and_problem(tmp_path, content, problem):
    path = tmp_path / "bad_camera.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(AvatarFileError) as err:
        load_camera(path)
    message = str(err.value)
    assert str(path) in message and problem in message and "\n" not in message


def head_points(n: int = 2000) -> np.ndarray:
    rng = np.random.default_rng(2)
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * [0.08, 0.11, 0.1] + [0.01, 0.02, -0.03]


@pytest.mark.parametrize("direction", ["front", "three_quarter_left", "three_quarter_right", "left", "right",
                                       (30.0, 10.0)])
def test_frame_points_contains_head(direction):
    pts = head_points()
    cam = frame_points(pts, 550, 802, fov=20.0, direction=direction)
    uv = cam.project(pts)
    assert np.all(cam.world_to_view(pts)[:, 2] > 0)
    assert uv[:, 0].min() >= 0 and uv[:, 0].max() <= 550 and uv[:, 1].min() >= 0 and uv[:, 1].max() <= 802
    span = max((uv[:, 0].max() - uv[:, 0].min()) / 550, (uv[:, 1].max() - uv[:, 1].min()) / 802)
    assert span > 0.6  # framed, not a dot in the middle


def test_frame_points_directions():
    pts = head_points()
    centre = pts.mean(axis=0)
    front = frame_points(pts, direction="front").camera_center - centre
    assert front[2] > 0 and abs(front[0]) < 0.01 and abs(front[1]) < 0.01  # the head looks along +z
    left = frame_points(pts, direction="left").camera_center - centre
    assert left[0] < 0 and abs(left[2]) < 0.01
    three = frame_points(pts, direction="three_quarter_right").camera_center - centre
    assert three[0] > 0 and three[2] > 0
    with pytest.raises(ValueError):
        frame_points(pts, direction="behind-ish")
    with pytest.raises(ValueError):
        frame_points(np.full((5, 3), np.nan))


def test_frame_points_ignores_stray_points():
    pts = np.concatenate([head_points(), [[50.0, 0.0, 0.0]]])
    cam = frame_points(pts, 550, 802)
    uv = cam.project(pts[:-1])
    assert (uv[:, 0].max() - uv[:, 0].min()) > 300


def test_resized_keeps_view():
    cam = look_at((0.0, 0.1, 1.0), (0, 0, 0), width=550, height=802)
    small = cam.resized(275, 401)
    pts = head_points(50)
    np.testing.assert_allclose(small.project(pts), cam.project(pts) / 2.0, atol=1e-9)
