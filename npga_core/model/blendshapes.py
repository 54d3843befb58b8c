"""`BlendshapeBasis`: an avatar's linear map from named blendshape weights to its expression code.

``code = offset + matrix @ weights``, with `matrix` (D, B) and `offset` (D,): B named shapes (weights
usually in [0, 1], 0 = rest) drive the D-dimensional expression code the avatar's dynamics take. For the demo
the map is exact (its codes are made this way, `npga_core.demo.expression_map`); for a captured avatar it is
a least-squares fit from paired takes (`fit`). Stored in an `.npga` through `to_arrays`/`header`:

- header key ``"blendshapes"``: ``{"names": [B names], "source": str}``;
- tensors ``blendshapes.matrix`` (D, B) float32 and ``blendshapes.offset`` (D,) float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HEADER_KEY = "blendshapes"
MATRIX_KEY = "blendshapes.matrix"
OFFSET_KEY = "blendshapes.offset"


@dataclass(frozen=True)
class BlendshapeBasis:
    """``code = offset + matrix @ weights`` for weights over `names`."""

    names: tuple[str, ...]
    matrix: np.ndarray  # (D, B) float32
    offset: np.ndarray  # (D,) float32
    source: str = ""

    def __post_init__(self) -> None:
        m, b = np.asarray(self.matrix), np.asarray(self.offset)
        if m.ndim != 2 or b.shape != (m.shape[0],) or m.shape[1] != len(self.names):
            raise ValueError(f"basis shapes disagree: matrix {m.shape}, offset {b.shape}, {len(self.names)} names")
        if not (np.isfinite(m).all() and np.isfinite(b).all()):
            raise ValueError("basis has NaN/Inf values")
        if len(set(self.names)) != len(self.names):
            raise ValueError("basis names repeat")
        object.__setattr__(self, "matrix", m.astype(np.float32))
        object.__setattr__(self, "offset", b.astype(np.float32))
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @property
    def code_dim(self) -> int:
        return int(self.matrix.shape[0])

    def codes(self, weights: np.ndarray) -> np.ndarray:
        """Codes (..., D) float32 of weights (..., B) over `names` (computed in float64)."""
        w = np.asarray(weights, np.float64)
        return (w @ self.matrix.T.astype(np.float64) + self.offset.astype(np.float64)).astype(np.float32)

    def weights(self, codes: np.ndarray) -> np.ndarray:
        """Least-squares weights (..., B) of codes (..., D) (exact for codes in the image of the map)."""
        z = np.asarray(codes, np.float64) - self.offset.astype(np.float64)
        pinv = np.linalg.pinv(self.matrix.astype(np.float64))
        return (z @ pinv.T).astype(np.float32)

    # ------------------------------------------------------------------ storage in an .npga

    def header(self) -> dict:
        """The JSON header entry (under `HEADER_KEY`)."""
        return {"names": list(self.names), "source": self.source}

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The tensors to store, by name."""
        return {MATRIX_KEY: self.matrix.astype(np.float32), OFFSET_KEY: self.offset.astype(np.float32)}

    @staticmethod
    def from_arrays(header: dict, arrays: dict[str, np.ndarray]) -> BlendshapeBasis:
        """The basis from its header entry and tensors; ValueError on anything inconsistent."""
        if not isinstance(header, dict) or not isinstance(header.get("names"), list):
            raise ValueError(f"{HEADER_KEY} header must be an object with a list of names")
        names = header["names"]
        if not all(isinstance(n, str) and 0 < len(n) <= 128 for n in names):
            raise ValueError(f"{HEADER_KEY} names must be non-empty strings of at most 128 characters")
        if MATRIX_KEY not in arrays or OFFSET_KEY not in arrays:
            raise ValueError(f"{HEADER_KEY} needs tensors {MATRIX_KEY} and {OFFSET_KEY}")
        m, b = np.asarray(arrays[MATRIX_KEY]), np.asarray(arrays[OFFSET_KEY])
        if m.dtype.kind != "f" or b.dtype.kind != "f":
            raise ValueError(f"{HEADER_KEY} tensors must be floats, got {m.dtype} and {b.dtype}")
        source = header.get("source", "")
        return BlendshapeBasis(tuple(names), m, b, source if isinstance(source, str) else "")


@dataclass(frozen=True)
class Fit:
    """A basis fitted from paired (weights, codes) frames and its error on them."""

    basis: BlendshapeBasis
    rms: float  # root mean square of the code residual per dimension
    relative: float  # residual norm / norm of the codes' variation about their mean
    frames: int


def fit(names: list[str] | tuple[str, ...], weights: np.ndarray, codes: np.ndarray, ridge: float = 1e-6,
        source: str = "least squares") -> Fit:
    """Least-squares ``codes ~ offset + matrix @ weights`` from T paired frames (T, B) and (T, D), with a small
    ridge on the matrix (shapes a take never moves get 0 columns instead of noise)."""
    w, z = np.asarray(weights, np.float64), np.asarray(codes, np.float64)
    if w.ndim != 2 or z.ndim != 2 or len(w) != len(z) or len(w) < 2:
        raise ValueError(f"need paired (T, B) weights and (T, D) codes with T >= 2, got {w.shape} and {z.shape}")
    if w.shape[1] != len(names):
        raise ValueError(f"{w.shape[1]} weight columns for {len(names)} names")
    wm, zm = w.mean(0), z.mean(0)
    wc, zc = w - wm, z - zm
    gram = wc.T @ wc + ridge * len(w) * np.eye(w.shape[1])
    m = np.linalg.solve(gram, wc.T @ zc).T  # (D, B)
    b = zm - m @ wm
    resid = z - (w @ m.T + b)
    rms = float(np.sqrt(np.mean(resid ** 2)))
    spread = float(np.linalg.norm(zc))
    rel = float(np.linalg.norm(resid) / spread) if spread > 0 else 0.0
    return Fit(BlendshapeBasis(tuple(names), m, b, source), rms, rel, len(w))
