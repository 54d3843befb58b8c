"""Screen-space refinement in the viewer: the avatar's CNN on the full-resolution image, and latent views.

The paper's final image is not the splats alone: the posed Gaussians are rasterised into an RGB image and a
latent image of h + delta_h^G, and the screen-space CNN turns both into the picture (`npga_core/model/cnn.py`).

The stages of that picture (splats, latent pass, the CNN's input and output) are those of
`npga_view/rendering/pipeline.py`, the one pipeline of the window, Compare and the commands.

- `Refiner` is what the window and Compare use: it keeps a copy of the avatar's CNN on a torch device (a GPU when
  one is given) and is the pipeline's CNN step (`start` + `result`: the CNN on a worker thread while the UI keeps
  drawing; `submit` makes the input and starts; `refine` does all at once); it makes the latent views
  (`latent_view`: PCA of h as RGB, or one channel through a colour map), decides from the viewer state what to
  show (`image_for`), and uploads and presents an image (`upload`, `present`). `last_timings` holds the
  milliseconds of each stage ("latent", "cnn", ...).

Avatars without a CNN are not touched: `image_for` returns None (unless a latent view of their h is asked for)
and the window draws the splats as before.
"""

from __future__ import annotations

import copy
import threading
import time
import warnings
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING

import moderngl
import numpy as np
import torch

from npga_core.camera.cameras import Camera
from npga_core.inspection.colouring import FeaturePCA, colour_map, robust_range
from npga_core.model.cnn import ScreenCNN, run_cnn, run_cnn_steps
from npga_core.posing.device import resolve_device
from npga_view.rendering.factory import choose_path
from npga_view.rendering.pipeline import cnn_input_parts, fit_output, made, refine_frame, wants_full_latent
from npga_view.rendering.shader_source import load_shader
from npga_view.rendering.uniforms import uniform

if TYPE_CHECKING:
    from npga_core.model.avatar import Avatar
    from npga_view.rendering.renderer import SplatRenderer

#: Values of `ViewerState.latent_view`: the colour image, PCA of h as RGB, or one channel of h.
LATENT_VIEWS = ("off", "pca", "channel")


def _traced_copy(cnn: ScreenCNN, channels: int, device: torch.device) -> torch.nn.Module:
    """A traced copy of the CNN (see `_run_traced`); the module itself where tracing is unavailable (torch marks
    `torch.jit.trace` as deprecated)."""
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", torch.jit.TracerWarning)  # instance norm's size check, a constant
            return torch.jit.trace(cnn, torch.zeros(1, channels, 16, 16, device=device))
    except Exception:  # noqa: BLE001 - any failure of the optional tracing falls back to eager
        return cnn


