"""Compare: the avatar against a capture (NeRSemble or GHA folders) or a second avatar B, as a wipe, blend,
difference heatmap or side by side, with PSNR/SSIM(/LPIPS) of the view."""

from __future__ import annotations

from typing import cast

from imgui_bundle import imgui

from npga_core.evaluation.compare import MODES, Mode
from npga_view import actions as C
from npga_view.comparison.snapshot import PAIRS, CompareInfo, score_label
from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState

PAIR_LABELS = {"a-capture": "avatar vs capture", "b-capture": "B vs capture", "a-b": "avatar vs B"}
MODE_LABELS = {"wipe": "wipe (drag in the view)", "blend": "blend", "difference": "difference heatmap",
               "side": "side by side", "a": "first only", "b": "second only"}


class ComparePanel:
    """The Compare panel; owns the typed paths."""

    def __init__(self) -> None:
        self.capture = ""
        self.sequence = ""
        self.avatar_b = ""

    def draw(self, state: ViewerState, app_info: AppInfo) -> None:
        if not imgui.collapsing_header("Compare"):
            return
        actions, info = state.actions, app_info.compare or CompareInfo()
        self._files(actions, info)
        changed, on = imgui.checkbox("Show comparison", info.active)
        if changed:
            actions.append(C.ShowComparison(on))
        self._settings(actions, info)
        if info.frames:
            self._stepping(actions, info)
        imgui.text_wrapped(info.status)
        for role, s in sorted(info.scores.items()):
            lp = "n/a" if s.lpips is None else f"{s.lpips:.4f}"
            imgui.text(f"{score_label(role)}: PSNR {s.psnr:.2f} dB  SSIM {s.ssim:.4f}  LPIPS {lp}")

    def _files(self, actions: list, info: CompareInfo) -> None:
        imgui.set_next_item_width(200)
        _, self.capture = imgui.input_text("Capture folder", self.capture)
        imgui.set_next_item_width(200)
        _, self.sequence = imgui.input_text("Its codes (optional)", self.sequence)
        if imgui.button("Open capture"):
            actions.append(C.OpenCapture(self.capture.strip(), self.sequence.strip()))
        imgui.set_next_item_width(200)
        _, self.avatar_b = imgui.input_text("Avatar B", self.avatar_b)
        imgui.same_line()
        if imgui.button("Open B"):
            actions.append(C.OpenAvatarB(self.avatar_b.strip()))
        if info.b_name:
            imgui.same_line()
            if imgui.button("Close B"):
                actions.append(C.OpenAvatarB(""))
        if info.loading:
            imgui.text_disabled(info.loading)

    @staticmethod
    def _settings(actions: list, info: CompareInfo) -> None:
        pairs, modes = list(PAIRS), list(MODES)
        changed, i = imgui.combo("Compare", pairs.index(info.pair), [PAIR_LABELS[p] for p in pairs])
        if changed:
            actions.append(C.SetComparePair(pairs[i]))
        changed, i = imgui.combo("Show", modes.index(cast(Mode, info.mode)), [MODE_LABELS[m] for m in modes])
        if changed:
            actions.append(C.SetCompareMode(modes[i]))
        if info.mode in ("wipe", "blend"):
            changed, t = imgui.slider_float("Position", info.position, 0.0, 1.0, "%.2f")
            if changed:
                actions.append(C.SetComparePosition(t))
        if info.mode == "difference":
            changed, v = imgui.slider_float("Scale top", info.vmax, 0.01, 1.0, "%.2f")
            if changed:
                actions.append(C.SetCompareScale(v))
        changed, bg = imgui.color_edit3("Compare background", list(info.background))
        if changed:
            actions.append(C.SetCompareBackground((float(bg[0]), float(bg[1]), float(bg[2]))))
        if imgui.is_item_hovered():
            imgui.set_tooltip("The renders' background, and the colour outside the capture's masks on both sides\n"
                              "(as `npga-view evaluate --background`; the scores depend on it)")
        changed, cnn = imgui.checkbox("Through the CNN", info.use_cnn)
        if changed:
            actions.append(C.SetCompareCnn(cnn))

    @staticmethod
    def _stepping(actions: list, info: CompareInfo) -> None:
        imgui.text(f"frame {info.frame} ({len(info.frames)}), camera {info.camera} ({len(info.cameras)})")
        for label, step in (("< frame", C.StepCapture(frames=-1)), ("frame >", C.StepCapture(frames=1)),
                            ("< camera", C.StepCapture(cameras=-1)), ("camera >", C.StepCapture(cameras=1))):
            if imgui.button(label):
                actions.append(step)
            imgui.same_line()
        imgui.new_line()
