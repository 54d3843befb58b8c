"""`LinearRig`: named linear blendshapes on an avatar's points, then a rigid transform of the centres.

A rig is the part of an avatar's dynamics that is linear in named channel weights (the 51 or 52 ARKit names,
for instance), as LAM's avatars are (its player, ``gaussian-splat-renderer-for-lam``, poses them this way):

    runtime weight   v_k = scale_k * w_k + bias_k                      (per channel; no clamping)
    displacement     d_i = sum_k v_k * delta_k,i                        (per point, sparse: rows of `support`)
    centre           mu_i' = M (mu_i + d_i)                             (M: the rest transform, 4x4)

The points are the Gaussians themselves (``carrier="gaussian"``) or each Gaussian's own mesh vertex
(``carrier="vertex"``, LAM: mu_i = vertex_i + offset_i, and the vertex carries the Gaussian rigidly, so the
displacement is the vertex's), or the vertices of a skinned mesh whose triangles carry the Gaussians
(``carrier="triangle"``, GaussianAvatars' FLAME: `skin` holds the joints, skinning weights, pose correctives,
triangles and each Gaussian's triangle; `npga_core.model.skinning`). With `turns_covariance` false (LAM) the
transform moves the centres only, as its player does; rotations, scales, opacity and colour stay.

The frame vector of an avatar with a rig is ``[network code, condition, rig inputs]``, the inputs being the K
channel weights and, with a skin, 3 per joint (axis-angle) and a translation (`input_names`); an avatar with only
a rig has ``[rig inputs]``. Posing code adds `attribute_offsets` (position; with a skin also rotation, composed,
and log scale) into the offsets like any network's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from npga_core.model.skinning import FaceMotion, Skin

CARRIERS = ("gaussian", "vertex", "triangle")
#: Carriers the format names and this reader refuses (none since format version 5 implemented "triangle").
RESERVED_CARRIERS: tuple[str, ...] = ()


@dataclass
class LinearRig:
    """Sparse named blendshapes with per-channel runtime scale and bias, and a rest transform of the centres."""

    channels: tuple[str, ...]
    support: np.ndarray  # (S,) int64 ascending rows that any channel moves
    deltas: np.ndarray  # (K, S, 3) float32 displacement per channel at weight 1 (after scale)
    n_points: int
    scale: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # (K,) runtime scale (empty: ones)
    bias: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # (K,) runtime bias (empty: zeros)
    carrier: str = "gaussian"
    vertices: np.ndarray | None = None  # (N, 3) rest positions of the carrying vertices (carrier "vertex")
    transform: np.ndarray = field(default_factory=lambda: np.eye(4, dtype=np.float64))
    turns_covariance: bool = False
    source: str = ""
    notes: dict[str, str] = field(default_factory=dict)  # what the source's runtime does that this rig records
    skin: Skin | None = None  # carrier "triangle": the mesh's skinning and the Gaussians' triangles
    _torch: tuple | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        k = len(self.channels)
        self.channels = tuple(str(c) for c in self.channels)
        if k == 0 or len(set(self.channels)) != k:
            raise ValueError("a rig needs at least one channel and distinct channel names")
        self.support = np.ascontiguousarray(self.support, np.int64).reshape(-1)
        self.deltas = np.ascontiguousarray(self.deltas, np.float32)
        s = len(self.support)
        if self.deltas.shape != (k, s, 3):
            raise ValueError(f"rig deltas have shape {self.deltas.shape}, expected ({k}, {s}, 3)")
        if s and (self.support[0] < 0 or self.support[-1] >= self.n_points or np.any(np.diff(self.support) <= 0)):
            raise ValueError(f"rig support rows must be ascending, distinct and within 0..{self.n_points - 1}")
        self.scale = np.ones(k, np.float32) if np.size(self.scale) == 0 else np.asarray(self.scale, np.float32)
        self.bias = np.zeros(k, np.float32) if np.size(self.bias) == 0 else np.asarray(self.bias, np.float32)
        if self.scale.shape != (k,) or self.bias.shape != (k,):
            raise ValueError(f"rig scale and bias must have {k} values")
        if self.carrier not in CARRIERS:
            raise ValueError(f"rig carrier {self.carrier!r} is not one of {', '.join(CARRIERS)}")
        if self.vertices is not None:
            self.vertices = np.ascontiguousarray(self.vertices, np.float32)
            if self.vertices.shape != (self.n_points, 3):
                raise ValueError(f"rig vertices have shape {self.vertices.shape}, expected ({self.n_points}, 3)")
        self.transform = np.asarray(self.transform, np.float64)
        if self.transform.shape != (4, 4) or not np.allclose(self.transform[3], [0, 0, 0, 1]):
            raise ValueError("the rig transform must be an affine 4x4 matrix")
        for name in ("deltas", "scale", "bias", "transform"):
            a = getattr(self, name)
            if a.size and not np.isfinite(a).all():
                raise ValueError(f"rig {name} has NaN/Inf values")
        if self.vertices is not None and not np.isfinite(self.vertices).all():
            raise ValueError("rig vertices have NaN/Inf values")
        self._check_skin()

    def _check_skin(self) -> None:
        """ValueError unless a skin comes exactly with carrier "triangle" and fits the rig."""
        k = self.n_channels
        if (self.carrier == "triangle") != (self.skin is not None):
            raise ValueError("a skin goes with carrier 'triangle' and only with it")
        if self.skin is not None:
            if self.vertices is None or self.skin.n_vertices != self.n_points:
                raise ValueError(f"a triangle rig needs the rest positions of its {self.n_points} mesh vertices "
                                 "and a skin of as many")
            if self.skin.joint_deltas.shape[0] != k or not self.identity_transform:
                raise ValueError(f"a triangle rig needs joint deltas for its {k} channels and no rest transform")

    @property
    def n_inputs(self) -> int:
        """Width of the rig's part of the frame vector: the channel weights, then the skin's pose inputs."""
        return self.n_channels + (0 if self.skin is None else self.skin.pose_dim)

    @property
    def input_names(self) -> tuple[str, ...]:
        return self.channels + (() if self.skin is None else self.skin.input_names())

    @property
    def n_gaussians(self) -> int | None:
        """How many Gaussians the rig poses when its points are not the Gaussians (None: `n_points`)."""
        return None if self.skin is None else len(self.skin.binding)

    @property
    def attributes(self) -> dict[str, int]:
        """The offsets the rig outputs and their widths."""
        return {"position": 3} if self.skin is None else {"position": 3, "rotation": 4, "scale": 3}

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def identity_transform(self) -> bool:
        return bool(np.array_equal(self.transform, np.eye(4)))

    def runtime_weights(self, w: np.ndarray | torch.Tensor, linear: bool = False) -> torch.Tensor:
        """v = scale * w + bias, float32 (K,) (without the bias when `linear`: a direction's derivative)."""
        wt = torch.as_tensor(np.asarray(w, np.float32)).reshape(-1)
        _, _, scale, bias, _ = self._tensors()
        return wt * scale if linear else wt * scale + bias

    def _tensors(self) -> tuple:
        if self._torch is None:
            flat = torch.from_numpy(self.deltas.reshape(self.n_channels, -1))
            where = np.full(self.n_points, -1, np.int64)
            where[self.support] = np.arange(len(self.support))
            self._torch = (flat, torch.from_numpy(self.support), torch.from_numpy(self.scale),
                           torch.from_numpy(self.bias), torch.from_numpy(where))
        return self._torch

    def offsets(self, w: np.ndarray | torch.Tensor, rows: slice | np.ndarray | None = None,
                linear: bool = False, runtime: bool = False) -> torch.Tensor:
        """Position displacements (m, 3) of the points `rows` (a slice, an index array or all) at weights w
        (`linear`: without the channels' bias, the change along a direction w; `runtime`: w are runtime weights)."""
        flat, support, _, _, where = self._tensors()
        v = torch.as_tensor(w) if runtime else self.runtime_weights(w, linear)
        if rows is None:
            rows = slice(0, self.n_points)
        if isinstance(rows, slice):
            s, e, _ = rows.indices(self.n_points)
            out = torch.zeros(max(e - s, 0), 3)
            a, b = np.searchsorted(self.support, [s, e])
            if b > a:
                part = (v @ flat[:, 3 * a : 3 * b]).view(b - a, 3)
                out.index_add_(0, support[a:b] - s, part)
            return out
        index = torch.as_tensor(np.asarray(rows, np.int64))
        out = torch.zeros(len(index), 3)
        pos = where[index]
        hit = torch.nonzero(pos >= 0).reshape(-1)
        if len(hit):
            cols = (3 * pos[hit])[:, None] + torch.arange(3)
            out[hit] = (v @ flat[:, cols.reshape(-1)]).view(-1, 3)
        return out

    def frame(self, inputs: np.ndarray | torch.Tensor) -> torch.Tensor | FaceMotion:
        """What one frame's offsets are computed from: the runtime weights, or with a skin each face's motion."""
        x = np.asarray(inputs, np.float32).reshape(-1)
        if self.skin is None:
            return self.runtime_weights(x)
        assert self.vertices is not None
        w = self.runtime_weights(x[: self.n_channels])
        rest = torch.from_numpy(self.vertices)
        posed = self.skin.posed_vertices(rest, self.offsets(w, None, runtime=True), w.numpy(), x[self.n_channels :])
        return self.skin.face_motion(posed, self.vertices)

    def reference_frame(self, inputs: np.ndarray) -> FaceMotion:
        """`frame` of a skinned rig by the reference path (numpy, float64: `Skin.mesh`, `Skin.motion`)."""
        x = np.asarray(inputs, np.float32).reshape(-1)
        assert self.skin is not None and self.vertices is not None
        w = self.runtime_weights(x[: self.n_channels]).numpy()
        posed = self.skin.mesh(self.vertices, self.deltas, self.support, w, x[self.n_channels :])
        return self.skin.motion(posed, self.vertices)

    def attribute_offsets(self, frame: torch.Tensor | FaceMotion, rows: slice | np.ndarray | None,
                          means: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Offsets by attribute (`attributes`) of the Gaussians `rows` at a `frame`; `means`: their canonical
        centres (needed with a skin)."""
        if isinstance(frame, FaceMotion):
            assert self.skin is not None and means is not None
            return self.skin.offsets(frame, slice(0, len(self.skin.binding)) if rows is None else rows, means)
        return {"position": self.offsets(frame, rows, runtime=True)}

    def dense_deltas(self) -> np.ndarray:
        """(K, N, 3) float32 displacement of every point per unit runtime weight (for inspection)."""
        out = np.zeros((self.n_channels, self.n_points, 3), np.float32)
        out[:, self.support] = self.deltas
        return out

    def move_centres(self, means: np.ndarray) -> np.ndarray:
        """Centres (N, 3) through the rest transform (a copy; unchanged values for the identity)."""
        if self.identity_transform:
            return means
        m = self.transform
        return (np.asarray(means, np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)

    def describe(self) -> str:
        """One line for `info`."""
        moved = len(self.support)
        scaled = int(np.count_nonzero(self.scale != 1.0)) + int(np.count_nonzero(self.bias))
        carried = {"vertex": "carried by their own mesh vertex", "gaussian": "carried by the Gaussians",
                   "triangle": "the vertices of a skinned mesh"}[self.carrier]
        parts = [f"{self.n_channels} linear blendshape channels on {self.n_points:,} points ({carried}; "
                 f"{moved:,} moved by some channel)"]
        if self.skin is not None:
            sk = self.skin
            parts.append(f"{len(sk.joint_names)} joints ({', '.join(sk.joint_names)}) by linear blend skinning "
                         f"with pose correctives, then a translation; {len(sk.binding):,} Gaussians on "
                         f"{len(sk.faces):,} triangles (position, rotation and scale follow each triangle)")
        if scaled:
            parts.append(f"{scaled} channels rescaled at run time (weight x scale + bias, not clamped)")
        parts.append("rest transform: identity" if self.identity_transform else
                     "rest transform of the centres" + ("" if self.turns_covariance else " (covariances static)"))
        return "; ".join(parts)
