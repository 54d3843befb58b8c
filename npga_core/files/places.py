"""Where npga-view's own files live on every platform.

- bundled data (the demo avatar): package data of `npga_core.assets`, found with importlib.resources, so it
  is the same in a wheel, an sdist build and an editable install;
- per-user settings and caches: each platform's own folders through platformdirs (Linux: `$XDG_CONFIG_HOME`
  and `$XDG_CACHE_HOME`, default `~/.config/npga-view`, `~/.cache/npga-view`; macOS: `~/Library/Application
  Support/npga-view`, `~/Library/Caches/npga-view`; Windows: `%LOCALAPPDATA%\\npga-view` and its `Cache`);
- caches derived from an avatar (preview models, bakes): next to the avatar when that folder is writable and
  is not the bundled data, else in the user's cache folder (an installed package is often read-only, and
  caches never belong inside site-packages).
"""

from __future__ import annotations

import functools
import importlib.resources
import os
import shutil
import tempfile
from pathlib import Path
from typing import cast

import platformdirs

APP = "npga-view"


@functools.cache
def bundled_root() -> Path:
    """The folder of the bundled data (the repository's `assets/`, installed as `npga_core/assets/`).

    Without an install (the checkout merely on sys.path) the data package is not there: the result is then a
    folder that does not exist, named so that the "missing" error that follows says why.
    """
    try:
        root = importlib.resources.files("npga_core.assets")
    except ModuleNotFoundError:
        return Path("npga_core.assets (not installed: pip install -e . or a wheel)")
    return Path(os.fspath(cast(Path, root))).resolve()  # a plain folder: wheels are installed unpacked


def bundled_path(*parts: str) -> Path:
    """A path inside the bundled data, e.g. `bundled_path("demo", "avatar.npga")`."""
    return bundled_root().joinpath(*parts)


def user_config_dir() -> Path:
    """Per-user settings folder (recent files, presets)."""
    return platformdirs.user_config_path(APP, appauthor=False)


def user_cache_dir(*parts: str) -> Path:
    """Per-user cache folder, or a subfolder of it (not created here)."""
    return platformdirs.user_cache_path(APP, appauthor=False).joinpath(*parts)


def is_bundled(path: str | Path) -> bool:
    """Whether `path` lies inside the bundled data."""
    try:
        Path(path).resolve().relative_to(bundled_root())
    except ValueError:
        return False
    return True


def folder_writable(folder: str | Path) -> bool:
    """Whether a file can be created in `folder` (tried for real: `os.access` misses Windows ACLs)."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def cache_folder_for(path: str | Path, kind: str) -> Path:
    """Where caches derived from the file `path` go: its folder when writable and not bundled data, else the
    user cache subfolder `kind` (e.g. "previews", "bakes")."""
    folder = Path(path).resolve().parent
    if not is_bundled(folder) and folder_writable(folder):
        return folder
    return user_cache_dir(kind)


def process_temp_folder(prefix: str) -> Path:
    """A new private temp folder named `prefix`-PID-xxxx for this process's working files. Folders of the same
    prefix left by processes of this user that no longer run (killed before they could remove theirs) are
    removed first (POSIX, where a pid can be asked whether it runs without touching the process)."""
    tmp = Path(tempfile.gettempdir())
    if os.name == "posix":
        for old in tmp.glob(f"{prefix}-*-*"):
            try:
                pid = int(old.name[len(prefix) + 1:].split("-", 1)[0])
                if old.stat().st_uid != os.getuid() or not old.is_dir() or pid == os.getpid():
                    continue
                os.kill(pid, 0)
            except ProcessLookupError:
                shutil.rmtree(old, ignore_errors=True)
            except (ValueError, OSError):
                continue
    return Path(tempfile.mkdtemp(prefix=f"{prefix}-{os.getpid()}-"))
