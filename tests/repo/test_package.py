"""The wheel and the sdist carry the shaders and the demo (with its licence) as package data, and an installed
wheel finds them from any folder without the source tree. (CI goes further: .ci/run installs the wheel with
its dependencies into a fresh venv and renders; see scripts/check_wheel.sh.)"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
DATA_PACKAGES = {"npga_core.assets": "assets", "npga_view.shaders": "shaders"}
_SKIP = shutil.ignore_patterns(".venv*", ".git", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache",
                               ".ruff_cache", "out", "*.preview-*", "*.npgabake")


def test_package_list_names_every_package_folder():
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for pkg in ("npga_core", "npga_view")
             for p in (ROOT / pkg).rglob("__init__.py")}
    assert found <= listed, f"add to [tool.setuptools] packages in pyproject.toml: {sorted(found - listed)}"
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == DATA_PACKAGES
    for folder in DATA_PACKAGES.values():
        assert (ROOT / folder / "__init__.py").is_file()


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    """The sdist and the wheel built (as `pip install .` would: the wheel from the sdist) from a copy of the
    checkout, so the build writes nothing into it."""
    pytest.importorskip("build")
    tmp = tmp_path_factory.mktemp("dist")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=_SKIP)
    res = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(tmp / "out"), str(src)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    return tmp / "out"


def _data_files(folder: str) -> set[str]:
    return {p.relative_to(ROOT / folder).as_posix() for p in (ROOT / folder).rglob("*")
            if p.is_file() and p.name != "__init__.py" and "__pycache__" not in p.parts
            and not p.match("*.preview-*") and not p.name.endswith(".npgabake")}


def test_wheel_and_sdist_carry_shaders_and_demo(dist):
    wheel = next(dist.glob("*.whl"))
    sdist = next(dist.glob("*.tar.gz"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for package, folder in DATA_PACKAGES.items():
        prefix = package.replace(".", "/") + "/"
        files = _data_files(folder)
        assert files, folder
        assert {prefix + f for f in files} <= names, sorted({prefix + f for f in files} - names)
    assert "npga_core/assets/demo/LICENSE.ict-facekit" in names
    assert any(n.endswith(".dist-info/licenses/assets/demo/LICENSE.ict-facekit") for n in names)
    assert not [n for n in names if ".preview-" in n or n.endswith(".npgabake")]  # no caches
    with tarfile.open(sdist) as tf:
        top = {m.name.split("/", 1)[1] for m in tf.getmembers() if "/" in m.name}
    for folder in DATA_PACKAGES.values():
        assert {f"{folder}/{f}" for f in _data_files(folder)} <= top


@pytest.mark.slow
def test_installed_wheel_runs_from_another_folder(dist, tmp_path):
    """The wheel's files alone (dependencies from this environment), used from a folder that is not the
    checkout: `info demo` finds the demo inside the install and `render demo` draws it with its shaders."""
    target = tmp_path / "site"
    wheel = next(dist.glob("*.whl"))
    res = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-compile", "--target",
                          str(target), str(wheel)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    user = tmp_path / "user"
    user.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(target), XDG_CACHE_HOME=str(tmp_path / "cache"))
    run = [sys.executable, "-m", "npga_view"]
    info = subprocess.run([*run, "info", "demo"], capture_output=True, text=True, timeout=300, cwd=user, env=env)
    assert info.returncode == 0, info.stderr[-2000:]
    assert info.stdout.splitlines()[0] == str(target / "npga_core" / "assets" / "demo" / "avatar.npga")
    out = user / "x.png"
    res = subprocess.run([*run, "render", "demo", "--out", str(out), "--width", "120", "--height", "160"],
                         capture_output=True, text=True, timeout=300, cwd=user, env=env)
    if "OpenGL" in res.stderr and not os.environ.get("CI"):
        pytest.skip(res.stderr.strip()[-300:])
    assert res.returncode == 0, res.stderr[-2000:]
    import cv2

    img = cv2.imread(str(out))
    assert img.shape == (160, 120, 3) and img.std() > 10  # a face, not a flat image
