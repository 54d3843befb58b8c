"""The fixed linear map between the demo's 100-D expression codes z and the 53 blendshape weights w.

``z = M w + b`` with M (100 x 53) having orthonormal columns (the first 53 columns of a random rotation,
from the QR decomposition of a seeded Gaussian matrix) and b a seeded random offset, so a code is a latent
vector, not one slider per blendshape. Because M^T M = I, ``w = M^T (z - b)`` recovers the weights exactly
for codes in the image of the map and is the least-squares weight vector for any other code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CODE_DIM = 100
OFFSET_STD = 0.25


@dataclass(frozen=True)
class ExpressionMap:
    """``z = matrix @ w + offset`` and back; `names` label the columns (blendshapes)."""

    matrix: np.ndarray  # (D, E) float32 with orthonormal columns
    offset: np.ndarray  # (D,) float32
    names: tuple[str, ...]

    @staticmethod
    def from_seed(seed: int, names: list[str] | tuple[str, ...], code_dim: int = CODE_DIM) -> ExpressionMap:
        """The map for a seed: deterministic, independent of anything else."""
        e = len(names)
        if code_dim < e:
            raise ValueError(f"code_dim {code_dim} is smaller than the {e} blendshapes")
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED_E4A9]))
        q, r = np.linalg.qr(rng.standard_normal((code_dim, code_dim)))
        q *= np.sign(np.diag(r))  # Haar-distributed rotation
        offset = OFFSET_STD * rng.standard_normal(code_dim)
        return ExpressionMap(q[:, :e].astype(np.float32), offset.astype(np.float32), tuple(names))

    @property
    def code_dim(self) -> int:
        return int(self.matrix.shape[0])

    def encode(self, w: np.ndarray) -> np.ndarray:
        """Codes (..., D) of weights (..., E)."""
        return (np.asarray(w, np.float32) @ self.matrix.T + self.offset).astype(np.float32)

    def decode(self, z: np.ndarray) -> np.ndarray:
        """Weights (..., E) of codes (..., D) (least squares; exact for encoded weights)."""
        return ((np.asarray(z, np.float32) - self.offset) @ self.matrix).astype(np.float32)
