"""The renderer's colour targets (npga_view/rendering/targets.py): RGBA16 at half scale for colour images, RGBA32F
for depth and for offline images (`precise_colour`), the same picture either way."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.model.gaussians import PosedGaussians, normalize_quats
from npga_view.rendering.targets import COLOUR_DTYPE, COLOUR_SCALE
from tests.support.render import COLOUR_ATOL, H, W, off_centre_camera, psnr, random_cloud, reference


@pytest.fixture
def renderer(make_renderer):
    r = make_renderer(W, H)
    yield r
    r.release()


def overbright_pair() -> PosedGaussians:
    """An opaque splat of colour 1.8 (SH above 1, as trained 3DGS colours can be) half covered by a translucent
    dark one in front of it: a float target keeps 1.8 * 0.9 behind the front one; a target clamped at 1 would not."""
    means = np.float32([[0.0, 0.0, 0.0], [0.12, 0.0, 0.5]])
    sh = np.zeros((2, 1, 3), np.float32)
    sh[0, 0] = (1.8 - 0.5) / 0.28209479177387814
    sh[1, 0] = (0.1 - 0.5) / 0.28209479177387814
    return PosedGaussians(means, normalize_quats(np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))),
                          np.float32([[0.15, 0.15, 0.15], [0.1, 0.1, 0.1]]), np.float32([0.9, 0.6]), sh)


def test_colour_images_are_16_bit_depth_and_offline_ones_float(renderer):
    g = random_cloud(400, seed=3)
    cam = off_centre_camera((0.3, 0.2, 3.0))
    renderer.set_gaussians(g)
    fast = renderer.render(cam, background=(0.2, 0.3, 0.4))
    assert renderer._colour_tex.dtype == COLOUR_DTYPE
    depth = renderer.render(cam, mode="depth")
    assert renderer._colour_tex.dtype == "f4" and depth.max() > 1.5  # camera-space z, beyond the unorm range
    renderer.precise_colour = True
    precise = renderer.render(cam, background=(0.2, 0.3, 0.4))
    assert renderer._colour_tex.dtype == "f4"
    ref = reference(g, cam, background=(0.2, 0.3, 0.4), early_stop=False, tile_rect=False)["rgb"]
    assert psnr(precise, ref) > psnr(fast, ref) >= 75.0
    np.testing.assert_allclose(fast, precise, atol=COLOUR_ATOL)


def test_colour_above_one_is_kept_as_a_float_target_keeps_it(renderer):
    g = overbright_pair()
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(g)
    renderer.precise_colour = True
    renderer.draw(cam)
    precise = renderer.front_rgba()
    assert precise[..., 0].max() > 1.2  # the splat's premultiplied colour, above 1
    renderer.precise_colour = False
    renderer.draw(cam)
    fast = renderer.front_rgba()
    assert COLOUR_SCALE < 1.0 and renderer._colour_tex.dtype == COLOUR_DTYPE
    np.testing.assert_allclose(fast, precise, atol=COLOUR_ATOL)


def test_present_undoes_the_scale(ctx, renderer):
    g = overbright_pair()
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(g)
    image = renderer.render(cam, background=(0.1, 0.1, 0.1))
    tex = ctx.texture((W, H), 4, dtype="f4")
    fbo = ctx.framebuffer([tex])
    try:
        renderer.present(fbo, background=(0.1, 0.1, 0.1), flip_y=False)
        shown = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)[..., :3]
        np.testing.assert_allclose(shown, image, atol=1e-5)
        assert shown.max() > 1.2  # presented at its true value (the window's 8 bits clamp it, not the target)
    finally:
        fbo.release()
        tex.release()
