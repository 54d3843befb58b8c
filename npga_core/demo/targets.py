"""Supervision for F and G from the ICT blendshape model.

F: a point sampled on triangle t at barycentrics b moves with the interpolated vertex offsets,
``delta(w) = sum_k w_k sum_c b_c D_k[t_c]``, plus the eyeball gaze rotation (see `ict.pose_vertices`).

G: per (point, expression) the rotation of the surface's local frame (polar decomposition of the
deformation gradient, averaged per vertex and interpolated), the stretch of the disc's tangent axes (log
scale offsets), and a darkening of the colour (SH DC offset) where the skin compresses (with wrinkle-like
stripes on the forehead and nose bridge) and deeper in the mouth as the jaw opens.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from npga_core.demo.colors import CM, smoothstep
from npga_core.demo.ict import PART_NAMES, GazeModel, IctHead, pose_vertices
from npga_core.model.gaussians import SH_C0

#: Colour darkening: strength of the compression term, wrinkle stripe period, mouth-interior strength.
COMPRESSION_DARKENING = 1.8
WRINKLE_PERIOD = 0.0065
MOUTH_DARKENING = 0.4
MAX_DARKENING = 0.6


def matrix_to_quat(r: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4) (w, x, y, z), w >= 0, of rotation matrices (..., 3, 3)."""
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    q = torch.stack([(1 + m00 + m11 + m22), (1 + m00 - m11 - m22), (1 - m00 + m11 - m22), (1 - m00 - m11 + m22)],
                    dim=-1).clamp_min(0.0).sqrt() / 2
    signs = torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    xyz = torch.copysign(q[..., 1:], signs)
    q = torch.cat([q[..., :1], xyz], dim=-1)
    return q / q.norm(dim=-1, keepdim=True)


def polar_rotation(f: torch.Tensor, iterations: int = 8) -> torch.Tensor:
    """Rotation factor R of F = R U (F with positive determinant) by Newton's iteration X <- (X + X^-T) / 2."""
    x = f
    for _ in range(iterations):
        x = 0.5 * (x + torch.linalg.inv(x).transpose(-1, -2))
    return x


