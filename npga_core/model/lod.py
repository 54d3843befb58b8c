"""Level-of-detail clouds: fewer, larger Gaussians that look like a posed cloud from a distance.

A software GL (Mesa llvmpipe) pays about a microsecond of vertex work per splat whatever the resolution, so
an image of the demo's 79k Gaussians costs ~70 ms even at 144x135. While the view changes (a drag, a slider,
playback) the window draws its reduced-resolution live images from a level-of-detail cloud instead; the
full-resolution image after the input stops is drawn from every Gaussian as before.

`LevelOfDetail(means, clusters)` groups the Gaussians once, by their centres in one pose, into at most
`clusters` (more than half of it) groups of neighbours (a k-d partition: every split halves a group at the
median of its widest axis, so dense regions such as eyes and lips get small clusters). `merge(posed)` then
replaces each cluster of a posed cloud by one Gaussian matched to its moments, as hierarchical 3DGS (Kerbl et
al. 2024) merges its nodes: with weights w_i = o_i A_i (opacity times the area of the Gaussian,
A_i = (s_1 s_2 s_3)^(2/3)),

    mu = sum w_i mu_i / W,   Sigma = sum w_i (Sigma_i + k (mu_i - mu)(mu_i - mu)^T) / W,

with k = `SPREAD` = 3 where the moments have 1 (measured: a merged Gaussian must reach further than the
moments say to cover as evenly as the group it replaces). SH coefficients and latent features are the
w-weighted means; the opacity keeps the covered area, o = sum o_i A_i / A, but is never more than the members
stacked on each other give, 1 - prod (1 - o_i), nor more than 0.99. Rotation and scales come from the
eigen-decomposition of Sigma. The grouping is fixed, so a merge of any pose of the same cloud costs only
products with a sparse averaging matrix and a closed-form 3x3 eigen-decomposition (~20-40 ms for the demo's
79k Gaussians to 16k on one core).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse

from npga_core.model.gaussians import PosedGaussians, covariances
from npga_core.model.rotations import quat_from_matrix

#: how much the spread of a cluster's centres adds to its covariance (1 would be the moments): a Gaussian is
#: peaked where a group of discs side by side covers evenly, so with the plain moments neighbouring merged
#: Gaussians leave a mesh of thinner coverage (34.7 dB against the full cloud at 288x270 for the demo; 2: 37.3,
#: 3: 38.4, 4: 38.4). Clusters of one Gaussian stay exact.
SPREAD = 3.0
#: Gaussians a level-of-detail cloud has by default (at most, and more than half of it): ~15 ms of llvmpipe
#: per image
CLUSTERS = 16384


def kd_clusters(points: np.ndarray, per_cluster: int) -> np.ndarray:
    """Cluster index (N,) of each point: groups of at most `per_cluster` neighbours, from halving every group at
    the median of its widest axis until it is small enough (ties and order are deterministic)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    if per_cluster < 1:
        raise ValueError(f"per_cluster must be at least 1, got {per_cluster}")
    order = np.arange(n)
    bounds = [(0, n)]  # segments of `order`, each one group
    done: list[tuple[int, int]] = []
    while bounds:
        nxt = []
        for lo, hi in bounds:
            if hi - lo <= per_cluster:
                done.append((lo, hi))
                continue
            idx = order[lo:hi]
            p = pts[idx]
            axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
            half = (hi - lo) // 2
            part = np.argpartition(p[:, axis], half, kind="introselect")
            order[lo:hi] = idx[part]
            nxt.append((lo, lo + half))
            nxt.append((lo + half, hi))
        bounds = nxt
    done.sort()
    labels = np.empty(n, dtype=np.int64)
    for k, (lo, hi) in enumerate(done):
        labels[order[lo:hi]] = k
    return labels


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)


