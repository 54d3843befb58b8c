"""GLSL sources of the renderers: shaders/ (installed as the package data `npga_view.shaders`) with `#include`."""

from __future__ import annotations

import importlib.resources
import re
from collections.abc import Mapping
from pathlib import Path

#: The GLSL sources: the repository's shaders/, installed as the package data `npga_view.shaders`.
SHADER_DIR = Path(str(importlib.resources.files("npga_view.shaders")))
_INCLUDE = re.compile(r'^#include\s+"([^"]+)"\s*$', re.MULTILINE)


def load_shader(name: str, defines: Mapping[str, object] | None = None) -> str:
    """GLSL source of shaders/`name` with `#include "file"` resolved and `defines` added after `#version`."""
    source = (SHADER_DIR / name).read_text()
    source = _INCLUDE.sub(lambda m: (SHADER_DIR / m.group(1)).read_text(), source)
    if defines:
        lines = source.split("\n", 1)
        extra = "".join(f"#define {k} {v}\n" for k, v in defines.items())
        source = lines[0] + "\n" + extra + (lines[1] if len(lines) > 1 else "")
    return source
