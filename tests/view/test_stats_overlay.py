"""The statistics overlay: its figures are refreshed every REFRESH_S (frames whose imgui output and view image are
those on screen are not drawn again), what the image is at once."""

from __future__ import annotations

from types import SimpleNamespace

from npga_view.panels import stats
from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState


def _driven(monkeypatch, info: AppInfo):
    """The overlay drawn through a stand-in imgui with a settable clock: (frame() -> the lines drawn, clock)."""
    shown: list[str] = []
    fake = SimpleNamespace(text=shown.append, text_colored=lambda colour, text: shown.append(text),
                           end=lambda: None, ImVec4=lambda *c: c)
    monkeypatch.setattr(stats, "imgui", fake)
    monkeypatch.setattr(stats, "_begin", lambda: None)
    clock = [100.0]
    overlay, state = stats.StatsOverlay(clock=lambda: clock[0]), ViewerState()

    def frame() -> list[str]:
        shown.clear()
        overlay.draw(state, info)
        return list(shown)

    return frame, clock


def test_figures_every_refresh_what_the_image_is_at_once(monkeypatch):
    info = AppInfo(fps=30.0, image_status="refining", draw_progress=0.1)
    frame, clock = _driven(monkeypatch, info)
    first = frame()
    assert "UI:  30.0 fps" in first and any("(10% drawn)" in t for t in first)
    info.fps, info.draw_progress = 31.0, 0.5  # the figures move every frame ...
    clock[0] += 0.05
    assert frame() == first  # ... the overlay (and so imgui's output) stays until REFRESH_S has passed
    clock[0] += stats.REFRESH_S
    later = frame()
    assert "UI:  31.0 fps" in later and any("(50% drawn)" in t for t in later)
    info.image_status = "exact"  # what the image is: at once
    clock[0] += 0.01
    assert any(t.startswith("image: exact") for t in frame())


def test_figures_of_a_quiet_window_every_quiet_refresh(monkeypatch):
    """While the window has nothing to do (its loop waits for input), the figures (its idle loop's own rate) are
    refreshed every QUIET_REFRESH_S, not every REFRESH_S: a still window is not drawn again four times a second."""
    info = AppInfo(fps=30.0, image_status="exact", quiet=True)
    frame, clock = _driven(monkeypatch, info)
    first = frame()
    info.fps = 27.0
    clock[0] += stats.REFRESH_S + 0.01
    assert frame() == first  # quiet: the figures wait
    clock[0] += stats.QUIET_REFRESH_S
    assert "UI:  27.0 fps" in frame()
    info.fps, info.quiet = 33.0, False  # busy again: every REFRESH_S
    clock[0] += stats.REFRESH_S + 0.01
    assert "UI:  33.0 fps" in frame()
