"""Stats: Gaussian counts, frame rate, per-stage times."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

from imgui_bundle import imgui

from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState

STAGES = (("F", "dynamics F"), ("G", "dynamics G"), ("cnn", "CNN"), ("sort", "sort"), ("upload", "upload"),
          ("preprocess", "project"), ("draw", "draw"))
#: the figures (rates, times, progress) are refreshed this often; what the image is, at once. A frame whose imgui
#: output and view image are those on screen is not drawn again, and the figures changed every frame: with the
#: overlay on (its default) a still view being refined paid a buffer swap every UI frame (7-18 ms on llvmpipe).
REFRESH_S = 0.25
#: ... and this often while the window has nothing to do (its idle loop's own rate changes them): a still window
#: with the overlay on was drawn 3.5 times a second for them
QUIET_REFRESH_S = 2.0
AMBER = (1.0, 0.8, 0.3, 1.0)

Line = tuple[tuple[float, float, float, float] | None, str]  # (colour or None, text)
T = TypeVar("T")


class Refreshed(Generic[T]):
    """A shown value made again every `period` (REFRESH_S), and at once when what it says changes (`what`)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self._value: T | None = None
        self._what: Hashable = object()  # (equal to nothing: the first call makes the value)
        self._t = -math.inf  # when it was made

    def get(self, make: Callable[[], T], what: Hashable = None, period: float = REFRESH_S) -> T:
        now = self._clock()
        if self._value is None or what != self._what or now - self._t >= period:
            self._value, self._what, self._t = make(), what, now
        return self._value


class StatsOverlay:
    """An overlay in the top-right corner of the splat view: counts, rates, what the image is, stage times."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._lines: Refreshed[list[Line]] = Refreshed(clock)  # said at once: what the image is

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        shown = self._lines.get(lambda: lines(info), _shown_state(info), QUIET_REFRESH_S if info.quiet else REFRESH_S)
        _begin()
        for colour, text in shown:
            if colour is None:
                imgui.text(text)
            else:
                imgui.text_colored(imgui.ImVec4(*colour), text)
        imgui.end()


def _begin() -> None:
    vp = imgui.get_main_viewport()
    imgui.set_next_window_pos(imgui.ImVec2(vp.pos.x + vp.size.x - 10, vp.pos.y + 10), imgui.Cond_.always,
                              imgui.ImVec2(1.0, 0.0))
    imgui.set_next_window_bg_alpha(0.55)
    flags = (imgui.WindowFlags_.no_decoration | imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_move
             | imgui.WindowFlags_.no_focus_on_appearing | imgui.WindowFlags_.no_nav)
    imgui.begin("Stats", None, flags)


def _shown_state(info: AppInfo) -> tuple:
    """What the image is (the overlay says it at once when it changes; the figures follow every REFRESH_S)."""
    a = info.avatar
    return (id(a), len(a) if a is not None else 0, info.image_status, info.shown, info.canonical, info.preview,
            info.baked, bool(info.merged_splats), info.renderer_path, info.live_counters != "",
            info.compare is not None)


def lines(info: AppInfo) -> list[Line]:
    """The overlay's lines for the figures in `info`."""
    a = info.avatar
    total = len(a) if a is not None else 0
    out: list[Line] = [(None, f"Gaussians: {total:,} total, {info.gaussians_drawn:,} in front of the camera"),
                       (None, f"UI: {info.fps:5.1f} fps" + ("   posing..." if info.posing else ""))]
    out += [(None, line) for line in info.frame_profile]
    out.append((None, f"renderer: {info.renderer_path}"))
    extra = ([info.live_counters] if info.live_counters else []) + list(info.compare.overlay if info.compare else ())
    out += [(None, line) for line in extra]  # the Live Link counters; the Compare panel's view and its scores
    if info.canonical:
        out.append((AMBER, "canonical cloud (the first pose is on its way)"))
    elif info.preview:
        out.append((AMBER, "preview pose (refining to the exact pose)"))
    elif info.baked:
        out.append((None, "baked frame" + (" (interpolated)" if info.interpolated else "")))
    status = info.image_status
    line = f"image: {status}, scale {info.draw_scale:.2f}, {info.image_ms:.0f} ms"
    if status == "refining":
        line += f" ({info.draw_progress:.0%} drawn)"
    if info.merged_splats:
        line += f", {info.merged_splats:,} merged Gaussians"
    if info.shown in ("refined", "latent"):  # what replaces the splats of the settled view
        line += ", CNN refined" if info.shown == "refined" else ", latent view"
    elif info.shown == "splats (refining)" and status == "exact":
        line += ", CNN refining"
    out.append((None if status == "exact" else AMBER, line))
    es = info.engine_status
    if es.get("device"):
        out.append((None, f"dynamics on {es['device']} ({es.get('kernel', '?')}, {es.get('precision', '?')}), "
                          f"first layer {es.get('first_layer', '?')}"))
    if a is not None and a.cnn is not None and info.cnn_device:
        out.append((None, f"CNN on {info.cnn_device}"))
    out += [(None, f"{label:>12}: {info.timings[key]:8.1f} ms") for key, label in STAGES if key in info.timings]
    return out
