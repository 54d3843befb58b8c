"""`SplatRenderer41`: the same renderer for OpenGL 4.1 core (macOS), without compute shaders or storage buffers.

`SplatRenderer` (renderer.py) needs OpenGL 4.3: a compute pre-pass writes projected splats into a storage
buffer that the draw shaders index through the sorted order. OpenGL 4.1 has neither, so this path:

1. sorts on the CPU as before (`sorting.py`);
2. runs the pre-pass on the CPU (`preprocess`, numpy, vectorised), the maths of `shaders/splat_preprocess.comp`
   line for line: EWA projection as 3DGS computeCov2D (clamped Jacobian, +0.3 px), SH colour
   (`npga_core.model.sh.sh_basis`, the shader's basis), the same culling rules (near plane, opacity < 1/255,
   non-positive 2D determinant, bounding box off the viewport) and the same quad half-axes; the 3D covariances
   depend only on the pose and are computed once per `set_gaussians`;
3. uploads the kept splats already in draw order (back to front) into an RGBA32F texture (four texels per splat,
   4096 texels per row, the Gaussian's index in the fourth texel of the conic) read with `texelFetch` by
   `shaders/gl41_*` (`#version 410 core`): a slice of the sorted order is `u_first` plus the instance (quads) or
   vertex (points) id, exactly as in the 4.3 path;
4. draws with the same fragment shaders, blending, targets, passes (colour, depth, alpha, latent, id) and styles,
   so everything else (`begin_draw`/`continue_draw` slices, `present`, `pick`, ...) is `SplatRenderer`'s code.

Latent features live in a second texture (indexed by the Gaussian); kNN lines are a vertex buffer of segment
ends (`LinePass41`). Culled splats are not uploaded, so the sliced draw covers only kept ones.
"""

from __future__ import annotations

import time

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import SH_C0, PosedGaussians, sh_degree_from_count
from npga_core.model.sh import sh_basis
from npga_view.rendering.lines import pack_rgba8
from npga_view.rendering.renderer import NEAR, SplatRenderer, _mat4_uniform, camera_key, load_shader
from npga_view.rendering.sorting import sort_back_to_front, view_depths

#: texels per row of the splat and latent textures (the shaders' SPLAT_TEXTURE_WIDTH)
TEXTURE_WIDTH = 4096
MIN_ALPHA = 1.0 / 255.0


def load_shader41(name: str, defines: dict[str, object] | None = None) -> str:
    """The 4.1 twin `shaders/gl41_<name>` of a shader of the 4.3 path (includes resolved as for the 4.3 path)."""
    return load_shader("gl41_" + name, defines)


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """3D covariances R S S^T R^T (N, 3, 3) float32 from (w, x, y, z) quaternions (normalised here, as 3DGS
    does) and scales, as the pre-pass shader builds them."""
    q = np.asarray(quats, np.float32).reshape(-1, 4)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    rot = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)
    m = rot * np.asarray(scales, np.float32).reshape(-1, 1, 3)
    return np.einsum("nij,nkj->nik", m, m)


