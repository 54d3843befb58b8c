"""The window's open actions (avatar, sequence, session, rig, keyframes, presets, Recover) given hostile files:
each is reported in the side panel as one line naming the file, and the window keeps running."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view import actions as A
from tests.support import hostile_corpus as hc
from tests.support.xvfb import xvfb_display

pytestmark = [pytest.mark.gui, pytest.mark.skipif(not sys.platform.startswith("linux"), reason="FIFOs, Xvfb")]


@pytest.fixture(scope="module")
def display():
    yield from xvfb_display()


def test_window_reports_hostile_files_and_stays_up(display, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from npga_view import actions as A
    from npga_view.app import ViewerApp

    avatar = make_synthetic_avatar(500, seed=4)
    good = tmp_path / "a.npga"
    save_avatar(avatar, good)
    for sub in ("npy", "ses", "kf", "rig", "av"):
        (tmp_path / sub).mkdir()
    npy = hc.npy_codes(tmp_path / "npy", avatar.code_dim)
    jsons = hc.session_json(tmp_path / "ses")
    keys = hc.keyframe_json(tmp_path / "kf", avatar.code_dim)
    rigs = hc.rig_json(tmp_path / "rig")
    avatars = hc.npga_files(tmp_path / "av", good)
    actions = [
        ("open_sequence", npy["huge claimed shape"]), ("open_sequence", npy["fifo"]),
        ("open_sequence", npy["complex"]), ("open_sequence", npy["object (pickle)"]),
        ("load_session", jsons["nested 100000 deep"]), ("load_session", jsons["fifo"]),
        ("load_session", jsons["camera fov a string"]), ("load_session", jsons["unknown smoothing"]),
        ("load_session", jsons["bake budget 0"]),
        ("open_sequence", npy["codes of 3e38 (finite, overflow in the dynamics)"]),
        ("kf_load", keys["key time 1e308"]), ("load_rig", rigs["singular world_2_cam"]),
        ("kf_load", keys["nested 100000 deep"]), ("kf_load", keys["20000 keys"]), ("kf_load", keys["fifo"]),
        ("load_rig", rigs["image_size 10^9"]), ("load_rig", rigs["char device (/dev/zero)"]),
        ("open_avatar", avatars["fifo"]), ("open_avatar", avatars["header claims 10^12 Gaussians"]),
    ]
    ACTIONS = {"open_sequence": A.OpenSequence, "load_session": A.LoadSession, "kf_load": A.LoadKeyframes,
               "load_rig": A.LoadRig, "open_avatar": A.OpenAvatar}
    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    try:
        assert app.open_avatar(str(good))
        for name, path in actions:
            app.state.errors = []
            app.state.actions.append(ACTIONS[name](str(path)))
            for _ in range(3):
                app.step()
            assert not app.should_close and app.window is not None, name
            assert len(app.state.errors) == 1 and str(path) in app.state.errors[0], (name, path, app.state.errors)
        # still the avatar it had, still drawing
        assert app.avatar is not None and len(app.avatar) == 500
        before = app.frames
        app.step()
        assert app.frames == before + 1
        assert np.isfinite(app.state.sliders).all()
    finally:
        app.close()
    assert not (tmp_path / "npy" / hc.MARKER).exists()


def test_window_shows_names_of_any_encoding(display, tmp_path, monkeypatch):
    """Part names, provenance, presets, file names, recent paths, browsed folders and messages with lone UTF-16
    surrogates, undecodable bytes and newlines: every panel (all forced open) draws them escaped through
    npga_core.errors.shown, the window title takes them, and the window keeps drawing."""
    import os

    from imgui_bundle import imgui

    from npga_view.app import ViewerApp

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from npga_core.files.ply import save_ply

    cases = tmp_path / "cases"
    cases.mkdir()
    good = tmp_path / "good.npga"
    avatar = make_synthetic_avatar(300, seed=4)
    save_avatar(avatar, good)
    save_ply(make_synthetic_avatar(50, with_f=False, with_g=False).cloud, tmp_path / "good.ply")
    named = hc.degenerate_avatars(cases, tmp_path / "good.ply", good)["lone surrogates and newlines in part names and "
                                                                      "provenance"]
    odd = tmp_path / os.fsdecode(b"odd-\xff\nname")  # undecodable byte and a newline in the folder's name
    odd.mkdir()
    src = odd / os.fsdecode(b"avatar-\xfe.npga")
    src.write_bytes(named.read_bytes())
    seq = odd / os.fsdecode(b"seq-\xfd\t.npy")
    np.save(seq, np.zeros((5, avatar.code_dim), np.float32))
    for name in ("open", "collapsing"):  # every tree node and header open, so that every panel draws its names
        original = imgui.tree_node if name == "open" else imgui.collapsing_header

        def forced(*a, _original=original, **k):
            imgui.set_next_item_open(True, imgui.Cond_.always)
            return _original(*a, **k)

        monkeypatch.setattr(imgui, "tree_node" if name == "open" else "collapsing_header", forced)
    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    app.panels.files.browse = str(odd)  # the Files panel browses the folder of odd names
    try:
        assert app.open_avatar(str(src)), app.state.errors
        assert app.open_sequence(str(seq)), app.state.errors
        app.state.presets = {"smile\ud800\nwide": [0.0] * avatar.code_dim}
        app.state.recent = [str(src), str(seq)]
        app.state.report(f"a message naming {src}")
        before = app.frames
        for _ in range(12):
            app.step()
        assert app.frames == before + 12 and not app.should_close and app.window is not None
        assert app.state.errors and all(e.isprintable() and "\\udcff" in e for e in app.state.errors)
        app.screenshot(str(tmp_path / "names.png"))
    finally:
        app.close()


@pytest.mark.slow
def test_window_with_an_avatar_of_0_gaussians(display, tmp_path, monkeypatch):
    """A degenerate but valid avatar of 0 Gaussians, from a file and left by deleting every Gaussian in the
    window: it opens, its pose arrives, the view is the background only, the panels say "0 Gaussians", its edits
    autosave and Recover reopens them, all without an error."""
    import time

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from npga_view.app import ViewerApp

    zero, good = tmp_path / "zero.npga", tmp_path / "good.npga"
    save_avatar(make_synthetic_avatar(0, seed=3), zero)
    save_avatar(make_synthetic_avatar(300, seed=4, latent_dim=3, with_cnn=True), good)  # h and a CNN, as the demo
    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    try:
        assert app.open_avatar(str(zero)), app.state.errors
        app.state.show_stats = False
        deadline = time.monotonic() + 180  # a bound on a hang: the worker's first pose
        app.step()
        while (app.poses.canonical or app.info.posing) and time.monotonic() < deadline:
            app.step()
        for _ in range(3):
            app.step()
        assert not app.info.canonical and len(app.info.avatar) == 0 and not app.state.errors
        view = app.read_window(viewport_only=True)
        assert (view == view[0, 0]).all()  # the background only
        app.screenshot(str(tmp_path / "zero.png"))
        assert app.open_avatar(str(good)), app.state.errors
        for action in (A.SelectAll(), A.DeleteSelection()):
            app.state.actions.append(action)
            app.step()
        session = app.info.edit
        assert session is not None and len(session.avatar) == 0 and session.dirty
        saved = session.autosave()  # what the window's autosave timer and close do
        assert saved is not None and saved.is_file()
        app.state.actions.append(A.RecoverEdits(str(good)))
        for _ in range(5):
            app.step()
        assert app.info.edit is not None and len(app.info.edit.avatar) == 0 and not app.state.errors, \
            app.state.errors
        before = app.frames
        app.step()
        assert app.frames == before + 1 and not app.should_close
    finally:
        app.close()


def test_window_extreme_means_surrogate_names_and_playback_quit(display, tmp_path, monkeypatch):
    """#36: an avatar whose means reach the position limit opens and is framed (3e38, beyond it, was opened and
    framing it failed: `look_at: eye and target coincide`; it is now refused by the reader, one line, the window
    stays); names with lone surrogates where the Live Link panel (basis names nothing drives), the Timeline's
    head-pose source and the overlay draw them (imgui raised TypeError); and `--quit-after-frames` ends a
    playing sequence of 5 frames (it counted only settled frames, which playback never has)."""
    import threading

    from imgui_bundle import imgui

    from npga_core.camera.cameras import MAX_POSITION
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.blendshapes import BlendshapeBasis
    from npga_view.app import ViewerApp

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    far, beyond, named = tmp_path / "far.npga", tmp_path / "beyond.npga", tmp_path / "named.npga"
    for path, value in ((far, MAX_POSITION), (beyond, 3e38)):
        a = make_synthetic_avatar(120, seed=6, with_f=False, with_g=False)
        a.cloud.means[:] = value
        a.cloud.means[::2] *= -1
        save_avatar(a, path)
    avatar = make_synthetic_avatar(300, seed=4)
    d = avatar.code_dim
    avatar.blendshapes = BlendshapeBasis(("jawOpen", "odd\ud800\nname", "x\udcff"), np.zeros((d, 3), np.float32),
                                         np.zeros(d, np.float32), "basis\ud800")
    save_avatar(avatar, named)
    seq = tmp_path / "posed.npzseq"
    ExpressionSequence(np.zeros((5, d), np.float32), 25.0, "s\ud800", pose=np.tile(np.eye(4), (5, 1, 1)),
                       pose_source="tracked\udcff\n\x1b[31m").save(seq)
    for name in ("open", "collapsing"):  # every tree node and header open, so that every panel draws its names
        original = imgui.tree_node if name == "open" else imgui.collapsing_header

        def forced(*a, _original=original, **k):
            imgui.set_next_item_open(True, imgui.Cond_.always)
            return _original(*a, **k)

        monkeypatch.setattr(imgui, "tree_node" if name == "open" else "collapsing_header", forced)
    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    fired = threading.Event()
    try:
        assert app.open_avatar(str(far)), app.state.errors
        for _ in range(3):
            app.step()
        assert np.isfinite(app.state.camera.target).all() and not app.state.errors, app.state.errors
        assert not app.open_avatar(str(beyond))
        assert len(app.state.errors) == 1 and str(beyond) in app.state.errors[0]
        app.state.errors = []
        assert app.open_avatar(str(named)), app.state.errors
        assert app.open_sequence(str(seq)), app.state.errors
        assert app.live.start("127.0.0.1:0"), app.state.errors
        before = app.frames
        for _ in range(8):
            app.step()
        assert app.frames == before + 8 and not app.should_close and not app.state.errors, app.state.errors
        assert app.open_avatar("demo"), app.state.errors  # a view that never settles while it plays
        demo_seq = tmp_path / "demo.npzseq"
        rng = np.random.default_rng(0)
        ExpressionSequence(rng.normal(0, 1, (5, app.avatar.code_dim)).astype(np.float32), 25.0, "d").save(demo_seq)
        assert app.open_sequence(str(demo_seq)), app.state.errors
        app.state.timeline.playing = app.state.timeline.loop = True

        def stop() -> None:
            fired.set()
            app.request_close()

        watchdog = threading.Timer(120.0, stop)  # a bound on the hang this test is about
        watchdog.start()
        try:
            app.run(None, 5)
        finally:
            watchdog.cancel()
        assert not fired.is_set(), "--quit-after-frames never ended the playing sequence"
    finally:
        app.close()
