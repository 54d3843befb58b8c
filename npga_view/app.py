"""The viewer window: input -> ViewerState -> PoseEngine (worker process) -> SplatRenderer -> imgui panels.

`ViewerApp` builds the parts in dependency order and runs one frame in `step()`; each part reads alone: the window
(window.py), the open avatar with its worker, sequence and cloud on screen (document.py: what an avatar opened
resets subscribes to it), opening files (opening.py), the cloud on screen coloured and uploaded (shown_cloud.py),
the view's camera (view_camera.py) and frame (view_frame.py: what it shows, whether it is drawn; the splat image is
redrawn only when what it depends on changed), the controllers that carry out actions (controllers/), the panels.
"""

from __future__ import annotations

import os

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.device import resolve_device
from npga_core.posing.engine import PoseEngine
from npga_view.actions import Dispatcher
from npga_view.comparison.controller import CompareController
from npga_view.controllers.actions import ActionController
from npga_view.controllers.bake import BakeController
from npga_view.controllers.editing import EditController
from npga_view.controllers.live_link import LiveLinkController
from npga_view.controllers.posing import PoseController
from npga_view.controllers.recording import Recorder
from npga_view.controllers.refining import RefineController
from npga_view.controllers.sequence_codes import SequenceCodes
from npga_view.display import AppInfo
from npga_view.document import Document, EngineOptions
from npga_view.frame_profile import FrameProfile
from npga_view.imgui_glfw import glfw
from npga_view.opening import Opener
from npga_view.panels import Panels
from npga_view.panels.files import FilesPanel, open_action
from npga_view.rendering.factory import create_renderer
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.refinement import Refiner
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.shown_cloud import ShownCloud
from npga_view.state import ViewerState
from npga_view.view_camera import ViewCamera
from npga_view.view_frame import ViewFrame
from npga_view.view_input import ViewInput
from npga_view.window import SIDE_PANEL, Window

#: a frame is drawn at least this often even when it would be the one on screen (a safety net: an expose, when the
#: window system lost the window's pixels, is drawn at once); every 0.25 s cost a still window ~5 % of a core
PRESENT_AT_LEAST_S = 2.0


