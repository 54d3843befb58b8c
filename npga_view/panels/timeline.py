"""Timeline: play, pause, loop, speed, scrub, step, real-time or every frame, smoothing with jitter readout."""

from __future__ import annotations

from imgui_bundle import imgui

from ..state import ViewerState
from .info import AppInfo, remember

SMOOTHING = ("none", "exponential", "one_euro")


def draw(state: ViewerState, info: AppInfo) -> None:
    if not imgui.collapsing_header("Timeline", imgui.TreeNodeFlags_.default_open):
        return
    seq = info.sequence
    if seq is None:
        imgui.text_disabled("No sequence loaded.")
        return
    tl = state.timeline
    n = len(seq)
    if imgui.button("Pause" if tl.playing else "Play"):
        tl.playing = not tl.playing
        state.follow_sequence = True
    remember(info, "play")
    imgui.same_line()
    if imgui.button("<"):
        state.actions.append(("step", -1))
    imgui.same_line()
    if imgui.button(">"):
        state.actions.append(("step", 1))
    imgui.same_line()
    _, tl.loop = imgui.checkbox("Loop", tl.loop)
    imgui.same_line()
    _, tl.every_frame = imgui.checkbox("Every frame", tl.every_frame)
    changed, f = imgui.slider_int("Frame", info.frame, 0, n - 1)
    remember(info, "scrub")
    if changed:
        tl.time_s = (f + 0.5) / seq.fps
        state.follow_sequence = True
    imgui.text(f"frame {info.frame + 1}/{n}   {tl.time_s:6.2f} s / {seq.duration:.2f} s   @ {seq.fps:g} fps")
    _, tl.speed = imgui.slider_float("Speed", tl.speed, 0.1, 4.0, "%.2fx")
    imgui.text(f"achieved {info.achieved_fps:5.1f} frames/s, skipped {info.skipped}")
    idx = SMOOTHING.index(tl.smoothing) if tl.smoothing in SMOOTHING else 0
    changed, idx = imgui.combo("Smoothing", idx, list(SMOOTHING))
    if changed:
        tl.smoothing = SMOOTHING[idx]
    if tl.smoothing == "exponential":
        _, tl.smooth_alpha = imgui.slider_float("Alpha", tl.smooth_alpha, 0.05, 1.0)
    elif tl.smoothing == "one_euro":
        _, tl.euro_min_cutoff = imgui.slider_float("Min cutoff (Hz)", tl.euro_min_cutoff, 0.05, 10.0)
        _, tl.euro_beta = imgui.slider_float("Beta", tl.euro_beta, 0.0, 5.0)
    imgui.text(f"jitter: raw {info.jitter_raw:.4f}, smoothed {info.jitter_smoothed:.4f}")
