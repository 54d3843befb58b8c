"""The real window under Xvfb, driven through imgui input events like a user's mouse."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view import actions as A
from tests.support.window import click, run_until, settle

pytestmark = pytest.mark.gui


def test_a_frame_with_nothing_new_is_not_drawn_again(app, avatar_path, monkeypatch):
    """A frame whose view image and imgui output are those on screen is not drawn again (on llvmpipe a frame costs
    ~10 ms of fill), but an expose, a panel change or a new image is, the pixels stay right, and a frame is drawn at
    least every PRESENT_AT_LEAST_S even so."""
    from npga_view import app as app_module

    monkeypatch.setattr(app_module, "PRESENT_AT_LEAST_S", 1e9)  # (the safety net checked at the end)
    assert app.open_avatar(avatar_path)
    settle(app)
    assert run_until(app, lambda: app.refining.complete, timeout=120)  # (the demo's CNN image is a new image)
    app.state.show_stats = False
    for _ in range(3):
        app.step()
    shown = app.read_window()
    p0 = app.presented
    for _ in range(10):
        app.step()
    assert app.presented == p0, "frames with nothing new were drawn again"
    np.testing.assert_array_equal(app.read_window(), shown)
    from npga_view.imgui_glfw import glfw

    handle = app.window.handle
    refresh = glfw.set_window_refresh_callback(handle, None)  # (the window's own, as glfw calls it on an expose)
    glfw.set_window_refresh_callback(handle, refresh)
    refresh(handle)  # the window system lost the window's pixels: drawn in the next frame, once
    app.step()
    assert app.presented == p0 + 1
    app.step()
    assert app.presented == p0 + 1
    p0 = app.presented
    app.state.show_stats = True  # a panel change: imgui's output differs
    app.step()
    assert app.presented == p0 + 1
    assert not np.array_equal(app.read_window(), shown)
    app.state.show_stats = False
    drag(app, "slider0", 0.9)  # a new pose: new images
    p1 = app.presented
    settle(app)
    assert app.presented > p1
    monkeypatch.setattr(app_module, "PRESENT_AT_LEAST_S", 0.0)
    p2 = app.presented
    for _ in range(3):
        app.step()
    assert app.presented == p2 + 3


def drag(app, name, fraction):
    """Drag a slider's grab from its centre to `fraction` of its width."""
    from imgui_bundle import imgui

    x0, y0, x1, y1 = app.info.rects[name]
    io = imgui.get_io()
    y = (y0 + y1) / 2
    io.add_mouse_pos_event((x0 + x1) / 2, y)
    app.step()
    io.add_mouse_button_event(0, True)
    app.step()
    for t in np.linspace(0.5, fraction, 6):
        io.add_mouse_pos_event(x0 + (x1 - x0) * t, y)
        app.step()
    io.add_mouse_button_event(0, False)
    app.step()


def test_every_action_type_has_a_handler_and_keys_send_actions(app, avatar_path):
    """The window's dispatcher handles every action type (a new one without a handler fails here), and a key
    press goes through the key table: `f` frames the avatar (its target moves), Ctrl+Z undoes a hide."""
    from imgui_bundle import imgui

    assert set(app.dispatcher.table) == set(A.action_types())
    assert app.dispatcher.strict  # tests/conftest.py: an unknown action raises here
    assert app.open_avatar(avatar_path)
    settle(app)
    app.state.camera.target = [5.0, 5.0, 5.0]
    io = imgui.get_io()
    io.add_key_event(imgui.Key.f, True)
    app.step()
    io.add_key_event(imgui.Key.f, False)
    app.step()
    assert max(abs(v) for v in app.state.camera.target) < 5.0
    app.state.actions += [A.SelectAll(), A.HideSelection()]
    app.step()
    assert app.edits.session.hidden.all()
    io.add_key_event(imgui.Key.mod_ctrl, True)
    io.add_key_event(imgui.Key.left_ctrl, True)
    io.add_key_event(imgui.Key.z, True)
    app.step()
    io.add_key_event(imgui.Key.z, False)
    io.add_key_event(imgui.Key.left_ctrl, False)
    io.add_key_event(imgui.Key.mod_ctrl, False)
    app.step()
    assert not app.edits.session.hidden.any()


