"""The real window (Xvfb) on a GaussianAvatars output folder with the user's FLAME model: the folder is imported
once into the user's cache (the status line says so; the pose worker reopens that file), the avatar is drawn, the
jaw slider moves its pixels, a second open reuses the cached import, a dropped folder opens as an avatar, and
`npga-view view FOLDER --flame-model PKL --screenshot` draws it from the command line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support import ga_synthetic as gs
from tests.support.window import settled, until_changed
from tests.support.xvfb import xvfb_display

pytestmark = pytest.mark.gui


@pytest.fixture(scope="module")
def display():
    yield from xvfb_display()


@pytest.fixture(scope="module")
def ga(tmp_path_factory):
    """A GaussianAvatars folder (2,000 Gaussians) and a FLAME pickle whose identity leaves a head-like mesh."""
    root = tmp_path_factory.mktemp("gawin")
    flame = gs.flame_arrays(2)
    flame["shapedirs"] *= 0.01  # a smooth identity: the random shape directions would crumple the mesh
    flame["posedirs"] *= 0.1
    pkl = gs.write_flame_pickle(root / "flame2023.pkl", flame, "numpy")
    folder = gs.write_ga_folder(root / "out", 2000, seed=3, frames=4, iterations=(30000,))
    return root, folder, pkl


@pytest.fixture(scope="module")
def window(display, ga):
    root = ga[0]
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CONFIG_HOME", str(root / "config"))
    mp.setenv("XDG_CACHE_HOME", str(root / "cache"))
    from npga_view.app import ViewerApp

    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    yield app
    app.close()
    mp.undo()


def test_window_opens_a_ga_folder_with_a_flame_model(window, ga):
    from npga_view import actions as A
    from npga_view.panels.files import open_action

    app = window
    root, folder, pkl = ga
    app.state.show_stats = False
    assert not app.open_avatar(str(folder))  # no FLAME model yet: one line naming the folder and the remedy
    assert str(folder) in app.state.errors[-1] and "--flame-model" in app.state.errors[-1]
    app.state.errors = []
    blank = app.read_window(viewport_only=True)
    app.state.flame_model = str(pkl)
    assert app.open_avatar(str(folder)), app.state.errors
    assert "imported" in app.state.notices[-1] and "MPI" in app.state.notices[-1]
    cached = Path(app.state.avatar_path or "")
    assert cached.parent == root / "cache" / "npga-view" / "gaussian-avatars" and cached.suffix == ".npga"
    assert app.avatar is not None and app.avatar.source == str(cached) and len(app.avatar) == 2000
    until_changed(app, blank)
    rest = settled(app)
    assert rest.std() > 5, "the avatar should be visible"
    names = app.avatar.rig.input_names  # type: ignore[union-attr]
    basis = app.avatar.expression.basis  # type: ignore[union-attr]
    jaw = [i for i in range(len(basis)) if names[int(np.argmax(basis[i]))] == "jaw.x"]
    assert len(jaw) == 1
    app.state.follow_sequence = False
    app.state.sliders[jaw[0]] = 3.0  # three of the avatar's own spreads
    opened = until_changed(app, rest)
    assert (np.abs(opened.astype(int) - rest.astype(int)).max(axis=2) > 8).mean() > 0.005
    if os.environ.get("NPGA_TEST_SHOTS"):  # where to keep the pictures to look at
        import cv2

        for name, img in (("ga_rest.png", rest), ("ga_jaw.png", opened)):
            cv2.imwrite(str(Path(os.environ["NPGA_TEST_SHOTS"]) / name), img[:, :, ::-1])

    app.state.notices = []
    assert app.open_avatar(str(folder)), app.state.errors  # the same inputs: the cached import, not a new one
    assert "cached import" in app.state.notices[-1] and app.state.avatar_path == str(cached)
    assert len(list(cached.parent.glob("*.npga"))) == 1
    assert open_action(str(folder)) == A.OpenAvatar(str(folder))  # a dropped or listed folder opens as an avatar


@pytest.mark.slow
def test_view_command_with_flame_model(display, ga, tmp_path):
    root, folder, pkl = ga
    out = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp_path / "config"),
               XDG_CACHE_HOME=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "npga_view.cli.main", "view", str(folder), "--flame-model", str(pkl), "--size",
           "640x480", "--screenshot", str(out), "--quit-after-frames", "30", "--threads", "1"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    shots = os.environ.get("NPGA_TEST_SHOTS")  # where to keep the screenshot to look at
    if shots:
        import shutil

        shutil.copy(out, Path(shots) / "ga_view_command.png")
    assert r.returncode == 0, r.stderr
    import cv2

    img = cv2.imread(str(out))
    assert img is not None and img.shape[:2] == (480, 640) and img.std() > 5
    assert len(list((tmp_path / "cache").rglob("*.npga"))) == 1
    assert (tmp_path / "config" / "npga-view" / "flame_model.json").is_file()  # remembered for the Files panel
    bad = tmp_path / "evil.pkl"
    bad.write_bytes(b"cos\nsystem\n(S'touch " + str(tmp_path / "pwned").encode() + b"'\ntR.")
    r = subprocess.run(cmd[:6] + [str(bad)] + cmd[7:], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and str(bad) in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "pwned").exists()
