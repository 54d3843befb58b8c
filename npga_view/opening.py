"""Opening files in the window: an avatar (the sliders at its neutral face, then the document's `open`, which the
window's parts subscribe to) and an expression sequence (checked against the avatar), each remembered in the
recent list. Errors go to the UI (`state.report`); the `open_*` methods then return False.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError, shown
from npga_core.files.loading import load_avatar, load_sequence_for
from npga_core.model.avatar import Avatar
from npga_view.document import Document
from npga_view.state import MAX_SLIDERS, ViewerState


class Opener:
    """Opens files into `doc`; `remember_recent`: the recent list is saved (not in tests); `set_title` names the
    window after the open avatar."""

    def __init__(self, doc: Document, state: ViewerState, remember_recent: bool = True,
                 set_title: Callable[[str], None] | None = None) -> None:
        self.doc = doc
        self.state = state
        self.remember_recent = remember_recent
        self.set_title = set_title

    def open_avatar(self, path: str) -> bool:
        """Load an avatar (errors go to the UI) and make it the open one. A GaussianAvatars output folder (or its
        point_cloud.ply) opens with the FLAME model the user gave (`state.flame_model`) through its cached `.npga`
        import, which the worker reopens by path; the status line says which happened."""
        try:
            opened, note = avatar_file(self.state, path)
            avatar = load_avatar(opened)
        except AvatarFileError as e:
            self.state.report(str(e))
            return False
        if note:
            self.state.tell(note)
        self.adopt(avatar, opened)
        self.add_recent(path)
        if self.set_title is not None:
            self.set_title(f"npga-view - {shown(Path(path).name)}")  # no raw surrogates for glfw
        return True

    def adopt(self, avatar: Avatar, path: str) -> None:
        """Show `avatar` (loaded from `path`): sliders at its neutral face, the document's `open` (worker, camera,
        first pixels: its subscribers); a sequence that no longer fits closes."""
        st = self.state
        st.avatar_path = path if path == "demo" else str(Path(path).resolve())
        ex = avatar.expression
        k = ex.n_components if ex is not None else 0
        st.sliders = np.zeros(k, np.float32)
        if ex is not None and "neutral" in ex.named:  # open at the avatar's neutral face, not the mean code
            st.sliders = ex.to_sliders(ex.named["neutral"]).astype(np.float32)
        st.n_sliders = min(max(st.n_sliders, 1), max(1, min(k, MAX_SLIDERS)))
        self.doc.open(avatar)
        seq = self.doc.sequence
        if seq is not None and seq.dim != avatar.code_dim:
            st.report(f"{st.sequence_path}: codes have {seq.dim} dims, the avatar expects {avatar.code_dim}; "
                      "sequence closed")
            self.close_sequence()

    def open_sequence(self, path: str) -> bool:
        """Load a sequence; refused (with both dimensions) if it does not fit the avatar."""
        avatar, st = self.doc.avatar, self.state
        try:
            if avatar is None or avatar.code_dim == 0:
                raise AvatarFileError(path, "open an animatable avatar first (this one has no dynamics)")
            seq = load_sequence_for(avatar, path)
            seq.check_dim(avatar.code_dim, path)
        except AvatarFileError as e:
            st.report(str(e))
            return False
        for note in seq.notes:  # unmatched shapes, frames not recorded: once, as one line each
            st.report(note, note=True)
        self.doc.set_sequence(seq)
        st.sequence_path = str(Path(path).resolve())
        st.timeline.time_s = 0.0
        st.follow_sequence = True
        self.add_recent(path)
        return True

    def close_sequence(self) -> None:
        self.doc.set_sequence(None)
        self.state.sequence_path = None

    def add_recent(self, path: str) -> None:
        self.state.add_recent(path)
        if self.remember_recent:
            self.state.save_recent()


def avatar_file(state: ViewerState, path: str) -> tuple[str, str]:
    """The file the window opens for `path` and a line saying what was done to get it ("" for most files)."""
    from npga_core.files.ga_cache import cached_import, is_ga_source

    if path == "demo" or not is_ga_source(path):
        return path, ""
    if not state.flame_model:
        raise AvatarFileError(path, "is a GaussianAvatars avatar, posed by FLAME: give your FLAME model (npga-view "
                              "view FOLDER --flame-model FLAME_PKL, or the Files panel's FLAME button)")
    out, note = cached_import(path, state.flame_model)
    return str(out), note