@pytest.mark.slow
def test_keyframes_play_from_the_panel_action(app, avatar_path):
    """`PlayKeyframes(True)` plays a timeline with keys: the playhead advances and the camera follows the keys
    (it never played before #26: `not timeline.is_empty` tested a bound method, always true)."""
    assert app.open_avatar(avatar_path)
    settle(app)
    app.state.actions += [A.NewKeyframes(), A.AddCameraKey(0.0)]
    app.step()
    app.state.camera.orbit(60, 0)
    app.state.actions += [A.AddCameraKey(2.0), A.PlayKeyframes(True)]
    app.step()
    assert app.edits.kf_playing
    start = app.current_camera().world_to_camera.copy()
    assert run_until(app, lambda: app.edits.kf_time > 0.3, timeout=60)
    assert not np.allclose(app.current_camera().world_to_camera, start)  # the keyed camera moves
    app.state.actions.append(A.PlayKeyframes(False))
    app.step()
    assert not app.edits.kf_playing


def test_open_move_slider_and_see_pixels_change(app, avatar_path):
    assert app.open_avatar(avatar_path)
    settle(app)
    before = app.read_window(viewport_only=True)
    assert before.std() > 5, "the avatar should be visible"
    drag(app, "slider0", 0.98)
    assert app.state.sliders[0] > 2.0
    settle(app)
    after = app.read_window(viewport_only=True)
    changed = np.abs(after.astype(int) - before.astype(int)).max(axis=2) > 8
    assert changed.mean() > 0.002, f"only {changed.mean():.4%} of the pixels changed"


def test_load_sequence_through_the_ui_and_play(app, avatar_path, tmp_path):
    assert app.open_avatar(avatar_path)
    ex = app.avatar.expression
    t = np.arange(50)
    codes = np.stack([ex.from_sliders(np.array([2.5 * np.sin(i / 4.0), 2 * np.cos(i / 5.0)])) for i in t])
    seq_path = tmp_path / "wave.npzseq"
    ExpressionSequence(codes.astype(np.float32), 25.0, "wave").save(seq_path)
    settle(app)
    app.panels.files.path = str(seq_path)
    click(app, "open_sequence")
    assert app.sequence is not None and len(app.sequence) == 50, app.state.errors
    first = app.read_window(viewport_only=True)
    click(app, "play")
    assert app.state.timeline.playing
    frames_seen: set = set()

    def two_frames_shown() -> bool:  # a condition with a generous bound, not a rate: the machine may be busy
        frames_seen.add(app.poses.shown_frame)
        return len(frames_seen - {None}) >= 2 and app.poses.playback.achieved_fps() > 0  # two shown while playing

    assert run_until(app, two_frames_shown, timeout=120), ("playback should show several frames", frames_seen)
    later = app.read_window(viewport_only=True)
    assert np.abs(later.astype(int) - first.astype(int)).max() > 8
    # the timeline's slider and readout are of the frame whose image is on screen (the clock runs ahead of it)
    presented = app.poses.presented_frame
    assert presented in frames_seen and app.info.presented_frame == presented


