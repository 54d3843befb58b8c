"""`LinePass`: coloured line segments between 3D points (the kNN graph), drawn over the splat image.

Positions (M, 3), edges (E, 2) and one RGBA colour per edge live in storage buffers; a new pose rewrites only
the positions. Lines are 1 pixel wide (core-profile OpenGL), projected with the same camera maths as the splats
(`Camera.opengl_projection`, clipped at the near plane) and blended premultiplied "over" the image, without a
depth test: they are always on top.
"""

from __future__ import annotations

from typing import Protocol

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_view.rendering.uniforms import mat4_bytes, uniform


def pack_rgba8(colours: np.ndarray) -> np.ndarray:
    """(E, 3 or 4) floats in [0, 1] -> (E,) uint32 as GLSL unpackUnorm4x8 reads them (R in the low byte)."""
    c = np.asarray(colours, dtype=np.float32)
    if c.ndim != 2 or c.shape[1] not in (3, 4):
        raise ValueError(f"colours must be (E, 3) or (E, 4), got shape {c.shape}")
    if c.shape[1] == 3:
        c = np.concatenate([c, np.ones((len(c), 1), np.float32)], axis=1)
    rgba = np.ascontiguousarray(np.round(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8))
    return rgba.view(np.uint32).reshape(len(c))


class Lines(Protocol):
    """What the renderers need of a line pass (`LinePass`, `renderer41.LinePass41`)."""

    @property
    def edge_count(self) -> int: ...
    def set_positions(self, positions: np.ndarray) -> None: ...
    def set(self, positions: np.ndarray, edges: np.ndarray, colours: np.ndarray) -> None: ...
    def clear(self) -> None: ...
    def draw(self, camera: Camera, flip_y: bool, near: float, far: float = 1000.0,
             colour_scale: float = 1.0) -> None: ...
    def release(self) -> None: ...


class LinePass:
    """Segments between rows of a position array; `draw` into the currently bound framebuffer."""

    def __init__(self, ctx: moderngl.Context, load_shader) -> None:
        self.ctx = ctx
        self._prog = ctx.program(vertex_shader=load_shader("lines.vert"), fragment_shader=load_shader("lines.frag"))
        self._vao = ctx.vertex_array(self._prog, [])
        self._buffers: dict[str, moderngl.Buffer] = {}
        self._points = 0
        self._edges = 0

    @property
    def edge_count(self) -> int:
        return self._edges

    def _write(self, name: str, data: np.ndarray) -> None:
        data = np.ascontiguousarray(data)
        nbytes = max(data.nbytes, 16)
        buf = self._buffers.get(name)
        if buf is None or buf.size < nbytes:
            if buf is not None:
                buf.release()
            buf = self._buffers[name] = self.ctx.buffer(reserve=nbytes, dynamic=True)
        if data.nbytes:
            buf.write(data)

    def set_positions(self, positions: np.ndarray) -> None:
        """Move the ends (M, 3) (same edges, e.g. a new pose)."""
        p = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        self._write("positions", p)
        self._points = len(p)

    def set(self, positions: np.ndarray, edges: np.ndarray, colours: np.ndarray) -> None:
        """Positions (M, 3), edges (E, 2) of row indices, colours (E, 3|4) in [0, 1] (straight alpha)."""
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        self.set_positions(positions)
        if e.size and (e.min() < 0 or e.max() >= self._points):
            raise ValueError(f"edge indices must be in 0..{self._points - 1}")
        if len(colours) != len(e):
            raise ValueError(f"{len(colours)} colours for {len(e)} edges")
        self._write("edges", e.astype(np.uint32))
        self._write("colours", pack_rgba8(colours) if len(e) else np.zeros(0, np.uint32))
        self._edges = len(e)

    def clear(self) -> None:
        self._edges = 0

    def draw(self, camera: Camera, flip_y: bool, near: float, far: float = 1000.0, colour_scale: float = 1.0) -> None:
        """Blend the lines into the current framebuffer (viewport and blend state set by the caller), their
        premultiplied colour at `colour_scale` (the target's, targets.py)."""
        if not self._edges:
            return
        uniform(self._prog, "u_view").write(mat4_bytes(camera.world_to_camera))
        uniform(self._prog, "u_proj").write(mat4_bytes(camera.opengl_projection(near, far, flip_y)))
        uniform(self._prog, "u_colour_scale").value = colour_scale
        self._buffers["positions"].bind_to_storage_buffer(6)
        self._buffers["edges"].bind_to_storage_buffer(7)
        self._buffers["colours"].bind_to_storage_buffer(8)
        self._vao.render(moderngl.LINES, vertices=2 * self._edges)

    def release(self) -> None:
        for buf in self._buffers.values():
            buf.release()
        self._buffers.clear()
        self._vao.release()
        self._prog.release()
