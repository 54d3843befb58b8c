"""Nothing Linux-only at import time, saves without `os.fchmod`, the platform's own folders, caches that stay
out of read-only and bundled folders."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from npga_core.files.atomic import atomic_write
from npga_core.files.loading import DEMO_AVATAR, DEMO_DIR
from npga_core.files.places import (
    bundled_root,
    cache_folder_for,
    is_bundled,
    process_temp_folder,
    user_cache_dir,
    user_config_dir,
)

ROOT = Path(__file__).resolve().parents[2]

# Imports every module of both packages as Windows would: the POSIX-only modules `resource`, `fcntl`, `termios`
# and `pwd`/`grp` cannot be imported and `os.fchmod` is absent (Windows before Python 3.13); then saves an
# avatar, a sequence and a preview cache path in a fresh folder.
_WINDOWS_LIKE = textwrap.dedent("""
    import importlib, os, pkgutil, sys, tempfile
    from pathlib import Path

    BLOCKED = {"resource", "fcntl", "termios", "pwd", "grp"}

    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r} (blocked: not on Windows)", name=name)
            return None

    for name in BLOCKED:
        sys.modules.pop(name, None)
    sys.meta_path.insert(0, Blocker())
    del os.fchmod

    imported = []
    for pkg in ("npga_core", "npga_view"):
        mod = importlib.import_module(pkg)
        imported.append(pkg)
        for info in pkgutil.walk_packages(mod.__path__, pkg + "."):
            if info.name.rsplit(".", 1)[-1] == "__main__":
                continue  # running it is not importing it
            importlib.import_module(info.name)
            imported.append(info.name)
    assert not BLOCKED & set(sys.modules), BLOCKED & set(sys.modules)

    import numpy as np
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.loading import load_avatar
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.synthetic import make_synthetic_avatar

    out = Path(tempfile.mkdtemp(dir="."))  # (in the test's folder: nothing left in the system's temp)
    avatar = make_synthetic_avatar(200, seed=1)
    save_avatar(avatar, out / "a.npga")
    save_avatar(avatar, out / "a.npga")  # over an existing file
    assert len(load_avatar(out / "a.npga")) == 200
    ExpressionSequence(np.zeros((3, avatar.code_dim), np.float32), 25.0).save(out / "s.npzseq")
    assert sorted(p.name for p in out.iterdir()) == ["a.npga", "s.npzseq"]  # no temp files left
    print(len(imported), "modules")
