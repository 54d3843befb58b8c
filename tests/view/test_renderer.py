"""The GL splat renderer against the independent numpy 3DGS rasterizer (tests/support/reference_rasterizer.py)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from npga_core.camera.cameras import Camera, frame_points, look_at
from npga_core.model.gaussians import PosedGaussians
from npga_view.rendering.sorting import depth_keys, sort_back_to_front, view_depths
from tests.support.render import COLOUR_ATOL, H, W, off_centre_camera, psnr, random_cloud, reference

MIN_PSNR = 40.0


@pytest.fixture
def renderer(make_renderer):
    r = make_renderer(W, H)
    yield r
    r.release()


def assert_close_mostly(actual: np.ndarray, desired: np.ndarray, atol: float, fraction: float = 0.999) -> None:
    """All but a few elements within atol: a Gaussian whose alpha is within float rounding of 1/255 at a
    pixel may be kept by one implementation and skipped by the other (a jump of up to ~1/255 * feature)."""
    close = np.abs(actual - desired) <= atol
    assert close.mean() >= fraction, f"{(~close).sum()} of {close.size} differ by more than {atol}"
    assert np.abs(actual - desired).max() <= 0.02 * max(np.abs(desired).max(), 1.0)


def check_scene(renderer, g: PosedGaussians, camera: Camera, background=(0.1, 0.2, 0.3), tight: bool = True) -> float:
    """PSNR >= 40 dB against 3DGS; with `tight`, also >= 75 dB against the reference without 3DGS's early
    termination and tile rectangles, i.e. what blending computes (catches small systematic errors)."""
    renderer.set_gaussians(g)
    image = renderer.render(camera, background)
    ref = reference(g, camera, background=background)
    value = psnr(image, ref["rgb"])
    assert value >= MIN_PSNR, f"PSNR {value:.1f} dB"
    assert np.mean(ref["alpha"]) > 0.05, "scene is (nearly) empty: the comparison would prove nothing"
    if tight:
        exact = reference(g, camera, background=background, early_stop=False, tile_rect=False)
        assert psnr(image, exact["rgb"]) >= 75.0
    return value


# --- image agreement with the 3DGS reference ---------------------------------------------------------
def test_random_anisotropic(renderer):
    cam = off_centre_camera((0.4, 0.3, 3.0))
    check_scene(renderer, random_cloud(1500, seed=1), cam)


def test_sh_degree3_view_dependent(renderer):
    g = random_cloud(800, seed=2, sh_degree=3, sh_rest=0.5)
    views = [off_centre_camera((0.0, 0.0, 3.0)), off_centre_camera((2.5, 1.0, -1.5))]
    for cam in views:
        check_scene(renderer, g, cam)
    # the SH part really changes colours with the view: the same Gaussians seen from another side
    one = g.subset(np.arange(1))
    one.means[:] = 0.0
    one.scales[:] = 0.3
    one.opacities[:] = 0.95
    colours = []
    for eye in ((0.0, 0.0, 3.0), (3.0, 0.0, 0.0)):
        renderer.set_gaussians(one)
        colours.append(renderer.render(look_at(eye, (0, 0, 0), fov_y_deg=40, width=W, height=H))[H // 2, W // 2])
    assert np.abs(colours[0] - colours[1]).max() > 0.05


def test_close_up_near_camera(renderer):
    # Gaussians from 0.02 to 0.4 in front of the camera: 3DGS's fixed 0.2 near cut would drop many
    g = random_cloud(400, seed=3, spread=0.08, scale=(0.002, 0.02), centre=(0.0, 0.0, 0.0))
    cam = look_at((0.0, 0.0, 0.2), (0.0, 0.0, 0.0), fov_y_deg=60, width=W, height=H)
    z = view_depths(g.means, cam.world_to_camera)
    assert np.sum((z > 0.01) & (z < 0.2)) > 100
    check_scene(renderer, g, cam)


def test_single_gaussian_closer_than_3dgs_near_plane(renderer):
    g = PosedGaussians(np.array([[0.0, 0.0, 0.0]], np.float32), np.array([[1.0, 0, 0, 0]], np.float32),
                       np.full((1, 3), 0.005, np.float32), np.array([0.9], np.float32),
                       np.zeros((1, 1, 3), np.float32))
    cam = look_at((0.0, 0.0, 0.05), (0.0, 0.0, 0.0), fov_y_deg=40, width=W, height=H)
    renderer.set_gaussians(g)
    alpha = renderer.render(cam, mode="alpha")
    assert alpha.max() == pytest.approx(0.9, abs=0.01)


def test_partly_behind_camera(renderer):
    g = random_cloud(1500, seed=4, spread=0.6)
    cam = off_centre_camera((0.1, 0.05, 0.3), (0.0, 0.0, -1.0), fov=70)  # the camera stands inside the cloud
    z = view_depths(g.means, cam.world_to_camera)
    assert (z < 0).sum() > 300 and (z > 0).sum() > 300
    check_scene(renderer, g, cam)


def test_synthetic_avatar(renderer):
    from npga_core.model.synthetic import make_synthetic_avatar

    avatar = make_synthetic_avatar(3000, latent_dim=5, seed=5)
    g = avatar.pose(None)
    for direction in ("front", "three_quarter_left"):
        check_scene(renderer, g, frame_points(g.means, W, H, direction=direction), background=(1.0, 1.0, 1.0))


@pytest.mark.slow
def test_demo_avatar(make_renderer):
    from npga_core.files.loading import DEMO_AVATAR, load_avatar

    if not DEMO_AVATAR.is_file():
        pytest.skip(f"demo avatar not built ({DEMO_AVATAR})")
    g = load_avatar("demo").pose(None)
    cam = frame_points(g.means, 110, 160)
    r = make_renderer(cam.width, cam.height)
    try:
        check_scene(r, g, cam, background=(1.0, 1.0, 1.0), tight=len(g) <= 50_000)
    finally:
        r.release()


# --- depth, alpha, latent, background ------------------------------------------------------------------
def test_depth_and_alpha_match_reference(renderer):
    g = random_cloud(1000, seed=6, latent_dim=0)
    cam = off_centre_camera((0.3, -0.2, 3.0))
    renderer.set_gaussians(g)
    ref = reference(g, cam)
    alpha = renderer.render(cam, mode="alpha")
    depth = renderer.render(cam, mode="depth")
    assert psnr(alpha, ref["alpha"]) >= MIN_PSNR
    zmax = float(ref["depth"].max())
    assert psnr(depth / zmax, ref["depth"] / zmax) >= MIN_PSNR
    # against the reference without early termination (what blending computes) they agree to float precision
    exact = reference(g, cam, early_stop=False, tile_rect=False)
    assert_close_mostly(alpha, exact["alpha"], atol=2e-4)
    assert_close_mostly(depth, exact["depth"], atol=2e-4 * zmax)


@pytest.mark.parametrize("latent_dim", [5, 30])
def test_latent_composited_like_colour(renderer, latent_dim):
    g = random_cloud(600, seed=7, latent_dim=latent_dim)
    # the first three latent channels are the (view-independent, degree 0) colour itself
    from tests.support.reference_rasterizer import SH_C0

    g.latent[:, :3] = np.maximum(g.sh[:, 0] * SH_C0 + 0.5, 0.0)
    cam = off_centre_camera((0.0, 0.4, 3.0))
    renderer.set_gaussians(g)
    latent = renderer.render_latent(cam)
    assert latent.shape == (H, W, latent_dim)
    rgb = renderer.render(cam, background=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(latent[..., :3], rgb, atol=COLOUR_ATOL)  # the latent targets are float
    exact = reference(g, cam, early_stop=False, tile_rect=False)
    scale = np.abs(exact["latent"]).max()
    assert_close_mostly(latent, exact["latent"], atol=2e-4 * scale)


def test_background_composited_under(renderer):
    g = random_cloud(500, seed=8)
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(g)
    bg = np.array([0.2, 0.5, 0.9], np.float32)
    black = renderer.render(cam)
    alpha = renderer.render(cam, mode="alpha")
    coloured = renderer.render(cam, background=bg)
    np.testing.assert_allclose(coloured, black + (1.0 - alpha[..., None]) * bg, atol=1e-6)
    assert psnr(coloured, reference(g, cam, background=bg)["rgb"]) >= MIN_PSNR
    assert np.allclose(coloured[0, 0], bg, atol=1e-3) or alpha[0, 0] > 0.01


def test_matches_reference_without_early_stop_to_float_precision(renderer):
    g = random_cloud(1200, seed=9, sh_degree=2)
    cam = off_centre_camera((0.5, 0.5, 2.5))
    renderer.set_gaussians(g)
    image = renderer.render(cam, (0.3, 0.3, 0.3))
    exact = reference(g, cam, background=(0.3, 0.3, 0.3), early_stop=False, tile_rect=False)
    assert psnr(image, exact["rgb"]) >= 75.0


# --- conventions -----------------------------------------------------------------------------------------
def test_pixel_centres_follow_opencv(renderer):
    cv2 = pytest.importorskip("cv2")
    point = np.array([[0.13, -0.07, 0.2]], np.float32)
    g = PosedGaussians(point, np.array([[1.0, 0, 0, 0]], np.float32), np.full((1, 3), 0.02, np.float32),
                       np.array([0.8], np.float32), np.zeros((1, 1, 3), np.float32))
    cam = off_centre_camera((0.2, 0.3, 2.0))
    renderer.set_gaussians(g)
    alpha = renderer.render(cam, mode="alpha").astype(np.float64)
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    centroid = np.array([(alpha * xs).sum(), (alpha * ys).sum()]) / alpha.sum()
    rvec, _ = cv2.Rodrigues(cam.rotation)
    expected, _ = cv2.projectPoints(point.astype(np.float64), rvec, cam.translation, cam.intrinsics(), None)
    np.testing.assert_allclose(centroid, expected.reshape(2), atol=0.05)


def test_flipped_draw_and_present(ctx, renderer):
    g = random_cloud(300, seed=10)
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(g)
    image = renderer.render(cam, background=(0.25, 0.5, 0.75))
    tex = ctx.texture((W, H), 4, dtype="f4")
    fbo = ctx.framebuffer([tex])
    try:
        renderer.draw(cam)  # internal target, then composite upright (rows bottom-up) onto another framebuffer
        renderer.present(fbo, background=(0.25, 0.5, 0.75), flip_y=True)
        shown = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
        np.testing.assert_allclose(shown[::-1, :, :3], image, atol=1e-5)
        renderer.draw(cam, framebuffer=fbo, flip_y=True)  # splat straight into a window-like framebuffer
        direct = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
        np.testing.assert_allclose(direct[::-1, :, :3] + (1 - direct[::-1, :, 3:]) * [0.25, 0.5, 0.75], image,
                                   atol=COLOUR_ATOL)  # a float framebuffer against the colour target
    finally:
        fbo.release()
        tex.release()


def test_camera_move_resorts_without_reupload(renderer, make_renderer):
    g = random_cloud(800, seed=11)
    renderer.set_gaussians(g)
    cams = [off_centre_camera((0.0, 0.0, 3.0)), off_centre_camera((3.0, 0.5, 0.0)), off_centre_camera((0, 0, -3))]
    images = [renderer.render(c) for c in cams]
    assert renderer.attribute_uploads == 1
    assert {"sort", "upload", "preprocess", "draw"} <= set(renderer.last_timings)
    fresh = make_renderer(W, H)
    try:
        for cam, image in zip(cams, images, strict=True):
            fresh.set_gaussians(g)
            np.testing.assert_array_equal(fresh.render(cam), image)
    finally:
        fresh.release()


def test_empty_and_fully_culled(renderer):
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(random_cloud(0))
    assert np.all(renderer.render(cam, background=(0.5, 0.5, 0.5)) == 0.5)
    g = random_cloud(50, seed=12, spread=0.1, centre=(0.0, 0.0, 10.0))  # all behind the camera
    renderer.set_gaussians(g)
    assert renderer.render(cam, mode="alpha").max() == 0.0


def test_sh_shape_is_checked(renderer):
    g = random_cloud(10)
    g.sh = np.zeros((10, 5, 3), np.float32)
    with pytest.raises(ValueError):
        renderer.set_gaussians(g)


# --- sorting ---------------------------------------------------------------------------------------------
def test_sort_exact_equals_float_argsort():
    rng = np.random.default_rng(0)
    z = np.abs(rng.normal(1.0, 0.5, 50_000)).astype(np.float32) + 0.02
    z[:100] = z[100:200]  # ties keep index order, as a stable argsort
    np.testing.assert_array_equal(sort_back_to_front(z), np.argsort(-z, kind="stable"))


def test_sort_quantised_keeps_precision_with_far_outliers():
    rng = np.random.default_rng(1)
    z = rng.uniform(0.4, 0.7, 100_000).astype(np.float32)
    far = np.array([5e3, 1e4, 2e3, 1e2, 50.0], np.float32)
    z[:5] = far
    order = sort_back_to_front(z, exact=False)
    assert order.dtype == np.uint32 and len(order) == len(z)
    np.testing.assert_array_equal(order[:5], np.argsort(-far))  # outliers first, in order
    zs = z[order[5:]]
    step = 2 * (0.7 - 0.4) / 60_000
    assert np.max(np.diff(zs)) <= step  # the core keeps a precision of ~(range / 2^16)
    # equal keys keep index order (a stable sort), so ties of the quantisation are the only departures
    keys = depth_keys(z)[order]
    assert np.all(np.diff(keys.astype(np.int64)) >= 0)
    tied = keys[1:] == keys[:-1]
    assert np.all(np.diff(order.astype(np.int64))[tied] > 0)
    assert keys.dtype == np.uint16


def test_sort_culls_behind_near_plane():
    z = np.array([0.5, -1.0, 0.005, 2.0, 0.011], np.float32)
    np.testing.assert_array_equal(sort_back_to_front(z, near=0.01), [3, 0, 4])
    assert sort_back_to_front(np.zeros(0, np.float32)).shape == (0,)
    assert sort_back_to_front(np.full(3, -1.0, np.float32)).shape == (0,)


def test_view_depths():
    cam = look_at((0.0, 0.0, 2.0), (0.0, 0.0, 0.0))
    pts = np.array([[0.0, 0.0, 0.0], [0.3, 0.2, 1.0]], np.float32)
    np.testing.assert_allclose(view_depths(pts, cam.world_to_camera), [2.0, 1.0], atol=1e-6)


# --- command line ----------------------------------------------------------------------------------------
def test_cli_render_png_and_errors(ctx, tmp_path, small_npga, capsys):
    cv2 = pytest.importorskip("cv2")
    from npga_view.cli.main import main

    out = tmp_path / "a.png"
    assert main(["render", str(small_npga), "--out", str(out), "--width", "64", "--height", "96",
                 "--background", "255,255,255"]) == 0
    image = cv2.imread(str(out))
    assert image.shape == (96, 64, 3) and image.min() < 200 and image[0, 0].min() == 255
    assert main(["render", str(small_npga), "--out", str(tmp_path / "d.npy"), "--mode", "depth",
                 "--width", "32", "--height", "48"]) == 0
    assert np.load(tmp_path / "d.npy").shape == (48, 32)
    capsys.readouterr()
    assert main(["render", str(tmp_path / "missing.npga"), "--out", str(out)]) == 2
    assert main(["render", str(small_npga), "--out", str(out), "--camera", str(tmp_path / "none.json")]) == 2
    assert main(["render", str(small_npga), "--out", str(tmp_path / "v.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all("Traceback" not in line for line in err)


# --- contexts --------------------------------------------------------------------------------------------
def test_two_contexts_do_not_interfere(renderer, make_renderer):
    from npga_view.rendering.gl import create_headless_context

    g = random_cloud(300, seed=13)
    cam = off_centre_camera((0.0, 0.0, 3.0))
    renderer.set_gaussians(g)
    first = renderer.render(cam)
    other_ctx = create_headless_context()
    try:
        other = make_renderer(W, H, context=other_ctx)
        other.set_gaussians(random_cloud(300, seed=14))
        other.render(cam)
        np.testing.assert_array_equal(renderer.render(cam), first)  # switches back to its own context
        other.release()
    finally:
        other_ctx.release()


OSMESA_SCRIPT = """
import sys
import numpy as np
from tests.support.render import W, H, off_centre_camera, psnr, random_cloud, reference
from npga_view.rendering.gl import GLUnavailableError, create_headless_context
from npga_view.rendering.renderer import SplatRenderer
try:
    ctx = create_headless_context("osmesa")
