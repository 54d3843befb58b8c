"""Synthetic FLAME models and GaussianAvatars output folders for the tests (written with pickle here, in tests only).

The FLAME model is MPI's and not available: its arrays here are random, on FLAME's sizes (5023 vertices, 9976
faces, 5 joints, 400 shape + expression components, 36 pose correctives). The topology is FLAME's own template
(`head_template_mesh.obj`) when a copy of GaussianAvatars is at hand (`NPGA_GA_SOURCE`), else a stated synthetic one:
the convex hull of 5023 points on a head-sized ellipsoid, its first 9976 triangles. Pickles come in both styles:
FLAME 2023's plain numpy dict and FLAME 2020's with chumpy `Ch` objects and a scipy csc regressor (a stand-in
class registered as chumpy.ch.Ch while pickling; protocol 2 as Python 2 wrote them).
"""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
import scipy.sparse
from scipy.spatial import ConvexHull

from npga_core.files.ply import write_ply

V, F, J = 5023, 9976, 5


def synthetic_topology(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(5023, 3) points on a head-sized ellipsoid and 9976 of their hull's triangles (a stated stand-in)."""
    i = np.arange(V) + 0.5
    phi, theta = np.arccos(1 - 2 * i / V), np.pi * (1 + 5**0.5) * i
    pts = np.stack([np.sin(phi) * np.cos(theta) * 0.08, np.cos(phi) * 0.11, np.sin(phi) * np.sin(theta) * 0.09], 1)
    return pts, ConvexHull(pts).simplices[:F].astype(np.int64)


def obj_topology(obj: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of an OBJ (FLAME's template from their repository)."""
    verts, faces = [], []
    for line in obj.read_text().splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            faces.append([int(w.split("/")[0]) - 1 for w in line.split()[1:4]])
    return np.array(verts), np.array(faces, np.int64)


def flame_arrays(seed: int = 0, topology: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """A random FLAME model (plain arrays) on the given or the synthetic topology."""
    rng = np.random.default_rng(seed)
    template, faces = topology or synthetic_topology()
    reg = np.zeros((J, V))
    for j, centre in enumerate([(0, -0.08, -0.02), (0, -0.06, -0.01), (0, -0.03, 0.02), (0.03, 0.03, 0.06),
                                (-0.03, 0.03, 0.06)]):
        near = np.argsort(np.linalg.norm(template - np.array(centre), axis=1))[:12]
        reg[j, near] = rng.dirichlet(np.ones(12))
    weights = rng.dirichlet(np.ones(J) * 0.3, size=V)
    return {"v_template": template, "f": faces.astype(np.uint32),
            "shapedirs": rng.normal(0, 2e-3, (V, 3, 400)), "posedirs": rng.normal(0, 5e-3, (V, 3, 36)),
            "J_regressor": reg, "kintree_table": np.array([[2**32 - 1, 0, 1, 1, 1], [0, 1, 2, 3, 4]], np.int64),
            "weights": weights, "J": reg @ template, "bs_style": "lbs", "bs_type": "lrotmin"}


class Ch:
    """Stand-in for chumpy's Ch, pickled under chumpy.ch.Ch (tests only)."""

    def __init__(self, x: np.ndarray):
        self.x = x
        self._dirty_vars = set()


def write_flame_pickle(path: Path, arrays: dict, style: str) -> Path:
    """`style` "numpy" (FLAME 2023) or "chumpy" (FLAME 2020: Ch shapedirs/posedirs/v_template, csc regressor)."""
    data = dict(arrays)
    if style == "chumpy":
        module, package = types.ModuleType("chumpy.ch"), types.ModuleType("chumpy")
        Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
        module.Ch = Ch  # type: ignore[attr-defined]
        package.ch = module  # type: ignore[attr-defined]
        sys.modules["chumpy"], sys.modules["chumpy.ch"] = package, module
        try:
            for k in ("shapedirs", "posedirs", "v_template"):
                data[k] = Ch(data[k])
            data["J_regressor"] = scipy.sparse.csc_matrix(data["J_regressor"])
            path.write_bytes(pickle.dumps(data, protocol=2))
        finally:
            del sys.modules["chumpy.ch"], sys.modules["chumpy"]
            Ch.__module__, Ch.__qualname__ = __name__, "Ch"
    else:
        path.write_bytes(pickle.dumps(data, protocol=2))
    return path


def flame_params(seed: int, frames: int, n_expr: int = 100, scale: float = 1.0) -> dict:
    """GaussianAvatars flame_param arrays: an identity and `frames` frames of expression and pose."""
    rng = np.random.default_rng(seed)
    t = frames
    return {"shape": rng.normal(0, 1, 300).astype(np.float32),
            "static_offset": rng.normal(0, 1e-3, (1, V + 120, 3)).astype(np.float32),
            "expr": rng.normal(0, scale, (t, n_expr)).astype(np.float32),
            "rotation": rng.normal(0, 0.2 * scale, (t, 3)).astype(np.float32),
            "neck_pose": rng.normal(0, 0.15 * scale, (t, 3)).astype(np.float32),
            "jaw_pose": np.abs(rng.normal(0, 0.15 * scale, (t, 3))).astype(np.float32),
            "eyes_pose": rng.normal(0, 0.1 * scale, (t, 6)).astype(np.float32),
            "translation": rng.normal(0, 0.05 * scale, (t, 3)).astype(np.float32),
            "dynamic_offset": np.zeros((t, V + 120, 3), np.float32)}


def write_ga_folder(folder: Path, n: int, seed: int = 0, frames: int = 3, iterations=(7000, 30000)) -> Path:
    """A GaussianAvatars output folder with `n` Gaussians (SH 3, binding_0 over FLAME + teeth faces)."""
    rng = np.random.default_rng(seed)
    for it in iterations:
        d = folder / "point_cloud" / f"iteration_{it}"
        d.mkdir(parents=True, exist_ok=True)
        binding = rng.integers(0, F + 168, n).astype(np.float32)
        binding[:168] = F + np.arange(168)  # every teeth face carries one
        write_ply(d / "point_cloud.ply", rng.normal(0, 0.4, (n, 3)).astype(np.float32),
                  rng.normal(0, 1, (n, 4)).astype(np.float32), rng.normal(-0.5, 0.5, (n, 3)).astype(np.float32),
                  rng.normal(0, 2, n).astype(np.float32), rng.normal(0, 0.5, (n, 16, 3)).astype(np.float32),
                  extra={"binding_0": binding})
        np.savez(d / "flame_param.npz", **flame_params(seed, frames))
    return folder
