"""`Window`: the glfw window with its OpenGL context and imgui, and the per-frame loop around them.

Opens a 4.3 core context (the compute path), else 4.1 core (macOS, the 4.1 path); installs imgui's glfw and
OpenGL backends; splits the framebuffer into the side panel (`SIDE_PANEL` logical pixels) and the splat view.
`take_input` polls input (or waits for it up to a timeout when nothing moves), `new_frame` starts imgui's frame,
`finish_ui` ends it (and fingerprints what imgui would draw, so that a frame with nothing new need not be drawn
again), `draw_ui` renders imgui, `swap` shows the frame. Nothing here knows about avatars.
"""

from __future__ import annotations

import ctypes
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import moderngl
import numpy as np

from npga_view.imgui_glfw import drawable, glfw, imgui
from npga_view.rendering.gl import prefer_raster_threads, release_current_egl, window_context

SIDE_PANEL = 400  # logical pixels
DRAW_VERT_BYTES = 20  # ImDrawVert: position (2 floats), uv (2 floats), colour (4 bytes)


def _memory(address: int, size: int) -> memoryview:
    """`size` bytes at `address`, read in place (hashed each frame: no copy)."""
    return memoryview((ctypes.c_char * size).from_address(address)) if size else memoryview(b"")


def draw_data_fingerprint(data: Any) -> int:
    """A fingerprint of what imgui's draw data `data` draws: its vertices, indices, commands, clip rectangles and
    sizes, and any texture it must update (equal fingerprints: the same pixels)."""
    h = zlib.crc32(np.array([*data.display_size, *data.framebuffer_scale, data.cmd_lists_count],
                            np.float32).tobytes())
    for cl in data.cmd_lists:
        v, i = cl.vtx_buffer, cl.idx_buffer
        h = zlib.crc32(_memory(v.data_address(), v.size() * DRAW_VERT_BYTES), h)
        h = zlib.crc32(_memory(i.data_address(), i.size() * 2), h)  # (at least 2 bytes an index)
        cmds = [(c.elem_count, c.idx_offset, c.vtx_offset, *c.clip_rect) for c in cl.cmd_buffer]
        h = zlib.crc32(repr(cmds).encode(), h)
    if any(t.status != imgui.ImTextureStatus.ok for t in (data.textures or [])):
        h = zlib.crc32(b"texture update", h ^ 0x5A5A5A5A)  # (never equal to a frame without it)
    return h