def test_a_played_image_reaches_the_window_with_its_readout(app, avatar_path, tmp_path, monkeypatch):
    """While a sequence plays with the Timeline in view, a new image is drawn into the window in the same frame as
    the Timeline's readout of it: an image that finished after the panels were drawn waits one UI frame for them,
    instead of the window being drawn twice (on llvmpipe each draw costs ~10-20 ms of the frame)."""
    from imgui_bundle import imgui

    real_text = imgui.text
    lines: list[str] = []

    def text(s: str) -> None:
        if s.startswith("frame "):
            lines.append(s)
        real_text(s)

    monkeypatch.setattr(imgui, "text", text)
    assert app.open_avatar(avatar_path)
    ex = app.avatar.expression
    codes = np.stack([ex.from_sliders(np.array([2.5 * np.sin(i / 4.0), 2 * np.cos(i / 5.0)])) for i in range(60)])
    seq_path = tmp_path / "wave.npzseq"
    ExpressionSequence(codes.astype(np.float32), 25.0, "wave").save(seq_path)
    assert app.open_sequence(str(seq_path))
    settle(app)
    app.state.show_stats = False
    app.panels.scroll_side()  # to its end, where the Timeline is
    app.state.timeline.playing = True
    shown = app.read_window(viewport_only=True)
    new_images = with_readout = 0
    end = time.monotonic() + 180
    while new_images < 8 and time.monotonic() < end:
        lines.clear()
        p0 = app.presented
        app.step()
        if app.presented == p0:
            continue
        view = app.read_window(viewport_only=True)
        if np.array_equal(view, shown):
            continue
        shown = view
        new_images += 1
        frame = app.poses.presented_frame
        with_readout += bool(lines) and lines[-1].startswith(f"frame {frame + 1}/60")
    assert new_images == 8, "playback should show new images"
    # never two frames held in a row, so a new image in each UI frame may come before its readout now and then
    assert with_readout >= 6, (with_readout, new_images)
    if os.environ.get("NPGA_TEST_SHOTS"):
        app.screenshot(os.path.join(os.environ["NPGA_TEST_SHOTS"], "playing_timeline.png"))


def test_bake_through_the_ui_then_play_from_the_bake(app, tmp_path):
    """Bake button -> progress -> baked playback; smoothing makes the bake stale; a second bake comes from the
    cache file next to the avatar."""
    path = tmp_path / "small.npga"
    save_avatar(make_synthetic_avatar(3000, seed=3), path)
    assert app.open_avatar(str(path))
    ex = app.avatar.expression
    codes = np.stack([ex.from_sliders(np.array([2.0 * np.sin(i / 2.0), 1.5 * np.cos(i / 3.0)])) for i in range(12)])
    ExpressionSequence(codes.astype(np.float32), 10.0, "short").save(tmp_path / "short.npzseq")
    assert app.open_sequence(str(tmp_path / "short.npzseq"))
    settle(app)
    assert app.info.bake_state == "none" and not app.bakes.usable()
    click(app, "bake")
    assert app.state.timeline.baked
    assert run_until(app, lambda: app.info.bake_state == "ready", timeout=120), app.info.bake
    st = app.info.bake
    assert st.finished and st.done == st.stored == 12 and not st.from_cache
    assert "bake_progress" in app.info.rects  # the progress bar was drawn
    assert list(tmp_path.glob("small.npga.bake-*.npgabake")), "the cache file is written next to the avatar"
    click(app, "play")
    baked_frames: set = set()

    def three_baked_frames_shown() -> bool:  # a condition with a generous bound, not a rate
        if app.info.baked:
            baked_frames.add(app.poses.shown_frame)
        return len(baked_frames - {None}) >= 3

    assert run_until(app, three_baked_frames_shown, timeout=120), baked_frames
    app.state.timeline.smoothing = "exponential"
    app.step()
    assert app.info.bake_state == "stale" and not app.bakes.usable()
    app.state.timeline.smoothing = "none"
    app.step()  # the layout loses the smoothing's slider: widgets move up
    click(app, "cancel_bake")
    assert app.info.bake_state == "none" and not app.state.timeline.baked
    click(app, "bake")
    assert run_until(app, lambda: app.info.bake_state == "ready", timeout=60), \
        (app.info.bake_state, app.info.bake, app.engine.status, app.state.timeline.baked)
    assert app.info.bake.from_cache