def preprocess(means: np.ndarray, opacities: np.ndarray, cov3d: np.ndarray, sh: np.ndarray, order: np.ndarray,
               camera: Camera, flip_y: bool, max_point: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The pre-pass of `shaders/splat_preprocess.comp` on the CPU for the sorted indices `order`.

    Returns (splats (K, 16) float32 in draw order: centre (x, y, depth, opacity), half-axes, conic (a, b, c,
    index), colour (r, g, b, 0); the indices (K,) kept; the number of kept splats whose bounding square exceeds
    `max_point` pixels).
    """
    idx = np.asarray(order, np.int64)
    view = np.asarray(camera.world_to_camera, np.float32)
    w3 = view[:3, :3]
    t = means[idx] @ w3.T + view[:3, 3]
    opacity = opacities[idx]
    tz = t[:, 2]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        keep = (tz > NEAR) & (opacity >= MIN_ALPHA)
        inv_z = (1.0 / tz).astype(np.float32)
        lim_x, lim_y = 1.3 * camera.tan_half_fov_x, 1.3 * camera.tan_half_fov_y
        tx = np.clip(t[:, 0] * inv_z, -lim_x, lim_x) * tz
        ty = np.clip(t[:, 1] * inv_z, -lim_y, lim_y) * tz
        fx, fy = np.float32(camera.fx), np.float32(camera.fy)
        # rows of J W: J = ((fx/z, 0, -fx tx/z^2), (0, fy/z, -fy ty/z^2))
        row0 = (fx * inv_z)[:, None] * w3[0] - (fx * tx * inv_z * inv_z)[:, None] * w3[2]
        row1 = (fy * inv_z)[:, None] * w3[1] - (fy * ty * inv_z * inv_z)[:, None] * w3[2]
        c3 = cov3d[idx]
        c_row0 = np.einsum("nij,nj->ni", c3, row0)
        a = np.einsum("ni,ni->n", row0, c_row0) + np.float32(0.3)
        b = np.einsum("ni,ni->n", row1, c_row0)
        c = np.einsum("ni,ni->n", row1, np.einsum("nij,nj->ni", c3, row1)) + np.float32(0.3)
        det = a * c - b * b
        keep &= det > 0.0
        proj = camera.opengl_projection(NEAR, 1000.0, flip_y).astype(np.float32)
        clip = t @ proj[:, :3].T + proj[:, 3]
        size = np.array([camera.width, camera.height], np.float32)
        centre = (clip[:, :2] / clip[:, 3:4] * 0.5 + 0.5) * size
        b = b * np.sign(proj[1, 1])
        r = 1.002 * np.sqrt(2.0 * np.log(255.0 * opacity))
        half_box = r[:, None] * np.sqrt(np.stack([a, c], axis=1))
        keep &= ~(np.any(centre + half_box < 0.0, axis=1) | np.any(centre - half_box > size, axis=1))
    k = np.flatnonzero(keep)
    a, b, c, det, r, centre = a[k], b[k], c[k], det[k], r[k], centre[k]
    mid = 0.5 * (a + c)
    disc = np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))
    l1 = mid + disc
    l2 = det / l1
    e1 = np.where((a >= c)[:, None], np.stack([l1 - c, b], axis=1), np.stack([b, l1 - a], axis=1))
    length = np.linalg.norm(e1, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        e1 = np.where(length > 0.0, e1 / length, np.array([1.0, 0.0], np.float32))
    ax1 = e1 * (np.sqrt(l1) * r)[:, None]
    ax2 = np.stack([-e1[:, 1], e1[:, 0]], axis=1) * (np.sqrt(l2) * r)[:, None]
    kept = idx[k]
    out = np.zeros((len(k), 16), np.float32)
    out[:, 0:2] = centre
    out[:, 2] = tz[k]
    out[:, 3] = opacity[k]
    out[:, 4:6] = ax1
    out[:, 6:8] = ax2
    out[:, 8] = c / det
    out[:, 9] = -b / det
    out[:, 10] = a / det
    out[:, 11] = kept
    if len(k):
        coeffs = sh.shape[1]
        degree = sh_degree_from_count(coeffs)
        means_k = means[kept]
        if degree:
            dirs = means_k - np.asarray(camera.camera_center, np.float32)
            dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
            basis = sh_basis(dirs, degree).astype(np.float32)
            colour = np.einsum("nk,nkc->nc", basis, sh[kept])
        else:
            colour = sh[kept, 0] * np.float32(SH_C0)
        out[:, 12:15] = np.maximum(colour + 0.5, 0.0)
    half = np.abs(out[:, 4:6]) + np.abs(out[:, 6:8])
    oversize = int(np.count_nonzero(2.0 * half.max(axis=1, initial=0.0) + 1.0 > max_point)) if len(k) else 0
    return out, kept, oversize


class LinePass41:
    """`lines.LinePass` for OpenGL 4.1: segment ends gathered into a vertex buffer (same API and drawing)."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._prog = ctx.program(vertex_shader=load_shader41("lines.vert"), fragment_shader=load_shader41("lines.frag"))
        self._positions = self.ctx.buffer(reserve=16, dynamic=True)
        self._colours = self.ctx.buffer(reserve=16, dynamic=True)
        self._vao: moderngl.VertexArray | None = None
        self._edges = np.zeros((0, 2), np.int64)
        self._count = 0

    @property
    def edge_count(self) -> int:
        return self._count

    def _write(self, name: str, data: np.ndarray) -> None:
        buf = getattr(self, name)
        if buf.size < max(data.nbytes, 16):
            buf.release()
            buf = self.ctx.buffer(reserve=max(data.nbytes, 16), dynamic=True)
            setattr(self, name, buf)
            if self._vao is not None:
                self._vao.release()
                self._vao = None
        if data.nbytes:
            buf.write(np.ascontiguousarray(data))

    def set_positions(self, positions: np.ndarray) -> None:
        """Move the ends (M, 3) (same edges, e.g. a new pose)."""
        p = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        self._write("_positions", p[self._edges.reshape(-1)] if self._count else np.zeros(0, np.float32))

    def set(self, positions: np.ndarray, edges: np.ndarray, colours: np.ndarray) -> None:
        """Positions (M, 3), edges (E, 2) of row indices, colours (E, 3|4) in [0, 1] (straight alpha)."""
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        points = len(np.asarray(positions).reshape(-1, 3))
        if e.size and (e.min() < 0 or e.max() >= points):
            raise ValueError(f"edge indices must be in 0..{points - 1}")
        if len(colours) != len(e):
            raise ValueError(f"{len(colours)} colours for {len(e)} edges")
        self._edges, self._count = e, len(e)
        self.set_positions(positions)
        packed = pack_rgba8(colours) if len(e) else np.zeros(0, np.uint32)
        self._write("_colours", np.repeat(packed, 2))

    def clear(self) -> None:
        self._count = 0

    def draw(self, camera: Camera, flip_y: bool, near: float, far: float = 1000.0) -> None:
        """Blend the lines into the current framebuffer (viewport and blend state set by the caller)."""
        if not self._count:
            return
        if self._vao is None:
            self._vao = self.ctx.vertex_array(self._prog, [(self._positions, "3f", "in_position"),
                                                           (self._colours, "4f1", "in_colour")])
        self._prog["u_view"].write(_mat4_uniform(camera.world_to_camera))
        self._prog["u_proj"].write(_mat4_uniform(camera.opengl_projection(near, far, flip_y)))
        self._vao.render(moderngl.LINES, vertices=2 * self._count)

    def release(self) -> None:
        if self._vao is not None:
            self._vao.release()
        self._positions.release()
        self._colours.release()
        self._prog.release()


class SplatRenderer41(SplatRenderer):
    """`SplatRenderer` for an OpenGL >= 4.1 core context; see the module docstring. Same API and images."""

    _load_shader = staticmethod(load_shader41)
    #: which renderer path this is (shown by the stats overlay, `info` and `render --verbose`)
    path = "OpenGL 4.1 (CPU pre-pass, texture splats)"

    def __init__(self, ctx: moderngl.Context, width: int, height: int, exact_sort: bool = True) -> None:
        self._textures: dict[str, moderngl.Texture] = {}
        self._cov3d: np.ndarray | None = None
        self._opacities: np.ndarray | None = None
        self._sh: np.ndarray | None = None
        self._kept = np.zeros(0, np.int64)
        super().__init__(ctx, width, height, exact_sort)
        self.max_texture = int(ctx.info.get("GL_MAX_TEXTURE_SIZE") or 16384)

    def _build_preprocess(self) -> None:
        return None  # the pre-pass runs on the CPU (`preprocess`)

    def _texture(self, name: str, texels: int) -> moderngl.Texture:
        """The named RGBA32F texture TEXTURE_WIDTH wide with room for `texels` (reallocated when too small)."""
        rows = max(1, -(-texels // TEXTURE_WIDTH))
        if rows > self.max_texture:
            raise ValueError(f"{name} needs a {TEXTURE_WIDTH}x{rows} texture, over this GL's limit of "
                             f"{self.max_texture} rows")
        tex = self._textures.get(name)
        if tex is None or tex.size[1] < rows:
            if tex is not None:
                tex.release()
            tex = self.ctx.texture((TEXTURE_WIDTH, rows), 4, dtype="f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._textures[name] = tex
        return tex

    def _upload(self, name: str, data: np.ndarray) -> None:
        """Write (texels, 4) float32 rows into the named texture from its first texel, whole rows at a time."""
        texels = data.size // 4
        tex = self._texture(name, texels)
        rows = max(1, -(-texels // TEXTURE_WIDTH))
        padded = np.zeros(rows * TEXTURE_WIDTH * 4, np.float32)
        padded[:data.size] = data.reshape(-1)
        tex.write(padded, viewport=(0, 0, TEXTURE_WIDTH, rows))

    def set_gaussians(self, posed: PosedGaussians) -> None:
        """Upload a posed cloud (all attributes). Call again whenever the expression changes."""
        self._activate()
        t0 = time.perf_counter()
        n = len(posed)
        means = np.array(posed.means, dtype=np.float32, copy=True).reshape(n, 3)
        sh = np.array(posed.sh, dtype=np.float32, copy=True)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise ValueError(f"sh must be (N, K, 3) with N={n}, got {sh.shape}")
        sh_degree_from_count(sh.shape[1])
        self._sh_coeffs = sh.shape[1]
        self._cov3d = covariances(posed.quats, posed.scales)
        self._opacities = np.array(posed.opacities, dtype=np.float32, copy=True).reshape(n)
        self._sh = sh
        self._texture("splats", 4 * n)
        if posed.latent is not None:
            latent = np.asarray(posed.latent, dtype=np.float32).reshape(n, -1)
            self._latent_dim = latent.shape[1]
            per = -(-self._latent_dim // 4)
            padded = np.zeros((n, 4 * per), np.float32)
            padded[:, :self._latent_dim] = latent
            self._upload("latent", padded)
        else:
            self._latent_dim = 0
        if n != self._count:
            self._job = None
        self._means = means
        self._count = n
        self._prepared = None
        self.attribute_uploads += 1
        self._pending_upload_ms += (time.perf_counter() - t0) * 1e3

    def _prepare(self, camera: Camera, flip_y: bool) -> None:
        """Sort and run the CPU pre-pass for `camera` (skipped when camera and data are unchanged)."""
        key = (*camera_key(camera), flip_y)
        timings = {"sort": 0.0, "upload": self._pending_upload_ms, "preprocess": 0.0}
        self._pending_upload_ms = 0.0
        if self._prepared == key:
            self.last_timings.update(timings)
            return
        self._job = None  # the splat texture an unfinished image draws from is rewritten
        t0 = time.perf_counter()
        z = view_depths(self._means, camera.world_to_camera)
        order = sort_back_to_front(z, NEAR, exact=self.exact_sort)
        t1 = time.perf_counter()
        splats, self._kept, self._oversize = preprocess(self._means, self._opacities, self._cov3d, self._sh, order,
                                                        camera, flip_y, self.max_point)
        t2 = time.perf_counter()
        if len(splats):
            self._upload("splats", splats)
        self._visible = len(splats)
        t3 = time.perf_counter()
        timings.update(sort=(t1 - t0) * 1e3, preprocess=(t2 - t1) * 1e3, upload=timings["upload"] + (t3 - t2) * 1e3)
        self.last_timings.update(timings)
        self._prepared = key

    def _bind_splats(self, prog: moderngl.Program) -> None:
        self._textures["splats"].use(0)
        prog["u_splats"].value = 0

    def _bind_latent(self, prog: moderngl.Program) -> None:
        self._textures["latent"].use(1)
        prog["u_latent"].value = 1

    @property
    def drawn_count(self) -> int:
        """Gaussians kept by the last pre-pass (drawn by the last `draw`/`render` if `style` is "splats")."""
        return len(self._kept) if self._count and self._prepared is not None else 0

    def drawn_mask(self) -> np.ndarray:
        """(N,) bool: which Gaussians the last pre-pass kept."""
        mask = np.zeros(self._count, bool)
        if self._count and self._prepared is not None:
            mask[self._kept] = True
        return mask

    def set_lines(self, positions: np.ndarray, edges: np.ndarray, colours: np.ndarray) -> None:
        """Segments between rows of `positions` (M, 3), edges (E, 2), colours (E, 3|4), drawn over the splats by
        `draw` in "rgb" mode until `clear_lines`."""
        self._activate()
        if self._lines is None:
            self._lines = LinePass41(self.ctx)
        self._lines.set(positions, edges, colours)

    def release(self) -> None:
        """Free all GL objects of this renderer."""
        self._activate()
        for tex in self._textures.values():
            tex.release()
        self._textures.clear()
        super().release()
