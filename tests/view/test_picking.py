"""Renderer inspection features: the id pass (picking), drawn counts, and the points / ellipsoids styles."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.camera.cameras import look_at
from npga_core.inspection.measures import count_gaussians
from npga_core.model.gaussians import PosedGaussians, normalize_quats, rgb_to_sh0
from tests.support.reference_rasterizer import project

W, H = 64, 80


@pytest.fixture
def renderer(make_renderer):
    r = make_renderer(W, H)
    yield r
    r.release()


def camera(width: int = W, height: int = H):
    return look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0, width=width, height=height)


def gaussians(means, scales, opacities, rgb=None, quats=None) -> PosedGaussians:
    n = len(means)
    rgb = np.full((n, 3), 0.6, np.float32) if rgb is None else np.asarray(rgb, np.float32)
    return PosedGaussians(
        means=np.asarray(means, np.float32).reshape(n, 3),
        quats=normalize_quats(np.tile([1.0, 0, 0, 0], (n, 1)) if quats is None else np.asarray(quats)),
        scales=np.asarray(scales, np.float32).reshape(n, 3),
        opacities=np.asarray(opacities, np.float32).reshape(n),
        sh=rgb_to_sh0(rgb)[:, None, :],
    )


def random_gaussians(n: int, seed: int) -> PosedGaussians:
    rng = np.random.default_rng(seed)
    return gaussians(rng.normal(0, 0.4, (n, 3)), np.exp(rng.uniform(np.log(0.02), np.log(0.15), (n, 3))),
                     rng.uniform(0.05, 1.0, n), rng.uniform(0, 1, (n, 3)), rng.normal(size=(n, 4)))


def reference_ids(g: PosedGaussians, cam, threshold: float) -> np.ndarray:
    """Per pixel the front-most Gaussian (by centre depth) with alpha >= threshold there, by the 3DGS alpha rule."""
    p = project(g.means, g.quats, g.scales, g.opacities, g.sh, cam)
    ids = np.full((cam.height, cam.width), -1)
    dx = np.arange(cam.width) + 0.5
    dy = np.arange(cam.height) + 0.5
    for i in np.argsort(p["depth"]):
        if not p["valid"][i]:
            continue
        x = dx[None, :] - p["uv"][i, 0]
        y = dy[:, None] - p["uv"][i, 1]
        a, b, c = p["conic"][i]
        power = -0.5 * (a * x * x + c * y * y) - b * x * y
        alpha = np.minimum(0.99, p["opacity"][i] * np.exp(power))
        ids[(ids < 0) & (power <= 0) & (alpha >= 1 / 255) & (alpha >= threshold)] = i
    return ids


# --- picking ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("threshold", [0.2, 0.6])
def test_render_ids_match_the_front_most_rule(renderer, threshold):
    g = random_gaussians(150, seed=1)
    cam = camera()
    renderer.set_gaussians(g)
    ids = renderer.render_ids(cam, threshold)
    expected = reference_ids(g, cam, threshold)
    assert (expected >= 0).mean() > 0.1
    assert (ids == expected).mean() > 0.995  # a pixel where an alpha is within rounding of the threshold may differ


def test_pick_returns_the_front_gaussian_above_the_threshold(renderer):
    cam = camera()
    g = gaussians([[0.0, 0.0, 0.5], [0.0, 0.0, 0.0], [0.6, 0.6, 0.0]], np.full((3, 3), 0.08), [0.9, 0.9, 0.9])
    renderer.set_gaussians(g)
    u, v = cam.project(g.means[:1])[0]
    assert renderer.pick(cam, u, v) == 0
    u2, v2 = cam.project(g.means[2:])[0]
    assert renderer.pick(cam, u2, v2) == 2
    assert renderer.pick(cam, 1.0, 1.0) is None  # empty corner
    assert renderer.pick(cam, -5.0, 10.0) is None and renderer.pick(cam, W + 1, 10) is None
    g.opacities[0] = 0.1  # below the pick threshold: the one behind is picked through it
    renderer.set_gaussians(g)
    assert renderer.pick(cam, u, v) == 1
    assert renderer.pick(cam, u, v, threshold=0.05) == 0
    ids = renderer.render_ids(cam)
    for x, y in ((u, v), (u2, v2), (3, 70), (30, 41)):
        expected = renderer.pick(cam, x, y)
        assert ids[int(y), int(x)] == (-1 if expected is None else expected)


def test_pick_after_a_flipped_draw_uses_image_coordinates(renderer, ctx):
    cam = camera()
    g = gaussians([[0.5, -0.6, 0.0]], [[0.05] * 3], [0.9])  # world y is up: lower right in the image
    renderer.set_gaussians(g)
    tex = ctx.texture((W, H), 4, dtype="f4")
    fbo = ctx.framebuffer([tex])
    try:
        renderer.draw(cam, framebuffer=fbo, flip_y=True)  # as the window draws
        u, v = cam.project(g.means)[0]
        assert v > H / 2 and renderer.pick(cam, u, v) == 0
        assert renderer.pick(cam, u, H - v) is None
    finally:
        fbo.release()
        tex.release()


# --- counts -------------------------------------------------------------------------------------------------
def test_drawn_count_and_mask_on_a_known_subset(renderer):
    cam = camera()  # half extent at z = 0: 3 tan(20 deg) = 1.09 vertically, 0.87 horizontally
    g = gaussians(
        [[0.0, 0.0, 0.0], [0.3, -0.4, 0.2], [-0.5, 0.5, -0.3],  # in view
         [0.0, 0.0, 3.5],  # behind the camera
         [0.2, 0.2, 0.0],  # in view, but opacity below 1/255
         [5.0, 0.0, 0.0],  # far outside the image
         [0.95, 0.0, 0.0]],  # centre just outside the right edge, its extent reaches into the image
        [[0.05] * 3] * 6 + [[0.2] * 3],
        [0.8, 0.8, 0.8, 0.8, 0.002, 0.8, 0.8])
    renderer.set_gaussians(g)
    renderer.render(cam)
    expected = np.array([1, 1, 1, 0, 0, 0, 1], bool)
    np.testing.assert_array_equal(renderer.drawn_mask(), expected)
    assert renderer.drawn_count == 4
    c = count_gaussians(cam, g.means, drawn=renderer.drawn_mask())
    assert (c.total, c.in_frustum, c.drawn) == (7, 4, 4)
    renderer.set_gaussians(gaussians(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)))
    assert renderer.drawn_count == 0 and renderer.drawn_mask().shape == (0,)


# --- styles -------------------------------------------------------------------------------------------------
def test_points_style_draws_opaque_discs(renderer):
    cam = camera()
    g = gaussians([[0.1, -0.05, 0.0]], [[0.2, 0.05, 0.01]], [0.5], [[0.2, 0.4, 0.8]])
    renderer.set_gaussians(g)
    renderer.style, renderer.point_px = "points", 3.0
    image = renderer.render(cam, background=(0.0, 0.0, 0.0))
    alpha = renderer.render(cam, mode="alpha")
    u, v = cam.project(g.means)[0]
    x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    inside = (x - u) ** 2 + (y - v) ** 2 <= 9.0
    np.testing.assert_array_equal(alpha > 0, inside)
    np.testing.assert_allclose(alpha[inside], 1.0)
    # the colour target keeps 16 bits at half scale (targets.py): steps of 2 / 65535
    np.testing.assert_allclose(image[inside], np.tile([0.2, 0.4, 0.8], (inside.sum(), 1)), atol=2e-5)
    assert renderer.pick(cam, u + 2.0, v) == 0 and renderer.pick(cam, u + 4.0, v) is None


def test_ellipsoids_style_fills_the_one_sigma_ellipse_with_shading(renderer):
    cam = camera()
    q = normalize_quats(np.array([[np.cos(0.3), 0.0, 0.0, np.sin(0.3)]]))
    g = gaussians([[0.0, 0.1, 0.0]], [[0.25, 0.08, 0.05]], [0.7], [[1.0, 1.0, 1.0]], q)
    renderer.set_gaussians(g)
    renderer.style = "ellipsoids"
    image = renderer.render(cam)
    p = project(g.means, g.quats, g.scales, g.opacities, g.sh, cam)
    x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dx, dy = x - p["uv"][0, 0], y - p["uv"][0, 1]
    a, b, c = p["conic"][0]
    mahal = a * dx * dx + 2 * b * dx * dy + c * dy * dy
    covered = image[..., 0] > 0
    assert np.mean(covered == (mahal <= 1.0)) > 0.998  # pixels with mahal within rounding of 1 may differ
    sure = mahal < 0.98
    np.testing.assert_allclose(image[sure, 0], 0.3 + 0.7 * np.sqrt(1.0 - mahal[sure]), atol=1e-3)


def test_geometry_styles_skip_faint_gaussians_and_splats_stay_unchanged(renderer):
    cam = camera()
    g = random_gaussians(300, seed=5)
    renderer.set_gaussians(g)
    splats = renderer.render(cam)
    renderer.style = "points"
    assert not np.array_equal(renderer.render(cam), splats)
    g.opacities[:] = np.where(np.arange(300) == 7, 0.04, 0.0)  # only one Gaussian, below the style threshold
    renderer.set_gaussians(g)
    assert renderer.render(cam, mode="alpha").max() == 0.0
    renderer.style = "splats"
    assert renderer.render(cam, mode="alpha").max() > 0.0
    renderer.set_gaussians(random_gaussians(300, seed=5))
    np.testing.assert_array_equal(renderer.render(cam), splats)
    renderer.style = "cubes"
    with pytest.raises(ValueError, match="style"):
        renderer.render(cam)
