"""`ViewFrame`: per UI frame, what the splat view shows and whether the frame is drawn at all.

`schedule` runs the frame's splat drawing (`DrawScheduler`: at the live scale while the view is changing), copies
its figures into the display snapshot, and picks what the view shows: the comparison, the refined (or latent)
image, or the splat image; `present` draws the frame unless it would be the one on screen again; `quiet` says that
the loop may wait for input (its clock, `FramePacing`, is `pacing`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import moderngl

from npga_core.camera.cameras import Camera
from npga_view.comparison.controller import CompareController
from npga_view.controllers.editing import EditController
from npga_view.controllers.live_link import LiveLinkController
from npga_view.controllers.posing import PoseController
from npga_view.controllers.refining import RefineController
from npga_view.display import AppInfo
from npga_view.document import Document
from npga_view.imgui_glfw import imgui
from npga_view.pacing import FramePacing
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.renderer import camera_key
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.shown_cloud import ShownCloud
from npga_view.state import ViewerState
from npga_view.window import Window

View = tuple[tuple | None, Callable[[], None]]  # what the view shows (None: changes every frame), what draws it


class ViewFrame:
    """Handed the parts whose images and state the view shows, the view's camera and rectangle (getters)."""

    def __init__(self, *, state: ViewerState, info: AppInfo, doc: Document, draws: DrawScheduler, lod: LiveDetail,
                 screen: ShownCloud, poses: PoseController, refining: RefineController, compare: CompareController,
                 live: LiveLinkController, edits: EditController, camera: Callable[[], Camera],
                 viewport: Callable[[], tuple[int, int, int, int]]) -> None:
        self.state, self.info, self.doc, self.draws, self.lod = state, info, doc, draws, lod
        self.screen, self.poses, self.refining, self.compare = screen, poses, refining, compare
        self.live, self.edits, self.camera, self.viewport = live, edits, camera, viewport
        self.pacing = FramePacing()
        self._shown_view: tuple | None = None  # camera and content version of the last frame
        self._changed_t = -1e9  # when they last changed
        self._held_back = False  # the last frame was not drawn for its stale panels (`_hold`)

    def _held(self) -> bool:
        """A drag in the view or a held widget."""
        io = imgui.get_io()
        dragging = not io.want_capture_mouse and any(imgui.is_mouse_down(b) for b in range(3))
        return dragging or imgui.is_any_item_active()

    def _playing(self) -> bool:
        """Playback of a sequence or of keyframes."""
        playing = self.doc.sequence is not None and self.state.follow_sequence and self.state.timeline.playing
        return playing or self.edits.kf_playing

    def input_active(self) -> bool:
        """A drag or a held widget, or playback (of a sequence or of keyframes)."""
        return self._held() or self._playing()

    def interacting(self) -> bool:
        """The view is changing now: a drag or slider that moved the view or its content within the scheduler's
        settle time (held still longer, the view is refined as if let go), playback, a Live Link stream (packets
        within the last half second: each one replaces the pose), or a pose that will be replaced (a preview or the
        canonical cloud before the first pose). Draws at the live scale meanwhile."""
        now = time.perf_counter()
        shown = (camera_key(self.camera()), self.doc.version)
        if shown != self._shown_view:
            self._shown_view, self._changed_t = shown, now
        moving = self._held() and now - self._changed_t < self.draws.settle_s
        return moving or self._playing() or self.live.busy() or self.poses.preview or self.poses.canonical

    def schedule(self, framebuffer: moderngl.Framebuffer) -> View:
        """This frame's splat drawing (`DrawScheduler`), the refinement or the comparison; returns what the view
        shows and what draws it into `framebuffer` (`present`)."""
        cam, info, draws, st = self.camera(), self.info, self.draws, self.state
        self.lod.enabled = st.merged_live
        if self.lod.error:  # a merge failed: say so and draw every Gaussian from now on
            st.report(self.lod.error)
            self.lod.error, st.merged_live = None, False
        interacting = self.interacting()
        if not interacting:
            self.screen.upload_pending()
        if draws.frame(cam, st.mode, self.doc.version, interacting, exact_content=self.poses.exact):
            t = draws.shown_renderer.last_timings
            info.timings.update({k: t[k] for k in ("sort", "upload", "preprocess", "draw") if k in t})
            info.merged_splats = draws.shown_merged
            if not info.merged_splats:  # (a merged cloud's count is not the number of the avatar's in view)
                info.gaussians_drawn = int(t.get("visible", 0))
            self.screen.inspection.due = True
            self.poses.presented(draws.shown_version)
        info.draw_scale, info.image_status = draws.scale, draws.status
        info.renderer_path = f"{draws.shown_renderer.path}, colour pass on {draws.shown_renderer.colour_pass}"
        info.image_ms, info.draw_progress = draws.last_image_ms, draws.progress
        self.screen.update_figures(cam, interacting)
        viewport, background = self.viewport(), st.background
        if self.compare.update(self.doc.avatar, self.doc.code, cam, draws.budget_ms * 0.5, st.report):
            return None, lambda: self.compare.draw(framebuffer, viewport, background)  # (replaces the splats)
        if self.refining.update(cam):
            return (("refined", self.refining.key, self.refining.shown, viewport),
                    lambda: self.refining.draw(framebuffer, viewport))
        bg = background if st.mode == "rgb" else (0.0, 0.0, 0.0)
        return (("splats", draws.images, draws.shown_target, draws.scale, bg, viewport),
                lambda: draws.present(framebuffer, bg, flip_y=True, viewport=viewport))

    def present(self, window: Window, view: View, ui_key: int, always: bool, at_least_s: float,
                panels_stale: bool = False) -> bool:
        """Draw the frame (the view, then imgui by the caller) unless it would be the frame on screen again: the
        same view image (splats or refined) and imgui output as the last frame drawn, nothing compared, nothing that
        asks for every frame (`always`: recording, an expose), drawn less than `at_least_s` ago. On a software GL
        drawing a frame costs ~10 ms of fill whether or not anything changed: undrawn frames leave it to the images
        being drawn (input is still taken every frame, and any change of the panels changes imgui's output).
        `panels_stale`: the panels were drawn before this frame's image finished and would show it differently
        (`_hold`)."""
        if self._hold(panels_stale, always):
            return False
        view_key, draw = view
        key = None if view_key is None else (view_key, ui_key, window.framebuffer_size())
        if not self.pacing.due(key, always, at_least_s):
            return False
        window.clear()
        draw()
        return True

    def _hold(self, panels_stale: bool, always: bool) -> bool:
        """While a sequence plays (nothing held, recorded or streamed): a frame whose panels are stale is not
        drawn, so that the image waits one UI frame for the panels' readout of it and the two reach the screen in
        one draw instead of two (each ~10-20 ms on llvmpipe). Never two frames in a row, so that images finishing
        in every frame still reach the screen; never for a Live Link stream, whose images are waited for."""
        hold = (panels_stale and not always and not self._held_back and self._playing()
                and not self._held() and not self.live.busy())
        self._held_back = hold
        return hold

    def quiet(self) -> bool:
        """Nothing to draw until something arrives: the view's image is on screen and nothing is being drawn or
        refined or compared, no input held, no playback, stream or queued action (a pose may be on its way from
        the worker); the caller adds what else keeps it drawing (recording)."""
        return (self.draws.idle and self.refining.complete and not self.compare.busy and not self.input_active()
                and not self.state.actions and not self.live.busy())

    def end(self, recording: bool) -> None:
        """The frame is over: counted, and whether the next one may wait for input (not while `recording`)."""
        self.pacing.frames += 1
        self.pacing.was_quiet = self.quiet() and not recording
