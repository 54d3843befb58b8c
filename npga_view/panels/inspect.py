"""Inspect: colour modes with their legend, draw style, Gaussian counts, histogram range highlight / filter,
clipping, the kNN graph and the inspector of a picked Gaussian.

Expects (the app provides them):
- ``state.inspect``: an `InspectSettings` (npga_core.inspection); this panel writes it directly (mode, parameters,
  style, histogram range and action, clipping, kNN display, `picked`, `pick_on_click`). The app rebuilds the
  frame when ``state.inspect.key()`` changes, when a new pose arrives and, if `Inspector.camera_dependent`,
  when the camera moves: ``frame = inspector.frame(settings, posed, code, camera, selection)`` then
  ``renderer.show(frame)``; a ValueError there goes to ``info.inspect.error`` (and the plain colours are shown).
- ``info.inspect``: an `npga_core.inspection.inspector.InspectInfo` from ``inspector.info(settings, posed, code,
  frame.colouring, camera, renderer.drawn_mask(), NEAR)`` after the draw (legend, counts, histogram, record of
  the picked Gaussian, kNN timing); None before an avatar is open.
- ``info.avatar`` for the feature / latent widths, G's blocks and the expression space.

When ``state.inspect.pick_on_click`` is on, a left click (without drag) in the splat view should set
``state.inspect.picked = renderer.pick(camera, x, y)`` (image pixels, top-left origin, unflipped camera).

Actions appended to ``state.actions``: `FocusGaussian(index)` (npga_view/actions.py): move the orbit camera's
target to the posed centre of Gaussian `index`.
"""

from __future__ import annotations

from typing import cast

import numpy as np
from imgui_bundle import imgui

from npga_core.errors import shown
from npga_core.inspection.colouring import COLOUR_MAPS, Colouring, colour_map
from npga_core.inspection.inspector import (
    CLIP_MODES,
    HIST_ACTIONS,
    KNN_COLOURS,
    KNN_SHOW,
    OFFSET_ATTRIBUTES,
    STYLES,
    InspectInfo,
    InspectSettings,
    parse_mode,
)
from npga_core.inspection.legend import format_value
from npga_core.inspection.measures import SCALE_MEASURES
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

#: (mode name as in InspectSettings.mode without ":K", label)
MODE_CHOICES: tuple[tuple[str, str], ...] = (
    ("rgb", "colour"), ("features", "features f (PCA)"), ("feature", "feature channel"),
    ("latent", "latent h (PCA)"), ("latent:", "latent channel"), ("offset", "offset"),
    ("laplacian", "Laplacian residual"), ("sensitivity", "sensitivity"), ("opacity", "opacity"),
    ("scale", "scale"), ("depth", "depth"),
)
G_BLOCKS = ("position", "rotation", "scale", "opacity", "sh", "latent")


def _combo(label: str, value: str, choices: tuple[str, ...] | list[str], labels=None) -> str:
    idx = choices.index(value) if value in choices else 0
    changed, idx = imgui.combo(label, idx, [shown(x) for x in labels or choices])
    return choices[idx] if changed else value


def _u32(rgb) -> int:
    return imgui.color_convert_float4_to_u32(imgui.ImVec4(float(rgb[0]), float(rgb[1]), float(rgb[2]), 1.0))


_Vec3 = tuple[float, float, float]


def _draw(state: ViewerState, info: AppInfo) -> None:
    opened = imgui.collapsing_header("Inspect")
    remember(info, "inspect")
    if not opened:
        return
    s: InspectSettings = state.inspect
    ii: InspectInfo | None = getattr(info, "inspect", None)
    a = info.avatar
    if a is None:
        imgui.text_disabled("Open an avatar to inspect it.")
        return
    _mode(s, a)
    remember(info, "inspect_mode")
    if ii is not None and ii.error:
        imgui.push_text_wrap_pos(0)
        imgui.text_colored(imgui.ImVec4(1.0, 0.55, 0.45, 1.0), ii.error)
        imgui.pop_text_wrap_pos()
    if ii is not None and ii.colouring is not None:
        _legend(ii.colouring, s)
    s.style = _combo("Style", s.style, STYLES)
    if s.style == "points":
        _, s.point_px = imgui.slider_float("Point radius", s.point_px, 0.5, 8.0, "%.1f px")
    if ii is not None and ii.counts is not None:
        _counts(ii)
    for title, body in (("Histogram and range", lambda: _histogram(s, ii, a, info)),
                        ("Clipping", lambda: _clipping(s)), ("kNN graph", lambda: _knn(s, ii)),
                        ("Picked Gaussian", lambda: _picked(s, ii, state, info, len(a)))):
        opened = imgui.tree_node(title)
        remember(info, f"inspect_node_{title.split()[0].lower()}")
        if opened:
            body()
            imgui.tree_pop()