def _frames(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Per-triangle matrices (..., T, 3, 3) with columns edge1, edge2, unit normal."""
    a, b, c = v[..., faces[:, 0], :], v[..., faces[:, 1], :], v[..., faces[:, 2], :]
    e1, e2 = b - a, c - a
    n = torch.linalg.cross(e1, e2)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.stack([e1, e2, n], dim=-1)


def shading_weights(head: IctHead, rest: np.ndarray, part: np.ndarray) -> dict[str, torch.Tensor]:
    """Per-point weights (float32) of the expression-dependent shading at canonical positions `rest`: skin (where
    compression darkens), stripe_weight and stripe (forehead and nose-bridge wrinkle stripes), mouth_depth."""
    face = part == PART_NAMES.index("face")
    skin = face | (part == PART_NAMES.index("head_neck"))
    brow_y = head.landmark_points(range(17, 27))[:, 1].mean()
    forehead = smoothstep(brow_y - 0.3 * CM, brow_y + 0.4 * CM, rest[:, 1])
    nose_bridge = (smoothstep(1.8 * CM, 1.2 * CM, np.abs(rest[:, 0])) * smoothstep(1.5 * CM, 2.5 * CM, rest[:, 1]))
    stripes = np.clip(forehead + nose_bridge, 0.0, 1.0) * (rest[:, 2] > 6.0 * CM) * face
    inside = np.isin(part, [PART_NAMES.index(k) for k in ("mouth_socket", "gums_tongue", "teeth")])
    depth = smoothstep(10.5 * CM, 6.0 * CM, rest[:, 2]) * inside
    stripe = 0.5 + 0.5 * np.cos(2 * np.pi * rest[:, 1] / WRINKLE_PERIOD)
    out = {"skin": skin, "stripe_weight": stripes, "stripe": stripe, "mouth_depth": depth}
    return {k: torch.from_numpy(np.asarray(v).astype(np.float32)) for k, v in out.items()}


def darkening(lam_min: torch.Tensor, jaw: torch.Tensor, skin: torch.Tensor, stripe_weight: torch.Tensor,
              stripe: torch.Tensor, mouth_depth: torch.Tensor) -> torch.Tensor:
    """Colour darkening in [0, MAX_DARKENING] from the smallest principal stretch of the surface `lam_min` (skin
    compression, modulated by the wrinkle stripes) and the jawOpen weight (deeper in the mouth)."""
    compression = (-lam_min.log()).clamp_min(0.0) * skin
    modulation = (1.0 - stripe_weight) + stripe_weight * (0.25 + 1.5 * stripe)
    dark = 1.0 - torch.exp(-COMPRESSION_DARKENING * compression * modulation)
    mouth = MOUTH_DARKENING * jaw * mouth_depth
    return (1.0 - (1.0 - dark) * (1.0 - mouth)).clamp(0.0, MAX_DARKENING)


@dataclass
class GTargets:
    """G's targets for a batch of (point, expression) pairs, in the network's output conventions."""

    rotation: torch.Tensor  # (B, 4) q_rel - (1, 0, 0, 0)
    scale: torch.Tensor  # (B, 3) log-scale offsets
    sh: torch.Tensor  # (B, 3) DC offsets


class HeadTargets:
    """Targets for points given by (triangle, barycentrics) on the ICT head (all torch, float32)."""

    def __init__(self, head: IctHead, tri: np.ndarray, bary: np.ndarray):
        self.head = head
        self.gaze = GazeModel(head.expression_names)
        self.faces = torch.from_numpy(head.faces)
        self.deltas = torch.from_numpy(head.deltas)  # (E, V, 3)
        self.tri = torch.from_numpy(np.asarray(tri, np.int64))
        self.bary = torch.from_numpy(np.asarray(bary, np.float32))
        corners = head.faces[tri]  # (N, 3)
        b = np.asarray(bary, np.float32)
        # per-point blendshape basis (N, E, 3)
        self.basis = torch.from_numpy(np.einsum("nc,encd->ned", b, head.deltas[:, corners]).astype(np.float32))
        self.rest = torch.from_numpy(np.einsum("nc,ncd->nd", b, head.vertices[corners]).astype(np.float32))
        eye = np.full(len(tri), -1, np.int64)
        for e, idx in enumerate(head.eye_vertices):
            eye[np.isin(corners, idx).all(axis=1)] = e
        self.eye = torch.from_numpy(eye)
        self.eye_centres = torch.from_numpy(head.eye_centres)

    def __len__(self) -> int:
        return int(self.tri.shape[0])

    def offsets(self, idx: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Position offsets (B, 3) in metres of points idx (B,) at weights w (B, E)."""
        d = torch.einsum("be,bec->bc", w, self.basis[idx])
        eye = self.eye[idx]
        on_eye = eye >= 0
        if on_eye.any():
            rot = self.gaze.rotations(w[on_eye])  # (M, 2, 3, 3)
            e = eye[on_eye]
            r = rot[torch.arange(len(e)), e]
            c = self.eye_centres[e]
            x0 = self.rest[idx[on_eye]]
            x = c + torch.einsum("mij,mj->mi", r, x0 + d[on_eye] - c)
            d[on_eye] = x - x0
        return d

    def unit_displacements(self) -> torch.Tensor:
        """Offsets (N, E, 3) of every point at weight 1 of each single shape (gaze included)."""
        out = self.basis.clone()
        idx = torch.nonzero(self.eye >= 0).flatten()
        e = self.head.n_expressions
        for k in range(e):
            w = torch.zeros(len(idx), e)
            w[:, k] = 1.0
            out[idx, k] = self.offsets(idx, w)
        return out


class VertexGradients:
    """Area-averaged deformation gradients of the ICT mesh per vertex: `[e1' e2' n'] [e1 e2 n]^-1` per triangle."""

    def __init__(self, head: IctHead, deltas: torch.Tensor | None = None, gaze: GazeModel | None = None):
        self.head = head
        self.deltas = torch.from_numpy(head.deltas) if deltas is None else deltas
        self.gaze = gaze or GazeModel(head.expression_names)
        self.faces = torch.from_numpy(head.faces)
        v0 = torch.from_numpy(head.vertices)
        frames0 = _frames(v0, self.faces).double()
        area = 0.5 * torch.linalg.cross(frames0[..., 0], frames0[..., 1]).norm(dim=-1)
        self.valid = area > 1e-12
        eye3 = torch.eye(3, dtype=torch.float64)
        safe = torch.where(self.valid[:, None, None], frames0, eye3)
        self.inv_frames = torch.linalg.inv(safe).float()  # (T, 3, 3)
        weight = torch.where(self.valid, area, torch.zeros_like(area)).float()
        vsum = torch.zeros(len(head.vertices))
        for c in range(3):
            vsum.index_add_(0, self.faces[:, c], weight)
        self.tri_weight = weight
        self.vertex_norm = 1.0 / vsum.clamp_min(1e-20)

    def __call__(self, w: torch.Tensor) -> torch.Tensor:
        """Gradients (B, V, 3, 3) at blendshape weights w (B, E) (gaze rotation included)."""
        v = pose_vertices(self.head, w, self.deltas, self.gaze)
        ft = _frames(v, self.faces) @ self.inv_frames  # (B, T, 3, 3)
        ft = torch.where(self.valid[None, :, None, None], ft, torch.eye(3)) * self.tri_weight[None, :, None, None]
        b = w.shape[0]
        fv = torch.zeros(b, self.vertex_norm.shape[0], 9)
        flat = ft.reshape(b, -1, 9)
        for c in range(3):
            fv.index_add_(1, self.faces[:, c], flat)
        return (fv * self.vertex_norm[None, :, None]).reshape(b, -1, 3, 3)


def min_stretch(stretched: torch.Tensor) -> torch.Tensor:
    """Smallest principal stretch in the tangent plane of deformed tangent axes (B, 3, 2): the square root of the
    smaller eigenvalue of their 2x2 metric."""
    g = stretched.transpose(1, 2) @ stretched
    tr, det2 = g[:, 0, 0] + g[:, 1, 1], g[:, 0, 0] * g[:, 1, 1] - g[:, 0, 1] ** 2
    return (0.5 * (tr - (tr * tr - 4 * det2).clamp_min(0.0).sqrt())).clamp_min(1e-8).sqrt()


class AppearanceTargets(HeadTargets):
    """G's targets: frame rotation, axis stretch and colour darkening of points with known disc frames."""

    def __init__(self, head: IctHead, tri: np.ndarray, bary: np.ndarray, frames: np.ndarray, colour: np.ndarray,
                 part: np.ndarray, dc_scale: float):
        super().__init__(head, tri, bary)
        self.axes = torch.from_numpy(np.ascontiguousarray(frames[:, :, :2], np.float32))  # (N, 3, 2) tangent axes
        # DC colour that the darkening scales (the head-on colour times the DC share, see colors.colours_to_sh)
        self.dc_colour = torch.from_numpy((np.asarray(colour) * dc_scale).astype(np.float32))
        weights = shading_weights(head, self.rest.numpy(), part)
        self.stripe_weight, self.stripe = weights["stripe_weight"], weights["stripe"]
        self.skin, self.mouth_depth = weights["skin"], weights["mouth_depth"]
        self.jaw = head.expression_index("jawOpen")
        self.gradients = VertexGradients(head, self.deltas, self.gaze)

    def vertex_gradients(self, w: torch.Tensor) -> torch.Tensor:
        """Area-averaged deformation gradients (B, V, 3, 3) of the mesh at weights w (B, E)."""
        return self.gradients(w)

    def g_targets(self, idx: torch.Tensor, expr: torch.Tensor, w: torch.Tensor, fv: torch.Tensor) -> GTargets:
        """Targets of points idx (B,) at expressions expr (B,), which index the rows of w (M, E) and of
        `vertex_gradients(w)` (the gradients `fv`)."""
        corners = self.faces[self.tri[idx]]  # (B, 3)
        fg = (fv[expr[:, None], corners] * self.bary[idx][:, :, None, None]).sum(dim=1)  # (B, 3, 3)
        det = torch.linalg.det(fg)
        fg = torch.where((det > 1e-6)[:, None, None], fg, torch.eye(3))
        rot = polar_rotation(fg)
        q = matrix_to_quat(rot)
        d_rot = q - torch.tensor([1.0, 0.0, 0.0, 0.0])
        stretched = fg @ self.axes[idx]  # (B, 3, 2)
        lengths = stretched.norm(dim=1).clamp_min(1e-4)
        d_scale = torch.cat([lengths.log(), torch.zeros(len(idx), 1)], dim=1)
        dark = darkening(min_stretch(stretched), w[expr, self.jaw], self.skin[idx], self.stripe_weight[idx],
                         self.stripe[idx], self.mouth_depth[idx])
        d_sh = -dark[:, None] * self.dc_colour[idx] / SH_C0
        return GTargets(d_rot, d_scale, d_sh)
