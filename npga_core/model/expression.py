"""The expression space of an avatar: mean code, PCA basis, per-component std, named expressions.

Slider values are in standard deviations along the PCA directions:
``z = mean + sum_k s_k * std_k * basis_k`` and back ``s = basis (z - mean) / std``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Range of a PCA standard deviation and largest magnitude of a code value (shared with
#: npga_core.files.untrusted, which checks every number read against these).
STD_RANGE = (1e-6, 1e4)
MAX_CODE = 1e4


@dataclass
class ExpressionSpace:
    """PCA statistics of expression codes (computed from training or tracked codes)."""

    mean: np.ndarray  # (D,)
    basis: np.ndarray  # (K, D), orthonormal rows, sorted by decreasing variance
    std: np.ndarray  # (K,), > 0
    named: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (D,) code

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    @property
    def n_components(self) -> int:
        return int(self.basis.shape[0])

    @staticmethod
    def from_codes(codes: np.ndarray, n_components: int | None = None, min_std: float = 1e-8) -> ExpressionSpace:
        """PCA of codes (T, D); keeps up to `n_components` directions with non-negligible variance."""
        codes = np.asarray(codes, dtype=np.float64)
        if codes.ndim != 2 or codes.shape[0] < 2:
            raise ValueError(f"need codes of shape (T>=2, D), got {codes.shape}")
        mean = codes.mean(axis=0)
        _, s, vt = np.linalg.svd(codes - mean, full_matrices=False)
        std = s / np.sqrt(codes.shape[0] - 1)
        keep = (std > min_std * max(1.0, float(std[0]) if std.size else 1.0)) & (std >= STD_RANGE[0])
        if n_components is not None:
            keep &= np.arange(std.size) < n_components
        vt, std = vt[keep], std[keep]
        # deterministic sign: the largest-magnitude entry of each direction is positive
        signs = np.sign(vt[np.arange(vt.shape[0]), np.abs(vt).argmax(axis=1)])
        vt *= signs[:, None]
        return ExpressionSpace(mean.astype(np.float32), vt.astype(np.float32), std.astype(np.float32))

    def to_sliders(self, z: np.ndarray) -> np.ndarray:
        """Project codes (..., D) onto the basis, in std units (..., K)."""
        return ((np.asarray(z, np.float32) - self.mean) @ self.basis.T) / self.std

    def from_sliders(self, s: np.ndarray) -> np.ndarray:
        """Codes (..., D) from slider values (..., K') with K' <= K (missing components are 0)."""
        s = np.asarray(s, np.float32)
        k = s.shape[-1]
        if k > self.n_components:
            raise ValueError(f"{k} slider values but only {self.n_components} PCA components")
        return self.mean + (s * self.std[:k]) @ self.basis[:k]

    def sample(self, rng: np.random.Generator, k: int | None = None, scale: float = 1.0) -> np.ndarray:
        """A random code: independent normal slider values on the first k components."""
        k = self.n_components if k is None else min(k, self.n_components)
        return self.from_sliders(rng.standard_normal(k).astype(np.float32) * scale)

    def validate(self) -> None:
        """Raise ValueError if shapes or values are inconsistent."""
        d = self.dim
        if self.mean.ndim != 1 or self.basis.ndim != 2 or self.basis.shape[1] != d:
            raise ValueError(f"basis has shape {self.basis.shape}, mean has {self.mean.shape}")
        if self.std.shape != (self.basis.shape[0],):
            raise ValueError(f"std has shape {self.std.shape}, expected ({self.basis.shape[0]},)")
        lo, hi = STD_RANGE
        if not np.all((self.std >= lo) & (self.std <= hi)):
            raise ValueError(f"std has values outside [{lo:g}, {hi:g}] (they scale the sliders both ways)")
        for what, a in (("mean", self.mean), ("basis", self.basis), *((f"named expression {n!r}", c)
                                                                        for n, c in self.named.items())):
            if not np.all(np.abs(a) <= MAX_CODE):
                raise ValueError(f"{what} has values that are NaN/Inf or beyond +-{MAX_CODE:g}")
        gram = self.basis.astype(np.float64) @ self.basis.T.astype(np.float64)
        if self.basis.shape[0] and np.abs(gram - np.eye(gram.shape[0])).max() > 1e-3:
            raise ValueError("PCA basis rows are not orthonormal")
        for name, code in self.named.items():
            if code.shape != (d,):
                raise ValueError(f"named expression {name!r} has shape {code.shape}, expected ({d},)")
