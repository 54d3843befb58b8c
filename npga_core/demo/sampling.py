"""Blue-noise sampling of the head's surfaces and flat, surface-aligned Gaussian discs on the samples.

Samples are drawn area-weighted per part (with a per-part density), then thinned to a Poisson-disk set by
a random-priority maximal independent set on the "closer than r" graph (Luby's algorithm, vectorised),
which keeps the lowest-priority-first greedy result without a Python loop per point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from npga_core.demo.ict import LIMBUS_ANGLE, PART_NAMES, IctHead
from npga_core.inspection.graph import knn
from npga_core.model.rotations import quat_from_matrix

#: Relative sample density (samples per area) of each part; parts not listed are not sampled.
DEFAULT_DENSITY: dict[str, float] = {
    "face": 1.0,
    "head_neck": 0.55,
    "mouth_socket": 0.45,
    "eye_socket_l": 0.8,
    "eye_socket_r": 0.8,
    "gums_tongue": 0.7,
    "teeth": 1.0,
    "sclera_l": 4.0,
    "sclera_r": 4.0,
}
#: Eye-shell triangles facing further than this from the eye axis are hidden in the socket and not sampled.
EYE_BACK_LIMIT = np.radians(105.0)


@dataclass
class SurfaceSamples:
    """Points on the mesh: triangle, barycentrics, position, smooth normal, part and local spacing."""

    tri: np.ndarray  # (N,) int64 triangle index
    bary: np.ndarray  # (N, 3) float32
    points: np.ndarray  # (N, 3) float32
    normals: np.ndarray  # (N, 3) float32, unit, interpolated vertex normals
    part: np.ndarray  # (N,) int16 index into PART_NAMES
    spacing: np.ndarray  # (N,) float32 mean distance to the nearest same-part samples

    def __len__(self) -> int:
        return int(self.tri.shape[0])


def random_barycentrics(n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform barycentric coordinates (n, 3) over a triangle."""
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    return np.stack([1.0 - u - v, u, v], axis=1)


