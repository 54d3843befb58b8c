"""The viewer window: input -> ViewerState -> PoseEngine (worker process) -> SplatRenderer -> imgui panels.

The splat image is redrawn only when something it depends on changed (camera, posed cloud, mode, size);
otherwise the last one is composited again, so the UI stays fluid while the avatar is still.
"""

from __future__ import annotations

import ctypes
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from npga_core.camera.orbit import OrbitCamera
from npga_core.errors import AvatarFileError, shown
from npga_core.files.loading import load_avatar, load_sequence
from npga_core.files.rig import fit_camera
from npga_core.files.sequences import ExpressionSequence
from npga_core.inspection.inspector import InspectInfo, Inspector
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.engine import PoseEngine
from npga_core.posing.headpose import has_head_pose, head_transform, posed_camera
from npga_view import panels
from npga_view.controllers.actions import ActionController
from npga_view.controllers.bake import BakeController
from npga_view.controllers.editing import EditController, highlight
from npga_view.controllers.playback import Playback
from npga_view.controllers.posing import PoseController
from npga_view.controllers.recording import Recorder
from npga_view.controllers.refining import RefineController
from npga_view.imgui_glfw import glfw, imgui
from npga_view.panels.files import AVATAR_EXT
from npga_view.panels.info import AppInfo
from npga_view.rendering.factory import create_renderer
from npga_view.rendering.gl import release_current_egl, window_context
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.refinement import Refiner
from npga_view.rendering.renderer import NEAR
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.state import MAX_SLIDERS, ViewerState

SIDE_PANEL = 400  # logical pixels
INSPECT_INFO_LIVE_S = 0.5  # seconds between the Inspect panel's figures while the view changes


