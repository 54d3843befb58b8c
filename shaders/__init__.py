"""Data package `npga_view.shaders`: pyproject.toml maps this folder into npga_view (wheel, sdist, editable).

The renderer reads the GLSL sources through importlib.resources (`npga_view.rendering.renderer.SHADER_DIR`).
"""
