"""Import imgui-bundle and glfw in the one order that works, and make every text imgui draws drawable.

`imgui_bundle` must be imported before `glfw` so that pyGLFW binds imgui-bundle's own libglfw instead of
loading a second copy (the C++ imgui backends and Python must share one GLFW). Import both from here.

imgui's bindings refuse a str that is not valid UTF-8 (a lone surrogate: a name from a file or a packet, a path
with an undecodable byte) with a TypeError in the middle of a frame. The functions that draw text or labels are
wrapped here, once for every panel, so that such a str is drawn with its surrogates as backslash escapes
(`drawable`); valid text passes unchanged (one encode).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from imgui_bundle import imgui  # isort: skip

import glfw  # isort: skip  # noqa: E402

__all__ = ["drawable", "glfw", "imgui"]

#: imgui functions whose str arguments are text or labels drawn on screen
TEXT_FUNCTIONS = ("text", "text_disabled", "text_colored", "text_wrapped", "text_unformatted", "bullet_text",
                  "label_text", "set_tooltip", "separator_text", "button", "small_button", "selectable",
                  "menu_item", "begin_menu", "checkbox", "radio_button", "tree_node", "collapsing_header",
                  "begin_combo", "combo", "begin", "begin_child", "begin_tab_item", "slider_float", "slider_int",
                  "drag_float", "drag_int", "input_text", "progress_bar", "plot_lines", "plot_histogram",
                  "calc_text_size")


def drawable(text: str) -> str:
    """`text` as imgui can take it: unchanged when it is valid UTF-8, else its lone surrogates escaped."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _fix(value: Any) -> Any:
    return drawable(value) if isinstance(value, str) else value


def _guarded(func: Callable) -> Callable:
    @functools.wraps(func)
    def call(*args, **kwargs):
        return func(*(_fix(a) for a in args), **{k: _fix(v) for k, v in kwargs.items()})

    call.__npga_guarded__ = True  # type: ignore[attr-defined]
    return call


for _name in TEXT_FUNCTIONS:
    _func = getattr(imgui, _name, None)
    if _func is not None and not getattr(_func, "__npga_guarded__", False):
        setattr(imgui, _name, _guarded(_func))
