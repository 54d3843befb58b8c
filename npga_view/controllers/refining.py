"""`RefineController`: the window's screen-space refinement (the paper's CNN) and latent views of h.

While the view changes, the window shows the raw splats at the live scale (labelled "splats (refining)").
Once the full-resolution image of the current view is on screen (`DrawScheduler.settled`), this controller
takes that image's RGB and alpha, runs the latent pass and either the CNN (on a worker thread of the
`Refiner`, so the UI keeps running) or the latent colouring, uploads the result and presents it instead of the
splats until the view changes again. Avatars without a CNN (and without h) are untouched.
"""

from __future__ import annotations

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.avatar import Avatar
from npga_view.panels.info import AppInfo
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
        self.info = info
        self._key: tuple | None = None  # what the uploaded refined/latent image shows

    def set_avatar(self, avatar: Avatar | None) -> None:
        """A new avatar (or an edited one): take its CNN and latent statistics."""
        self.refiner.set_avatar(avatar)
        self._key = None

    def present(self, camera: Camera, framebuffer, viewport: tuple[int, int, int, int]) -> bool:
        """Present the refined or latent image of the view if it is ready (True), else leave it to the splats."""
        st, info = self.state, self.info
        what = self.refiner.shows(st.use_cnn, st.latent_view, st.mode)
        if what is None:
            self.refiner.cancel()
            info.shown = "splats"
            return False
        if not self.draws.settled:  # the view changed: a refinement still running is of a view left behind
            self.refiner.cancel()
            info.shown = "splats (refining)"
            return False
        bg = tuple(float(v) for v in st.background)
        key = (self.draws.shown_target, what, st.latent_view, st.latent_channel, bg)
        if key != self._key and not self._compute(key, what, camera, bg):
            info.shown = "splats (refining)"
            return False
        self.refiner.present(framebuffer, viewport, flip_y=True)
        info.shown = what
        return True

    def _front(self) -> np.ndarray:
        """The finished splat image on screen: premultiplied RGBA, rows top to bottom."""
        r = self.renderer
        w, h = r.image_size
        return r._read(r._fbo, 0, w, h)

    def _compute(self, key: tuple, what: str, camera: Camera, bg: tuple[float, float, float]) -> bool:
        refiner, info = self.refiner, self.info
        try:
            if what == "latent":
                alpha = self._front()[..., 3]
                image = refiner.latent_view(self.renderer, camera, bg, self.state.latent_view,
                                            self.state.latent_channel, alpha=alpha)
            else:
                if refiner.pending_key() != key:
                    front = self._front()
                    rgb = front[..., :3] + (1.0 - front[..., 3:4]) * np.asarray(bg, np.float32)
                    refiner.submit(key, self.renderer, camera, bg, rgb=rgb)
                    return False
                image = refiner.result(key)
                if image is None:
                    return False
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
