"""Errors: the last few problems reported (`state.report`: a bad file, a refused edit), above the panels, with
a button that dismisses them; above them the status lines of what opening a file did (`state.tell`)."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState

ERROR_RGBA = (1.0, 0.45, 0.4, 1.0)
NOTICE_RGBA = (0.6, 0.85, 1.0, 1.0)


class ErrorsPanel:
    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if state.notices:  # what opening a file did (`state.tell`): status lines, not errors
            imgui.push_text_wrap_pos(0)
            for msg in state.notices:
                imgui.text_colored(imgui.ImVec4(*NOTICE_RGBA), msg)
            imgui.pop_text_wrap_pos()
            if imgui.small_button("OK##notices"):
                state.notices = []
            imgui.separator()
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
