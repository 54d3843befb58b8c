"""Selection masks: screen-space tools, 3D shapes, ranges, kNN grow/shrink and combine modes."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.camera.cameras import look_at
from npga_core.editing.selection import (
    attribute_names,
    attribute_values,
    combine,
    grow,
    in_box,
    in_brush,
    in_lasso,
    in_range,
    in_rect,
    in_sphere,
    points_in_polygon,
    project_front,
    shrink,
)
from npga_core.inspection.graph import knn
from npga_core.model.gaussians import SH_C0, sigmoid
from npga_core.model.synthetic import make_synthetic_avatar


@pytest.fixture
def camera():
    # at z=+2 looking at the origin: image x grows with world -x, image y with world -y
    return look_at([0.0, 0.0, 2.0], [0.0, 0.0, 0.0], fov_y_deg=40.0, width=200, height=100)


def test_rect_selects_projected_centres_in_front_only(camera):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.5, 0.5, (500, 3))
    uv = camera.project(pts)
    got = in_rect(camera, pts, 120, 70, 60, 20)  # corners in any order
    want = (uv[:, 0] >= 60) & (uv[:, 0] <= 120) & (uv[:, 1] >= 20) & (uv[:, 1] <= 70)
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < len(pts)
    # points behind the camera mirror onto the same pixels but must never be selected
    behind = pts.copy()
    behind[:, 2] = 4.0 - pts[:, 2] + 1.0  # z > 2: behind a camera at z=2 looking towards -z
    assert not in_rect(camera, behind, -1e6, -1e6, 1e6, 1e6).any()
    _, front = project_front(camera, np.vstack([pts, behind]))
    assert front[: len(pts)].all() and not front[len(pts):].any()


def test_lasso_follows_a_concave_polygon(camera):
    # an L-shaped polygon in pixels; the notch (upper right) is outside
    poly = np.array([[20, 10], [60, 10], [60, 50], [100, 50], [100, 90], [20, 90]], float)
    grid = np.stack(np.meshgrid(np.arange(5, 120, 2.5) + 0.1, np.arange(2, 98, 2.5) + 0.1), -1).reshape(-1, 2)
    x, y = grid[:, 0], grid[:, 1]
    want = ((x > 20) & (x < 60) & (y > 10) & (y < 90)) | ((x > 20) & (x < 100) & (y > 50) & (y < 90))
    np.testing.assert_array_equal(points_in_polygon(grid, poly), want)
    # the same through a camera: unproject the pixels at depth 2 and select them back
    rays = np.column_stack([(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, np.ones_like(x)]) * 2.0
    world = (rays - camera.translation) @ camera.rotation  # camera -> world (rotation is orthonormal)
    np.testing.assert_array_equal(in_lasso(camera, world, poly), want)
    assert not points_in_polygon(grid, poly[:2]).any()  # fewer than 3 vertices select nothing


def test_brush_is_a_disc_in_pixels(camera):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.4, 0.4, (400, 3))
    uv = camera.project(pts)
    got = in_brush(camera, pts, (100.0, 50.0), 15.0)
    np.testing.assert_array_equal(got, np.hypot(uv[:, 0] - 100, uv[:, 1] - 50) <= 15.0)
    assert got.any() and not got.all()


def test_sphere_and_box():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, (1000, 3))
    np.testing.assert_array_equal(in_sphere(pts, [0.2, 0, 0], 0.5), np.linalg.norm(pts - [0.2, 0, 0], axis=1) <= 0.5)
    np.testing.assert_array_equal(in_box(pts, [0.5, -1, -1], [-0.5, 0, 1]),  # lo/hi in any order
                                  (np.abs(pts[:, 0]) <= 0.5) & (pts[:, 1] <= 0))
    # a box rotated 45 degrees about z and moved by (0.3, 0, 0): test in its own frame by hand
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = [0.3, 0, 0]
    local = (pts - [0.3, 0, 0]) @ t[:3, :3]  # world -> box: R^T (p - t)
    want = np.all(np.abs(local) <= [0.4, 0.1, 1.0], axis=1)
    np.testing.assert_array_equal(in_box(pts, [-0.4, -0.1, -1], [0.4, 0.1, 1], t), want)
    assert want.sum() > 10
    with pytest.raises(ValueError):
        in_box(pts, [0, 0, 0], [1, 1, 1], np.eye(3))


def test_range_bounds_and_nan():
    v = np.array([0.0, 0.5, 1.0, np.nan, 2.0])
    np.testing.assert_array_equal(in_range(v, 1.0, 0.5), [False, True, True, False, False])


def _chain(n: int) -> np.ndarray:
    """kNN graph of points on a line: each point's two nearest neighbours."""
    return knn(np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]), 2)