def test_screenshot_button_writes_the_window(app, avatar_path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert app.open_avatar(avatar_path)
    settle(app)
    click(app, "screenshot", frames=1)
    import cv2

    shots = list(tmp_path.glob("npga-view-*.png"))
    assert len(shots) == 1
    img = cv2.imread(str(shots[0]))
    assert img.shape[:2] == app.read_window().shape[:2] and img.std() > 5


def test_bad_files_show_in_the_ui_and_the_app_keeps_running(app, avatar_path, tmp_path):
    assert app.open_avatar(avatar_path)
    bad = tmp_path / "bad.npga"
    bad.write_bytes(b"\x89NPGA\r\n\x1a" + b"\x00" * 4)
    app.state.actions.append(A.OpenAvatar(str(bad)))
    np.save(tmp_path / "wrong_dim.npy", np.zeros((10, 64), np.float32))
    app.state.actions.append(A.OpenSequence(str(tmp_path / "wrong_dim.npy")))
    for _ in range(3):
        app.step()
    errs = " | ".join(app.state.errors)
    assert "bad.npga: truncated" in errs
    assert f"64 dims, the avatar expects {app.avatar.code_dim}" in errs
    assert app.avatar is not None and app.sequence is None
    settle(app)
    assert app.read_window(viewport_only=True).std() > 5


def test_session_round_trip(app, avatar_path, tmp_path):
    assert app.open_avatar(avatar_path)
    app.state.camera.orbit(30, 10)
    app.state.sliders[:2] = [1.5, -0.5]
    app.state.mode = "depth"
    app.state.save_session(tmp_path / "s.json")
    app.state.camera.orbit(-60, 0)
    app.state.sliders[:] = 0
    app.state.mode = "rgb"
    app.load_session(str(tmp_path / "s.json"))
    assert app.state.mode == "depth" and app.state.sliders[0] == pytest.approx(1.5)
    assert app.state.camera.yaw == pytest.approx(30)


@pytest.mark.slow
def test_cli_screenshot_and_quit(display, avatar_path, tmp_path):
    out = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", avatar_path, "--size", "800x600", "--screenshot",
                        str(out), "--quit-after-frames", "2", "--threads", "1"], env=env, capture_output=True,
                       text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    import cv2

    img = cv2.imread(str(out))
    assert img is not None and img.shape[:2] == (600, 800)


def test_cli_bad_avatar_exits_2(display, tmp_path):
    bad = tmp_path / "x.npga"
    bad.write_bytes(b"nonsense")
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", str(bad), "--screenshot", str(tmp_path / "s.png")],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and str(bad) in r.stderr


@pytest.mark.slow
def test_drop_files_and_rig_cameras(app, avatar_path, tmp_path):
    import json

    assert app.open_avatar(avatar_path)
    ex = app.avatar.expression
    np.save(tmp_path / "codes.npy", np.stack([ex.mean] * 5))
    app.on_drop(app.window, [str(tmp_path / "codes.npy")])
    app.step()
    assert app.sequence is not None and len(app.sequence) == 5
    # a two-camera rig in NeRSemble's layout: world_2_cam per serial, shared intrinsics
    from npga_core.camera.cameras import frame_points

    cams = [frame_points(np.asarray(app.avatar.cloud.means), 550, 802, direction=d) for d in ("front", "right")]
    k = [[cams[0].fx, 0, cams[0].cx], [0, cams[0].fy, cams[0].cy], [0, 0, 1]]
    serials = ("222200037", "222200038")
    rig = {"world_2_cam": {s: c.world_to_camera.tolist() for s, c in zip(serials, cams, strict=True)}, "intrinsics": k}
    (tmp_path / "camera_params.json").write_text(json.dumps(rig))
    app.state.actions.append(A.LoadRig(str(tmp_path / "camera_params.json")))
    settle(app)
    assert app.info.rig_names == ["222200037", "222200038"] and app.state.rig_index == 0
    front = app.read_window(viewport_only=True)
    app.state.rig_index = 1
    settle(app)
    side = app.read_window(viewport_only=True)
    assert np.abs(front.astype(int) - side.astype(int)).max() > 30