""")


def test_every_module_imports_and_saves_without_posix_only_modules(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "XDG_CONFIG_HOME": str(tmp_path / "config")}
    res = subprocess.run([sys.executable, "-c", _WINDOWS_LIKE], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    n = int(res.stdout.split()[0])
    expected = sum(1 for pkg in ("npga_core", "npga_view") for p in (ROOT / pkg).rglob("*.py")
                   if p.name != "__main__.py")
    assert n >= expected  # every module file (plus the data packages)


def test_the_blocker_really_blocks():
    code = _WINDOWS_LIKE.split("imported = []")[0] + "import resource\n"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode != 0 and "blocked" in res.stderr


def test_saves_keep_the_permissions_of_the_file_they_replace(tmp_path):
    if os.name != "posix":
        pytest.skip("permission bits are POSIX")
    target = tmp_path / "f.bin"
    atomic_write(target, lambda fh: fh.write(b"one"))
    target.chmod(0o640)
    atomic_write(target, lambda fh: fh.write(b"two"))
    assert target.read_bytes() == b"two" and target.stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["f.bin"]


def test_user_folders_are_the_platforms(tmp_path, monkeypatch):
    if not sys.platform.startswith("linux"):
        pytest.skip("XDG variables are the Linux convention")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from npga_core.editing.edits import autosave_dir
    from npga_view.state import config_dir

    assert config_dir() == user_config_dir() == tmp_path / "cfg" / "npga-view"
    assert user_cache_dir("previews") == tmp_path / "cache" / "npga-view" / "previews"
    assert autosave_dir() == tmp_path / "cache" / "npga-view" / "autosave"


def test_bundled_demo_is_package_data():
    assert is_bundled(DEMO_AVATAR) and bundled_root() / "demo" == DEMO_DIR
    assert (DEMO_DIR / "LICENSE.ict-facekit").is_file()
    assert not is_bundled(ROOT / "README.md")


def test_caches_go_next_to_avatars_in_writable_folders_else_to_the_user_cache(tmp_path, monkeypatch):
    from npga_core.posing.bake import cache_path
    from npga_core.posing.preview import preview_cache_path

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    mine = tmp_path / "work" / "me.npga"
    mine.parent.mkdir()
    mine.write_bytes(b"x")
    assert cache_folder_for(mine, "previews") == mine.parent
    assert preview_cache_path(mine, "k" * 40, 64, 8, 2).parent == mine.parent
    assert cache_path(mine, "k" * 40).parent == mine.parent
    # the bundled demo: never written into (an installed package lives in site-packages)
    cache = user_cache_dir()
    assert preview_cache_path(DEMO_AVATAR, "k" * 40, 64, 8, 2).parent == cache / "previews"
    assert cache_path(DEMO_AVATAR, "k" * 40).parent == cache / "bakes"
    # an explicit cache folder still wins
    assert cache_path(DEMO_AVATAR, "k" * 40, tmp_path / "c").parent == tmp_path / "c"


def test_read_only_avatar_folder_sends_caches_to_the_user_cache(tmp_path, monkeypatch):
    if os.name != "posix" or os.geteuid() == 0:
        pytest.skip("root writes into read-only folders: this case needs an ordinary user")
    from npga_core.posing.preview import preview_cache_path

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = tmp_path / "ro"
    folder.mkdir()
    (folder / "a.npga").write_bytes(b"x")
    folder.chmod(0o555)
    try:
        assert preview_cache_path(folder / "a.npga", "k" * 40, 64, 8, 2).parent == user_cache_dir("previews")
    finally:
        folder.chmod(0o755)


def test_native_dialogs_only_where_a_desktop_is_present():
    from npga_view.panels.files import native_dialogs_available as native

    def which_none(_: str) -> None:
        return None

    def which_zenity(name: str) -> str | None:
        return "/usr/bin/zenity" if name == "zenity" else None

    desktop = {"DISPLAY": ":0", "XDG_CURRENT_DESKTOP": "GNOME"}
    assert native(desktop, "linux", which_zenity)
    assert not native(desktop, "linux", which_none)  # no dialog program
    assert not native({"DISPLAY": ":99"}, "linux", which_zenity)  # a bare Xvfb: no desktop session
    assert not native({}, "linux", which_zenity)  # no display at all
    assert native({"WAYLAND_DISPLAY": "wayland-0", "DESKTOP_SESSION": "plasma"}, "linux", which_zenity)
    assert not native({**desktop, "SSH_CONNECTION": "10.0.0.1 5 10.0.0.2 22"}, "linux", which_zenity)
    assert native({}, "win32", which_none) and native({}, "darwin", which_none)
    assert not native({"SSH_TTY": "/dev/pts/1"}, "darwin", which_none)
    assert not native({**desktop, "NPGA_VIEW_DIALOGS": "builtin"}, "linux", which_zenity)
    assert native({"NPGA_VIEW_DIALOGS": "native"}, "linux", which_none)


@pytest.mark.gui
def test_native_open_dialog_answers_into_an_action(tmp_path):
    """The real portable_file_dialogs path on Linux: zenity opens under Xvfb, a user types a path and presses
    Enter (xdotool), the panel queues it as an open action. Needs zenity and xdotool (not installed by
    scripts/install.sh: zenity brings GTK and WebKit), else skipped."""
    if not sys.platform.startswith("linux") or not (shutil.which("zenity") and shutil.which("xdotool")):
        pytest.skip("needs Linux with zenity and xdotool (apt-get install zenity xdotool)")
    from npga_view.actions import OpenAvatar
    from npga_view.panels.files import FilesPanel
    from npga_view.state import ViewerState
    from tests.support.xvfb import start_xvfb, stop

    try:
        proc, display = start_xvfb()
    except RuntimeError as e:
        pytest.skip(str(e))
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = display
    target = tmp_path / "mine.npga"
    target.write_bytes(b"x")
    state = ViewerState()
    files = None
    try:
        files = FilesPanel(browse=str(tmp_path), native=True)
        files.ask_open("open_avatar", "Open an avatar (test)")
        found = subprocess.run(["xdotool", "search", "--sync", "--name", "Open an avatar"], capture_output=True,
                               text=True, timeout=30).stdout.split()
        assert found, "the zenity dialog did not appear"
        subprocess.run(["xdotool", "windowfocus", "--sync", found[0]], capture_output=True, timeout=10)
        time.sleep(0.5)
        subprocess.run(["xdotool", "type", "--delay", "50", str(target)], check=True, timeout=30)
        time.sleep(1.0)
        subprocess.run(["xdotool", "key", "Return"], check=True, timeout=10)
        end = time.monotonic() + 30
        while files.dialog is not None and time.monotonic() < end:
            files.poll_dialog(state)
            time.sleep(0.1)
        assert state.actions == [OpenAvatar(str(target))]
        assert files.browse == str(tmp_path)
    finally:
        if files is not None and files.dialog is not None:
            files.dialog[1].kill()
            files.dialog = None
        if old is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = old
        stop(proc)


@pytest.mark.skipif(os.name != "posix", reason="a pid is asked whether it runs on POSIX only")
def test_a_killed_viewers_temp_folder_is_removed_by_the_next_one(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a pid that no longer runs (reaped)
    dead = tmp_path / f"npga-view-edits-{gone.pid}-abc"
    alive = tmp_path / f"npga-view-edits-{os.getppid()}-def"  # the process that started this one runs
    other = tmp_path / f"npga-view-other-{gone.pid}-ghi"
    for d in (dead, alive, other):
        d.mkdir()
        (d / "edited-1.npga").write_bytes(b"x")
    mine = process_temp_folder("npga-view-edits")
    assert mine.parent == tmp_path and mine.name.startswith(f"npga-view-edits-{os.getpid()}-")
    assert not dead.exists() and alive.exists() and other.exists()
    assert process_temp_folder("npga-view-edits").exists() and mine.exists()  # a second one keeps this process's
