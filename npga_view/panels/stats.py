"""Stats: Gaussian counts, frame rate, per-stage times."""

from __future__ import annotations

from imgui_bundle import imgui

from npga_view.panels.info import AppInfo
from npga_view.state import ViewerState

STAGES = (("F", "dynamics F"), ("G", "dynamics G"), ("cnn", "CNN"), ("sort", "sort"), ("upload", "upload"),
          ("preprocess", "project"), ("draw", "draw"))


class StatsOverlay:
    """An overlay in the top-right corner of the splat view: counts, rates, what the image is, stage times."""

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        _draw()
        _body(info)
        imgui.end()


def _draw() -> None:
    vp = imgui.get_main_viewport()
    imgui.set_next_window_pos(imgui.ImVec2(vp.pos.x + vp.size.x - 10, vp.pos.y + 10), imgui.Cond_.always,
                              imgui.ImVec2(1.0, 0.0))
    imgui.set_next_window_bg_alpha(0.55)
    flags = (imgui.WindowFlags_.no_decoration | imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_move
             | imgui.WindowFlags_.no_focus_on_appearing | imgui.WindowFlags_.no_nav)
    imgui.begin("Stats", None, flags)


def _body(info: AppInfo) -> None:
    a = info.avatar
    total = len(a) if a is not None else 0
    imgui.text(f"Gaussians: {total:,} total, {info.gaussians_drawn:,} in front of the camera")
    imgui.text(f"UI: {info.fps:5.1f} fps" + ("   posing..." if info.posing else ""))
    for line in info.frame_profile:
        imgui.text(line)
    imgui.text(f"renderer: {info.renderer_path}")
    extra = ([info.live_counters] if info.live_counters else []) + list(info.compare.overlay if info.compare else ())
    for line in extra:  # the Live Link counters; the Compare panel's view (it replaces the splats) and its scores
        imgui.text(line)
    amber = imgui.ImVec4(1.0, 0.8, 0.3, 1.0)
    if info.canonical:
        imgui.text_colored(amber, "canonical cloud (the first pose is on its way)")
    elif info.preview:
        imgui.text_colored(amber, "preview pose (refining to the exact pose)")
    elif info.baked:
        imgui.text("baked frame" + (" (interpolated)" if info.interpolated else ""))
    status = info.image_status
    line = f"image: {status}, scale {info.draw_scale:.2f}, {info.image_ms:.0f} ms"
    if status == "refining":
        line += f" ({info.draw_progress:.0%} drawn)"
    if info.merged_splats:
        line += f", {info.merged_splats:,} merged Gaussians"
    if info.shown in ("refined", "latent"):  # what replaces the splats of the settled view
        line += ", CNN refined" if info.shown == "refined" else ", latent view"
    elif info.shown == "splats (refining)" and status == "exact":
        line += ", CNN refining"
    if status == "exact":
        imgui.text(line)
    else:
        imgui.text_colored(amber, line)
    es = info.engine_status
    if es.get("device"):
        imgui.text(f"dynamics on {es['device']} ({es.get('kernel', '?')}, {es.get('precision', '?')}), "
                   f"first layer {es.get('first_layer', '?')}")
    if info.avatar is not None and info.avatar.cnn is not None and info.cnn_device:
        imgui.text(f"CNN on {info.cnn_device}")
    for key, label in STAGES:
        if key in info.timings:
            imgui.text(f"{label:>12}: {info.timings[key]:8.1f} ms")
