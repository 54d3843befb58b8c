"""Where `npga-view web` finds LAM's web player (npm `gaussian-splat-renderer-for-lam`, MIT), never shipped with
npga-view: `--player DIR` (its build folder, its package folder or a folder whose node_modules holds it), else
the user's cache folder (`npga_core.files.places.user_cache_dir("web-player", VERSION)`), where npm installs the
version pinned by the page's package.json (`npga_view/web/package.json`) on first use. Without npm that is one
line saying what to install.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from npga_core.errors import CommandError
from npga_core.files.places import user_cache_dir

PAGE = Path(__file__).resolve().parent / "web"
PACKAGE = "gaussian-splat-renderer-for-lam"
MODULE = PACKAGE + ".module.js"
NPM_TIMEOUT_S = 600


class PlayerError(CommandError):
    """The player is not found and cannot be installed (one line, exit 2)."""


def pinned_version() -> str:
    """The player's version the page is written for (npga_view/web/package.json)."""
    return str(json.loads((PAGE / "package.json").read_text())["dependencies"][PACKAGE])


def build_folder(folder: Path) -> Path | None:
    """The folder holding the player's module among `folder`, `folder`/build and its node_modules; None if none."""
    for where in (folder, folder / "build", folder / "node_modules" / PACKAGE / "build"):
        if (where / MODULE).is_file():
            return where
    return None


def cache_folder() -> Path:
    return user_cache_dir("web-player", pinned_version())


def _installed(cache: Path, version: str) -> Path | None:
    meta = cache / "node_modules" / PACKAGE / "package.json"
    try:
        ok = json.loads(meta.read_text()).get("version") == version
    except (OSError, ValueError):
        return None
    return build_folder(cache) if ok else None


def install(cache: Path, version: str, npm: str | None = None) -> Path:
    """npm-install the pinned player into `cache` (if it is not there yet); its build folder."""
    found = _installed(cache, version)
    if found is not None:
        return found
    npm = npm or shutil.which("npm")
    if npm is None:
        raise PlayerError(f"LAM's web player ({PACKAGE} {version}, npm) is not installed and npm is not found: "
                          "install Node.js with npm (e.g. apt-get install npm) or give --player DIR")
    print(f"npga-view web: installing LAM's web player ({PACKAGE} {version}, npm, MIT) into {cache} (once)",
          file=sys.stderr, flush=True)
    try:
        cache.mkdir(parents=True, exist_ok=True)
        shutil.copy(PAGE / "package.json", cache / "package.json")
        r = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--ignore-scripts", "--no-save"], cwd=cache,
                           capture_output=True, text=True, timeout=NPM_TIMEOUT_S, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise PlayerError(f"npm install {PACKAGE}@{version} took more than {NPM_TIMEOUT_S} s") from None
    except OSError as e:
        raise PlayerError(f"npm install {PACKAGE}@{version} into {cache}: {e.strerror or e}") from None
    found = _installed(cache, version)
    if r.returncode != 0 or found is None:
        tail = " ".join((r.stderr or r.stdout or "no output").split())[-300:]
        raise PlayerError(f"npm install {PACKAGE}@{version} into {cache} failed (exit {r.returncode}): {tail}")
    return found


def player(given: Path | None) -> Path:
    """The player's build folder: `given` (--player) or the cache's npm install."""
    if given is not None:
        found = build_folder(given)
        if found is None:
            raise PlayerError(f"--player {given}: no {MODULE} in it, its build/ or its node_modules/{PACKAGE}/build/")
        return found
    return install(cache_folder(), pinned_version())
