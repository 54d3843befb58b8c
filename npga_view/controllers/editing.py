"""The window's side of editing and keyframes: runs the edit/keyframe panels' actions, turns Ctrl-drags in the
splat view into screen-space selections, highlights selected/hidden/preview Gaussians in what is uploaded, and
keeps the pose worker in step with the edited cloud.

The pose worker opens the avatar from a file, so after an edit that changes the cloud the controller writes
the edited avatar to a private temp file and restarts the worker on it (about a second for the demo).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from npga_core.editing.edits import EditSession
from npga_core.editing.keyframes import KeyframeTimeline
from npga_core.files.checkpoint import save_avatar
from npga_core.model.gaussians import PosedGaussians, rgb_to_sh0
from npga_view.controllers.host import ViewerHost
from npga_view.imgui_glfw import imgui
from npga_view.panels import edit as edit_panel
from npga_view.panels import keyframes as keyframe_panel

SELECT_RGB = (1.0, 0.55, 0.1)  # orange: selected
PREVIEW_RGB = (1.0, 0.1, 0.1)  # red: would be removed
AUTOSAVE_EVERY_S = 60.0
SCREEN_TOOLS = ("rect", "lasso", "brush")


def highlight(posed: PosedGaussians, session: EditSession | None) -> PosedGaussians:
    """What to upload: hidden Gaussians get opacity 0, selected ones turn orange, previewed ones red."""
    if session is None or len(session) != len(posed):
        return posed
    sel, hid, pre = session.selection, session.hidden, session.preview
    if not (sel.any() or hid.any() or (pre is not None and pre.any())):
        return posed
    out = PosedGaussians(posed.means, posed.quats, posed.scales, posed.opacities, posed.sh, posed.latent)
    if hid.any():
        out.opacities = np.where(hid, 0.0, posed.opacities).astype(np.float32)
    marks = [(sel, SELECT_RGB)] + ([(pre, PREVIEW_RGB)] if pre is not None else [])
    if any(m.any() for m, _ in marks):
        out.sh = posed.sh.copy()
        for mask, rgb in marks:
            if mask.any():
                out.sh[mask, 0] = 0.4 * out.sh[mask, 0] + 0.6 * rgb_to_sh0(np.array(rgb, np.float32))
                out.sh[mask, 1:] *= 0.4
    return out


class EditController:
    """Owned by the app; the app calls `handle`, `mouse`, `after_actions` and `tick` each frame."""

    def __init__(self, app: ViewerHost, code_for_keyframe):
        self.app = app
        self._code_for_keyframe = code_for_keyframe  # (source, preset) -> code of a new expression key
        self.session: EditSession | None = None
        self.keyframes = KeyframeTimeline()
        self.kf_time = 0.0
        self.kf_playing = False
        self.tool = {"tool": "rect", "mode": "replace", "brush_radius": 20.0}
        self._drag: list[tuple[float, float]] | None = None
        self._seen = (0, 0)
        self._last_autosave = time.monotonic()
        self._tmp = Path(tempfile.mkdtemp(prefix="npga-view-edits-"))
        self._serial = 0

    # -- sessions -----------------------------------------------------------------------------------
    def start(self, avatar, source: str | None) -> None:
        self.session = EditSession(avatar, source=source)
        self._seen = (self.session.version, self.session.mask_version)
        self.app.info.edit = self.session

    # -- actions ------------------------------------------------------------------------------------
    def handle(self, name: str, arg) -> bool:
        """Run an edit or keyframe action; False if `name` belongs to neither panel."""
        app, s = self.app, self.session
        if name == "select_tool":
            self.tool = dict(arg)
            return True
        if name == "edit_recover":
            session = EditSession.recover(arg)
            app.adopt_avatar(session.avatar, str(arg))
            self.session = session
            app.info.edit = session
            self._seen = (-1, -1)  # force a re-sync with the worker
            return True
        if name.startswith(("select_", "edit_")):
            if s is None:
                raise ValueError("open an avatar first")
            means = app.shown_means()
            return edit_panel.apply(s, name, arg, camera=app.current_camera(), means=means, code=app.shown_code())
        if name.startswith("kf_"):
            return self._keyframe(name, arg)
        return False

    def _keyframe(self, name: str, arg) -> bool:
        app, tl = self.app, self.keyframes
        if keyframe_panel.apply(tl, name, arg):
            return True
        if name == "kf_new":
            self.keyframes = KeyframeTimeline()
            self.kf_time, self.kf_playing = 0.0, False
        elif name == "kf_add_expression":
            code = self._code_for_keyframe(arg.get("source", "sliders"), arg.get("preset"))
            tl.add_expression(float(arg["time"]), code, interp=arg.get("interp", "smooth"),
                              label=arg.get("preset") or arg.get("source", ""))
        elif name == "kf_add_camera":
            tl.add_camera(float(arg["time"]), app.current_camera(ignore_keyframes=True))
        elif name == "kf_play":
            self.kf_playing = bool(arg) and not tl.is_empty
        elif name == "kf_seek":
            self.kf_time, self.kf_playing = max(0.0, float(arg)), False
        elif name == "kf_load":
            loaded = KeyframeTimeline.load(arg)
            if app.avatar is not None:
                loaded.check_code_dim(app.avatar.code_dim, arg)
            self.keyframes = loaded
            self.kf_time, self.kf_playing = 0.0, False
        else:
            return False
        app.info.keyframes = self.keyframes
        return True

    # -- mouse ------------------------------------------------------------------------------------------
    def mouse(self, view_origin: tuple[float, float], scale: float) -> bool:
        """Ctrl + left drag in the view selects with the active screen tool; True while it owns the mouse."""
        io = imgui.get_io()
        tool = self.tool.get("tool")
        if self.session is None or tool not in SCREEN_TOOLS:
            self._drag = None
            return False
        pos = (io.mouse_pos.x, io.mouse_pos.y)
        if self._drag is None:
            if io.key_ctrl and imgui.is_mouse_clicked(0):
                self._drag = [pos]
                return True
            return False
        if imgui.is_mouse_down(0):
            if tool != "rect" and pos != self._drag[-1]:
                self._drag.append(pos)
            elif tool == "rect":
                self._drag[1:] = [pos]
            self._draw_outline(tool)
            return True
        # released: convert window points (logical px) to view-camera pixels
        pts = [((x - view_origin[0]) * scale, (y - view_origin[1]) * scale) for x, y in self._drag]
        self._drag = None
        mode = self.tool.get("mode", "replace")
        if tool == "rect" and len(pts) >= 2:
            (x0, y0), (x1, y1) = pts[0], pts[-1]
            self.app.state.actions.append(("select_rect", {"rect": (x0, y0, x1, y1), "mode": mode}))
        elif tool == "lasso" and len(pts) >= 3:
            self.app.state.actions.append(("select_lasso", {"polygon": pts, "mode": mode}))
        elif tool == "brush":
            radius = float(self.tool.get("brush_radius", 20.0)) * scale
            self.app.state.actions.append(("select_brush", {"centres": pts, "radius": radius, "mode": mode}))
        return True

    def _draw_outline(self, tool: str) -> None:
        dl = imgui.get_foreground_draw_list()
        col = imgui.get_color_u32(imgui.ImVec4(1.0, 0.6, 0.1, 1.0))
        d = self._drag
        if tool == "rect" and len(d) >= 2:
            (x0, y0), (x1, y1) = d[0], d[-1]
            dl.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), col,
                        rounding=0.0, thickness=1.5)
        elif tool == "lasso":
            for a, b in zip(d, d[1:] + d[:1], strict=True):
                dl.add_line(imgui.ImVec2(*a), imgui.ImVec2(*b), col, thickness=1.5)
        elif tool == "brush":
            r = float(self.tool.get("brush_radius", 20.0))
            for p in d[-1:]:
                dl.add_circle(imgui.ImVec2(*p), r, col, num_segments=0, thickness=1.5)

    def keyframe_code(self):
        """The keyframed expression while keyframes with expression keys play, else None."""
        if self.kf_playing and self.keyframes.expression:
            return self.keyframes.code_at(self.kf_time)
        return None

    # -- per frame ------------------------------------------------------------------------------------
    def after_actions(self) -> None:
        """React to edits: re-pose after cloud changes, re-highlight after mask changes."""
        s = self.session
        if s is None:
            return
        version, masks = s.version, s.mask_version
        if version != self._seen[0]:
            self._seen = (version, masks)
            self.app.cloud_changed(self._write_for_worker())
        elif masks != self._seen[1]:
            self._seen = (version, masks)
            self.app.reupload()

    def _write_for_worker(self) -> str | None:
        """The edited avatar in a private file for the pose worker (None for static avatars)."""
        a = self.session.avatar
        if a.dynamics is None:
            return None
        self._serial += 1
        path = self._tmp / f"edited-{self._serial}.npga"
        save_avatar(a, path)
        old = self._tmp / f"edited-{self._serial - 2}.npga"  # the worker before last is gone by now
        old.unlink(missing_ok=True)
        return str(path)

    def tick(self, dt: float) -> None:
        """Keyframe playhead and autosave."""
        if self.kf_playing and not self.keyframes.is_empty:
            dur = max(self.keyframes.duration, 1e-6)
            self.kf_time = (self.kf_time + dt) % dur
        info = self.app.info
        info.keyframe_time, info.keyframe_playing = self.kf_time, self.kf_playing
        s = self.session
        if s is not None and s.dirty and time.monotonic() - self._last_autosave > AUTOSAVE_EVERY_S:
            self._last_autosave = time.monotonic()
            try:
                s.autosave()
            except OSError as e:
                self.app.state.report(f"autosave failed: {e}")

    def close(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
