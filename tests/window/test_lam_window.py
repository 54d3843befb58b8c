"""The real window (Xvfb) on a LAM avatar zip: it opens the zip as it is, the named channel sliders and a Live
Link Face take move the pixels where the channels move the splats, a Live Link stream drives it, and a hostile
zip is one line in the window, which keeps drawing."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from npga_core.files.blendshape_names import ARKIT_52
from tests.support.lam_layout import write_lam_zip
from tests.support.takes import write_one_channel_take
from tests.support.window import settled, until_changed
from tests.support.xvfb import xvfb_display

pytestmark = pytest.mark.gui


@pytest.fixture(scope="module")
def display():
    yield from xvfb_display()


@pytest.fixture(scope="module")
def window(display, tmp_path_factory):
    root = tmp_path_factory.mktemp("lamwin")
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CONFIG_HOME", str(root / "config"))
    from npga_view.app import ViewerApp

    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    app.state.show_stats = False  # its figures change from frame to frame over the view (every test reads it)
    yield app, root
    app.close()
    mp.undo()


def test_window_on_a_lam_zip(window):
    app, root = window
    zpath = write_lam_zip(root / "avatar.zip", n=1500, seed=4)
    blank = app.read_window(viewport_only=True)
    assert app.open_avatar(str(zpath)), app.state.errors
    a = app.avatar
    assert a is not None and a.slider_channels is not None and len(a.slider_channels) == 51
    until_changed(app, blank)
    rest = settled(app)
    assert rest.std() > 5, "the avatar should be visible"
    app.state.follow_sequence = False
    jaw = a.slider_channels.index("jawOpen")
    app.state.sliders[jaw] = 1.0  # the jawOpen slider (0..1), scaled x1.2 as LAM's player does
    opened = until_changed(app, rest)
    assert (np.abs(opened.astype(int) - rest.astype(int)).max(axis=2) > 8).mean() > 0.01
    app.state.sliders[jaw] = 0.0
    until_changed(app, opened)
    closed = settled(app)
    differs = (np.abs(closed.astype(int) - rest.astype(int)).max(axis=2) > 8).mean()
    assert differs < 0.002, differs  # back to the rest pose's pixels (jaw open changed far more)
    take = root / "take.csv"
    write_one_channel_take(take, 60, "jawOpen")
    assert app.open_sequence(str(take)), app.state.errors
    assert app.sequence is not None and len(app.sequence) >= 60  # (the frame rate of takes is issue #35's)
    app.state.follow_sequence = True
    app.state.timeline.time_s = 10.0  # past the end: the last row, jaw fully open
    until_changed(app, closed)


def test_live_link_stream_drives_a_lam_zip(window):
    from npga_core.posing.livelink import encode

    app, root = window
    zpath = write_lam_zip(root / "live.zip", n=1500, seed=5)
    app.state.errors = []
    assert app.open_avatar(str(zpath)), app.state.errors
    rest = until_changed(app, app.read_window(viewport_only=True), min_fraction=0.0)
    assert app.live.start("127.0.0.1:0"), app.state.errors
    addr = app.live.receiver.address
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        v = np.zeros(61, np.float32)
        v[ARKIT_52.index("jawOpen")] = 1.0
        end = time.monotonic() + 180
        changed = False
        frame = 1
        while time.monotonic() < end and not changed:
            sock.sendto(encode(v, frame, fps=60, subject="test"), addr)
            frame += 1
            for _ in range(3):
                app.step()
            now = app.read_window(viewport_only=True)
            changed = (np.abs(now.astype(int) - rest.astype(int)).max(axis=2) > 8).mean() > 0.002
        assert changed, "the stream's jawOpen did not move the pixels"
        assert app.live.taken > 0 and not app.state.errors
    finally:
        sock.close()
        app.live.stop()


def test_hostile_zip_is_one_line_and_the_window_keeps_drawing(window):
    app, root = window
    good = write_lam_zip(root / "good.zip", n=800, seed=6)
    assert app.open_avatar(str(good))
    bad = write_lam_zip(root / "bad.zip", n=800, seed=6, tamper_ply=lambda c: c["x"].__setitem__(3, np.nan))
    app.state.errors = []
    assert not app.open_avatar(str(bad))
    assert len(app.state.errors) == 1 and str(bad) in app.state.errors[0] and "\n" not in app.state.errors[0]
    assert app.avatar is not None and len(app.avatar) == 800  # the open avatar stays
    for _ in range(5):
        app.step()


def test_an_avatar_without_a_basis_gets_one_from_load_basis(window):
    """A take handed to an avatar without a blendshape basis is one line saying how to get one; "Load basis"
    (the LoadBasis action) gives it one, and the take then opens through it."""
    from npga_core.files.basis_file import save_basis
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.blendshapes import BlendshapeBasis
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_view import actions as A

    app, root = window
    avatar = make_synthetic_avatar(400, code_dim=6, hidden=8, depth=2, n_components=3, seed=2)
    path = root / "nobasis.npga"
    save_avatar(avatar, path)
    take = root / "take6.csv"
    write_one_channel_take(take, 12, "jawOpen")
    assert app.open_avatar(str(path))
    app.state.errors = []
    assert not app.open_sequence(str(take))
    assert len(app.state.errors) == 1 and "no blendshape basis" in app.state.errors[0]
    basis = root / "basis.npz"
    rng = np.random.default_rng(0)
    save_basis(BlendshapeBasis(ARKIT_52, rng.normal(size=(6, 52)), np.zeros(6), "test"), basis)
    app.state.actions.append(A.LoadBasis(str(basis)))
    app.step()
    assert app.avatar is not None and app.avatar.blendshapes is not None
    assert app.open_sequence(str(take)), app.state.errors
    assert app.sequence is not None and app.sequence.codes.shape[1] == 6
    wrong = root / "wrong.npz"
    save_basis(BlendshapeBasis(ARKIT_52, np.ones((9, 52)), np.zeros(9), "test"), wrong)
    app.state.errors = []
    app.state.actions.append(A.LoadBasis(str(wrong)))
    app.step()
    assert len(app.state.errors) == 1 and "wrong.npz" in app.state.errors[0] and "9-D" in app.state.errors[0]
