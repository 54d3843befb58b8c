"""A sequence's head pose as one canonical -> world 4x4 per frame, built from each tracker's own definition.

Every reader turns what its tracker stores into T matrices M_t with x_world = M_t x (x a point of the avatar's
canonical space, column vectors); the viewer, `render` and `export` use only these. The definitions:

- npga-view's old `.npzseq` and other npz files with `rotation` (axis-angle), `translation`, `scale`:
  x_world = s R x + t.
- MonoNPHM (`rot.npy` (1, 3, 3), `trans.npy` (1, 3), `scale.npy` (1,) per frame folder) maps *world to NPHM*
  space: its renderer does ``pnts = scale * pnts @ R.T + trans`` on world-space samples, so the avatar (in
  NPHM space) sits at x_world = R^T (x - t) / s, the inverse of [[s R, t], [0, 1]].
- NeRSemble FLAME tracking (`flame2023_tracking*.npz`): `rotation` is intrinsic Euler XYZ (scipy
  ``Rotation.from_euler('XYZ')``), `scale` one value for the sequence: x_world = s R x + t, about the origin.
- GaussianAvatars `flame_param.npz`: FLAME applies `rotation` (axis-angle) about its root joint J0, which a
  non-FLAME avatar does not have; applied here about the origin: x_world = R x + t.

The research behind these (tracker repositories, files, lines) is cited in tests/files/test_tracker_pose.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from npga_core.errors import AvatarFileError
from npga_core.files.untrusted import MAX_POSITION
from npga_core.model import rotations

#: Range of a tracked scale.
SCALE_RANGE = (1e-6, 1e6)

SIMILARITY = "x_world = s R x + t (rotation axis-angle)"
MONONPHM = "MonoNPHM: x_world = R^T (x - t) / s (its rot/trans/scale map world to NPHM space)"
NERSEMBLE = "NeRSemble FLAME tracking: x_world = s R x + t (rotation Euler XYZ, about the origin)"
GAUSSIAN_AVATARS = ("GaussianAvatars: x_world = R x + t, rotation about the origin "
                    "(FLAME's root joint is not known for this avatar)")
#: Largest angle (radians) between a file's rotation matrices and its Euler angles accepted as agreeing.
AGREE_TOL = 1e-3


def finite_rows(a: npt.ArrayLike, t: int, width: int, path: str | Path, key: str) -> np.ndarray:
    """`a` as (T, width) float64, from (T, width) or T * width values; AvatarFileError otherwise or if it has
    NaN/Inf values."""
    a = np.asarray(a)
    if a.dtype.kind not in "fiu":
        raise AvatarFileError(path, f"{key} has dtype {a.dtype}, expected numbers")
    if a.size != t * width or not (t == 1 or (a.ndim >= 2 and a.shape[0] == t)):
        raise AvatarFileError(path, f"{key} must be finite with shape ({t}, {width}), got {a.shape}")
    a = a.reshape(t, width).astype(np.float64)
    if not np.isfinite(a).all():
        raise AvatarFileError(path, f"{key} has NaN/Inf values (frame {int(np.argmax(~np.isfinite(a).all(1)))})")
    big = ~(np.abs(a) <= MAX_POSITION).all(1)
    if big.any():
        raise AvatarFileError(path, f"{key} has values beyond +-{MAX_POSITION:g} (frame {int(np.argmax(big))})")
    return a


def frame_scales(scale: npt.ArrayLike, t: int, path: str | Path, key: str = "scale") -> np.ndarray:
    """Per-frame scales (T,): T values, or one value for the whole sequence (shape (), (1,) or (1, 1))
    broadcast; each finite and > 0."""
    a = np.asarray(scale)
    if a.dtype.kind not in "fiu":
        raise AvatarFileError(path, f"{key} has dtype {a.dtype}, expected numbers")
    if a.size == 1 and a.ndim <= 2:
        a = np.broadcast_to(a.reshape(1), (t,))
    elif a.size == t and a.ndim <= 2 and a.shape[0] == t:
        a = a.reshape(t)
    else:
        raise AvatarFileError(path, f"{key} must be one value or one per frame ({t},), got shape {a.shape}")
    a = a.astype(np.float64)
    bad = ~(np.isfinite(a) & (a >= SCALE_RANGE[0]) & (a <= SCALE_RANGE[1]))
    if bad.any():
        i = int(np.argmax(bad))
        raise AvatarFileError(path, f"{key} must be finite and positive (frame {i} is {a[i]:.4g}) within "
                              f"[{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}]")
    return a


def checked_rotations(m: npt.ArrayLike, t: int, path: str | Path, key: str) -> np.ndarray:
    """Rotation matrices (T, 3, 3) from (T, 3, 3) or (1, 3, 3) values: finite, orthonormal within
    `rotations.ORTHONORMAL_TOL` with determinant +1, returned as the nearest exact rotations."""
    m = np.asarray(m)
    if m.dtype.kind not in "fiu" or m.shape[-2:] != (3, 3) or m.size != 9 * t:
        raise AvatarFileError(path, f"{key} must be {t} rotation matrices (3, 3), got shape {m.shape} "
                              f"of {m.dtype}")
    m = m.reshape(t, 3, 3).astype(np.float64)
    bad = ~np.isfinite(m).all(axis=(1, 2))
    if bad.any():
        raise AvatarFileError(path, f"{key} has NaN/Inf values (frame {int(np.argmax(bad))})")
    err = rotations.orthonormality_error(m)
    bad = ~(err <= rotations.ORTHONORMAL_TOL)
    if bad.any():
        i = int(np.argmax(bad))
        why = "determinant is not positive" if np.isinf(err[i]) else f"|R^T R - I| up to {err[i]:.2g}"
        raise AvatarFileError(path, f"{key} of frame {i} is not a rotation matrix ({why})")
    return rotations.nearest_rotation(m)


def similarity_pose(rotation: npt.ArrayLike | None, translation: npt.ArrayLike | None,
                    scale: npt.ArrayLike | None, t: int, path: str | Path) -> np.ndarray:
    """x_world = s R x + t from axis-angle `rotation` (T, 3), `translation` (T, 3), `scale` (T,) or one value;
    a part that is None is the identity. npga-view's old `.npzseq` meaning."""
    r = None if rotation is None else rotations.matrix_from_rotvec(finite_rows(rotation, t, 3, path, "rotation"))
    tr = None if translation is None else finite_rows(translation, t, 3, path, "translation")
    s = None if scale is None else frame_scales(scale, t, path)
    return np.broadcast_to(rotations.similarity(r, tr, s), (t, 4, 4)).copy()


