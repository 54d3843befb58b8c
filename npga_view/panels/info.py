"""What the panels share: the display snapshot `AppInfo` (defined in npga_view/display.py, where the controllers
that fill it import it from) and `remember`, which records a widget's rectangle for tests."""

from __future__ import annotations

from npga_view.display import AppInfo as AppInfo


def remember(info: AppInfo, name: str) -> None:
    """Record the last widget's screen rectangle (tests drive widgets by these)."""
    from imgui_bundle import imgui

    a, b = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    info.rects[name] = (a.x, a.y, b.x, b.y)
