"""The viewer window: input -> ViewerState -> PoseEngine (worker process) -> SplatRenderer -> imgui panels.

`ViewerApp` builds the parts in dependency order and runs one frame in `step()`; each part reads alone:
the window and its frame loop (window.py), which camera the view shows (view_camera.py), opening files
(opening.py), the Inspect panel's cache (inspection_cache.py), the controllers that carry out actions
(controllers/), the panels (panels/). The splat image is redrawn only when something it depends on changed
(camera, posed cloud, mode, size); otherwise the last one is composited again, so the UI stays fluid while
the avatar is still.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.device import resolve_device
from npga_core.posing.engine import PoseEngine
from npga_view import opening
from npga_view.actions import Dispatcher
from npga_view.comparison.controller import CompareController
from npga_view.controllers.actions import ActionController
from npga_view.controllers.bake import BakeController
from npga_view.controllers.editing import EditController, highlight
from npga_view.controllers.live_link import LiveLinkController
from npga_view.controllers.posing import PoseController
from npga_view.controllers.recording import Recorder
from npga_view.controllers.refining import RefineController
from npga_view.controllers.sequence_codes import SequenceCodes
from npga_view.frame_profile import FrameProfile
from npga_view.imgui_glfw import glfw, imgui
from npga_view.inspection_cache import InspectionCache
from npga_view.panels import Panels
from npga_view.panels.files import FilesPanel, open_action
from npga_view.panels.info import AppInfo
from npga_view.rendering.factory import create_renderer
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.refinement import Refiner
from npga_view.rendering.renderer import NEAR
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.state import ViewerState
from npga_view.view_camera import ViewCamera
from npga_view.view_input import ViewInput
from npga_view.window import SIDE_PANEL, Window

#: a frame is drawn at least this often even when it would be the one on screen (a safety net)
PRESENT_AT_LEAST_S = 0.25

class ViewerApp:
    """One window. Use `run()` for the interactive loop or `step()` to drive it frame by frame (tests)."""

    def __init__(self, width: int = 1360, height: int = 900, visible: bool = True, vsync: bool = True,
                 threads: int = 2, remember_recent: bool = True, device: str = "cpu",
                 frame_budget_ms: float | None = 25.0, level_of_detail: bool = True,
                 unbudgeted: type[DrawScheduler] | None = None, precision: str = "auto"):
        self.window: Window | None = Window(width, height, visible, vsync, on_drop=self._on_drop)
        self.ctx = self.window.ctx
        self.renderer = create_renderer(self.ctx, 64, 64)  # the 4.3 path, or the 4.1 one (macOS)
        # live images from a merged level-of-detail cloud (a second renderer, merged in a thread); on while
        # state.merged_live (set each frame in _draw_splats)
        self.lod = LiveDetail(lambda: create_renderer(self.ctx, 64, 64), self.renderer)
        # frame-budgeted, adaptive-resolution drawing; frame_budget_ms=None is the benchmark's comparison: every
        # change drawn at once in full by its `unbudgeted` scheduler (npga_view/benchmarks/bench_window.py)
        if frame_budget_ms is None and unbudgeted is None:
            raise ValueError("frame_budget_ms=None needs the unbudgeted scheduler of the window benchmark")
        scheduler: type[DrawScheduler] = DrawScheduler if unbudgeted is None or frame_budget_ms is not None \
            else unbudgeted
        self.draws = scheduler(self.renderer, budget_ms=frame_budget_ms or 25.0, lod=self.lod)
        self.content_version = 0  # incremented whenever the cloud on screen (or how it is coloured) changes
        # frame_budget_ms=None is the behaviour before budgeting (benchmarks compare both): every change drawn
        # at once in full, a blank view until the first pose, exact poses only in playback
        self.legacy = frame_budget_ms is None
        self.idle_wait_s = 0.0 if self.legacy else 1.0 / 30.0  # see step(); the legacy loop spins as before
        self._was_quiet = False
        self.state = ViewerState()
        self.state.merged_live = level_of_detail
        self.info = AppInfo(renderer_path=self.renderer.path)  # what the panels show: a snapshot, each frame
        # the screen-space CNN (on the device asked for, as the dynamics) and latent views, on settled images
        self.refining = RefineController(Refiner(self.ctx, resolve_device(device)), self.renderer, self.draws,
                                         self.state, self.info)
        self.compare = CompareController(self.ctx, str(resolve_device(device)))  # the Compare panel's views
        self.threads = threads
        self.device = device  # where the worker runs the dynamics ("cpu", "cuda", "mps", "auto")
        self.precision = precision  # the exact dynamics' number format ("fp32", "bf16", "auto")
        self.remember_recent = remember_recent
        if remember_recent:
            self.state.load_recent()
        # the open files (opening.py sets them)
        self.avatar: Avatar | None = None
        self.engine: PoseEngine | None = None
        self.sequence: ExpressionSequence | None = None
        self._posed: PosedGaussians | None = None  # a copy of the cloud on screen (before highlighting)
        self._pending: PosedGaussians | None = None  # shown but not uploaded yet (`show`, `_upload_pending`)
        self.draws.before_full_image = lambda: self._upload_pending(force=True)
        self.inspection = InspectionCache()
        self._last_t = time.perf_counter()
        self._fps_t: list[float] = []
        self.frames = 0
        self.presented = 0  # frames drawn into the window (`_present`: the others were the frame on screen)
        self._presented_key: tuple | None = None
        self._presented_t = -1e9
        self.profile = FrameProfile()  # wall time per section of the UI frames (stats overlay, bench)
        self.should_close = False
        # controllers, each built after what it is handed
        self.edits = EditController(self)
        self.sequence_codes = SequenceCodes(self.state, lambda: self.sequence)
        self.bakes = BakeController(self.state, lambda: self.engine, self.sequence_codes)
        self.live = LiveLinkController(self, wake=glfw.post_empty_event)  # its code comes before keyframes
        self.poses = PoseController(self, self.sequence_codes, self.bakes,
                                    keyframe_code=self.live.code_or(self.edits.keyframe_code),
                                    playback_previews=not self.legacy)
        self.recorder = Recorder(lambda: self.read_window(viewport_only=True))
        self.actions = ActionController(self, self.poses, self.bakes,
                                        lambda: self.recorder.toggle_reported(self._viewport()[2:], self.state.report))
        self.actions.load_presets()
        self.view_camera = ViewCamera(self.state, self._viewport, self.edits, lambda: self.actions.rig,
                                      lambda: self.sequence, self.poses.frame_on_screen, self.live.head_transform)
        self.input = ViewInput(self.state, self.window.scale, self._viewport, self.edits, self.view_camera,
                               self.pick, self.compare.drag_divider)
        # every action type -> its controller's handler (npga_view/actions.py); strict in tests
        self.dispatcher = Dispatcher()
        self.dispatcher.include(self.actions.handlers())
        self.dispatcher.include(self.edits.handlers())
        self.dispatcher.include(self.live.handlers())
        self.dispatcher.include(self.compare.handlers())
        self.panels = Panels(files=FilesPanel(browse=os.getcwd()))
        self._publish_info()

    # ------------------------------------------------------------------------------------ open files
    def open_avatar(self, path: str) -> bool:
        """Load an avatar (errors go to the UI); starts the pose worker for animatable ones."""
        return opening.open_avatar(self, path)

    def adopt_avatar(self, avatar: Avatar, path: str) -> None:
        """Show `avatar` (loaded from `path`): worker, sliders, camera."""
        opening.adopt_avatar(self, avatar, path)

    def open_sequence(self, path: str) -> bool:
        """Load a sequence; refused (with both dimensions) if it does not fit the avatar."""
        return opening.open_sequence(self, path)

    def load_session(self, path: str) -> None:
        """Restore camera, sliders, modes and open files from a session file."""
        self.actions.load_session(path)

    def _on_drop(self, window, paths) -> None:
        self.state.actions.extend(open_action(p) for p in paths)

    # --------------------------------------------------------------------------- the cloud on screen
    def show(self, posed: PosedGaussians) -> None:
        """Keep `posed` as the cloud on screen; upload it as the Inspect settings colour it, with the edit
        highlights on top."""
        self._posed = posed
        session = self.edits.session
        selection = session.selection if session is not None and len(session) == len(posed) else None
        frame = self.inspection.frame(self.state.inspect, posed, self.poses.shown_code, self.current_camera,
                                      selection)
        self._pending = None
        if frame is None:
            uploaded = highlight(posed, session)
            self.renderer.clear_lines()
        else:  # style, point size and lines now; the Gaussians as below
            uploaded = frame.posed = highlight(frame.posed, session)
            self.renderer.show(frame, upload=False)
        if len(uploaded) == self.renderer.count > 0:
            # uploaded when an image of the full cloud starts (`before_full_image`): poses arriving faster than
            # images (a stream, playback; live images from the merged cloud) cost no upload each
            self._pending = uploaded
        else:
            self.renderer.set_gaussians(uploaded)
        self.content_version += 1
        self.lod.submit(self.content_version, uploaded)

    def _upload_pending(self, force: bool = False) -> None:
        """Upload the newest shown cloud to the full cloud's renderer unless one of its images is in progress (or
        now, with `force`): poses that arrive faster than images are drawn (a Live Link stream, playback) cost one
        upload per image of the full cloud, not one per pose."""
        if self._pending is not None and (force or not self.draws.drawing_full):
            pending, self._pending = self._pending, None
            self.renderer.set_gaussians(pending)

    def reupload(self) -> None:
        """Upload the cloud on screen again (after a selection, hide or preview change)."""
        if self._posed is not None:
            self.show(self._posed)

    def cloud_changed(self, worker_path: str | None) -> None:
        """The canonical cloud was edited: re-pose it (in the worker, from `worker_path`, if animatable)."""
        avatar = self.avatar
        assert avatar is not None
        self.inspection.set_avatar(avatar)
        self.refining.set_avatar(avatar)
        self.lod.reset()
        if self.state.inspect.picked is not None and self.state.inspect.picked >= len(avatar):
            self.state.inspect.picked = None
        if worker_path is None:
            self.show(avatar.pose())
        else:
            opening.start_engine(self, worker_path)

    def shown_posed(self) -> PosedGaussians | None:
        """The posed cloud on screen, before highlighting (None until the first pose)."""
        return self._posed

    @property
    def first_pose_shown(self) -> bool:
        """True once a pose of the open avatar has been drawn."""
        return self.poses.first_pose_shown

    def shown_means(self) -> np.ndarray:
        """Centres of the Gaussians on screen (canonical ones until the first pose, or after a deletion)."""
        assert self.avatar is not None
        if self._posed is not None and len(self._posed) == len(self.avatar):
            return self._posed.means
        return np.asarray(self.avatar.cloud.means)

    def shown_code(self) -> np.ndarray | None:
        code = self.poses.shown_code
        return None if code is None else code.copy()

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        return self.poses.code_for_keyframe(source, preset)

    # ------------------------------------------------------------------------------------------ camera
    def _viewport(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the splat view in framebuffer pixels (right of the side panel)."""
        assert self.window is not None
        return self.window.viewport()

    def current_camera(self, ignore_keyframes: bool = False):
        """The splat view's camera (view_camera.py)."""
        return self.view_camera.current(ignore_keyframes)

    def frame_avatar(self, reset: bool = False) -> None:
        self.view_camera.frame_avatar(self.avatar, reset)

    def pick(self, x: float, y: float) -> int | None:
        """Pick the Gaussian at view pixel (x, y) (top-left origin) for the inspector."""
        self._upload_pending(force=True)
        idx = self.renderer.pick(self.current_camera(), x, y)
        self.state.inspect.picked = idx
        self.inspection.due = True
        return idx

    def _run_actions(self) -> None:
        actions, self.state.actions = self.state.actions, []
        self.dispatcher.run_all(actions, self.state.report, expected=(AvatarFileError, ValueError, OSError))

    # ------------------------------------------------------------------------------------------ drawing
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
        """The view is changing now: a drag or slider, playback, a Live Link stream (packets within the last
        half second: each one replaces the pose), or a pose that will be replaced (a preview or the canonical cloud
        before the first pose). Draws at the live scale meanwhile."""
        return self._input_active() or self.live.busy() or self.poses.preview or self.poses.canonical

    def _draw_splats(self) -> tuple[tuple | None, Callable[[], None]]:
        """Schedule this frame's splat drawing (`DrawScheduler`), the refinement or the comparison; returns what the
        view shows (None: drawn every frame) and what draws it into the window (`_present`)."""
        cam = self.current_camera()
        info = self.info
        self.lod.enabled = self.state.merged_live and not self.legacy
        if self.lod.error:  # a merge failed: say so and draw every Gaussian from now on
            self.state.report(self.lod.error)
            self.lod.error, self.state.merged_live = None, False
        interacting = self._interacting()
        if not interacting:
            self._upload_pending()
        if self.draws.frame(cam, self.state.mode, self.content_version, interacting, exact_content=self.poses.exact):
            t = self.draws.shown_renderer.last_timings
            info.timings.update({k: t[k] for k in ("sort", "upload", "preprocess", "draw") if k in t})
            info.merged_splats = self.draws.shown_merged
            if not info.merged_splats:  # (a merged cloud's count is not the number of the avatar's in view)
                info.gaussians_drawn = int(t.get("visible", 0))
            self.inspection.due = True
            self.poses.presented(self.draws.shown_version)
        info.draw_scale, info.image_status = self.draws.scale, self.draws.status
        info.image_ms, info.draw_progress = self.draws.last_image_ms, self.draws.progress
        self.inspection.update_figures(self.state.inspect, self._posed, self.poses.shown_code, cam,
                                       self.renderer.drawn_mask, NEAR, interacting, time.perf_counter())
        viewport = self._viewport()
        screen, background = self.ctx.screen, self.state.background
        if self.compare.update(self.avatar, self.poses.shown_code, cam, self.draws.budget_ms * 0.5,
                               self.state.report):  # replaces the splats
            return None, lambda: self.compare.draw(screen, viewport, background)
        if self.refining.update(cam):
            return (("refined", self.refining.key, self.refining.shown, viewport),
                    lambda: self.refining.draw(screen, viewport))
        bg = background if self.state.mode == "rgb" else (0.0, 0.0, 0.0)
        return (("splats", self.draws.images, self.draws.shown_target, self.draws.scale, bg, viewport),
                lambda: self.draws.present(screen, bg, flip_y=True, viewport=viewport))

    def _present(self, view_key: tuple | None, ui_key: int, view: Callable[[], None]) -> bool:
        """Draw the frame (the view, then imgui by the caller) unless it would be the frame on screen again: the
        same view image (splats or refined) and imgui output as the last frame drawn, nothing compared or recorded,
        drawn less than `PRESENT_AT_LEAST_S` ago. On a software GL drawing a frame costs ~10 ms of fill whether
        or not anything changed: undrawn frames leave it to the images being drawn (input is still taken every
        frame, and any change of the panels changes imgui's output)."""
        window = self.window
        assert window is not None
        now = time.perf_counter()
        key = None if view_key is None else (view_key, ui_key, window.framebuffer_size())
        if key is not None and key == self._presented_key and not self.recorder.recording \
                and now - self._presented_t < PRESENT_AT_LEAST_S:
            return False
        window.clear()
        view()
        self._presented_key, self._presented_t = key, now
        self.presented += 1
        return True

    def _draw_ui(self) -> None:
        assert self.window is not None
        _, fh = self.window.logical_size()
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(SIDE_PANEL, fh))
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("npga-view", None, flags)
        for panel in self.panels.side:
            panel.draw(self.state, self.info)
        imgui.end()

    def _publish_info(self) -> None:
        """The display snapshot the panels read, copied from the controllers' own state."""
        info = self.info
        info.avatar, info.sequence = self.avatar, self.sequence
        info.rig_names = list(self.actions.rig)
        info.cnn_device = str(self.refining.refiner.device)
        info.recording, info.compare = self.recorder.recording, self.compare.info()
        info.bake, info.bake_state = self.bakes.status, self.bakes.state()
        info.inspect = self.inspection.figures
        self.poses.publish(info)
        self.edits.publish(info)
        self.live.publish(info)

    def _quiet(self) -> bool:
        """Nothing to draw in this window until something arrives: the view's image is on screen and nothing is
        being drawn or refined, no input held, no playback, recording or queued action (a pose may be on its way
        from the worker)."""
        return (self.draws.idle and self.refining.complete and not self.compare.busy and not self._input_active()
                and not self.state.actions and not self.recorder.recording)

    def step(self) -> None:
        """One frame: input, panels, actions, dynamics, splats, UI. After a quiet frame the next one waits for
        input for up to `idle_wait_s` (worker results and threads are picked up at that rate) instead of
        spinning: an idle window on llvmpipe otherwise redraws ~80 times a second on the cores the pose worker
        and the CNN need."""
        window = self.window
        assert window is not None
        profile = self.profile
        profile.start()
        window.take_input(self.idle_wait_s if self._was_quiet else 0.0)
        profile.mark("wait")
        window.new_frame()
        now = time.perf_counter()
        dt, self._last_t = now - self._last_t, now
        self._fps_t = [t for t in self._fps_t if now - t < 1.0] + [now]
        self.info.fps = len(self._fps_t) / max(1e-6, now - self._fps_t[0]) if len(self._fps_t) > 1 else 0.0
        self.input.mouse()
        self.input.keys()
        self._draw_ui()
        self._run_actions()
        self.edits.after_actions()
        self.edits.tick(dt)
        profile.mark("panels")
        self.live.update()  # the newest packet, asked for in this same frame
        self.poses.update(dt)
        if self._posed is not None and self.inspection.stale(self.state.inspect, self.current_camera):
            self.show(self._posed)  # the Inspect settings (or, for depth colouring, the camera) changed
        profile.mark("posing")
        view_key, view = self._draw_splats()
        profile.mark("splats")
        self._publish_info()
        if self.state.show_stats:
            self.info.frame_profile = profile.lines()
            for panel in self.panels.overlays:  # after drawing, so that they report this frame's image
                panel.draw(self.state, self.info)
        ui_key = window.finish_ui()
        profile.mark("stats")
        if self._present(view_key, ui_key, view):
            profile.mark("splats")
            self.recorder.frame()
            window.draw_ui()
            profile.mark("ui")
            window.swap()
            profile.mark("swap")
        profile.end()
        self.frames += 1
        self._was_quiet = self._quiet() and not self.live.busy()
        if window.close_requested():
            self.should_close = True

    # ------------------------------------------------------------------------------------ snapshots
    def read_window(self, viewport_only: bool = False) -> np.ndarray:
        """RGB uint8 pixels of the back buffer as last drawn (top row first)."""
        assert self.window is not None
        return self.window.read(viewport_only)

    def screenshot(self, path: str, viewport_only: bool = False) -> str:
        """Save the window (panels included) or only the splat view as PNG."""
        assert self.window is not None
        self.info.last_screenshot = self.window.screenshot(path, viewport_only)  # (display only)
        return self.info.last_screenshot

    # ------------------------------------------------------------------------------------------ loop
    def run(self, screenshot: str | None = None, quit_after_frames: int | None = None) -> int:
        """The interactive loop. With `quit_after_frames`, count frames from the first drawn pose: settled frames
        (the view finished, refined), or any drawn frame while a sequence plays (a playing view never settles: a
        looping sequence on the demo never ended the run); at most 20x as many frames pass in all."""
        counted = shown = 0
        try:
            while not self.should_close:
                self.step()
                if quit_after_frames is not None and (self.poses.first_pose_shown or self.avatar is None):
                    shown += 1
                    if self.state.timeline.playing or (self.draws.settled and self.refining.complete):
                        counted += 1
                    if counted >= quit_after_frames or shown >= 20 * max(quit_after_frames, 10):
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
        self.live.close()
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
            self.compare.release()
            self.window.close()
            self.window = None