class ViewerApp:
    """One window. Use `run()` for the interactive loop or `step()` to drive it frame by frame (tests)."""

    def __init__(self, width: int = 1360, height: int = 900, visible: bool = True, vsync: bool = True,
                 threads: int = 2, remember_recent: bool = True, device: str = "cpu",
                 frame_budget_ms: float | None = 25.0, level_of_detail: bool = True):
        release_current_egl()  # a current headless context of this process would make the window's GLX fail
        if not glfw.init():
            raise RuntimeError("glfw could not initialise (no display? set DISPLAY or use Xvfb)")
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)  # macOS gives core contexts only forward-compatible
        glfw.window_hint(glfw.VISIBLE, visible)
        glfw.window_hint(glfw.SCALE_TO_MONITOR, True)
        self.window = None
        for minor in (3, 1):  # 4.3 core for the compute path, else 4.1 core (macOS) for the 4.1 path (#18)
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, minor)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pyGLFW warns about the refused 4.3 request
                self.window = glfw.create_window(width, height, "npga-view", None, None)
            if self.window:
                break
        if not self.window:
            glfw.terminate()
            raise RuntimeError("could not open an OpenGL 4.3 or 4.1 core window")
        glfw.make_context_current(self.window)
        glfw.swap_interval(1 if vsync else 0)
        glfw.set_drop_callback(self.window, self._on_drop)  # before imgui installs (and chains) its callbacks
        imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)
        ptr = ctypes.cast(self.window, ctypes.c_void_p).value
        imgui.backends.glfw_init_for_opengl(ptr, True)
        imgui.backends.opengl3_init("#version 330")
        self.ctx = window_context()
        self.renderer = create_renderer(self.ctx, 64, 64)  # the 4.3 path, or the 4.1 one (macOS)
        # live images from a merged level-of-detail cloud (a second renderer, merged in a thread); on while
        # state.merged_live (set each frame in _draw_splats)
        self.lod = LiveDetail(lambda: create_renderer(self.ctx, 64, 64), self.renderer)
        # frame-budgeted, adaptive-resolution drawing; frame_budget_ms=None draws every change at once in full
        self.draws = DrawScheduler(self.renderer, budget_ms=frame_budget_ms or 25.0,
                                   enabled=frame_budget_ms is not None, lod=self.lod)
        self.content_version = 0  # incremented whenever the cloud on screen (or how it is coloured) changes
        # frame_budget_ms=None is the behaviour before budgeting (benchmarks compare both): every change drawn
        # at once in full, a blank view until the first pose, exact poses only in playback
        self.legacy = frame_budget_ms is None
        self.idle_wait_s = 0.0 if self.legacy else 1.0 / 30.0  # see step(); the legacy loop spins as before
        self._was_quiet = False
        self.state = ViewerState()
        self.state.merged_live = level_of_detail
        self.info = AppInfo(renderer_path=self.renderer.path)
        # the screen-space CNN (on the dynamics' GPU when one is asked for) and latent views, on settled images
        cnn_device = device if device.startswith("cuda") else "cpu"
        self.refining = RefineController(Refiner(self.ctx, cnn_device), self.renderer, self.draws, self.state,
                                         self.info)
        self.threads = threads
        self.device = device  # where the worker runs the dynamics ("cpu", "cuda", "mps", "auto")
        self.remember_recent = remember_recent
        if remember_recent:
            self.state.load_recent()
        self.avatar: Avatar | None = None
        self.engine: PoseEngine | None = None
        self.sequence: ExpressionSequence | None = None
        self.playback: Playback | None = None
        self._colouring = None  # legend of the current Inspect colour mode
        self._inspect_info_due = False
        self._inspect_info_t = -math.inf  # when the Inspect panel's figures were last computed
        self._last_t = time.perf_counter()
        self._fps_t: list[float] = []
        self.frames = 0
        self.should_close = False
        self._posed: PosedGaussians | None = None  # a copy of the cloud on screen (before highlighting)
        self.edits = EditController(self, self.code_for_keyframe)
        self.poses = PoseController(self, bake_usable=lambda: self.bakes.usable(),
                                    keyframe_code=self.edits.keyframe_code, playback_previews=not self.legacy)
        self.bakes = BakeController(self.state, lambda: self.engine, self.poses.sequence_codes, self.poses.bake_key)
        self.recorder = Recorder(lambda: self.read_window(viewport_only=True))
        self.actions = ActionController(self, self.poses, self.bakes, self._toggle_recording)
        self.actions.load_presets()
        self.inspector: Inspector | None = None
        self._inspect_key: tuple | None = None
        self._click_pos: tuple[float, float] | None = None
        self.info.keyframes = self.edits.keyframes

    # ------------------------------------------------------------------------------------------ files
    def open_avatar(self, path: str) -> bool:
        """Load an avatar (errors go to the UI); starts the pose worker for animatable ones."""
        try:
            avatar = load_avatar(path)
        except AvatarFileError as e:
            self.state.report(str(e))
            return False
        self.adopt_avatar(avatar, path)
        self.edits.start(avatar, avatar.source)
        self._add_recent(path)
        glfw.set_window_title(self.window, f"npga-view - {shown(Path(path).name)}")
        return True

    def adopt_avatar(self, avatar: Avatar, path: str) -> None:
        """Show `avatar` (loaded from `path`): worker, sliders, camera; sequences that no longer fit close."""
        if self.engine is not None:
            self.engine.close()
            self.engine = None
        self.avatar = avatar
        self.info.avatar = avatar
        self.state.avatar_path = path if path == "demo" else str(Path(path).resolve())
        ex = avatar.expression
        k = ex.n_components if ex is not None else 0
        self.state.sliders = np.zeros(k, np.float32)
        if ex is not None and "neutral" in ex.named:  # open at the avatar's neutral face, not the mean code
            self.state.sliders = ex.to_sliders(ex.named["neutral"]).astype(np.float32)
        self.state.n_sliders = min(max(self.state.n_sliders, 1), max(1, min(k, MAX_SLIDERS)))
        self._posed = None
        self.poses.reset()
        self.inspector = Inspector(avatar)
        self.refining.set_avatar(avatar)
        self.lod.reset()
        self.state.inspect.picked = None
        self.poses.first_pose_shown = False
        if avatar.dynamics is not None and avatar.source:
            self._start_engine(avatar.source)
            # first pixels at once: the canonical cloud, labelled, until the worker's first pose arrives
            if not self.legacy:
                self.info.canonical = True
                self.show(avatar.cloud.posed_static())
        else:
            self.show(avatar.pose())
            self.poses.first_pose_shown = True
        if self.sequence is not None and self.sequence.dim != avatar.code_dim:
            self.state.report(f"{self.state.sequence_path}: codes have {self.sequence.dim} dims, the avatar expects "
                              f"{avatar.code_dim}; sequence closed")
            self._close_sequence()
        self.frame_avatar(reset=True)

    def _start_engine(self, path: str) -> None:
        if self.engine is not None:
            self.engine.close()
        a = self.avatar
        self.engine = PoseEngine(path, len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=self.threads,
                                 device=self.device)
        self.bakes.forget()
        self.poses.engine_restarted()

    def show(self, posed: PosedGaussians) -> None:
        """Keep `posed` as the cloud on screen; upload it as the Inspect settings colour it, with the edit
        highlights on top."""
        self._posed = posed
        settings, session = self.state.inspect, self.edits.session
        selection = session.selection if session is not None and len(session) == len(posed) else None
        self._inspect_key = (settings.key(), self._inspect_camera_key())
        frame = None
        if self.inspector is not None and len(posed) == len(self.avatar):
            try:
                frame = self.inspector.frame(settings, posed, self.poses.shown_code, self.current_camera(), selection)
            except ValueError as e:
                self.info.inspect = self.info.inspect or InspectInfo()
                self.info.inspect.error = str(e)
        if frame is None:
            uploaded = highlight(posed, session)
            self.renderer.set_gaussians(uploaded)
            self.renderer.clear_lines()
            self._colouring = None
        else:
            uploaded = frame.posed = highlight(frame.posed, session)
            self.renderer.show(frame)
            self._colouring = frame.colouring
        self.content_version += 1
        self.lod.submit(self.content_version, uploaded)
        self._inspect_info_due = True

    def _inspect_camera_key(self) -> tuple | None:
        if self.inspector is None or not Inspector.camera_dependent(self.state.inspect):
            return None
        return (self.current_camera().world_to_camera.tobytes(),)

    def _refresh_inspect(self) -> None:
        """Rebuild the frame when the Inspect settings (or, for depth colouring, the camera) changed."""
        if self._posed is not None and (self.state.inspect.key(), self._inspect_camera_key()) != self._inspect_key:
            self.show(self._posed)

    def reupload(self) -> None:
        """Upload the cloud on screen again (after a selection, hide or preview change)."""
        if self._posed is not None:
            self.show(self._posed)

    def cloud_changed(self, worker_path: str | None) -> None:
        """The canonical cloud was edited: re-pose it (in the worker, from `worker_path`, if animatable)."""
        self.inspector = Inspector(self.avatar)
        self.refining.set_avatar(self.avatar)
        self.lod.reset()
        if self.state.inspect.picked is not None and self.state.inspect.picked >= len(self.avatar):
            self.state.inspect.picked = None
        if worker_path is None:
            self.show(self.avatar.pose())
        else:
            self._start_engine(worker_path)

    def shown_posed(self) -> PosedGaussians | None:
        """The posed cloud on screen, before highlighting (None until the first pose)."""
        return self._posed

    @property
    def first_pose_shown(self) -> bool:
        """True once a pose of the open avatar has been drawn."""
        return self.poses.first_pose_shown

    def shown_means(self) -> np.ndarray:
        """Centres of the Gaussians on screen (canonical ones until the first pose, or after a deletion)."""
        if self._posed is not None and self.avatar is not None and len(self._posed) == len(self.avatar):
            return self._posed.means
        return np.asarray(self.avatar.cloud.means)

    def shown_code(self) -> np.ndarray | None:
        code = self.poses.shown_code
        return None if code is None else code.copy()

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        """The code a new expression keyframe takes: from the sliders, the sequence frame or a preset."""
        ex = self.avatar.expression if self.avatar is not None else None
        if ex is None:
            raise ValueError("this avatar has no expression space")
        if source == "frame":
            if self.poses.codes is None:
                raise ValueError("no sequence frame: open a sequence first")
            return self.poses.codes[self.info.frame].copy()
        if source == "preset":
            if preset in ex.named:
                return ex.named[preset].copy()
            if preset in self.state.presets:
                return np.asarray(self.state.presets[preset], np.float32)
            raise ValueError(f"no preset named {preset!r}")
        return self.poses.slider_code()

    def open_sequence(self, path: str) -> bool:
        """Load a sequence; refused (with both dimensions) if it does not fit the avatar."""
        try:
            seq = load_sequence(path)
            if self.avatar is None or self.avatar.code_dim == 0:
                raise AvatarFileError(path, "open an animatable avatar first (this one has no dynamics)")
            seq.check_dim(self.avatar.code_dim, path)
        except AvatarFileError as e:
            self.state.report(str(e))
            return False
        self.sequence = seq
        self.info.sequence = seq
        self.playback = Playback(len(seq), seq.fps)
        self.state.sequence_path = str(Path(path).resolve())
        self.state.timeline.time_s = 0.0
        self.state.follow_sequence = True
        self.poses.sequence_closed()
        self._add_recent(path)
        return True

    def _close_sequence(self) -> None:
        self.sequence = self.playback = None
        self.poses.sequence_closed()
        self.info.sequence = None
        self.state.sequence_path = None

    def _add_recent(self, path: str) -> None:
        self.state.add_recent(path)
        if self.remember_recent:
            self.state.save_recent()

    def _on_drop(self, window, paths) -> None:
        for p in paths:
            is_avatar = Path(p).suffix.lower() in AVATAR_EXT and Path(p).is_file()
            self.state.actions.append(("open_avatar" if is_avatar else "open_sequence", p))

    # ----------------------------------------------------------------------------------------- camera
    def frame_avatar(self, reset: bool = False) -> None:
        if self.avatar is None or len(self.avatar) == 0:
            return
        cam = self.state.camera
        if reset:
            self.state.camera = cam = OrbitCamera(fov_y=cam.fov_y or 20.0)
        w, h = self._viewport()[2:]
        cam.frame(np.asarray(self.avatar.cloud.means), aspect=w / max(h, 1))

    def _viewport(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the splat view in framebuffer pixels (right of the side panel)."""
        fw, fh = glfw.get_framebuffer_size(self.window)
        ww, _ = glfw.get_window_size(self.window)
        scale = fw / max(ww, 1)
        side = min(int(SIDE_PANEL * scale), fw - 16)
        return side, 0, max(1, fw - side), max(1, fh)

    def current_camera(self, ignore_keyframes: bool = False):
        """The splat view's camera: keyframed, a rig camera or the orbit camera, moved by the sequence's head
        pose (of the frame on screen) while it is followed."""
        x, y, w, h = self._viewport()
        kf = self.edits
        rig = self.state.rig_index >= 0 and bool(self.actions.rig)
        if not ignore_keyframes and kf.kf_playing and kf.keyframes.camera:
            cam = kf.keyframes.camera_at(kf.kf_time, w, h)
        elif rig:
            names = list(self.actions.rig)
            cam = fit_camera(self.actions.rig[names[self.state.rig_index % len(names)]], w, h)
        else:
            cam = self.state.camera.camera(w, h)
        seq = self.sequence
        if seq is not None and self.state.follow_sequence and self.state.timeline.head_pose and has_head_pose(seq):
            shown = self.poses.shown_frame
            frame = shown if shown is not None else self.info.frame
            cam = posed_camera(cam, head_transform(seq, frame, relative=not rig))
        return cam

    def _mouse(self) -> None:
        io = imgui.get_io()
        if io.want_capture_mouse:
            return
        fw, _ = glfw.get_framebuffer_size(self.window)
        ww, _ = glfw.get_window_size(self.window)
        scale = fw / max(ww, 1)
        x0 = self._viewport()[0] / scale
        if io.mouse_pos.x < x0 and not self.edits._drag:
            return
        if self.edits.mouse((x0, 0.0), scale):
            return
        if self.state.inspect.pick_on_click:
            if imgui.is_mouse_clicked(0):
                self._click_pos = (io.mouse_pos.x, io.mouse_pos.y)
            elif imgui.is_mouse_released(0) and self._click_pos is not None:
                cx, cy = self._click_pos
                self._click_pos = None
                if abs(io.mouse_pos.x - cx) + abs(io.mouse_pos.y - cy) < 4:
                    self.pick((cx - x0) * scale, cy * scale)
        cam = self.state.camera
        d = io.mouse_delta
        if (d.x or d.y) and self.state.rig_index < 0:
            if imgui.is_mouse_down(0) and io.key_shift:
                cam.roll += d.x * 0.3
            elif imgui.is_mouse_down(0):
                cam.orbit(-d.x * 0.3, d.y * 0.3)
            elif imgui.is_mouse_down(1) or imgui.is_mouse_down(2):
                cam.pan(d.x * scale, d.y * scale, self._viewport()[3])
        if io.mouse_wheel:
            cam.zoom(io.mouse_wheel)

    def _keys(self) -> None:
        io = imgui.get_io()
        if io.want_capture_keyboard:
            return
        cam = self.state.camera
        k = imgui.Key
        pressed = imgui.is_key_pressed
        acts = self.state.actions
        if io.key_ctrl:
            if pressed(k.z):
                acts.append(("edit_redo" if io.key_shift else "edit_undo", None))
            if pressed(k.a):
                acts.append(("select_all", None))
            if pressed(k.i):
                acts.append(("select_invert", None))
            return
        if pressed(k.delete) or pressed(k.backspace):
            acts.append(("edit_delete", None))
        if pressed(k.escape):
            acts.append(("select_clear", None))
        if pressed(k.h):
            acts.append(("edit_show_all", None) if io.key_alt else ("edit_hide", None))
        if pressed(k.left_arrow):
            cam.orbit(-10, 0)
        if pressed(k.right_arrow):
            cam.orbit(10, 0)
        if pressed(k.up_arrow):
            cam.orbit(0, 10)
        if pressed(k.down_arrow):
            cam.orbit(0, -10)
        if pressed(k.equal) or pressed(k.keypad_add):
            cam.zoom(1)
        if pressed(k.minus) or pressed(k.keypad_subtract):
            cam.zoom(-1)
        if pressed(k.q):
            cam.roll -= 5
        if pressed(k.e):
            cam.roll += 5
        if pressed(k.f):
            self.frame_avatar()
        if pressed(k.r):
            self.frame_avatar(reset=True)
        for key, name in ((k._1, "front"), (k._2, "three_quarter"), (k._3, "side"), (k._4, "top")):
            if pressed(key):
                cam.preset(name)
        if pressed(k.space) and self.sequence is not None:
            self.state.timeline.playing = not self.state.timeline.playing
            self.state.follow_sequence = True
        if pressed(k.comma):
            self.state.actions.append(("step", -1))
        if pressed(k.period):
            self.state.actions.append(("step", 1))
        if pressed(k.p):
            self.state.actions.append(("screenshot", None))
        rig = self.actions.rig
        if rig and (pressed(k.left_bracket) or pressed(k.right_bracket)):
            step = 1 if pressed(k.right_bracket) else -1
            self.state.rig_index = (self.state.rig_index + step) % len(rig)

    # ---------------------------------------------------------------------------------------- actions
    def _run_actions(self) -> None:
        actions, self.state.actions = self.state.actions, []
        for name, arg in actions:
            try:
                if not self.edits.handle(name, arg):
                    self.actions.run(name, arg)
            except (AvatarFileError, ValueError, OSError) as e:
                self.state.report(str(e))

    # --------------------------------------------------------------------------------------- drawing
    def pick(self, x: float, y: float) -> int | None:
        """Pick the Gaussian at view pixel (x, y) (top-left origin) for the inspector."""
        idx = self.renderer.pick(self.current_camera(), x, y)
        self.state.inspect.picked = idx
        self._inspect_info_due = True
        return idx

    @property
    def _dirty(self) -> bool:
        """The current view is not yet on screen at full resolution (an image is pending or being drawn)."""
        return not self.draws.settled

    def _input_active(self) -> bool:
        """A drag or a held widget, or playback (of a sequence or of keyframes)."""
        io = imgui.get_io()
        dragging = not io.want_capture_mouse and any(imgui.is_mouse_down(b) for b in range(3))
        playing = self.sequence is not None and self.state.follow_sequence and self.state.timeline.playing
        return dragging or imgui.is_any_item_active() or playing or self.edits.kf_playing

    def _interacting(self) -> bool:
        """The view is changing now: a drag or slider, playback, or a pose that will be replaced (a preview
        or the canonical cloud before the first pose). Draws at the live scale meanwhile."""
        return self._input_active() or self.info.preview or self.info.canonical

    def _draw_splats(self) -> None:
        cam = self.current_camera()
        info = self.info
        self.lod.enabled = self.state.merged_live and not self.legacy
        if self.lod.error:  # a merge failed: say so and draw every Gaussian from now on
            self.state.report(self.lod.error)
            self.lod.error, self.state.merged_live = None, False
        exact = not (info.preview or info.canonical or info.interpolated)
        interacting = self._interacting()
        if self.draws.frame(cam, self.state.mode, self.content_version, interacting, exact_content=exact):
            t = self.draws.shown_renderer.last_timings
            info.timings.update({k: t[k] for k in ("sort", "upload", "preprocess", "draw") if k in t})
            info.merged_splats = self.draws.shown_merged
            if not info.merged_splats:  # (a merged cloud's count is not the number of the avatar's in view)
                info.gaussians_drawn = int(t.get("visible", 0))
            self._inspect_info_due = True
            self.poses.presented(self.draws.shown_version)
        info.draw_scale, info.image_status = self.draws.scale, self.draws.status
        info.image_ms, info.draw_progress = self.draws.last_image_ms, self.draws.progress
        now = time.perf_counter()
        # the Inspect panel's counts and histograms (~25 ms for the demo): at most twice a second while the view
        # changes (playback brings a pose every frame), at once when it has settled
        throttled = interacting and now - self._inspect_info_t < INSPECT_INFO_LIVE_S
        if self._inspect_info_due and not throttled and self.inspector is not None and self._posed is not None \
                and len(self._posed) == len(self.avatar):
            self._inspect_info_due = False
            self._inspect_info_t = now
            err = self.info.inspect.error if self.info.inspect is not None else None
            self.info.inspect = self.inspector.info(self.state.inspect, self._posed, self.poses.shown_code,
                                                    self._colouring, cam, self.renderer.drawn_mask(), NEAR)
            self.info.inspect.error = self.info.inspect.error or err
        x, y, w, h = self._viewport()
        if self.refining.present(cam, self.ctx.screen, (x, y, w, h)):
            return
        bg = self.state.background if self.state.mode == "rgb" else (0.0, 0.0, 0.0)
        self.draws.present(self.ctx.screen, bg, flip_y=True, viewport=(x, y, w, h))

    def _draw_ui(self) -> None:
        fw, fh = glfw.get_window_size(self.window)
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(SIDE_PANEL, fh))
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("npga-view", None, flags)
        if self.state.errors:
            for msg in self.state.errors:
                imgui.text_colored(imgui.ImVec4(1.0, 0.45, 0.4, 1.0), "")
                imgui.same_line()
                imgui.push_text_wrap_pos(0)
                imgui.text_colored(imgui.ImVec4(1.0, 0.45, 0.4, 1.0), msg)
                imgui.pop_text_wrap_pos()
            if imgui.button("Dismiss"):
                self.state.errors = []
            imgui.separator()
        for panel in panels.SIDE:
            panel.draw(self.state, self.info)
        imgui.end()

    def _quiet(self) -> bool:
        """Nothing to draw in this window until something arrives: the view's image is on screen and nothing is
        being drawn or refined, no input held, no playback, recording or queued action (a pose may be on its way
        from the worker)."""
        return (self.draws.idle and self.refining.complete and not self._input_active()
                and not self.state.actions and not self.recorder.recording)

    def step(self) -> None:
        """One frame: input, panels, actions, dynamics, splats, UI. After a quiet frame the next one waits for
        input for up to `idle_wait_s` (worker results and threads are picked up at that rate) instead of
        spinning: an idle window on llvmpipe otherwise redraws ~80 times a second on the cores the pose worker
        and the CNN need."""
        if self._was_quiet and self.idle_wait_s > 0:
            glfw.wait_events_timeout(self.idle_wait_s)
        else:
            glfw.poll_events()
        now = time.perf_counter()
        dt, self._last_t = now - self._last_t, now
        self._fps_t = [t for t in self._fps_t if now - t < 1.0] + [now]
        self.info.fps = len(self._fps_t) / max(1e-6, now - self._fps_t[0]) if len(self._fps_t) > 1 else 0.0
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()
        self._mouse()
        self._keys()
        self._draw_ui()
        self._run_actions()
        self.edits.after_actions()
        self.edits.tick(dt)
        self.poses.update(dt)
        self.info.bake, self.info.bake_state = self.bakes.status, self.bakes.state()
        self._refresh_inspect()
        self.ctx.screen.use()
        fw, fh = glfw.get_framebuffer_size(self.window)
        self.ctx.viewport = (0, 0, fw, fh)
        self.ctx.clear(0.08, 0.08, 0.09, 1.0)
        self._draw_splats()
        if self.state.show_stats:
            for panel in panels.OVERLAYS:  # after drawing, so that they report this frame's image
                panel.draw(self.state, self.info)
        self.recorder.frame()
        imgui.render()
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
        glfw.swap_buffers(self.window)
        self.frames += 1
        self._was_quiet = self._quiet()
        if glfw.window_should_close(self.window):
            self.should_close = True

    # ------------------------------------------------------------------------------------ snapshots
    def read_window(self, viewport_only: bool = False) -> np.ndarray:
        """RGB uint8 pixels of the back buffer as last drawn (top row first)."""
        fw, fh = glfw.get_framebuffer_size(self.window)
        vp = self._viewport() if viewport_only else (0, 0, fw, fh)
        data = self.ctx.screen.read(viewport=vp, components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(vp[3], vp[2], 3)[::-1].copy()

    def screenshot(self, path: str, viewport_only: bool = False) -> str:
        """Save the window (panels included) or only the splat view as PNG."""
        import cv2

        img = self.read_window(viewport_only)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), img[:, :, ::-1]):
            raise OSError(f"{path}: could not write the PNG")
        self.info.last_screenshot = str(path)
        return str(path)

    def load_session(self, path: str) -> None:
        """Restore camera, sliders, modes and open files from a session file."""
        self.actions.load_session(path)

    def _toggle_recording(self) -> None:
        try:
            self.info.recording = self.recorder.toggle(self._viewport()[2:])
        except (OSError, ValueError) as e:
            self.info.recording = False
            self.state.report(f"Record MP4: {e}")
        if self.recorder.error:
            self.state.report(f"Record MP4: {self.recorder.error}")
            self.recorder.error = None
        self.record_path = self.recorder.path

    # ------------------------------------------------------------------------------------------ loop
    def run(self, screenshot: str | None = None, quit_after_frames: int | None = None) -> int:
        """The interactive loop. With `quit_after_frames`, count frames from the first drawn pose."""
        counted = 0
        try:
            while not self.should_close:
                self.step()
                if quit_after_frames is not None and (self.poses.first_pose_shown or self.avatar is None) \
                        and self.draws.settled and self.refining.complete:
                    counted += 1
                    if counted >= quit_after_frames:
                        if screenshot:
                            self.screenshot(screenshot)
                        break
        finally:
            self.close()
        return 0

    def request_close(self, signum: int | None = None) -> None:
        """Close at the end of the current frame, as the window's close button does (SIGTERM/SIGINT/SIGHUP)."""
        self.should_close = True

    def close(self) -> None:
        """Unsaved edits autosaved, recording stopped, worker stopped (its shared memory unlinked), window
        closed. The path of a window close and of the close signals; safe to call twice."""
        self.recorder.stop()
        session = self.edits.session
        if session is not None and session.dirty:
            try:
                session.autosave()
            except (OSError, ValueError) as e:
                print(f"npga-view: autosave failed: {' '.join(str(e).split())}", file=sys.stderr)
        if self.engine is not None:
            self.engine.close()
            self.engine = None
        self.edits.close()
        if self.window is not None:
            self.lod.close()
            self.refining.release()
            imgui.backends.opengl3_shutdown()
            imgui.backends.glfw_shutdown()
            imgui.destroy_context()
            glfw.destroy_window(self.window)
            self.window = None
            glfw.terminate()
