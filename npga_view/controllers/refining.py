"""`RefineController`: the window's screen-space refinement (the paper's CNN) and latent views of h.

While the view changes, the window shows the raw splats at the live scale (labelled "splats (refining)").
Once the full-resolution image of the current view is on screen (`DrawScheduler.settled`), this controller
takes that image's RGB and alpha, runs the latent pass and either the CNN (on a worker thread of the
`Refiner`, so the UI keeps running) or the latent colouring, uploads the result and presents it instead of the
splats. When the view changes, the refined image stays on screen until the scheduler has finished a splat image
of the new view (as the splat image itself would), and a refinement still running is cancelled. Avatars without
a CNN (and without h) are untouched.
"""

from __future__ import annotations

import time
from typing import cast

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.avatar import Avatar
from npga_view.display import AppInfo
from npga_view.document import AvatarOpened, CloudChanged, Subscriptions
from npga_view.rendering.pipeline import ViewImage
from npga_view.rendering.refinement import Refiner
from npga_view.rendering.renderer import SplatRenderer
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.state import ViewerState


class RefineController:
    """Owned by the app; `present` once per UI frame after the splats were drawn."""

    def __init__(self, refiner: Refiner, renderer: SplatRenderer, draws: DrawScheduler, state: ViewerState,
                 info: AppInfo):
        self.refiner = refiner
        self.renderer = renderer
        self.draws = draws
        self.state = state
        self.info = info  # the display snapshot this controller writes what the view shows into
        self.shown = "splats"  # "splats", "refined", "latent" or "splats (refining)"
        self._key: tuple | None = None  # what the uploaded refined/latent image shows
        self._latent_for: tuple | None = None  # what the latent image being drawn in slices is for
        self._latent: np.ndarray | None = None  # that latent image once finished
        self._view: ViewImage | None = None  # the refined image of the view on its way (the one pipeline)
        self._images = -1  # the scheduler's finished images when this controller last looked (`update`)

    def set_avatar(self, avatar: Avatar | None) -> None:
        """A new avatar (or an edited one): take its CNN and latent statistics."""
        self.refiner.set_avatar(avatar)
        self._key = None

    def subscriptions(self) -> Subscriptions:
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._avatar)
        s.subscribe(CloudChanged, self._avatar)
        return s

    def _avatar(self, e: AvatarOpened | CloudChanged) -> None:
        self.set_avatar(e.avatar)

    def present(self, camera: Camera, framebuffer, viewport: tuple[int, int, int, int]) -> bool:
        """Present the refined or latent image of the view if it is ready (True), else leave it to the splats."""
        if not self.update(camera):
            return False
        self.draw(framebuffer, viewport)
        return True

    def draw(self, framebuffer, viewport: tuple[int, int, int, int]) -> None:
        """Draw the refined or latent image (`update` said it is ready) into `viewport` of `framebuffer`."""
        self.refiner.present(framebuffer, viewport, flip_y=True)

    @property
    def key(self) -> tuple | None:
        """What the refined image on screen is of (the splat image, view, latent channel, background)."""
        return self._key

    def update(self, camera: Camera) -> bool:
        """One UI frame: start, continue or drop the refinement of the view; True when its refined or latent image
        is ready to be shown instead of the splats (`draw`)."""
        st = self.state
        what = self.refiner.shows(st.use_cnn, st.latent_view, st.mode)
        if what is None:
            self.refiner.cancel()
            self._drop_latent()
            self._set_shown("splats")
            return False
        bg = cast(tuple[float, float, float], tuple(float(v) for v in st.background))
        key = (self.draws.shown_target, what, st.latent_view, st.latent_channel, bg)
        if self.renderer.latent_dim != self.refiner.latent_dim:  # nothing uploaded yet (or not this avatar's)
            self._set_shown("splats")
            return False
        if not self.draws.settled:  # the view changed: a refinement still running is of a view left behind
            self.refiner.cancel()
            self._drop_latent()
        # a splat image finished in this frame is shown in it: its refinement starts in the next frame (read-back,
        # latent pass and CNN input took 75-100 ms on llvmpipe, which delayed the full-resolution image by as much)
        fresh, self._images = self._images != self.draws.images, self.draws.images
        if not self.draws.settled or self.draws.interacting:  # (or a change is on its way: its image first)
            ready = key == self._key  # no new splat image yet: the refined one of the image on screen stays
        else:
            ready = key == self._key or (not fresh and self._compute(key, what, camera, bg))
        if not ready:
            self._set_shown("splats (refining)")
            return False
        self._set_shown(what)
        return True

    @property
    def complete(self) -> bool:
        """The image on screen is what the state asks for: the refined or latent image once it is ready, or the
        splats where nothing is refined (scripted screenshots wait for this)."""
        return self.shown != "splats (refining)"

    def _set_shown(self, what: str) -> None:
        """What the view shows now (its own state; copied to `AppInfo.shown` for the panels)."""
        self.shown = what
        self.info.shown = what

    def _drop_latent(self) -> None:
        if self._latent_for is not None:
            self.renderer.cancel_latent()
        self._latent_for = self._latent = None
        if self._view is not None:
            self._view.cancel()
            self._view = None

    def _latent_image(self, key: tuple, camera: Camera) -> np.ndarray | None:
        """The latent image of the view, drawn in slices within the scheduler's budget over UI frames (the whole
        pass at 960 x 900 took 1.1 s on llvmpipe: inside one frame it froze the window); None until finished."""
        r = self.renderer
        if self._latent_for != key:
            self._drop_latent()
            r.begin_latent(camera)
            self._latent_for = key
        if self._latent is None:
            t0 = time.perf_counter()
            self._latent = r.continue_latent(self.draws.frame_budget(False))
            self.draws.drew_outside((time.perf_counter() - t0) * 1e3)
            if self._latent is None and not r.latent_drawing:  # dropped by another pass: start again
                self._latent_for = None
        return self._latent

    def _compute(self, key: tuple, what: str, camera: Camera, bg: tuple[float, float, float]) -> bool:
        refiner, info = self.refiner, self.info
        try:
            if what == "latent":
                latent = self._latent_image(key, camera)
                if latent is None:
                    return False
                alpha = self.renderer.front_rgba()[..., 3]
                image = refiner.latent_view(self.renderer, camera, bg, self.state.latent_view,
                                            self.state.latent_channel, alpha=alpha, latent=latent)
                self._drop_latent()
            else:
                view = self._view
                if view is None or view.key != key or (view.stage == "cnn" and refiner.pending_key() != key):
                    self._drop_latent()  # a new view (or its CNN job was cancelled): from the splat image on screen
                    rgb = self.renderer.front_image(bg)
                    self._view = ViewImage(self.renderer, camera, bg, refiner, key, rgb)
                    return False  # the read-back in this frame (20-40 ms at 1360 x 900), the latent pass from the next
                t0 = time.perf_counter()
                stage = view.stage
                done = self.draws.bounded(view.advance, self.draws.frame_budget(False))
                if stage == "latent":  # the latent pass in slices within the frame's budget
                    self.draws.drew_outside((time.perf_counter() - t0) * 1e3)
                if not done:
                    return False
                image = cast(np.ndarray, view.image)
                self._view = None
                info.cnn_ms = refiner.last_timings.get("cnn", 0.0)
                info.timings["cnn"] = info.cnn_ms
        except (ValueError, RuntimeError) as e:
            self.state.report(f"refinement: {e}")
            self.state.use_cnn, self.state.latent_view = False, "off"
            return False
        refiner.upload(image)
        self._key = key
        return True

    def release(self) -> None:
        self.refiner.release()