def _any_orthogonal(v: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to each unit row of `v`."""
    axis = np.zeros_like(v)
    axis[np.arange(len(v)), np.argmin(np.abs(v), axis=1)] = 1.0
    return _unit(np.cross(v, axis))


def _null_vector(c6: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A unit vector in the null space of (C - lam I) for symmetric C given by its 6 entries, from the largest
    cross product of two of its rows, and that cross product's length (small when the eigenvalue repeats)."""
    xx, yy, zz, xy, xz, yz = (c6[:, k] for k in range(6))
    r0 = np.stack([xx - lam, xy, xz], axis=1)
    r1 = np.stack([xy, yy - lam, yz], axis=1)
    r2 = np.stack([xz, yz, zz - lam], axis=1)
    cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    norms = np.einsum("nkd,nkd->nk", cands, cands)
    best = np.argmax(norms, axis=1)
    rows = np.arange(len(c6))
    return _unit(cands[rows, best]), np.sqrt(norms[rows, best])


def eigh3(c6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition of symmetric 3x3 matrices given by their entries (xx, yy, zz, xy, xz, yz) (N, 6):
    eigenvalues (N, 3) descending and a proper rotation (N, 3, 3) whose columns are the eigenvectors, in closed
    form (trigonometric eigenvalues, eigenvectors from cross products; repeated eigenvalues get any orthonormal
    basis of their space). About 8x faster than LAPACK's per-matrix calls for many small matrices."""
    c6 = np.asarray(c6, dtype=np.float64)
    xx, yy, zz, xy, xz, yz = (c6[:, k] for k in range(6))
    q = (xx + yy + zz) / 3.0
    p1 = xy * xy + xz * xz + yz * yz
    p2 = (xx - q) ** 2 + (yy - q) ** 2 + (zz - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = np.where(p > 0, p, 1.0)
    b = [(xx - q) / safe, (yy - q) / safe, (zz - q) / safe, xy / safe, xz / safe, yz / safe]
    det_b = (b[0] * (b[1] * b[2] - b[5] * b[5]) - b[3] * (b[3] * b[2] - b[5] * b[4])
             + b[4] * (b[3] * b[5] - b[1] * b[4]))
    phi = np.arccos(np.clip(det_b / 2.0, -1.0, 1.0)) / 3.0
    lam1 = q + 2.0 * p * np.cos(phi)
    lam3 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    lam2 = 3.0 * q - lam1 - lam3
    v1, n1 = _null_vector(c6, lam1)
    v3, n3 = _null_vector(c6, lam3)
    # a cross product of rows of (C - lam I) has length ~ the product of the gaps to the other eigenvalues
    tol = 1e-9 * np.maximum(p * p, 1e-300)
    ok1, ok3 = n1 > tol, n3 > tol
    trust1 = ok1 & (~ok3 | (n1 >= n3))  # build the basis from the better-determined vector
    v3 = np.where(trust1[:, None], _unit(v3 - np.einsum("nd,nd->n", v3, v1)[:, None] * v1), v3)
    bad3 = trust1 & ~ok3
    v3[bad3] = _any_orthogonal(v1[bad3])
    v1_alt = _unit(v1 - np.einsum("nd,nd->n", v1, v3)[:, None] * v3)
    v1 = np.where(trust1[:, None], v1, v1_alt)
    bad1 = ~trust1 & ok3 & ~ok1
    v1[bad1] = _any_orthogonal(v3[bad1])
    flat = ~ok1 & ~ok3  # all three equal (or p == 0): any basis
    v1[flat] = (1.0, 0.0, 0.0)
    v3[flat] = (0.0, 0.0, 1.0)
    v2 = np.cross(v3, v1)  # [v1, v3 x v1, v3] has determinant +1
    return np.stack([lam1, lam2, lam3], axis=1), np.stack([v1, v2, v3], axis=2)


@dataclass
class Merge:
    """A merged cloud and what it was merged from: the members' centres and the averaging weights (clusters x N)."""

    cloud: PosedGaussians
    source_means: np.ndarray
    weights: sparse.csr_matrix
    source_dc: np.ndarray | None = None  # the members' SH DC terms (N, 3) the merge was of

    def shifted(self, means: np.ndarray, sh: np.ndarray | None = None) -> PosedGaussians:
        """The merged cloud of a pose of the same cloud whose centres are `means` (and SH `sh`), to first order:
        each merged centre moves by the weighted mean of its members' moves (exact for a cluster that only
        translates) and, with `sh`, its base colour (the DC term) changes by theirs (exact for fixed weights);
        shapes, opacities and the view-dependent bands stay those of this merge (about a millisecond for the
        demo: a live image of a new pose need not wait for its merge)."""
        moved = np.asarray(means, dtype=np.float32).reshape(self.source_means.shape) - self.source_means
        out = replace(self.cloud, means=(self.cloud.means + self.weights @ moved).astype(np.float32))
        if sh is not None and self.source_dc is not None:
            dc = np.asarray(sh, dtype=np.float32)[:, 0, :] - self.source_dc
            out.sh = self.cloud.sh.copy()
            out.sh[:, 0, :] += self.weights @ dc
        return out


def _area(scales: np.ndarray) -> np.ndarray:
    """(s_1 s_2 s_3)^(2/3): the area of the sphere of the same volume."""
    return np.cbrt(np.prod(scales, axis=1)) ** 2


class LevelOfDetail:
    """A fixed grouping of an avatar's Gaussians (see the module docstring); `merge` applies it to any pose."""

    def __init__(self, means: np.ndarray, clusters: int = CLUSTERS) -> None:
        self.count = int(np.asarray(means).reshape(-1, 3).shape[0])  # Gaussians of the cloud
        leaves = 1 << max(0, int(clusters).bit_length() - 1)  # halving gives a power of two: <= clusters
        per_cluster = 1 if clusters >= self.count else max(1, -(-self.count // leaves))
        labels = kd_clusters(means, per_cluster)
        order = np.argsort(labels, kind="stable")  # members of a cluster are consecutive in this order
        sorted_labels = labels[order]
        starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]])
        self.clusters = int(starts.shape[0])  # Gaussians of a merged cloud
        self.labels = labels  #: each Gaussian's cluster
        self._first = order[starts]  # one member of each cluster: the reference its offsets are taken from
        indptr = np.r_[starts, self.count].astype(np.int64)
        #: (clusters x N) sums over each cluster's members
        self._sum_of = sparse.csr_matrix((np.ones(self.count), order.astype(np.int64), indptr),
                                         shape=(self.clusters, self.count))

    def _weights(self, w: np.ndarray) -> sparse.csr_matrix:
        """(clusters x N) matrix averaging each cluster's members with weights `w` (normalised per cluster)."""
        wsum = np.bincount(self.labels, weights=w, minlength=self.clusters)
        mean_of = self._sum_of.copy()
        mean_of.data = (w / wsum[self.labels])[mean_of.indices]
        return mean_of

    def merge(self, posed: PosedGaussians) -> PosedGaussians:
        """One Gaussian per cluster of `posed` (which must have this grouping's count), moment-matched."""
        return self.merge_keeping(posed).cloud

    def merge_keeping(self, posed: PosedGaussians) -> Merge:
        """`merge`, keeping what `Merge.shifted` needs to follow later poses cheaply."""
        if len(posed) != self.count:
            raise ValueError(f"the level of detail was built for {self.count} Gaussians, the cloud has {len(posed)}")
        scales = np.maximum(np.asarray(posed.scales, dtype=np.float64), 1e-12)
        opac = np.clip(np.asarray(posed.opacities, dtype=np.float64).reshape(-1), 0.0, 1.0)
        area = _area(scales)
        mean_of = self._weights(opac * area + 1e-30)
        means = np.asarray(posed.means, dtype=np.float64)
        ref = means[self._first]  # offsets from one member keep the second moments free of cancellation
        d = means - ref[self.labels]
        dd = np.stack([d[:, 0] * d[:, 0], d[:, 1] * d[:, 1], d[:, 2] * d[:, 2], d[:, 0] * d[:, 1],
                       d[:, 0] * d[:, 2], d[:, 1] * d[:, 2]], axis=1)
        own = covariances(posed.quats, scales)[[0, 3, 5, 1, 2, 4]].T  # as xx, yy, zz, xy, xz, yz
        m = mean_of @ np.concatenate([d, own + SPREAD * dd], axis=1)
        dm = m[:, :3]
        cov = m[:, 3:] - SPREAD * np.stack([dm[:, 0] * dm[:, 0], dm[:, 1] * dm[:, 1], dm[:, 2] * dm[:, 2],
                                   dm[:, 0] * dm[:, 1], dm[:, 0] * dm[:, 2], dm[:, 1] * dm[:, 2]], axis=1)
        evals, rot = eigh3(cov)
        new_scales = np.sqrt(np.maximum(evals, 1e-18))
        new_area = _area(new_scales)
        sum_of = self._sum_of
        covered = (sum_of @ (opac * area)) / new_area
        stacked = -np.expm1(sum_of @ np.log1p(-np.minimum(opac, 0.999999)))
        sh = np.asarray(posed.sh, dtype=np.float32)
        feats = [sh.reshape(self.count, -1)]
        if posed.latent is not None:
            feats.append(np.asarray(posed.latent, dtype=np.float32).reshape(self.count, -1))
        mean_of32 = mean_of.astype(np.float32)
        averaged = mean_of32 @ (np.concatenate(feats, axis=1) if len(feats) > 1 else feats[0])
        k = sh.shape[1] * 3
        cloud = PosedGaussians(
            means=(ref + dm).astype(np.float32),
            quats=np.ascontiguousarray(quat_from_matrix(rot, proper=True), dtype=np.float32),
            scales=new_scales.astype(np.float32),
            opacities=np.minimum(np.minimum(covered, stacked), 0.99).astype(np.float32),
            sh=np.ascontiguousarray(averaged[:, :k].reshape(self.clusters, sh.shape[1], 3)),
            latent=None if posed.latent is None else np.ascontiguousarray(averaged[:, k:]))
        return Merge(cloud, np.array(posed.means, dtype=np.float32), mean_of32, np.array(sh[:, 0, :]))
