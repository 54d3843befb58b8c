"""Expression space: PCA statistics and slider conversion."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.model.expression import ExpressionSpace


def test_pca_recovers_directions_and_std():
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.standard_normal((10, 10)))[0].T[:3]
    std = np.array([3.0, 1.0, 0.2])
    codes = 5 + (rng.standard_normal((20000, 3)) * std) @ basis
    ex = ExpressionSpace.from_codes(codes)
    assert ex.n_components == 3  # the other 7 directions have no variance
    np.testing.assert_allclose(ex.std, std, rtol=0.03)
    np.testing.assert_allclose(np.abs(ex.basis @ basis.T), np.eye(3), atol=0.02)
    ex.validate()


def test_sliders_round_trip():
    rng = np.random.default_rng(1)
    ex = ExpressionSpace.from_codes(rng.standard_normal((500, 8)))
    s = rng.standard_normal(8).astype(np.float32)
    np.testing.assert_allclose(ex.to_sliders(ex.from_sliders(s)), s, atol=1e-4)
    np.testing.assert_allclose(ex.from_sliders(np.zeros(3)), ex.mean)
    with pytest.raises(ValueError):
        ex.from_sliders(np.zeros(9))


def test_projection_of_a_code_outside_the_span_is_the_least_squares_one():
    rng = np.random.default_rng(2)
    ex = ExpressionSpace.from_codes(rng.standard_normal((100, 6)), n_components=2)
    z = rng.standard_normal(6).astype(np.float32)
    back = ex.from_sliders(ex.to_sliders(z))
    # the residual is orthogonal to the kept directions
    np.testing.assert_allclose(ex.basis @ (z - back), 0, atol=1e-5)