def test_grow_and_shrink_along_the_graph():
    nbrs = _chain(20)
    m = np.zeros(20, bool)
    m[10] = True
    np.testing.assert_array_equal(np.flatnonzero(grow(m, nbrs)), [9, 10, 11])  # its two nearest
    np.testing.assert_array_equal(np.flatnonzero(grow(m, nbrs, steps=3)), np.arange(7, 14))
    run = np.zeros(20, bool)
    run[5:15] = True
    np.testing.assert_array_equal(np.flatnonzero(shrink(run, nbrs)), np.arange(6, 14))
    np.testing.assert_array_equal(np.flatnonzero(shrink(run, nbrs, steps=2)), np.arange(7, 13))
    assert not shrink(m, nbrs).any()
    end = np.zeros(20, bool)
    end[19] = True  # the last point's neighbours are 18 and 17, and 18 links back to it
    np.testing.assert_array_equal(np.flatnonzero(grow(end, nbrs)), [17, 18, 19])
    assert shrink(np.ones(20, bool), nbrs).all()  # nothing unselected: nothing to erode from
    # growing is monotone and shrink(grow(x)) keeps x
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 3))
    g = knn(pts, 6)
    x = rng.random(300) < 0.2
    assert np.all(grow(x, g) >= x) and np.all(shrink(x, g) <= x)
    assert np.all(shrink(grow(x, g), g) >= x)
    with pytest.raises(ValueError):
        grow(x[:10], g)


def test_combine_modes():
    a = np.array([1, 1, 0, 0], bool)
    b = np.array([1, 0, 1, 0], bool)
    np.testing.assert_array_equal(combine(a, b, "replace"), b)
    np.testing.assert_array_equal(combine(a, b, "add"), [1, 1, 1, 0])
    np.testing.assert_array_equal(combine(a, b, "subtract"), [0, 1, 0, 0])
    np.testing.assert_array_equal(combine(a, b, "intersect"), [1, 0, 0, 0])
    with pytest.raises(ValueError, match="unknown selection mode"):
        combine(a, b, "xor")


def test_attribute_values():
    cloud = make_synthetic_avatar(64, with_f=False, with_g=False, feature_dim=3, seed=4).cloud
    names = attribute_names(cloud)
    assert {"opacity", "red", "feature_2", "part"} <= set(names)
    np.testing.assert_allclose(attribute_values(cloud, "opacity"), sigmoid(cloud.opacity_logits))
    np.testing.assert_allclose(attribute_values(cloud, "green"), cloud.sh[:, 0, 1] * SH_C0 + 0.5, rtol=1e-6)
    np.testing.assert_allclose(attribute_values(cloud, "max_scale"), np.exp(cloud.log_scales).max(1), rtol=1e-6)
    np.testing.assert_array_equal(attribute_values(cloud, "feature_1"), cloud.features[:, 1])
    for name in names:
        assert attribute_values(cloud, name).shape == (64,)
    for bad in ("feature_3", "feature_x", "size"):
        with pytest.raises(ValueError):
            attribute_values(cloud, bad)
