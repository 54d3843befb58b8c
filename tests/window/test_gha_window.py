"""The real window (Xvfb) on an imported Gaussian-Head-Avatar checkpoint: it opens the folder, the sliders and a
params sequence move the pixels, and the raw/refined switch shows the first three colour channels or the CNN."""

from __future__ import annotations

import pytest

from npga_core.files.gha_synthetic import write_gha_folder, write_gha_params
from tests.support.window import until_changed
from tests.support.xvfb import xvfb_display

pytestmark = pytest.mark.gui

SMALL = {"feature_dim": 16, "exp_dim": 8, "hidden": 32, "channels": 8, "freqs": 2, "capacity": 2}


@pytest.fixture(scope="module")
def display():
    yield from xvfb_display()


@pytest.fixture(scope="module")
def window(display, tmp_path_factory):
    root = tmp_path_factory.mktemp("ghawin")
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CONFIG_HOME", str(root / "config"))
    from npga_view.app import ViewerApp

    app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
    app.state.show_stats = False  # its figures change from frame to frame over the view
    yield app, root
    app.close()
    mp.undo()


@pytest.mark.slow
def test_window_on_an_imported_gha_checkpoint(window):
    app, root = window
    folder = write_gha_folder(root / "ckpt", n=2500, seed=5, **SMALL)
    data = write_gha_params(root / "data", frames=6, exp_dim=SMALL["exp_dim"])
    for _ in range(3):  # the empty view drawn (the back buffer before the first frame holds anything)
        app.step()
    blank = app.read_window(viewport_only=True)
    app.state.use_cnn = False  # the raw splats: the first three colour channels
    assert app.open_avatar(str(folder))
    assert app.avatar is not None and app.avatar.condition_dim == 6
    raw = until_changed(app, blank)
    assert raw.std() > 5, "the avatar should be visible"
    app.state.follow_sequence = False
    app.state.sliders[0] = 3.0  # the first raw expression coefficient, +3
    moved = until_changed(app, raw)
    assert app.open_sequence(str(data))
    app.state.follow_sequence = True
    until_changed(app, moved)
    app.state.use_cnn = True  # GHA's super-resolution CNN on the 8-channel image at a quarter of the size
    refined = until_changed(app, app.read_window(viewport_only=True), min_fraction=0.05)
    assert refined.std() > 1


class _Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        from pathlib import Path

        return (Path.touch, (self.marker,))


def test_window_shows_a_hostile_checkpoint_in_one_line_and_keeps_running(window):
    import torch

    from npga_core.files.gha_synthetic import gha_state_dicts

    app, root = window
    evil = root / "evil"
    evil.mkdir()
    marker = root / "executed"
    head, _ = gha_state_dicts(300, 0, **SMALL)
    torch.save({**head, "x": _Payload(marker)}, evil / "gaussianhead_latest")
    before = app.avatar
    assert not app.open_avatar(str(evil))
    for _ in range(3):
        app.step()
    errs = " | ".join(app.state.errors)
    assert "gaussianhead_latest: holds more than tensors" in errs and "\n" not in errs
    assert app.avatar is before and not marker.exists()
    assert app.read_window(viewport_only=True).std() > 1