except GLUnavailableError as exc:
    print("UNAVAILABLE", exc)
    sys.exit(0)
g = random_cloud(500, seed=15)
cam = off_centre_camera((0.2, 0.1, 3.0))
r = SplatRenderer(ctx, W, H)
r.set_gaussians(g)
print("PSNR", psnr(r.render(cam), reference(g, cam)["rgb"]), ctx.info["GL_RENDERER"])
"""


def test_osmesa_fallback_renders(tmp_path):
    import subprocess

    # its own process: OSMesa becomes moderngl's default context there
    script = OSMESA_SCRIPT
    root = str(Path(__file__).resolve().parents[2])
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=root,
                         env={**os.environ, "PYTHONPATH": root})
    assert res.returncode == 0, res.stderr[-2000:]
    if res.stdout.startswith("UNAVAILABLE"):
        pytest.skip(res.stdout.strip())
    assert float(res.stdout.split()[1]) >= MIN_PSNR


def test_llvmpipe_gets_two_raster_threads_per_cpu_unless_set(monkeypatch):
    """`prefer_raster_threads` (called before the first context) asks llvmpipe for RASTER_THREADS_PER_CPU threads
    per usable CPU, and leaves a person's LP_NUM_THREADS alone."""
    from npga_view.rendering import gl

    monkeypatch.delenv("LP_NUM_THREADS", raising=False)
    gl.prefer_raster_threads()
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert os.environ["LP_NUM_THREADS"] == str(gl.RASTER_THREADS_PER_CPU * cpus)
    monkeypatch.setenv("LP_NUM_THREADS", "3")
    gl.prefer_raster_threads()
    assert os.environ["LP_NUM_THREADS"] == "3"