# --- mode and its parameters -----------------------------------------------------------------------------------
def _mode(s: InspectSettings, a) -> None:
    try:
        name, channel = parse_mode(s.mode)
    except ValueError:
        name, channel = "rgb", None
    key = "latent:" if name == "latent" and channel is not None else name
    keys = tuple(k for k, _ in MODE_CHOICES)
    new = _combo("Colour mode", key, keys, [label for _, label in MODE_CHOICES])
    channel = channel or 0
    if new in ("feature", "latent:"):
        width = a.cloud.feature_dim if new == "feature" else a.cloud.latent_dim
        _, channel = imgui.slider_int("Channel", min(channel, max(width - 1, 0)), 0, max(width - 1, 0))
        s.mode = f"{'feature' if new == 'feature' else 'latent'}:{channel}"
    else:
        s.mode = new
    if new == "offset":
        s.offset_attr = _combo("Attribute", s.offset_attr, OFFSET_ATTRIBUTES)
        key = "sh" if s.offset_attr == "colour" else s.offset_attr
        nets = [k for k, n in (a.dynamics.networks().items() if a.dynamics is not None else [])
                if any(r.attribute == key for r in n.config.routes or [])]
        if len(nets) > 1:  # offsets of one network, or the sum of all that offset this attribute
            sources = ("sum", *nets)
            if s.offset_source not in sources:
                s.offset_source = "sum"
            s.offset_source = _combo("Network", s.offset_source, sources, (" + ".join(nets), *nets))
        else:
            s.offset_source = "sum"
    elif new == "laplacian":
        blocks = [b for b, _ in a.dynamics.G.config.outputs] if a.dynamics is not None and a.dynamics.G else []
        choices = ["features"] + (["G"] + [b for b in G_BLOCKS if b in blocks] if blocks else [])
        s.laplacian_of = _combo("Of", s.laplacian_of, choices,
                                ["features f"] + (["all offsets of G"] + [f"G {b}" for b in choices[2:]]
                                                  if blocks else []))
        _, s.knn_k = imgui.slider_int("k##lap", s.knn_k, 1, 32)
    elif new == "sensitivity":
        n = a.expression.n_components if a.expression is not None else a.code_dim
        _, d = imgui.slider_int("Direction", s.direction + 1, 1, max(n, 1), "PC %d")
        s.direction = d - 1
    elif new == "scale":
        s.scale_measure = _combo("Measure", s.scale_measure, SCALE_MEASURES)
    if new not in ("rgb", "features", "latent"):
        s.cmap = _combo("Colour map", s.cmap, ("",) + COLOUR_MAPS, ("default",) + COLOUR_MAPS)


