"""Rigid head pose of tracked sequences, applied by moving the camera instead of the Gaussians.

A sequence's `pose` (T, 4, 4) maps the avatar's canonical space to the tracking's world, x_world = M_t x, as
its tracker defines it (the readers build it: `npga_core.files.pose`); M_t is a similarity, s R plus t.
Seen through a camera V (world to camera) the posed head is V M x, so the renderer only needs the camera
V' = V M: positions, covariances (V M carries s R into every Gaussian's frame) and the SH view direction
(`Camera.camera_center` inverts the scaled matrix) all follow, and nothing of size N is recomputed.

With a calibrated rig the tracked pose is used as it is (`absolute`): the head appears where the camera saw
it. The orbit camera frames the canonical head, so there the motion is shown relative to the first frame,
M_0^-1 M_t, which is the identity at frame 0 and keeps the head in view.

Where the Gaussians themselves must move (a posed `.ply` export in the tracking's world), `transform_posed`
moves centres, rotations, scales and turns the SH with the head (`sh.rotate_sh`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TypeGuard

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.rigid import transform_posed
from npga_core.model.rotations import matrix_from_rotvec, similarity

__all__ = ["head_transform", "head_transforms", "pose_matrix", "posed_camera", "transform_posed"]


def pose_matrix(rotation: np.ndarray | None = None, translation: np.ndarray | None = None,
                scale: float | None = None) -> np.ndarray:
    """4x4 matrix of x -> s R x + t, R the rotation of the axis-angle vector `rotation`."""
    return similarity(None if rotation is None else matrix_from_rotvec(np.asarray(rotation).reshape(3)),
                      None if translation is None else np.asarray(translation).reshape(3),
                      None if scale is None else float(scale))


def has_head_pose(seq: ExpressionSequence | None) -> TypeGuard[ExpressionSequence]:
    """True when the sequence carries a head pose."""
    return seq is not None and seq.pose is not None


def pose_description(seq: ExpressionSequence | None) -> str:
    """What the sequence's head pose is and how it is applied (its source's definition), for the UI."""
    if not has_head_pose(seq):
        return "no head pose"
    return seq.pose_source or "x_world = M x (as stored)"


def head_transform(seq: ExpressionSequence, frame: int, relative: bool = True) -> np.ndarray:
    """4x4 canonical -> view-space transform of `frame`: M_frame, or M_0^-1 M_frame when `relative`."""
    if seq.pose is None:
        return np.eye(4)
    frame = int(np.clip(frame, 0, len(seq) - 1))
    m = np.asarray(seq.pose[frame], np.float64)
    return np.linalg.solve(np.asarray(seq.pose[0], np.float64), m) if relative else m.copy()


def head_transforms(seq: ExpressionSequence, frames: Iterable[int], mode: str, source: object) -> list[np.ndarray]:
    """Head transforms of `frames` for a CLI's --head-pose `mode` ("relative" or "absolute"); ValueError
    naming `source` if the sequence carries no pose."""
    if not has_head_pose(seq):
        raise ValueError(f"--head-pose: {source} has no head pose")
    return [head_transform(seq, f, relative=mode == "relative") for f in frames]


def posed_camera(camera: Camera, transform: np.ndarray) -> Camera:
    """The camera that shows the Gaussians moved by `transform` (4x4) when given the unmoved ones."""
    return Camera(camera.world_to_camera @ transform, camera.fx, camera.fy, camera.cx, camera.cy,
                  camera.width, camera.height)