RASTER_THREADS_SCRIPT = """
import hashlib, os, sys
from npga_view.rendering.gl import create_headless_context
from npga_view.rendering.renderer import SplatRenderer
from tests.support.render import off_centre_camera, random_cloud
ctx = create_headless_context()
r = SplatRenderer(ctx, 160, 120, cpu_colour=False)  # llvmpipe's own threads (the CPU pass: test_cpu_splats.py)
r.set_gaussians(random_cloud(3000, seed=21))
cam = off_centre_camera((0.1, 0.0, 3.0)).resized(384, 320)  # 6 x 5 tiles of 64 pixels among the threads
print(os.environ["LP_NUM_THREADS"], hashlib.sha256(r.render(cam).tobytes()).hexdigest())
"""


def test_the_image_does_not_depend_on_the_raster_threads():
    """The same pixels with 1 and 4 llvmpipe threads (tiles are split among threads; each pixel blends its splats
    in the sorted order either way), so the default of more threads changes only the time."""
    import subprocess

    root = str(Path(__file__).resolve().parents[2])
    out = []
    for n in ("1", "4"):
        res = subprocess.run([sys.executable, "-c", RASTER_THREADS_SCRIPT], capture_output=True, text=True,
                             timeout=120, cwd=root, env={**os.environ, "PYTHONPATH": root, "LP_NUM_THREADS": n})
        assert res.returncode == 0, res.stderr[-2000:]
        out.append(res.stdout.split())
    assert [o[0] for o in out] == ["1", "4"]
    assert out[0][1] == out[1][1]
