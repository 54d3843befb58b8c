"""The smoothing widget, drawn by the Timeline panel and by its Live Link part: the method (one of
`npga_core.posing.smoothing.METHODS`) and its settings, written into the timeline's settings, by which sequences
and the Live Link stream are both smoothed."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_core.posing.smoothing import METHODS
from npga_view.state import Timeline


def smoothing_widget(tl: Timeline, suffix: str = "", width: float | None = None) -> None:
    """The method combo and the method's sliders; `suffix` (e.g. "##live") keeps two copies of the widget in one
    window apart, `width` sets the combo's width."""
    idx = METHODS.index(tl.smoothing) if tl.smoothing in METHODS else 0
    if width is not None:
        imgui.set_next_item_width(width)
    changed, idx = imgui.combo(f"Smoothing{suffix}", idx, list(METHODS))
    if changed:
        tl.smoothing = METHODS[idx]
    if tl.smoothing == "exponential":
        _, tl.smooth_alpha = imgui.slider_float(f"Alpha{suffix}", tl.smooth_alpha, 0.05, 1.0)
    elif tl.smoothing == "one_euro":
        _, tl.euro_min_cutoff = imgui.slider_float(f"Min cutoff (Hz){suffix}", tl.euro_min_cutoff, 0.05, 10.0)
        _, tl.euro_beta = imgui.slider_float(f"Beta{suffix}", tl.euro_beta, 0.0, 5.0)
