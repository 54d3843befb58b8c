"""The Live Link part of the Timeline panel: listen for a Live Link Face stream (the iPhone app, `npga-view
webcam`), its status and counters, neutral, head pose on/off and smoothing (the Timeline's), per-channel gains,
and recording the stream to a take that reopens as a sequence. Actions go to `LiveLinkController`."""

from __future__ import annotations

import time
from collections.abc import Callable

from imgui_bundle import imgui

from npga_core.files.blendshape_names import ARKIT_52
from npga_core.posing.livelink import DEFAULT_PORT
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.panels.smoothing import smoothing_widget
from npga_view.panels.stats import Refreshed
from npga_view.state import ViewerState


class LiveLinkPanel:
    """Owns the typed address, the take path and the gains shown. The stream's counters are shown as they were
    at most `stats.REFRESH_S` ago (they change with every packet, and a frame whose imgui output and view image are
    those on screen is not drawn again)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._counters: Refreshed[str] = Refreshed(clock)  # said at once: recording or not
        self.address = str(DEFAULT_PORT)
        self.take_path = "live_take.csv"
        self.gains = {n: 1.0 for n in ARKIT_52}
        self.recorded: str | None = None  # the last take written, offered to reopen

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        opened = imgui.tree_node_ex("Live Link", imgui.TreeNodeFlags_.default_open)
        remember(info, "live_node")
        if not opened:
            return
        imgui.set_next_item_width(150)
        _, self.address = imgui.input_text("##live_address", self.address)
        remember(info, "live_address")
        if imgui.is_item_hovered():
            imgui.set_tooltip("[HOST:]PORT to listen on (default host 127.0.0.1; 0.0.0.0 for a phone on the LAN)")
        imgui.same_line()
        if imgui.button("Stop listening" if info.live_listening else "Listen"):
            state.actions.append(A.LiveLinkStop() if info.live_listening else A.LiveLinkStart(self.address.strip()))
        remember(info, "live_start")
        imgui.text_disabled(info.live_link)
        if info.live_listening:
            imgui.text(self._counters.get(lambda: info.live_counters, info.live_recording))
            if info.live_unmatched:
                imgui.text_disabled(info.live_unmatched)
            if imgui.button("Neutral"):
                state.actions.append(A.LiveLinkNeutral())
            remember(info, "live_neutral")
            if imgui.is_item_hovered():
                imgui.set_tooltip("Take the current weights as the rest pose")
            imgui.same_line()
            self._record(state, info)
            _, state.timeline.head_pose = imgui.checkbox("Head pose##live", state.timeline.head_pose)
            if imgui.is_item_hovered():
                imgui.set_tooltip("Move the head by the stream's head yaw, pitch and roll (relative to the neutral)")
            smoothing_widget(state.timeline, "##live", width=150)
            self._gains(state)
        if self.recorded and not info.live_recording:
            if imgui.button(f"Open {self.recorded}"):
                state.actions.append(A.OpenSequence(self.recorded))
            remember(info, "live_open_take")
        imgui.tree_pop()

    def _record(self, state: ViewerState, info: AppInfo) -> None:
        if info.live_recording:
            if imgui.button("Stop recording"):
                state.actions.append(A.LiveLinkRecord(self.take_path.strip()))
                self.recorded = self.take_path.strip()
        elif imgui.button("Record"):
            state.actions.append(A.LiveLinkRecord(None))
        remember(info, "live_record")
        imgui.same_line()
        imgui.set_next_item_width(160)
        _, self.take_path = imgui.input_text("##live_take", self.take_path)
        remember(info, "live_take_path")

    def _gains(self, state: ViewerState) -> None:
        if not imgui.tree_node("Gains"):
            return
        if imgui.button("All 1"):
            for n in ARKIT_52:
                if self.gains[n] != 1.0:
                    self.gains[n] = 1.0
                    state.actions.append(A.LiveLinkGain(n, 1.0))
        for n in ARKIT_52:
            imgui.set_next_item_width(150)
            changed, g = imgui.slider_float(f"{n}##gain", self.gains[n], 0.0, 3.0, "%.2f")
            if changed:
                self.gains[n] = g
                state.actions.append(A.LiveLinkGain(n, float(g)))
        imgui.tree_pop()