def _run_traced(traced: torch.nn.Module, device: torch.device, image: np.ndarray) -> np.ndarray:
    """The CNN on a stacked [rgb, latent] image through its traced copy: one call into C++ that does not need
    Python's GIL between layers, so a worker thread is not starved by GL calls holding it (measured: 0.35 s
    instead of 0.82 s for a 0.22 s CNN beside a GIL-holding loop); synchronised on a GPU for the timings."""
    out = run_cnn(traced, image, device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return out


#: rows of one band of the window's CNN on a CPU (`_run_banded`): a running refinement stops within one band
BAND_ROWS = 96


def _run_banded(traced: torch.nn.Module, device: torch.device, image: np.ndarray, halo: int,
                cancelled: Callable[[], bool], rows: int = BAND_ROWS) -> np.ndarray | None:
    """The CNN on horizontal bands of `rows` rows, each with `halo` rows of context above and below (the CNN's
    receptive radius: the band's output is then that of the whole image, up to float rounding), so that a
    refinement the view has left stops after one band (None) instead of holding the CPU's cores for the whole
    image (about 1 s at 960 x 900 on a 2-core CPU)."""
    height = image.shape[0]
    out: np.ndarray | None = None
    for y0 in range(0, height, rows):
        if cancelled():
            return None
        y1 = min(height, y0 + rows)
        a, b = max(0, y0 - halo), min(height, y1 + halo)
        part = _run_traced(traced, device, image[a:b])
        if out is None:
            out = np.empty((height, image.shape[1], part.shape[2]), np.float32)
        out[y0:y1] = part[y0 - a:y1 - a]
    return out


class Refiner:
    """The window's screen-space refinement and latent views; see the module docstring.

    `ctx` is the window's moderngl context (for `upload`/`present`), `device` the torch device of the CNN
    ("cpu", "cuda", "cuda:1", "mps", "auto": `npga_core.posing.device.resolve_device`). Call `set_avatar`
    whenever the avatar (or its CNN or latent features) changes.
    """

    def __init__(self, ctx: moderngl.Context, device: str | torch.device = "cpu") -> None:
        self.ctx = ctx
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        self.cnn: ScreenCNN | None = None
        self._traced: torch.nn.Module | None = None
        self.latent_dim = 0
        self._pca: FeaturePCA | None = None
        self._ranges: list[tuple[float, float]] = []
        self.last_timings: dict[str, float] = {}
        self._texture: moderngl.Texture | None = None
        # the composite shaders of the renderer path this context gets (4.3, or the 4.1 twins on macOS)
        prefix = "gl41_" if choose_path(ctx) == "41" else ""
        self._program = ctx.program(vertex_shader=load_shader(prefix + "fullscreen.vert"),
                                    fragment_shader=load_shader(prefix + "composite.frag"))
        self._vao = ctx.vertex_array(self._program, [])
        self._pool: ThreadPoolExecutor | None = None
        self._job: tuple[object, Future, dict[str, float], threading.Event] | None = None
        self._lock = threading.Lock()
        self._source: object = None  # the avatar's CNN that `cnn` is a copy of

    # --- avatar -------------------------------------------------------------------------------------
    def set_avatar(self, avatar: Avatar | None) -> None:
        """Take the avatar's CNN (a copy on `device`; one that does not take 3 + H channels is ignored) and fit the
        PCA and channel ranges of its canonical h."""
        self.cancel()
        cnn = None if avatar is None else avatar.cnn
        latent = None if avatar is None else avatar.cloud.latent
        latent_dim = 0 if latent is None else int(latent.shape[1])
        # an edit keeps the avatar's CNN: its copy and trace (0.4 s for the demo's) are kept
        same = cnn is not None and cnn is self._source and latent_dim == self.latent_dim
        self.latent_dim, self._source = latent_dim, cnn
        if not same:
            self.cnn, self._traced = None, None
            if cnn is not None and cnn.config.in_channels == cnn.config.input_channels(latent_dim):
                self.cnn = copy.deepcopy(cnn).to(self.device).eval()
                for p in self.cnn.parameters():
                    p.requires_grad_(False)
                self._traced = _traced_copy(self.cnn, self.cnn.config.in_channels, self.device)
        self._pca = None
        self._ranges = []
        if self.latent_dim:
            h = np.asarray(latent, np.float64)
            if len(h) >= 2:
                self._pca = FeaturePCA.fit(h)
            self._ranges = [robust_range(h[:, k], symmetric=bool(len(h) and h[:, k].min() < 0.0 < h[:, k].max()))
                            for k in range(self.latent_dim)]  # (an avatar of 0 Gaussians: default ranges)

    @property
    def has_cnn(self) -> bool:
        """The avatar has a CNN that fits its latent features (3 + H input channels, or H alone)."""
        return self.cnn is not None

    @property
    def wants_full_latent(self) -> bool:
        """The CNN takes the latent image at the view's own size (the window then draws it in slices); a CNN
        that upsamples takes a smaller one, which `submit` draws itself."""
        return self.cnn is not None and wants_full_latent(self.cnn, self.latent_dim)

    def shows(self, use_cnn: bool, latent_view: str, mode: str = "rgb") -> str | None:
        """What the window should show for these state values: "refined", "latent" or None (the raw splats, as
        without a refiner). Only the rgb mode is refined or replaced."""
        if mode != "rgb":
            return None
        if latent_view in ("pca", "channel") and self.latent_dim:
            return "latent"
        if use_cnn and self.has_cnn:
            return "refined"
        return None

    # --- images -------------------------------------------------------------------------------------
    def refine(self, renderer: SplatRenderer, camera: Camera, background=(0.0, 0.0, 0.0),
               rgb: np.ndarray | None = None) -> np.ndarray:
        """The refined RGB image (H, W, 3) float32 (`refine_frame` with this refiner's CNN); times in
        `last_timings`."""
        if self.cnn is None:
            raise ValueError("the avatar has no CNN for its latent features")
        timings: dict[str, float] = {}
        out = refine_frame(renderer, self.cnn, camera, background, rgb, timings, self._run)
        self.last_timings = timings
        return out

    def _run(self, image: np.ndarray) -> np.ndarray:
        traced = self._traced
        assert traced is not None
        return _run_traced(traced, self.device, image)

    def latent_view(self, renderer: SplatRenderer, camera: Camera, background=(0.0, 0.0, 0.0), view: str = "pca",
                    channel: int = 0, alpha: np.ndarray | None = None, latent: np.ndarray | None = None) -> np.ndarray:
        """The latent image as RGB (H, W, 3) float32 over `background`: per pixel the composited h + delta_h
        divided by the alpha (the mean latent seen there), coloured by the PCA of the canonical h ("pca") or by
        a colour map of one channel over its canonical range ("channel": coolwarm when signed, else viridis),
        then composited with the alpha over the background."""
        if self.latent_dim == 0 or renderer.latent_dim == 0:
            raise ValueError("the avatar has no latent features h")
        if view not in ("pca", "channel"):
            raise ValueError(f"unknown latent view {view!r}; choose pca or channel")
        t0 = time.perf_counter()
        if latent is None:  # the window passes the latent image it drew in slices
            latent = renderer.render_latent(camera)
        if alpha is None:  # the window passes the alpha of the image on screen (no second draw)
            alpha = renderer.render(camera, mode="alpha")
        t1 = time.perf_counter()
        mean = latent / np.maximum(alpha, 1e-6)[..., None]
        flat = mean.reshape(-1, mean.shape[2])
        if view == "pca":
            if self._pca is None:
                raise ValueError("the avatar has too few Gaussians for a PCA of h")
            colours = self._pca.colours(flat)
        else:
            if not 0 <= channel < self.latent_dim:
                raise ValueError(f"no latent channel {channel}; the avatar has {self.latent_dim}")
            lo, hi = self._ranges[channel]
            signed = lo < 0.0 < hi
            colours = colour_map((flat[:, channel] - lo) / max(hi - lo, 1e-12), "coolwarm" if signed else "viridis")
        a = alpha[..., None]
        bg = np.asarray(background, np.float32).reshape(1, 1, 3)
        out = colours.reshape(mean.shape[:2] + (3,)) * a + (1.0 - a) * bg
        self.last_timings = {"latent": (t1 - t0) * 1e3, "colour": (time.perf_counter() - t1) * 1e3}
        return out.astype(np.float32)

    def image_for(self, renderer: SplatRenderer, camera: Camera, background, use_cnn: bool, latent_view: str,
                  latent_channel: int = 0, mode: str = "rgb") -> np.ndarray | None:
        """The image the window shows for these state values (`shows`), or None for the raw splats."""
        what = self.shows(use_cnn, latent_view, mode)
        if what == "latent":
            return self.latent_view(renderer, camera, background, latent_view, latent_channel)
        if what == "refined":
            return self.refine(renderer, camera, background)
        return None

    # --- the CNN on a worker thread ---------------------------------------------------------------------
    def submit(self, key: object, renderer: SplatRenderer, camera: Camera, background=(0.0, 0.0, 0.0),
               rgb: np.ndarray | None = None, latent: np.ndarray | None = None) -> None:
        """Start refining: the GL passes now (this thread holds the context), the CNN on a worker thread.

        `key` names what is refined (e.g. camera key, content version, background); `result(key)` returns the
        image once it is done. A new submit replaces an unfinished one (whose result is dropped). `rgb` and `latent`
        are the colour image over the background and the latent image of `camera` when the caller has them.
        """
        if self.cnn is None:
            raise ValueError("the avatar has no CNN for its latent features")
        if renderer.latent_dim != self.latent_dim:
            raise ValueError(f"the uploaded Gaussians have {renderer.latent_dim} latent channels, the avatar "
                             f"{self.latent_dim}")
        t1 = time.perf_counter()
        image = cnn_input_parts(renderer, self.cnn, camera, background, rgb, latent)
        self.start(key, image, camera, {"latent": (time.perf_counter() - t1) * 1e3})

    def start(self, key: object, image: np.ndarray | Callable[[], np.ndarray], camera: Camera,
              timings: dict[str, float] | None = None) -> None:
        """Run the CNN on the worker thread on its input `image` (`pipeline.cnn_input`, or the function that
        assembles it, `cnn_input_parts`, called there too): the pipeline's CNN step (`result(key)` gives its output
        cut to `camera`; `last_timings` ms of "input", the assembly, and "cnn"). A new start replaces an
        unfinished one."""
        if self.cnn is None:
            raise ValueError("the avatar has no CNN for its latent features")
        timings = dict(timings or {})
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="npga-cnn")
        traced, device = self._traced, self.device
        assert traced is not None
        halo = self.cnn.config.band_halo()  # None: the CNN needs the whole image at once (instance norm, upsampling)
        stop = threading.Event()

        cnn = self.cnn

        def run() -> np.ndarray | None:
            t1 = time.perf_counter()
            x = made(image)
            t2 = time.perf_counter()
            timings["input"] = (t2 - t1) * 1e3
            if device.type == "cpu" and halo is not None:  # in bands: a refinement the person left stops early
                out = _run_banded(traced, device, x, halo, stop.is_set)
            elif device.type == "cpu":  # the whole image, one operation at a time: it stops between two
                out = run_cnn_steps(cnn, x, stop.is_set)
            else:
                out = _run_traced(traced, device, x)
            timings["cnn"] = (time.perf_counter() - t2) * 1e3
            return None if out is None else fit_output(out, camera)

        with self._lock:
            if self._job is not None:
                self._job[3].set()
            self._job = (key, self._pool.submit(run), timings, stop)

    @property
    def busy(self) -> bool:
        """A submitted refinement is still running."""
        with self._lock:
            return self._job is not None and not self._job[1].done()

    def pending_key(self) -> object | None:
        """The key of the submitted refinement (finished or not), or None."""
        with self._lock:
            return None if self._job is None else self._job[0]

    def result(self, key: object) -> np.ndarray | None:
        """The refined image of `key` once its CNN has finished (then `last_timings` are its times), else None.
        Errors of the CNN are raised here."""
        with self._lock:
            job = self._job
        if job is None or job[0] != key or not job[1].done():
            return None
        out = job[1].result()
        self.last_timings = dict(job[2])
        return out

    def cancel(self) -> None:
        """Forget the submitted refinement; a running CNN stops after the band it is on (on a GPU it finishes, and
        its result is dropped)."""
        with self._lock:
            if self._job is not None:
                self._job[3].set()
            self._job = None

    # --- on screen ----------------------------------------------------------------------------------
    def upload(self, image: np.ndarray) -> moderngl.Texture:
        """Put an (H, W, 3) image in [0, 1] (rows top to bottom, as `refine` returns it) into this refiner's
        RGBA8 texture (reallocated when the size changes); `present` draws it."""
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) image, got {image.shape}")
        h, w = image.shape[:2]
        t0 = time.perf_counter()
        rgba = np.empty((h, w, 4), np.uint8)
        rgba[..., :3] = np.clip(image * 255.0 + 0.5, 0.0, 255.0)
        rgba[..., 3] = 255
        if self._texture is None or self._texture.size != (w, h):
            if self._texture is not None:
                self._texture.release()
            self._texture = self.ctx.texture((w, h), 4, dtype="f1")
        self._texture.write(rgba.tobytes())
        self.last_timings["upload"] = (time.perf_counter() - t0) * 1e3
        return self._texture

    @property
    def texture(self) -> moderngl.Texture | None:
        """The texture of the last `upload`."""
        return self._texture

    def present(self, framebuffer: moderngl.Framebuffer, viewport: tuple[int, int, int, int] | None = None,
                flip_y: bool = True) -> None:
        """Draw the last uploaded image into `framebuffer` (a window's: `flip_y` shows it upright), scaled to the
        viewport (bilinear when the sizes differ), like `SplatRenderer.present`."""
        if self._texture is None:
            return
        framebuffer.use()
        self.ctx.viewport = viewport or (0, 0, *framebuffer.size)
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        vp = self.ctx.viewport
        scaled = self._texture.size != (vp[2], vp[3])
        self._texture.filter = (moderngl.LINEAR, moderngl.LINEAR) if scaled else (moderngl.NEAREST, moderngl.NEAREST)
        self._texture.use(0)
        uniform(self._program, "u_image").value = 0
        uniform(self._program, "u_background").value = (0.0, 0.0, 0.0)
        uniform(self._program, "u_flip_y").value = 1 if flip_y else 0
        uniform(self._program, "u_colour_scale").value = 1.0  # an RGBA8 image at its true colour
        self._vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        """Free the GL objects and stop the worker thread."""
        self.cancel()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._texture is not None:
            self._texture.release()
            self._texture = None
        self._vao.release()
        self._program.release()
