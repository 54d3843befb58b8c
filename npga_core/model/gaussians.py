"""Gaussian clouds: the canonical cloud of an avatar and a posed cloud ready to render.

Storage conventions (shared by the `.npga` format, PLY and the renderer):

- quaternions are (w, x, y, z), not necessarily normalised in storage;
- scales are stored as natural logs, opacities as logits;
- SH coefficients are (N, (degree+1)**2, 3), coefficient-major then RGB, with the 3DGS meaning
  (colour = SH . basis(view dir) + 0.5, clamped at 0).

`PER_GAUSSIAN_FIELDS` is the one list of every array that has a row per Gaussian; subset, concat,
deletion and the checkpoint writer all iterate it, so nothing is forgotten when Gaussians go.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

SH_C0 = 0.28209479177387814

#: Every per-Gaussian array of a canonical cloud, in file order. Optional ones may be None.
PER_GAUSSIAN_FIELDS: tuple[str, ...] = (
    "means",
    "quats",
    "log_scales",
    "opacity_logits",
    "sh",
    "features",
    "latent",
    "part_ids",
    "blend_weights",
)
OPTIONAL_FIELDS: frozenset[str] = frozenset({"latent", "part_ids", "blend_weights"})


def sh_coeff_count(degree: int) -> int:
    """Number of SH coefficients per channel for a degree 0..3."""
    return (degree + 1) ** 2


def sh_degree_from_count(count: int) -> int:
    """Inverse of `sh_coeff_count`; raises ValueError for counts that are not (d+1)^2 with d <= 3."""
    for d in range(4):
        if (d + 1) ** 2 == count:
            return d
    raise ValueError(f"{count} SH coefficients is not (degree+1)^2 for a degree 0..3")


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Numerically stable logistic function."""
    x = np.asarray(x, dtype=np.float32)
    return (0.5 * (np.tanh(0.5 * x) + 1.0)).astype(np.float32)