def interpolate(values: np.ndarray, faces: np.ndarray, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of per-vertex values (V, ...) at samples (tri, bary)."""
    corners = values[faces[tri]]  # (N, 3, ...)
    b = bary.reshape(bary.shape + (1,) * (corners.ndim - 2))
    return (corners * b).sum(axis=1)


def uniform_samples(head: IctHead, tris: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n area-weighted uniform samples over the triangles `tris`: (triangle index, barycentrics)."""
    area = head.triangle_areas()[tris]
    pick = rng.choice(len(tris), size=n, p=area / area.sum())
    return tris[pick], random_barycentrics(n, rng)


def poisson_select(points: np.ndarray, radius: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean mask of a maximal subset whose points are pairwise at least `radius` apart."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    prio = rng.permutation(n)
    active = np.ones(n, bool)
    chosen = np.zeros(n, bool)
    while active.any():
        e = pairs[active[pairs[:, 0]] & active[pairs[:, 1]]]
        pairs = e
        best_nb = np.full(n, -1)
        np.maximum.at(best_nb, e[:, 0], prio[e[:, 1]])
        np.maximum.at(best_nb, e[:, 1], prio[e[:, 0]])
        win = active & (prio > best_nb)
        chosen |= win
        active &= ~win
        active[e[win[e[:, 0]], 1]] = False
        active[e[win[e[:, 1]], 0]] = False
    return chosen


def sampleable_density(head: IctHead, density: dict[str, float]) -> np.ndarray:
    """Per-triangle sampling density of `head` (0 where not sampled), with the hidden back of the eyeballs
    removed (also the triangles the refine targets are drawn on)."""
    dens = np.zeros(len(head.faces))
    for name, d in density.items():
        dens[head.tri_part == PART_NAMES.index(name)] = d
    centroids = head.vertices[head.faces].mean(axis=1)
    for e, name in enumerate(("sclera_l", "sclera_r")):
        m = head.tri_part == PART_NAMES.index(name)
        d = centroids[m] - head.eye_centres[e]
        cosang = (d @ head.eye_axes[e]) / np.linalg.norm(d, axis=1)
        dens[np.flatnonzero(m)[cosang < np.cos(EYE_BACK_LIMIT)]] = 0.0
    return dens


def sample_surface(head: IctHead, n_target: int, rng: np.random.Generator,
                   density: dict[str, float] | None = None, oversample: int = 5,
                   refinements: int = 2) -> SurfaceSamples:
    """About `n_target` blue-noise samples over the sampled parts, area-weighted by part density."""
    density = DEFAULT_DENSITY if density is None else density
    dens = sampleable_density(head, density)
    area = head.triangle_areas()
    budget = n_target / float((dens * area).sum())
    normals_v = head.vertex_normals()
    chunks = []
    for pid in range(len(PART_NAMES)):
        tris = np.flatnonzero((head.tri_part == pid) & (dens > 0))
        if len(tris) == 0:
            continue
        part_area = float(area[tris].sum())
        want = max(16, int(round(budget * dens[tris[0]] * part_area)))
        tri, bary = uniform_samples(head, tris, want * oversample, rng)
        pts = interpolate(head.vertices, head.faces, tri, bary)
        # a maximal Poisson-disk set of radius r has about 0.7 / r^2 points per unit area; refine r from the count
        r = np.sqrt(0.7 * part_area / want)
        for _ in range(refinements + 1):
            keep = poisson_select(pts, r, rng)
            r *= np.sqrt(keep.sum() / want)
        chunks.append((tri[keep], bary[keep], np.full(int(keep.sum()), pid, np.int16)))
    tri = np.concatenate([c[0] for c in chunks])
    bary = np.concatenate([c[1] for c in chunks]).astype(np.float32)
    part = np.concatenate([c[2] for c in chunks])
    points = interpolate(head.vertices, head.faces, tri, bary).astype(np.float32)
    nrm = interpolate(normals_v, head.faces, tri, bary)
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    spacing = local_spacing(points, part)
    return SurfaceSamples(tri, bary, points, nrm, label_iris(head, points, part), spacing)


def label_iris(head: IctHead, points: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Part ids with eye-shell samples inside the limbus relabelled from sclera_* to iris_*."""
    part = part.copy()
    for e, (sclera, iris) in enumerate((("sclera_l", "iris_l"), ("sclera_r", "iris_r"))):
        m = part == PART_NAMES.index(sclera)
        d = points[m] - head.eye_centres[e]
        inside = (d @ head.eye_axes[e]) / np.linalg.norm(d, axis=1) > np.cos(LIMBUS_ANGLE)
        idx = np.flatnonzero(m)[inside]
        part[idx] = PART_NAMES.index(iris)
    return part


def local_spacing(points: np.ndarray, part: np.ndarray, k: int = 6) -> np.ndarray:
    """Mean distance from each point to its k nearest neighbours of the same part."""
    out = np.zeros(len(points), np.float32)
    for pid in np.unique(part):
        idx = np.flatnonzero(part == pid)
        kk = min(k, len(idx) - 1)
        nb = knn(points[idx], kk)
        out[idx] = np.linalg.norm(points[idx][nb] - points[idx][:, None], axis=2).mean(axis=1)
    return out


def tangent_frames(normals: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) whose third column is the normal (first two span the tangent plane)."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, 1:2]) < 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    t1 = np.cross(helper, n)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=2).astype(np.float32)


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) (w, x, y, z) with w >= 0 from rotation matrices (N, 3, 3), float32."""
    return quat_from_matrix(r).astype(np.float32)


def disc_attributes(samples: SurfaceSamples, size: float = 0.6, thickness: float = 0.12
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quaternions (N, 4), log scales (N, 3) and frames (N, 3, 3) of flat discs on the samples.

    The two tangent axes get standard deviation ``size * spacing``, the normal axis ``thickness`` times that.
    """
    frames = tangent_frames(samples.normals)
    sigma = size * samples.spacing
    scales = np.stack([sigma, sigma, thickness * sigma], axis=1)
    return matrix_to_quat(frames), np.log(scales).astype(np.float32), frames
