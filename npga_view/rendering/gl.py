"""OpenGL context creation: headless (EGL, or OSMesa through ctypes) and the window's current context.

The renderer needs OpenGL 4.1 core: 4.3 and later run `SplatRenderer` (compute shaders, shader storage buffers),
4.1 and 4.2 (macOS) run `SplatRenderer41` (`npga_view.rendering.factory.create_renderer` chooses).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

import moderngl

REQUIRED_GL = 410
#: llvmpipe's rasterizer threads per CPU this process may use, unless LP_NUM_THREADS is set (`prefer_raster_threads`)
RASTER_THREADS_PER_CPU = 2

# OSMesa constants (GL/osmesa.h)
_OSMESA_RGBA = 0x1908
_OSMESA_FORMAT = 0x22
_OSMESA_DEPTH_BITS = 0x30
_OSMESA_STENCIL_BITS = 0x31
_OSMESA_ACCUM_BITS = 0x32
_OSMESA_PROFILE = 0x33
_OSMESA_CORE_PROFILE = 0x34
_OSMESA_CONTEXT_MAJOR_VERSION = 0x36
_OSMESA_CONTEXT_MINOR_VERSION = 0x37
_GL_UNSIGNED_BYTE = 0x1401


class GLUnavailableError(RuntimeError):
    """No OpenGL 4.1 context could be created; the message says what was tried and why it failed."""


class _OSMesaLoader:
    """A moderngl function loader for a current OSMesa context (keeps the context and its buffer alive)."""

    def __init__(self, lib: ctypes.CDLL, context: int, buffer: ctypes.Array, size: tuple[int, int]) -> None:
        self._lib = lib
        self._context = context
        self._buffer = buffer
        self._size = size
        self._get = lib.OSMesaGetProcAddress
        self._get.restype = ctypes.c_void_p
        self._get.argtypes = [ctypes.c_char_p]

    def load_opengl_function(self, name: str) -> int:
        return self._get(name.encode()) or 0

    def __enter__(self) -> None:
        if self._context:
            self._lib.OSMesaMakeCurrent(self._context, self._buffer, _GL_UNSIGNED_BYTE, *self._size)

    def __exit__(self, *args) -> None:
        pass

    def release(self) -> None:
        if self._context:
            self._lib.OSMesaDestroyContext(ctypes.c_void_p(self._context))
            self._context = 0


def _load_osmesa() -> ctypes.CDLL:
    names = [ctypes.util.find_library("OSMesa"), "libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"]
    errors = []
    for name in names:
        if not name:
            continue
        try:
            return ctypes.CDLL(name)
        except OSError as exc:
            errors.append(str(exc))
    raise GLUnavailableError("libOSMesa not found (install libosmesa6)" + (f": {errors[-1]}" if errors else ""))


def create_osmesa_context(width: int = 16, height: int = 16) -> moderngl.Context:
    """A GL 4.5 core context from Mesa's OSMesa (software), made current and wrapped by moderngl.

    It becomes moderngl's default context of this process. Render into your own framebuffers; the OSMesa
    default framebuffer is a small RGBA8 buffer.
    """
    lib = _load_osmesa()
    if not hasattr(lib, "OSMesaCreateContextAttribs"):
        raise GLUnavailableError("libOSMesa lacks OSMesaCreateContextAttribs (need Mesa >= 11.2)")
    lib.OSMesaCreateContextAttribs.restype = ctypes.c_void_p
    lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p]
    lib.OSMesaMakeCurrent.restype = ctypes.c_ubyte
    lib.OSMesaMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_int]
    lib.OSMesaDestroyContext.argtypes = [ctypes.c_void_p]
    attribs = [
        _OSMESA_FORMAT, _OSMESA_RGBA,
        _OSMESA_DEPTH_BITS, 24,
        _OSMESA_STENCIL_BITS, 8,
        _OSMESA_ACCUM_BITS, 0,
        _OSMESA_PROFILE, _OSMESA_CORE_PROFILE,
        _OSMESA_CONTEXT_MAJOR_VERSION, 4,
        _OSMESA_CONTEXT_MINOR_VERSION, 5,
        0,
    ]
    context = lib.OSMesaCreateContextAttribs((ctypes.c_int * len(attribs))(*attribs), None)
    if not context:
        raise GLUnavailableError("OSMesaCreateContextAttribs failed to create a GL 4.5 core context")
    buffer = (ctypes.c_ubyte * (width * height * 4))()
    if not lib.OSMesaMakeCurrent(context, buffer, _GL_UNSIGNED_BYTE, width, height):
        lib.OSMesaDestroyContext(context)
        raise GLUnavailableError("OSMesaMakeCurrent failed")
    loader = _OSMesaLoader(lib, context, buffer, (width, height))
    moderngl.init_context(loader)
    ctx = moderngl.get_context()
    ctx.extra = {"osmesa_loader": loader}  # keep the loader (and the buffer) alive with the context
    return ctx


def prefer_raster_threads() -> None:
    """Ask Mesa's llvmpipe (a software GL; GPU drivers ignore the variable) for `RASTER_THREADS_PER_CPU` rasterizer
    threads per usable CPU unless LP_NUM_THREADS is set: beside two busy processes on 2 cores the full-resolution
    draw of the demo took 283 ms with 4 threads against 361-370 ms with llvmpipe's default of 2 (its threads get a
    larger share of the CPUs, and a thread descheduled in its last tile holds up fewer pixels); idle, the same
    (docs/PERFORMANCE.md). Read when the driver is loaded: call before the process's first GL context."""
    if "LP_NUM_THREADS" not in os.environ:
        os.environ["LP_NUM_THREADS"] = str(RASTER_THREADS_PER_CPU * usable_cpus())