def logit(p: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Inverse of `sigmoid`, clipped away from 0 and 1."""
    p = np.clip(np.asarray(p, dtype=np.float64), eps, 1.0 - eps)
    return np.log(p / (1.0 - p)).astype(np.float32)


def normalize_quats(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z); zero-length rows become the identity."""
    q = np.asarray(q, dtype=np.float32)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    out = np.where(n > 1e-12, q / np.maximum(n, 1e-12), np.array([1, 0, 0, 0], np.float32))
    return out.astype(np.float32)


def rgb_to_sh0(rgb: np.ndarray) -> np.ndarray:
    """DC SH coefficient giving colour `rgb` (in [0, 1]) under the 3DGS convention."""
    return ((np.asarray(rgb, dtype=np.float32) - 0.5) / SH_C0).astype(np.float32)


@dataclass
class GaussianCloud:
    """The canonical Gaussians of an avatar (or a static 3DGS scene).

    Arrays are float32 except `part_ids` (int16). `latent` (the CNN features h) and `part_ids` may be None.
    Arrays coming from a checkpoint may be read-only memory maps: edits build new arrays.
    """

    means: np.ndarray  # (N, 3)
    quats: np.ndarray  # (N, 4) w, x, y, z
    log_scales: np.ndarray  # (N, 3)
    opacity_logits: np.ndarray  # (N,)
    sh: np.ndarray  # (N, K, 3)
    features: np.ndarray  # (N, F), F may be 0
    latent: np.ndarray | None = None  # (N, H)
    part_ids: np.ndarray | None = None  # (N,) int16 index into part_names, -1 = none
    part_names: list[str] = field(default_factory=list)
    blend_weights: np.ndarray | None = None  # (N, B) per-Gaussian weights of blended networks, in [0, 1]
    blend_names: list[str] = field(default_factory=list)  # the B names networks refer to

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        for name in PER_GAUSSIAN_FIELDS:
            arr = getattr(self, name)
            if arr is None:
                if name not in OPTIONAL_FIELDS:
                    raise ValueError(f"GaussianCloud.{name} is required")
                continue
            if arr.shape[0] != n:
                raise ValueError(f"GaussianCloud.{name} has {arr.shape[0]} rows, means has {n}")
        sh_degree_from_count(self.sh.shape[1])
        if (self.blend_weights is None) != (not self.blend_names) or (
                self.blend_weights is not None and self.blend_weights.shape[1:] != (len(self.blend_names),)):
            raise ValueError("GaussianCloud.blend_weights needs one column per blend name")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_count(self.sh.shape[1])

    @property
    def feature_dim(self) -> int:
        return int(self.features.shape[1])

    @property
    def latent_dim(self) -> int:
        return 0 if self.latent is None else int(self.latent.shape[1])

    def arrays(self) -> dict[str, np.ndarray]:
        """The present per-Gaussian arrays by field name."""
        return {k: getattr(self, k) for k in PER_GAUSSIAN_FIELDS if getattr(self, k) is not None}

    def subset(self, index: np.ndarray) -> GaussianCloud:
        """A new cloud with the rows selected by an index or boolean mask (arrays are copied)."""
        index = np.asarray(index)
        kw: dict[str, Any] = {k: (None if v is None else np.ascontiguousarray(v[index]))
                              for k, v in self._fields().items()}
        return replace(self, **kw)

    def copy(self) -> GaussianCloud:
        """A deep, writable copy."""
        return self.subset(np.arange(len(self)))

    def _fields(self) -> dict[str, np.ndarray | None]:
        return {k: getattr(self, k) for k in PER_GAUSSIAN_FIELDS}

    @staticmethod
    def concat(clouds: list[GaussianCloud]) -> GaussianCloud:
        """Stack clouds with the same layout (SH degree, feature widths, parts)."""
        if not clouds:
            raise ValueError("nothing to concatenate")
        first = clouds[0]
        kw: dict[str, Any] = {}
        for name in PER_GAUSSIAN_FIELDS:
            parts = [getattr(c, name) for c in clouds]
            if all(p is None for p in parts):
                kw[name] = None
            elif any(p is None for p in parts):
                raise ValueError(f"cannot concatenate clouds where only some have {name}")
            else:
                kw[name] = np.concatenate(parts, axis=0)
        if any(c.blend_names != first.blend_names for c in clouds):
            raise ValueError("cannot concatenate clouds with different blend weights")
        return GaussianCloud(**kw, part_names=list(first.part_names), blend_names=list(first.blend_names))

    def posed_static(self) -> PosedGaussians:
        """Activated attributes without any dynamics (the canonical pose)."""
        return PosedGaussians(
            means=np.ascontiguousarray(self.means, dtype=np.float32),
            quats=normalize_quats(self.quats),
            scales=np.exp(np.asarray(self.log_scales, dtype=np.float32)),
            opacities=sigmoid(self.opacity_logits),
            sh=np.ascontiguousarray(self.sh, dtype=np.float32),
            latent=None if self.latent is None else np.ascontiguousarray(self.latent, dtype=np.float32),
        )


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """The 3D covariances R S S^T R^T as (6, N) float32 rows xx, xy, xz, yy, yz, zz, from (w, x, y, z)
    quaternions (normalised here, as 3DGS does) and scales, as the renderers' pre-pass builds them
    (the 4.1 path's CPU pre-pass and the level-of-detail merge use this one)."""
    q = np.asarray(quats, np.float32).reshape(-1, 4)
    s = np.asarray(scales, np.float32).reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = q / np.sqrt(np.einsum("ni,ni->n", q, q))[:, None]
    w, x, y, z = (np.ascontiguousarray(q[:, i]) for i in range(4))
    r = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
         (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
         (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))
    s2 = [s[:, i] * s[:, i] for i in range(3)]
    out = np.empty((6, len(q)), np.float32)
    for row, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        out[row] = r[i][0] * r[j][0] * s2[0] + r[i][1] * r[j][1] * s2[1] + r[i][2] * r[j][2] * s2[2]
    return out


@dataclass
class PosedGaussians:
    """Activated attributes of Gaussians at one expression: what the renderer draws.

    means (N,3); quats (N,4) unit (w,x,y,z); scales (N,3) > 0 (linear, not log); opacities (N,) in [0,1];
    sh (N,K,3) raw SH coefficients (3DGS convention); latent (N,H) or None. All float32, C-contiguous.
    """

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    latent: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_count(self.sh.shape[1])

    def subset(self, index: np.ndarray) -> PosedGaussians:
        """Rows selected by an index or mask."""
        kw: dict[str, Any] = {f.name: (None if getattr(self, f.name) is None else getattr(self, f.name)[index])
                              for f in fields(self)}
        return PosedGaussians(**kw)

