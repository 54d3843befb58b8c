"""pytest plugin (`-p gl41_swap`, tests/ on sys.path): runs the renderer test modules against the OpenGL 4.1 path.

Loaded before the test modules are collected, it replaces `npga_view.rendering.renderer.SplatRenderer` by
`SplatRenderer41` (a subclass, created from the original before the swap), so every
`from npga_view.rendering.renderer import SplatRenderer` in tests/view/test_renderer.py, test_picking.py,
test_budgeted_draw.py, test_live_detail.py and test_knn_lines.py builds the 4.1 path. tests/view/test_gl41.py runs
them this way under Mesa's 4.1 override (MESA_GL_VERSION_OVERRIDE=4.1FC); the report header names the
context's version.
"""

from __future__ import annotations

import npga_view.rendering.renderer as renderer_module
from npga_view.rendering.renderer41 import SplatRenderer41

renderer_module.SplatRenderer = SplatRenderer41


def pytest_report_header(config) -> str:
    from npga_view.rendering.gl import create_headless_context, version_text

    ctx = create_headless_context()
    try:
        return f"gl41_swap: SplatRenderer is SplatRenderer41; headless context {version_text(ctx)}"
    finally:
        ctx.release()
