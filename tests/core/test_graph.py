"""kNN graph of canonical centres and the Laplacian smoothness residual (npga_core.inspection.graph)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from npga_core.inspection.graph import knn, laplacian_penalty, laplacian_residual


def brute_force_knn(points: np.ndarray, k: int) -> np.ndarray:
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return np.argsort(d, axis=1, kind="stable")[:, :k]


@pytest.mark.parametrize("k", [1, 5, 8])
def test_knn_matches_brute_force(k: int) -> None:
    pts = np.random.default_rng(0).normal(size=(400, 3))
    nb = knn(pts, k)
    assert nb.shape == (400, k) and nb.dtype == np.int32
    np.testing.assert_array_equal(nb, brute_force_knn(pts, k))


def test_knn_never_returns_the_point_itself_even_with_duplicates() -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(50, 3))
    pts = np.concatenate([pts, pts[:10]])  # 10 exact duplicates
    nb = knn(pts, 4)
    assert not np.any(nb == np.arange(len(pts))[:, None])
    # a duplicated point's nearest neighbour is its twin, at distance 0
    assert np.all(np.linalg.norm(pts[nb[:10, 0]] - pts[:10], axis=1) == 0)
    assert np.all(np.linalg.norm(pts[nb[50:, 0]] - pts[50:], axis=1) == 0)


def test_knn_rejects_bad_k() -> None:
    with pytest.raises(ValueError):
        knn(np.zeros((3, 3)), 3)
    with pytest.raises(ValueError):
        knn(np.zeros((5, 3)), 0)


def test_laplacian_residual_known_answer() -> None:
    x = np.array([[0.0], [1.0], [3.0]])
    nbrs = np.array([[1, 2], [0, 2], [0, 1]])
    expected = np.array([[2.0], [0.5], [-2.5]])  # mean of the other two minus self
    np.testing.assert_allclose(laplacian_residual(x, nbrs), expected)
    xt = torch.tensor(x, requires_grad=True)
    res = laplacian_residual(xt, torch.from_numpy(nbrs))
    np.testing.assert_allclose(res.detach().numpy(), expected)
    res.pow(2).sum().backward()
    assert xt.grad is not None and torch.isfinite(xt.grad).all()


def test_laplacian_of_a_linear_field_vanishes_on_a_symmetric_stencil() -> None:
    # 5x5 grid, 4-neighbourhood of the interior points: the residual of any linear function is zero there
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij"), -1).reshape(-1, 2)
    field = g @ np.array([[2.0, -1.0], [0.5, 3.0]]) + 7.0
    index = {tuple(p): i for i, p in enumerate(g.astype(int))}
    interior = [i for i, (a, b) in enumerate(g.astype(int)) if 0 < a < 4 and 0 < b < 4]
    nbrs = np.array([[index[(a + da, b + db)] for da, db in ((1, 0), (-1, 0), (0, 1), (0, -1))]
                     for a, b in g[interior].astype(int)])
    full = np.zeros((len(g), 4), np.int64)
    full[:] = np.arange(len(g))[:, None]  # boundary points: self-loops (residual 0 too)
    full[interior] = nbrs
    np.testing.assert_allclose(laplacian_residual(field, full), 0.0, atol=1e-12)


def test_laplacian_penalty_is_the_mean_squared_residual() -> None:
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(60, 3))
    nb = knn(pts, 6)
    f = torch.from_numpy(rng.normal(size=(60, 8)))
    expected = (laplacian_residual(f.numpy(), nb) ** 2).sum(axis=1).mean()
    assert float(laplacian_penalty(f, torch.from_numpy(nb))) == pytest.approx(expected)
    rows = torch.tensor([0, 5, 7])
    expected_rows = (laplacian_residual(f.numpy(), nb)[[0, 5, 7]] ** 2).sum(axis=1).mean()
    assert float(laplacian_penalty(f, torch.from_numpy(nb), rows)) == pytest.approx(expected_rows)
