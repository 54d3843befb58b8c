"""`SplatRenderer`: rasterises posed 3D Gaussians with OpenGL 4.3, matching the 3DGS reference rasterizer.

(OpenGL 4.1/4.2, e.g. macOS: `renderer41.SplatRenderer41`, the same renderer with the pre-pass on the CPU and
the splats in textures; `factory.create_renderer` picks the path.)

Pipeline per frame (see shaders/):

1. sort (CPU, `sorting.py`): camera-space depth of every Gaussian centre, culled at the near plane, O(N)
   radix sort far to near (exact float order by default); the order (uint32, 4 bytes per Gaussian) is
   uploaded.
2. pre-pass (compute shader, once per camera): EWA projection as 3DGS `computeCov2D` (Jacobian with
   t.x/t.z, t.y/t.z clamped to 1.3 tan(fov/2), +0.3 px on the covariance diagonal), SH colour as
   `computeColorFromSH`, and a quad along the covariance eigenvectors reaching the radius where
   alpha = 1/255 (at most 3.33 sigma; fragments beyond it are discarded by the 3DGS rule anyway).
3. draw: one instanced quad per Gaussian in sorted order, or, when every splat's bounding square fits the
   GL's point sizes, one GL point per Gaussian: a quarter of the vertex work but the whole square's fragments;
   which is cheaper for an image size is measured (`drawcost.PathCosts`); the fragment shader evaluates
   alpha = min(0.99, o exp(-d^T S^-1 d / 2)) at d = gl_FragCoord - centre with the 2D conic, exactly as
   renderCUDA, discards it below 1/255, and blends premultiplied "over" into the colour target (RGBA16 at half
   scale; RGBA32F for offline images: `targets.py`). On a software GL (llvmpipe) the "splats" colour pass runs
   instead on the CPU over the pre-pass's splats (`cpu_splats.py`: tiles, exact ellipse spans; the same image).

The result is C = sum_i c_i a_i T_i and A = 1 - prod_i (1 - a_i); `render` composites C + (1 - A) bg.

Difference to 3DGS: its front-to-back loop stops a pixel at the first Gaussian that would bring the
transmittance below 1e-4 and skips that Gaussian and all behind it; blending cannot stop, so here they are
composited. The difference per pixel is at most T_stop * max|feature - background| with
T_stop < 1e-4 / (1 - alpha) <= 1e-2, i.e. up to 1 % where a pixel saturates with alpha-0.99 splats, and far
less otherwise (the PSNR tests against tests/support/reference_rasterizer.py include it).
Pixels of 3DGS outside a Gaussian's 16x16-tile bounding rectangle also see no contribution there, while here
every pixel with alpha >= 1/255 does; this touches only alphas within [1/255, ~1/90] at the 3-sigma edge.

Frame-budgeted drawing: `begin_draw` sorts, runs the pre-pass and clears a back target; `continue_draw(budget)`
draws the sorted order in slices (consecutive ranges of it, so the blend order and the pixels are those of one
draw) until the budget is spent, and swaps the finished image to the front, which `present` shows (the previous
image stays there meanwhile). `draw` is both with no budget.

Camera-only changes re-sort, re-run the pre-pass and redraw; the Gaussian attributes are uploaded only by
`set_gaussians`.

Inspection (see npga_core/inspection/colouring.py for the colour modes, which only replace the uploaded SH):

- `style`: "splats" (the above), "points" (opaque discs of `point_px` radius) or "ellipsoids" (the 1-sigma
  ellipse of the projected covariance, opaque and shaded); the two geometry styles skip Gaussians with opacity
  below `style_min_opacity`. The "splats" output is unchanged by this.
- `drawn_count` / `drawn_mask()`: Gaussians the pre-pass keeps (in front of the near plane, opacity >= 1/255, a
  non-degenerate covariance, quad overlapping the viewport), counted with an atomic counter in the pre-pass.
- `pick(camera, x, y)` / `render_ids(camera)`: an id pass over the same sorted quads into an R32UI target,
  without blending, so a pixel keeps the front-most Gaussian whose alpha there reaches a threshold.
- `set_lines(positions, edges, colours)`: segments (kNN edges) drawn over the splats in "rgb" mode
  (`npga_view/rendering/lines.py`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import cast

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import PosedGaussians, sh_degree_from_count
from npga_view.rendering import cpu_splats
from npga_view.rendering.aux_passes import AuxiliaryPasses
from npga_view.rendering.drawcost import PathCosts
from npga_view.rendering.lines import Lines
from npga_view.rendering.shader_source import load_shader
from npga_view.rendering.slice_cost import LATENT_PRIOR, SliceCost, footprints
from npga_view.rendering.sorting import sort_back_to_front, view_depths
from npga_view.rendering.targets import ImageTargets, read_rgba
from npga_view.rendering.uniforms import mat4_bytes, uniform

NEAR = 0.01
_GROUP = 128
MODES = ("rgb", "depth", "alpha")
STYLES = ("splats", "points", "ellipsoids")


@dataclass
class DrawJob:
    """An image being drawn slice by slice into the back target."""

    key: tuple  # camera key, mode, flip
    width: int
    height: int
    mode: str
    points: bool  # colour pass as GL points (every splat fits the point size range)
    fits: bool  # points were possible (so the image's cost says something about the choice)
    total: int  # sorted positions to draw
    next: int = 0  # next sorted position
    slices: int = 0
    draw_ms: float = 0.0
    synced: bool = True  # every slice was finished before it was timed
    internal: bool = True  # drawn into the back target (swapped to the front when finished)
    colour_scale: float = 1.0  # the target's premultiplied colour factor (targets.py)
    cpu: bool = False  # the colour pass on the CPU (cpu_splats.py)


def camera_key(camera: Camera) -> tuple:
    """What a drawn image depends on of a camera."""
    return (camera.world_to_camera.tobytes(), camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)


class SplatRenderer(AuxiliaryPasses):
    """Draws a `PosedGaussians` cloud from any `Camera` into float framebuffers.

    `ctx` must be an OpenGL >= 4.3 moderngl context (`npga_view.rendering.gl`). `width`, `height` is the size of the
    internal framebuffer; cameras of another size are rendered at their own size (the targets are resized).
    `exact_sort` sorts by the exact float32 depth (two 16-bit radix passes, the order 3DGS uses); False uses
    one pass over 16-bit quantised depths (about 2x faster; near-equal depths may swap). `cpu_colour`: the
    "splats" colour pass on the CPU (`cpu_splats.py`; None: where the GL is a software renderer).
    """

    _load_shader = staticmethod(load_shader)
    #: which renderer path this is (shown by the stats overlay, `info` and `render --verbose`)
    path = "OpenGL 4.3 (compute pre-pass, storage buffers)"

    def __init__(self, ctx: moderngl.Context, width: int, height: int, exact_sort: bool = True,
                 cpu_colour: bool | None = None) -> None:
        self.ctx = ctx
        self.exact_sort = exact_sort
        self._activate()
        self.max_targets = min(8, int(ctx.info["GL_MAX_DRAW_BUFFERS"]))
        self.max_ssbo_bytes = int(ctx.info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE") or 0)
        self._preprocess = self._build_preprocess()
        fast = {"SPLATS_ONLY": 1}  # the colour pass of the "splats" style: no style branches (splat.frag)
        self._splat_prog = self._program("splat.vert", "splat.frag", fast)
        self._splat_vao = ctx.vertex_array(self._splat_prog, [])
        self._styled: tuple[moderngl.Program, moderngl.VertexArray] | None = None  # `_styled_program`
        self._points_prog = self._program("splat_points.vert", "splat.frag", fast)
        self._points_vao = ctx.vertex_array(self._points_prog, [])
        #: largest GL point size; splats of up to this size may be drawn as points (`use_points`)
        self.max_point = float(ctx.info["GL_POINT_SIZE_RANGE"][1])
        #: None: points or quads by their measured cost at the image's size (`path_costs`); True: points when every
        #: splat fits; False: quads
        self.use_points: bool | None = None
        self.path_costs = PathCosts()
        self._oversize = 0
        self._job: DrawJob | None = None
        self._job_camera: Camera | None = None
        self._job_framebuffer: moderngl.Framebuffer | None = None
        self._slices = SliceCost()  # sorted positions per slice, from their predicted cost (slice_cost.py)
        #: sorted positions per slice of the latent pass, from their predicted cost (its own rates)
        self.latent_slices = SliceCost(LATENT_PRIOR)
        self._footprints: np.ndarray | None = None  # the drawn splats' estimated pixels, in sorted order
        self._radius: np.ndarray | None = None  # each Gaussian's largest scale (the footprint of its splat)
        self._id_prog = self._program("splat.vert", "splat_id.frag")
        self._id_vao = ctx.vertex_array(self._id_prog, [])
        self._id_target: tuple[moderngl.Texture, moderngl.Framebuffer] | None = None
        self._lines: Lines | None = None
        #: draw style: "splats", "points" or "ellipsoids" (see the module docstring)
        self.style = "splats"
        self.point_px = 2.0
        self.style_min_opacity = 0.05
        self._latent_progs: dict[int, tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._composite_prog = self._program("fullscreen.vert", "composite.frag")
        self._composite_vao = ctx.vertex_array(self._composite_prog, [])
        self._count = 0
        self._means: np.ndarray | None = None
        self._latent_dim = 0
        self._buffers: dict[str, moderngl.Buffer] = {}
        self._sh_coeffs = 1
        self._pending_upload_ms = 0.0
        self._targets = ImageTargets(ctx)  # front: the finished image; back: the one being drawn
        #: colour images into RGBA32F instead of the faster RGBA16 (targets.py): for offline images (`render`,
        #: `evaluate`) that are written or scored as floats
        self.precise_colour = False
        self._latent_fbo: tuple[int, moderngl.Framebuffer, list[moderngl.Texture]] | None = None
        self._latent_job = None  # a latent image being drawn in slices (aux_passes.begin_latent)
        self._prepared: tuple | None = None  # (camera key, flip) of the current splat buffer + order
        self._visible = 0
        self.attribute_uploads = 0  # number of set_gaussians calls (camera moves must not add to it)
        #: glFinish after each stage so that `last_timings` measures GPU work; turn off in an interactive loop on a
        #: real GPU to let the stages overlap (the timings then only measure submission).
        self.sync_timings = True
        self.last_timings: dict[str, float] = {}
        self._targets.back(width, height, precise=False)
        cpu_colour = cpu_splats.wanted(str(ctx.info.get("GL_RENDERER", ""))) if cpu_colour is None else cpu_colour
        on = self._preprocess is not None and cpu_colour
        #: the "splats" colour pass on the CPU (a software GL: cpu_splats.py), used once compiled
        self.cpu_pass: cpu_splats.CpuColourPass | None = cpu_splats.CpuColourPass() if on else None
        self._order: np.ndarray | None = None  # the sorted order of the current pre-pass

    # --- resources -----------------------------------------------------------------------------
    def _build_preprocess(self) -> moderngl.ComputeShader | None:
        """The pre-pass program (None in a subclass that runs the pre-pass elsewhere)."""
        return self.ctx.compute_shader(self._load_shader("splat_preprocess.comp"))

    def _bind_splats(self, prog: moderngl.Program) -> None:
        """Make the projected splats and the sorted order readable by the draw program `prog`."""
        self._buffers["splats"].bind_to_storage_buffer(2)
        self._buffers["order"].bind_to_storage_buffer(3)

    def _bind_latent(self, prog: moderngl.Program) -> None:
        """Make the latent features readable by the latent program `prog`."""
        self._buffers["latent"].bind_to_storage_buffer(4)

    def _activate(self) -> None:
        """Make this renderer's context current: with several contexts in one process (a window and a
        headless one, or tests) moderngl does not switch by itself, and GL calls would reach the wrong one."""
        self.ctx.__enter__()

    @property
    def _colour_tex(self) -> moderngl.Texture | None:
        """The finished image (front target)."""
        return self._targets.front_texture

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the finished image that `present` shows ((0, 0) before the first)."""
        return self._targets.size

    def _release_targets(self) -> None:
        self._targets.release()
        self._job = None
        if self._latent_fbo is not None:
            _, fbo, textures = self._latent_fbo
            fbo.release()
            for t in textures:
                t.release()
        if self._id_target is not None:
            for obj in reversed(self._id_target):
                obj.release()
        self._latent_fbo = self._id_target = None

    def _buffer(self, name: str, data: np.ndarray | None = None, size: int = 0) -> moderngl.Buffer:
        """(Re)allocate the named buffer when it is too small, then write the C-contiguous `data` if given."""
        nbytes = max(data.nbytes if data is not None else size, 16)
        if nbytes > self.max_ssbo_bytes:
            raise ValueError(f"{name} needs {nbytes / 2**20:.0f} MiB, over this GL's shader storage block limit "
                             f"of {self.max_ssbo_bytes / 2**20:.0f} MiB")
        buf = self._buffers.get(name)
        if buf is None or buf.size < nbytes:
            if buf is not None:
                buf.release()
            buf = self.ctx.buffer(reserve=nbytes, dynamic=True)
            self._buffers[name] = buf
        if data is not None and data.nbytes:
            buf.write(np.ascontiguousarray(data))
        return buf

    def release(self) -> None:
        """Free all GL objects of this renderer."""
        self._activate()
        self._release_targets()
        if self.cpu_pass is not None:
            self.cpu_pass.release()
        for buf in self._buffers.values():
            buf.release()
        self._buffers.clear()
        for prog, vao in self._latent_progs.values():
            vao.release()
            prog.release()
        self._latent_progs.clear()
        if self._lines is not None:
            self._lines.release()
            self._lines = None
        for obj in (self._splat_vao, self._splat_prog, *(self._styled or ())[::-1], self._points_vao, self._points_prog,
                    self._id_vao, self._id_prog, self._composite_vao, self._composite_prog, self._preprocess):
            if obj is not None:
                obj.release()

    # --- data ----------------------------------------------------------------------------------
    @property
    def count(self) -> int:
        """Number of Gaussians uploaded."""
        return self._count

    @property
    def latent_dim(self) -> int:
        """Number of latent channels uploaded (0 if none)."""
        return self._latent_dim

    def set_gaussians(self, posed: PosedGaussians) -> None:
        """Upload a posed cloud (all attributes). Call again whenever the expression changes."""
        self._activate()
        t0 = time.perf_counter()
        n = len(posed)
        means = np.array(posed.means, dtype=np.float32, copy=True).reshape(n, 3)  # the caller may reuse its arrays
        geometry = np.zeros((n, 3, 4), dtype=np.float32)
        geometry[:, 0, :3] = means
        geometry[:, 0, 3] = np.asarray(posed.opacities, dtype=np.float32).reshape(n)
        geometry[:, 1] = np.asarray(posed.quats, dtype=np.float32).reshape(n, 4)
        geometry[:, 2, :3] = np.asarray(posed.scales, dtype=np.float32).reshape(n, 3)
        sh = np.ascontiguousarray(posed.sh, dtype=np.float32)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise ValueError(f"sh must be (N, K, 3) with N={n}, got {sh.shape}")
        sh_degree_from_count(sh.shape[1])  # raises for K that is not (degree + 1)^2
        self._sh_coeffs = sh.shape[1]
        self._buffer("geometry", geometry)
        self._buffer("sh", sh)
        self._buffer("splats", size=n * 64)
        self._buffer("order", size=n * 4)
        self._buffer("counter", size=8)
        if posed.latent is not None:
            latent = np.ascontiguousarray(posed.latent, dtype=np.float32).reshape(n, np.shape(posed.latent)[-1])
            self._latent_dim = latent.shape[1]
            self._buffer("latent", latent)
        else:
            self._latent_dim = 0
        self._uploaded(means, n, t0, posed.scales)

    def _uploaded(self, means: np.ndarray, n: int, t0: float, scales: np.ndarray) -> None:
        """Bookkeeping after `set_gaussians` (both paths): a cloud of another size drops an unfinished image
        (the buffers it draws from may be reallocated); the next draw runs the pre-pass again."""
        if n != self._count:
            self._job = None
        self._means, self._radius = means, np.asarray(scales, np.float32).reshape(n, 3).max(axis=1)
        self._count = n
        self._prepared = None
        self.attribute_uploads += 1
        self._pending_upload_ms += (time.perf_counter() - t0) * 1e3

    # --- per-camera work -----------------------------------------------------------------------
    def _start_prepare(self, key: tuple) -> float | None:
        """Start of `_prepare` (both paths): None if the pre-pass of `key` is current (its timings are recorded as
        zero), else the upload time still to be reported with it; an unfinished image is then dropped, since the
        new pre-pass overwrites the splats it draws from."""
        upload_ms, self._pending_upload_ms = self._pending_upload_ms, 0.0
        if self._prepared == key:
            self.last_timings.update(sort=0.0, upload=upload_ms, preprocess=0.0)
            return None
        self._job = None
        return upload_ms

    def _prepare(self, camera: Camera, flip_y: bool) -> None:
        """Sort and run the pre-pass for `camera` (skipped when camera and data are unchanged)."""
        key = (*camera_key(camera), flip_y)
        upload_ms = self._start_prepare(key)
        if upload_ms is None:
            return
        t0 = time.perf_counter()
        means = self._means
        assert means is not None
        z = view_depths(means, camera.world_to_camera)
        order = sort_back_to_front(z, NEAR, exact=self.exact_sort)
        self._plan_slices(z, order, camera)
        t1 = time.perf_counter()
        self._buffers["order"].write(order)
        self._visible = int(order.shape[0])
        self._order = order
        t2 = time.perf_counter()
        prog = self._preprocess
        assert prog is not None
        uniform(prog, "u_view").write(mat4_bytes(camera.world_to_camera))
        uniform(prog, "u_proj").write(mat4_bytes(camera.opengl_projection(NEAR, 1000.0, flip_y)))
        prog["u_viewport"].value = (float(camera.width), float(camera.height))
        prog["u_focal"].value = (camera.fx, camera.fy)
        prog["u_tan_fov"].value = (camera.tan_half_fov_x, camera.tan_half_fov_y)
        prog["u_campos"].value = tuple(float(v) for v in camera.camera_center)
        prog["u_near"].value = NEAR
        prog["u_count"].value = self._count
        prog["u_sh_coeffs"].value = self._sh_coeffs
        prog["u_max_point"].value = self.max_point
        self._buffers["geometry"].bind_to_storage_buffer(0)
        self._buffers["sh"].bind_to_storage_buffer(1)
        self._buffers["splats"].bind_to_storage_buffer(2)
        self._buffers["counter"].write(np.zeros(2, np.uint32))
        self._buffers["counter"].bind_to_storage_buffer(5)
        prog.run(group_x=(self._count + _GROUP - 1) // _GROUP)
        self.ctx.memory_barrier()
        self._oversize = int(np.frombuffer(self._buffers["counter"].read(size=8), np.uint32)[1])
        t3 = time.perf_counter()
        self.last_timings.update(sort=(t1 - t0) * 1e3, upload=upload_ms + (t2 - t1) * 1e3, preprocess=(t3 - t2) * 1e3)
        self._prepared = key

    def _plan_slices(self, z: np.ndarray, drawn: np.ndarray, camera: Camera) -> None:
        """Each drawn splat's estimated footprint, in draw order, for sizing the slices (`SliceCost`)."""
        r = self._radius
        self._footprints = None if r is None else footprints(z[drawn], r[drawn], camera.fx, camera.fy,
                                                             camera.width, camera.height)
        self._slices.begin(self._footprints)

    def _begin_pass(self, fbo: moderngl.Framebuffer, viewport: tuple[int, int, int, int]) -> None:
        fbo.use()
        self.ctx.viewport = viewport
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        self.ctx.blend_equation = moderngl.FUNC_ADD  # type: ignore[assignment]

    # --- drawing -------------------------------------------------------------------------------
    def draw(self, camera: Camera, mode: str = "rgb", framebuffer: moderngl.Framebuffer | None = None,
             flip_y: bool = False, clear: tuple[float, float, float, float] | None = (0.0, 0.0, 0.0, 0.0)) -> None:
        """Splat into `framebuffer` (default: the internal RGBA32F target), premultiplied, without readback.

        mode "rgb" or "alpha" composites colours, "depth" camera-space z. `flip_y` renders upright for a
        window (row 0 at the bottom). Clearing with (bg, 1) instead of zeros composites over a background
        directly (then alpha is lost). Timings go to `last_timings` (ms: sort, upload, preprocess, draw).
        """
        self.begin_draw(camera, mode, flip_y, clear, framebuffer)
        self.continue_draw(math.inf)

    def begin_draw(self, camera: Camera, mode: str = "rgb", flip_y: bool = False,
                   clear: tuple[float, float, float, float] | None = (0.0, 0.0, 0.0, 0.0),
                   framebuffer: moderngl.Framebuffer | None = None) -> None:
        """Start an image: sort, pre-pass and clear the back target (or `framebuffer`); an unfinished image is
        dropped. `continue_draw` draws it."""
        if mode not in MODES:
            raise ValueError(f"unknown render mode {mode!r}; choose from {', '.join(MODES)} (or render_latent)")
        self._activate()
        self.last_timings = {}
        if self._count:
            self._prepare(camera, flip_y)
        fbo = framebuffer if framebuffer is not None else self._targets.back(camera.width, camera.height,
                                                                             mode == "depth" or self.precise_colour)
        scale = 1.0 if framebuffer is not None else self._targets.back_scale
        cpu = (self.cpu_pass is not None and self.style == "splats" and mode != "depth" and framebuffer is None
               and self._count > 0 and cpu_splats.ready())
        fits = not cpu and self.style == "splats" and self._oversize == 0 and self.use_points is not False
        points = fits and (self.use_points or self.path_costs.choose(camera.width, camera.height))
        self._job = DrawJob((*camera_key(camera), mode, flip_y), camera.width, camera.height, mode, points,
                            fits and self.use_points is None, self._visible if self._count else 0,
                            internal=framebuffer is None, colour_scale=scale, cpu=cpu)
        self._job_camera, self._job_framebuffer = camera, fbo
        if cpu:
            assert self.cpu_pass is not None and self._order is not None
            self.cpu_pass.begin(self._buffers["splats"], self._count, self._order, camera.width, camera.height,
                                clear if clear is not None else (0.0, 0.0, 0.0, 0.0))
        elif clear is not None:
            r, g, b, a = clear  # the colour at the target's scale (targets.py)
            fbo.clear(r * scale, g * scale, b * scale, a, viewport=(0, 0, camera.width, camera.height))

    @property
    def colour_pass(self) -> str:
        """Where the "splats" colour pass runs: "GL", "CPU" (a software GL), or GL while the CPU pass compiles."""
        if self.cpu_pass is None:
            return "GL"
        return "CPU" if cpu_splats.status() == "ready" else f"GL (CPU pass: {cpu_splats.status()})"

    @property
    def drawing(self) -> bool:
        """An image is started and not finished."""
        return self._job is not None

    @property
    def progress(self) -> float:
        """Fraction of the unfinished image drawn (1.0 when none)."""
        job = self._job
        if job is not None and job.cpu:
            return cast(cpu_splats.CpuColourPass, self.cpu_pass).progress
        return 1.0 if job is None or not job.total else job.next / job.total

    def cancel_draw(self) -> None:
        """Drop the unfinished image (the finished one stays in front)."""
        self._job = None

    def continue_draw(self, budget_ms: float = math.inf) -> bool:
        """Draw slices of the started image for about `budget_ms` (at least one slice); True when it is
        finished and swapped to the front (then `last_timings` has the whole image's figures)."""
        job = self._job
        if job is None:
            return True
        self._activate()
        camera, fbo = cast(Camera, self._job_camera), cast(moderngl.Framebuffer, self._job_framebuffer)
        if not math.isinf(budget_ms):
            # a software GL renders lazily: work queued earlier (the window's last frame) would otherwise be
            # waited for in the first slice and be taken for the cost of splats
            self.ctx.finish()
        t_start = time.perf_counter()
        last_ms = 0.0
        if job.cpu:  # tiles on the CPU for the budget; the finished image is written into the back target
            assert self.cpu_pass is not None
            done = self.cpu_pass.step(budget_ms, self._targets.back_texture, job.colour_scale)
            job.slices, job.draw_ms = job.slices + 1, job.draw_ms + (time.perf_counter() - t_start) * 1e3
            if not done:
                return False
            job.next = job.total
        while job.next < job.total:
            remaining = budget_ms - (time.perf_counter() - t_start) * 1e3
            if last_ms and remaining <= 0:
                break
            budgeted = not math.isinf(budget_ms)  # then the slice is what its splats are predicted to fit
            count = self._slices.count(job.next, job.total, remaining) if budgeted else job.total - job.next
            t0 = time.perf_counter()
            self._draw_slice(job, camera, fbo, job.next, count)
            if self.sync_timings or budgeted:
                self.ctx.finish()
            else:
                job.synced = False
            ms = last_ms = (time.perf_counter() - t0) * 1e3
            if budgeted:
                self._slices.record(job.next, count, ms)
            job.next += count
            job.slices += 1
            job.draw_ms += ms
        if job.next < job.total:
            return False
        if job.fits and job.synced:
            self.path_costs.record(job.width, job.height, job.points, job.draw_ms, job.total)
        t0 = time.perf_counter()
        if job.mode == "rgb" and self._lines is not None and self._lines.edge_count:
            self._begin_pass(fbo, (0, 0, job.width, job.height))
            self._lines.draw(camera, job.key[-1], NEAR, colour_scale=job.colour_scale)
            if self.sync_timings:
                self.ctx.finish()
        job.draw_ms += (time.perf_counter() - t0) * 1e3
        self.last_timings["draw"] = job.draw_ms
        self.last_timings["slices"] = float(job.slices)
        self.last_timings["visible"] = float(job.total)
        self.last_timings["points"] = float(job.points)
        self.last_timings["cpu"] = float(job.cpu)
        self.last_timings["oversize"] = float(self._oversize)  # splats too large for a GL point (drawn as quads)
        if job.internal:
            self._targets.swap()
        self._job = None
        if self.cpu_pass is not None:  # compiled by a helper process after the first image (GL draws until then)
            cpu_splats.warm_up()
        return True

    def _draw_slice(self, job: DrawJob, camera: Camera, fbo: moderngl.Framebuffer, first: int, count: int) -> None:
        """Blend sorted positions [first, first + count) into `fbo`."""
        if job.points:
            guard = math.ceil(self.max_point / 2)
            self._begin_pass(fbo, (-guard, -guard, job.width + 2 * guard, job.height + 2 * guard))
            self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
            prog = self._points_prog
            self._bind_splats(prog)
            uniform(prog, "u_viewport").value = (float(job.width), float(job.height))
            uniform(prog, "u_guard").value = float(guard)
            uniform(prog, "u_first").value = first
            uniform(prog, "u_mode").value = 1 if job.mode == "depth" else 0
            uniform(prog, "u_colour_scale").value = job.colour_scale
            self._points_vao.render(moderngl.POINTS, vertices=count)
            self.ctx.disable(moderngl.PROGRAM_POINT_SIZE)
        else:
            self._begin_pass(fbo, (0, 0, job.width, job.height))
            prog, vao = (self._splat_prog, self._splat_vao) if self.style == "splats" else self._styled_program()
            self._bind_splats(prog)
            self._set_style(prog, camera)
            uniform(prog, "u_first").value = first
            uniform(prog, "u_mode").value = 1 if job.mode == "depth" else 0
            uniform(prog, "u_colour_scale").value = job.colour_scale
            vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=count)

    def _styled_program(self) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """The colour pass of the points and ellipsoids styles (the general splat.frag), compiled on first use."""
        if self._styled is None:
            prog = self._program("splat.vert", "splat.frag")
            self._styled = (prog, self.ctx.vertex_array(prog, []))
        return self._styled

    def _set_style(self, prog: moderngl.Program, camera: Camera) -> None:
        if self.style not in STYLES:
            raise ValueError(f"unknown style {self.style!r}; choose from {', '.join(STYLES)}")
        uniform(prog, "u_viewport").value = (float(camera.width), float(camera.height))
        uniform(prog, "u_style").value = STYLES.index(self.style)
        uniform(prog, "u_point_px").value = float(self.point_px)
        uniform(prog, "u_min_opacity").value = float(self.style_min_opacity)

    def _read(self, fbo: moderngl.Framebuffer, attachment: int, width: int, height: int) -> np.ndarray:
        return read_rgba(fbo, attachment, width, height)

    def render(self, camera: Camera, background=(0.0, 0.0, 0.0), mode: str = "rgb") -> np.ndarray:
        """Render and read back: rgb (H,W,3) C + (1-A) bg, depth (H,W) sum_i w_i z_i, or alpha (H,W) A.

        Rows go top to bottom (OpenCV image order). Depth is the alpha-weighted expected depth, not
        normalised by alpha (divide by the alpha image for the depth of the visible surface).
        """
        self.draw(camera, mode)
        t0 = time.perf_counter()
        if mode == "rgb":
            out = self.front_image(background)
        else:
            out = self.front_rgba()[..., 0 if mode == "depth" else 3].copy()
        self.last_timings["readback"] = (time.perf_counter() - t0) * 1e3
        return out

    def front_rgba(self) -> np.ndarray:
        """The finished image read back: premultiplied RGBA (H, W, 4) float32, rows top to bottom."""
        return self._targets.read_front()

    def front_image(self, background=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The finished image over `background`: (H, W, 3) float32 C + (1 - A) bg, rows top to bottom (what `render`
        returns, and what the CNN takes)."""
        image = self.front_rgba()
        return image[..., :3] + (1.0 - image[..., 3:4]) * np.asarray(background, dtype=np.float32).reshape(3)

    def present(self, framebuffer: moderngl.Framebuffer, background=(0.0, 0.0, 0.0), flip_y: bool = True,
                viewport: tuple[int, int, int, int] | None = None) -> None:
        """Composite the last internal `draw` over `background` onto e.g. a window's framebuffer."""
        self._activate()
        framebuffer.use()
        self.ctx.viewport = viewport or (0, 0, *framebuffer.size)
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        tex = self._colour_tex
        if tex is None:
            return
        vp = self.ctx.viewport
        scaled = tex.size != (vp[2], vp[3])  # a reduced-resolution image: upscale bilinearly
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR) if scaled else (moderngl.NEAREST, moderngl.NEAREST)
        tex.use(0)
        uniform(self._composite_prog, "u_image").value = 0
        uniform(self._composite_prog, "u_background").value = tuple(float(v) for v in background)
        uniform(self._composite_prog, "u_flip_y").value = 1 if flip_y else 0
        uniform(self._composite_prog, "u_colour_scale").value = self._targets.front_scale
        self._composite_vao.render(moderngl.TRIANGLES, vertices=3)
