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


def _xtest():
    """libX11 and libXtst (the X server's input as a device gives it) through ctypes, or None where absent."""
    import ctypes
    import ctypes.util

    try:
        x11 = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
        xt = ctypes.CDLL(ctypes.util.find_library("Xtst") or "libXtst.so.6")
    except OSError:
        return None
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XFlush.argtypes = x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    xt.XTestFakeMotionEvent.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_ulong]
    xt.XTestFakeButtonEvent.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_ulong]
    return x11, xt


def test_input_that_arrives_during_a_frame_is_seen_before_the_next(app):
    """`Window.input_pending` (asked between the budgets of a still view's refinement): a button pressed in the X
    server while a frame is being made is seen at once, and counts until the next frame takes it; the pointer
    moving without a button is not input that changes the view."""
    import time

    libs = _xtest()
    if libs is None:
        pytest.skip("libXtst is not installed (the X server's test extension client)")
    x11, xt = libs
    dpy = x11.XOpenDisplay(None)
    assert dpy, "no X display"
    x, _, w, h = app.window.viewport()
    try:
        xt.XTestFakeMotionEvent(dpy, -1, x + w // 2, h // 2, 0)
        x11.XFlush(dpy)
        app.step()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.5:  # (the motion reaches glfw meanwhile)
            assert not app.window.input_pending(), "pointer motion without a button is not view input"
        xt.XTestFakeButtonEvent(dpy, 1, 1, 0)
        x11.XFlush(dpy)
        t0 = time.perf_counter()
        while not app.window.input_pending():
            assert time.perf_counter() - t0 < 30, "the press was not seen"
        assert app.window.input_pending()  # until a frame takes it
        app.step()
        assert not app.window.input_pending()
    finally:
        xt.XTestFakeButtonEvent(dpy, 1, 0, 0)
        x11.XFlush(dpy)
        x11.XCloseDisplay(dpy)
        app.step()
