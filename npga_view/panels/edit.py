"""Edit: selection tools, operations on the selection, floater clean-up, history, save and export.

Reads ``info.edit`` (an `npga_core.editing.edits.EditSession`, or None when no avatar is open) and ``info.avatar``.
Writes only `state.actions`; `apply(session, name, arg, ...)` below carries out every action except the ones
marked "app" (they need the window or create a new session). Actions and their args:

selection (the app interprets drags in the splat view with the active tool and emits the screen-space ones):
- ``("select_tool", {"tool": "rect"|"lasso"|"brush"|"sphere"|"box"|"range", "mode": "replace"|"add"|"subtract"|
  "intersect", "brush_radius": px})``: app; sent when the tool, mode or brush radius changes (the panel starts
  at rect, replace, 20 px).
- ``("select_rect", {"rect": (x0, y0, x1, y1), "mode": m})``, ``("select_lasso", {"polygon": [(x, y), ...],
  "mode": m})``, ``("select_brush", {"centres": [(x, y), ...], "radius": px, "mode": m})``: pixels of the view
  camera; `apply` needs `camera` and `means` (the posed centres on screen).
- ``("select_sphere", {"centre": (x, y, z), "radius": r, "mode": m})``, ``("select_box", {"lo": (x, y, z),
  "hi": (x, y, z), "mode": m})``, ``("select_range", {"attribute": name, "lo": a, "hi": b, "mode": m})``.
- ``("select_grow", steps)``, ``("select_shrink", steps)``, ``("select_invert", None)``, ``("select_clear", None)``,
  ``("select_all", None)``.

operations:
- ``("edit_delete", None)``, ``("edit_hide", None)``, ``("edit_show_all", None)``,
  ``("edit_scale_opacity", factor)``, ``("edit_tint", {"rgb": (r, g, b), "mode": "multiply"|"blend",
  "amount": a})``, ``("edit_set_feature", {"channel": k, "value": v})``, ``("edit_scale_feature", {"channel": k,
  "factor": f})``.
- ``("edit_preview_floaters", {"k": k, "distance_factor": f, "min_opacity": o})``, ``("edit_clear_preview",
  None)``, ``("edit_remove_floaters", {... the same, "within_selection": bool})``.
- ``("edit_undo", None)``, ``("edit_redo", None)`` (also Ctrl+Z / Ctrl+Shift+Z, bound by the app).

files:
- ``("edit_save", {"path": str | None, "overwrite_source": bool})``: path None is "Save"; the panel asks before
  overwriting the source or an existing file, so `overwrite_source` is True only once the user agreed.
- ``("edit_export_ply", path)``: the posed avatar at the current expression; `apply` needs `code`.
- ``("edit_recover", source)``: app; open the autosaved edits of `source` with `EditSession.recover(source)`.
- ``("edit_discard_autosave", None)``.

The app should call `EditSession.autosave()` every minute or so while `dirty`, and re-pose when
`EditSession.version` changes (only the highlight when `mask_version` changes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from npga_core.editing.edits import (
    DeleteSelected,
    EditSession,
    Hide,
    RemoveFloaters,
    ScaleFeature,
    ScaleOpacity,
    SetFeature,
    ShowAll,
    Tint,
    find_autosave,
    same_file,
)
from npga_core.editing.selection import COMBINE_MODES, attribute_names, attribute_values
from npga_core.errors import shown
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

TOOLS = ("rect", "lasso", "brush", "sphere", "box", "range")
TOOL_LABELS = ("Rectangle", "Lasso", "Brush", "Sphere", "Box", "Range")
WARN = imgui.ImVec4(1.0, 0.75, 0.3, 1.0)

_ui: dict = {
    "tool": 0, "mode": 0, "brush_radius": 20.0,
    "centre": [0.0, 0.0, 0.0], "radius": 0.05, "lo": [-0.05, -0.05, -0.05], "hi": [0.05, 0.05, 0.05],
    "attribute": 0, "range": None, "hist": None,
    "steps": 1, "opacity": 0.5, "tint": [1.0, 0.8, 0.8], "tint_mode": 0, "tint_amount": 1.0,
    "channel": 0, "feature_value": 0.0, "feature_factor": 1.0,
    "k": 8, "distance_factor": 3.0, "min_opacity": 0.02, "within": False,
    "save_as": "edited.npga", "export": "posed.ply", "confirm": None, "autosave": None,
}


def draw(state: ViewerState, info: AppInfo) -> None:
    if not imgui.collapsing_header("Edit"):
        return
    s: EditSession | None = getattr(info, "edit", None)
    if s is None:
        imgui.text_disabled("Open an avatar to edit it.")
        return
    _status(state, s)
    _tools(state, info, s)
    _operations(state, info, s)
    _floaters(state, s)
    _history(state, info, s)
    _files(state, s)
    _confirm(state)


def _act(state: ViewerState, name: str, arg: object = None) -> None:
    state.actions.append((name, arg))


def _mode() -> str:
    return COMBINE_MODES[_ui["mode"]]


def _status(state: ViewerState, s: EditSession) -> None:
    n, sel, hid = len(s), int(s.selection.sum()), int(s.hidden.sum())
    imgui.text(f"{n:,} Gaussians, {sel:,} selected, {hid:,} hidden")
    if s.dirty:
        imgui.same_line()
        imgui.text_colored(WARN, "(unsaved)")
    key = s.source
    fresh = not s.can_undo and not s.dirty  # offer recovery only before any edit
    if _ui["autosave"] is None or _ui["autosave"][0] != key:
        _ui["autosave"] = (key, find_autosave(key) if fresh and key is not None else None)
    if _ui["autosave"][1] is not None and fresh:
        imgui.text_colored(WARN, "Unsaved edits of this file were autosaved.")
        if imgui.button("Recover"):
            _act(state, "edit_recover", key)
            _ui["autosave"] = None
        imgui.same_line()
        if imgui.button("Discard"):
            _act(state, "edit_discard_autosave")
            _ui["autosave"] = (key, None)


def _tools(state: ViewerState, info: AppInfo, s: EditSession) -> None:
    imgui.separator_text("Select")
    before = (_ui["tool"], _ui["mode"], _ui["brush_radius"])
    for i, label in enumerate(TOOL_LABELS):
        if i % 3:
            imgui.same_line()
        if imgui.radio_button(label, _ui["tool"] == i):
            _ui["tool"] = i
        remember(info, f"edit_tool_{TOOLS[i]}")
    _, _ui["mode"] = imgui.combo("Mode##select", _ui["mode"], list(COMBINE_MODES))
    tool = TOOLS[_ui["tool"]]
    if tool in ("rect", "lasso", "brush"):
        imgui.text_disabled("Ctrl + left drag in the view selects; plain drags orbit.")
        if tool == "brush":
            _, _ui["brush_radius"] = imgui.slider_float("Radius (px)", _ui["brush_radius"], 2.0, 200.0, "%.0f")
    elif tool == "sphere":
        _, _ui["centre"] = imgui.drag_float3("Centre", _ui["centre"], 0.001)
        _, _ui["radius"] = imgui.drag_float("Radius", _ui["radius"], 0.001, 0.0, 10.0, "%.4f")
        _centre_buttons(s)
        if imgui.button("Select in sphere"):
            _act(state, "select_sphere", {"centre": tuple(_ui["centre"]), "radius": _ui["radius"], "mode": _mode()})
    elif tool == "box":
        _, _ui["lo"] = imgui.drag_float3("Min", _ui["lo"], 0.001)
        _, _ui["hi"] = imgui.drag_float3("Max", _ui["hi"], 0.001)
        if imgui.button("Fit to selection") and s.selection.any():
            m = np.asarray(s.avatar.cloud.means)[s.selection]
            _ui["lo"], _ui["hi"] = [float(v) for v in m.min(0)], [float(v) for v in m.max(0)]
        imgui.same_line()
        if imgui.button("Select in box"):
            _act(state, "select_box", {"lo": tuple(_ui["lo"]), "hi": tuple(_ui["hi"]), "mode": _mode()})
    else:
        _range_tool(state, s)
    if (_ui["tool"], _ui["mode"], _ui["brush_radius"]) != before:
        _act(state, "select_tool", {"tool": tool, "mode": _mode(), "brush_radius": _ui["brush_radius"]})
    imgui.set_next_item_width(80)
    _, _ui["steps"] = imgui.input_int("##steps", _ui["steps"])
    _ui["steps"] = max(1, min(_ui["steps"], 50))
    for label, name, arg in (("Grow", "select_grow", _ui["steps"]), ("Shrink", "select_shrink", _ui["steps"]),
                             ("Invert", "select_invert", None), ("All", "select_all", None),
                             ("Clear", "select_clear", None)):
        imgui.same_line()
        if imgui.button(label):
            _act(state, name, arg)


def _centre_buttons(s: EditSession) -> None:
    means = np.asarray(s.avatar.cloud.means)
    if imgui.button("On selection") and s.selection.any():
        _ui["centre"] = [float(v) for v in means[s.selection].mean(0)]
    imgui.same_line()
    if imgui.button("On avatar") and len(means):
        _ui["centre"] = [float(v) for v in np.median(means, axis=0)]


def _range_tool(state: ViewerState, s: EditSession) -> None:
    names = attribute_names(s.avatar.cloud)
    _ui["attribute"] = min(_ui["attribute"], len(names) - 1)
    changed, _ui["attribute"] = imgui.combo("Attribute", _ui["attribute"], [shown(n) for n in names])
    name = names[_ui["attribute"]]
    key = (id(s.avatar.cloud), s.version, name)
    if _ui["hist"] is None or _ui["hist"][0] != key:
        values = attribute_values(s.avatar.cloud, name)
        finite = values[np.isfinite(values)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        counts, _ = np.histogram(finite, bins=48, range=(lo, hi if hi > lo else lo + 1.0))
        _ui["hist"] = (key, counts.astype(np.float32), lo, hi)
        if changed or _ui["range"] is None or _ui["range"][0] != name:
            _ui["range"] = (name, lo, hi)
    _, counts, lo, hi = _ui["hist"]
    imgui.plot_histogram("##hist", counts, graph_size=imgui.ImVec2(-1, 60))
    imgui.text_disabled(f"{lo:.4g} .. {hi:.4g}")
    _, a, b = _ui["range"]
    speed = max(hi - lo, 1e-6) / 300.0
    _, a, b = imgui.drag_float_range2("Range", a, b, speed, lo, hi, "%.4g")
    _ui["range"] = (name, a, b)
    if imgui.button("Select in range"):
        _act(state, "select_range", {"attribute": name, "lo": a, "hi": b, "mode": _mode()})


def _operations(state: ViewerState, info: AppInfo, s: EditSession) -> None:
    imgui.separator_text("Operations")
    has_sel = bool(s.selection.any())
    imgui.begin_disabled(not has_sel)
    if imgui.button("Delete"):
        _act(state, "edit_delete")
    remember(info, "edit_delete")
    imgui.same_line()
    if imgui.button("Hide"):
        _act(state, "edit_hide")
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not s.hidden.any())
    if imgui.button("Show all"):
        _act(state, "edit_show_all")
    imgui.end_disabled()
    imgui.begin_disabled(not has_sel)
    imgui.set_next_item_width(140)
    _, _ui["opacity"] = imgui.slider_float("##opacity", _ui["opacity"], 0.0, 2.0, "x%.2f")
    imgui.same_line()
    if imgui.button("Scale opacity"):
        _act(state, "edit_scale_opacity", float(_ui["opacity"]))
    _, _ui["tint"] = imgui.color_edit3("Tint colour", _ui["tint"])
    imgui.set_next_item_width(100)
    _, _ui["tint_mode"] = imgui.combo("##tintmode", _ui["tint_mode"], ["multiply", "blend"])
    imgui.same_line()
    imgui.set_next_item_width(100)
    _, _ui["tint_amount"] = imgui.slider_float("##amount", _ui["tint_amount"], 0.0, 1.0, "%.2f")
    imgui.same_line()
    if imgui.button("Tint"):
        _act(state, "edit_tint", {"rgb": tuple(float(v) for v in _ui["tint"]),
                                  "mode": ("multiply", "blend")[_ui["tint_mode"]], "amount": _ui["tint_amount"]})
    f_dim = s.avatar.cloud.feature_dim
    if f_dim:
        _ui["channel"] = min(_ui["channel"], f_dim - 1)
        imgui.set_next_item_width(140)
        _, _ui["channel"] = imgui.slider_int("Feature channel", _ui["channel"], 0, f_dim - 1)
        imgui.set_next_item_width(100)
        _, _ui["feature_value"] = imgui.input_float("##fvalue", _ui["feature_value"], 0.0, 0.0, "%.3f")
        imgui.same_line()
        if imgui.button("Set"):
            _act(state, "edit_set_feature", {"channel": _ui["channel"], "value": float(_ui["feature_value"])})
        imgui.same_line()
        imgui.set_next_item_width(100)
        _, _ui["feature_factor"] = imgui.input_float("##ffactor", _ui["feature_factor"], 0.0, 0.0, "x%.3f")
        imgui.same_line()
        if imgui.button("Scale"):
            _act(state, "edit_scale_feature", {"channel": _ui["channel"], "factor": float(_ui["feature_factor"])})
    imgui.end_disabled()


def _floater_params() -> dict:
    return {"k": int(_ui["k"]), "distance_factor": float(_ui["distance_factor"]),
            "min_opacity": float(_ui["min_opacity"])}


def _floaters(state: ViewerState, s: EditSession) -> None:
    imgui.separator_text("Floaters")
    _, _ui["k"] = imgui.slider_int("Neighbours", _ui["k"], 2, 32)
    _, _ui["distance_factor"] = imgui.slider_float("Distance x median", _ui["distance_factor"], 1.0, 20.0, "%.1f")
    _, _ui["min_opacity"] = imgui.slider_float("Min opacity", _ui["min_opacity"], 0.0, 0.5, "%.3f")
    _, _ui["within"] = imgui.checkbox("Only within the selection", _ui["within"])
    if imgui.button("Preview"):
        _act(state, "edit_preview_floaters", _floater_params())
    imgui.same_line()
    if imgui.button("Remove floaters"):
        _act(state, "edit_remove_floaters", {**_floater_params(), "within_selection": bool(_ui["within"])})
    if s.preview is not None:
        imgui.same_line()
        if imgui.button("Clear preview"):
            _act(state, "edit_clear_preview")
        imgui.text(f"{int(s.preview.sum()):,} would be removed (highlighted)")


def _history(state: ViewerState, info: AppInfo, s: EditSession) -> None:
    imgui.separator_text("History")
    imgui.begin_disabled(not s.can_undo)
    if imgui.button("Undo"):
        _act(state, "edit_undo")
    remember(info, "edit_undo")
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not s.can_redo)
    if imgui.button("Redo"):
        _act(state, "edit_redo")
    imgui.end_disabled()
    done, undone = s.history.names()
    if imgui.begin_list_box("##history", imgui.ImVec2(-1, 110)):
        for i, name in enumerate(done):
            imgui.selectable(f"{shown(name)}##done{i}", i == len(done) - 1)
        for name in undone:
            imgui.text_disabled(f"  {shown(name)}")
        imgui.end_list_box()


def _request_save(state: ViewerState, s: EditSession, path: str | None) -> None:
    target = path if path is not None else (s.save_path or s.source)
    if target is None:
        state.report("this avatar has no file yet: use Save as")
        return
    if same_file(target, s.source):
        _ui["confirm"] = (path, True, f"{target} is the file the avatar was opened from. Overwrite it?")
    elif path is not None and Path(path).exists() and not same_file(path, s.save_path):
        _ui["confirm"] = (path, False, f"{path} exists. Overwrite it?")
    else:
        _act(state, "edit_save", {"path": path, "overwrite_source": False})
        return
    imgui.open_popup("Overwrite?##edit")


def _files(state: ViewerState, s: EditSession) -> None:
    imgui.separator_text("File")
    if imgui.button("Save"):
        _request_save(state, s, None)
    imgui.same_line()
    imgui.set_next_item_width(-90)
    _, _ui["save_as"] = imgui.input_text("##saveas", _ui["save_as"])
    imgui.same_line()
    if imgui.button("Save as") and _ui["save_as"].strip():
        _request_save(state, s, _ui["save_as"].strip())
    imgui.set_next_item_width(-90)
    _, _ui["export"] = imgui.input_text("##export", _ui["export"])
    imgui.same_line()
    if imgui.button("Export PLY") and _ui["export"].strip():
        _act(state, "edit_export_ply", _ui["export"].strip())
    imgui.text_disabled("PLY: posed at the current expression, hidden Gaussians left out.")


def _confirm(state: ViewerState) -> None:
    opened, _ = imgui.begin_popup_modal("Overwrite?##edit", None, imgui.WindowFlags_.always_auto_resize)
    if not opened:
        return
    path, is_source, question = _ui["confirm"] or (None, False, "")
    imgui.text(question)
    if imgui.button("Overwrite"):
        _act(state, "edit_save", {"path": path, "overwrite_source": is_source})
        _ui["confirm"] = None
        imgui.close_current_popup()
    imgui.same_line()
    if imgui.button("Cancel"):
        _ui["confirm"] = None
        imgui.close_current_popup()
    imgui.end_popup()


# --------------------------------------------------------------------------------------------------
# carrying out the actions


def _mask_mode(arg: dict) -> str:
    return str(arg.get("mode", "replace"))


def apply(s: EditSession, name: str, arg, camera=None, means: np.ndarray | None = None,
          code: np.ndarray | None = None) -> bool:
    """Carry out one of this panel's actions on `s`; False for names it does not handle ("select_tool",
    "edit_recover" and other panels' actions). `camera`/`means` (the view camera and the posed centres on screen)
    are needed by the screen-space selections, `code` (the current expression) by "edit_export_ply".
    Errors (ValueError, OSError, AvatarFileError) propagate for the app to report."""
    if name in ("select_rect", "select_lasso", "select_brush") and camera is None:
        raise ValueError(f"{name} needs the view camera")
    if name == "select_rect":
        s.select_rect(camera, *arg["rect"], mode=_mask_mode(arg), means=means)
    elif name == "select_lasso":
        s.select_lasso(camera, np.asarray(arg["polygon"], float), mode=_mask_mode(arg), means=means)
    elif name == "select_brush":
        s.select_brush(camera, np.asarray(arg["centres"], float), arg["radius"], mode=_mask_mode(arg), means=means)
    elif name == "select_sphere":
        s.select_sphere(arg["centre"], arg["radius"], mode=_mask_mode(arg), means=means)
    elif name == "select_box":
        s.select_box(arg["lo"], arg["hi"], arg.get("transform"), mode=_mask_mode(arg), means=means)
    elif name == "select_range":
        s.select_range(arg["attribute"], arg["lo"], arg["hi"], mode=_mask_mode(arg))
    elif name in ("select_grow", "select_shrink"):
        (s.grow if name == "select_grow" else s.shrink)(int(arg or 1))
    elif name in ("select_invert", "select_all", "select_clear"):
        {"select_invert": s.invert, "select_all": s.select_all, "select_clear": s.clear_selection}[name]()
    elif name in _COMMANDS:
        s.run(_COMMANDS[name](arg))
    elif name == "edit_preview_floaters":
        s.preview_floaters(**arg)
    elif name == "edit_clear_preview":
        s.clear_preview()
    elif name == "edit_undo":
        s.undo()
    elif name == "edit_redo":
        s.redo()
    elif name == "edit_save":
        s.save(arg.get("path"), overwrite_source=bool(arg.get("overwrite_source")))
    elif name == "edit_export_ply":
        s.export_posed_ply(arg, code)
    elif name == "edit_discard_autosave":
        s.discard_autosave()
    else:
        return False
    return True


_COMMANDS = {
    "edit_delete": lambda a: DeleteSelected(),
    "edit_hide": lambda a: Hide(),
    "edit_show_all": lambda a: ShowAll(),
    "edit_scale_opacity": lambda a: ScaleOpacity(float(a)),
    "edit_tint": lambda a: Tint(a["rgb"], a.get("mode", "multiply"), a.get("amount", 1.0)),
    "edit_set_feature": lambda a: SetFeature(a["channel"], a["value"]),
    "edit_scale_feature": lambda a: ScaleFeature(a["channel"], a["factor"]),
    "edit_remove_floaters": lambda a: RemoveFloaters(**a),
}
