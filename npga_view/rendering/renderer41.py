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
from collections.abc import Mapping
from typing import cast

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import SH_C0, PosedGaussians, covariances, sh_degree_from_count
from npga_core.model.sh import SH_C1, SH_C2, SH_C3
from npga_view.rendering.lines import pack_rgba8
from npga_view.rendering.renderer import NEAR, SplatRenderer, camera_key
from npga_view.rendering.shader_source import load_shader
from npga_view.rendering.sorting import sort_back_to_front, view_depths
from npga_view.rendering.uniforms import mat4_bytes, uniform

#: texels per row of the splat and latent textures (the shaders' SPLAT_TEXTURE_WIDTH)
TEXTURE_WIDTH = 4096
MIN_ALPHA = 1.0 / 255.0
#: what a GL point's side adds to the ellipse's box (splat_common.glsl POINT_MARGIN)
POINT_MARGIN = 0.05


def load_shader41(name: str, defines: Mapping[str, object] | None = None) -> str:
    """The 4.1 twin `shaders/gl41_<name>` of a shader of the 4.3 path (includes resolved as for the 4.3 path)."""
    return load_shader("gl41_" + name, defines)


class Columns:
    """A posed cloud as the CPU pre-pass reads it: one contiguous float32 row per quantity (fast elementwise
    numpy over chunks): means (3, N), covariances (6, N), opacities (N,); SH (N, 3K)."""

    def __init__(self, posed: PosedGaussians) -> None:
        n = len(posed)
        self.means = np.ascontiguousarray(np.asarray(posed.means, np.float32).reshape(n, 3).T)
        self.cov = covariances(posed.quats, posed.scales)
        self.opacities = np.array(posed.opacities, dtype=np.float32, copy=True).reshape(n)
        sh = np.asarray(posed.sh, np.float32)
        self.degree = sh_degree_from_count(sh.shape[1])
        # a copy (the caller may reuse its arrays, e.g. a shared-memory slot); coefficient k of channel c at 3k + c
        self.sh = np.array(sh, dtype=np.float32, copy=True).reshape(n, 3 * sh.shape[1])
        self.n = n


def _sh_colour(cols: Columns, sl: slice, dirs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> list[np.ndarray]:
    """max(sum_k sh_k Y_k(d) + 0.5, 0) per channel: the basis of `npga_core.model.sh.sh_basis` in float32."""
    x, y, z = dirs
    basis: list[np.ndarray | None] = [None]
    if cols.degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if cols.degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
                  SH_C2[4] * (xx - yy)]
    if cols.degree >= 3:
        basis += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                  SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                  SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    out = []
    for ch in range(3):
        colour = np.float32(SH_C0) * cols.sh[sl, ch]
        for k in range(1, len(basis)):
            colour += cast(np.ndarray, basis[k]).astype(np.float32, copy=False) * cols.sh[sl, 3 * k + ch]
        out.append(np.maximum(colour + np.float32(0.5), np.float32(0.0)))
    return out