class ViewerApp:
    """One window. Use `run()` for the interactive loop or `step()` to drive it frame by frame (tests).
    `scheduler`: the class that schedules the splat drawing (a `DrawScheduler`; a subclass draws otherwise)."""

    def __init__(self, width: int = 1360, height: int = 900, visible: bool = True, vsync: bool = True,
                 threads: int = 2, remember_recent: bool = True, device: str = "cpu",
                 frame_budget_ms: float = 25.0, level_of_detail: bool = True,
                 scheduler: type[DrawScheduler] = DrawScheduler, precision: str = "auto"):
        self.window: Window | None = Window(width, height, visible, vsync, on_drop=self.on_drop)
        self.ctx = self.window.ctx
        self.renderer = create_renderer(self.ctx, 64, 64)  # the 4.3 path, or the 4.1 one (macOS)
        # frame-budgeted drawing; live images from a merged level-of-detail cloud while state.merged_live
        self.lod = LiveDetail(lambda: create_renderer(self.ctx, 64, 64), self.renderer)
        self.draws = scheduler(self.renderer, budget_ms=frame_budget_ms, lod=self.lod)
        self.draws.input_probe = self.window.input_pending
        self.profile = FrameProfile()  # wall time per section of the UI frames (stats overlay, bench)
        self.should_close = False
        self.state = ViewerState()
        self.state.merged_live = level_of_detail
        if remember_recent:
            self.state.load_recent()
        self.info = AppInfo(renderer_path=self.renderer.path)  # what the panels show: a snapshot, each frame
        # the open avatar, its worker ("cpu", "cuda", "mps", "auto"; "fp32", "bf16", "auto"), sequence, cloud
        self.doc = Document(EngineOptions(threads, device, precision))
        self.opener = Opener(self.doc, self.state, remember_recent, self._set_title)
        self.edits = EditController(self)
        self.screen = ShownCloud(self.doc, self.state, self.renderer, self.lod, self.draws, self.edits,
                                 self.current_camera)
        # the screen-space CNN (on the device asked for, as the dynamics) and latent views, on settled images
        self.refining = RefineController(Refiner(self.ctx, resolve_device(device)), self.renderer, self.draws,
                                         self.state, self.info)
        self.compare = CompareController(self.ctx, str(resolve_device(device)))  # the Compare panel's views
        codes = SequenceCodes(self.state, lambda: self.doc.sequence)
        self.bakes = BakeController(self.state, lambda: self.doc.engine, codes)
        self.live = LiveLinkController(self, wake=glfw.post_empty_event)  # its code comes before keyframes
        self.poses = PoseController(self, codes, self.bakes, keyframe_code=self.live.code_or(self.edits.keyframe_code),
                                    taken_version=lambda: self.draws.taken_version)
        self.recorder = Recorder(lambda: self.read_window(viewport_only=True))
        self.actions = ActionController(self, self.poses, self.bakes,
                                        lambda: self.recorder.toggle_reported(self._viewport()[2:], self.state.report))
        self.actions.load_presets()
        self.view_camera = ViewCamera(self.state, self._viewport, self.edits, lambda: self.actions.rig,
                                      lambda: self.doc.sequence, self.poses.frame_on_screen, self.live.head_transform)
        self.view = ViewFrame(state=self.state, info=self.info, doc=self.doc, draws=self.draws, lod=self.lod,
                              screen=self.screen, poses=self.poses, refining=self.refining, compare=self.compare,
                              live=self.live, edits=self.edits, camera=self.current_camera, viewport=self._viewport)
        self.input = ViewInput(self.state, self.window.scale, self._viewport, self.edits, self.view_camera,
                               self.screen.pick, self.compare.drag_divider)
        # what an avatar opened or an edited cloud resets, the one list, in this order (npga_view/document.py)
        for part in (self.edits, self.screen, self.refining, self.compare, self.bakes, self.poses, self.view_camera):
            self.doc.include(part.subscriptions())
        # every action type -> its controller's handler (npga_view/actions.py); strict in tests
        self.dispatcher = Dispatcher()
        for handlers in (self.actions, self.edits, self.live, self.compare):
            self.dispatcher.include(handlers.handlers())
        self.panels = Panels(files=FilesPanel(browse=os.getcwd()))
        self._publish_info()

    # ------------------------------------------------------------------------------------ the document
    @property
    def avatar(self) -> Avatar | None:
        return self.doc.avatar

    @property
    def engine(self) -> PoseEngine | None:
        return self.doc.engine

    @property
    def sequence(self) -> ExpressionSequence | None:
        return self.doc.sequence

    def open_avatar(self, path: str) -> bool:
        """Load an avatar (errors go to the UI); starts the pose worker for animatable ones."""
        return self.opener.open_avatar(path)

    def open_sequence(self, path: str) -> bool:
        """Load a sequence; refused (with both dimensions) if it does not fit the avatar."""
        return self.opener.open_sequence(path)

    def load_session(self, path: str) -> None:
        """Restore camera, sliders, modes and open files from a session file."""
        self.actions.load_session(path)

    def on_drop(self, window, paths) -> None:
        """Files dropped on the window: each opened as what it is (avatar, sequence, take, session)."""
        self.state.actions.extend(open_action(p) for p in paths)

    def _set_title(self, title: str) -> None:
        if self.window is not None:
            self.window.set_title(title)

    def shown_posed(self) -> PosedGaussians | None:
        """The posed cloud on screen, before highlighting (None until the first pose)."""
        return self.doc.posed

    def shown_code(self) -> np.ndarray | None:
        code = self.doc.code
        return None if code is None else code.copy()

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        return self.poses.code_for_keyframe(source, preset)

    @property
    def frames(self) -> int:
        return self.view.pacing.frames

    @property
    def presented(self) -> int:
        return self.view.pacing.presented

    # ------------------------------------------------------------------------------------------ camera
    def _viewport(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the splat view in framebuffer pixels (right of the side panel)."""
        assert self.window is not None
        return self.window.viewport()

    def current_camera(self, ignore_keyframes: bool = False):
        """The splat view's camera (view_camera.py)."""
        return self.view_camera.current(ignore_keyframes)

    def frame_avatar(self, reset: bool = False) -> None:
        self.view_camera.frame_avatar(self.doc.avatar, reset)

    def pick(self, x: float, y: float) -> int | None:
        """Pick the Gaussian at view pixel (x, y) (top-left origin) for the inspector."""
        return self.screen.pick(x, y)

    # ------------------------------------------------------------------------------------------ drawing
    def _draw_ui(self) -> None:
        assert self.window is not None
        self.panels.draw_side(self.state, self.info, SIDE_PANEL, self.window.logical_size()[1])

    def _publish_info(self) -> None:
        """The display snapshot the panels read, copied from the controllers' own state."""
        info = self.info
        info.avatar, info.sequence = self.doc.avatar, self.doc.sequence
        info.rig_names = list(self.actions.rig)
        info.cnn_device = str(self.refining.refiner.device)
        info.recording, info.compare = self.recorder.recording, self.compare.info()
        info.bake, info.bake_state = self.bakes.status, self.bakes.state()
        pacing = self.view.pacing
        info.inspect, info.fps, info.quiet = self.screen.inspection.figures, pacing.fps, pacing.was_quiet
        for part in (self.poses, self.edits, self.live):
            part.publish(info)

    def step(self) -> None:
        """One frame: input, panels, actions, dynamics, splats, UI. After a quiet frame the next one waits for
        input for up to `view.pacing.idle_wait_s` (worker results and threads are picked up at that rate) instead of
        spinning: an idle window on llvmpipe otherwise redraws ~80 times a second on the cores the pose worker
        and the CNN need."""
        window, profile = self.window, self.profile
        assert window is not None
        profile.start()
        window.take_input(self.view.pacing.wait_s())
        profile.mark("wait")
        window.new_frame()
        dt = self.view.pacing.tick()
        self.input.mouse()
        self.input.keys()
        self._draw_ui()
        actions, self.state.actions = self.state.actions, []
        self.dispatcher.run_all(actions, self.state.report, expected=(AvatarFileError, ValueError, OSError))
        self.edits.after_actions()
        self.edits.tick(dt)
        profile.mark("panels")
        self.live.update()  # the newest packet, asked for in this same frame
        self.poses.update(dt)
        self.screen.refresh()  # the Inspect settings (or, for depth colouring, the camera) changed
        profile.mark("posing")
        view = self.view.schedule(self.ctx.screen)
        profile.mark("splats")
        self._publish_info()
        if self.state.show_stats:
            self.info.frame_profile = profile.lines()
            for panel in self.panels.overlays:  # after drawing, so that they report this frame's image
                panel.draw(self.state, self.info)
        ui_key = window.finish_ui()
        profile.mark("stats")
        stale = self.panels.stale(self.state, self.info)
        always = self.recorder.recording or window.take_exposed()
        if self.view.present(window, view, ui_key, always, PRESENT_AT_LEAST_S, stale):
            profile.mark("splats")
            self.recorder.frame()
            window.draw_ui()
            profile.mark("ui")
            window.swap()
            profile.mark("swap")
        profile.end()
        self.view.end(self.recorder.recording)
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
                if quit_after_frames is not None and (self.poses.first_pose_shown or self.doc.avatar is None):
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
        self.edits.close()  # (unsaved edits autosaved)
        self.doc.close_engine()
        if self.window is not None:
            self.lod.close()
            self.refining.release()
            self.compare.release()
            self.window.close()
            self.window = None
