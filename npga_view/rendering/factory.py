"""`create_renderer`: the splat renderer path for a GL context, the 4.3 one or the 4.1 one (macOS).

OpenGL 4.3 and later get `SplatRenderer` (compute pre-pass, storage buffers); 4.1 and 4.2 get `SplatRenderer41`
(CPU pre-pass, texture splats). Both have the same API and draw the same images. The environment variable
NPGA_VIEW_GL=41 (or 43) forces a path, e.g. to try the 4.1 path on a 4.3 machine.
"""

from __future__ import annotations

import os

import moderngl

from npga_view.rendering.gl import GLUnavailableError
from npga_view.rendering.renderer import SplatRenderer

PATH_ENV = "NPGA_VIEW_GL"
PATHS = ("41", "43")


def choose_path(ctx: moderngl.Context, path: str | None = None) -> str:
    """"43" or "41": `path` if given, else $NPGA_VIEW_GL, else what the context's version allows."""
    wanted = path if path is not None else os.environ.get(PATH_ENV, "").strip()
    if wanted in ("", "auto"):
        return "43" if ctx.version_code >= 430 else "41"
    if wanted not in PATHS:
        raise ValueError(f"{PATH_ENV}={wanted!r}: choose 41, 43 or auto")
    if wanted == "43" and ctx.version_code < 430:
        raise GLUnavailableError(f"the OpenGL 4.3 renderer path was asked for ({PATH_ENV}=43), but the context "
                                 f"gives OpenGL {ctx.version_code // 100}.{ctx.version_code % 100 // 10}")
    return wanted


def create_renderer(ctx: moderngl.Context, width: int, height: int, exact_sort: bool = True,
                    path: str | None = None, cpu_colour: bool | None = None) -> SplatRenderer:
    """A splat renderer for `ctx` (see the module docstring); `path` "41"/"43" overrides the choice; `cpu_colour`
    the 4.3 path's colour pass on the CPU (None: on a software GL, `cpu_splats.py`)."""
    if choose_path(ctx, path) == "41":
        from npga_view.rendering.renderer41 import SplatRenderer41

        return SplatRenderer41(ctx, width, height, exact_sort)
    return SplatRenderer(ctx, width, height, exact_sort, cpu_colour)


def describe(renderer: SplatRenderer) -> str:
    """One line naming the renderer's path and its context, e.g. for `render --verbose` and `info`."""
    from npga_view.rendering.gl import version_text

    return f"{renderer.path} on {version_text(renderer.ctx)}"


def headless_path_line() -> str:
    """Which path a headless renderer of this machine would use ($NPGA_VIEW_GL included), or why there is none."""
    from npga_view.rendering.gl import create_headless_context, version_text

    try:
        ctx = create_headless_context()
    except GLUnavailableError as exc:
        return f"renderer: none ({exc})"
    try:
        choice = choose_path(ctx)
        name = "OpenGL 4.3 path" if choice == "43" else "OpenGL 4.1 path"
        return f"renderer: {name} (headless: {version_text(ctx)})"
    except (GLUnavailableError, ValueError) as exc:
        return f"renderer: none ({exc})"
    finally:
        ctx.release()
