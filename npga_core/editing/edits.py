"""Editing an avatar's canonical Gaussians with undo/redo, saving, and crash recovery through autosaves.

`EditSession` wraps an `Avatar` and owns three things besides it: the `selection` and `hidden` masks (N,) and a
`History` of named `Command`s. Every change goes through `EditSession.run(command)`, so Ctrl+Z / Ctrl+Shift+Z
(`undo` / `redo`) can take it back. Decisions worth knowing:

- Selections are commands too (`SetSelection`), so undo restores a selection as it was; they do not make the
  session dirty and do not touch the cloud.
- Two counters tell the viewer what to refresh: `version` changes when the cloud changed (re-pose; the
  avatar's caches have been invalidated), `mask_version` when the selection, hidden or preview masks changed
  (re-highlight only). Every command bumps `mask_version`; only cloud edits bump `version`.
- Hiding is a view aid: hidden Gaussians are still saved (use delete to drop them) and cannot be selected.
- Arrays the session has not edited stay those of the loaded avatar (possibly read-only memory maps); the first
  edit of a field replaces it with a writable copy, which later edits change in place. The avatar's original
  arrays are never written to.
- Commands store exactly what restores the previous state bit for bit: row edits the affected indices and the
  old values, deletions the removed indices and rows (`GaussianCloud.subset` keeps every array of
  `PER_GAUSSIAN_FIELDS` consistent; dynamics, CNN and expression space are per model and never change).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.editing.commands import (  # noqa: F401  (the commands are public here too)
    DEFAULT_K,
    Command,
    DeleteRows,
    DeleteSelected,
    Hide,
    History,
    NothingSelectedError,
    RemoveFloaters,
    RowEdit,
    ScaleFeature,
    ScaleOpacity,
    SetFeature,
    SetSelection,
    ShowAll,
    SourceOverwriteError,
    Tint,
    floater_mask,
)
from npga_core.editing.selection import (
    attribute_values,
    combine,
    grow,
    in_box,
    in_brush,
    in_lasso,
    in_range,
    in_rect,
    in_sphere,
    shrink,
)
from npga_core.files.places import user_cache_dir
from npga_core.inspection.graph import knn
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PER_GAUSSIAN_FIELDS, GaussianCloud


def autosave_dir() -> Path:
    """The `autosave` folder in the platform's user cache folder (Linux: `$XDG_CACHE_HOME/npga-view/autosave`,
    default `~/.cache/...`; see `npga_core.files.places`)."""
    return user_cache_dir("autosave")


def autosave_path_for(source: str | Path | None) -> Path:
    """The autosave file of edits to `source` (one per source file; None: an avatar without a file)."""
    if source is None:
        key, stem = "untitled", "untitled"
    else:
        key, stem = str(Path(source).resolve()), Path(source).stem
    # a name of any encoding (undecodable bytes, lone surrogates, newlines): hashed as it is, shown as "_"
    stem = "".join(c if c.isprintable() and not 0xD800 <= ord(c) <= 0xDFFF else "_" for c in stem)
    return autosave_dir() / f"{stem}-{hashlib.sha1(key.encode('utf-8', 'surrogatepass')).hexdigest()[:12]}.npga"


def find_autosave(source: str | Path | None) -> Path | None:
    """The autosave of unsaved edits to `source`, if one exists and is newer than the source file."""
    path = autosave_path_for(source)
    if not path.is_file():
        return None
    with contextlib.suppress(OSError):
        if source is not None and Path(source).stat().st_mtime > path.stat().st_mtime:
            return None
    return path


def same_file(a: str | Path, b: str | Path | None) -> bool:
    """Whether two paths name the same file (also when `a` does not exist yet)."""
    if b is None:
        return False
    with contextlib.suppress(OSError):
        return os.path.samefile(a, b)
    return Path(a).resolve() == Path(b).resolve()


class EditSession:
    """An avatar being edited: selection, hidden mask, history, dirty flag, saving and autosave."""

    def __init__(self, avatar: Avatar, source: str | Path | None = None, history_limit: int = 200):
        self.avatar = avatar
        self.source = str(source) if source is not None else avatar.source
        self.save_path: str | None = None  # where "Save" writes after a "Save as"
        self.history = History(history_limit)
        self.selection = np.zeros(len(avatar), bool)
        self.hidden = np.zeros(len(avatar), bool)
        self.preview: np.ndarray | None = None  # e.g. the floaters that would go
        self.version = 0
        self.mask_version = 0
        # (version before, mask): the last cloud change kept these rows of the cloud at that version, unchanged
        self.kept_rows: tuple[int, np.ndarray] | None = None
        self._saved_serial = 0
        self._owned: set[str] = set()
        self._nbrs: tuple[np.ndarray, int, np.ndarray] | None = None  # (means it was built on, k, graph)

    def __len__(self) -> int:
        return len(self.avatar)

    # -- state ------------------------------------------------------------------------------------
    @property
    def dirty(self) -> bool:
        """True when the cloud differs from the last save (or the source, before any save)."""
        return self.history.cloud_serial() != self._saved_serial

    @property
    def can_undo(self) -> bool:
        return bool(self.history.undo_stack)

    @property
    def can_redo(self) -> bool:
        return bool(self.history.redo_stack)

    def require_selection(self) -> np.ndarray:
        """The selection mask, or NothingSelectedError when it is empty."""
        if not self.selection.any():
            raise NothingSelectedError("nothing is selected")
        return self.selection

    def writable(self, name: str) -> np.ndarray:
        """The cloud's array `name`, replaced by a writable copy the first time the session edits it."""
        if name not in self._owned:
            setattr(self.avatar.cloud, name, np.array(getattr(self.avatar.cloud, name), copy=True))
            self._owned.add(name)
        return getattr(self.avatar.cloud, name)

    def set_cloud(self, cloud: GaussianCloud) -> None:
        """Install a new cloud whose arrays the session owns (made by deletion or its undo)."""
        self.avatar.cloud = cloud
        self._owned = {k for k in PER_GAUSSIAN_FIELDS if getattr(cloud, k) is not None}

    def neighbours(self, k: int = DEFAULT_K) -> np.ndarray:
        """kNN graph (N, k) of the canonical centres, cached until the centres change."""
        means = self.avatar.cloud.means
        if self._nbrs is None or self._nbrs[0] is not means or self._nbrs[1] != k:
            k_eff = min(k, len(means) - 1)
            graph = knn(means, k_eff) if k_eff >= 1 else np.zeros((len(means), 0), np.int32)
            self._nbrs = (means, k, graph)
        return self._nbrs[2]

    # -- running commands -------------------------------------------------------------------------
    def run(self, cmd: Command) -> Command:
        """Do `cmd` and put it on the undo stack."""
        self.history.push(cmd, self)
        self._changed(cmd, cmd.kept_rows())
        return cmd

    def undo(self) -> Command | None:
        """Take back the newest command; returns it (None if there was nothing to undo)."""
        cmd = self.history.undo(self)
        if cmd is not None:
            self._changed(cmd)
        return cmd

    def redo(self) -> Command | None:
        """Do the newest undone command again."""
        cmd = self.history.redo(self)
        if cmd is not None:
            self._changed(cmd, cmd.kept_rows())
        return cmd

    def _changed(self, cmd: Command, kept: np.ndarray | None = None) -> None:
        self.preview = None
        self.mask_version += 1
        if cmd.changes_cloud:
            self.avatar.invalidate_caches()
            self.kept_rows = None if kept is None else (self.version, kept)
            self.version += 1

    # -- selection ----------------------------------------------------------------------------------
    def select(self, mask: np.ndarray, mode: str = "replace", name: str = "Select") -> bool:
        """Merge `mask` (hidden Gaussians left out) into the selection as an undoable step; False if nothing
        changed (then no step is recorded)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != self.selection.shape:
            raise ValueError(f"selection mask has shape {mask.shape}, the avatar has {len(self)} Gaussians")
        new = combine(self.selection, mask & ~self.hidden, mode)
        if np.array_equal(new, self.selection):
            return False
        self.run(SetSelection(new, name))
        return True

    def _pts(self, means: np.ndarray | None) -> np.ndarray:
        return self.avatar.cloud.means if means is None else means

    def select_rect(self, camera: Camera, x0: float, y0: float, x1: float, y1: float, mode: str = "replace",
                    means: np.ndarray | None = None) -> bool:
        """Rectangle in pixels. `means`: the positions on screen (posed); default the canonical ones."""
        return self.select(in_rect(camera, self._pts(means), x0, y0, x1, y1), mode, "Rectangle")

    def select_lasso(self, camera: Camera, polygon_px: np.ndarray, mode: str = "replace",
                     means: np.ndarray | None = None) -> bool:
        return self.select(in_lasso(camera, self._pts(means), polygon_px), mode, "Lasso")

    def select_brush(self, camera: Camera, centres_px: np.ndarray, radius_px: float, mode: str = "add",
                     means: np.ndarray | None = None) -> bool:
        """A brush stroke: the union of discs at `centres_px` (M, 2), recorded as one step."""
        pts = self._pts(means)
        hit = np.zeros(len(self), bool)
        for c in np.asarray(centres_px, dtype=np.float64).reshape(-1, 2):
            hit |= in_brush(camera, pts, c, radius_px)
        return self.select(hit, mode, "Brush")

    def select_sphere(self, centre: np.ndarray, radius: float, mode: str = "replace",
                      means: np.ndarray | None = None) -> bool:
        return self.select(in_sphere(self._pts(means), centre, radius), mode, "Sphere")

    def select_box(self, lo: np.ndarray, hi: np.ndarray, transform: np.ndarray | None = None, mode: str = "replace",
                   means: np.ndarray | None = None) -> bool:
        return self.select(in_box(self._pts(means), lo, hi, transform), mode, "Box")

    def select_range(self, attribute: str, lo: float, hi: float, mode: str = "replace") -> bool:
        """By a canonical attribute's value (see `selection.attribute_values`)."""
        return self.select(in_range(attribute_values(self.avatar.cloud, attribute), lo, hi), mode, attribute)

    def grow(self, steps: int = 1, k: int = DEFAULT_K) -> bool:
        return self.select(grow(self.selection, self.neighbours(k), steps), "replace", "Grow")

    def shrink(self, steps: int = 1, k: int = DEFAULT_K) -> bool:
        return self.select(shrink(self.selection, self.neighbours(k), steps), "replace", "Shrink")

    def invert(self) -> bool:
        return self.select(~self.selection, "replace", "Invert")

    def select_all(self) -> bool:
        return self.select(np.ones(len(self), bool), "replace", "Select all")

    def clear_selection(self) -> bool:
        return self.select(np.zeros(len(self), bool), "replace", "Clear selection")

    # -- operations ---------------------------------------------------------------------------------
    def floater_mask(self, k: int = DEFAULT_K, distance_factor: float = 3.0, min_opacity: float = 0.02) -> np.ndarray:
        return floater_mask(self.avatar.cloud, k, distance_factor, min_opacity, self.neighbours(k))

    def preview_floaters(self, k: int = DEFAULT_K, distance_factor: float = 3.0, min_opacity: float = 0.02) -> int:
        """Put the floaters that `RemoveFloaters` would delete into `preview`; returns their count."""
        self.preview = self.floater_mask(k, distance_factor, min_opacity)
        self.mask_version += 1
        return int(self.preview.sum())

    def clear_preview(self) -> None:
        self.preview = None
        self.mask_version += 1

    # -- files ------------------------------------------------------------------------------------------
    def save(self, path: str | Path | None = None, overwrite_source: bool = False) -> Path:
        """Write the edited avatar as `.npga` (atomically). No path: the last "Save as" target, else the source.

        Raises SourceOverwriteError when the target is the file the avatar was opened from, unless
        `overwrite_source`; ValueError when there is nowhere to save.
        """
        from npga_core.files.checkpoint import save_avatar

        target = path if path is not None else (self.save_path or self.source)
        if target is None:
            raise ValueError("this avatar has no file yet: use Save as")
        target = Path(target)
        if same_file(target, self.source) and not overwrite_source:
            raise SourceOverwriteError(target)
        edits = [c.name for c in self.history.undo_stack if c.changes_cloud]
        save_avatar(self.avatar, target, provenance={"edited_from": self.source, "edits": edits})
        self.save_path = str(target)
        self._saved_serial = self.history.cloud_serial()
        self.discard_autosave()
        return target

    def autosave_path(self) -> Path:
        return autosave_path_for(self.source)

    def autosave(self) -> Path | None:
        """Write unsaved edits to `autosave_path()` (atomically); None when there is nothing unsaved."""
        from npga_core.files.checkpoint import save_avatar

        if not self.dirty:
            return None
        path = self.autosave_path()
        save_avatar(self.avatar, path, provenance={"autosave_of": self.source})
        return path

    def discard_autosave(self) -> None:
        with contextlib.suppress(OSError):
            self.autosave_path().unlink()

    @classmethod
    def recover(cls, source: str | Path) -> EditSession:
        """A session on the autosaved edits of `source` (dirty: the edits are not in `source` yet).

        Raises FileNotFoundError when there is no autosave and AvatarFileError when it does not load.
        """
        from npga_core.files.loading import load_avatar

        path = find_autosave(source)
        if path is None:
            raise FileNotFoundError(f"{source}: no autosaved edits")
        session = cls(load_avatar(path), source=source)
        session._saved_serial = -1
        return session

    def export_posed_ply(self, path: str | Path, code: np.ndarray | None = None, include_hidden: bool = False) -> int:
        """Write the avatar posed at `code` (None: the mean) as a standard 3DGS `.ply`; returns the count."""
        from npga_core.files.ply import save_posed_ply

        posed = self.avatar.pose(code)
        if not include_hidden and self.hidden.any():
            posed = posed.subset(~self.hidden)
        save_posed_ply(posed, path)
        return len(posed)
