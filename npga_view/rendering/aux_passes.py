"""The passes of `SplatRenderer` besides the colour image: latent features (for the screen-space CNN), Gaussian ids
(picking), what the last pre-pass kept, and the inspection frame with its line overlay.

A mixin: `SplatRenderer` inherits these; they use its buffers (`splats`, `order`, `latent`), its pre-pass
(`_prepare`, which drops an unfinished sliced image when the camera differs) and its programs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_view.rendering.lines import LinePass, Lines
from npga_view.rendering.slice_cost import SliceCost
from npga_view.rendering.uniforms import uniform

if TYPE_CHECKING:
    from collections.abc import Mapping

    from npga_core.inspection.inspector import InspectFrame
    from npga_core.model.gaussians import PosedGaussians

PICK_THRESHOLD = 0.2  # alpha a Gaussian must reach at a pixel to be picked there


@dataclass
class _LatentJob:
    """A latent image being drawn in slices (`begin_latent` / `continue_latent`)."""

    prepared: tuple | None  # the pre-pass it draws from (dropped when another one replaces it)
    width: int
    height: int
    passes: list[tuple[int, int]]  # (first channel, channels) of each pass
    out: np.ndarray
    pass_index: int = 0
    next: int = 0  # next sorted position of the current pass
    first_slice: int | None = None  # instances of the first slice when given (later ones: `SliceCost`)
    slices: int = 0
    draw_ms: float = 0.0


class AuxiliaryPasses:
    """Latent, id and coverage passes; see the module docstring."""

    if TYPE_CHECKING:  # provided by `SplatRenderer`
        ctx: moderngl.Context
        max_targets: int
        style: str
        point_px: float
        last_timings: dict[str, float]
        _count: int
        _latent_dim: int
        _visible: int
        _prepared: tuple | None
        _buffers: dict[str, moderngl.Buffer]
        _latent_progs: dict[int, tuple[moderngl.Program, moderngl.VertexArray]]
        _latent_fbo: tuple[int, moderngl.Framebuffer, list[moderngl.Texture]] | None
        _latent_job: _LatentJob | None
        latent_slices: SliceCost
        _footprints: np.ndarray | None
        _id_prog: moderngl.Program
        _id_vao: moderngl.VertexArray
        _id_target: tuple[moderngl.Texture, moderngl.Framebuffer] | None
        _lines: Lines | None

        @staticmethod
        def _load_shader(name: str, defines: Mapping[str, object] | None = None) -> str: ...
        def _activate(self) -> None: ...
        def _prepare(self, camera: Camera, flip_y: bool) -> None: ...
        def _begin_pass(self, fbo: moderngl.Framebuffer, viewport: tuple[int, int, int, int]) -> None: ...
        def _bind_splats(self, prog: moderngl.Program) -> None: ...
        def _bind_latent(self, prog: moderngl.Program) -> None: ...
        def _set_style(self, prog: moderngl.Program, camera: Camera) -> None: ...
        def _read(self, fbo: moderngl.Framebuffer, attachment: int, width: int, height: int) -> np.ndarray: ...
        def set_gaussians(self, posed: PosedGaussians) -> None: ...

    def _program(self, vertex: str, fragment: str, defines: Mapping[str, object] | None = None) -> moderngl.Program:
        """A GL program (of this renderer's shader path) of two shaders/ files, `defines` added to both."""
        return self.ctx.program(vertex_shader=self._load_shader(vertex, defines),
                                fragment_shader=self._load_shader(fragment, defines))

    def _latent_program(self, targets: int) -> tuple[moderngl.Program, moderngl.VertexArray]:
        if targets not in self._latent_progs:
            defines = {"NUM_TARGETS": targets}
            prog = self._program("splat_latent.vert", "splat_latent.frag", defines)
            self._latent_progs[targets] = (prog, self.ctx.vertex_array(prog, []))
        return self._latent_progs[targets]

    def _latent_targets(self, width: int, height: int, targets: int) -> tuple[moderngl.Framebuffer, list]:
        if self._latent_fbo is not None:
            count, fbo, textures = self._latent_fbo
            if count == targets and fbo.size == (width, height):
                return fbo, textures
            fbo.release()
            for t in textures:
                t.release()
        textures = [self.ctx.texture((width, height), 4, dtype="f4") for _ in range(targets)]
        fbo = self.ctx.framebuffer(textures)
        self._latent_fbo = (targets, fbo, textures)
        return fbo, textures

    def render_latent(self, camera: Camera) -> np.ndarray:
        """Composite the latent channels like colour: (H, W, Hdim) = sum_i h_i a_i T_i (no background).

        Each RGBA32F target carries three channels plus alpha; up to 8 targets (24 channels) per pass.
        """
        self.begin_latent(camera)
        out = self.continue_latent()
        assert out is not None
        return out

    def begin_latent(self, camera: Camera, first_slice: int | None = None) -> None:
        """Start the latent image of `camera` (`render_latent` in slices): `continue_latent` draws it, its first
        slice `first_slice` Gaussians when given; slices are sized by their splats' predicted cost (`SliceCost`,
        fitted to this pass's own slices: a rate from the last slice, as before, overshot a 75 ms budget by up to
        2x where the sorted order turns from small splats to large ones)."""
        if self._latent_dim == 0:
            raise ValueError("the uploaded Gaussians have no latent features")
        self._activate()
        self.last_timings = {}
        self._prepare(camera, False)
        w, h = camera.width, camera.height
        per_pass = 3 * self.max_targets
        passes = [(first, min(per_pass, self._latent_dim - first)) for first in range(0, self._latent_dim, per_pass)]
        self._latent_job = _LatentJob(self._prepared, w, h, passes,
                                      np.empty((h, w, self._latent_dim), dtype=np.float32),
                                      first_slice=None if first_slice is None else max(1, int(first_slice)))
        self.latent_slices.begin(self._footprints)

    @property
    def latent_drawing(self) -> bool:
        """A latent image is started and not finished (nor dropped by a new pre-pass or upload)."""
        job = self._latent_job
        return job is not None and job.prepared is self._prepared

    def cancel_latent(self) -> None:
        """Drop an unfinished latent image."""
        self._latent_job = None

    def continue_latent(self, budget_ms: float = math.inf) -> np.ndarray | None:
        """Draw slices of the started latent image for about `budget_ms` (at least one slice); the image when it
        is finished, else None (also when a new pre-pass or upload dropped it: see `latent_drawing`)."""
        job = self._latent_job
        if job is None or job.prepared is not self._prepared:
            self._latent_job = None
            return None
        self._activate()
        if not math.isinf(budget_ms):  # (work queued earlier, e.g. the window's last frame, is not this pass's cost)
            self.ctx.finish()
        t_start = time.perf_counter()
        drawn = 0  # slices drawn in this call (at least one)
        w, h = job.width, job.height
        while job.pass_index < len(job.passes):
            first, channels = job.passes[job.pass_index]
            targets = (channels + 2) // 3
            prog, vao = self._latent_program(targets)
            fbo, _ = self._latent_targets(w, h, targets)
            self._begin_pass(fbo, (0, 0, w, h))
            if job.next == 0:
                fbo.clear(0.0, 0.0, 0.0, 0.0)
            uniform(prog, "u_viewport").value = (float(w), float(h))
            uniform(prog, "u_latent_dim").value = self._latent_dim
            uniform(prog, "u_first_channel").value = first
            self._bind_splats(prog)
            self._bind_latent(prog)
            while job.next < self._visible:
                if drawn and (time.perf_counter() - t_start) * 1e3 >= budget_ms:
                    return None
                left = self._visible - job.next
                if math.isinf(budget_ms):
                    count = left
                elif job.first_slice is not None:
                    count, job.first_slice = min(left, job.first_slice), None
                else:
                    remaining = budget_ms - (time.perf_counter() - t_start) * 1e3
                    count = self.latent_slices.count(job.next, self._visible, remaining)
                t0 = time.perf_counter()
                uniform(prog, "u_first").value = job.next
                vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=count)
                if not math.isinf(budget_ms):  # a software GL renders lazily: time the slice itself
                    self.ctx.finish()
                    self.latent_slices.record(job.next, count, (time.perf_counter() - t0) * 1e3)
                job.draw_ms += (time.perf_counter() - t0) * 1e3
                job.next += count
                job.slices += 1
                drawn += 1
            if drawn and (time.perf_counter() - t_start) * 1e3 >= budget_ms:
                return None  # the pass's read-back (10-20 ms a target at 1360 x 900) opens the next call
            for k in range(targets):
                lo = first + 3 * k
                n = min(3, self._latent_dim - lo)
                job.out[..., lo:lo + n] = self._read(fbo, k, w, h)[..., :n]
            job.pass_index += 1
            job.next = 0
            drawn += 1  # (a read-back counts as a slice: the next pass's first slice waits if the budget is spent)
        self._latent_job = None
        self.last_timings["draw"] = job.draw_ms
        self.last_timings["slices"] = float(job.slices)
        return job.out

    # --- inspection ----------------------------------------------------------------------------
    @property
    def drawn_count(self) -> int:
        """Gaussians kept by the last pre-pass (drawn by the last `draw`/`render` if `style` is "splats")."""
        if not self._count or self._prepared is None:
            return 0
        self._activate()
        return int(np.frombuffer(self._buffers["counter"].read(size=4), np.uint32)[0])

    def drawn_mask(self) -> np.ndarray:
        """(N,) bool: which Gaussians the last pre-pass kept (reads the projected splats back)."""
        if not self._count or self._prepared is None:
            return np.zeros(self._count, bool)
        self._activate()
        data = self._buffers["splats"].read(size=self._count * 64)
        return np.frombuffer(data, np.float32).reshape(self._count, 16)[:, 3] > 0.0

    def _ids_into(self, camera: Camera, threshold: float, scissor: tuple[int, int, int, int] | None) -> None:
        w, h = camera.width, camera.height
        if self._id_target is None or self._id_target[0].size != (w, h):
            if self._id_target is not None:
                for obj in reversed(self._id_target):
                    obj.release()
            tex = self.ctx.texture((w, h), 1, dtype="u4")
            self._id_target = (tex, self.ctx.framebuffer([tex]))
        fbo = self._id_target[1]
        fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        if not self._count:
            return
        self._prepare(camera, False)
        if not self._visible:
            return
        prog = self._id_prog
        self._set_style(prog, camera)
        uniform(prog, "u_threshold").value = float(threshold)
        uniform(prog, "u_first").value = 0
        self._bind_splats(prog)
        fbo.scissor = scissor  # type: ignore[assignment]
        try:
            self._id_vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=self._visible)
        finally:
            fbo.scissor = None  # type: ignore[assignment]

    def render_ids(self, camera: Camera, threshold: float = PICK_THRESHOLD) -> np.ndarray:
        """(H, W) int64: per pixel the front-most Gaussian (by centre depth) whose alpha there, in the current
        `style`, is at least `threshold`; -1 where there is none. Rows top to bottom."""
        self._activate()
        self._ids_into(camera, threshold, None)
        target = self._id_target
        assert target is not None
        data = target[1].read(viewport=(0, 0, camera.width, camera.height), components=1, dtype="u4")
        return np.frombuffer(data, np.uint32).reshape(camera.height, camera.width).astype(np.int64) - 1

    def pick(self, camera: Camera, x: float, y: float, threshold: float = PICK_THRESHOLD) -> int | None:
        """The Gaussian at pixel (x, y) (OpenCV: x right, y down, from the image's top-left corner) as
        `render_ids` defines it, or None; only that pixel is rasterised."""
        px, py = int(np.floor(x)), int(np.floor(y))
        if not (0 <= px < camera.width and 0 <= py < camera.height):
            return None
        self._activate()
        self._ids_into(camera, threshold, (px, py, 1, 1))
        target = self._id_target
        assert target is not None
        data = target[1].read(viewport=(px, py, 1, 1), components=1, dtype="u4")
        value = int(np.frombuffer(data, np.uint32)[0])
        return value - 1 if value else None

    def show(self, frame: InspectFrame, upload: bool = True) -> None:
        """Take an inspection frame (`Inspector.frame` in npga_core.inspection): style, lines and (unless the caller
        uploads them itself) its Gaussians."""
        if upload:
            self.set_gaussians(frame.posed)
        self.style, self.point_px = frame.style, frame.point_px
        if frame.lines is None:
            self.clear_lines()
        else:
            self.set_lines(frame.lines.positions, frame.lines.edges, frame.lines.colours)

    def set_lines(self, positions: np.ndarray, edges: np.ndarray, colours: np.ndarray) -> None:
        """Segments between rows of `positions` (M, 3), edges (E, 2), colours (E, 3|4), drawn over the splats by
        `draw` in "rgb" mode until `clear_lines`."""
        self._activate()
        if self._lines is None:
            self._lines = LinePass(self.ctx, self._load_shader)
        self._lines.set(positions, edges, colours)

    def clear_lines(self) -> None:
        if self._lines is not None:
            self._lines.clear()

    @property
    def line_count(self) -> int:
        return 0 if self._lines is None else self._lines.edge_count
