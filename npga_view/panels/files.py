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
from typing import Any

from imgui_bundle import imgui

from npga_core.errors import shown
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

AVATAR_EXT = (".npga", ".ply", ".zip")
SEQUENCE_EXT = (".npzseq", ".npz", ".npy")
DIALOG_ENV = "NPGA_VIEW_DIALOGS"
#: the programs portable_file_dialogs drives on Linux/BSD (portable-file-dialogs.h, settings::available)
LINUX_DIALOG_PROGRAMS = ("zenity", "matedialog", "qarma", "kdialog")
FILTERS = {
    "open_avatar": ["Avatars (.npga, .ply)", "*.npga *.ply", "All files", "*"],
    "open_sequence": ["Sequences (.npzseq, .npz, .npy)", "*.npzseq *.npz *.npy", "All files", "*"],
}


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


def ask_save(title: str, default_path: str, filters: list[str] | None = None):
    """Start a native save dialog (it asks before overwriting); poll `.ready(0)`, then `.result()` is the
    chosen path or "" when cancelled."""
    from imgui_bundle import portable_file_dialogs as pfd

    return pfd.save_file(title, default_path, filters if filters is not None else ["All files", "*"])



def open_action(path: str) -> A.OpenAvatar | A.OpenSequence:
    """Open `path` as an avatar (.npga, .ply files; GaussianAvatars and Gaussian-Head-Avatar folders) or else as
    a sequence (files, tracking folders)."""
    p = Path(path)
    if p.is_dir():
        return A.OpenAvatar(path) if is_avatar_folder(p) else A.OpenSequence(path)
    return A.OpenAvatar(path) if p.suffix.lower() in AVATAR_EXT else A.OpenSequence(path)


def is_avatar_folder(p: Path) -> bool:
    """A folder the avatar readers open: a GaussianAvatars output or a Gaussian-Head-Avatar checkpoint folder."""
    from npga_core.files.gaussian_avatars import is_ga_folder
    from npga_core.files.gha import is_gha_folder

    return is_ga_folder(p) or is_gha_folder(p)


_OPENERS = {"open_avatar": A.OpenAvatar, "open_sequence": A.OpenSequence}


