"""Real spherical harmonics in the 3DGS convention (degree <= 3), and their rotation.

`sh_basis` evaluates the basis functions the splat shader uses (`shaders/splat_preprocess.comp`), so that a
colour is sum_k sh[k] * Y_k(d) + 0.5 for a unit view direction d. `rotate_sh` turns a Gaussian's SH with
its body: after a rotation R the new coefficients c' satisfy colour'(R d) = colour(d). Each band l mixes only
within itself, by a (2l + 1)^2 matrix found here by least squares on sample directions (exact, since both
sides are polynomials of degree l in d).
"""

from __future__ import annotations

import numpy as np

from npga_core.model.gaussians import SH_C0

SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Basis values (M, (degree + 1)^2) at unit directions (M, 3), in the coefficient order of `sh`."""
    d = np.asarray(dirs, np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    cols = [np.full_like(x, SH_C0)]
    if degree >= 1:
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        cols += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
                 SH_C2[4] * (xx - yy)]
    if degree >= 3:
        cols += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                 SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                 SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(cols, axis=1)


def sh_rotation_matrices(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per band l = 1..degree, the matrix D_l with c'_l = D_l c_l for a rotation matrix (3, 3)."""
    r = np.asarray(rotation, np.float64)
    dirs = np.random.default_rng(0).standard_normal((64, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    new, old = sh_basis(dirs, degree), sh_basis(dirs @ r, degree)  # rows: Y(d) and Y(R^T d)
    out = []
    for band in range(1, degree + 1):
        cols = slice(band * band, (band + 1) * (band + 1))
        out.append(np.linalg.lstsq(new[:, cols], old[:, cols], rcond=None)[0])
    return out


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K, 3) of Gaussians turned by `rotation` (3, 3); band 0 is unchanged."""
    sh = np.asarray(sh)
    k = sh.shape[1]
    degree = int(round(np.sqrt(k))) - 1
    if (degree + 1) ** 2 != k or degree > 3:
        raise ValueError(f"SH with {k} coefficients: expected 1, 4, 9 or 16")
    out = np.array(sh, dtype=np.float32, copy=True)
    for band, m in enumerate(sh_rotation_matrices(rotation, degree), start=1):
        cols = slice(band * band, (band + 1) * (band + 1))
        out[:, cols] = np.einsum("ij,njc->nic", m, sh[:, cols].astype(np.float64)).astype(np.float32)
    return out
