"""MonoNPHM tracking folders as expression sequences.

Layout: ``ROOT/{t:05d}/z_exp.npy`` per frame (numeric folder names, sorted by number). Stage 1 stores the
frame's own code, shape (1, D) or (D,); stage 2 stores the whole table (T, D) in every frame folder, and
frame t takes row t. ``rot.npy``, ``trans.npy`` and ``scale.npy`` beside it are read as head pose when present
(per-frame rows, or the whole table in the stage-2 layout).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.sequences import DEFAULT_FPS, MAX_SEQUENCE_BYTES, ExpressionSequence
from npga_core.files.untrusted import read_npy, real_floats


def _frame_dirs(root: Path) -> list[tuple[int, Path]]:
    frames = []
    for p in root.iterdir():
        if p.is_dir() and p.name.isdigit() and (p / "z_exp.npy").is_file():
            frames.append((int(p.name), p))
    return sorted(frames)


def _load(path: Path) -> np.ndarray:
    """One tracked array: size checked from the .npy header, real finite numbers as float32."""
    return real_floats(read_npy(path, MAX_SEQUENCE_BYTES, path.stem), path, path.stem)


def _row(path: Path, t_index: int, n_frames: int, width: int | None) -> np.ndarray:
    """Frame t's row from a per-frame (1, W)/(W,) array or a whole (T, W) table."""
    a = _load(path)
    if a.shape[-2:] == (3, 3) and (a.ndim == 2 or (a.ndim == 3 and a.shape[0] in (1, n_frames))):
        m = a if a.ndim == 2 else a[0] if a.shape[0] == 1 else a[t_index]
        return m.reshape(-1)  # a rotation matrix: 9 values, turned into axis-angle by the caller
    if a.ndim == 2 and a.shape[0] == n_frames and n_frames > 1:
        row = a[t_index]
    elif a.ndim <= 2 and (a.ndim < 2 or a.shape[0] == 1):
        row = a.reshape(-1)
    else:
        raise AvatarFileError(path, f"shape {a.shape} is neither one frame's row nor a ({n_frames}, W) table")
    if width is not None and row.shape[0] != width:
        raise AvatarFileError(path, f"row has {row.shape[0]} values, expected {width}")
    return row


def load_mononphm_folder(root: str | Path):
    """Read a MonoNPHM tracking folder (stage 1 or 2) into an ExpressionSequence."""

    root = Path(root)
    frames = _frame_dirs(root)
    if not frames:
        raise AvatarFileError(root, "no frame folders with z_exp.npy (expected ROOT/00000/z_exp.npy, ...)")
    n = len(frames)
    codes = np.stack([_row(p / "z_exp.npy", i, n, None) for i, (_, p) in enumerate(frames)])
    pose: dict[str, np.ndarray] = {}
    for key, fname, width in (("rotation", "rot.npy", 3), ("translation", "trans.npy", 3), ("scale", "scale.npy", 1)):
        if all((p / fname).is_file() for _, p in frames):
            rows = np.stack([_row(p / fname, i, n, None) for i, (_, p) in enumerate(frames)])
            if key == "rotation" and rows.shape[1] == 9:  # rotation matrices -> axis-angle
                rows = _matrix_to_axis_angle(rows.reshape(-1, 3, 3))
            if rows.shape[1] != width:
                raise AvatarFileError(root / frames[0][1].name / fname,
                                      f"{key} rows have {rows.shape[1]} values, expected {width}")
            pose[key] = rows[:, 0] if key == "scale" else rows
    names = [p.name for _, p in frames]
    return ExpressionSequence(codes, DEFAULT_FPS, root.name, frame_names=names, **pose)


def _matrix_to_axis_angle(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) to axis-angle vectors (T, 3)."""
    cos = np.clip((np.trace(m, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1)
    s = np.linalg.norm(axis, axis=1, keepdims=True)
    axis = np.where(s > 1e-8, axis / np.maximum(s, 1e-12), 0.0)
    return (axis * angle[:, None]).astype(np.float32)
