"""The one pipeline from the posed Gaussians uploaded to a renderer to the picture of a view.

The paper's picture is not the splats alone: the splats are composited over the background (C + (1 - A) bg), a
latent image of h + delta_h^G is composited like colour, and the screen-space CNN (`npga_core/model/cnn.py`)
turns both into the picture (its input: `cnn_input`, FORMAT.md section 7; its output clamped to [0, 1] and cut to
the view: `fit_output`).

`ViewImage` carries one view through these stages: splats -> latent -> cnn -> done. Who runs the CNN is a
`CnnStep`: the window's `Refiner` (a copy on its device, on a worker thread) or `InlineCnn` (the CNN itself, in
this thread). All three users go through it:

- the window (`controllers/refining.py`): from the splat image its scheduler finished (`rgb`), `advance` within
  each UI frame's budget (the latent pass in slices, the CNN on the refiner's thread);
- Compare (`comparison/view.py`): from the splats, `advance` within the budget likewise;
- `npga-view render` and `evaluate`: `run`, every stage at once with `InlineCnn` (`refine_frame` when the
  splat image is already there).

Drawing in slices gives the image of drawing at once (the same passes in the same order), so the window, Compare
and the commands show one picture of one view.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from npga_core.camera.cameras import Camera

if TYPE_CHECKING:
    from npga_core.model.cnn import ScreenCNN
    from npga_view.rendering.renderer import SplatRenderer


def cnn_camera(camera: Camera, upsample: int) -> Camera:
    """The camera of a CNN's input image: `camera`'s view with intrinsics divided by the CNN's upsampling factor
    (pixel centres at +0.5 on both grids), the size rounded up so that the output covers the whole image."""
    if upsample == 1:
        return camera
    w, h = -(-camera.width // upsample), -(-camera.height // upsample)
    return Camera(camera.world_to_camera.copy(), camera.fx / upsample, camera.fy / upsample, camera.cx / upsample,
                  camera.cy / upsample, w, h)


def cnn_input(renderer: SplatRenderer, cnn: ScreenCNN, camera: Camera, background=(0.0, 0.0, 0.0),
              rgb: np.ndarray | None = None, latent: np.ndarray | None = None) -> np.ndarray:
    """The CNN's input image of `camera`'s view: [rgb, latent] at the camera's size, or (a CNN on the latent
    channels alone, e.g. Gaussian-Head-Avatar's) the latent channels over their background at the CNN's input
    size (`cnn_camera`). `rgb` and `latent` are used when the caller has them for this camera."""
    return cnn_input_parts(renderer, cnn, camera, background, rgb, latent)()


def cnn_input_parts(renderer: SplatRenderer, cnn: ScreenCNN, camera: Camera, background=(0.0, 0.0, 0.0),
                    rgb: np.ndarray | None = None, latent: np.ndarray | None = None) -> Callable[[], np.ndarray]:
    """`cnn_input` in two steps: the GL passes it needs and its checks now (the thread that holds the context),
    the assembly when the returned function is called (by the CNN's own thread: a new image of the whole view,
    ~70 ms at 960 x 900 on these machines, most of it the first touch of its pages)."""
    cfg = cnn.config
    if cfg.in_channels != cfg.input_channels(renderer.latent_dim):
        raise ValueError(f"the CNN takes {cfg.in_channels} channels, the avatar renders "
                         f"{cfg.input_channels(renderer.latent_dim)}")
    if cfg.input == "latent":
        small = cnn_camera(camera, cfg.upsample)
        lat = latent if latent is not None and small is camera else renderer.render_latent(small)
        alpha = renderer.render(small, mode="alpha") if cfg.latent_background else None
        return lambda: cnn.assemble(None, lat, alpha)
    if rgb is None:
        rgb = renderer.render(camera, background)
    if renderer.latent_dim and latent is None:
        latent = renderer.render_latent(camera)
    colour = rgb
    return lambda: cnn.assemble(colour, latent, None)


def made(image: np.ndarray | Callable[[], np.ndarray]) -> np.ndarray:
    """A CNN input given as the image or as the function that assembles it (`cnn_input_parts`)."""
    return image() if callable(image) else image


def fit_output(image: np.ndarray, camera: Camera) -> np.ndarray:
    """A CNN's output cut to the camera's size (an upsampling CNN's input size was rounded up)."""
    return image if image.shape[:2] == (camera.height, camera.width) else \
        np.ascontiguousarray(image[: camera.height, : camera.width])


def wants_full_latent(cnn: ScreenCNN, latent_dim: int) -> bool:
    """The CNN takes the latent image at the view's own size (drawn in slices by `ViewImage`); a CNN that
    upsamples takes a smaller one, which `cnn_input` draws itself."""
    return latent_dim > 0 and cnn.config.upsample == 1


class CnnStep(Protocol):
    """Who runs the CNN of a `ViewImage`: `start` takes its input image, or the function that assembles it from
    what the GL thread drew (`cnn_input_parts`); `result` gives the output (clamped to [0, 1], cut to `camera`)
    once it is done, else None."""

    @property
    def cnn(self) -> ScreenCNN | None: ...

    def start(self, key: object, image: np.ndarray | Callable[[], np.ndarray], camera: Camera) -> None: ...

    def result(self, key: object) -> np.ndarray | None: ...


class InlineCnn:
    """The CNN run in this thread when started (`render`, `evaluate`): `runner` runs it on an input image
    (default `cnn.refine`; the commands pass one that a signal interrupts). Milliseconds go to `timings["cnn"]`."""

    def __init__(self, cnn: ScreenCNN, runner: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self._cnn = cnn
        self._runner = runner or cnn.refine
        self._done: tuple[object, np.ndarray] | None = None
        self.timings: dict[str, float] = {}

    @property
    def cnn(self) -> ScreenCNN:
        return self._cnn

    def start(self, key: object, image: np.ndarray | Callable[[], np.ndarray], camera: Camera) -> None:
        t0 = time.perf_counter()
        self._done = (key, fit_output(self._runner(made(image)), camera))
        self.timings["cnn"] = (time.perf_counter() - t0) * 1e3

    def result(self, key: object) -> np.ndarray | None:
        return self._done[1] if self._done is not None and self._done[0] == key else None


class ViewImage:
    """One view of the Gaussians uploaded to `renderer` through the pipeline (see the module docstring).

    `cnn` None: the picture is the splats over `background`. `rgb`: the splat image over the background when the
    caller has it (the window's scheduler drew it); else the splats are drawn first. `key` names the view for the
    CNN step (a new image of another view replaces an unfinished one there). `stage` is where it is, `image` the
    picture once `stage` is "done"; `timings` has milliseconds of "latent" (the CNN's input) and "cnn".
    """

    def __init__(self, renderer: SplatRenderer, camera: Camera, background=(0.0, 0.0, 0.0),
                 cnn: CnnStep | None = None, key: object = None, rgb: np.ndarray | None = None) -> None:
        self.renderer, self.camera, self.cnn, self.key = renderer, camera, cnn, key
        self.background = tuple(float(v) for v in background)
        self.rgb = rgb
        self.image: np.ndarray | None = None
        self.timings: dict[str, float] = {}
        self._latent: np.ndarray | None = None
        self._latent_begun = False  # this view's latent pass was begun (the renderer's may be another's)
        net = cnn.cnn if cnn is not None else None
        self.stage = "splats" if rgb is None and (net is None or net.config.input != "latent") else "latent"
        if self.stage == "splats":  # (a CNN on the latent channels alone takes no splat image)
            renderer.begin_draw(camera)

    @property
    def done(self) -> bool:
        return self.stage == "done"

    def advance(self, budget_ms: float = math.inf) -> bool:
        """Draw or wait for about `budget_ms` (at least one slice); True once the picture is done."""
        if self.stage == "splats":
            if not self.renderer.continue_draw(budget_ms):
                return False
            self.rgb = self.renderer.front_image(self.background)
            self.stage = "latent"
            if self.cnn is not None and self._full_latent():
                return False  # the latent pass from the next frame's budget
        if self.stage == "latent":
            if self.cnn is None or self.cnn.cnn is None:
                self.image, self.stage = self.rgb, "done"
                return True
            if self._full_latent():
                t_latent = time.perf_counter()
                if not self._latent_slices(budget_ms):
                    return False
                if (time.perf_counter() - t_latent) * 1e3 >= budget_ms:
                    return False  # the CNN's input (~70 ms of compositing at 1360 x 900) in the next call
            t0 = time.perf_counter()
            image = cnn_input_parts(self.renderer, self.cnn.cnn, self.camera, self.background, self.rgb, self._latent)
            self.timings["latent"] = (time.perf_counter() - t0) * 1e3  # (the assembly is the CNN step's)
            self._latent = None
            self.cnn.start(self.key, image, self.camera)
            self.stage = "cnn"
        if self.stage == "cnn":
            out = self.cnn.result(self.key) if self.cnn is not None else None
            if out is None:
                return False
            self.image, self.stage = out, "done"
        return self.stage == "done"

    def _full_latent(self) -> bool:
        cnn = self.cnn.cnn if self.cnn is not None else None
        return cnn is not None and wants_full_latent(cnn, self.renderer.latent_dim)

    def _latent_slices(self, budget_ms: float) -> bool:
        """The latent image of the view in slices (the whole pass at 960 x 900 took 1.1 s on llvmpipe: inside
        one UI frame it froze the window); True once it is finished."""
        r = self.renderer
        if self._latent is None:
            if not (self._latent_begun and r.latent_drawing):  # not begun, or dropped by another pass: (again)
                r.begin_latent(self.camera)
                self._latent_begun = True
            self._latent = r.continue_latent(budget_ms)
        return self._latent is not None

    def run(self) -> np.ndarray:
        """Every stage at once (the CNN step then must finish when started: `InlineCnn`); the picture."""
        while not self.advance(math.inf):
            if self.stage == "cnn":
                raise RuntimeError("the CNN step did not finish when started (use InlineCnn to run at once)")
        assert self.image is not None
        return self.image

    def cancel(self) -> None:
        """Drop the unfinished passes of this view (the CNN step's own job is the caller's to cancel)."""
        if self.stage == "splats":
            self.renderer.cancel_draw()
        elif self.stage == "latent" and self._latent_begun and self.renderer.latent_drawing:
            self.renderer.cancel_latent()


def refine_frame(renderer: SplatRenderer, cnn: ScreenCNN, camera: Camera, background=(0.0, 0.0, 0.0),
                 rgb: np.ndarray | None = None, timings: dict[str, float] | None = None,
                 runner: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """The CNN's picture (H, W, 3) float32 of the Gaussians uploaded to `renderer`, seen by `camera`, at once:
    `ViewImage` with `InlineCnn(cnn, runner)`; `rgb` is the splat image over `background` when the caller has it.
    Milliseconds of the stages go to `timings` ("latent": the passes, "cnn")."""
    step = InlineCnn(cnn, runner)
    view = ViewImage(renderer, camera, background, step, rgb=rgb)
    out = view.run()
    if timings is not None:
        timings.update(latent=view.timings.get("latent", 0.0), cnn=step.timings.get("cnn", 0.0))
    return out