def test_record_viewport_to_mp4(app, avatar_path, tmp_path, monkeypatch):
    """Record MP4 writes H.264 whose frames carry the wall-clock times they were drawn at (read back with PyAV)."""
    import av

    monkeypatch.chdir(tmp_path)
    assert app.open_avatar(avatar_path)
    settle(app)
    started = time.perf_counter()
    app.state.actions.append(A.ToggleRecording())
    app.step()  # starts recording and records this frame
    for _ in range(6):
        time.sleep(0.15)  # a UI at well under 25 fps: the video must last as long as the recording did
        app.state.camera.orbit(3, 0)
        app.step()
    time.sleep(0.15)
    app.state.actions.append(A.ToggleRecording())
    app.step()  # stops before this frame is drawn
    elapsed = time.perf_counter() - started
    assert not app.info.recording and app.recorder.error is None and not app.state.errors
    with av.open(str(tmp_path / app.recorder.path)) as c:
        stream = c.streams.video[0]
        assert stream.codec_context.name == "h264" and stream.codec_context.pix_fmt == "yuv420p"
        frames = list(c.decode(stream))
        duration = float(stream.duration * stream.time_base)
    assert len(frames) == 7 == app.recorder.frames and app.recorder.dropped == 0
    times = [float(f.time) for f in frames]
    assert times[0] == 0.0 and min(np.diff(times)) >= 0.15 - 1e-3
    assert 7 * 0.15 - 1e-3 <= duration <= elapsed
    assert frames[0].to_ndarray(format="rgb24").std() > 5  # the avatar, not a flat image


def _key(app, key, ctrl=False):
    from imgui_bundle import imgui

    io = imgui.get_io()
    if ctrl:
        io.add_key_event(imgui.Key.mod_ctrl, True)
    io.add_key_event(key, True)
    app.step()
    io.add_key_event(key, False)
    if ctrl:
        io.add_key_event(imgui.Key.mod_ctrl, False)
    app.step()


@pytest.mark.slow
def test_ctrl_drag_selects_delete_and_undo(app, avatar_path):
    from imgui_bundle import imgui

    assert app.open_avatar(avatar_path)
    settle(app)
    n = len(app.avatar)
    before = app.read_window(viewport_only=True)
    io = imgui.get_io()
    x, _, w, h = app.window.viewport()  # framebuffer pixels; the Xvfb window has scale 1
    cx, cy = x + w / 2, h / 2
    io.add_mouse_pos_event(cx - 60, cy - 60)
    io.add_key_event(imgui.Key.mod_ctrl, True)
    app.step()
    io.add_mouse_button_event(0, True)
    app.step()
    for t in np.linspace(0, 1, 5):
        io.add_mouse_pos_event(cx - 60 + 120 * t, cy - 60 + 120 * t)
        app.step()
    io.add_mouse_button_event(0, False)
    io.add_key_event(imgui.Key.mod_ctrl, False)
    for _ in range(3):
        app.step()
    selected = int(app.edits.session.selection.sum())
    assert 0 < selected < n
    settle(app)
    highlighted = app.read_window(viewport_only=True)
    centre = highlighted[int(cy) - 20 : int(cy) + 20, int(cx - x) - 20 : int(cx - x) + 20].astype(int)
    assert (centre[..., 0] - centre[..., 2]).mean() > 40, "selected Gaussians should turn orange"
    posed, kept = app.doc.posed, ~app.edits.session.selection
    _key(app, imgui.Key.delete)
    assert len(app.avatar) == n - selected and app.edits.session.dirty
    np.testing.assert_array_equal(app.doc.posed.means, posed.means[kept])  # at once, before the worker's pose
    settle(app)
    np.testing.assert_allclose(app.doc.posed.means, posed.means[kept], atol=1e-5)  # the worker's pose agrees
    holed = app.read_window(viewport_only=True)
    assert np.abs(holed.astype(int) - before.astype(int)).max(axis=2).mean() > 1
    _key(app, imgui.Key.z, ctrl=True)
    assert len(app.avatar) == n
    settle(app)
    assert app.edits.session.history.names()[0][-1].lower().startswith(("select", "rect"))


