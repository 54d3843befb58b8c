"""The window's side of editing and keyframes: runs the edit/keyframe actions, turns Ctrl-drags in the
splat view into screen-space selections, highlights selected/hidden/preview Gaussians in what is uploaded, and
keeps the pose worker in step with the edited cloud (the document's `change_cloud`). Each avatar opened gets a new
edit session (it subscribes to `AvatarOpened`).

The pose worker opens the avatar from a file, so after an edit that changes the cloud the controller writes
the edited avatar to a private temp file (35 ms for the demo) and the running worker opens it (`PoseEngine.reopen`;
a new worker only where the edited cloud outgrew the old one's slots, the old one stopping in the background).
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

import numpy as np

from npga_core.editing.edits import EditSession
from npga_core.editing.keyframes import KeyframeTimeline
from npga_core.files.checkpoint import save_avatar
from npga_core.files.places import process_temp_folder
from npga_core.model.gaussians import PosedGaussians, rgb_to_sh0
from npga_view import actions as A
from npga_view.controllers.edit_actions import EDIT_TABLE, KEYFRAME_TABLE, EditView, apply_edit, apply_keyframe
from npga_view.controllers.host import ViewerHost
from npga_view.display import AppInfo
from npga_view.document import AvatarOpened, Subscriptions
from npga_view.imgui_glfw import imgui

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
    """Owned by the app, which registers `handlers()` and calls `mouse`, `after_actions` and `tick` each frame."""

    def __init__(self, app: ViewerHost):
        self.app = app
        self.session: EditSession | None = None
        self.keyframes = KeyframeTimeline()
        self.kf_time = 0.0
        self.kf_playing = False
        self.tool = A.SelectTool("rect")  # the active selection tool, mode and brush radius
        self._drag: list[tuple[float, float]] | None = None
        self._seen = (0, 0)
        self._last_autosave = time.monotonic()
        self._tmp: Path | None = None  # made at the first edit the worker must see
        self._serial = 0

    # -- sessions -----------------------------------------------------------------------------------
    def subscriptions(self) -> Subscriptions:
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._opened)
        return s

    def _opened(self, e: AvatarOpened) -> None:
        self.start(e.avatar, e.avatar.source)

    def start(self, avatar, source: str | None) -> None:
        self.session = EditSession(avatar, source=source)
        self._seen = (self.session.version, self.session.mask_version)

    # -- actions ------------------------------------------------------------------------------------
    def handlers(self) -> A.Handlers:
        """This controller's typed table of action type -> handler: the edit and keyframe tables of
        `edit_actions` bound to the open session / timeline, and the actions that need the window."""
        h = A.Handlers()
        for t in EDIT_TABLE:
            h.register(t, self._edit)
        for t in KEYFRAME_TABLE:
            h.register(t, self._timeline)
        h.register(A.SelectTool, self._select_tool)
        h.register(A.RecoverEdits, self._recover)
        h.register(A.NewKeyframes, self._new_keyframes)
        h.register(A.AddExpressionKey, self._add_expression_key)
        h.register(A.AddCameraKey, self._add_camera_key)
        h.register(A.PlayKeyframes, self._play)
        h.register(A.SeekKeyframes, self._seek)
        h.register(A.LoadKeyframes, self._load_keyframes)
        return h

    def _edit(self, a: A.Action) -> None:
        if self.session is None:
            raise ValueError("open an avatar first")
        app = self.app
        apply_edit(self.session, a, EditView(app.current_camera(), app.doc.shown_means(), app.doc.code))

    def _timeline(self, a: A.Action) -> None:
        apply_keyframe(self.keyframes, a)

    def _select_tool(self, a: A.SelectTool) -> None:
        self.tool = a

    def _recover(self, a: A.RecoverEdits) -> None:
        session = EditSession.recover(a.source)
        self.app.opener.adopt(session.avatar, a.source)
        self.session = session
        self._seen = (-1, -1)  # force a re-sync with the worker

    def _new_keyframes(self, a: A.NewKeyframes) -> None:
        self.keyframes = KeyframeTimeline()
        self.kf_time, self.kf_playing = 0.0, False

    def _add_expression_key(self, a: A.AddExpressionKey) -> None:
        code = self.app.code_for_keyframe(a.source, a.preset)
        self.keyframes.add_expression(a.time, code, interp=a.interp, label=a.preset or a.source)

    def _add_camera_key(self, a: A.AddCameraKey) -> None:
        self.keyframes.add_camera(a.time, self.app.current_camera(ignore_keyframes=True))

    def _play(self, a: A.PlayKeyframes) -> None:
        self.kf_playing = a.playing and not self.keyframes.is_empty()

    def _seek(self, a: A.SeekKeyframes) -> None:
        self.kf_time, self.kf_playing = max(0.0, a.time), False

    def _load_keyframes(self, a: A.LoadKeyframes) -> None:
        loaded = KeyframeTimeline.load(a.path)
        avatar = self.app.doc.avatar
        if avatar is not None:
            loaded.check_code_dim(avatar.code_dim, a.path)
        self.keyframes = loaded
        self.kf_time, self.kf_playing = 0.0, False

    def publish(self, info: AppInfo) -> None:
        """Copy what the Edit and Keyframes panels show into the frame's display snapshot."""
        info.edit, info.keyframes = self.session, self.keyframes
        info.keyframe_time, info.keyframe_playing = self.kf_time, self.kf_playing

    @property
    def dragging(self) -> bool:
        """A selection drag is under way (it owns the mouse, even over the side panel)."""
        return bool(self._drag)

    # -- mouse ------------------------------------------------------------------------------------------
    def mouse(self, view_origin: tuple[float, float], scale: float) -> bool:
        """Ctrl + left drag in the view selects with the active screen tool; True while it owns the mouse."""
        io = imgui.get_io()
        tool = self.tool.tool
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
        mode, send = self.tool.mode, self.app.state.actions.append
        if tool == "rect" and len(pts) >= 2:
            (x0, y0), (x1, y1) = pts[0], pts[-1]
            send(A.SelectRect((x0, y0, x1, y1), mode))
        elif tool == "lasso" and len(pts) >= 3:
            send(A.SelectLasso(tuple(pts), mode))
        elif tool == "brush":
            send(A.SelectBrush(tuple(pts), self.tool.brush_radius * scale, mode))
        return True

    def _draw_outline(self, tool: str) -> None:
        dl = imgui.get_foreground_draw_list()
        col = imgui.get_color_u32(imgui.ImVec4(1.0, 0.6, 0.1, 1.0))
        d = self._drag or []
        if tool == "rect" and len(d) >= 2:
            (x0, y0), (x1, y1) = d[0], d[-1]
            dl.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), col,
                        rounding=0.0, thickness=1.5)
        elif tool == "lasso":
            for a, b in zip(d, d[1:] + d[:1], strict=True):
                dl.add_line(imgui.ImVec2(*a), imgui.ImVec2(*b), col, thickness=1.5)
        elif tool == "brush":
            r = self.tool.brush_radius
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
            kept = s.kept_rows[1] if s.kept_rows is not None and s.kept_rows[0] == self._seen[0] else None
            self._seen = (version, masks)
            self.app.doc.change_cloud(self._write_for_worker(), kept)
        elif masks != self._seen[1]:
            self._seen = (version, masks)
            self.app.screen.reupload()

    def _write_for_worker(self) -> str | None:
        """The edited avatar in a private file for the pose worker (None for static avatars)."""
        assert self.session is not None
        a = self.session.avatar
        if a.dynamics is None:
            return None
        if self._tmp is None:
            self._tmp = process_temp_folder("npga-view-edits")
        self._serial += 1
        path = self._tmp / f"edited-{self._serial}.npga"
        save_avatar(a, path)
        old = self._tmp / f"edited-{self._serial - 2}.npga"  # the worker before last is gone by now
        old.unlink(missing_ok=True)
        return str(path)

    def tick(self, dt: float) -> None:
        """Keyframe playhead and autosave."""
        if self.kf_playing and not self.keyframes.is_empty():
            dur = max(self.keyframes.duration, 1e-6)
            self.kf_time = (self.kf_time + dt) % dur
        s = self.session
        if s is not None and s.dirty and time.monotonic() - self._last_autosave > AUTOSAVE_EVERY_S:
            self._last_autosave = time.monotonic()
            try:
                s.autosave()
            except OSError as e:
                self.app.state.report(f"autosave failed: {e}")

    def close(self) -> None:
        """The window closes: unsaved edits autosaved (a failure said on stderr), the worker's copies removed."""
        s = self.session
        if s is not None and s.dirty:
            try:
                s.autosave()
            except (OSError, ValueError) as e:
                print(f"npga-view: autosave failed: {' '.join(str(e).split())}", file=sys.stderr)
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
