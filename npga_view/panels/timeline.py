"""Timeline: play, pause, loop, speed, scrub, step, real-time or every frame, smoothing with jitter readout,
the tracked head pose on or off, and baked playback (bake with progress and memory budget, live or baked); the
Live Link stream (npga_view/panels/live_link.py)."""

from __future__ import annotations

from typing import cast

from imgui_bundle import imgui

from npga_core.errors import shown
from npga_core.posing.headpose import has_head_pose, pose_description
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.panels.live_link import LiveLinkPanel
from npga_view.panels.smoothing import smoothing_widget
from npga_view.state import ViewerState


def _readout(state: ViewerState, info: AppInfo) -> tuple[int, list[str]]:
    """The frame the slider is at and the lines under it. While playing: the frame whose image is on screen,
    and the figures as they were when it reached the screen, so that imgui's output changes with the images and
    not with every tick of the clock (a frame whose output and image are those on screen is not drawn again; a
    redraw costs ~15-20 ms on llvmpipe). Otherwise the clock's frame and time."""
    seq, tl = info.sequence, state.timeline
    assert seq is not None
    frame, t = (info.presented_frame, info.presented_frame / seq.fps) if tl.playing else (info.frame, tl.time_s)
    return frame, [f"frame {frame + 1}/{len(seq)}   {t:6.2f} s / {seq.duration:.2f} s   @ {seq.fps:g} fps",
                   f"achieved {info.achieved_fps:5.1f} frames/s, skipped {info.skipped}"]


def _draw(state: ViewerState, info: AppInfo, readout: tuple[int, list[str]]) -> bool:
    """The panel's widgets; whether the frame slider or readout is within the visible part of the side panel."""
    seq = info.sequence
    if seq is None:
        imgui.text_disabled("No sequence loaded.")
        return False
    tl = state.timeline
    n = len(seq)
    if imgui.button("Pause" if tl.playing else "Play"):
        state.actions.append(A.TogglePlay())
    remember(info, "play")
    imgui.same_line()
    if imgui.button("<"):
        state.actions.append(A.StepFrames(-1))
    imgui.same_line()
    if imgui.button(">"):
        state.actions.append(A.StepFrames(1))
    imgui.same_line()
    _, tl.loop = imgui.checkbox("Loop", tl.loop)
    imgui.same_line()
    _, tl.every_frame = imgui.checkbox("Every frame", tl.every_frame)
    frame, lines = readout
    changed, f = imgui.slider_int("Frame", frame, 0, n - 1)
    visible = imgui.is_item_visible()
    remember(info, "scrub")
    if changed:
        tl.time_s = (f + 0.5) / seq.fps
        state.follow_sequence = True
    imgui.text(lines[0])
    _, tl.speed = imgui.slider_float("Speed", tl.speed, 0.1, 4.0, "%.2fx")
    imgui.text(lines[1])
    visible = visible or imgui.is_item_visible()
    smoothing_widget(tl)
    imgui.text(f"jitter: raw {info.jitter_raw:.4f}, smoothed {info.jitter_smoothed:.4f}")
    if has_head_pose(seq):
        _, tl.head_pose = imgui.checkbox("Head pose", tl.head_pose)
        remember(info, "head_pose")
        if imgui.is_item_hovered():
            imgui.set_tooltip("Move the head as tracked (the sequence's canonical -> world pose, as its tracker\n"
                              "defines it). Through a rig camera: where the camera saw it. Orbit camera:\n"
                              "relative to frame 1.")
        imgui.same_line()
        rig = state.rig_index >= 0 and bool(state.rig_path)
        imgui.text_disabled("as tracked" if rig else "relative to frame 1")
        imgui.push_text_wrap_pos(0.0)
        imgui.text_disabled(pose_description(seq))  # what is applied, e.g. GaussianAvatars' rotation about 0
        imgui.pop_text_wrap_pos()
        remember(info, "pose_source")
    else:
        imgui.text_disabled("no head pose in this sequence")
    _bake(state, info)
    return visible


