"""Rigid head pose of tracked sequences, applied by moving the camera instead of the Gaussians.

A sequence's pose maps the avatar's canonical space to the tracking's world space: x_world = s R x + t, R the
rotation of the axis-angle vector `rotation`, t `translation`, s `scale` (missing parts: identity). Seen
through a camera V (world to camera) the posed head is V T x, so the renderer only needs the camera
V' = V T: positions, covariances (V T carries s R into every Gaussian's frame) and the SH view direction
(`Camera.camera_center` inverts the scaled matrix) all follow, and nothing of size N is recomputed.

With a calibrated rig the tracked pose is used as it is (`absolute`): the head appears where the camera saw
it. The orbit camera frames the canonical head, so there the motion is shown relative to the first frame,
T_0^-1 T_t, which is the identity at frame 0 and keeps the head in view.

Where the Gaussians themselves must move (a posed `.ply` export in the tracking's world), `transform_posed`
moves centres, rotations, scales and turns the SH with the head (`sh.rotate_sh`).
"""

from __future__ import annotations

import numpy as np
import torch

from npga_core.camera.cameras import Camera
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.dynamics import quat_multiply
from npga_core.model.gaussians import PosedGaussians
from npga_core.model.sh import rotate_sh


def axis_angle_matrix(v: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of an axis-angle vector (radians; Rodrigues' formula)."""
    v = np.asarray(v, np.float64).reshape(3)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def pose_matrix(rotation: np.ndarray | None = None, translation: np.ndarray | None = None,
                scale: float | None = None) -> np.ndarray:
    """4x4 matrix of x -> s R x + t."""
    m = np.eye(4)
    r = np.eye(3) if rotation is None else axis_angle_matrix(rotation)
    m[:3, :3] = (1.0 if scale is None else float(scale)) * r
    if translation is not None:
        m[:3, 3] = np.asarray(translation, np.float64).reshape(3)
    return m


def has_head_pose(seq: ExpressionSequence | None) -> bool:
    """True when the sequence carries any part of a head pose."""
    return seq is not None and any(getattr(seq, k) is not None for k in ("rotation", "translation", "scale"))


def head_transform(seq: ExpressionSequence, frame: int, relative: bool = True) -> np.ndarray:
    """4x4 canonical -> view-space transform of `frame`: T_frame, or T_0^-1 T_frame when `relative`."""
    def at(i: int) -> np.ndarray:
        return pose_matrix(None if seq.rotation is None else seq.rotation[i],
                           None if seq.translation is None else seq.translation[i],
                           None if seq.scale is None else float(seq.scale[i]))

    frame = int(np.clip(frame, 0, len(seq) - 1))
    t = at(frame)
    return np.linalg.solve(at(0), t) if relative else t


def head_transforms(seq: ExpressionSequence, frames, mode: str, source: object) -> list[np.ndarray]:
    """Head transforms of `frames` for a CLI's --head-pose `mode` ("relative" or "absolute"); ValueError
    naming `source` if the sequence carries no pose."""
    if not has_head_pose(seq):
        raise ValueError(f"--head-pose: {source} has no head pose (rotation, translation or scale)")
    return [head_transform(seq, f, relative=mode == "relative") for f in frames]


def posed_camera(camera: Camera, transform: np.ndarray) -> Camera:
    """The camera that shows the Gaussians moved by `transform` (4x4) when given the unmoved ones."""
    return Camera(camera.world_to_camera @ transform, camera.fx, camera.fy, camera.cx, camera.cy,
                  camera.width, camera.height)


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (3, 3)."""
    r = np.asarray(r, np.float64)
    # the largest of 4w^2, 4x^2, 4y^2, 4z^2 gives the best-conditioned formula (Shepperd)
    t = np.array([1 + r[0, 0] + r[1, 1] + r[2, 2], 1 + r[0, 0] - r[1, 1] - r[2, 2],
                  1 - r[0, 0] + r[1, 1] - r[2, 2], 1 - r[0, 0] - r[1, 1] + r[2, 2]])
    i = int(np.argmax(t))
    f = 0.5 / np.sqrt(t[i])
    if i == 0:
        q = [0.25 / f, (r[2, 1] - r[1, 2]) * f, (r[0, 2] - r[2, 0]) * f, (r[1, 0] - r[0, 1]) * f]
    elif i == 1:
        q = [(r[2, 1] - r[1, 2]) * f, 0.25 / f, (r[0, 1] + r[1, 0]) * f, (r[0, 2] + r[2, 0]) * f]
    elif i == 2:
        q = [(r[0, 2] - r[2, 0]) * f, (r[0, 1] + r[1, 0]) * f, 0.25 / f, (r[1, 2] + r[2, 1]) * f]
    else:
        q = [(r[1, 0] - r[0, 1]) * f, (r[0, 2] + r[2, 0]) * f, (r[1, 2] + r[2, 1]) * f, 0.25 / f]
    q = np.asarray(q)
    return q if q[0] >= 0 else -q


def transform_posed(posed: PosedGaussians, transform: np.ndarray) -> PosedGaussians:
    """The Gaussians moved by `transform` (4x4, s R with s > 0, plus t): centres, rotations, scales, SH."""
    m = np.asarray(transform, np.float64)
    det = float(np.linalg.det(m[:3, :3]))
    if not det > 0:
        raise ValueError("a head transform must be a scaled rotation (positive determinant)")
    s = det ** (1.0 / 3.0)
    r = m[:3, :3] / s
    q_r = torch.from_numpy(matrix_to_quat(r))
    quats = quat_multiply(q_r, torch.from_numpy(np.asarray(posed.quats, np.float64))).numpy()  # q' = q_R q
    means = np.asarray(posed.means, np.float64) @ m[:3, :3].T + m[:3, 3]
    return PosedGaussians(means.astype(np.float32), quats.astype(np.float32),
                          (s * np.asarray(posed.scales, np.float64)).astype(np.float32), posed.opacities,
                          rotate_sh(posed.sh, r), posed.latent)
