"""The undoable edits of an `EditSession` (npga_core/editing/edits.py) and their `History`.

Each `Command` stores exactly what restores the previous state bit for bit: row edits the affected indices and
the old values, deletions the removed indices and rows (`GaussianCloud.subset` keeps every array of
`PER_GAUSSIAN_FIELDS` consistent). Commands act on a `Session` (the members of `EditSession` they use).
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from npga_core.inspection.graph import knn
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PER_GAUSSIAN_FIELDS, SH_C0, GaussianCloud, logit, sigmoid

DEFAULT_K = 8


class Session(Protocol):
    """What commands use of an `EditSession`."""

    avatar: Avatar
    selection: np.ndarray
    hidden: np.ndarray

    def __len__(self) -> int: ...

    def require_selection(self) -> np.ndarray: ...

    def writable(self, name: str) -> np.ndarray: ...

    def set_cloud(self, cloud: GaussianCloud) -> None: ...

    def floater_mask(self, k: int = DEFAULT_K, distance_factor: float = 3.0,
                     min_opacity: float = 0.02) -> np.ndarray: ...


class SourceOverwriteError(FileExistsError):
    """Saving would replace the file the avatar was loaded from; ask the user, then save with
    ``overwrite_source=True``. (A FileExistsError, so code that reports OSErrors shows it too.)"""

    def __init__(self, path: str | Path):
        super().__init__(f"{path}: this is the file the avatar was opened from; overwrite it?")
        self.path = str(path)


class NothingSelectedError(ValueError):
    """An operation on the selection was asked for with nothing selected."""


# --------------------------------------------------------------------------------------------------
# commands


class Command(ABC):
    """One undoable step. `do` may be called again after `undo` (redo) and must give the same result."""

    name: str = "edit"
    changes_cloud: bool = True
    serial: int = 0  # set by History.push; identifies the state after this command

    @abstractmethod
    def do(self, s: Session) -> None: ...

    @abstractmethod
    def undo(self, s: Session) -> None: ...

    def kept_rows(self) -> np.ndarray | None:
        """After `do`: a mask over the cloud before it of the rows the cloud after it consists of, unchanged, in
        order (a deletion); None where rows are added or any attribute changes."""
        return None


class SetSelection(Command):
    """Replace the selection mask (the selection tools build the new mask)."""

    changes_cloud = False

    def __init__(self, mask: np.ndarray, name: str = "Select"):
        self.mask = np.asarray(mask, dtype=bool).copy()
        self.name = f"{name} ({int(self.mask.sum()):,})"
        self._prev: np.ndarray | None = None

    def do(self, s: Session) -> None:
        if self.mask.shape != s.selection.shape:
            raise ValueError(f"selection mask has {self.mask.shape[0]} rows, the avatar has {len(s)} Gaussians")
        self._prev = s.selection
        s.selection = self.mask.copy()

    def undo(self, s: Session) -> None:
        s.selection = cast(np.ndarray, self._prev)


class Hide(Command):
    """Hide the selected Gaussians (they stay in the avatar and in saved files) and deselect them."""

    changes_cloud = False

    def __init__(self) -> None:
        self.name = "Hide"
        self._prev: tuple[np.ndarray, np.ndarray] | None = None

    def do(self, s: Session) -> None:
        s.require_selection()
        self.name = f"Hide {int(s.selection.sum()):,}"
        self._prev = (s.hidden, s.selection)
        s.hidden = s.hidden | s.selection
        s.selection = np.zeros(len(s), bool)

    def undo(self, s: Session) -> None:
        s.hidden, s.selection = cast(tuple[np.ndarray, np.ndarray], self._prev)


class ShowAll(Command):
    """Unhide every Gaussian."""

    changes_cloud = False
    name = "Show all"

    def __init__(self) -> None:
        self._prev: np.ndarray | None = None

    def do(self, s: Session) -> None:
        self._prev = s.hidden
        s.hidden = np.zeros(len(s), bool)

    def undo(self, s: Session) -> None:
        s.hidden = cast(np.ndarray, self._prev)


class RowEdit(Command):
    """Change `field[rows, *columns]` of the selected rows; subclasses give the new values from the old."""

    field: str = ""
    columns: tuple = ()

    def __init__(self) -> None:
        self.index: np.ndarray | None = None  # rows, fixed at the first do so redo edits the same ones
        self._old: np.ndarray | None = None

    @abstractmethod
    def compute(self, old: np.ndarray) -> np.ndarray: ...

    def do(self, s: Session) -> None:
        if self.index is None:
            self.index = np.flatnonzero(s.require_selection())
        arr = s.writable(self.field)
        key = (self.index, *self.columns)
        self._old = arr[key].copy()
        arr[key] = self.compute(self._old)

    def undo(self, s: Session) -> None:
        s.writable(self.field)[(self.index, *self.columns)] = self._old
        self._old = None


class ScaleOpacity(RowEdit):
    """Multiply the activated opacity by `factor` (clamped to [0, 1]; stored back as logits)."""

    field = "opacity_logits"

    def __init__(self, factor: float):
        super().__init__()
        if not np.isfinite(factor) or factor < 0:
            raise ValueError(f"opacity factor must be a finite number >= 0, got {factor}")
        self.factor = float(factor)
        self.name = f"Scale opacity x{self.factor:g}"

    def compute(self, old: np.ndarray) -> np.ndarray:
        return logit(np.clip(sigmoid(old).astype(np.float64) * self.factor, 0.0, 1.0))


TINT_MODES = ("multiply", "blend")


class Tint(RowEdit):
    """Tint the base (SH DC) colour in RGB: multiply by `rgb`, or blend towards it; `amount` 0..1 fades the
    effect (multiply by (1 - a) + a * rgb, blend to (1 - a) * colour + a * rgb). View-dependent terms stay."""

    field = "sh"
    columns = (0,)

    def __init__(self, rgb: tuple[float, float, float], mode: str = "multiply", amount: float = 1.0):
        super().__init__()
        self.rgb = np.asarray(rgb, dtype=np.float64).reshape(3)
        if mode not in TINT_MODES:
            raise ValueError(f"unknown tint mode {mode!r}; choose from {', '.join(TINT_MODES)}")
        if not (np.all(np.isfinite(self.rgb)) and np.isfinite(amount)):
            raise ValueError("tint colour and amount must be finite")
        self.mode, self.amount = mode, float(amount)
        self.name = f"Tint {mode} ({', '.join(f'{v:.2f}' for v in self.rgb)})"

    def compute(self, old: np.ndarray) -> np.ndarray:
        colour = old.astype(np.float64) * SH_C0 + 0.5
        a = self.amount
        multiply = self.mode == "multiply"
        colour = colour * ((1.0 - a) + a * self.rgb) if multiply else (1.0 - a) * colour + a * self.rgb
        return ((colour - 0.5) / SH_C0).astype(np.float32)


class _FeatureEdit(RowEdit):
    field = "features"

    def __init__(self, channel: int):
        super().__init__()
        self.channel = int(channel)
        self.columns = (self.channel,)

    def do(self, s: Session) -> None:
        if not 0 <= self.channel < s.avatar.cloud.feature_dim:
            raise ValueError(f"feature channel {self.channel} does not exist (the avatar has "
                             f"{s.avatar.cloud.feature_dim})")
        super().do(s)


class SetFeature(_FeatureEdit):
    """Set feature channel `channel` of the selected Gaussians to `value`."""

    def __init__(self, channel: int, value: float):
        super().__init__(channel)
        if not np.isfinite(value):
            raise ValueError(f"feature value must be finite, got {value}")
        self.value = float(value)
        self.name = f"Set feature {self.channel} = {self.value:g}"

    def compute(self, old: np.ndarray) -> np.ndarray:
        return np.full_like(old, self.value)


class ScaleFeature(_FeatureEdit):
    """Multiply feature channel `channel` of the selected Gaussians by `factor`."""

    def __init__(self, channel: int, factor: float):
        super().__init__(channel)
        if not np.isfinite(factor):
            raise ValueError(f"feature factor must be finite, got {factor}")
        self.factor = float(factor)
        self.name = f"Scale feature {self.channel} x{self.factor:g}"

    def compute(self, old: np.ndarray) -> np.ndarray:
        return (old.astype(np.float64) * self.factor).astype(old.dtype)


class DeleteRows(Command):
    """Delete Gaussians (rows of every per-Gaussian array); subclasses choose which by `pick`."""

    def __init__(self) -> None:
        self.index: np.ndarray | None = None  # removed rows of the cloud before the deletion, sorted
        self._kept: np.ndarray | None = None  # mask of the rows kept, over the cloud before the deletion
        self._rows: dict[str, np.ndarray] | None = None
        self._masks: tuple[np.ndarray, np.ndarray] | None = None  # selection, hidden before

    @abstractmethod
    def pick(self, s: Session) -> np.ndarray: ...

    def do(self, s: Session) -> None:
        cloud = s.avatar.cloud
        if self.index is None:
            self.index = np.flatnonzero(self.pick(s))
            self.name = self.label(len(self.index))
        if len(self.index) == 0:
            raise NothingSelectedError("there is nothing to delete")
        keep = np.ones(len(cloud), bool)
        keep[self.index] = False
        self._kept = keep
        self._rows = {k: np.array(v[self.index]) for k, v in cloud.arrays().items()}
        self._masks = (s.selection, s.hidden)
        s.set_cloud(cloud.subset(keep))
        s.selection = np.zeros(len(s), bool)
        s.hidden = self._masks[1][keep]

    def undo(self, s: Session) -> None:
        index, rows, masks, keep = self.index, self._rows, self._masks, self._kept
        assert index is not None and rows is not None and masks is not None and keep is not None  # undo follows do
        cur = s.avatar.cloud
        n = len(keep)
        restored: dict[str, Any] = {}
        for name in PER_GAUSSIAN_FIELDS:
            a = getattr(cur, name)
            if a is None:
                continue
            out = np.empty((n, *a.shape[1:]), dtype=a.dtype)
            out[keep] = a
            out[index] = rows[name]
            restored[name] = out
        s.set_cloud(replace(cur, **restored))
        s.selection, s.hidden = masks
        self._rows = self._masks = None

    def kept_rows(self) -> np.ndarray | None:
        return self._kept

    def label(self, count: int) -> str:
        return f"Delete {count:,}"


class DeleteSelected(DeleteRows):
    """Delete the selected Gaussians."""

    def pick(self, s: Session) -> np.ndarray:
        return s.require_selection()


class RemoveFloaters(DeleteRows):
    """Delete the Gaussians `floater_mask` flags (within the selection if `within_selection`)."""

    def __init__(self, k: int = DEFAULT_K, distance_factor: float = 3.0, min_opacity: float = 0.02,
                 within_selection: bool = False):
        super().__init__()
        self.params: dict[str, Any] = {"k": int(k), "distance_factor": float(distance_factor),
                                       "min_opacity": float(min_opacity)}
        self.within_selection = within_selection

    def pick(self, s: Session) -> np.ndarray:
        mask = s.floater_mask(**self.params)
        return mask & s.require_selection() if self.within_selection else mask

    def label(self, count: int) -> str:
        return f"Remove {count:,} floaters"


def floater_mask(cloud: GaussianCloud, k: int = DEFAULT_K, distance_factor: float = 3.0, min_opacity: float = 0.02,
                 nbrs: np.ndarray | None = None) -> np.ndarray:
    """Gaussians that look like floaters: the mean distance to their k nearest neighbours is more than
    `distance_factor` x its median over the cloud, or the opacity is below `min_opacity`."""
    n = len(cloud)
    mask = sigmoid(cloud.opacity_logits) < min_opacity
    if n < 3:
        return mask
    if nbrs is None:
        nbrs = knn(cloud.means, min(int(k), n - 1))
    means = np.asarray(cloud.means, dtype=np.float64)
    dist = np.linalg.norm(means[nbrs] - means[:, None, :], axis=2).mean(axis=1)
    return mask | (dist > distance_factor * float(np.median(dist)))


# --------------------------------------------------------------------------------------------------
# history


class History:
    """Undo and redo stacks of commands, at most `limit` undo steps."""

    _serials = itertools.count(1)

    def __init__(self, limit: int = 200):
        self.limit = limit
        self.undo_stack: list[Command] = []
        self.redo_stack: list[Command] = []
        self.base_serial = 0  # the cloud state below the oldest kept command

    def push(self, cmd: Command, s: Session) -> None:
        cmd.do(s)  # an error here leaves the stacks as they were
        cmd.serial = next(self._serials)
        self.undo_stack.append(cmd)
        self.redo_stack.clear()
        while len(self.undo_stack) > self.limit:
            dropped = self.undo_stack.pop(0)
            if dropped.changes_cloud:
                self.base_serial = dropped.serial

    def undo(self, s: Session) -> Command | None:
        if not self.undo_stack:
            return None
        cmd = self.undo_stack.pop()
        cmd.undo(s)
        self.redo_stack.append(cmd)
        return cmd

    def redo(self, s: Session) -> Command | None:
        if not self.redo_stack:
            return None
        cmd = self.redo_stack.pop()
        cmd.do(s)
        self.undo_stack.append(cmd)
        return cmd

    def cloud_serial(self) -> int:
        """Identifies the current cloud content: the serial of the newest applied cloud edit."""
        return next((c.serial for c in reversed(self.undo_stack) if c.changes_cloud), self.base_serial)

    def names(self) -> tuple[list[str], list[str]]:
        """(undo names oldest first, redo names next-to-redo first)."""
        return [c.name for c in self.undo_stack], [c.name for c in reversed(self.redo_stack)]


# --------------------------------------------------------------------------------------------------
# the session


