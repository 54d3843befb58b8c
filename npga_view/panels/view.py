"""View: camera presets and field of view, rig cameras, render mode, background, raw splats vs CNN-refined image
and latent views, screenshots, sessions."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_core.errors import shown
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.state import RENDER_MODES, ViewerState


class ViewPanel:
    """The View panel; owns the typed rig and session paths."""

    def __init__(self) -> None:
        self.session = "session.json"
        self.rig = ""

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
            return
        self._camera(state, info)
        self._image(state, info)
        _refinement(state, info)
        self._output(state, info)

    def _camera(self, state: ViewerState, info: AppInfo) -> None:
        """Presets, frame and reset, field of view and roll, rig cameras."""
        cam = state.camera
        presets: tuple[tuple[A.PresetName, str], ...] = (("front", "Front"), ("three_quarter", "3/4"), ("side", "Side"),
                                                         ("top", "Top"))
        for name, label in presets:
            if imgui.button(label):
                state.actions.append(A.CameraPreset(name))
            imgui.same_line()
        if imgui.button("Frame"):
            state.actions.append(A.FrameAvatar())
        imgui.same_line()
        if imgui.button("Reset"):
            state.actions.append(A.ResetCamera())
        _, cam.fov_y = imgui.slider_float("FOV", cam.fov_y, 5.0, 90.0, "%.1f deg")
        _, cam.roll = imgui.slider_float("Roll", cam.roll, -180.0, 180.0, "%.0f deg")
        if info.rig_names:
            labels = ["orbit camera"] + info.rig_names
            changed, idx = imgui.combo("Rig camera", state.rig_index + 1, [shown(x) for x in labels])
            if changed:
                state.rig_index = idx - 1
        imgui.set_next_item_width(200)
        _, self.rig = imgui.input_text("##rig", self.rig)
        imgui.same_line()
        if imgui.button("Load rig"):
            state.actions.append(A.LoadRig(self.rig.strip()))

    def _image(self, state: ViewerState, info: AppInfo) -> None:
        """Render pass, background, the statistics overlay and merged live images."""
        idx = RENDER_MODES.index(state.mode) if state.mode in RENDER_MODES else 0
        changed, idx = imgui.combo("Pass", idx, list(RENDER_MODES))
        if changed:
            state.mode = RENDER_MODES[idx]
        remember(info, "mode")
        _, bg = imgui.color_edit3("Background", list(state.background))
        state.background = (float(bg[0]), float(bg[1]), float(bg[2]))
        _, state.show_stats = imgui.checkbox("Statistics overlay", state.show_stats)
        _, state.merged_live = imgui.checkbox("Merged cloud while moving", state.merged_live)
        if imgui.is_item_hovered():
            imgui.set_tooltip("While you drag, move a slider or play, draw the live images from at most 16k merged\n"
                              "Gaussians where a full image does not fit in the frame (software GL); the image\n"
                              "after you stop is always drawn from every Gaussian. Off: every Gaussian, always.")
        remember(info, "merged_live")

    def _output(self, state: ViewerState, info: AppInfo) -> None:
        """Screenshot, MP4 recording, sessions."""
        if imgui.button("Screenshot"):
            state.actions.append(A.Screenshot())
        remember(info, "screenshot")
        imgui.same_line()
        if imgui.button("Stop recording" if info.recording else "Record MP4"):
            state.actions.append(A.ToggleRecording())
        if info.last_screenshot:
            imgui.text_disabled(f"saved {shown(info.last_screenshot)[-48:]}")
        imgui.set_next_item_width(200)
        _, self.session = imgui.input_text("##session", self.session)
        imgui.same_line()
        if imgui.button("Save session"):
            state.actions.append(A.SaveSession(self.session.strip()))
        imgui.same_line()
        if imgui.button("Load"):
            state.actions.append(A.LoadSession(self.session.strip()))


LATENT_LABELS = {"off": "off (colour image)", "pca": "PCA of h (RGB)", "channel": "one channel of h"}


def _refinement(state: ViewerState, info: AppInfo) -> None:
    """Raw splats vs the CNN-refined image (avatars with a CNN), and the latent image h (avatars with h)."""
    avatar = info.avatar
    latent_dim = 0 if avatar is None else avatar.cloud.latent_dim
    if avatar is not None and avatar.cnn is not None:
        imgui.text("Image:")
        imgui.same_line()
        if imgui.radio_button("raw splats", not state.use_cnn):
            state.use_cnn = False
        remember(info, "raw_splats")
        imgui.same_line()
        if imgui.radio_button("CNN refined", state.use_cnn):
            state.use_cnn = True
        remember(info, "cnn_refined")
        if info.shown != "splats" or info.cnn_ms:
            imgui.text_disabled(f"showing {info.shown}" + (f", CNN {info.cnn_ms:.0f} ms" if info.cnn_ms else ""))
    if not latent_dim:
        return
    keys = list(LATENT_LABELS)
    idx = keys.index(state.latent_view) if state.latent_view in keys else 0
    changed, idx = imgui.combo("Latent h", idx, [LATENT_LABELS[k] for k in keys])
    if changed:
        state.latent_view = keys[idx]
    remember(info, "latent_view")
    if state.latent_view == "channel":
        state.latent_channel = min(max(state.latent_channel, 0), latent_dim - 1)
        _, state.latent_channel = imgui.slider_int("Channel", state.latent_channel, 0, latent_dim - 1)
        remember(info, "latent_channel")