@pytest.mark.slow
def test_inspect_mode_and_pick_in_the_window(app, avatar_path):
    assert app.open_avatar(avatar_path)
    settle(app)
    rgb = app.read_window(viewport_only=True)
    app.state.inspect.mode = "features"
    settle(app)
    feat = app.read_window(viewport_only=True)
    assert np.abs(feat.astype(int) - rgb.astype(int)).max(axis=2).mean() > 10
    assert app.info.inspect is not None and app.info.inspect.colouring is not None
    x, _, w, h = app.window.viewport()
    idx = app.pick(w / 2, h / 2)
    assert idx is not None and 0 <= idx < len(app.avatar)
    settle(app)
    rec = app.info.inspect.record
    assert rec is not None and app.info.inspect.counts.total == len(app.avatar)
    app.state.actions.append(A.FocusGaussian(idx))
    app.step()
    np.testing.assert_allclose(app.state.camera.target, app.shown_posed().means[idx], atol=1e-6)


def test_sequence_head_pose_moves_the_view(app, tmp_path):
    """A tracked sequence with head rotation: frame 0 is the unmoved view (relative pose), a later frame turns
    the head (camera = V T_0^-1 T_t), and the Head pose checkbox turns it off again."""
    from npga_core.posing.headpose import head_transform

    path = tmp_path / "small.npga"
    save_avatar(make_synthetic_avatar(3000, seed=3), path)
    app.state.show_stats = False  # its figures change from frame to frame over the view (more so on a busy machine)
    assert app.open_avatar(str(path))
    code = app.avatar.neutral_code()
    t = 8
    rotation = np.zeros((t, 3), np.float32)
    rotation[:, 1] = np.linspace(0.1, 0.9, t)  # turning about the vertical axis
    translation = np.zeros((t, 3), np.float32)
    translation[:, 0] = np.linspace(0.0, 0.05, t)
    seq = ExpressionSequence(np.repeat(code[None], t, 0), 10.0, "turn", rotation=rotation, translation=translation)
    seq.save(tmp_path / "turn.npzseq")
    settle(app)
    base = app.current_camera().world_to_camera.copy()
    assert app.open_sequence(str(tmp_path / "turn.npzseq"))
    settle(app)
    np.testing.assert_allclose(app.current_camera().world_to_camera, base, atol=1e-9)  # frame 0: identity
    unmoved = app.read_window(viewport_only=True)
    app.state.actions.append(A.StepFrames(5))
    assert run_until(app, lambda: app.poses.shown_frame == 5)
    settle(app)
    want = base @ head_transform(app.sequence, 5)
    np.testing.assert_allclose(app.current_camera().world_to_camera, want, atol=1e-9)
    turned = app.read_window(viewport_only=True)
    assert (np.abs(turned.astype(int) - unmoved.astype(int)).max(axis=2) > 8).mean() > 0.01
    click(app, "head_pose")
    assert not app.state.timeline.head_pose
    from imgui_bundle import imgui

    imgui.get_io().add_mouse_pos_event(5.0, 5.0)  # away from the checkbox: its tooltip reaches into the view
    settle(app)
    np.testing.assert_allclose(app.current_camera().world_to_camera, base, atol=1e-9)
    back = app.read_window(viewport_only=True)
    moved = (np.abs(back.astype(int) - unmoved.astype(int)).max(axis=2) > 8).mean()
    assert moved < 0.002  # the same picture again


