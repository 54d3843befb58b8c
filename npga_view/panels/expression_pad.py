"""The expression pad of the Expression panel: a square whose point blends four corner expressions bilinearly
(`npga_core.posing.pad`); corners are named expressions, presets or sequence frames. Moving the point sets the
sliders to the blended code, as dragging the sliders does (the code must lie in the slider space: named
expressions, presets and the frames of the avatar's own sequences do)."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from npga_core.posing.pad import CORNERS, blend
from npga_view.imgui_glfw import drawable
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

#: Corners chosen by default when the avatar has these named expressions (else the first four it has).
DEFAULT = ("smile", "surprise", "angry", "sad")
PAD_SIZE = 180.0

Spec = tuple[str, str | int]  # ("named", name), ("preset", name) or ("frame", index)


def label(spec: Spec) -> str:
    kind, value = spec
    return f"frame {value}" if kind == "frame" else str(value) + (" (preset)" if kind == "preset" else "")


class ExpressionPad:
    """Owns the four corners and the point (u right, v down, both 0..1)."""

    def __init__(self) -> None:
        self.corners: list[Spec | None] = [None] * 4
        self.u = self.v = 0.5
        self._avatar_id: int | None = None

    # ---------------------------------------------------------------------------------------- corners
    def options(self, state: ViewerState, info: AppInfo) -> list[Spec]:
        """What a corner can be: the avatar's named expressions, the user's presets, the current frame."""
        avatar = info.avatar
        assert avatar is not None and avatar.expression is not None  # the pad shows only for such an avatar
        ex = avatar.expression
        out: list[Spec] = [("named", n) for n in ex.named]
        out += [("preset", n) for n in state.presets if n not in ex.named]
        if info.sequence is not None:
            out.append(("frame", int(info.frame)))
        return out

    def corner_code(self, spec: Spec | None, state: ViewerState, info: AppInfo) -> np.ndarray | None:
        """The code of a corner, None if it no longer exists or does not fit the avatar."""
        if spec is None or info.avatar is None or info.avatar.expression is None:
            return None
        kind, value = spec
        ex = info.avatar.expression
        code: np.ndarray | list[float] | None
        if kind == "named":
            code = ex.named.get(str(value))
        elif kind == "preset":
            code = state.presets.get(str(value))
        elif kind == "frame" and info.sequence is not None and 0 <= int(value) < len(info.sequence):
            code = info.sequence.codes[int(value)]
        else:
            code = None
        if code is None:
            return None
        arr = np.asarray(code, np.float32).reshape(-1)
        return arr if arr.shape == (ex.dim,) and np.isfinite(arr).all() else None

    def defaults(self, state: ViewerState, info: AppInfo) -> None:
        """Fill the corners for a newly opened avatar (its named expressions)."""
        avatar = info.avatar
        assert avatar is not None and avatar.expression is not None  # called for an avatar with expressions
        named = list(avatar.expression.named)
        picks = [n for n in DEFAULT if n in named]
        picks += [n for n in named if n not in picks and n != "neutral"]
        picks += [n for n in named if n not in picks]
        self.corners = [("named", n) for n in picks[:4]] + [None] * (4 - min(4, len(picks)))
        self.u = self.v = 0.5

    # ---------------------------------------------------------------------------------------- the code
    def code(self, state: ViewerState, info: AppInfo) -> np.ndarray | None:
        """The blended code at the point, None while a corner is missing."""
        codes = [self.corner_code(c, state, info) for c in self.corners]
        present = [c for c in codes if c is not None]
        if len(present) < len(codes):
            return None
        return blend(np.stack(present), self.u, self.v)

    def move(self, u: float, v: float, state: ViewerState, info: AppInfo) -> bool:
        """Put the point at (u, v) and drive the sliders with its code; False while a corner is missing."""
        self.u, self.v = float(np.clip(u, 0, 1)), float(np.clip(v, 0, 1))
        z = self.code(state, info)
        if z is None:
            return False
        avatar = info.avatar
        assert avatar is not None and avatar.expression is not None  # a code needs them
        state.sliders = avatar.expression.to_sliders(z).astype(np.float32)
        state.follow_sequence = False
        return True

    # ---------------------------------------------------------------------------------------- drawing
    def draw(self, state: ViewerState, info: AppInfo) -> None:
        a = info.avatar
        if a is None or a.expression is None:
            return
        if self._avatar_id != id(a):
            self._avatar_id = id(a)
            self.defaults(state, info)
        opened = imgui.tree_node("Pad")
        remember(info, "pad_node")
        if not opened:
            return
        options = self.options(state, info)
        for i, name in enumerate(CORNERS):
            imgui.set_next_item_width(170)
            current = self.corners[i]
            if imgui.begin_combo(f"{name}##padcorner{i}", label(current) if current else "(choose)"):
                for spec in options:
                    if imgui.selectable(label(spec), spec == current)[0]:
                        self.corners[i] = spec
                        self.move(self.u, self.v, state, info)
                imgui.end_combo()
            remember(info, f"pad_corner{i}")
        self._square(state, info)
        imgui.tree_pop()

    def _square(self, state: ViewerState, info: AppInfo) -> None:
        p0 = imgui.get_cursor_screen_pos()
        s = PAD_SIZE
        imgui.invisible_button("##pad", imgui.ImVec2(s, s))
        remember(info, "pad")
        if imgui.is_item_active():
            m = imgui.get_io().mouse_pos
            self.move((m.x - p0.x) / s, (m.y - p0.y) / s, state, info)
        dl = imgui.get_window_draw_list()
        grey, light = imgui.get_color_u32((0.25, 0.25, 0.28, 1.0)), imgui.get_color_u32((0.5, 0.5, 0.55, 1.0))
        dl.add_rect_filled(p0, imgui.ImVec2(p0.x + s, p0.y + s), grey)
        for k in (1, 2, 3):
            t = k * s / 4
            dl.add_line(imgui.ImVec2(p0.x + t, p0.y), imgui.ImVec2(p0.x + t, p0.y + s), light)
            dl.add_line(imgui.ImVec2(p0.x, p0.y + t), imgui.ImVec2(p0.x + s, p0.y + t), light)
        text = imgui.get_color_u32((0.85, 0.85, 0.9, 1.0))
        for i, c in enumerate(self.corners):
            name = drawable(label(c)) if c else "?"  # draw-list text is not wrapped by imgui_glfw
            w = imgui.calc_text_size(name).x
            x = p0.x + 3 if i % 2 == 0 else p0.x + s - w - 3
            y = p0.y + 2 if i < 2 else p0.y + s - imgui.get_text_line_height() - 2
            dl.add_text(imgui.ImVec2(x, y), text, name)
        ok = self.code(state, info) is not None
        dot = imgui.get_color_u32((1.0, 0.75, 0.2, 1.0) if ok else (0.6, 0.6, 0.6, 1.0))
        dl.add_circle_filled(imgui.ImVec2(p0.x + self.u * s, p0.y + self.v * s), 6.0, dot)
        if not ok:
            imgui.text_disabled("choose four corners")
