"""The splat renderer's two colour targets: the front holds the finished image, the back the one being drawn.

Colour images (modes "rgb" and "alpha") are kept as RGBA16 (normalised): llvmpipe blends it ~10 % faster than
RGBA32F at 1360x900 (docs/PERFORMANCE.md) and its 16 bits stay ~100 dB from a float image after blending
the demo's 79k splats. The premultiplied colour is stored at `COLOUR_SCALE` (half) of its value, so that colour
up to 2.0 (SH colours above 1, a fragment's or an accumulated one) is kept as a float target keeps it, instead of
being clamped at 1 by the format; the draw passes multiply by the scale, `read_front` and the compositing pass
divide by it. Depth images (camera-space z, beyond [0, 1]) get RGBA32F.
"""

from __future__ import annotations

import moderngl
import numpy as np

#: storage of colour images, and the factor their premultiplied colour is stored at
COLOUR_DTYPE = "nu2"
COLOUR_SCALE = 0.5
#: storage of depth images
PRECISE_DTYPE = "f4"

_Target = tuple[moderngl.Texture, moderngl.Framebuffer]


def read_rgba(fbo: moderngl.Framebuffer, attachment: int, width: int, height: int) -> np.ndarray:
    """Colour attachment `attachment` of `fbo` as float32 (height, width, 4), rows as stored (a read-only view)."""
    data = fbo.read(viewport=(0, 0, width, height), components=4, dtype="f4", attachment=attachment)
    return np.frombuffer(data, dtype=np.float32).reshape(height, width, 4)


def colour_scale(dtype: str) -> float:
    """What premultiplied colour is multiplied by when stored in a target of `dtype`."""
    return COLOUR_SCALE if dtype == COLOUR_DTYPE else 1.0


class ImageTargets:
    """Front and back colour target of one context; `swap` makes a finished back image the front."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._targets: list[_Target | None] = [None, None]  # front, back

    def back(self, width: int, height: int, precise: bool) -> moderngl.Framebuffer:
        """The back target at `width` x `height`, RGBA32F when `precise` (depth) else the colour format,
        reallocated when it differs (the front keeps the last finished image)."""
        dtype = PRECISE_DTYPE if precise else COLOUR_DTYPE
        back = self._targets[1]
        if back is not None and back[0].size == (width, height) and back[0].dtype == dtype:
            return back[1]
        info = self.ctx.info  # a target larger than GL allows crashed natively (stack smashing) in Mesa
        limit = min(int(info.get("GL_MAX_TEXTURE_SIZE", 16384)), int(info.get("GL_MAX_RENDERBUFFER_SIZE", 16384)),
                    *(int(v) for v in info.get("GL_MAX_VIEWPORT_DIMS", (16384, 16384))))
        if not (1 <= width <= limit and 1 <= height <= limit):
            raise ValueError(f"image size {width}x{height} is outside what this GL can allocate (1..{limit} per side)")
        if back is not None:
            back[1].release()
            back[0].release()
        tex = self.ctx.texture((width, height), 4, dtype=dtype)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        fbo = self.ctx.framebuffer([tex])
        self._targets[1] = (tex, fbo)
        return fbo

    @property
    def back_scale(self) -> float:
        """`colour_scale` of the back target (1.0 before it exists)."""
        back = self._targets[1]
        return 1.0 if back is None else colour_scale(back[0].dtype)

    @property
    def back_texture(self) -> moderngl.Texture:
        """The back target's texture (after `back`)."""
        back = self._targets[1]
        assert back is not None
        return back[0]

    def swap(self) -> None:
        self._targets[0], self._targets[1] = self._targets[1], self._targets[0]

    @property
    def front_texture(self) -> moderngl.Texture | None:
        return None if self._targets[0] is None else self._targets[0][0]

    @property
    def front_scale(self) -> float:
        """`colour_scale` of the finished image (1.0 before the first)."""
        tex = self.front_texture
        return 1.0 if tex is None else colour_scale(tex.dtype)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the finished image ((0, 0) before the first)."""
        tex = self.front_texture
        return (0, 0) if tex is None else tex.size

    def read_front(self) -> np.ndarray:
        """The finished image: premultiplied RGBA (H, W, 4) float32 at its true colour, rows as stored."""
        front = self._targets[0]
        if front is None:
            raise ValueError("no image is finished yet")
        (w, h), scale = front[0].size, colour_scale(front[0].dtype)
        image = read_rgba(front[1], 0, w, h)
        if scale == 1.0:
            return image
        image = image.copy()
        image[..., :3] *= np.float32(1.0 / scale)
        return image

    def release(self) -> None:
        for target in self._targets:
            if target is not None:
                target[1].release()
                target[0].release()
        self._targets = [None, None]