def _preprocess_chunk(cols: Columns, sl: slice, camera: Camera, proj: np.ndarray, out: np.ndarray,
                      keep: np.ndarray) -> None:
    """The pre-pass for Gaussians `sl` (stored order) into out[sl]'s rows and keep[sl]."""
    f32 = np.float32
    v = np.asarray(camera.world_to_camera, np.float32)
    x, y, z = cols.means[0, sl], cols.means[1, sl], cols.means[2, sl]
    op = cols.opacities[sl]
    tx = v[0, 0] * x + v[0, 1] * y + v[0, 2] * z + v[0, 3]
    ty = v[1, 0] * x + v[1, 1] * y + v[1, 2] * z + v[1, 3]
    tz = v[2, 0] * x + v[2, 1] * y + v[2, 2] * z + v[2, 3]
    k = (tz > f32(NEAR)) & (op >= f32(MIN_ALPHA))
    inv = f32(1.0) / tz
    lim_x, lim_y = f32(1.3 * camera.tan_half_fov_x), f32(1.3 * camera.tan_half_fov_y)
    cx = np.clip(tx * inv, -lim_x, lim_x) * tz
    cy = np.clip(ty * inv, -lim_y, lim_y) * tz
    fx, fy = f32(camera.fx), f32(camera.fy)
    # J W with J = ((fx/z, 0, -fx cx/z^2), (0, fy/z, -fy cy/z^2)): rows u and w
    j00, j02 = fx * inv, -fx * cx * inv * inv
    j11, j12 = fy * inv, -fy * cy * inv * inv
    u = [j00 * v[0, i] + j02 * v[2, i] for i in range(3)]
    w = [j11 * v[1, i] + j12 * v[2, i] for i in range(3)]
    cxx, cxy, cxz, cyy, cyz, czz = (cols.cov[i, sl] for i in range(6))
    cu = (cxx * u[0] + cxy * u[1] + cxz * u[2], cxy * u[0] + cyy * u[1] + cyz * u[2],
          cxz * u[0] + cyz * u[1] + czz * u[2])
    cw = (cxx * w[0] + cxy * w[1] + cxz * w[2], cxy * w[0] + cyy * w[1] + cyz * w[2],
          cxz * w[0] + cyz * w[1] + czz * w[2])
    a = u[0] * cu[0] + u[1] * cu[1] + u[2] * cu[2] + f32(0.3)
    b = w[0] * cu[0] + w[1] * cu[1] + w[2] * cu[2]
    c = w[0] * cw[0] + w[1] * cw[1] + w[2] * cw[2] + f32(0.3)
    det = a * c - b * b
    k &= det > 0.0
    # window coordinates of the centre through the GL projection; b flips with it
    clip_w = proj[3, 0] * tx + proj[3, 1] * ty + proj[3, 2] * tz + proj[3, 3]
    px = ((proj[0, 0] * tx + proj[0, 1] * ty + proj[0, 2] * tz + proj[0, 3]) / clip_w * f32(0.5) + f32(0.5)) \
        * f32(camera.width)
    py = ((proj[1, 0] * tx + proj[1, 1] * ty + proj[1, 2] * tz + proj[1, 3]) / clip_w * f32(0.5) + f32(0.5)) \
        * f32(camera.height)
    b = b * np.sign(proj[1, 1])
    r = f32(1.002) * np.sqrt(f32(2.0) * np.log(f32(255.0) * op))
    hx, hy = r * np.sqrt(a), r * np.sqrt(c)
    k &= (px + hx >= 0.0) & (py + hy >= 0.0) & (px - hx <= f32(camera.width)) & (py - hy <= f32(camera.height))
    keep[sl] = k
    # quad: eigenvectors of the covariance scaled by sqrt(eigenvalue) r
    mid = f32(0.5) * (a + c)
    disc = np.sqrt(np.maximum(f32(0.25) * (a - c) * (a - c) + b * b, f32(0.0)))
    l1 = mid + disc
    l2 = det / l1
    first = a >= c
    ex, ey = np.where(first, l1 - c, b), np.where(first, b, l1 - a)
    length = np.sqrt(ex * ex + ey * ey)
    ok = length > 0.0
    ex, ey = np.where(ok, ex / length, f32(1.0)), np.where(ok, ey / length, f32(0.0))
    s1, s2 = np.sqrt(l1) * r, np.sqrt(l2) * r
    o = out[sl]
    o[:, 0], o[:, 1], o[:, 2], o[:, 3] = px, py, tz, op
    o[:, 4], o[:, 5], o[:, 6], o[:, 7] = ex * s1, ey * s1, -ey * s2, ex * s2
    o[:, 8], o[:, 9], o[:, 10] = c / det, -b / det, a / det
    o[:, 11] = np.arange(sl.start, sl.stop, dtype=np.float32)
    centre = np.asarray(camera.camera_center, np.float32)
    dx, dy, dz = x - centre[0], y - centre[1], z - centre[2]
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    o[:, 12], o[:, 13], o[:, 14] = _sh_colour(cols, sl, (dx / norm, dy / norm, dz / norm))
    o[:, 15] = f32(2.0) * np.maximum(hx, hy) + f32(POINT_MARGIN)  # point_side (splat_common.glsl)


