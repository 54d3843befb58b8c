"""The pieces of the demo's refine stage (npga_core/demo/): the CPU splat rasteriser against the reference
rasterizer (tests/support/reference_rasterizer.py, which follows diff-gaussian-rasterization), the mesh rasteriser,
the latent compositing and its gradient, G's latent block, and the target colours against the Gaussians'."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from npga_core.camera.cameras import Camera, look_at
from npga_core.demo.mesh_raster import box_filter, crop_camera, rasterize_mesh, supersampled
from npga_core.demo.refine_stage import hidden_features, with_latent_block
from npga_core.demo.splat_raster import rasterize_splats
from npga_core.model.dynamics import ConditionedMLP, MLPConfig
from tests.support.reference_rasterizer import rasterize


def _find_ict() -> tuple[Path | None, str]:
    """The ICT-FaceKit npz (--ict is not a test option: $NPGA_ICT_DIR, else beside the checkout), or why not."""
    from npga_core.demo.ict import find_ict

    try:
        return find_ict(), ""
    except FileNotFoundError as e:
        return None, str(e)


ICT, ICT_MISSING = _find_ict()


def random_cloud(n: int, seed: int):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    sh = rng.normal(0, 0.7, (n, 4, 3))
    sh[:, 1:] *= 0.3 / 0.7
    return (rng.normal(0, 0.5, (n, 3)), q, np.exp(rng.uniform(np.log(0.01), np.log(0.12), (n, 3))),
            rng.uniform(0.05, 1.0, n), sh, rng.normal(size=(n, 5)))


@pytest.mark.parametrize("seed", [0, 1])
def test_splat_rasteriser_matches_the_reference_without_early_stop(seed) -> None:
    means, q, s, o, sh, lat = random_cloud(500, seed)
    cam = look_at((0.3, -0.2, 4.0), (0, 0, 0), width=96, height=80, fov_y_deg=40)
    ref = rasterize(means, q, s, o, sh, cam, latent=lat, early_stop=False, tile_rect=False)
    img = rasterize_splats(means, q, s, o, sh, cam, min_weight=0.0)
    np.testing.assert_allclose(img.rgb, ref["rgb"], atol=1e-5)  # black background: rgb is C
    np.testing.assert_allclose(img.alpha, ref["alpha"], atol=1e-5)
    np.testing.assert_allclose(img.over((0.2, 0.5, 0.9)), ref["rgb"] + (1 - ref["alpha"])[..., None]
                               * np.array([0.2, 0.5, 0.9]), atol=1e-5)
    np.testing.assert_allclose(img.composite(torch.from_numpy(lat)).numpy(), ref["latent"], atol=1e-5)
    # cropping the camera crops the image
    crop = rasterize_splats(means, q, s, o, sh, crop_camera(cam, 20, 10, 40, 30), min_weight=0.0, fov_camera=cam)
    np.testing.assert_allclose(crop.rgb, img.rgb[10:40, 20:60], atol=1e-6)


def test_latent_compositing_is_differentiable_and_linear() -> None:
    means, q, s, o, sh, lat = random_cloud(200, 3)
    cam = look_at((0.0, 0.0, 4.0), (0, 0, 0), width=48, height=40, fov_y_deg=40)
    img = rasterize_splats(means, q, s, o, sh, cam, min_weight=0.0)
    h = torch.from_numpy(lat).requires_grad_(True)
    img.composite(h).sum().backward()
    # d(sum of the image)/dh_i = the total blending weight of Gaussian i, for every channel
    total = np.bincount(img.gaussian, img.weight, minlength=len(lat))
    np.testing.assert_allclose(h.grad.numpy(), np.repeat(total[:, None], 5, 1), atol=1e-5)
    np.testing.assert_allclose(img.alpha.sum(), total.sum(), rtol=1e-5)
    rows = torch.from_numpy(np.unique(img.gaussian))
    np.testing.assert_allclose(img.composite(h.detach()[rows], rows).numpy(),
                               img.composite(h.detach()).numpy(), atol=1e-6)


def test_mesh_rasteriser_covers_projects_and_occludes() -> None:
    # a square at z = 2 (two triangles) and a smaller triangle in front of it at z = 1.5
    verts = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2], [-0.2, -0.2, 1.5], [0.3, -0.2, 1.5],
                      [0.0, 0.3, 1.5]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    cam = Camera(np.eye(4), 20.0, 20.0, 32.0, 24.0, 64, 48)  # at the origin looking along +z
    fr = rasterize_mesh(verts, faces, cam)
    # the square spans u = 32 +- 10, v = 24 +- 10: pixel centres 22.5 .. 41.5
    cov = fr.covered
    assert cov[14:34, 22:42].all() and cov.sum() == 400
    # barycentrics are perspective-correct: the interpolated 3D point lies on each pixel's ray
    ys, xs = np.nonzero(cov)
    p = (verts[faces[fr.triangle[ys, xs]]] * fr.bary[ys, xs][..., None]).sum(axis=1)
    np.testing.assert_allclose(20.0 * p[:, 0] / p[:, 2] + 32.0, xs + 0.5, atol=1e-6)
    np.testing.assert_allclose(20.0 * p[:, 1] / p[:, 2] + 24.0, ys + 0.5, atol=1e-6)
    np.testing.assert_allclose(fr.depth[ys, xs], p[:, 2], atol=1e-9)
    # the near triangle hides the square where it lies (centre pixel)
    assert fr.triangle[24, 32] == 2 and abs(fr.depth[24, 32] - 1.5) < 1e-9
    # 2 x 2 supersampling: coverage is the covered fraction of each pixel
    ss = rasterize_mesh(verts, faces, supersampled(cam, 2))
    cov2 = box_filter(ss.covered.astype(float), 2)
    assert cov2.shape == (48, 64) and cov2[24, 32] == 1.0 and cov2[0, 0] == 0.0
    assert np.abs(cov2.sum() - 400.0) < 1.0


def test_g_latent_block_leaves_the_other_outputs_and_reads_the_hidden_layer() -> None:
    torch.manual_seed(0)
    g = ConditionedMLP(MLPConfig(4, 6, [("rotation", 4), ("scale", 3), ("sh", 3)], hidden=32, depth=4, pos_freqs=2))
    mu, f, z = torch.randn(50, 3), torch.randn(50, 4), torch.randn(6)
    w, b = torch.randn(5, 32), torch.randn(5)
    g2 = with_latent_block(g, w, b)
    assert g2.config.outputs[-1] == ("latent", 5)
    with torch.no_grad():
        old, new = g(mu, f, z), g2(mu, f, z)
        torch.testing.assert_close(new[:, :10], old, rtol=1e-5, atol=1e-6)
        hidden = hidden_features(g, g.precompute(mu, f), z)
        torch.testing.assert_close(new[:, 10:], hidden @ w.T + b, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(hidden @ g.layers[-1].weight.T + g.layers[-1].bias, old, rtol=1e-4, atol=1e-5)


@pytest.mark.skipif(ICT is None, reason=ICT_MISSING)
def test_targets_colour_the_surface_like_the_gaussians() -> None:
    """At the neutral face the target's colour at a Gaussian's surface point is the Gaussian's own (SH) colour,
    up to the jitter and cavity interpolation; the colour model reproduces the canonical build exactly."""
    from npga_core.demo.canonical import build_canonical
    from npga_core.demo.colors import AlbedoModel
    from npga_core.demo.ict import load_ict
    from npga_core.demo.refine_targets import HeadRenderer
    from npga_core.demo.sampling import sample_surface
    from npga_core.demo.splat_raster import sh_colour

    head = load_ict(ICT)
    canon = build_canonical(head, 6000, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    s = sample_surface(head, 6000, rng)
    albedo = AlbedoModel.draw(s, rng)
    np.testing.assert_array_equal(s.points, canon.samples.points)
    hr = HeadRenderer(head, canon, albedo)
    cam = look_at((0.0, 0.0, 0.9), (0.0, 0.0, 0.0), width=64, height=64, fov_y_deg=20)
    w0 = np.zeros(head.n_expressions, np.float32)
    verts, normals, fv = hr.posed_mesh(w0)
    face = s.part == 0
    got = hr.shade(verts, normals, fv, s.tri[face], s.bary[face].astype(np.float64), w0, cam)
    dirs = s.points[face] - cam.camera_center
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    want = sh_colour(canon.cloud.sh[face].astype(np.float64), dirs)
    err = np.abs(got - want)
    assert np.median(err) < 0.01 and np.percentile(err, 99) < 0.06


def test_missing_ict_kit_says_where_it_looked(tmp_path, monkeypatch) -> None:
    """No machine-specific default: --ict, then $NPGA_ICT_DIR, then ../shared/data/ict_facekit beside the
    checkout; a missing kit is one message naming the place looked in and the ways to name another."""
    from npga_core.demo.ict import ICT_ENV, find_ict, ict_candidates

    with pytest.raises(FileNotFoundError, match=re.escape(f"{tmp_path / 'nothing'} (--ict)") + ".*NPGA_ICT_DIR"):
        find_ict(tmp_path / "nothing")
    monkeypatch.setenv(ICT_ENV, str(tmp_path))
    assert ict_candidates() == [(tmp_path, f"${ICT_ENV}")]
    with pytest.raises(FileNotFoundError, match=r"\$NPGA_ICT_DIR\)"):
        find_ict()
    monkeypatch.delenv(ICT_ENV)
    (where, how), = ict_candidates()
    assert how == "beside the checkout" and where == (Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
                                                      / "ict_facekit").resolve()