# --- frame-budgeted drawing (#14): behaviour in the real window, never rates ------------------------------------
def test_first_image_is_the_labelled_canonical_cloud_then_the_exact_pose(app, avatar_path):
    assert app.open_avatar(avatar_path)
    assert app.poses.canonical  # shown at once, before the pose worker has answered
    assert run_until(app, lambda: app.draws.images >= 1)
    first_pixels = app.read_window(viewport_only=True)
    assert first_pixels.max() > 40  # the avatar, not a black view
    if app.poses.canonical:
        assert app.draws.status == "preview"
    assert run_until(app, lambda: not app.poses.canonical and app.draws.status == "exact", timeout=120)
    assert app.draws.scale == 1.0


def test_scale_goes_down_while_orbiting_and_back_to_full_after(app, avatar_path):
    assert app.open_avatar(avatar_path)
    settle(app)
    app.draws.interactive_ms = 1e-3  # as if drawing were very slow: the live scale must drop to its minimum
    scales = []
    for _ in range(60):
        app.state.camera.orbit(2.0, 0.0)
        app.step()
        scales.append(app.draws.scale)
        if app.draws.scale <= app.draws.min_scale + 1e-6:
            break
    assert min(scales) < 1.0
    assert app.info.image_status == "preview"
    assert run_until(app, lambda: app.draws.settled)
    assert app.draws.scale == 1.0 and app.draws.status == "exact"
    app.step()
    assert app.info.image_status == "exact" and app.info.draw_scale == 1.0
    # the UI frames' time by section (npga_view/frame_profile.py): every section of a drawn frame (a frame with
    # nothing new is not drawn: then it has no ui and swap), the splats' work inside "splats"; the overlay says it
    from npga_view.frame_profile import SECTIONS

    assert run_until(app, lambda: "swap" in app.profile.last)
    assert set(app.profile.last) == set(SECTIONS) and sum(app.profile.last.values()) > 0.0
    assert app.info.frame_profile[0].startswith("UI frame ") and "splats" in app.info.frame_profile[1]


def test_sliced_window_image_equals_one_draw(app, avatar_path):
    app.state.use_cnn = False  # the splat image itself (the demo's CNN image would replace it once settled)
    assert app.open_avatar(avatar_path)
    settle(app)
    app.draws.budget_ms = 0.0  # the smallest slices: the image takes many UI frames
    app.draws.invalidate()
    frames = 0
    while not app.draws.settled:
        app.step()
        frames += 1
        assert frames < 5000
    assert app.renderer.last_timings["slices"] >= 2
    app.step()
    below = slice(320, None)  # below the statistics overlay, whose figures differ between the two
    sliced = app.read_window(viewport_only=True)[below]
    assert sliced.max() > 40
    app.draws.enabled = False  # the behaviour before budgeting: one draw inside the frame
    app.draws.invalidate()
    app.step()
    app.step()
    np.testing.assert_array_equal(app.read_window(viewport_only=True)[below], sliced)


