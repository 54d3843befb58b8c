"""npga_core.model.rotations: conversions at 0, 90, 179.9 and 180 degrees and random rotations, against the
textbook formulas written out here; (w, x, y, z) quaternion order; similarity transforms and their checks."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.model import rotations as rot
from tests.support.reference_rasterizer import quat_to_rotation

AXES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.48, -0.6, 0.64]])


def rodrigues(v: np.ndarray) -> np.ndarray:
    """R = I + sin(a) K + (1 - cos(a)) K^2, K the cross-product matrix of the unit axis (the formula of
    pytorch3d's so3_exp_map, MonoNPHM's rot.npy, and FLAME's batch_rodrigues)."""
    a = np.linalg.norm(v)
    if a == 0:
        return np.eye(3)
    k = v / a
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


def elementary(axis: int, a: float) -> np.ndarray:
    """The right-handed rotation by `a` about coordinate axis 0, 1 or 2 (x, y, z)."""
    c, s = np.cos(a), np.sin(a)
    return [np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])][axis]


@pytest.mark.parametrize("degrees", [0.0, 90.0, 179.9, 180.0])
@pytest.mark.parametrize("axis", range(len(AXES)))
def test_round_trips_at_special_angles(degrees, axis):
    v = np.radians(degrees) * AXES[axis] / np.linalg.norm(AXES[axis])
    m = rot.matrix_from_rotvec(v)
    np.testing.assert_allclose(m, rodrigues(v), atol=1e-12)
    back = rot.rotvec_from_matrix(m)
    # the angle survives (the old hand-written inverse turned 180 degrees into the identity)
    assert np.linalg.norm(back) == pytest.approx(np.radians(degrees), abs=1e-9)
    np.testing.assert_allclose(rot.matrix_from_rotvec(back), m, atol=1e-12)
    if degrees < 180:
        np.testing.assert_allclose(back, v, atol=1e-9)
    else:  # 180 degrees about k and about -k are the same rotation
        assert min(np.abs(back - v).max(), np.abs(back + v).max()) < 1e-9
    q = rot.quat_from_matrix(m)
    assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(q[0], np.cos(np.radians(degrees) / 2), atol=1e-12)
    np.testing.assert_allclose(rot.matrix_from_quat(q), m, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotation(q[None])[0], m, atol=1e-12)  # the renderer's (w, x, y, z)
    np.testing.assert_allclose(rot.matrix_from_rotvec(rot.rotvec_from_quat(rot.quat_from_rotvec(v))), m, atol=1e-12)


def test_quaternion_order_is_w_first():
    q = rot.quat_from_rotvec([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(rot.matrix_from_quat([0.0, 1.0, 0.0, 0.0]), np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(rot.matrix_from_quat([2.0, 0.0, 0.0, 0.0]), np.eye(3))  # normalised first


def test_random_rotations_round_trip():
    rng = np.random.default_rng(0)
    v = rng.standard_normal((500, 3))
    v *= (rng.uniform(0, np.pi, 500) / np.linalg.norm(v, axis=1))[:, None]
    m = rot.matrix_from_rotvec(v)
    np.testing.assert_allclose(m, np.stack([rodrigues(x) for x in v]), atol=1e-12)
    np.testing.assert_allclose(rot.rotvec_from_matrix(m), v, atol=1e-9)
    q = rot.quat_from_matrix(m)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(q, rot.quat_from_rotvec(v), atol=1e-12)
    np.testing.assert_allclose(rot.rotvec_from_quat(q), v, atol=1e-9)
    np.testing.assert_allclose(quat_to_rotation(q), m, atol=1e-12)
    assert rot.matrix_from_rotvec(v.reshape(5, 100, 3)).shape == (5, 100, 3, 3)  # leading shapes kept
    assert rot.quat_from_matrix(m[0]).shape == (4,)


def test_euler_xyz_is_intrinsic():
    """Upper-case 'XYZ' (NeRSemble's Pose.from_euler) is Rx(a) Ry(b) Rz(c); lower-case extrinsic differs."""
    a = np.array([0.5, -0.4, 0.6])
    want = elementary(0, a[0]) @ elementary(1, a[1]) @ elementary(2, a[2])
    np.testing.assert_allclose(rot.matrix_from_euler(a, "XYZ"), want, atol=1e-12)
    np.testing.assert_allclose(rot.matrix_from_euler(a, "xyz"), elementary(2, a[2]) @ elementary(1, a[1]) @
                               elementary(0, a[0]), atol=1e-12)
    assert np.abs(rot.matrix_from_euler(a, "XYZ") - rot.matrix_from_rotvec(a)).max() > 0.05


def test_angle_between_and_nearest_rotation():
    a = rot.matrix_from_rotvec([0.2, 0.1, -0.3])
    b = a @ rot.matrix_from_rotvec([0.0, 0.0, 0.25])
    assert rot.angle_between(a, b) == pytest.approx(0.25)
    noisy = a + 1e-5 * np.random.default_rng(1).standard_normal((3, 3))
    near = rot.nearest_rotation(noisy)
    assert rot.orthonormality_error(near) < 1e-12 and np.abs(near - a).max() < 1e-4


def test_similarity_and_its_checks():
    r = rot.matrix_from_rotvec([[0.0, 0.4, 0.0], [0.3, 0.0, 0.2]])
    t = np.array([[0.1, 0.2, 0.3], [0.0, -0.1, 0.0]])
    s = np.array([1.2, 0.8])
    m = rot.similarity(r, t, s)
    x = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(m[1] @ np.append(x, 1), np.append(s[1] * r[1] @ x + t[1], 1), atol=1e-12)
    s2, r2, t2 = rot.similarity_parts(m)
    np.testing.assert_allclose(s2, s) and np.testing.assert_allclose(r2, r, atol=1e-12)
    np.testing.assert_allclose(t2, t)
    assert rot.similarity_error(m) is None
    np.testing.assert_allclose(rot.similarity(translation=t[0]), [[1, 0, 0, 0.1], [0, 1, 0, 0.2], [0, 0, 1, 0.3],
                                                                  [0, 0, 0, 1]])

    def broken(fix) -> str:
        b = m.copy()
        fix(b)
        return rot.similarity_error(b)

    assert "matrix 1 has NaN" in broken(lambda b: b.__setitem__((1, 0, 3), np.nan))
    assert "bottom row" in broken(lambda b: b.__setitem__((0, 3, 0), 0.5))
    assert "must be positive" in broken(lambda b: b.__setitem__((1, slice(0, 3), 0), -b[1, :3, 0]))  # a mirror
    assert "not a scaled rotation" in broken(lambda b: b.__setitem__((0, 0, 1), b[0, 0, 1] + 0.05))  # a shear
    assert "not a scaled rotation" in broken(lambda b: b.__setitem__((0, 0, slice(0, 3)), 2 * b[0, 0, :3]))
    assert "(T, 4, 4)" in rot.similarity_error(m[0])
    with pytest.raises(ValueError, match="expected shape"):
        rot.matrix_from_rotvec(np.zeros(4))
