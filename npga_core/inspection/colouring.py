"""Colour maps and per-Gaussian colourings: what an inspection mode draws and what its legend needs.

`Colouring` holds an RGB in [0, 1] per Gaussian plus the scalar, range and label behind it; `colour_map`
evaluates viridis, turbo, coolwarm and grey; `FeaturePCA` maps feature vectors to RGB by their first three
principal components. Used by `inspect.Inspector` and by the legend of `npga-view render`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# --- colour maps -----------------------------------------------------------------------------------------
# Polynomial fits, evaluated by Horner's rule in t in [0, 1]: viridis by Matt Zucker (CC0, within ~0.01 of
# matplotlib's table) and turbo by Anton Mikhailov (Google, Apache-2.0; darker than the turbo table at both
# ends); coefficients of t^0 .. t^6 / t^5.
_VIRIDIS = np.array([
    [0.2777273272234177, 0.005407344544966578, 0.3340998053353061],
    [0.1050930431085774, 1.404613529898575, 1.384590162594685],
    [-0.3308618287255563, 0.214847559468213, 0.09509516302823659],
    [-4.634230498983486, -5.799100973351585, -19.33244095627987],
    [6.228269936347081, 14.17993336680509, 56.69055260068105],
    [4.776384997670288, -13.74514537774601, -65.35303263337234],
    [-5.435455855934631, 4.645852612178535, 26.3124352495832],
])
_TURBO = np.array([
    [0.13572138, 0.09140261, 0.10667330],
    [4.61539260, 2.19418839, 12.64194608],
    [-42.66032258, 4.84296658, -60.58204836],
    [132.13108234, -14.18503333, 110.36276771],
    [-152.94239396, 4.27729857, -89.90310912],
    [59.28637943, 2.82956604, 27.34824973],
])
# diverging blue - light grey - red (the end and middle colours of K. Moreland's cool-warm map), piecewise linear
_COOLWARM = np.array([[0.230, 0.299, 0.754], [0.865, 0.865, 0.865], [0.706, 0.016, 0.150]])

#: Colour map names; append "_r" to reverse one.
COLOUR_MAPS: tuple[str, ...] = ("viridis", "turbo", "coolwarm", "grey")
NAN_COLOUR = (0.5, 0.5, 0.5)


def colour_map(t: np.ndarray, name: str = "viridis") -> np.ndarray:
    """RGB (..., 3) float32 in [0, 1] of values t (clipped to [0, 1]; NaN gives grey) under a named map."""
    base = name[:-2] if name.endswith("_r") else name
    if base not in COLOUR_MAPS:
        raise ValueError(f"unknown colour map {name!r}; choose from {', '.join(COLOUR_MAPS)} (or NAME_r)")
    t = np.asarray(t, dtype=np.float64)
    nan = ~np.isfinite(t)
    t = np.clip(np.where(nan, 0.0, t), 0.0, 1.0)
    if name.endswith("_r"):
        t = 1.0 - t
    if base in ("viridis", "turbo"):
        coeffs = _VIRIDIS if base == "viridis" else _TURBO
        rgb = np.zeros(t.shape + (3,))
        for c in coeffs[::-1]:
            rgb = rgb * t[..., None] + c
    elif base == "coolwarm":
        rgb = np.stack([np.interp(t, [0.0, 0.5, 1.0], _COOLWARM[:, i]) for i in range(3)], axis=-1)
    else:
        rgb = np.repeat(t[..., None], 3, axis=-1)
    rgb[nan] = NAN_COLOUR
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def robust_range(values: np.ndarray, percentiles: tuple[float, float] = (1.0, 99.0),
                 symmetric: bool = False) -> tuple[float, float]:
    """(lo, hi) of the finite values at the given percentiles; symmetric: (-m, m) with m the upper percentile of
    |values|. An empty or constant input gives a range of width 1e-9 or more around it."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (0.0, 1.0)
    if symmetric:
        m = float(np.percentile(np.abs(v), percentiles[1]))
        lo, hi = -m, m
    else:
        lo, hi = (float(x) for x in np.percentile(v, percentiles))
    if hi - lo < 1e-9:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 5e-10 - 1e-6 * abs(mid), mid + 5e-10 + 1e-6 * abs(mid)
    return lo, hi


