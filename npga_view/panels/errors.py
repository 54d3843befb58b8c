"""Errors: the last few problems reported (`state.report`: a bad file, a refused edit), above the panels, with
a button that dismisses them."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState

ERROR_RGBA = (1.0, 0.45, 0.4, 1.0)


class ErrorsPanel:
    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not state.errors:
            return
        for msg in state.errors:
            imgui.text_colored(imgui.ImVec4(*ERROR_RGBA), "")
            imgui.same_line()
            imgui.push_text_wrap_pos(0)
            imgui.text_colored(imgui.ImVec4(*ERROR_RGBA), msg)
            imgui.pop_text_wrap_pos()
        if imgui.button("Dismiss"):
            state.errors = []
        imgui.separator()