def preprocess(cols: Columns, order: np.ndarray, camera: Camera, flip_y: bool, max_point: float,
               chunk: int = 16384) -> tuple[np.ndarray, np.ndarray, int]:
    """The pre-pass of `shaders/splat_preprocess.comp` on the CPU, drawn in the sorted order `order`.

    Returns (splats (K, 16) float32 in draw order: centre (x, y, depth, opacity), half-axes, conic (a, b, c,
    index), colour (r, g, b, point side); the indices (K,) kept; the number of kept splats whose bounding square exceeds
    `max_point` pixels). Computed in chunks over all Gaussians in stored order (contiguous reads that stay in
    cache; a head is mostly in view), then the kept rows are taken in the sorted order.
    """
    proj = camera.opengl_projection(NEAR, 1000.0, flip_y).astype(np.float32)
    out = np.empty((cols.n, 16), np.float32)
    keep = np.zeros(cols.n, bool)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for start in range(0, cols.n, chunk):
            _preprocess_chunk(cols, slice(start, min(cols.n, start + chunk)), camera, proj, out, keep)
    kept = np.asarray(order, np.int64)
    kept = kept[keep[kept]]
    splats = out[kept]
    return splats, kept, int(np.count_nonzero(splats[:, 15] > max_point))


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

    def draw(self, camera: Camera, flip_y: bool, near: float, far: float = 1000.0, colour_scale: float = 1.0) -> None:
        """Blend the lines into the current framebuffer (viewport and blend state set by the caller), their
        premultiplied colour at `colour_scale` (the target's, targets.py)."""
        if not self._count:
            return
        if self._vao is None:
            self._vao = self.ctx.vertex_array(self._prog, [(self._positions, "3f", "in_position"),
                                                           (self._colours, "4f1", "in_colour")])
        uniform(self._prog, "u_view").write(mat4_bytes(camera.world_to_camera))
        uniform(self._prog, "u_proj").write(mat4_bytes(camera.opengl_projection(near, far, flip_y)))
        uniform(self._prog, "u_colour_scale").value = colour_scale
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
        self._columns: Columns | None = None
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
        sh = np.asarray(posed.sh, dtype=np.float32)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise ValueError(f"sh must be (N, K, 3) with N={n}, got {sh.shape}")
        sh_degree_from_count(sh.shape[1])
        self._sh_coeffs = sh.shape[1]
        self._columns = Columns(posed)
        self._texture("splats", 4 * n)
        if posed.latent is not None:
            latent = np.asarray(posed.latent, dtype=np.float32).reshape(n, np.shape(posed.latent)[-1])
            self._latent_dim = latent.shape[1]
            per = -(-self._latent_dim // 4)
            padded = np.zeros((n, 4 * per), np.float32)
            padded[:, :self._latent_dim] = latent
            self._upload("latent", padded)
        else:
            self._latent_dim = 0
        self._uploaded(means, n, t0, posed.scales)

    def _prepare(self, camera: Camera, flip_y: bool) -> None:
        """Sort and run the CPU pre-pass for `camera` (skipped when camera and data are unchanged)."""
        key = (*camera_key(camera), flip_y)
        upload_ms = self._start_prepare(key)
        if upload_ms is None:
            return
        t0 = time.perf_counter()
        means, columns = self._means, self._columns
        assert means is not None and columns is not None
        z = view_depths(means, camera.world_to_camera)
        order = sort_back_to_front(z, NEAR, exact=self.exact_sort)
        t1 = time.perf_counter()
        splats, self._kept, self._oversize = preprocess(columns, order, camera, flip_y,
                                                        self.max_point)
        self._plan_slices(z, self._kept, camera)
        t2 = time.perf_counter()
        if len(splats):
            self._upload("splats", splats)
        self._visible = len(splats)
        t3 = time.perf_counter()
        self.last_timings.update(sort=(t1 - t0) * 1e3, preprocess=(t2 - t1) * 1e3, upload=upload_ms + (t3 - t2) * 1e3)
        self._prepared = key

    def _bind_splats(self, prog: moderngl.Program) -> None:
        self._textures["splats"].use(0)
        uniform(prog, "u_splats").value = 0

    def _bind_latent(self, prog: moderngl.Program) -> None:
        self._textures["latent"].use(1)
        uniform(prog, "u_latent").value = 1

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
