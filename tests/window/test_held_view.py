"""The view in the real window (Xvfb) while the mouse button is held: a drag that stops is refined without being
let go, as a person holding the view still expects."""

from __future__ import annotations

import pytest

from tests.support.window import run_until, settle

pytestmark = pytest.mark.gui


def test_a_drag_held_still_is_refined_before_the_button_is_let_go(app, avatar_path):
    """While the drag moves the camera, live images are drawn at a reduced scale; once the camera has not moved for
    the scheduler's settle time, the view is drawn at full resolution although the button is still down (before,
    a held button kept the view at the live scale until it was let go)."""
    from imgui_bundle import imgui

    assert app.open_avatar(avatar_path)
    settle(app)
    app.draws.interactive_ms = 1e-3  # live images at the smallest scale, whatever the machine
    app.draws.interactive_scale = app.draws.min_scale
    io = imgui.get_io()
    x, _, w, h = app.window.viewport()  # framebuffer pixels; the Xvfb window has scale 1
    cx, cy = x + w / 2, h / 2
    io.add_mouse_pos_event(cx, cy)
    app.step()
    io.add_mouse_button_event(0, True)
    app.step()
    key = app.view.camera().world_to_camera.tobytes()
    for k in range(1, 6):
        io.add_mouse_pos_event(cx + 12 * k, cy)
        app.step()
    assert app.view.camera().world_to_camera.tobytes() != key, "the drag should orbit the camera"
    assert app.view.interacting() and not app.draws.settled  # moving: live images
    assert run_until(app, lambda: app.draws.settled, timeout=120)  # held still: refined
    assert imgui.is_mouse_down(0) and app.draws.scale == 1.0 and app.draws.status == "exact"
    io.add_mouse_button_event(0, False)
    app.step()
