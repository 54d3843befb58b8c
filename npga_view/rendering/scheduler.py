"""`DrawScheduler`: what the splat view draws each UI frame, at which resolution, within a time budget.

The window must stay responsive on a 2-core CPU with a software GL (llvmpipe: the demo takes 0.2-0.5 s to
draw at full resolution) as on a workstation GPU (a millisecond). Each UI frame the app hands the scheduler
the view's camera, the render mode, a version number of the cloud on screen and whether the person is
interacting (dragging, moving sliders, playing). The scheduler then

- draws for at most `budget_ms` per UI frame: an image is started with `SplatRenderer.begin_draw` and
  continued with `continue_draw(budget)` over the following frames; the previous finished image stays on
  screen until the new one is complete (slices blend the same sorted order, so the pixels are those of one
  draw);
- while the view changes (and for `settle_s` after), draws at a reduced `scale` chosen from the measured
  cost of the last images so that a complete image takes about `interactive_ms` of drawing; the image is
  upscaled bilinearly to the viewport;
- once input stops, draws the current view at full resolution ("refining"), then stops drawing ("exact",
  if the cloud on screen is the exact pose, else "preview").

Live images come from a level-of-detail cloud when one is handed in (`LiveDetail`: at most 16k merged
Gaussians, drawn by a second renderer) wherever a full-resolution image of every Gaussian does not fit in the
budget (llvmpipe: every splat costs vertex work at any resolution; on a GPU nothing changes). While the merge of
the current pose is on its way (a thread, 25-90 ms) the scheduler waits for it, at most `lod_wait_ms` since
it began waiting; when poses change faster than they are merged (playback, a slider drag) it draws the newest
merged pose that is newer than the one on screen (a preview; playback counts its frame as the one shown).
The merged cloud's live scale adapts to `lod_interactive_ms`, and its slices leave the UI `target_fps`.
Full-resolution images are always drawn from every Gaussian.

An unfinished image is finished even if the view changed meanwhile (so complete images keep coming during a
long drag), unless it is a full-resolution refinement that a new interaction makes pointless: that one is
dropped. Which image to start is decided by the pure `draw_plan.plan` (its named states: idle, live,
refining, waiting for a merge); this class gathers its inputs and carries it out. (The behaviour before
budgeting, every change drawn at once in full, lives in the benchmark that compares both:
npga_view/benchmarks/bench_window.py.)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from npga_core.camera.cameras import Camera
from npga_view.rendering.draw_plan import FrameState, ImageInfo, PlanInputs, Source, Target, plan
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.renderer import SplatRenderer, camera_key

SMOOTHING = 0.2  # weight of the newest figure in the smoothed UI and overshoot times
SCALE_STEP = (0.6, 1.6)  # the live scale changes by at most these factors per image
FIRST_LIVE_SCALE = 0.5  # the live scales before any image was measured
FIRST_BUDGETS = 4  # the first live image after a still view may take this many budgets in its first UI frame
FIRST_SCALE = 0.7  # ... at this times the live scale (LAM p2-1, a packet -> pixels: 0.110-0.120 -> 0.079-0.085 s)
LIVE_FRAMES = 5  # a live image is sized to take about this many UI frames (about 6 images/s at 30 UI fps)
# a still view's full-resolution image takes this many budgets of each UI frame (the view is still: a slower UI for
# the 0.2-0.5 s it takes is not seen, a new drag in that time waits for the frame; demo, orbit -> exact beside two
# busy processes 0.70 -> 0.56 s with 2 against 1, 0.487 -> 0.441 s with 3 against 2, no better with 4)
REFINE_BUDGETS = 3


def scaled_camera(camera: Camera, scale: float) -> Camera:
    """`camera` at `scale` times its resolution (same field of view; at least 16 px a side)."""
    if scale >= 1.0:
        return camera
    w = max(16, round(camera.width * scale))
    h = max(16, round(camera.height * scale))
    return camera.resized(w, h)


@dataclass
class ImageJob:
    """One image the scheduler draws (or has on screen): of what, at which scale, from which cloud, by whom."""

    target: Target
    scale: float
    exact_content: bool  # the cloud drawn was the exact pose (not a preview)
    live: bool
    renderer: SplatRenderer  # who draws it: the full cloud's renderer or the merged cloud's
    first: bool = False  # the first live image after a settled view: FIRST_BUDGETS in its first frame

    def info(self, full: SplatRenderer) -> ImageInfo:
        return ImageInfo(self.target, self.scale, self.exact_content, self.live, self.renderer is not full)


class DrawScheduler:
    """See the module docstring. `frame()` once per UI frame; `status` and `scale` describe the shown image."""

    def __init__(self, renderer: SplatRenderer, budget_ms: float = 25.0, interactive_ms: float = 120.0,
                 min_scale: float = 0.2, settle_s: float = 0.1, lod: LiveDetail | None = None,
                 lod_wait_ms: float = 200.0, lod_interactive_ms: float = 40.0):
        self.renderer = renderer
        self.lod = lod
        self.lod_wait_ms = lod_wait_ms
        self.lod_interactive_ms = lod_interactive_ms
        self.lod_above_ms = budget_ms  # the merged cloud only where a full-resolution image costs more than this
        # the UI rate live images of the merged cloud leave room for (`frame_budget`): 30 with a 5 % margin, since
        # the UI's own time is a smoothed estimate (aiming at 30, live playback measured 26.9-32.2 UI fps)
        self.target_fps = 31.5
        self._lod_wait: float | None = None  # since when the view has waited for a merge (None: not waiting)
        self.budget_ms = budget_ms
        self.live_budget_ms = budget_ms  # what the last live frames were given (`frame_budget`)
        self.before_full_image: Callable[[], None] | None = None  # called before an image of the full cloud starts
        #: True when input that can change the view has arrived during this UI frame (the window's
        #: `input_pending`): a still view's refinement (`bounded`) stops after the budget in progress
        self.input_probe: Callable[[], bool] | None = None
        self.interactive_ms = interactive_ms
        self.min_scale = min_scale
        self.settle_s = settle_s
        self.interactive_scale = FIRST_LIVE_SCALE  # the scale for live images, adapted to the measured cost
        self.lod_scale = FIRST_LIVE_SCALE  # the same for live images of the merged cloud
        self._shown: ImageJob | None = None
        self._job: ImageJob | None = None
        self._job_t0 = 0.0
        self._target: Target | None = None
        self._view: tuple | None = None  # camera and mode of the last frame
        self._last_change = -math.inf  # when the camera or mode last changed
        self._frame_end: float | None = None
        self.ui_ms = 0.0  # the UI frame's own time (everything but splat drawing), smoothed
        self.over_ms = 0.0  # drawing beyond the budget given (the last slice, waiting for queued GL work), smoothed
        self._given_ms: float | None = None
        self._outside_ms = 0.0  # drawing since the last frame() done elsewhere (`drew_outside`)
        self._live = False  # the last frame was an interaction (see `idle`)
        self._was_live = False  # the last frame drew at the live scale (interaction or settle time)
        self.last_image_ms = 0.0  # drawing time (pre-pass + slices) of the last finished image
        #: drawing time of a full-resolution image of every Gaussian, measured (or from a reduced one, / scale^2)
        self.full_image_ms: float | None = None
        self.last_image_wall_ms = 0.0  # wall time from its start to its end (spans UI frames)
        self._live_wall_ms: list[float | None] = [None, None]  # that of the last live image: full cloud, merged
        self.images = 0  # finished images so far
        self.last_plan = FrameState.IDLE  # what the last frame decided (draw_plan.FrameState)

    # ----------------------------------------------------------------------------------------- state
    @property
    def scale(self) -> float:
        """Resolution scale of the image on screen (1.0 = full)."""
        return 1.0 if self._shown is None else self._shown.scale

    @property
    def status(self) -> str:
        """"preview" (reduced resolution or a preview pose), "refining" (a full-resolution image of the
        current view is being drawn) or "exact" (the full-resolution image of the exact pose is on screen)."""
        shown, job = self._shown, self._job
        if shown is not None and shown.target == self._target and self._final(shown):
            return "exact" if shown.exact_content else "preview"
        if job is not None and job.target == self._target and job.scale >= 1.0:
            return "refining"
        return "preview"

    @property
    def shown_target(self) -> Target | None:
        """(camera key, mode, content version) of the image on screen."""
        return None if self._shown is None else self._shown.target

    @property
    def shown_version(self) -> int:
        """Content version of the image on screen (-1 before the first)."""
        return -1 if self._shown is None else self._shown.target.version

    @property
    def taken_version(self) -> int:
        """The newest content version in an image on screen or being drawn (-1 before the first)."""
        job = self._job
        return max(self.shown_version, -1 if job is None else job.target.version)

    @property
    def settled(self) -> bool:
        """The current view is on screen at full resolution and nothing is being drawn."""
        shown = self._shown
        return self._job is None and shown is not None and shown.target == self._target and self._final(shown)

    def _final(self, image: ImageJob) -> bool:
        """A full-resolution image of every Gaussian (a merged cloud's image is not, at any scale)."""
        return image.scale >= 1.0 and image.renderer is self.renderer

    @property
    def idle(self) -> bool:
        """Nothing to draw next frame unless the view or its content changes: the current view's image is on
        screen and nothing is being drawn (a live image counts while the last frame was live; else only the
        full-resolution one)."""
        shown = self._shown
        return (self._job is None and shown is not None and shown.target == self._target
                and (self._final(shown) or self._live))

    @property
    def interacting(self) -> bool:
        """The last frame was an interaction (input held, playback, a stream, a pose about to be replaced): work on the
        settled image (its refinement) waits, since the view is about to change."""
        return self._live

    @property
    def drawing_full(self) -> bool:
        """An image of the full cloud (not the merged one) is being drawn."""
        return self._job is not None and self._job.renderer is self.renderer

    @property
    def progress(self) -> float:
        """How much of the image being drawn is done (1.0 when none)."""
        return self._job.renderer.progress if self._job is not None else 1.0

    @property
    def shown_renderer(self) -> SplatRenderer:
        """The renderer that drew the image on screen (the full cloud's before the first image)."""
        return self.renderer if self._shown is None else self._shown.renderer

    @property
    def shown_merged(self) -> int:
        """Gaussians of the merged cloud the image on screen was drawn from (0: the full cloud)."""
        r = self.shown_renderer
        return 0 if r is self.renderer else r.count

    def invalidate(self) -> None:
        """Forget the shown image (e.g. the renderer's targets were dropped): the next frame draws anew."""
        if self._job is not None:
            self._job.renderer.cancel_draw()
        self._shown = None
        self._job = None
        self.renderer.cancel_draw()

    def present(self, framebuffer, background=(0.0, 0.0, 0.0), flip_y: bool = True,
                viewport: tuple[int, int, int, int] | None = None) -> None:
        """Show the finished image on screen (`SplatRenderer.present` of the renderer that drew it)."""
        self.shown_renderer.present(framebuffer, background, flip_y, viewport)

    # ---------------------------------------------------------------------------------------- per frame
    def frame(self, camera: Camera, mode: str, content_version: int, interacting: bool,
              exact_content: bool = True, now: float | None = None) -> bool:
        """Advance drawing for this UI frame; True when a new finished image was swapped to the front."""
        frame_start = time.perf_counter()
        if self._frame_end is not None:
            gap = max(0.0, (frame_start - self._frame_end) * 1e3 - self._outside_ms)
            self.ui_ms = gap if not self.ui_ms else (1 - SMOOTHING) * self.ui_ms + SMOOTHING * gap
        self._outside_ms = 0.0
        self._given_ms = None
        try:
            return self._frame(camera, mode, content_version, interacting, exact_content, now, frame_start)
        finally:
            self._frame_end = time.perf_counter()
            if self._given_ms is not None and not math.isinf(self._given_ms):
                over = max(0.0, (self._frame_end - frame_start) * 1e3 - self._given_ms)
                self.over_ms = (1 - SMOOTHING) * self.over_ms + SMOOTHING * over

    def drew_outside(self, ms: float) -> None:
        """Drawing done elsewhere in this UI frame within `frame_budget` (the refinement's latent pass): not
        counted as the UI's own time."""
        self._outside_ms += ms

    def _frame(self, camera: Camera, mode: str, content_version: int, interacting: bool, exact_content: bool,
               now: float | None, frame_start: float) -> bool:
        now = frame_start if now is None else now
        key = camera_key(camera)
        target = Target(key, mode, content_version)
        self._target = target
        if (key, mode) != self._view:  # a camera move is an interaction; a new pose alone is not
            if self._view is not None and self._shown is not None:
                self._last_change = now
            self._view = (key, mode)
        if self._live and not interacting:  # a drag or a held slider let go: the view has stopped, no settle time
            self._last_change = -math.inf
        live = interacting or (now - self._last_change) < self.settle_s
        stopped, self._was_live = self._was_live and not live, live  # the view stopped in this frame
        self._live = interacting  # (not the settle time: a live image is refined once it has passed)
        job = self._job
        if job is not None and not job.renderer.drawing:  # dropped (another pass re-ran the pre-pass)
            self._job = job = None
        if job is not None and ((live and not job.live and job.target != target) or (job.live and stopped)):
            # a full-resolution refinement of a view the person has already left, or a live image unfinished when
            # the view stops: the stopped view's image starts at once, the last live image stays on screen
            # meanwhile (finishing it took another 30-125 ms and a redraw of a busy machine first); a cheap first
            # image of a still view (no image yet) is not a live view stopping
            job.renderer.cancel_draw()
            self._job = job = None
        if job is None and not self._plan_and_start(camera, target, live, exact_content, now):
            return False
        if self._job is None:
            return False
        # the first response to a change after a settled view (a packet, a click, the start of a drag) comes in one UI
        # frame where it can: one longer frame of a still view is not seen, a late answer is (LAM p2-1, a packet ->
        # pixels: 0.113 -> 0.103 s with 4 budgets instead of 1)
        given = self.frame_budget(live)  # (also sets the live budget `_adapt` sizes images by)
        self._given_ms = FIRST_BUDGETS * self.budget_ms if self._job.first and live else given
        return self._continue(self._given_ms, frame_start)

    def _plan_inputs(self, target: Target, live: bool, exact_content: bool,
                     now: float) -> tuple[PlanInputs, SplatRenderer | None]:
        """The inputs of `plan` for this frame, and the merged cloud's renderer if it is ready. Asks for the merge
        of this pose (LiveDetail.request) only where a merged image could be drawn, as the plan will."""
        shown = self._shown
        # live images from the merged cloud where an image of the full cloud does not fit in the budget at full
        # resolution (on a GPU it does: no merged cloud there)
        costly = self.full_image_ms is not None and self.full_image_ms > self.lod_above_ms
        lod = self.lod if live and costly and shown is not None else None
        merged = lod.request(target.version) if lod is not None else None
        pending = lod is not None and lod.usable() and lod.pending(target.version)
        walls = (self._live_wall_ms[0], self._live_wall_ms[1])
        inputs = PlanInputs(
            target, live, exact_content, None if shown is None else shown.info(self.renderer),
            self.interactive_scale, self.lod_scale, use_lod=lod is not None, merged_ready=merged is not None,
            merged_version=lod.uploaded_version if lod is not None else -1, merge_pending=pending,
            # (how long merges take matters only when both live images were measured)
            merge_ms=lod.merge_ms if lod is not None and pending and None not in walls else 0.0,
            lod_wait_ms=self.lod_wait_ms,
            live_wall_ms=walls,
            waited_ms=None if self._lod_wait is None else (now - self._lod_wait) * 1e3)
        return inputs, merged

    def _plan_and_start(self, camera: Camera, target: Target, live: bool, exact_content: bool, now: float) -> bool:
        """Decide (`plan`) and start the image it asks for; False when the frame waits for a merge."""
        inputs, merged = self._plan_inputs(target, live, exact_content, now)
        decision = plan(inputs)
        self.last_plan = decision.state
        if decision.state is FrameState.WAITING_FOR_MERGE:
            if self._lod_wait is None:
                self._lod_wait = now
            return False
        if decision.draw is None:
            return True
        renderer = merged if decision.source is Source.MERGED else None
        if decision.source is Source.MERGED_BEHIND and self.lod is not None:
            renderer = self.lod.renderer
        self._lod_wait = None
        first = decision.live and self._shown is not None and not self._shown.live
        scale = decision.scale
        if first and scale < 1.0:  # (smaller still: drawn in one frame where it can; the next live image is sharper)
            scale = max(self.min_scale, round(scale * FIRST_SCALE, 3))
        self._start(camera, target.mode, ImageJob(decision.draw, scale, decision.exact_content,
                                                decision.live, renderer or self.renderer, first), now)
        return True

    def frame_budget(self, live: bool) -> float:
        """Milliseconds of drawing per UI frame: while the view changes, what keeps the UI at `target_fps` beside
        the UI's own time and the usual overshoot (the last slice, GL work queued by the window), at most
        `budget_ms`, at least a third of it (no cliff: the whole budget once less than a quarter was left flipped a
        LAM stream between 32 and 20 UI fps as the UI's own time moved by a millisecond, and held the demo at 17-19
        UI fps beside two busy processes); live images adapt their scale to what they are given (`_adapt`); while
        nothing changes, a refinement takes `REFINE_BUDGETS` budgets or as long as the rest of the UI frame (so that
        it gets most of the machine), at most 4 budgets."""
        if not live:
            return max(REFINE_BUDGETS * self.budget_ms, min(self.ui_ms, 4 * self.budget_ms))
        left = 1e3 / self.target_fps - self.ui_ms - self.over_ms
        self.live_budget_ms = min(self.budget_ms, max(left, self.budget_ms / 3))
        return self.live_budget_ms

    def _start(self, camera: Camera, mode: str, image: ImageJob, now: float) -> None:
        if image.renderer is self.renderer and self.before_full_image is not None:
            self.before_full_image()  # e.g. the newest pose, held back while the last image was drawn
        image.renderer.begin_draw(scaled_camera(camera, image.scale), mode)
        self._job = image
        self._job_t0 = time.perf_counter()  # (wall time; `now` may be a test's clock)

    def _continue(self, budget_ms: float, frame_start: float) -> bool:
        """Draw until `budget_ms` after `frame_start` is spent (the pre-pass of a new image counts)."""
        job = self._job
        assert job is not None
        r = job.renderer
        # (the full-resolution image takes the frame's share in one call, not `bounded`: drawn one budget at a time
        # and asking for input between them, orbit -> exact beside two busy processes took 0.523 s against 0.461)
        left = budget_ms - (time.perf_counter() - frame_start) * 1e3
        if not r.continue_draw(max(left, 1.0)):
            return False
        self._job = None
        t = r.last_timings
        self.last_image_ms = t.get("draw", 0.0) + t.get("sort", 0.0) + t.get("preprocess", 0.0)
        self.last_image_wall_ms = (time.perf_counter() - self._job_t0) * 1e3
        self.images += 1
        self._shown = job
        if job.renderer is self.renderer:
            self.full_image_ms = self.last_image_ms / min(1.0, max(job.scale, 1e-3)) ** 2
        if job.live:
            self._adapt(job, self.last_image_ms)
            self._live_wall_ms[0 if job.renderer is self.renderer else 1] = self.last_image_wall_ms
        return True

    def bounded(self, step: Callable[[float], bool], budget_ms: float) -> bool:
        """Run a still view's refinement `step(ms)` (the latent pass and the CNN's input: work in slices of about
        `ms`, at least one; True once finished) until it finishes or `budget_ms` from now is spent, one budget at a
        time, stopping early when `input_probe` reports input: a drag started meanwhile waits for one budget, not
        for all (without a probe: the whole `budget_ms` in one call)."""
        start = time.perf_counter()
        probe = self.input_probe
        while True:
            left = budget_ms - (time.perf_counter() - start) * 1e3
            if step(max(left if probe is None else min(left, self.budget_ms), 1.0)):
                return True
            if probe is None or (time.perf_counter() - start) * 1e3 >= budget_ms or probe():
                return False

    def _adapt(self, job: ImageJob, image_ms: float) -> None:
        """Choose the live scale (of the renderer that drew `job`) from its cost (damped, within limits)."""
        if image_ms <= 0:
            return
        full = job.renderer is self.renderer
        # an image in about LIVE_FRAMES UI frames at what they give to drawing, at most the interactive cost
        aim = min(self.interactive_ms if full else self.lod_interactive_ms, LIVE_FRAMES * self.live_budget_ms)
        factor = math.sqrt(aim / image_ms)
        lo, hi = SCALE_STEP
        new = round(min(1.0, max(self.min_scale, job.scale * min(hi, max(lo, factor)))), 3)
        if full:
            self.interactive_scale = new
        else:
            self.lod_scale = new
