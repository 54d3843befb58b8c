"""k-nearest-neighbour graph of canonical Gaussian centres and the Laplacian smoothness residual.

NPGA regularises per-Gaussian features and G's offsets with a Laplacian term on the kNN graph of the
canonical centres: ``R_lap(x)_i = || mean_{j in N(i)} x_j - x_i ||^2``. `laplacian_residual` returns the
vector inside the norm, for numpy arrays or torch tensors alike, `laplacian_terms` the per-row R_lap.

For viewing the graph: `knn_cached` (the same graph, memoised by the content of the points and k),
`knn_edges` (the undirected edge list), `edges_touching` and `edge_lengths`.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from typing import TypeVar

import numpy as np
import torch
from scipy.spatial import cKDTree

ArrayT = TypeVar("ArrayT", np.ndarray, torch.Tensor)


def knn(points: np.ndarray, k: int, workers: int = -1) -> np.ndarray:
    """Indices (N, k) int32 of the k nearest other points of every point (Euclidean, nearest first).

    A point is never its own neighbour, also when duplicates exist. Needs N > k.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2:
        raise ValueError(f"points must be (N, dim), got shape {pts.shape}")
    n = pts.shape[0]
    if k < 1 or n <= k:
        raise ValueError(f"need 1 <= k < N, got k={k} for N={n}")
    _, idx = cKDTree(pts).query(pts, k=k + 1, workers=workers)
    idx = np.asarray(idx, dtype=np.int64)
    is_self = idx == np.arange(n)[:, None]
    # drop the point itself; if a duplicate pushed it out of the k+1 list, drop the farthest instead
    drop = np.where(is_self.any(axis=1), is_self.argmax(axis=1), k)
    keep = np.ones_like(idx, dtype=bool)
    keep[np.arange(n), drop] = False
    return idx[keep].reshape(n, k).astype(np.int32)


def laplacian_residual(x: ArrayT, nbrs: np.ndarray | torch.Tensor) -> ArrayT:
    """``mean_j x[nbrs[i, j]] - x[i]`` for every row i, shaped like x.

    `x` (N, ...) is a numpy array or a torch tensor (then the result is differentiable); `nbrs` (N, k) is
    the neighbour list from `knn`.
    """
    if x.shape[0] != nbrs.shape[0]:
        raise ValueError(f"x has {x.shape[0]} rows, nbrs has {nbrs.shape[0]}")
    if isinstance(x, torch.Tensor):
        idx = torch.as_tensor(nbrs, device=x.device).long()
        return x[idx].mean(dim=1) - x
    return x[np.asarray(nbrs, dtype=np.int64)].mean(axis=1) - x


def laplacian_penalty(x: torch.Tensor, nbrs: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared Laplacian residual ``mean_i ||mean_j x_j - x_i||^2`` over `rows` (all rows if None)."""
    rows = torch.arange(x.shape[0], device=x.device) if rows is None else rows
    res = x[nbrs[rows].long()].mean(dim=1) - x[rows]
    return res.pow(2).sum(dim=-1).mean()


def laplacian_terms(x: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """Per-row ``R_lap(x)_i = ||mean_j x[nbrs[i, j]] - x_i||^2`` (N,) float64 for x (N, ...)."""
    res = np.asarray(laplacian_residual(np.asarray(x, dtype=np.float64), nbrs))
    return (res.reshape(res.shape[0], -1) ** 2).sum(axis=1)


_KNN_CACHE: OrderedDict[tuple[bytes, int], np.ndarray] = OrderedDict()
KNN_CACHE_SIZE = 4


def knn_cached(points: np.ndarray, k: int, workers: int = -1) -> np.ndarray:
    """`knn(points, k)`, memoised: the key is a BLAKE2 digest of the points' bytes and shape, and k.

    The last `KNN_CACHE_SIZE` graphs are kept; the returned array is read-only (it is shared).
    """
    pts = np.ascontiguousarray(points, dtype=np.float32)
    digest = hashlib.blake2b(pts.tobytes(), digest_size=16)
    digest.update(repr(pts.shape).encode())
    key = (digest.digest(), int(k))
    hit = _KNN_CACHE.get(key)
    if hit is not None:
        _KNN_CACHE.move_to_end(key)
        return hit
    nbrs = knn(pts, k, workers)
    nbrs.setflags(write=False)
    _KNN_CACHE[key] = nbrs
    while len(_KNN_CACHE) > KNN_CACHE_SIZE:
        _KNN_CACHE.popitem(last=False)
    return nbrs


def knn_edges(nbrs: np.ndarray) -> np.ndarray:
    """Undirected edges (E, 2) int32 of a neighbour list, each once with i < j, sorted (a pair that is in both
    neighbour lists counts once)."""
    g = np.asarray(nbrs, dtype=np.int64)
    n, k = g.shape
    i = np.repeat(np.arange(n, dtype=np.int64), k)
    j = g.reshape(-1)
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    keys = np.sort(lo[lo != hi] * max(n, 1) + hi[lo != hi])  # sort + diff: much faster than np.unique here
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if keys.size else keys
    return np.stack([keys // max(n, 1), keys % max(n, 1)], axis=1).astype(np.int32)


def edges_touching(edges: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The edges (E', 2) with at least one end in the boolean `mask` (N,)."""
    m = np.asarray(mask, dtype=bool)
    e = np.asarray(edges)
    return e[m[e[:, 0]] | m[e[:, 1]]]


def edge_lengths(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Euclidean length (E,) float32 of every edge between rows of `points`."""
    p = np.asarray(points, dtype=np.float32)
    e = np.asarray(edges, dtype=np.int64)
    return np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1).astype(np.float32)
