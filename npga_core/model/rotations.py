"""Rotation conversions and similarity transforms, all through `scipy.spatial.transform.Rotation`.

Conventions: quaternions are (w, x, y, z) here and in the whole project (scipy's are (x, y, z, w): the
reordering happens only in this module) and come out with w >= 0; axis-angle vectors are radians, axis times
angle, angle in [0, pi]; matrices act on column vectors (x' = R x). Every function takes a batch (..., k) or
a single value and returns the same leading shape, float64.

A similarity transform is the 4x4 [[s R, t], [0, 0, 0, 1]] of x -> s R x + t (s > 0, R a rotation).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

#: Largest |R^T R - I| entry (after dividing out the scale) accepted as a rotation; float32 files of true
#: rotations are within ~1e-6, a visible shear or non-uniform scale is far above it.
ORTHONORMAL_TOL = 1e-3


def _batch(a: npt.ArrayLike, tail: tuple[int, ...]) -> tuple[np.ndarray, tuple[int, ...]]:
    a = np.asarray(a, np.float64)
    if a.shape[a.ndim - len(tail):] != tail:
        raise ValueError(f"expected shape (..., {', '.join(map(str, tail))}), got {a.shape}")
    lead = a.shape[: a.ndim - len(tail)]
    return a.reshape((-1, *tail)), lead


def _wxyz(xyzw: np.ndarray) -> np.ndarray:
    return xyzw[..., [3, 0, 1, 2]]


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    return wxyz[..., [1, 2, 3, 0]]


def matrix_from_rotvec(v: npt.ArrayLike) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of axis-angle vectors (..., 3) (Rodrigues)."""
    b, lead = _batch(v, (3,))
    return Rotation.from_rotvec(b).as_matrix().reshape(*lead, 3, 3)


def rotvec_from_matrix(m: npt.ArrayLike) -> np.ndarray:
    """Axis-angle vectors (..., 3), angle in [0, pi], of rotation matrices (..., 3, 3); exact at 180 degrees."""
    b, lead = _batch(m, (3, 3))
    return Rotation.from_matrix(b).as_rotvec().reshape(*lead, 3)


def quat_from_matrix(m: npt.ArrayLike, proper: bool = False) -> np.ndarray:
    """Unit quaternions (..., 4) (w, x, y, z), w >= 0, of rotation matrices (..., 3, 3). `proper`: the caller
    knows they are orthonormal with determinant 1 (skips scipy's orthonormalisation, ~10x faster)."""
    b, lead = _batch(m, (3, 3))
    try:
        rot = Rotation.from_matrix(b, assume_valid=proper) if proper else Rotation.from_matrix(b)
    except TypeError:  # scipy before `assume_valid`
        rot = Rotation.from_matrix(b)
    return _wxyz(rot.as_quat(canonical=True)).reshape(*lead, 4)


def matrix_from_quat(q: npt.ArrayLike) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) (w, x, y, z); normalised first, must not be 0."""
    b, lead = _batch(q, (4,))
    return Rotation.from_quat(_xyzw(b)).as_matrix().reshape(*lead, 3, 3)


def quat_from_rotvec(v: npt.ArrayLike) -> np.ndarray:
    """Unit quaternions (..., 4) (w, x, y, z), w >= 0, of axis-angle vectors (..., 3)."""
    b, lead = _batch(v, (3,))
    return _wxyz(Rotation.from_rotvec(b).as_quat(canonical=True)).reshape(*lead, 4)


def rotvec_from_quat(q: npt.ArrayLike) -> np.ndarray:
    """Axis-angle vectors (..., 3), angle in [0, pi], of quaternions (..., 4) (w, x, y, z)."""
    b, lead = _batch(q, (4,))
    return Rotation.from_quat(_xyzw(b)).as_rotvec().reshape(*lead, 3)


def quat_product(a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """Hamilton product a*b of (w, x, y, z) quaternions (float64, broadcast over leading dims; the rotation
    b, then a)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack((aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw), axis=-1)


def matrix_from_euler(angles: npt.ArrayLike, order: str = "XYZ") -> np.ndarray:
    """Rotation matrices (..., 3, 3) of Euler angles (..., 3) in radians; scipy's `order`: upper case is
    intrinsic ("XYZ": R = Rx(a0) Ry(a1) Rz(a2)), lower case extrinsic."""
    b, lead = _batch(angles, (3,))
    return Rotation.from_euler(order, b).as_matrix().reshape(*lead, 3, 3)


