"""`Skin`: the skinned mesh of a `LinearRig` with carrier "triangle", and Gaussians riding its triangles.

The rig's points are the mesh vertices (rest positions `LinearRig.vertices`, linear blendshapes
`LinearRig.deltas`). Per frame, with blendshape weights w, joint rotations r_j (axis-angle) and a translation t
(GaussianAvatars' FLAME, read from their `flame_model/flame.py` and `lbs.py`):

    v      = rest + sum_k w_k delta_k                         linear blendshapes (FLAME's expression)
    J      = joints + sum_k w_k joint_delta_k                 joints regressed from v (linear, precomputed)
    v      = v + posedirs . vec(R_j - I, j >= 1)               pose correctives
    v'     = sum_j W_vj G_j (v - J_j) + t                     linear blend skinning, G_j along the parents
    face f = (v0, v1, v2): a0 = n(v1 - v0), a1 = n(a0 x (v2 - v0)), a2 = -n(a1 x a0), R_f = [a0 a1 a2],
             s_f = (|v1 - v0| + |a2 . (v2 - v0)|) / 2, c_f = (v0 + v1 + v2) / 3

A Gaussian bound to face f rides it: local position x, log scale l and rotation q give R_f x s_f + c_f,
l + log s_f and q_f (x) q. The avatar's canonical cloud holds the Gaussians on the rest mesh (every input 0), so
the rig's output per Gaussian is the face's motion since rest, as offsets composed by `ATTRIBUTE_OPS`:
position A_f mu + b_f - mu (A_f = (s_f / s0_f) R_f R0_f^T, b_f = c_f - A_f c0_f), rotation
quat(R_f R0_f^T) - (1, 0, 0, 0) (the "compose" rule) and scale log(s_f / s0_f). Colour is not turned.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from npga_core.model import rotations

TRANSLATION = "translation"
#: The skin's arrays, as stored (`rig.skin.NAME` in an `.npga`, docs/FORMAT.md section 19).
SKIN_ARRAYS = ("joints", "joint_deltas", "parents", "weights", "posedirs", "faces", "binding")
AXES = ("x", "y", "z")


@dataclass
class FaceMotion:
    """Per face, its motion since rest at one frame, packed (F, 17) float32: A - I (9, row-major), b (3), dq (4,
    wxyz, the rotation's quaternion minus (1, 0, 0, 0)), dlog (1); one gather per chunk of Gaussians."""

    packed: torch.Tensor

    @classmethod
    def of(cls, a: torch.Tensor, b: torch.Tensor, dq: torch.Tensor, dlog: torch.Tensor) -> FaceMotion:
        am = a - torch.eye(3, dtype=a.dtype)
        return cls(torch.cat([am.reshape(-1, 9), b, dq, dlog[:, None]], 1).float().contiguous())

    @property
    def a(self) -> torch.Tensor:
        return self.packed[:, :9].reshape(-1, 3, 3) + torch.eye(3)

    @property
    def b(self) -> torch.Tensor:
        return self.packed[:, 9:12]

    @property
    def dq(self) -> torch.Tensor:
        return self.packed[:, 12:16]

    @property
    def dlog(self) -> torch.Tensor:
        return self.packed[:, 16]


@dataclass
class Skin:
    """Joints, skinning weights, pose correctives, triangles and each Gaussian's triangle (see the module)."""

    joint_names: tuple[str, ...]
    joints: np.ndarray  # (J, 3) rest joints
    joint_deltas: np.ndarray  # (K, J, 3) joints' change per unit blendshape weight
    parents: np.ndarray  # (J,) int64, -1 for the root, parents[j] < j
    weights: np.ndarray  # (V, J) skinning weights
    posedirs: np.ndarray  # (9 (J - 1), V, 3) pose correctives per element of R_j - I, j >= 1
    faces: np.ndarray  # (F, 3) int64
    binding: np.ndarray  # (N,) int64 face of each Gaussian
    _rest: tuple | None = field(default=None, init=False, repr=False)
    _torch: dict | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.joint_names = tuple(str(n) for n in self.joint_names)
        self.joints = np.ascontiguousarray(self.joints, np.float32)
        j = len(self.joint_names)
        self.joint_deltas = np.ascontiguousarray(self.joint_deltas, np.float32)
        self.parents = np.ascontiguousarray(self.parents, np.int64).reshape(-1)
        self.weights = np.ascontiguousarray(self.weights, np.float32)
        self.posedirs = np.ascontiguousarray(self.posedirs, np.float32)
        self.faces = np.ascontiguousarray(self.faces, np.int64)
        self.binding = np.ascontiguousarray(self.binding, np.int64).reshape(-1)
        v = self.weights.shape[0]
        if j < 1 or len(set(self.joint_names)) != j or TRANSLATION in self.joint_names:
            raise ValueError("a skin needs distinct joint names (not 'translation')")
        checks = {"joints": (self.joints, (j, 3)), "parents": (self.parents, (j,)),
                  "weights": (self.weights, (v, j)), "posedirs": (self.posedirs, (9 * (j - 1), v, 3))}
        for name, (a, shape) in checks.items():
            if a.shape != shape:
                raise ValueError(f"skin {name} have shape {a.shape}, expected {shape}")
        if self.joint_deltas.ndim != 3 or self.joint_deltas.shape[1:] != (j, 3):
            raise ValueError(f"skin joint deltas have shape {self.joint_deltas.shape}, expected (K, {j}, 3)")
        if self.parents[0] != -1 or any(not 0 <= self.parents[i] < i for i in range(1, j)):
            raise ValueError("skin parents must be -1 for joint 0 and an earlier joint for the others")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or not len(self.faces):
            raise ValueError(f"skin faces have shape {self.faces.shape}, expected (F, 3)")
        if self.faces.min() < 0 or self.faces.max() >= v:
            raise ValueError(f"skin faces index vertices outside 0..{v - 1}")
        if len(self.binding) and (self.binding.min() < 0 or self.binding.max() >= len(self.faces)):
            raise ValueError(f"skin binding names faces outside 0..{len(self.faces) - 1}")
        for name in ("joints", "joint_deltas", "weights", "posedirs"):
            if not np.isfinite(getattr(self, name)).all():
                raise ValueError(f"skin {name} have NaN/Inf values")

    @property
    def n_vertices(self) -> int:
        return int(self.weights.shape[0])

    @property
    def pose_dim(self) -> int:
        """Inputs after the blendshape weights: 3 per joint (axis-angle), then the translation (3)."""
        return 3 * len(self.joint_names) + 3

    def input_names(self) -> tuple[str, ...]:
        return tuple(f"{n}.{a}" for n in (*self.joint_names, TRANSLATION) for a in AXES)

    def mesh(self, rest: np.ndarray, deltas: np.ndarray, support: np.ndarray, w: np.ndarray,
             pose: np.ndarray) -> np.ndarray:
        """Posed vertices (V, 3) float64 at blendshape weights w (K,) and `pose` (pose_dim,): the reference (numpy,
        float64) that `posed_vertices` is tested against."""
        w = np.asarray(w, np.float64)
        v = np.array(rest, np.float64)
        if len(support) and w.any():
            v[support] += np.tensordot(w.astype(np.float32), deltas, 1)
        joints = self.joints + np.tensordot(w, self.joint_deltas.astype(np.float64), 1)
        n = len(self.joint_names)
        rot = rotations.matrix_from_rotvec(np.asarray(pose[: 3 * n], np.float64).reshape(n, 3))
        feature = (rot[1:] - np.eye(3)).reshape(-1)
        if feature.any():
            v += np.tensordot(feature.astype(np.float32), self.posedirs, 1)
        chain = self._chain(rot, joints)
        t = np.einsum("vj,jab->vab", self.weights.astype(np.float64), chain[:, :3, :])
        return np.einsum("vab,vb->va", t[:, :, :3], v) + t[:, :, 3] + np.asarray(pose[3 * n:], np.float64)

    def _chain(self, rot: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """(J, 4, 4) float64 skinning transforms G_j (along the parents, about the rest joints)."""
        n = len(self.joint_names)
        chain = np.zeros((n, 4, 4))
        for j in range(n):
            local = np.eye(4)
            local[:3, :3] = rot[j]
            p = self.parents[j]
            local[:3, 3] = joints[j] - (joints[p] if p >= 0 else 0.0)
            chain[j] = local if p < 0 else chain[p] @ local
        chain[:, :3, 3] -= np.einsum("jab,jb->ja", chain[:, :3, :3], joints)
        return chain

    def _tensors(self) -> dict:
        if self._torch is None:
            self._torch = {"weights64": torch.from_numpy(self.weights.astype(np.float64)),
                           "posedirs": torch.from_numpy(self.posedirs.reshape(len(self.posedirs), -1)),
                           "faces": torch.from_numpy(self.faces), "binding": torch.from_numpy(self.binding)}
        return self._torch

    def posed_vertices(self, rest: torch.Tensor, blend: torch.Tensor, w: np.ndarray, pose: np.ndarray) -> torch.Tensor:
        """Posed vertices (V, 3) float64 as `mesh`, fast: `rest` (V, 3) and the blendshapes' displacement `blend`
        (V, 3) given as tensors, the pose correctives one float32 matmul (as `mesh`), the skinning one float64
        matmul (V x J by J x 12), only the joints' chain (J of them) in numpy."""
        t = self._tensors()
        n = len(self.joint_names)
        joints = self.joints + np.tensordot(np.asarray(w, np.float64), self.joint_deltas.astype(np.float64), 1)
        rot = rotations.matrix_from_rotvec(np.asarray(pose[: 3 * n], np.float64).reshape(n, 3))
        v = rest.double() + blend  # float64 sums: small triangles' frames amplify a float32 rounding
        feature = (rot[1:] - np.eye(3)).reshape(-1)
        if feature.any():
            v += (torch.from_numpy(feature.astype(np.float32)) @ t["posedirs"]).view(-1, 3)
        chain = torch.from_numpy(self._chain(rot, joints)[:, :3, :].reshape(n, 12))
        g = (t["weights64"] @ chain).view(-1, 3, 4)
        out = g[:, :, 0] * v[:, :1] + g[:, :, 1] * v[:, 1:2] + g[:, :, 2] * v[:, 2:] + g[:, :, 3]
        return out + torch.from_numpy(np.asarray(pose[3 * n :], np.float64))

    def face_motion(self, posed: torch.Tensor, rest: np.ndarray) -> FaceMotion:
        """`motion` in torch (float64) from `posed_vertices`."""
        r0, s0, c0 = (torch.from_numpy(x) for x in self.rest_frames(rest))
        r, s, c = torch_face_frames(posed, self._tensors()["faces"])
        turn = r @ r0.transpose(1, 2)
        ratio = s / s0
        a = turn * ratio[:, None, None]
        b = c - (a @ c0[:, :, None])[:, :, 0]
        dq = quat_from_rotation(turn)
        dq[:, 0] -= 1.0
        return FaceMotion.of(a, b, dq, torch.log(ratio))

    def rest_frames(self, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R0 (F, 3, 3), s0 (F,), c0 (F, 3)) of the rest mesh, float64 (cached)."""
        if self._rest is None:
            self._rest = face_frames(np.asarray(rest, np.float64), self.faces)
        return self._rest

    def motion(self, posed: np.ndarray, rest: np.ndarray) -> FaceMotion:
        """Each face's motion from rest to the `posed` vertices."""
        r0, s0, c0 = self.rest_frames(rest)
        r, s, c = face_frames(posed, self.faces)
        turn = r @ np.swapaxes(r0, 1, 2)
        ratio = s / s0
        a = turn * ratio[:, None, None]
        b = c - np.einsum("fab,fb->fa", a, c0)
        dq = rotations.quat_from_matrix(turn, proper=True)
        dq[:, 0] -= 1.0
        return FaceMotion.of(*(torch.from_numpy(x) for x in (a, b, dq, np.log(ratio))))

    def offsets(self, motion: FaceMotion, rows: slice | np.ndarray, means: torch.Tensor) -> dict[str, torch.Tensor]:
        """Position, rotation and scale offsets of the Gaussians `rows` whose canonical centres are `means`."""
        binding = self._tensors()["binding"]
        face = binding[rows] if isinstance(rows, slice) else binding.index_select(0, torch.from_numpy(
            np.asarray(rows, np.int64)))
        g = motion.packed.index_select(0, face)
        mu = means.to(g.dtype)
        pos = (g[:, :9].view(-1, 3, 3) * mu[:, None, :]).sum(2)  # (A - I) mu
        return {"position": pos + g[:, 9:12], "rotation": g[:, 12:16], "scale": g[:, 16:17].expand(-1, 3)}


def face_frames(v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per face its frame R = [a0 a1 a2] (F, 3, 3), scale s (F,) and centre c (F, 3) (see the module)."""
    v0, v1, v2 = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    a0 = _unit(e1)
    a1 = _unit(np.cross(a0, e2))
    a2 = -_unit(np.cross(a1, a0))
    s = (np.linalg.norm(e1, axis=1) + np.abs(np.einsum("fa,fa->f", a2, e2))) / 2
    return np.stack([a0, a1, a2], axis=2), s, (v0 + v1 + v2) / 3


def torch_face_frames(v: torch.Tensor, faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`face_frames` in torch."""
    v0, v1, v2 = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    e1, e2 = v1 - v0, v2 - v0

    def unit(x: torch.Tensor) -> torch.Tensor:
        return x / x.norm(dim=1, keepdim=True).clamp_min(1e-20)

    a0 = unit(e1)
    a1 = unit(torch.linalg.cross(a0, e2))
    a2 = -unit(torch.linalg.cross(a1, a0))
    s = (e1.norm(dim=1) + (a2 * e2).sum(1).abs()) / 2
    return torch.stack([a0, a1, a2], dim=2), s, (v0 + v1 + v2) / 3


def quat_from_rotation(m: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (F, 4) wxyz, w >= 0, of rotation matrices (F, 3, 3): each from its largest component."""
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = torch.stack([  # 4 |q_i|^2 for i = w, x, y, z, and each candidate's quaternion times 4 q_i
        torch.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], 1),
        torch.stack([m[:, 2, 1] - m[:, 1, 2], 1 + 2 * m[:, 0, 0] - tr, m[:, 0, 1] + m[:, 1, 0],
                     m[:, 0, 2] + m[:, 2, 0]], 1),
        torch.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 + 2 * m[:, 1, 1] - tr,
                     m[:, 1, 2] + m[:, 2, 1]], 1),
        torch.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1],
                     1 + 2 * m[:, 2, 2] - tr], 1)], 1)  # (F, 4 candidates, 4)
    best = cand.diagonal(dim1=1, dim2=2).argmax(1)
    q = cand[torch.arange(len(m)), best]
    q = q / q.norm(dim=1, keepdim=True)
    return torch.where(q[:, :1] < 0, -q, q)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-20)
