"""MonoNPHM tracking folders as expression sequences.

Layout (MonoNPHM's `Tracker.rec_and_save`): ``ROOT/{t:05d}/z_exp.npy`` per frame (numeric folder names,
sorted by number). Stage 1 stores the frame's own code, shape (1, D) or (D,); stage 2 stores the whole table
(T, D) in every frame folder, and frame t takes row t. ``rot.npy`` (1, 3, 3), ``trans.npy`` (1, 3) and
``scale.npy`` (1,) beside it are the tracker's head pose, which maps *world to NPHM space*
(x_nphm = s R x_world + t); the sequence carries its inverse, canonical (NPHM) -> world
(`npga_core.files.pose.mononphm_pose`). Whole (T, ...) tables in every folder are read row by row too.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.pose import MONONPHM, mononphm_pose
from npga_core.files.sequences import DEFAULT_FPS, MAX_SEQUENCE_BYTES, ExpressionSequence
from npga_core.files.untrusted import read_npy, real_floats

#: A frame folder's name: ASCII digits only (str.isdigit also takes other scripts' digits and superscripts).
_FRAME_NAME = re.compile(r"[0-9]{1,12}")


def _frame_dirs(root: Path) -> list[tuple[int, Path]]:
    frames = []
    for p in root.iterdir():
        if _FRAME_NAME.fullmatch(p.name) and p.is_dir() and (p / "z_exp.npy").is_file():
            frames.append((int(p.name), p))
    return sorted(frames)


#: Most bytes read from all the frame files of one folder together (stage 2 repeats the whole table per frame).
MAX_FOLDER_READ_BYTES = 4 * 2**30


def _load(path: Path) -> np.ndarray:
    """One tracked array: size checked from the .npy header, real finite numbers as float64."""
    return real_floats(read_npy(path, MAX_SEQUENCE_BYTES, path.stem), path, path.stem, np.float64)


def _row(path: Path, t_index: int, n_frames: int, tail: tuple[int, ...], budget: list[int] | None = None
         ) -> np.ndarray:
    """Frame t's entry of shape `tail` ((W,) for a row, (3, 3) for a matrix) from a per-frame array (one entry,
    with or without a leading 1) or a whole (T, *tail) table; `tail` () takes the row's width as it comes.
    Only the entry is converted to float64 and kept (a view would pin the whole table); `budget` ([bytes
    left]) bounds what all frames of a folder read together."""
    a = read_npy(path, MAX_SEQUENCE_BYTES if budget is None else min(MAX_SEQUENCE_BYTES, budget[0]), path.stem)
    if budget is not None:
        budget[0] -= a.nbytes
    k = len(tail) or 1
    if a.ndim == k + 1 and a.shape[0] == n_frames and n_frames > 1 and (not tail or a.shape[1:] == tail):
        entry = a[t_index]
    elif a.ndim <= k + 1 and (a.ndim <= k or a.shape[0] == 1):
        entry = a.reshape(a.shape[1:] if a.ndim == k + 1 else a.shape)
    else:
        raise AvatarFileError(path, f"shape {a.shape} is neither one frame's entry nor a ({n_frames}, ...) table")
    entry = real_floats(entry, path, path.stem, np.float64).copy()
    del a
    if not tail:
        return entry.reshape(-1)
    if entry.size != math.prod(tail):
        raise AvatarFileError(path, f"entry has shape {entry.shape}, expected {tail}")
    return entry.reshape(tail)


def _pose_part(frames: list[tuple[int, Path]], fname: str) -> np.ndarray | None:
    """One pose file of every frame stacked (T, ...), or None when no frame has it."""
    have = [(p / fname).is_file() for _, p in frames]
    if not any(have):
        return None
    if not all(have):
        missing = frames[have.index(False)][1]
        raise AvatarFileError(missing, f"has no {fname} while other frames have one")
    n = len(frames)
    if fname == "rot.npy":  # (1, 3, 3) matrices as saved, or (1, 3) axis-angle as the tracker's loader takes
        first = _load(frames[0][1] / fname)
        tail = (3, 3) if first.ndim == 3 or first.shape == (3, 3) else (3,)
    else:
        tail = (3,) if fname == "trans.npy" else (1,)
    return np.stack([_row(p / fname, i, n, tail) for i, (_, p) in enumerate(frames)])


def load_mononphm_folder(root: str | Path) -> ExpressionSequence:
    """Read a MonoNPHM tracking folder (stage 1 or 2) into an ExpressionSequence with its head pose."""
    root = Path(root)
    frames = _frame_dirs(root)
    if not frames:
        raise AvatarFileError(root, "no frame folders with z_exp.npy (expected ROOT/00000/z_exp.npy, ...)")
    n = len(frames)
    budget = [MAX_FOLDER_READ_BYTES]
    rows = [_row(p / "z_exp.npy", i, n, (), budget) for i, (_, p) in enumerate(frames)]
    for (_, p), row in zip(frames, rows, strict=True):
        if row.shape != rows[0].shape:
            raise AvatarFileError(p / "z_exp.npy", f"code has {row.size} values, frame {frames[0][1].name} has "
                                  f"{rows[0].size}")
    codes = np.stack(rows).astype(np.float32)
    rot, trans, scale = (_pose_part(frames, f) for f in ("rot.npy", "trans.npy", "scale.npy"))
    pose, source = None, ""
    if rot is not None or trans is not None or scale is not None:
        pose, source = mononphm_pose(rot, trans, scale, n, root), MONONPHM
    names = [p.name for _, p in frames]
    return ExpressionSequence(codes, DEFAULT_FPS, root.name, frame_names=names, pose=pose, pose_source=source)
