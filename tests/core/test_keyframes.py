"""Keyframe timelines: keys hit exactly, holds, eases, smooth paths, cameras, JSON round trip and validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from npga_core.camera.cameras import look_at
from npga_core.camera.orbit import OrbitCamera
from npga_core.editing.keyframes import KeyframeTimeline, ease
from npga_core.errors import AvatarFileError


def timeline(seed: int = 0, d: int = 5) -> KeyframeTimeline:
    rng = np.random.default_rng(seed)
    tl = KeyframeTimeline()
    times = [0.0, 0.37, 1.2, 1.25, 2.9, 4.0]
    for i, t in enumerate(times):
        tl.add_expression(t, rng.normal(size=d), interp=("smooth", "linear")[i % 2], ease_in=rng.uniform(),
                          ease_out=rng.uniform(), hold=0.3 if i == 2 else 0.0, label=f"k{i}")
    for t, yaw, fov, size in ((0.5, -40.0, 20.0, (550, 802)), (1.5, 10.0, 30.0, (400, 400)),
                              (3.0, 60.0, 15.0, (550, 802)), (3.6, 80.0, 25.0, (100, 300))):
        orbit = OrbitCamera(target=[0.0, 0.02, 0.0], yaw=yaw, pitch=yaw / 8, distance=0.9, fov_y=fov)
        tl.add_camera(t, orbit.camera(*size), ease_in=0.5, ease_out=0.2)
    return tl


def test_keys_are_hit_exactly():
    tl = timeline()
    for key in tl.expression:
        code = tl.code_at(key.time)
        assert code.dtype == np.float32 and code.tobytes() == key.code.tobytes()
    for key in tl.camera:
        cam = tl.camera_at(key.time, key.camera.width, key.camera.height)
        np.testing.assert_array_equal(cam.world_to_camera, key.camera.world_to_camera)
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == (key.camera.fx, key.camera.fy, key.camera.cx, key.camera.cy)
        other = tl.camera_at(key.time, 275, 401)  # another size: same pose and vertical field of view
        np.testing.assert_array_equal(other.world_to_camera, key.camera.world_to_camera)
        assert other.fov_y_deg == pytest.approx(key.camera.fov_y_deg, rel=1e-12)
        assert (other.width, other.height) == (275, 401)
    for t in np.linspace(-1, 5, 241):
        assert np.all(np.isfinite(tl.code_at(t))) and np.all(np.isfinite(tl.camera_at(t).world_to_camera))
    # ends hold; frame_times over the duration hits every key on the grid
    np.testing.assert_array_equal(tl.code_at(-1.0), tl.expression[0].code)
    np.testing.assert_array_equal(tl.code_at(99.0), tl.expression[-1].code)
    assert tl.duration == 4.0
    times = tl.frame_times(20)
    assert times[0] == 0 and times[-1] == pytest.approx(4.0) and len(times) == 81
    for key in tl.expression:
        k = int(round(key.time * 20))
        if abs(k / 20 - key.time) < 1e-12:
            np.testing.assert_array_equal(tl.code_at(times[k]), key.code)


def test_hold_and_linear_segments():
    tl = KeyframeTimeline()
    a, b, c = np.zeros(3), np.ones(3), np.array([2.0, 0.0, -1.0])
    tl.add_expression(0.0, a, interp="linear", hold=0.5)
    tl.add_expression(1.5, b, interp="linear")
    tl.add_expression(2.5, c, interp="linear", hold=1.0)
    for t in (0.0, 0.2, 0.5):
        np.testing.assert_array_equal(tl.code_at(t), a)
    np.testing.assert_allclose(tl.code_at(1.0), 0.5 * (a + b))  # moves over 0.5..1.5
    np.testing.assert_allclose(tl.code_at(2.0), 0.5 * (b + c))
    np.testing.assert_allclose(tl.code_at(1.75), 0.75 * b + 0.25 * c)
    assert tl.duration == 3.5
    # a hold as long as the gap makes a step
    tl.update_key("expression", 1, hold=5.0)
    np.testing.assert_array_equal(tl.code_at(2.49), b)


def test_ease_reshapes_time_only():
    u = np.linspace(0, 1, 101)
    for eo, ei in ((0, 0), (1, 1), (0.3, 0.9), (1, 0)):
        s = np.array([ease(x, eo, ei) for x in u])
        assert s[0] == 0 and s[-1] == pytest.approx(1.0) and np.all(np.diff(s) >= 0)
    np.testing.assert_allclose([ease(x, 0, 0) for x in u], u, atol=1e-12)
    assert ease(0.1, 1, 1) < 0.1 and ease(0.5, 1, 1) == pytest.approx(0.5)
    tl = KeyframeTimeline()
    tl.add_expression(0, [0.0], interp="linear", ease_out=1.0)
    tl.add_expression(1, [1.0], ease_in=1.0)
    assert tl.code_at(0.1)[0] < 0.1 and tl.code_at(0.9)[0] > 0.9
    assert tl.code_at(0.5)[0] == pytest.approx(0.5)


def test_smooth_codes_are_continuous_with_continuous_velocity():
    tl = KeyframeTimeline()
    rng = np.random.default_rng(2)
    for t in (0.0, 0.8, 1.3, 2.6):
        tl.add_expression(t, rng.normal(size=4))
    h = 1e-4
    for key in tl.expression[1:-1]:
        t = key.time
        left = (tl.code_at(t).astype(float) - tl.code_at(t - h)) / h
        right = (tl.code_at(t + h).astype(float) - tl.code_at(t)) / h
        np.testing.assert_allclose(left, right, atol=0.05 * np.abs(left).max() + 1e-2)
        assert np.abs(left).max() > 0.1  # it really moves through the key
    # a linear segment has a velocity jump at interior keys
    tl.update_key("expression", 0, interp="linear")
    tl.update_key("expression", 1, interp="linear")
    t = tl.expression[1].time
    left = (tl.code_at(t).astype(float) - tl.code_at(t - h)) / h
    right = (tl.code_at(t + h).astype(float) - tl.code_at(t)) / h
    assert np.abs(left - right).max() > 0.1


def test_camera_interpolation_is_a_slerp_with_interpolated_intrinsics():
    tl = KeyframeTimeline()
    c0 = look_at([0, 0, 1], [0, 0, 0], fov_y_deg=20, width=200, height=100)
    c1 = look_at([1, 0, 0], [0, 0, 0], fov_y_deg=40, width=200, height=100)
    tl.add_camera(0.0, c0)
    tl.add_camera(2.0, c1)
    mid = tl.camera_at(1.0)
    r = mid.rotation
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(r, look_at([1, 0, 1], [0, 0, 0]).rotation, atol=1e-12)  # half of the 90 degrees
    np.testing.assert_allclose(mid.camera_center, [0.5, 0, 0.5], atol=1e-12)
    assert mid.fy == pytest.approx(0.5 * (c0.fy + c1.fy))
    assert (mid.width, mid.height) == (200, 100)
    for t in np.linspace(0, 2, 9):
        cam = tl.camera_at(t)
        np.testing.assert_allclose(np.linalg.det(cam.rotation), 1.0, atol=1e-9)
    assert tl.camera_at(5.0).world_to_camera.tobytes() == c1.world_to_camera.tobytes()
    assert KeyframeTimeline().camera_at(0.0) is None and KeyframeTimeline().code_at(0.0) is None


def test_json_round_trip(tmp_path):
    tl = timeline(seed=4)
    path = tmp_path / "keys.json"
    tl.save(path)
    back = KeyframeTimeline.load(path)
    assert back.code_dim == 5 and len(back.expression) == 6 and len(back.camera) == 4
    for a, b in zip(tl.expression, back.expression, strict=True):
        assert (a.time, a.interp, a.ease_in, a.ease_out, a.hold, a.label) == (b.time, b.interp, b.ease_in, b.ease_out,
                                                                             b.hold, b.label)
        assert a.code.tobytes() == b.code.tobytes()
    for t in np.linspace(-0.5, 4.5, 37):
        np.testing.assert_array_equal(back.code_at(t), tl.code_at(t))
        w2c = tl.camera_at(t, 64, 80).world_to_camera
        np.testing.assert_array_equal(back.camera_at(t, 64, 80).world_to_camera, w2c)
    assert not list(tmp_path.glob(".*.tmp"))


def test_editing_keys():
    tl = KeyframeTimeline()
    tl.add_expression(1.0, [1.0, 1.0])
    tl.add_expression(0.0, [0.0, 0.0])
    assert [k.time for k in tl.expression] == [0.0, 1.0]
    assert tl.add_expression(1.0, [2.0, 2.0], label="again") == 1 and len(tl.expression) == 2  # replaced
    assert tl.update_key("expression", 0, time=3.0, interp="linear") == 1
    assert [k.label for k in tl.expression] == ["again", ""] and tl.expression[1].interp == "linear"
    with pytest.raises(ValueError, match="3 dims"):
        tl.add_expression(2.0, [1.0, 2.0, 3.0])
    for bad in ({"interp": "cubic"}, {"ease_in": 1.5}, {"hold": -1}, {"time": float("nan")}, {"colour": 1}):
        with pytest.raises(ValueError):
            tl.update_key("expression", 0, **bad)
    tl.remove_key("expression", 0)
    tl.remove_key("expression", 0)
    assert tl.is_empty() and tl.code_dim is None
    with pytest.raises(ValueError, match="track"):
        tl.keys("audio")


GOOD_CAMERA = look_at([0, 0, 1], [0, 0, 0]).to_dict()


@pytest.mark.parametrize("content, problem", [
    ("not json", "not valid JSON"),
    ('{"expression": []}', "npga_keyframes"),
    ('{"npga_keyframes": 2}', "version 2"),
    ('{"npga_keyframes": 1, "expression": {}}', "expression: expected a list, got an object"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": [1, NaN]}]}', "NaN"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": []}]}', "expression[0].code: expected a list"),
    ('{"npga_keyframes": 1, "expression": [{"time": "0", "code": [1]}]}', "expression[0].time"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": [1], "interp": "cubic"}]}', "interp"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": [1], "ease_in": 2}]}', "ease_in"),
    ('{"npga_keyframes": 1, "expression": [{"time": -1, "code": [1]}]}', "time"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": [1]}, {"time": 0, "code": [2]}]}', "two"),
    ('{"npga_keyframes": 1, "expression": [{"time": 0, "code": [1]}, {"time": 1, "code": [2, 3]}]}', "dims"),
    ('{"npga_keyframes": 1, "code_dim": 3, "expression": [{"time": 0, "code": [1]}]}', "dims"),
    ('{"npga_keyframes": 1, "camera": [{"time": 0, "camera": {"fx": 1}}]}', "camera[0]"),
    ('{"npga_keyframes": 1, "camera": [{"time": 0}]}', "camera[0]"),
])
def test_bad_files_are_reported_with_their_path(tmp_path, content, problem):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(AvatarFileError) as err:
        KeyframeTimeline.load(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and problem in msg and "\n" not in msg


def test_missing_file_and_code_dim_check(tmp_path):
    with pytest.raises(AvatarFileError, match="no such file"):
        KeyframeTimeline.load(tmp_path / "none.json")
    path = tmp_path / "ok.json"
    path.write_text(json.dumps({"npga_keyframes": 1, "camera": [{"time": 1, "camera": GOOD_CAMERA}]}))
    tl = KeyframeTimeline.load(path)
    assert tl.code_dim is None and tl.duration == 1.0
    tl.check_code_dim(100)
    tl.add_expression(0, np.zeros(4))
    with pytest.raises(AvatarFileError, match="4 dims, the avatar expects 100"):
        tl.check_code_dim(100, path)


def test_render_timeline_cli(tmp_path, capsys):
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_view.cli.main import main

    avatar = make_synthetic_avatar(300, hidden=32, depth=2, code_dim=10, n_components=5, seed=2)
    path = tmp_path / "a.npga"
    save_avatar(avatar, path)
    tl = KeyframeTimeline()
    tl.add_expression(0.0, avatar.expression.mean)
    tl.add_expression(0.8, avatar.expression.sample(np.random.default_rng(0), scale=2.0))
    for t, yaw in ((0.0, -60.0), (0.8, 60.0)):
        tl.add_camera(t, OrbitCamera(yaw=yaw, distance=0.8).camera(40, 60))
    keys = tmp_path / "keys.json"
    tl.save(keys)
    # argument and file problems are found before any rendering
    bad = tmp_path / "bad.json"
    tl_wrong = KeyframeTimeline()
    tl_wrong.add_expression(0.0, np.zeros(3))
    tl_wrong.save(bad)
    for argv, problem in (
        (["--out", str(tmp_path / "x.png"), "--timeline", str(keys)], ".mp4"),
        (["--out", str(tmp_path / "x.mp4"), "--timeline", str(bad)], "3 dims"),
        (["--out", str(tmp_path / "x.mp4"), "--timeline", str(tmp_path / "none.json")], "no such file"),
        (["--out", str(tmp_path / "x.mp4"), "--timeline", str(keys), "--fps", "0"], "--fps"),
        (["--out", str(tmp_path / "x.mp4"), "--timeline", str(keys), "--expr", str(keys)], "leave out"),
    ):
        capsys.readouterr()
        assert main(["render", str(path), *argv]) == 2, argv
        assert problem in capsys.readouterr().err
    cv2 = pytest.importorskip("cv2")
    from npga_view.rendering.gl import GLUnavailableError, create_headless_context

    try:
        create_headless_context().release()
    except GLUnavailableError as exc:
        pytest.skip(f"no OpenGL 4.3 context: {exc}")
    out = tmp_path / "t.mp4"
    assert main(["render", str(path), "--timeline", str(keys), "--out", str(out), "--fps", "10",
                 "--width", "40", "--height", "60"]) == 0
    cap = cv2.VideoCapture(str(out))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame.astype(float))
    cap.release()
    assert len(frames) == 9  # 0.0, 0.1, ..., 0.8 s
    assert frames[0].shape == (60, 40, 3) and frames[0].max() > 50
    assert np.abs(frames[0] - frames[-1]).mean() > 5  # the camera swung from one side to the other


def test_keyframe_panel_and_apply(tmp_path):
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_view import actions as A
    from npga_view.controllers.edit_actions import apply_keyframe
    from npga_view.panels.info import AppInfo
    from npga_view.panels.keyframes import KeyframesPanel
    from npga_view.state import ViewerState
    from tests.support.panels import PanelDriver

    avatar = make_synthetic_avatar(50, hidden=16, depth=2, code_dim=6, n_components=3, seed=1)
    info, state = AppInfo(avatar=avatar), ViewerState()
    driver = PanelDriver(KeyframesPanel(), state, info)
    try:
        assert "kf_play" not in info.rects  # no timeline yet: only "new" and "load"
        info.keyframes = timeline(d=6)
        info.keyframe_time = 1.5
        driver.frame()
        driver.click("kf_add_camera")
        assert state.actions == [A.AddCameraKey(1.5)]
        state.actions.clear()
        driver.click("kf_add_expression")
        assert state.actions == [A.AddExpressionKey(1.5, "sliders", None, "smooth")]
        state.actions.clear()
        driver.click("kf_play")
        assert state.actions == [A.PlayKeyframes(True)]
    finally:
        driver.close()
    tl = info.keyframes
    assert apply_keyframe(tl, A.UpdateKey("expression", 0, {"time": 5.0, "hold": 1.0}))
    assert tl.expression[-1].time == 5.0 and tl.duration == 6.0
    assert apply_keyframe(tl, A.RemoveKey("camera", 0)) and len(tl.camera) == 3
    assert apply_keyframe(tl, A.SaveKeyframes(str(tmp_path / "k.json")))
    assert len(KeyframeTimeline.load(tmp_path / "k.json").expression) == 6
    assert apply_keyframe(tl, A.ClearKeyframes()) and tl.is_empty()
    assert not apply_keyframe(tl, A.SeekKeyframes(1.0))