def mononphm_pose(rot: npt.ArrayLike | None, trans: npt.ArrayLike | None, scale: npt.ArrayLike | None, t: int,
                  path: str | Path) -> np.ndarray:
    """MonoNPHM's world -> NPHM pose inverted: x_world = R^T (x - t) / s. `rot` is (T, 3, 3) matrices (what
    the tracker saves, `so3_exp_map` of its parameters) or (T, 3) axis-angle (which its loader also takes);
    a part that is None is the identity."""
    if rot is None:
        r = np.eye(3)
    elif np.shape(rot)[-2:] == (3, 3):
        r = checked_rotations(rot, t, path, "rot.npy")
    else:
        r = rotations.matrix_from_rotvec(finite_rows(rot, t, 3, path, "rot.npy"))
    tr = np.zeros(3) if trans is None else finite_rows(trans, t, 3, path, "trans.npy")
    s = np.ones(1) if scale is None else frame_scales(scale, t, path, "scale.npy")
    world_to_nphm = np.broadcast_to(rotations.similarity(r, tr, s), (t, 4, 4))
    return np.linalg.inv(world_to_nphm)


def nersemble_pose(euler: npt.ArrayLike, matrices: npt.ArrayLike | None, translation: npt.ArrayLike,
                   scale: npt.ArrayLike, t: int, path: str | Path) -> np.ndarray:
    """NeRSemble FLAME tracking: x_world = s R x + t with R from `rotation_matrices` when present (checked to
    agree with the intrinsic Euler XYZ `rotation` within AGREE_TOL), else from the Euler angles."""
    r_euler = rotations.matrix_from_euler(finite_rows(euler, t, 3, path, "rotation"), "XYZ")
    r = r_euler
    if matrices is not None:
        r = checked_rotations(matrices, t, path, "rotation_matrices")
        gap = rotations.angle_between(r, r_euler)
        if (gap > AGREE_TOL).any():
            i = int(np.argmax(gap))
            raise AvatarFileError(path, f"rotation_matrices disagree with rotation (Euler XYZ) at frame {i} by "
                                  f"{np.degrees(gap[i]):.3g} degrees")
    return rotations.similarity(r, finite_rows(translation, t, 3, path, "translation"), frame_scales(scale, t, path))


def gaussian_avatars_pose(rotation: npt.ArrayLike, translation: npt.ArrayLike, t: int, path: str | Path) -> np.ndarray:
    """GaussianAvatars' FLAME rotation (axis-angle) and translation, the rotation about the origin (the root
    joint FLAME rotates about needs FLAME's regressor and shape): x_world = R x + t."""
    r = rotations.matrix_from_rotvec(finite_rows(rotation, t, 3, path, "rotation"))
    return rotations.similarity(r, finite_rows(translation, t, 3, path, "translation"))


def checked_pose(pose: npt.ArrayLike, t: int, path: str | Path) -> np.ndarray:
    """A stored pose (T, 4, 4) as float64 after the checks: T frames, finite, similarity transforms."""
    a = np.asarray(pose)
    if a.dtype.kind not in "fiu":
        raise AvatarFileError(path, f"pose has dtype {a.dtype}, expected numbers")
    if a.shape != (t, 4, 4):
        raise AvatarFileError(path, f"pose must have shape ({t}, 4, 4) for {t} frames, got {a.shape}")
    why = rotations.similarity_error(a)
    if why is not None:
        raise AvatarFileError(path, f"pose {why}")
    if not (np.abs(a[:, :3, 3]) <= MAX_POSITION).all():
        raise AvatarFileError(path, f"pose has translations beyond +-{MAX_POSITION:g}")
    s = np.cbrt(np.abs(np.linalg.det(a[:, :3, :3].astype(np.float64))))
    if not ((s >= SCALE_RANGE[0]) & (s <= SCALE_RANGE[1])).all():
        raise AvatarFileError(path, f"pose has scales outside [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}]")
    return a.astype(np.float64)
