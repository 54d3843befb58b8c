"""Files: open an avatar or a sequence by path, from a folder listing, or from the recent list."""

from __future__ import annotations

import os
from pathlib import Path

from imgui_bundle import imgui

from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

AVATAR_EXT = (".npga", ".ply")
SEQUENCE_EXT = (".npzseq", ".npz", ".npy")
_ui = {"path": "", "browse": os.getcwd()}


def _browser(state: ViewerState) -> None:
    folder = Path(_ui["browse"])
    imgui.text_disabled(str(folder)[-60:])
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
                if imgui.selectable(f"[{'seq' if is_track else 'dir'}] {p.name}", False)[0]:
                    if is_track:
                        state.actions.append(("open_sequence", str(p)))
                    else:
                        _ui["browse"] = str(p)
            elif p.suffix in AVATAR_EXT + SEQUENCE_EXT and imgui.selectable(p.name, False)[0]:
                kind = "open_avatar" if p.suffix in AVATAR_EXT else "open_sequence"
                state.actions.append((kind, str(p)))
        imgui.end_list_box()


def draw(state: ViewerState, info: AppInfo) -> None:
    if not imgui.collapsing_header("Files", imgui.TreeNodeFlags_.default_open):
        return
    a = info.avatar
    imgui.text_wrapped(f"Avatar: {Path(state.avatar_path).name if state.avatar_path else '-'}"
                       + (f" ({len(a):,} Gaussians)" if a is not None else ""))
    imgui.text_wrapped(f"Sequence: {Path(state.sequence_path).name if state.sequence_path else '-'}")
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
    if imgui.tree_node("Browse"):
        _browser(state)
        imgui.tree_pop()
    if state.recent and imgui.tree_node("Recent"):
        for p in state.recent:
            if imgui.selectable(p if len(p) < 50 else "..." + p[-47:], False)[0]:
                ext = Path(p).suffix
                kind = "open_sequence" if ext in SEQUENCE_EXT or Path(p).is_dir() else "open_avatar"
                state.actions.append((kind, p))
        imgui.tree_pop()
    imgui.text_disabled("Tip: drop files on the window.")