# --- screen-space refinement in the window (#17) --------------------------------------------------------------
def test_window_shows_the_cnn_refined_image_as_render_does(app, tmp_path):
    """With a CNN avatar and "CNN refined" on, the settled view is the CNN's output: the same pixels as
    `npga-view render` for the same camera and code; "raw splats" changes them."""
    import cv2

    path = tmp_path / "cnn.npga"
    save_avatar(make_synthetic_avatar(3000, latent_dim=4, with_cnn=True, seed=5), path)
    app.state.show_stats = False
    assert app.open_avatar(str(path))
    settle(app)
    assert run_until(app, lambda: app.info.shown == "refined", timeout=120)
    app.step()
    window = app.read_window(viewport_only=True).astype(np.int16)
    camera = app.current_camera()
    camera.to_json(tmp_path / "cam.json")
    np.save(tmp_path / "z.npy", app.poses.shown_code)
    r = subprocess.run([sys.executable, "-m", "npga_view.cli", "render", str(path), "--camera",
                        str(tmp_path / "cam.json"), "--expr", str(tmp_path / "z.npy"), "--out",
                        str(tmp_path / "ref.png")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    ref = cv2.imread(str(tmp_path / "ref.png"))[:, :, ::-1].astype(np.int16)
    assert ref.shape == window.shape
    assert np.abs(window - ref).mean() < 1.0 and np.abs(window - ref).max() <= 12
    click(app, "raw_splats")
    assert run_until(app, lambda: app.info.shown == "splats")
    settle(app)
    raw = app.read_window(viewport_only=True).astype(np.int16)
    assert np.abs(raw - window).mean() > 1.0  # the CNN does change the picture


def test_an_idle_window_waits_for_input_instead_of_spinning(app, avatar_path, monkeypatch, tmp_path):
    """Once the view is on screen and nothing is drawn, the loop waits for input (up to its idle wait, so worker
    results still arrive) instead of redrawing as fast as it can; a pose from the worker is still taken and
    drawn while waiting, and playback never waits."""
    import glfw

    waits = []
    real_wait = glfw.wait_events_timeout
    monkeypatch.setattr(glfw, "wait_events_timeout", lambda t: (waits.append(t), real_wait(t)))
    assert app.open_avatar(avatar_path)
    settle(app)
    assert run_until(app, lambda: app.view.pacing.was_quiet)
    waits.clear()
    app.step()
    assert waits == [pytest.approx(1.0 / 30.0)]
    # a slider move made while waiting (no input event): the new exact pose still reaches the screen
    version = app.draws.shown_version
    app.state.follow_sequence = False
    app.state.sliders[0] += 1.0
    assert run_until(app, lambda: app.draws.shown_version != version and app.draws.settled
                     and not app.poses.preview and app.engine.pending is None, timeout=120)
    # playback is never quiet
    codes = np.repeat(app.avatar.expression.mean[None], 50, axis=0).astype(np.float32)
    ExpressionSequence(codes, 25.0, "still").save(tmp_path / "still.npzseq")
    assert app.open_sequence(str(tmp_path / "still.npzseq"))
    app.state.follow_sequence, app.state.timeline.playing = True, True
    app.step()
    app.step()
    assert not app.view.pacing.was_quiet
    waits.clear()
    app.step()
    assert waits == []


def test_orbit_draws_live_images_from_the_merged_cloud_and_the_exact_one_from_all(app, avatar_path, tmp_path):
    """While only the camera moves, live images come from the merged level-of-detail cloud (the overlay says
    so); once it stops, the full-resolution image is drawn from every Gaussian."""
    assert app.open_avatar(avatar_path)
    app.lod.min_count = 0  # (the small synthetic avatar, when the demo is not built, is merged too, and its
    app.draws.lod_above_ms = 0.0  # full image, a few ms, counts as too slow: as the demo's on llvmpipe)
    settle(app)
    merged = []
    for _ in range(400):
        app.state.camera.orbit(2.0, 0.0)
        app.step()
        merged.append(app.info.merged_splats)
        if app.info.merged_splats:
            break
    assert merged[-1] == app.lod.count > 0 and app.lod.count < len(app.avatar)
    assert app.info.image_status == "preview" and app.draws.shown_renderer is app.lod.renderer
    app.screenshot(str(tmp_path / "orbit_merged.png"))
    assert app.read_window(viewport_only=True).max() > 40  # the merged avatar on screen
    assert run_until(app, lambda: app.draws.settled, timeout=120)
    app.step()
    assert app.info.merged_splats == 0 and app.info.image_status == "exact" and app.draws.scale == 1.0
    assert app.draws.shown_renderer is app.renderer


@pytest.mark.slow
def test_merged_cloud_can_be_switched_off_in_the_view_panel(app, avatar_path):
    """The View panel's "Merged cloud while moving": off, an orbit's live images come from every Gaussian."""
    assert app.open_avatar(avatar_path)
    app.lod.min_count = 0
    settle(app)
    assert app.state.merged_live
    click(app, "merged_live")
    assert not app.state.merged_live
    for _ in range(60):
        app.state.camera.orbit(2.0, 0.0)
        app.step()
        assert app.info.merged_splats == 0 and app.draws.shown_renderer is app.renderer
    assert not app.lod.enabled
