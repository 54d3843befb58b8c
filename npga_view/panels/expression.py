"""Expression: sliders along the top-k PCA directions (in std), or a rig's named channels (0..1: an avatar posed
by a linear rig alone, such as LAM's ARKit shapes); reset, random, from frame, presets, the pad."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_core.errors import shown
from npga_view import actions as A
from npga_view.panels.expression_pad import ExpressionPad
from npga_view.panels.info import AppInfo, remember
from npga_view.state import MAX_SLIDERS, ViewerState


class ExpressionPanel:
    """The Expression panel; owns the name typed for a new preset and the expression pad."""

    def __init__(self) -> None:
        self.preset_name = "my expression"
        self.pad = ExpressionPad()

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not imgui.collapsing_header("Expression", imgui.TreeNodeFlags_.default_open):
            return
        a = info.avatar
        if a is None or a.expression is None or a.code_dim == 0:
            imgui.text_disabled("This avatar has no expression space.")
            return
        ex = a.expression
        channels = a.slider_channels
        k_max = min(MAX_SLIDERS, ex.n_components)
        if channels is None:
            _, state.n_sliders = imgui.slider_int("Directions", min(state.n_sliders, k_max), 1, k_max)
        else:
            state.n_sliders = k_max
            imgui.text_disabled(f"{len(channels)} rig channels (weights; 0 = rest)")
        if info.sequence is not None:
            _, state.follow_sequence = imgui.checkbox("Follow sequence", state.follow_sequence)
            remember(info, "follow_sequence")
        if imgui.button("Mean"):
            state.actions.append(A.ResetExpression())
        imgui.same_line()
        if imgui.button("Random"):
            state.actions.append(A.RandomExpression())
        remember(info, "random")
        if info.sequence is not None:
            imgui.same_line()
            if imgui.button("From frame"):
                state.actions.append(A.SlidersFromFrame())
        self._sliders(state, info, channels)
        if imgui.tree_node("Presets"):
            for name in list(ex.named) + [p for p in state.presets if p not in ex.named]:
                if imgui.selectable(shown(name), False)[0]:
                    state.actions.append(A.ApplyPreset(name))
            imgui.set_next_item_width(160)
            _, self.preset_name = imgui.input_text("##preset", self.preset_name)
            imgui.same_line()
            if imgui.button("Save preset"):
                state.actions.append(A.SavePreset(self.preset_name.strip()))
            imgui.tree_pop()
        self.pad.draw(state, info)

    @staticmethod
    def _sliders(state: ViewerState, info: AppInfo, channels: tuple[str, ...] | None) -> None:
        """PCA directions in std, or the rig's channels 0..1; while a sequence is followed, the values of the frame on
        screen (moving one takes the sliders over from that frame)."""
        values, frame = state.sliders, info.frame_sliders
        following = state.follow_sequence and frame is not None
        if frame is not None and following:
            values = state.sliders.copy()
            k = min(values.size, frame.size)
            values[:k] = frame[:k]
        for i in range(min(state.n_sliders, values.size)):
            if channels is None:
                changed, v = imgui.slider_float(f"PC {i + 1}##pc{i}", float(values[i]), -3.0, 3.0, "%+.2f sd")
            else:
                changed, v = imgui.slider_float(f"{shown(channels[i])}##pc{i}", float(values[i]), 0.0, 1.0, "%.2f")
            remember(info, f"slider{i}")
            if changed:
                if following:
                    state.sliders = values
                state.sliders[i] = v
                state.follow_sequence = False
