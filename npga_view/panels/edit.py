"""Edit: selection tools, operations on the selection, floater clean-up, history, save and export.

Reads ``info.edit`` (an `npga_core.editing.edits.EditSession`, or None when no avatar is open) and ``info.avatar``.
Writes only `state.actions`: the selection and edit actions of npga_view/actions.py (`SelectTool` when the
tool, mode or brush radius changes; `SelectSphere`, `SelectBox`, `SelectRange`, grow, shrink, invert, all,
clear; `DeleteSelection`, `HideSelection`, `ShowAllHidden`, opacity, tint, features, floaters; `Undo`,
`Redo`; `SaveEdits` (asking first before overwriting the source or an existing file), `ExportPly`,
`RecoverEdits`, `DiscardAutosave`). The screen-space selections (rectangle, lasso, brush) come from Ctrl-drags
in the splat view (npga_view/controllers/editing.py). npga_view/controllers/edit_actions.py carries them out.
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np
from imgui_bundle import imgui

from npga_core.editing.edits import EditSession, find_autosave, same_file
from npga_core.editing.selection import COMBINE_MODES, attribute_names, attribute_values
from npga_core.errors import shown
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

TOOLS: tuple[A.SelectToolName, ...] = ("rect", "lasso", "brush", "sphere", "box", "range")
TOOL_LABELS = ("Rectangle", "Lasso", "Brush", "Sphere", "Box", "Range")
WARN = imgui.ImVec4(1.0, 0.75, 0.3, 1.0)


def _vec3(v) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))



class EditPanel:
    """The Edit panel; owns its widgets: tool, mode, parameters of each tool and operation, file names."""

    def __init__(self) -> None:
        self.tool = 0
        self.mode = 0
        self.brush_radius = 20.0
        self.centre = [0.0, 0.0, 0.0]
        self.radius = 0.05
        self.lo = [-0.05, -0.05, -0.05]
        self.hi = [0.05, 0.05, 0.05]
        self.attribute = 0
        self.range: tuple[str, float, float] | None = None
        self.hist: tuple[tuple[int, int, str], np.ndarray, float, float] | None = None
        self.steps = 1
        self.opacity = 0.5
        self.tint = [1.0, 0.8, 0.8]
        self.tint_mode = 0
        self.tint_amount = 1.0
        self.channel = 0
        self.feature_value = 0.0
        self.feature_factor = 1.0
        self.k = 8
        self.distance_factor = 3.0
        self.min_opacity = 0.02
        self.within = False
        self.save_as = 'edited.npga'
        self.export = 'posed.ply'
        self.confirm: tuple[str | None, bool, str] | None = None
        self.autosave: tuple[str | None, Path | None] | None = None

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not imgui.collapsing_header("Edit"):
            return
        s: EditSession | None = getattr(info, "edit", None)
        if s is None:
            imgui.text_disabled("Open an avatar to edit it.")
            return
        self._status(state, s)
        self._tools(state, info, s)
        self._operations(state, info, s)
        self._floaters(state, s)
        self._history(state, info, s)
        self._files(state, s)
        self._confirm(state)

    @staticmethod
    def _act(state: ViewerState, action: A.Action) -> None:
        state.actions.append(action)

    def _mode(self) -> A.CombineMode:
        return cast(A.CombineMode, COMBINE_MODES[self.mode])

    def _status(self, state: ViewerState, s: EditSession) -> None:
        n, sel, hid = len(s), int(s.selection.sum()), int(s.hidden.sum())
        imgui.text(f"{n:,} Gaussians, {sel:,} selected, {hid:,} hidden")
        if s.dirty:
            imgui.same_line()
            imgui.text_colored(WARN, "(unsaved)")
        key = s.source
        fresh = not s.can_undo and not s.dirty  # offer recovery only before any edit
        if self.autosave is None or self.autosave[0] != key:
            self.autosave = (key, find_autosave(key) if fresh and key is not None else None)
        if self.autosave[1] is not None and fresh:
            imgui.text_colored(WARN, "Unsaved edits of this file were autosaved.")
            if imgui.button("Recover"):
                self._act(state, A.RecoverEdits(cast(str, key)))  # an autosave is looked for only with a key
                self.autosave = None
            imgui.same_line()
            if imgui.button("Discard"):
                self._act(state, A.DiscardAutosave())
                self.autosave = (key, None)

    def _tools(self, state: ViewerState, info: AppInfo, s: EditSession) -> None:
        imgui.separator_text("Select")
        before = (self.tool, self.mode, self.brush_radius)
        for i, label in enumerate(TOOL_LABELS):
            if i % 3:
                imgui.same_line()
            if imgui.radio_button(label, self.tool == i):
                self.tool = i
            remember(info, f"edit_tool_{TOOLS[i]}")
        _, self.mode = imgui.combo("Mode##select", self.mode, list(COMBINE_MODES))
        tool = TOOLS[self.tool]
        if tool in ("rect", "lasso", "brush"):
            imgui.text_disabled("Ctrl + left drag in the view selects; plain drags orbit.")
            if tool == "brush":
                _, self.brush_radius = imgui.slider_float("Radius (px)", self.brush_radius, 2.0, 200.0, "%.0f")
        elif tool == "sphere":
            _, self.centre = imgui.drag_float3("Centre", self.centre, 0.001)
            _, self.radius = imgui.drag_float("Radius", self.radius, 0.001, 0.0, 10.0, "%.4f")
            self._centre_buttons(s)
            if imgui.button("Select in sphere"):
                self._act(state, A.SelectSphere(_vec3(self.centre), float(self.radius), self._mode()))
        elif tool == "box":
            _, self.lo = imgui.drag_float3("Min", self.lo, 0.001)
            _, self.hi = imgui.drag_float3("Max", self.hi, 0.001)
            if imgui.button("Fit to selection") and s.selection.any():
                m = np.asarray(s.avatar.cloud.means)[s.selection]
                self.lo, self.hi = [float(v) for v in m.min(0)], [float(v) for v in m.max(0)]
            imgui.same_line()
            if imgui.button("Select in box"):
                self._act(state, A.SelectBox(_vec3(self.lo), _vec3(self.hi), self._mode()))
        else:
            self._range_tool(state, s)
        if (self.tool, self.mode, self.brush_radius) != before:
            self._act(state, A.SelectTool(tool, self._mode(), float(self.brush_radius)))
        imgui.set_next_item_width(80)
        _, self.steps = imgui.input_int("##steps", self.steps)
        self.steps = max(1, min(self.steps, 50))
        for label, action in (("Grow", A.SelectGrow(self.steps)), ("Shrink", A.SelectShrink(self.steps)),
                              ("Invert", A.SelectInvert()), ("All", A.SelectAll()), ("Clear", A.SelectClear())):
            imgui.same_line()
            if imgui.button(label):
                self._act(state, action)

    def _centre_buttons(self, s: EditSession) -> None:
        means = np.asarray(s.avatar.cloud.means)
        if imgui.button("On selection") and s.selection.any():
            self.centre = [float(v) for v in means[s.selection].mean(0)]
        imgui.same_line()
        if imgui.button("On avatar") and len(means):
            self.centre = [float(v) for v in np.median(means, axis=0)]

    def _range_tool(self, state: ViewerState, s: EditSession) -> None:
        names = attribute_names(s.avatar.cloud)
        self.attribute = min(self.attribute, len(names) - 1)
        changed, self.attribute = imgui.combo("Attribute", self.attribute, [shown(n) for n in names])
        name = names[self.attribute]
        key = (id(s.avatar.cloud), s.version, name)
        if self.hist is None or self.hist[0] != key:
            values = attribute_values(s.avatar.cloud, name)
            finite = values[np.isfinite(values)]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
            counts, _ = np.histogram(finite, bins=48, range=(lo, hi if hi > lo else lo + 1.0))
            self.hist = (key, counts.astype(np.float32), lo, hi)
            if changed or self.range is None or self.range[0] != name:
                self.range = (name, lo, hi)
        _, counts, lo, hi = self.hist
        imgui.plot_histogram("##hist", counts, graph_size=imgui.ImVec2(-1, 60))
        imgui.text_disabled(f"{lo:.4g} .. {hi:.4g}")
        assert self.range is not None  # set with the first histogram
        _, a, b = self.range
        speed = max(hi - lo, 1e-6) / 300.0
        _, a, b = imgui.drag_float_range2("Range", a, b, speed, lo, hi, "%.4g")
        self.range = (name, a, b)
        if imgui.button("Select in range"):
            self._act(state, A.SelectRange(name, float(a), float(b), self._mode()))

    def _operations(self, state: ViewerState, info: AppInfo, s: EditSession) -> None:
        imgui.separator_text("Operations")
        has_sel = bool(s.selection.any())
        imgui.begin_disabled(not has_sel)
        if imgui.button("Delete"):
            self._act(state, A.DeleteSelection())
        remember(info, "edit_delete")
        imgui.same_line()
        if imgui.button("Hide"):
            self._act(state, A.HideSelection())
        imgui.end_disabled()
        imgui.same_line()
        imgui.begin_disabled(not s.hidden.any())
        if imgui.button("Show all"):
            self._act(state, A.ShowAllHidden())
        imgui.end_disabled()
        imgui.begin_disabled(not has_sel)
        imgui.set_next_item_width(140)
        _, self.opacity = imgui.slider_float("##opacity", self.opacity, 0.0, 2.0, "x%.2f")
        imgui.same_line()
        if imgui.button("Scale opacity"):
            self._act(state, A.ScaleSelectionOpacity(float(self.opacity)))
        _, self.tint = imgui.color_edit3("Tint colour", self.tint)
        imgui.set_next_item_width(100)
        _, self.tint_mode = imgui.combo("##tintmode", self.tint_mode, ["multiply", "blend"])
        imgui.same_line()
        imgui.set_next_item_width(100)
        _, self.tint_amount = imgui.slider_float("##amount", self.tint_amount, 0.0, 1.0, "%.2f")
        imgui.same_line()
        if imgui.button("Tint"):
            self._act(state, A.TintSelection(_vec3(self.tint), ("multiply", "blend")[self.tint_mode],
                                                 float(self.tint_amount)))
        f_dim = s.avatar.cloud.feature_dim
        if f_dim:
            self.channel = min(self.channel, f_dim - 1)
            imgui.set_next_item_width(140)
            _, self.channel = imgui.slider_int("Feature channel", self.channel, 0, f_dim - 1)
            imgui.set_next_item_width(100)
            _, self.feature_value = imgui.input_float("##fvalue", self.feature_value, 0.0, 0.0, "%.3f")
            imgui.same_line()
            if imgui.button("Set"):
                self._act(state, A.SetSelectionFeature(int(self.channel), float(self.feature_value)))
            imgui.same_line()
            imgui.set_next_item_width(100)
            _, self.feature_factor = imgui.input_float("##ffactor", self.feature_factor, 0.0, 0.0, "x%.3f")
            imgui.same_line()
            if imgui.button("Scale"):
                self._act(state, A.ScaleSelectionFeature(int(self.channel), float(self.feature_factor)))
        imgui.end_disabled()

    def _floater_params(self) -> dict:
        return {"k": int(self.k), "distance_factor": float(self.distance_factor),
                "min_opacity": float(self.min_opacity)}

    def _floaters(self, state: ViewerState, s: EditSession) -> None:
        imgui.separator_text("Floaters")
        _, self.k = imgui.slider_int("Neighbours", self.k, 2, 32)
        _, self.distance_factor = imgui.slider_float("Distance x median", self.distance_factor, 1.0, 20.0, "%.1f")
        _, self.min_opacity = imgui.slider_float("Min opacity", self.min_opacity, 0.0, 0.5, "%.3f")
        _, self.within = imgui.checkbox("Only within the selection", self.within)
        if imgui.button("Preview"):
            self._act(state, A.PreviewFloaters(**self._floater_params()))
        imgui.same_line()
        if imgui.button("Remove floaters"):
            self._act(state, A.RemoveFloaters(**self._floater_params(), within_selection=bool(self.within)))
        if s.preview is not None:
            imgui.same_line()
            if imgui.button("Clear preview"):
                self._act(state, A.ClearFloaterPreview())
            imgui.text(f"{int(s.preview.sum()):,} would be removed (highlighted)")

    def _history(self, state: ViewerState, info: AppInfo, s: EditSession) -> None:
        imgui.separator_text("History")
        imgui.begin_disabled(not s.can_undo)
        if imgui.button("Undo"):
            self._act(state, A.Undo())
        remember(info, "edit_undo")
        imgui.end_disabled()
        imgui.same_line()
        imgui.begin_disabled(not s.can_redo)
        if imgui.button("Redo"):
            self._act(state, A.Redo())
        imgui.end_disabled()
        done, undone = s.history.names()
        if imgui.begin_list_box("##history", imgui.ImVec2(-1, 110)):
            for i, name in enumerate(done):
                imgui.selectable(f"{shown(name)}##done{i}", i == len(done) - 1)
            for name in undone:
                imgui.text_disabled(f"  {shown(name)}")
            imgui.end_list_box()

    def _request_save(self, state: ViewerState, s: EditSession, path: str | None) -> None:
        target = path if path is not None else (s.save_path or s.source)
        if target is None:
            state.report("this avatar has no file yet: use Save as")
            return
        if same_file(target, s.source):
            self.confirm = (path, True, f"{target} is the file the avatar was opened from. Overwrite it?")
        elif path is not None and Path(path).exists() and not same_file(path, s.save_path):
            self.confirm = (path, False, f"{path} exists. Overwrite it?")
        else:
            self._act(state, A.SaveEdits(path, False))
            return
        imgui.open_popup("Overwrite?##edit")

    def _files(self, state: ViewerState, s: EditSession) -> None:
        imgui.separator_text("File")
        if imgui.button("Save"):
            self._request_save(state, s, None)
        imgui.same_line()
        imgui.set_next_item_width(-90)
        _, self.save_as = imgui.input_text("##saveas", self.save_as)
        imgui.same_line()
        if imgui.button("Save as") and self.save_as.strip():
            self._request_save(state, s, self.save_as.strip())
        imgui.set_next_item_width(-90)
        _, self.export = imgui.input_text("##export", self.export)
        imgui.same_line()
        if imgui.button("Export PLY") and self.export.strip():
            self._act(state, A.ExportPly(self.export.strip()))
        imgui.text_disabled("PLY: posed at the current expression, hidden Gaussians left out.")

    def _confirm(self, state: ViewerState) -> None:
        opened, _ = imgui.begin_popup_modal("Overwrite?##edit", None, imgui.WindowFlags_.always_auto_resize)
        if not opened:
            return
        path, is_source, question = self.confirm or (None, False, "")
        imgui.text(question)
        if imgui.button("Overwrite"):
            self._act(state, A.SaveEdits(path, is_source))
            self.confirm = None
            imgui.close_current_popup()
        imgui.same_line()
        if imgui.button("Cancel"):
            self.confirm = None
            imgui.close_current_popup()
        imgui.end_popup()