@dataclass
class Colouring:
    """Per-Gaussian colours of a mode and what its legend shows."""

    rgb: np.ndarray  # (N, 3) float32 in [0, 1]
    label: str  # what the colour encodes, with units
    values: np.ndarray | None = None  # (N,) the scalar behind a colour map; None for direct RGB (PCA)
    lo: float = 0.0  # value at the low end of the colour map
    hi: float = 1.0
    cmap: str | None = None  # None: `rgb` is not a colour map of `values`
    notes: tuple[str, ...] = ()  # extra legend lines


def scalar_colouring(values: np.ndarray, label: str, cmap: str = "viridis",
                     value_range: tuple[float, float] | None = None, symmetric: bool = False) -> Colouring:
    """Colour a scalar per Gaussian: rgb = cmap((v - lo) / (hi - lo)), range robust unless given."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    lo, hi = value_range if value_range is not None else robust_range(v, symmetric=symmetric)
    t = (v - lo) / (hi - lo) if hi != lo else np.full_like(v, 0.5)
    return Colouring(colour_map(t, cmap), label, v.astype(np.float32), float(lo), float(hi), cmap)


# --- PCA colours ------------------------------------------------------------------------------------------
@dataclass
class FeaturePCA:
    """First three principal axes of per-Gaussian vectors and the range of each projection."""

    mean: np.ndarray  # (D,)
    axes: np.ndarray  # (3, D) orthonormal rows (zero rows when D < 3), largest |entry| of each positive
    lo: np.ndarray  # (3,) 1st percentile of each projection
    hi: np.ndarray  # (3,) 99th percentile
    explained: np.ndarray  # (3,) fraction of the total variance along each axis

    @staticmethod
    def fit(x: np.ndarray, percentiles: tuple[float, float] = (1.0, 99.0)) -> FeaturePCA:
        """PCA of x (N, D) by the eigen-decomposition of its covariance."""
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] == 0 or x.shape[0] < 2:
            raise ValueError(f"need vectors of shape (N >= 2, D >= 1) for a PCA, got {x.shape}")
        mean = x.mean(axis=0)
        cov = np.cov(x - mean, rowvar=False).reshape(x.shape[1], x.shape[1])
        w, v = np.linalg.eigh(cov)
        order = np.argsort(w)[::-1][:3]
        axes = np.zeros((3, x.shape[1]))
        axes[: len(order)] = v[:, order].T
        for a in axes:
            if np.any(a):
                a *= np.sign(a[np.abs(a).argmax()])
        explained = np.zeros(3)
        explained[: len(order)] = np.maximum(w[order], 0.0) / max(float(np.maximum(w, 0).sum()), 1e-30)
        proj = (x - mean) @ axes.T
        lo, hi = np.percentile(proj, percentiles, axis=0)
        hi = np.where(hi - lo < 1e-12, lo + 1.0, hi)
        return FeaturePCA(mean, axes, lo, hi, explained)

    def project(self, x: np.ndarray) -> np.ndarray:
        """Coordinates (N, 3) along the three axes."""
        return (np.asarray(x, dtype=np.float64) - self.mean) @ self.axes.T

    def colours(self, x: np.ndarray) -> np.ndarray:
        """RGB (N, 3): each coordinate mapped from [lo, hi] to [0, 1] (0.5 for missing axes)."""
        t = (self.project(x) - self.lo) / (self.hi - self.lo)
        t[:, ~np.any(self.axes, axis=1)] = 0.5
        return np.clip(t, 0.0, 1.0).astype(np.float32)


def pca_colouring(x: np.ndarray, pca: FeaturePCA, name: str) -> Colouring:
    """`features` / `latent` mode: RGB = the first three principal components of `name`."""
    e = pca.explained * 100.0
    note = f"R, G, B = PC 1, 2, 3 of {name} ({e[0]:.0f} %, {e[1]:.0f} %, {e[2]:.0f} % of the variance)"
    return Colouring(pca.colours(x), f"PCA of {name}", notes=(note,))


# --- modes on offsets -------------------------------------------------------------------------------------