def usable_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # (macOS, Windows)
        return os.cpu_count() or 1


def _check_version(ctx: moderngl.Context, backend: str) -> moderngl.Context:
    if ctx.version_code < REQUIRED_GL:
        version = ctx.version_code
        ctx.release()
        raise GLUnavailableError(f"{backend} gives OpenGL {version // 100}.{version % 100 // 10}, need 4.1 core")
    return ctx


def create_headless_context(backend: str = "auto") -> moderngl.Context:
    """A headless OpenGL >= 4.1 core context (the highest version the driver offers): EGL first, then OSMesa;
    `backend` may force "egl" or "osmesa".

    Raises GLUnavailableError naming each backend tried and why it failed.
    """
    if backend not in ("auto", "egl", "osmesa"):
        raise ValueError(f"unknown GL backend {backend!r} (auto, egl, osmesa)")
    prefer_raster_threads()
    errors = []
    if backend in ("auto", "egl"):
        try:
            return _check_version(moderngl.create_standalone_context(require=REQUIRED_GL, backend="egl"), "EGL")  # type: ignore[arg-type]
        except Exception as exc:  # noqa: BLE001 - any failure means: try the next backend
            errors.append(f"EGL: {str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}")
    if backend in ("auto", "osmesa"):
        try:
            return _check_version(create_osmesa_context(), "OSMesa")
        except Exception as exc:  # noqa: BLE001
            errors.append(f"OSMesa: {str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}")
    raise GLUnavailableError("no headless OpenGL 4.1 context (" + "; ".join(errors) + ")")


def window_context() -> moderngl.Context:
    """Wrap the GL context current on this thread (e.g. a glfw window's) for the renderer."""
    return _check_version(moderngl.create_context(require=REQUIRED_GL), "the window context")


def version_text(ctx: moderngl.Context) -> str:
    """The context's OpenGL version and renderer, e.g. "OpenGL 4.5 (Core Profile) Mesa 22.3.6, llvmpipe (...)"."""
    info = ctx.info
    return f"OpenGL {info.get('GL_VERSION', ctx.version_code)}, {info.get('GL_RENDERER', '?')}"


def release_current_egl() -> None:
    """Make no EGL context current on this thread (a no-op without libEGL).

    A headless EGL context left current (moderngl does not un-bind it on release) makes the X server refuse
    the GLX context of a window opened later in the same process and thread (BadAccess on X_GLXMakeCurrent,
    which aborts the process). The window calls this before making its own context current; headless
    renderers make theirs current again before every use.
    """
    import ctypes.util

    name = ctypes.util.find_library("EGL")
    if name is None:
        return
    try:
        egl = ctypes.CDLL(name)
    except OSError:
        return
    egl.eglGetCurrentDisplay.restype = ctypes.c_void_p
    egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    egl.eglMakeCurrent.restype = ctypes.c_uint
    display = egl.eglGetCurrentDisplay()
    if display:
        egl.eglMakeCurrent(display, None, None, None)
