"""The colour pass on the CPU (npga_view/rendering/cpu_splats.py): the GL pass's image, bad values, its warm-up.

Its images are also checked against the independent reference rasterizer by every renderer test (the "cpu" entry
of the `gl_path` fixture in tests/conftest.py); here it is checked against the GL colour pass of the same renderer.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from npga_core.camera.cameras import frame_points
from npga_core.model.gaussians import PosedGaussians
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.rendering import cpu_splats
from tests.support.render import off_centre_camera, psnr, random_cloud


@pytest.fixture(scope="module")
def pair(ctx):
    """Two 4.3 renderers: the GL colour pass and the CPU one."""
    from npga_view.rendering.renderer import SplatRenderer

    if ctx.version_code < 430:
        pytest.skip("the OpenGL 4.3 path needs a 4.3 context")
    assert cpu_splats.warm_up(wait=True), cpu_splats.status()
    gl, cpu = SplatRenderer(ctx, 64, 64, cpu_colour=False), SplatRenderer(ctx, 64, 64, cpu_colour=True)
    yield gl, cpu
    gl.release(), cpu.release()


def both(pair, g: PosedGaussians, camera, **kw) -> tuple[np.ndarray, np.ndarray]:
    """The finished premultiplied RGBA image of the GL and of the CPU colour pass."""
    out = []
    for r in pair:
        r.set_gaussians(g)
        r.draw(camera, **kw)
        assert r.last_timings["cpu"] == float(r is pair[1])
        out.append(r.front_rgba().copy())
    return out[0], out[1]


def assert_same_image(gl: np.ndarray, cpu: np.ndarray) -> None:
    """The GL target rounds to 16 bits at every blended layer (a step of 3e-5); the CPU pass blends in float and
    rounds once. A fragment within rounding of alpha = 1/255 may be kept by one and not the other."""
    assert np.isfinite(cpu).all()
    close = np.abs(cpu - gl) <= 1e-3
    assert close.mean() >= 0.999, f"{(~close).sum()} of {close.size} values differ by more than 1e-3"
    assert np.abs(cpu - gl).max() <= 0.02
    assert psnr(cpu, gl) >= 80.0


@pytest.mark.parametrize("size", [(64, 64), (200, 131), (333, 250)])
@pytest.mark.parametrize("flip", [False, True])
def test_the_cpu_pass_draws_the_gl_pass_image(pair, size, flip):
    g = make_synthetic_avatar(6000, seed=3).pose()
    cam = frame_points(g.means, *size, direction="three_quarter_left")
    gl, cpu = both(pair, g, cam, flip_y=flip)
    assert gl[..., 3].mean() > 0.05, "nearly empty: the comparison would prove nothing"
    assert_same_image(gl, cpu)


def test_anisotropic_splats_off_centre_and_a_clear_colour(pair):
    g = random_cloud(3000, seed=5, sh_degree=3, scale=(0.005, 0.3))
    cam = off_centre_camera((0.3, 0.2, 2.2))
    gl, cpu = both(pair, g, cam, clear=(0.2, 0.1, 0.05, 0.5))
    assert_same_image(gl, cpu)


def test_precise_target(pair):
    g = random_cloud(2000, seed=8, sh_degree=1)
    cam = off_centre_camera((0.0, 0.0, 2.5))
    for r in pair:
        r.precise_colour = True
    try:
        gl, cpu = both(pair, g, cam)
    finally:
        for r in pair:
            r.precise_colour = False
    assert_same_image(gl, cpu)
    assert np.abs(cpu - gl).max() < 2e-3  # no 16-bit rounding on either side: only the 1/255 edge and exp


def test_bad_values_draw_what_the_gl_pass_draws(pair):
    g = random_cloud(2000, seed=9, scale=(0.01, 0.1))
    g.means[:50] = np.nan
    g.scales[50:60] = np.inf
    g.scales[60:70] = 1e6  # splats covering the whole image and far beyond
    g.quats[70:80] = 0.0
    g.opacities[80:90] = np.nan
    g.opacities[90:100] = 0.0
    g.sh[100:110] = 1e30
    cam = off_centre_camera((0.0, 0.0, 2.5))
    for r in pair:
        r.precise_colour = True  # float targets: colour 1e30 is kept by both (a 16-bit target clamps each layer)
    try:
        gl, cpu = both(pair, g, cam)
    finally:
        for r in pair:
            r.precise_colour = False
    assert gl[..., 3].min() > 0.5, "the huge splats cover the image"
    np.testing.assert_array_equal(np.isfinite(cpu), np.isfinite(gl))
    ok = np.isfinite(gl)
    assert np.allclose(cpu[ok], gl[ok], rtol=2e-3, atol=2e-3)


def test_a_budgeted_image_is_the_whole_image_in_slices(pair):
    _, r = pair
    g = make_synthetic_avatar(6000, seed=4).pose()
    cam = frame_points(g.means, 300, 260, direction="front")
    r.set_gaussians(g)
    r.draw(cam)
    whole = r.front_rgba().copy()
    r.begin_draw(cam)
    progress = []
    while not r.continue_draw(0.0):
        progress.append(r.progress)
    # the first slice bins the splats (no budget left for tiles), then every slice blends tiles
    assert len(progress) >= 3 and progress[0] == 0.0 and progress[-1] < 1.0
    assert all(b > a for a, b in zip(progress, progress[1:], strict=False))
    assert r.last_timings["cpu"] == 1.0 and r.last_timings["slices"] >= 4
    np.testing.assert_array_equal(r.front_rgba(), whole)


def test_a_slow_small_batch_does_not_shrink_the_next_slices(pair, monkeypatch):
    """A batch of a few tiles that takes long (the threads woken late, a preempted thread) moves the measured rate
    by at most `RATE_STEP` (a 1-tile batch of 11 ms once raised it 500-fold: the next images came a few tiles per UI
    frame)."""
    import time

    from npga_view.rendering import cpu_kernels

    _, r = pair
    g = make_synthetic_avatar(6000, seed=4).pose()
    cam = frame_points(g.means, 512, 448, direction="front")
    r.set_gaussians(g)
    r.begin_draw(cam)
    cpu = r.cpu_pass
    real = cpu_kernels.draw_tiles
    monkeypatch.setattr(cpu_kernels, "draw_tiles", lambda *a: (time.sleep(0.011), real(*a))[1])
    assert not r.continue_draw(0.0)  # the binning only
    before = cpu.ms_per_work
    assert not r.continue_draw(0.0)  # the smallest batch (a tile), 11 ms late
    lo, hi = cpu_splats.RATE_STEP
    assert before * lo <= cpu.ms_per_work <= before * hi
    assert 0.0 < cpu.progress < 1.0
    while not r.continue_draw(50.0):
        pass


def test_the_image_does_not_depend_on_the_threads(pair):
    """A tile is blended whole by one thread, in the sorted order: the same bytes with one thread or several."""
    from npga_view.rendering import cpu_kernels

    _, r = pair
    g = random_cloud(3000, seed=21)
    cam = off_centre_camera((0.1, 0.0, 3.0)).resized(384, 320)
    r.set_gaussians(g)
    images = []
    threads = cpu_kernels.nb.get_num_threads()
    try:
        for n in sorted({1, threads}):
            cpu_kernels.nb.set_num_threads(n)
            r._prepared = None
            images.append(r.render(cam))
    finally:
        cpu_kernels.nb.set_num_threads(threads)
    assert r.last_timings["cpu"] == 1.0 and images[0].max() > 0.1
    assert all(np.array_equal(images[0], im) for im in images)


def test_a_still_camera_with_new_splats_draws_the_new_splats(pair):
    """The splats are read back once per pre-pass: a new pose seen by the same camera is a new pre-pass."""
    _, r = pair
    g = make_synthetic_avatar(6000, seed=4).pose()
    cam = frame_points(g.means, 120, 100, direction="front")
    r.set_gaussians(g)
    first = r.render(cam)
    moved = PosedGaussians(g.means + np.float32(0.01), g.quats, g.scales, g.opacities, g.sh)
    r.set_gaussians(moved)
    assert not np.array_equal(r.render(cam), first)


def test_which_gl_gets_the_cpu_pass(monkeypatch):
    monkeypatch.delenv(cpu_splats.ENV, raising=False)
    assert cpu_splats.wanted("llvmpipe (LLVM 15.0.6, 256 bits)")
    assert cpu_splats.wanted("softpipe")
    assert not cpu_splats.wanted("NVIDIA GeForce RTX 4090/PCIe/SSE2")
    assert not cpu_splats.wanted("AMD Radeon Pro W7900 (radeonsi, navi31, LLVM 17.0.6, DRM 3.54)")
    monkeypatch.setenv(cpu_splats.ENV, "0")
    assert not cpu_splats.wanted("llvmpipe (LLVM 15.0.6, 256 bits)")
    monkeypatch.setenv(cpu_splats.ENV, "1")
    assert cpu_splats.wanted("NVIDIA GeForce RTX 4090/PCIe/SSE2")


def test_kernels_that_fail_leave_the_gl_pass(ctx, monkeypatch):
    from npga_view.rendering.renderer import SplatRenderer

    if ctx.version_code < 430:
        pytest.skip("the OpenGL 4.3 path needs a 4.3 context")

    def refuse():
        raise ImportError("No module named 'numba'")

    monkeypatch.setattr(cpu_splats, "_state", {"status": "off", "error": ""})
    monkeypatch.setattr(cpu_splats, "_kernels", None)
    monkeypatch.setattr(cpu_splats, "_load", refuse)
    assert not cpu_splats.warm_up(wait=True)
    assert cpu_splats.status().startswith("failed (ImportError")
    r = SplatRenderer(ctx, 64, 64, cpu_colour=True)
    try:
        g = make_synthetic_avatar(2000, seed=1).pose()
        r.set_gaussians(g)
        image = r.render(frame_points(g.means, 80, 60))
        assert r.last_timings["cpu"] == 0.0 and image.max() > 0.1
        assert r.colour_pass.startswith("GL (CPU pass: failed")
    finally:
        r.release()


def test_warm_up_compiles_in_a_helper_process_and_the_renderer_then_uses_it(tmp_path):
    """A process without numba's cache: the first images are the GL pass's while a helper process compiles (the
    window's frames are not stalled by the compiler); then the CPU pass draws, and the helper has exited."""
    script = textwrap.dedent("""
        import os, sys, time
        import numpy as np
        from npga_core.camera.cameras import frame_points
        from npga_core.model.synthetic import make_synthetic_avatar
        from npga_view.rendering import cpu_splats
        from npga_view.rendering.gl import create_headless_context
        from npga_view.rendering.renderer import SplatRenderer

        if __name__ == "__main__":
            ctx = create_headless_context()
            r = SplatRenderer(ctx, 64, 64, cpu_colour=True)
            g = make_synthetic_avatar(2000, seed=1).pose()
            r.set_gaussians(g)
            cam = frame_points(g.means, 80, 60)
            r.draw(cam)
            first = r.last_timings["cpu"]
            deadline = time.monotonic() + 600
            while cpu_splats.status() != "ready" and time.monotonic() < deadline:
                time.sleep(0.05)
            import multiprocessing as mp
            time.sleep(0.2)
            r._prepared = None
            r.draw(cam)
            print(first, r.last_timings["cpu"], cpu_splats.status(), len(mp.active_children()))
    """)
    path = tmp_path / "warm.py"
    path.write_text(script)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop(cpu_splats.ENV, None)
    out = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, env=env, timeout=900,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    first, later, status, children = out.stdout.split()
    assert (first, later, status, children) == ("0.0", "1.0", "ready", "0"), out.stdout
    assert any((tmp_path / "cache").rglob("*.nbi")), "nothing was written to numba's cache"
    assert math.isfinite(float(later))
