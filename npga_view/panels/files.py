"""Files: open an avatar or a sequence by path, through the platform's file dialog (where a desktop is
present) or the in-window folder listing (otherwise: Xvfb, SSH, no dialog program), or from the recent list.

Native dialogs are imgui-bundle's `portable_file_dialogs` (Windows' and macOS' own, zenity/kdialog on Linux);
they run beside the window and are polled each frame, so the viewer keeps drawing while one is open.
`native_dialogs_available` decides; `NPGA_VIEW_DIALOGS=native|builtin` overrides it. `ask_save` is the same
for a save dialog, for panels that save.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

from imgui_bundle import imgui

from npga_core.errors import shown
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

AVATAR_EXT = (".npga", ".ply")
SEQUENCE_EXT = (".npzseq", ".npz", ".npy")
DIALOG_ENV = "NPGA_VIEW_DIALOGS"
#: the programs portable_file_dialogs drives on Linux/BSD (portable-file-dialogs.h, settings::available)
LINUX_DIALOG_PROGRAMS = ("zenity", "matedialog", "qarma", "kdialog")
FILTERS = {
    "open_avatar": ["Avatars (.npga, .ply)", "*.npga *.ply", "All files", "*"],
    "open_sequence": ["Sequences (.npzseq, .npz, .npy)", "*.npzseq *.npz *.npy", "All files", "*"],
}
_ui: dict = {"path": "", "browse": os.getcwd(), "dialog": None, "native": None}


def native_dialogs_available(env: Mapping[str, str] = os.environ, platform: str = sys.platform,
                             which: Callable[[str], str | None] = shutil.which) -> bool:
    """Whether a native file dialog would reach the user: Windows and macOS unless over SSH; elsewhere a
    desktop session (a display and XDG_CURRENT_DESKTOP or DESKTOP_SESSION, which a bare Xvfb lacks) and one of
    the dialog programs. `NPGA_VIEW_DIALOGS=native` or `builtin` decides instead."""
    choice = env.get(DIALOG_ENV, "").strip().lower()
    if choice in ("native", "builtin"):
        return choice == "native"
    if env.get("SSH_CONNECTION") or env.get("SSH_TTY"):
        return False  # the dialog would open on the remote machine's screen, or nowhere
    if platform in ("win32", "cygwin", "darwin"):
        return True
    if not (env.get("WAYLAND_DISPLAY") or env.get("DISPLAY")):
        return False
    if not (env.get("XDG_CURRENT_DESKTOP") or env.get("DESKTOP_SESSION")):
        return False
    return any(which(p) for p in LINUX_DIALOG_PROGRAMS)


def _native() -> bool:
    if _ui["native"] is None:
        _ui["native"] = native_dialogs_available()
    return _ui["native"]


def ask_open(action: str, title: str) -> None:
    """Open the native dialog for `action` ("open_avatar", "open_sequence", or "open_folder" for a tracking
    folder); its answer is queued as that action when the user closes it."""
    from imgui_bundle import portable_file_dialogs as pfd

    if _ui["dialog"] is not None:
        return
    if action == "open_folder":
        _ui["dialog"] = ("open_sequence", pfd.select_folder(title, _ui["browse"]))
    else:
        _ui["dialog"] = (action, pfd.open_file(title, _ui["browse"], FILTERS[action]))


def ask_save(title: str, default_path: str, filters: list[str] | None = None):
    """Start a native save dialog (it asks before overwriting); poll `.ready(0)`, then `.result()` is the
    chosen path or "" when cancelled."""
    from imgui_bundle import portable_file_dialogs as pfd

    return pfd.save_file(title, default_path, filters if filters is not None else ["All files", "*"])


def _poll_dialog(state: ViewerState) -> None:
    pending = _ui["dialog"]
    if pending is None or not pending[1].ready(0):
        return
    _ui["dialog"] = None
    result = pending[1].result()
    path = result[0] if isinstance(result, list) and result else result if isinstance(result, str) else ""
    if path:
        state.actions.append((pending[0], path))
        _ui["browse"] = str(Path(path).parent if Path(path).is_file() else Path(path))


def _native_buttons() -> None:
    if _ui["dialog"] is not None:
        imgui.text_disabled("waiting for the file dialog...")
        return
    if imgui.button("Choose avatar..."):
        ask_open("open_avatar", "Open an avatar")
    imgui.same_line()
    if imgui.button("Choose sequence..."):
        ask_open("open_sequence", "Open an expression sequence")
    imgui.same_line()
    if imgui.button("Folder..."):
        ask_open("open_folder", "Open a MonoNPHM tracking folder")
    if imgui.is_item_hovered():
        imgui.set_tooltip("Choose a MonoNPHM tracking folder")


def _browser(state: ViewerState) -> None:
    folder = Path(_ui["browse"])
    imgui.text_disabled(shown(str(folder))[-60:])
    if imgui.begin_list_box("##browser", imgui.ImVec2(-1, 140)):
        if imgui.selectable("..", False)[0]:
            _ui["browse"] = str(folder.parent)
        try:
            entries = sorted(folder.iterdir(), key=lambda p: (not p.is_dir(), p.name.lower()))
        except OSError:
            entries = []
        for p in entries[:500]:
            if p.name.startswith("."):
                continue
            if p.is_dir():
                is_track = (p / "00000" / "z_exp.npy").is_file()
                if imgui.selectable(f"[{'seq' if is_track else 'dir'}] {shown(p.name)}", False)[0]:
                    if is_track:
                        state.actions.append(("open_sequence", str(p)))
                    else:
                        _ui["browse"] = str(p)
            elif p.suffix in AVATAR_EXT + SEQUENCE_EXT and imgui.selectable(shown(p.name), False)[0]:
                kind = "open_avatar" if p.suffix in AVATAR_EXT else "open_sequence"
                state.actions.append((kind, str(p)))
        imgui.end_list_box()


def draw(state: ViewerState, info: AppInfo) -> None:
    if not imgui.collapsing_header("Files", imgui.TreeNodeFlags_.default_open):
        return
    a = info.avatar
    imgui.text_wrapped(f"Avatar: {shown(Path(state.avatar_path).name) if state.avatar_path else '-'}"
                       + (f" ({len(a):,} Gaussians)" if a is not None else ""))
    imgui.text_wrapped(f"Sequence: {shown(Path(state.sequence_path).name) if state.sequence_path else '-'}")
    imgui.set_next_item_width(-1)
    _, _ui["path"] = imgui.input_text("##path", _ui["path"])
    remember(info, "path_input")
    if imgui.button("Open avatar"):
        state.actions.append(("open_avatar", _ui["path"].strip()))
    remember(info, "open_avatar")
    imgui.same_line()
    if imgui.button("Open sequence"):
        state.actions.append(("open_sequence", _ui["path"].strip()))
    remember(info, "open_sequence")
    imgui.same_line()
    if imgui.button("Demo"):
        state.actions.append(("open_avatar", "demo"))
    if _native():
        _poll_dialog(state)
        _native_buttons()
    elif imgui.tree_node("Browse"):
        _browser(state)
        imgui.tree_pop()
    if state.recent and imgui.tree_node("Recent"):
        for p in state.recent:
            if imgui.selectable(shown(p if len(p) < 50 else "..." + p[-47:]), False)[0]:
                ext = Path(p).suffix
                kind = "open_sequence" if ext in SEQUENCE_EXT or Path(p).is_dir() else "open_avatar"
                state.actions.append((kind, p))
        imgui.tree_pop()
    imgui.text_disabled("Tip: drop files on the window.")
