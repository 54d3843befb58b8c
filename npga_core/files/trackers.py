"""Tracker npz files read as expression sequences with the head pose as each tracker defines it.

- NeRSemble FLAME tracking (`flame2023_tracking.npz`, `flame2023_tracking_v2.npz`; nersemble-benchmark's
  `FlameTracking`): ``expression`` (T, 100), ``rotation`` (T, 3) intrinsic Euler XYZ, ``rotation_matrices``
  (T, 3, 3), ``translation`` (T, 3), ``scale`` (1, 1) for the whole sequence, ``jaw``, ``neck``, ``eyes``,
  ``frames`` (T,), ``shape``.
- GaussianAvatars `flame_param.npz`: ``expr`` (T, 100), ``rotation`` (T, 3) axis-angle, ``translation``
  (T, 3), ``neck_pose``, ``jaw_pose``, ``eyes_pose``, ``shape``, ``static_offset``, ``dynamic_offset``; its FLAME
  inputs are kept (`ExpressionSequence.flame`) for avatars posed by FLAME (`gaussian_avatars.flame_sequence`).

Both are recognised by their keys (`tracker_of`); the pose matrices come from `npga_core.files.pose`. The
expression codes are the FLAME expression parameters: they drive an avatar whose code is that vector.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.pose import GAUSSIAN_AVATARS, NERSEMBLE, gaussian_avatars_pose, nersemble_pose
from npga_core.files.sequences import DEFAULT_FPS, MAX_SEQUENCE_BYTES, ExpressionSequence
from npga_core.files.untrusted import read_npz, real_floats

NERSEMBLE_KEYS = frozenset({"expression", "rotation", "translation", "scale", "jaw", "neck", "eyes"})
GAUSSIAN_AVATARS_KEYS = frozenset({"expr", "rotation", "translation", "neck_pose", "jaw_pose", "eyes_pose"})


def _codes(z: dict[str, np.ndarray], key: str, path: Path) -> np.ndarray:
    codes = real_floats(z[key], path, "expression codes")
    if codes.ndim != 2 or codes.shape[0] < 1 or codes.shape[1] < 1:
        raise AvatarFileError(path, f"{key} must be (T, D) with T, D >= 1, got shape {codes.shape}")
    return codes


def read_nersemble(path: Path) -> ExpressionSequence:
    """A NeRSemble FLAME tracking npz: codes from `expression`, pose x_world = s R_XYZ x + t."""
    z = read_npz(path, MAX_SEQUENCE_BYTES, keys=("expression", "rotation", "rotation_matrices", "translation",
                                                  "scale", "frames"))
    codes = _codes(z, "expression", path)
    t = codes.shape[0]
    pose = nersemble_pose(z["rotation"], z.get("rotation_matrices"), z["translation"], z["scale"], t, path)
    names = None
    if "frames" in z:
        frames = np.asarray(z["frames"]).reshape(-1)
        if frames.size != t:
            raise AvatarFileError(path, f"{frames.size} frame numbers for {t} frames")
        names = [f"{f:g}" if isinstance(f, float) else str(f) for f in frames.tolist()]
    return ExpressionSequence(codes, DEFAULT_FPS, path.stem, frame_names=names, pose=pose, pose_source=NERSEMBLE)


def read_gaussian_avatars(path: Path) -> ExpressionSequence:
    """A GaussianAvatars flame_param.npz: codes from `expr`, pose x_world = R x + t (about the origin)."""
    keys = ("expr", "rotation", "translation", "neck_pose", "jaw_pose", "eyes_pose")
    z = read_npz(path, MAX_SEQUENCE_BYTES, keys=keys)
    codes = _codes(z, "expr", path)
    pose = gaussian_avatars_pose(z["rotation"], z["translation"], codes.shape[0], path)
    flame = {k: real_floats(z[k], path, k, np.float64) for k in keys if k in z}
    return ExpressionSequence(codes, DEFAULT_FPS, path.parent.name if path.stem == "flame_param" else path.stem,
                              pose=pose, pose_source=GAUSSIAN_AVATARS, flame=flame)


def tracker_of(keys: Iterable[str]) -> Callable[[Path], ExpressionSequence] | None:
    """The reader of a tracker's npz recognised by its array names, or None (npga-view's own or a plain npz)."""
    keys = set(keys)
    if "codes" in keys:  # npga-view's own format wins
        return None
    if ("rotation_matrices" in keys and "expression" in keys) or keys >= NERSEMBLE_KEYS:
        return read_nersemble
    if keys >= GAUSSIAN_AVATARS_KEYS:
        return read_gaussian_avatars
    return None
