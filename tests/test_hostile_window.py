"""The window's open actions (avatar, sequence, session, rig, keyframes, presets, Recover) given hostile files:
each is reported in the side panel as one line naming the file, and the window keeps running."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.model.synthetic import make_synthetic_avatar

from . import hostile_corpus as hc
from .xvfb import xvfb_display

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