def nearest_rotation(m: npt.ArrayLike) -> np.ndarray:
    """The rotation matrices (..., 3, 3) closest to nearly orthonormal matrices (..., 3, 3) (scipy's
    quaternion fit); exact rotations come back unchanged up to rounding."""
    b, lead = _batch(m, (3, 3))
    return Rotation.from_matrix(b).as_matrix().reshape(*lead, 3, 3)


def angle_between(a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """Angles (...,) in radians of the rotations a^T b between rotation matrices a and b (..., 3, 3)."""
    ra, lead = _batch(a, (3, 3))
    rb, _ = _batch(b, (3, 3))
    return (Rotation.from_matrix(ra).inv() * Rotation.from_matrix(rb)).magnitude().reshape(lead)


def orthonormality_error(m: npt.ArrayLike) -> np.ndarray:
    """Largest |R^T R - I| entry (...,) of matrices (..., 3, 3); inf where the determinant is not positive."""
    b, lead = _batch(m, (3, 3))
    err = np.abs(np.einsum("nji,njk->nik", b, b) - np.eye(3)).max(axis=(1, 2))
    return np.where(np.linalg.det(b) > 0, err, np.inf).reshape(lead)


def similarity(rotation: npt.ArrayLike | None = None, translation: npt.ArrayLike | None = None,
               scale: npt.ArrayLike | None = None) -> np.ndarray:
    """4x4 matrices (..., 4, 4) of x -> s R x + t from rotation matrices (..., 3, 3), translations (..., 3)
    and scales (...,); a part given as None is the identity. The leading shapes must agree."""
    shapes = [np.shape(p)[: np.ndim(p) - k] for p, k in ((rotation, 2), (translation, 1), (scale, 0))
              if p is not None]
    lead = np.broadcast_shapes(*shapes) if shapes else ()
    m = np.zeros((*lead, 4, 4))
    m[..., :3, :3] = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    if scale is not None:
        m[..., :3, :3] *= np.asarray(scale, np.float64)[..., None, None]
    if translation is not None:
        m[..., :3, 3] = np.asarray(translation, np.float64)
    m[..., 3, 3] = 1.0
    return m


def similarity_parts(m: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scale (...,), rotation (..., 3, 3), translation (..., 3)) of similarity transforms (..., 4, 4); the
    scale is det^(1/3). Checks nothing: see `similarity_error`."""
    m = np.asarray(m, np.float64)
    a = m[..., :3, :3]
    s = np.cbrt(np.linalg.det(a))
    with np.errstate(divide="ignore", invalid="ignore"):
        r = a / s[..., None, None]
    return s, r, m[..., :3, 3]


def similarity_error(m: npt.ArrayLike) -> str | None:
    """Why 4x4 matrices (T, 4, 4) are not similarity transforms (finite, bottom row 0 0 0 1, 3x3 a positive
    scale times a rotation within ORTHONORMAL_TOL), naming the first bad one; None if they all are."""
    m = np.asarray(m, np.float64)
    if m.ndim != 3 or m.shape[1:] != (4, 4):
        return f"expected shape (T, 4, 4), got {m.shape}"
    bad = ~np.isfinite(m).all(axis=(1, 2))
    if bad.any():
        return f"matrix {int(np.argmax(bad))} has NaN/Inf values"
    bad = np.abs(m[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-9
    if bad.any():
        return f"matrix {int(np.argmax(bad))} has bottom row {m[int(np.argmax(bad)), 3].tolist()}, not 0 0 0 1"
    s, r, _ = similarity_parts(m)
    bad = ~(s > 0)
    if bad.any():
        i = int(np.argmax(bad))
        return f"matrix {i} has scale {s[i]:.4g} (3x3 determinant {s[i] ** 3:.4g}), must be positive"
    err = orthonormality_error(r)
    bad = ~(err <= ORTHONORMAL_TOL)
    if bad.any():
        i = int(np.argmax(bad))
        return f"matrix {i} is not a scaled rotation (|R^T R - I| up to {err[i]:.2g})"
    return None
