"""The window's entrance hall stays small and layered (issue 40, ARCHITECTURE.md "Size and complexity"):
controllers see the app through a host of at most 8 public members, import no panel, panels import no GL module,
the document imports none, and `ViewerApp` keeps to 25 attributes and 300 lines."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GL = ("moderngl", "glfw", "OpenGL")


def _project_imports(path: Path) -> set[str]:
    """The npga_view modules and the GL libraries `path` imports (at top level, in functions or for typing)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return {m for m in out if m.startswith(("npga_view", *GL))}


def _module_path(name: str) -> Path | None:
    p = ROOT / Path(*name.split("."))
    for candidate in (p / "__init__.py", p.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def _reach(start: Path) -> set[str]:
    """Every npga_view module and GL library `start` reaches through imports (package __init__s included)."""
    seen: set[str] = set()
    todo = list(_project_imports(start))
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]  # a.b.c runs a/__init__ and a/b/__init__
        p = _module_path(name)
        if p is not None:
            todo += list(_project_imports(p))
    return seen


def test_the_reach_finds_a_gl_import():
    assert "moderngl" in _reach(ROOT / "npga_view/comparison/controller.py")


def test_panels_reach_no_gl_module():
    for p in sorted((ROOT / "npga_view/panels").glob("*.py")):
        gl = {m for m in _reach(p) if m.startswith(("moderngl", "OpenGL", "npga_view.rendering", "npga_view.window"))}
        assert not gl, f"{p.relative_to(ROOT)} reaches {sorted(gl)}"


def test_controllers_import_no_panel():
    for p in sorted((ROOT / "npga_view/controllers").glob("*.py")):
        panels = {m for m in _project_imports(p) if m.startswith("npga_view.panels")}
        assert not panels, f"{p.relative_to(ROOT)} imports {sorted(panels)}"


def test_the_document_is_free_of_gl_and_ui():
    reach = _reach(ROOT / "npga_view/document.py")
    assert not {m for m in reach if m.startswith((*GL, "npga_view.imgui_glfw", "npga_view.rendering"))}, reach


def test_the_host_the_controllers_see_is_small_and_public():
    tree = ast.parse((ROOT / "npga_view/controllers/host.py").read_text())
    host = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "ViewerHost")
    members = [n.target.id for n in host.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)]
    members += [n.name for n in host.body if isinstance(n, ast.FunctionDef)]
    assert len(members) <= 8, members
    assert not [m for m in members if m.startswith("_")]
    assert not (ROOT / "npga_view/opening.py").read_text().count("class OpeningHost")


def test_the_app_stays_small():
    text = (ROOT / "npga_view/app.py").read_text()
    assert len(text.splitlines()) <= 300
    app = next(n for n in ast.parse(text).body if isinstance(n, ast.ClassDef) and n.name == "ViewerApp")
    attributes = {t.attr for n in ast.walk(app) if isinstance(n, ast.Assign | ast.AnnAssign)
                  for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                  if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) and t.value.id == "self"}
    assert len(attributes) <= 25, sorted(attributes)
    assert not {"legacy", "unbudgeted"} & attributes  # benchmarks inject what they need (a scheduler class)