class Window:
    """One glfw window; `handle` is glfw's window (None once closed), `ctx` its moderngl context."""

    def __init__(self, width: int, height: int, visible: bool = True, vsync: bool = True,
                 on_drop: Callable[[Any, list[str]], None] | None = None, title: str = "npga-view"):
        release_current_egl()  # a current headless context of this process would make the window's GLX fail
        prefer_raster_threads()  # (before the driver loads with the first window)
        if not glfw.init():
            raise RuntimeError("glfw could not initialise (no display? set DISPLAY or use Xvfb)")
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)  # macOS gives core contexts only forward-compatible
        glfw.window_hint(glfw.VISIBLE, visible)
        glfw.window_hint(glfw.SCALE_TO_MONITOR, True)
        self.handle = None
        self._size_cache: tuple[tuple[int, int], tuple[int, int]] | None = None
        for minor in (3, 1):  # 4.3 core for the compute path, else 4.1 core (macOS) for the 4.1 path (#18)
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, minor)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pyGLFW warns about the refused 4.3 request
                self.handle = glfw.create_window(width, height, title, None, None)
            if self.handle:
                break
        if not self.handle:
            glfw.terminate()
            raise RuntimeError("could not open an OpenGL 4.3 or 4.1 core window")
        glfw.make_context_current(self.handle)
        glfw.swap_interval(1 if vsync else 0)
        if on_drop is not None:  # before imgui installs (and chains) its callbacks; pyGLFW's stub lacks this form
            glfw.set_drop_callback(self.handle, on_drop)  # type: ignore[arg-type]
        self._watch_input()
        imgui.create_context()
        imgui.get_io().set_ini_filename(None)
        ptr = ctypes.cast(self.handle, ctypes.c_void_p).value
        assert ptr is not None
        imgui.backends.glfw_init_for_opengl(ptr, True)
        imgui.backends.opengl3_init("#version 330")
        self.ctx: moderngl.Context = window_context()

    # -- input ----------------------------------------------------------------------------------------
    def _watch_input(self) -> None:
        """Count the input that can change the view (a button, the wheel, a key, the pointer while a button is
        held) in `input_serial`; installed before imgui's callbacks, which chain to these."""
        self.input_serial = 0
        self._serial_taken = 0
        self._held: set[int] = set()

        def bump(*_args) -> None:
            self.input_serial += 1

        def button(_window, button: int, action: int, _mods: int) -> None:
            (self._held.add if action == glfw.PRESS else self._held.discard)(button)
            self.input_serial += 1

        def motion(*_args) -> None:
            if self._held:
                self.input_serial += 1

        def exposed(_window) -> None:  # uncovered, restored: the window system lost what was drawn
            self.exposed = True

        self.exposed = False  # (take_exposed)
        handle = self._h
        glfw.set_window_refresh_callback(handle, exposed)
        glfw.set_mouse_button_callback(handle, button)
        glfw.set_scroll_callback(handle, bump)
        glfw.set_key_callback(handle, bump)
        glfw.set_cursor_pos_callback(handle, motion)

    def take_exposed(self) -> bool:
        """Whether the window system asked for the window to be drawn again since the last call (an expose)."""
        exposed, self.exposed = self.exposed, False
        return exposed

    def input_pending(self) -> bool:
        """Input that can change the view arrived since this frame took its input (the window system is asked
        now: its events are queued for the next frame). Long work of a still view checks this between slices."""
        glfw.poll_events()
        return self.input_serial != self._serial_taken

    # -- geometry ---------------------------------------------------------------------------------------
    @property
    def _h(self):
        """The glfw window (an error once closed)."""
        if self.handle is None:
            raise RuntimeError("the window is closed")
        return self.handle

    def _sizes(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """(framebuffer size, window size), asked of the window system once per `take_input` (each ask is a round
        trip to the X server: ~0.2 ms, eight of them a frame before)."""
        if self._size_cache is None:
            (fw, fh), (ww, wh) = glfw.get_framebuffer_size(self._h), glfw.get_window_size(self._h)
            self._size_cache = ((int(fw), int(fh)), (int(ww), int(wh)))
        return self._size_cache

    def framebuffer_size(self) -> tuple[int, int]:
        return self._sizes()[0]

    def logical_size(self) -> tuple[int, int]:
        """The window's size in logical pixels (imgui's units)."""
        return self._sizes()[1]

    def scale(self) -> float:
        """Framebuffer pixels per logical pixel."""
        (fw, _), (ww, _) = self._sizes()
        return fw / max(ww, 1)

    def viewport(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the splat view in framebuffer pixels (right of the side panel)."""
        fw, fh = self.framebuffer_size()
        side = min(int(SIDE_PANEL * self.scale()), fw - 16)
        return side, 0, max(1, fw - side), max(1, fh)

    def set_title(self, title: str) -> None:
        glfw.set_window_title(self._h, drawable(title))

    # -- frames -----------------------------------------------------------------------------------------
    def take_input(self, wait_s: float = 0.0) -> None:
        """Take input (waiting for it up to `wait_s` when > 0)."""
        if wait_s > 0:
            glfw.wait_events_timeout(wait_s)
        else:
            glfw.poll_events()
        self._size_cache = None  # (a resize comes with the events)
        self._serial_taken = self.input_serial

    def new_frame(self) -> None:
        """Start an imgui frame."""
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()

    def clear(self) -> None:
        """Bind the window's framebuffer over its whole size and clear it to the background grey."""
        self.ctx.screen.use()
        fw, fh = self.framebuffer_size()
        self.ctx.viewport = (0, 0, fw, fh)
        self.ctx.clear(0.08, 0.08, 0.09, 1.0)

    def finish_ui(self) -> int:
        """End imgui's frame (its draw lists are built, nothing is drawn yet); returns a fingerprint of what it
        would draw: its vertices, indices, commands, clip rectangles and sizes, and any texture it must update
        (a frame whose fingerprint and splat image are those on screen need not be drawn again)."""
        imgui.render()
        return draw_data_fingerprint(imgui.get_draw_data())

    def draw_ui(self) -> None:
        """Render imgui's draw lists (built by `finish_ui`) over the frame."""
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())

    def swap(self) -> None:
        """Show the frame (on a software GL this finishes the frame's queued drawing and copies the image)."""
        glfw.swap_buffers(self._h)

    def close_requested(self) -> bool:
        return bool(glfw.window_should_close(self._h))

    def read(self, viewport_only: bool = False) -> np.ndarray:
        """RGB uint8 pixels of the back buffer as last drawn (top row first)."""
        fw, fh = self.framebuffer_size()
        vp = self.viewport() if viewport_only else (0, 0, fw, fh)
        data = self.ctx.screen.read(viewport=vp, components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(vp[3], vp[2], 3)[::-1].copy()

    def screenshot(self, path: str, viewport_only: bool = False) -> str:
        """Save the window or the splat view as an image (PNG by the name); OSError naming the file."""
        from npga_core.files.image_file import write_image  # (an OSError naming the file)

        Path(path).parent.mkdir(parents=True, exist_ok=True)
        write_image(Path(path), np.ascontiguousarray(self.read(viewport_only)[:, :, ::-1]))
        return str(path)

    def close(self) -> None:
        """Shut imgui down and destroy the window (safe to call twice)."""
        if self.handle is None:
            return
        imgui.backends.opengl3_shutdown()
        imgui.backends.glfw_shutdown()
        imgui.destroy_context()
        glfw.destroy_window(self.handle)
        self.handle = None
        glfw.terminate()