class FilesPanel:
    """The Files panel; owns its widgets' state: the typed path, the folder being browsed, a pending dialog."""

    def __init__(self, browse: str, native: bool | None = None):
        self.path = ""
        self.browse = browse  # the folder the browser and the dialogs start in
        self.dialog: tuple[str, Any] | None = None  # (action name, pending portable_file_dialogs dialog)
        self.native = native  # native dialogs (None: decided by `native_dialogs_available` when first drawn)

    def _native(self) -> bool:
        if self.native is None:
            self.native = native_dialogs_available()
        return self.native

    def ask_open(self, action: str, title: str) -> None:
        """Open the native dialog for `action` ("open_avatar", "open_sequence", or "open_folder" for a tracking
        folder); its answer is queued as that action when the user closes it."""
        from imgui_bundle import portable_file_dialogs as pfd

        if self.dialog is not None:
            return
        if action == "open_folder":
            self.dialog = ("open_sequence", pfd.select_folder(title, self.browse))
        else:
            self.dialog = (action, pfd.open_file(title, self.browse, FILTERS[action]))

    def poll_dialog(self, state: ViewerState) -> None:
        pending = self.dialog
        if pending is None or not pending[1].ready(0):
            return
        self.dialog = None
        result = pending[1].result()
        path = result[0] if isinstance(result, list) and result else result if isinstance(result, str) else ""
        if path:
            state.actions.append(_OPENERS[pending[0]](path))
            self.browse = str(Path(path).parent if Path(path).is_file() else Path(path))

    def _native_buttons(self) -> None:
        if self.dialog is not None:
            imgui.text_disabled("waiting for the file dialog...")
            return
        if imgui.button("Choose avatar..."):
            self.ask_open("open_avatar", "Open an avatar")
        imgui.same_line()
        if imgui.button("Choose sequence..."):
            self.ask_open("open_sequence", "Open an expression sequence")
        imgui.same_line()
        if imgui.button("Folder..."):
            self.ask_open("open_folder", "Open a MonoNPHM tracking folder")
        if imgui.is_item_hovered():
            imgui.set_tooltip("Choose a MonoNPHM tracking folder")

    def _browser(self, state: ViewerState) -> None:
        folder = Path(self.browse)
        imgui.text_disabled(shown(str(folder))[-60:])
        if imgui.begin_list_box("##browser", imgui.ImVec2(-1, 140)):
            if imgui.selectable("..", False)[0]:
                self.browse = str(folder.parent)
            try:
                entries = sorted(folder.iterdir(), key=lambda p: (not p.is_dir(), p.name.lower()))
            except OSError:
                entries = []
            for p in entries[:500]:
                if p.name.startswith("."):
                    continue
                if p.is_dir():
                    kind = "avatar" if is_avatar_folder(p) else "seq" if (p / "00000" / "z_exp.npy").is_file() else ""
                    if imgui.selectable(f"[{kind or 'dir'}] {shown(p.name)}", False)[0]:
                        if kind:
                            state.actions.append(open_action(str(p)))
                        else:
                            self.browse = str(p)
                elif p.suffix in AVATAR_EXT + SEQUENCE_EXT and imgui.selectable(shown(p.name), False)[0]:
                    state.actions.append(open_action(str(p)))
            imgui.end_list_box()

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not imgui.collapsing_header("Files", imgui.TreeNodeFlags_.default_open):
            return
        a = info.avatar
        imgui.text_wrapped(f"Avatar: {shown(Path(state.avatar_path).name) if state.avatar_path else '-'}"
                           + (f" ({len(a):,} Gaussians)" if a is not None else ""))
        imgui.text_wrapped(f"Sequence: {shown(Path(state.sequence_path).name) if state.sequence_path else '-'}")
        imgui.set_next_item_width(-1)
        _, self.path = imgui.input_text("##path", self.path)
        remember(info, "path_input")
        if imgui.button("Open avatar"):
            state.actions.append(A.OpenAvatar(self.path.strip()))
        remember(info, "open_avatar")
        imgui.same_line()
        if imgui.button("Open sequence"):
            state.actions.append(A.OpenSequence(self.path.strip()))
        remember(info, "open_sequence")
        imgui.same_line()
        if imgui.button("Load basis"):
            state.actions.append(A.LoadBasis(self.path.strip()))
        remember(info, "load_basis")
        if imgui.is_item_hovered():
            imgui.set_tooltip("a blendshape basis .npz (npga-view fit-blendshapes) for the open avatar: ARKit takes "
                              "and the Live Link stream then drive it")
        imgui.same_line()
        if imgui.button("Demo"):
            state.actions.append(A.OpenAvatar("demo"))
        imgui.same_line()  # (on the row of the buttons above: the panels below keep their place)
        if imgui.button("FLAME"):
            state.actions.append(A.SetFlameModel(self.path.strip()))
        if imgui.is_item_hovered():
            now = shown(state.flame_model) if state.flame_model else "none"
            imgui.set_tooltip("set the path above as your FLAME model (flame2023.pkl, FLAME 2020's "
                              "generic_model.pkl): GaussianAvatars output folders then open (imported once into the "
                              f"cache; read without running code). Now: {now}")
        if self._native():
            self.poll_dialog(state)
            self._native_buttons()
        elif imgui.tree_node("Browse"):
            self._browser(state)
            imgui.tree_pop()
        if state.recent and imgui.tree_node("Recent"):
            for p in state.recent:
                if imgui.selectable(shown(p if len(p) < 50 else "..." + p[-47:]), False)[0]:
                    state.actions.append(open_action(p))
            imgui.tree_pop()
        imgui.text_disabled("Tip: drop files on the window.")