def _legend(c: Colouring, s: InspectSettings) -> None:
    imgui.push_text_wrap_pos(0)
    imgui.text(shown(c.label))
    for note in c.notes:
        imgui.text_disabled(shown(note))
    imgui.pop_text_wrap_pos()
    if c.cmap is None:
        return
    dl = imgui.get_window_draw_list()
    p = imgui.get_cursor_screen_pos()
    width, height, steps = max(imgui.get_content_region_avail().x, 60.0), 14.0, 48
    colours = colour_map(np.linspace(0.0, 1.0, steps + 1), c.cmap)
    for i in range(steps):
        x0, x1 = p.x + width * i / steps, p.x + width * (i + 1) / steps
        left, right = _u32(colours[i]), _u32(colours[i + 1])
        dl.add_rect_filled_multi_color(imgui.ImVec2(x0, p.y), imgui.ImVec2(x1, p.y + height), left, right, right,
                                       left)
    imgui.dummy(imgui.ImVec2(width, height))
    imgui.text(format_value(c.lo))
    mid = format_value(0.5 * (c.lo + c.hi))
    imgui.same_line(max(width / 2 - imgui.calc_text_size(mid).x / 2, 40))
    imgui.text(mid)
    imgui.same_line(max(width - imgui.calc_text_size(format_value(c.hi)).x, 80))
    imgui.text(format_value(c.hi))
    fixed = s.value_range is not None
    changed, fixed = imgui.checkbox("Fix range", fixed)
    if changed:
        s.value_range = (c.lo, c.hi) if fixed else None
    if s.value_range is not None:
        lo, hi = s.value_range
        speed = max(abs(hi - lo), 1e-9) / 200.0
        changed, lo, hi = imgui.drag_float_range2("Range", lo, hi, speed, 0.0, 0.0, "%.4g")
        if changed and hi > lo:
            s.value_range = (lo, hi)


def _counts(ii: InspectInfo) -> None:
    c = ii.counts
    assert c is not None  # called only with counts
    drawn = "-" if c.drawn is None else f"{c.drawn:,}"
    imgui.text(f"Gaussians: {c.total:,} total, {c.in_frustum:,} in view, {drawn} drawn")
    for name, total, frustum, d in c.parts:
        imgui.text_disabled(f"  {shown(name)}: {total:,} / {frustum:,} / {'-' if d is None else f'{d:,}'}")


# --- histogram, clipping -----------------------------------------------------------------------------------------
def _histogram(s: InspectSettings, ii: InspectInfo | None, a, info: AppInfo) -> None:
    from npga_core.inspection.inspector import Inspector

    names = Inspector(a).attribute_names()
    s.hist_attr = _combo("Attribute##hist", s.hist_attr, names)
    if ii is None or ii.hist_counts is None:
        imgui.text_disabled("(no values)")
        return
    edges = cast(np.ndarray, ii.hist_edges)  # present with the counts
    lo_all, hi_all = float(edges[0]), float(edges[-1])
    width = max(imgui.get_content_region_avail().x, 60.0)
    imgui.plot_histogram("##hist", ii.hist_counts.astype(np.float32), graph_size=imgui.ImVec2(width, 70))
    p0, p1 = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    lo, hi = s.hist_range if s.hist_range is not None else (lo_all, hi_all)
    span = max(hi_all - lo_all, 1e-12)
    x0 = p0.x + (p1.x - p0.x) * np.clip((lo - lo_all) / span, 0, 1)
    x1 = p0.x + (p1.x - p0.x) * np.clip((hi - lo_all) / span, 0, 1)
    imgui.get_window_draw_list().add_rect_filled(imgui.ImVec2(x0, p0.y), imgui.ImVec2(x1, p1.y),
                                                 imgui.color_convert_float4_to_u32(imgui.ImVec4(1, 0.85, 0.1, 0.25)))
    imgui.text_disabled(f"{format_value(lo_all)} .. {format_value(hi_all)}")
    changed, lo, hi = imgui.drag_float_range2("Range##hist", lo, hi, span / 300.0, lo_all, hi_all, "%.4g")
    remember(info, "inspect_hist_range")
    if changed:
        s.hist_range = (min(lo, hi), max(lo, hi))
    for i, action in enumerate(HIST_ACTIONS):
        if i:
            imgui.same_line()
        clicked = imgui.radio_button(f"{action}##hist", s.hist_action == action)
        remember(info, f"inspect_hist_{action}")
        if clicked:
            s.hist_action = action
            if s.hist_range is None:
                s.hist_range = (lo_all, hi_all)
    if s.hist_range is not None:
        imgui.text(f"{ii.hist_in_range:,} Gaussians in the range")


