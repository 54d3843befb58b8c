"""The expression pad: bilinear blending of four corner codes, corners from named expressions, presets and
sequence frames, and the sliders it drives."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.sequences import ExpressionSequence
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing.pad import blend, weights
from npga_view.panels.expression_pad import ExpressionPad
from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState


def test_blend_corners_centre_and_edges():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(4, 7))
    for i, (u, v) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        np.testing.assert_allclose(blend(c, u, v), c[i], atol=1e-6)
    np.testing.assert_allclose(blend(c, 0.5, 0.5), c.mean(0), atol=1e-6)
    np.testing.assert_allclose(blend(c, 0.5, 0.0), (c[0] + c[1]) / 2, atol=1e-6)  # top edge: the top corners
    np.testing.assert_allclose(blend(c, 0.25, 1.0), 0.75 * c[2] + 0.25 * c[3], atol=1e-6)
    np.testing.assert_allclose(blend(c, -3, 7), c[2], atol=1e-6)  # outside: clamped to the square
    assert weights(0.3, 0.8).sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="4 corner codes"):
        blend(c[:3], 0.5, 0.5)


@pytest.fixture
def world():
    avatar = make_synthetic_avatar(50, code_dim=6, hidden=8, depth=2, n_components=6, seed=1)
    ex = avatar.expression
    rng = np.random.default_rng(3)
    ex.named = {"neutral": ex.mean.copy(), "a": ex.sample(rng), "b": ex.sample(rng)}
    state = ViewerState()
    state.sliders = np.zeros(ex.n_components, np.float32)
    state.presets = {"mine": [float(x) for x in ex.sample(rng)]}
    seq = ExpressionSequence(np.stack([ex.sample(rng) for _ in range(5)]), 25.0, "s")
    info = AppInfo(avatar=avatar, sequence=seq, frame=3)
    return avatar, state, info


def test_corners_give_their_codes_and_the_centre_the_mean(world):
    avatar, state, info = world
    ex = avatar.expression
    pad = ExpressionPad()
    opts = pad.options(state, info)
    assert ("named", "a") in opts and ("preset", "mine") in opts and ("frame", 3) in opts
    pad.corners = [("named", "a"), ("preset", "mine"), ("frame", 3), ("named", "b")]
    want = [ex.named["a"], np.asarray(state.presets["mine"], np.float32), info.sequence.codes[3], ex.named["b"]]
    for i, (u, v) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        state.follow_sequence = True
        assert pad.move(u, v, state, info)
        assert not state.follow_sequence  # the pad drives the code, like the sliders
        np.testing.assert_allclose(ex.from_sliders(state.sliders), want[i], atol=1e-5)
    assert pad.move(0.5, 0.5, state, info)
    np.testing.assert_allclose(ex.from_sliders(state.sliders), np.mean(want, axis=0), atol=1e-5)


def test_missing_corner_leaves_the_sliders_alone(world):
    avatar, state, info = world
    pad = ExpressionPad()
    pad.defaults(state, info)
    assert pad.corners[:3] == [("named", "a"), ("named", "b"), ("named", "neutral")] and pad.corners[3] is None
    before = state.sliders.copy()
    assert not pad.move(0.2, 0.2, state, info)
    np.testing.assert_array_equal(state.sliders, before)
    pad.corners[3] = ("frame", 99)  # beyond the sequence
    assert pad.code(state, info) is None
    pad.corners[3] = ("preset", "gone")
    assert pad.code(state, info) is None


# ------------------------------------------------------------------------------------------ the real window


@pytest.fixture(scope="module")
def display():
    from tests.support.xvfb import xvfb_display

    yield from xvfb_display()


@pytest.mark.gui
def test_dragging_the_pad_in_the_window_poses_the_corner(display, tmp_path, monkeypatch):
    """Open the pad, press in it and drag to the top-left corner: the window poses that corner's code."""
    from imgui_bundle import imgui

    from npga_core.files.checkpoint import save_avatar
    from npga_view.app import ViewerApp
    from tests.support.window import click, run_until, settle

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    avatar = make_synthetic_avatar(800, code_dim=8, n_components=8, seed=2)
    ex = avatar.expression
    rng = np.random.default_rng(4)
    ex.named = {"smile": ex.sample(rng, scale=2.0), "surprise": ex.sample(rng, scale=2.0),
                "angry": ex.sample(rng, scale=2.0), "sad": ex.sample(rng, scale=2.0)}
    path = tmp_path / "pad.npga"
    save_avatar(avatar, path)
    app = ViewerApp(1000, 990, vsync=False, threads=1, remember_recent=False)
    try:
        assert app.open_avatar(str(path))
        settle(app)
        click(app, "pad_node")
        assert run_until(app, lambda: "pad" in app.info.rects, timeout=20)
        x0, y0, x1, y1 = app.info.rects["pad"]
        io = imgui.get_io()
        io.add_mouse_pos_event((x0 + x1) / 2, (y0 + y1) / 2)
        app.step()
        io.add_mouse_button_event(0, True)
        app.step()
        for t in np.linspace(0.5, -0.2, 6):  # past the corner: clamped to it
            io.add_mouse_pos_event(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t)
            app.step()
        io.add_mouse_button_event(0, False)
        app.step()
        settle(app)
        np.testing.assert_allclose(app.shown_code(), ex.named["smile"], atol=1e-4)
    finally:
        app.close()
