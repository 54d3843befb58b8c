"""Driving the real window (Xvfb) from tests: a restartable display, stepping until a condition or a settled
image, and clicks on the widgets the panels remember (imgui input events, like a user's mouse)."""

from __future__ import annotations

import os
import time

import numpy as np

from tests.support.xvfb import start_xvfb


class Display:
    """A private Xvfb that is restarted if it has gone away between tests."""

    def __init__(self):
        self.proc, self.name = start_xvfb()

    def ensure(self) -> str:
        if self.proc.poll() is not None:
            self.proc, self.name = start_xvfb()
        os.environ["DISPLAY"] = self.name
        return self.name


def run_until(app, cond, timeout=60.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        app.step()
        if cond():
            return True
    return False


def settle(app, frames=3):
    """Step until no pose is pending and the splats were redrawn, then a few more frames."""
    assert run_until(app, lambda: app.engine is None or (app.engine.pending is None and app.draws.settled))
    for _ in range(frames):
        app.step()


def click(app, name, frames=2):
    """Press and release the left button at the centre of a remembered widget."""
    from imgui_bundle import imgui

    io = imgui.get_io()
    for _ in range(5):  # follow the widget if the layout moved it in the frame just drawn
        x0, y0, x1, y1 = app.info.rects[name]
        io.add_mouse_pos_event((x0 + x1) / 2, (y0 + y1) / 2)
        app.step()
        if app.info.rects[name] == (x0, y0, x1, y1):
            break
    io.add_mouse_button_event(0, True)
    app.step()
    io.add_mouse_button_event(0, False)
    for _ in range(frames):
        app.step()
def until_changed(app, before: np.ndarray, timeout: float = 180.0, min_fraction: float = 0.002) -> np.ndarray:
    """Step the window until its viewport differs from `before` (a generous bound, not a rate), then until two
    reads agree (the image settled). The statistics overlay must be off (before `before` is read): its figures
    change every frame over the view, so two reads agreed only by chance (a GHA window test waited ~10 s per image).
    """
    assert not app.state.show_stats, "switch the statistics overlay off before reading the view"
    end = time.monotonic() + timeout
    now = before
    while time.monotonic() < end:
        app.step()
        now = app.read_window(viewport_only=True)
        if (np.abs(now.astype(int) - before.astype(int)).max(axis=2) > 8).mean() > min_fraction:
            break
    else:
        raise AssertionError("the viewport did not change")
    while time.monotonic() < end:
        for _ in range(3):
            app.step()
        again = app.read_window(viewport_only=True)
        if np.array_equal(again, now):
            return again
        now = again
    return now
def settled(app, timeout: float = 180.0) -> np.ndarray:
    """Step until the exact pose's full-resolution image is on screen (a generous bound), then read the view."""
    from npga_view.benchmarks.bench_window import _exact

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        app.step()
        if _exact(app):
            break
    else:
        raise AssertionError("the view did not settle")
    for _ in range(3):
        app.step()
    return app.read_window(viewport_only=True)