def _clipping(s: InspectSettings) -> None:
    s.clip = _combo("Clip", s.clip, CLIP_MODES)
    if s.clip == "box":
        _, lo = imgui.drag_float3("Min", list(s.clip_lo), 0.002)
        _, hi = imgui.drag_float3("Max", list(s.clip_hi), 0.002)
        s.clip_lo, s.clip_hi = cast(_Vec3, tuple(lo)), cast(_Vec3, tuple(hi))
        imgui.text_disabled("Gaussians outside the box are hidden.")
    elif s.clip == "plane":
        _, point = imgui.drag_float3("Point", list(s.clip_point), 0.002)
        _, normal = imgui.drag_float3("Normal", list(s.clip_normal), 0.01)
        s.clip_point = cast(_Vec3, tuple(point))
        if np.linalg.norm(normal) > 0:
            s.clip_normal = cast(_Vec3, tuple(normal))
        imgui.text_disabled("Gaussians behind the plane (against the normal) are hidden.")


# --- kNN graph, picked Gaussian -----------------------------------------------------------------------------------
def _knn(s: InspectSettings, ii: InspectInfo | None) -> None:
    s.knn_show = _combo("Show", s.knn_show, KNN_SHOW, ("off", "all edges", "around the picked", "around selection"))
    _, s.knn_k = imgui.slider_int("k", s.knn_k, 1, 32)
    s.knn_colour = _combo("Colour by", s.knn_colour, KNN_COLOURS,
                          ("canonical length", "feature difference", "stretch (posed / canonical)"))
    if ii is not None and ii.knn_ms > 1.0:
        imgui.text_disabled(f"graph computed in {ii.knn_ms:.0f} ms (cached)")


def _picked(s: InspectSettings, ii: InspectInfo | None, state: ViewerState, info: AppInfo, n: int) -> None:
    _, s.pick_on_click = imgui.checkbox("Pick with a click in the view", s.pick_on_click)
    remember(info, "inspect_pick_on_click")
    changed, idx = imgui.input_int("Index", -1 if s.picked is None else s.picked)
    if changed:
        s.picked = idx if 0 <= idx < n else None
    if s.picked is None:
        imgui.text_disabled("Nothing picked.")
        return
    if imgui.button("Clear##pick"):
        s.picked = None
        return
    imgui.same_line()
    if imgui.button("Focus"):
        state.actions.append(A.FocusGaussian(s.picked))
    remember(info, "inspect_focus")
    rec = ii.record if ii is not None else None
    if rec is None or rec.get("index") != s.picked:
        return
    _record(rec, s)


def _vec(v, limit: int = 12) -> str:
    flat = np.ravel(v)
    text = ", ".join(format_value(float(x)) for x in flat[:limit])
    return f"({text}{f', ... {len(flat)} values' if len(flat) > limit else ''})"


def _record(rec: dict, s: InspectSettings) -> None:
    if "part" in rec:
        imgui.text(f"part: {shown(rec['part'])}")
    flags = imgui.TableFlags_.borders_inner_v | imgui.TableFlags_.row_bg
    if imgui.begin_table("attrs", 2, flags):
        imgui.table_setup_column("", imgui.TableColumnFlags_.width_fixed)
        imgui.table_setup_column("canonical / posed")
        imgui.table_headers_row()
        for key in ("position", "rotation", "scale", "opacity", "colour"):
            imgui.table_next_row()
            imgui.table_next_column()
            imgui.text(key)
            imgui.table_next_column()
            for side in ("canonical", "posed"):
                value = rec[side][key]
                imgui.text(format_value(cast(float, value)) if np.isscalar(value) else _vec(value))
        imgui.end_table()
    imgui.push_text_wrap_pos(0)
    imgui.text(f"f: {_vec(rec['features'])}")
    if rec.get("latent") is not None:
        imgui.text(f"h: {_vec(rec['latent'])}")
        imgui.text(f"h posed: {_vec(rec['posed_latent'])}")
    for name, value in rec["offsets"].items():
        imgui.text(f"{shown(name)} offset: {_vec(value)}")
    imgui.pop_text_wrap_pos()
    imgui.text(f"{len(rec['neighbours'])} nearest neighbours (canonical distance):")
    for j, dist in rec["neighbours"]:
        if imgui.selectable(f"  {j}  ({format_value(dist)})##nb{j}", False)[0]:
            s.picked = j


class InspectPanel:
    """The Inspect panel (its settings live in `state.inspect`, its figures in `info.inspect`)."""

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        _draw(state, info)
