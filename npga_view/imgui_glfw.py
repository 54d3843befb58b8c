"""Import imgui-bundle and glfw in the one order that works.

`imgui_bundle` must be imported before `glfw` so that pyGLFW binds imgui-bundle's own libglfw instead of
loading a second copy (the C++ imgui backends and Python must share one GLFW). Import both from here.
"""

from imgui_bundle import imgui  # isort: skip

import glfw  # isort: skip  # noqa: E402

__all__ = ["glfw", "imgui"]