def _bake(state: ViewerState, info: AppInfo) -> None:
    """Live (exact poses as fast as they come) or baked (precomputed, plays at the display rate)."""
    tl = state.timeline
    imgui.separator()
    imgui.text("Playback:")
    imgui.same_line()
    if imgui.radio_button("Live", not tl.baked):
        tl.baked = False
    remember(info, "live")
    imgui.same_line()
    if imgui.radio_button("Baked", tl.baked):
        tl.baked = True
    remember(info, "baked")
    imgui.same_line()
    if imgui.button("Bake"):
        state.actions.append(A.Bake())
    remember(info, "bake")
    if imgui.is_item_hovered():
        imgui.set_tooltip("Precompute the dynamics of every frame (of the smoothed codes), then play them at the "
                          "display rate. Reused from the cache file while the avatar and sequence are unchanged.")
    st, what = info.bake, info.bake_state
    if st is not None and what != "none":
        imgui.same_line()
        if imgui.button("Cancel##bake" if what == "baking" else "Drop##bake"):
            state.actions.append(A.CancelBake())
        remember(info, "cancel_bake")
    imgui.set_next_item_width(160)
    _, tl.bake_budget_mb = imgui.slider_float("Budget", tl.bake_budget_mb, 64.0, 8192.0, "%.0f MB",
                                              imgui.SliderFlags_.logarithmic)
    imgui.same_line()
    _, tl.bake_cache = imgui.checkbox("Cache file", tl.bake_cache)
    if st is None or what == "none":
        imgui.text_disabled("Not baked: playback is live." if tl.baked else "Not baked.")
        return
    if what == "error":
        imgui.text_colored(imgui.ImVec4(1.0, 0.4, 0.4, 1.0), f"bake failed: {shown(cast(str, st.error))}")
        return
    label = f"{st.done}/{st.stored} frames"
    imgui.progress_bar(st.fraction, imgui.ImVec2(-1, 0), label)
    remember(info, "bake_progress")
    every = f"1 in {st.stride} stored, the rest interpolated" if st.stride > 1 else "all stored"
    source = "read from the cache file" if st.from_cache else f"{st.seconds:.1f} s"
    imgui.text_wrapped(f"{st.frames} frames ({every}), {st.megabytes:.0f} MB, {source}")
    if what == "stale":
        imgui.text_colored(imgui.ImVec4(1.0, 0.8, 0.3, 1.0), "Bake is of other codes (sequence or smoothing "
                           "changed): playback is live until you bake again.")
    elif what == "baking" and tl.baked:
        imgui.text_disabled("Frames not baked yet are posed exactly as they come.")
    if st.error:
        imgui.text_colored(imgui.ImVec4(1.0, 0.8, 0.3, 1.0), shown(st.error))


class TimelinePanel:
    """The Timeline panel (what it shows and sets lives in `state.timeline` and `info`), with the Live Link
    stream's controls (`LiveLinkPanel`)."""

    def __init__(self) -> None:
        self.live = LiveLinkPanel()
        self._key: tuple[int, int] | None = None  # (sequence, frame on screen) the readout is of, while playing
        self._readout: tuple[int, list[str]] = (0, [])
        self._shown = False  # the slider or readout was in view in the last frame drawn

    @staticmethod
    def _playing_key(state: ViewerState, info: AppInfo) -> tuple[int, int] | None:
        """While a sequence plays: (sequence, frame on screen), what the readout is of; else None."""
        playing = info.sequence is not None and state.timeline.playing
        return (id(info.sequence), info.presented_frame) if playing else None

    def stale(self, state: ViewerState, info: AppInfo) -> bool:
        """While playing: whether the readout drawn this frame is of another frame than the one `info` now says is
        on screen (an image finished after the panels were drawn; the next frame's imgui output differs)."""
        key = self._playing_key(state, info)
        return self._shown and key is not None and key != self._key

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        self._shown = False
        if not imgui.collapsing_header("Timeline", imgui.TreeNodeFlags_.default_open):
            return
        if info.sequence is not None:
            key = self._playing_key(state, info)
            if key is None or key != self._key:
                self._readout = _readout(state, info)
            self._key = key
        self._shown = _draw(state, info, self._readout)
        self.live.draw(state, info)
