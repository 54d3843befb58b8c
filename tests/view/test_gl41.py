"""The OpenGL 4.1 renderer path (#18, `npga_view/rendering/renderer41.py`): no compute shaders, no storage buffers.

Checked here without a Mac:
- in-process on this machine's 4.5 context, the 4.1 path forced: its images against the independent reference
  rasterizer (tests/support/reference_rasterizer.py) as closely as the 4.3 path's, and against the 4.3 path itself;
- every renderer test (test_renderer.py, test_picking.py, test_budgeted_draw.py, test_live_detail.py,
  test_knn_lines.py) runs on both paths: they take the `gl_path` fixture (tests/conftest.py);
- under Mesa's 4.1 core override (MESA_GL_VERSION_OVERRIDE=4.1FC, MESA_GLSL_VERSION_OVERRIDE=410, where
  compute shaders and storage buffers do not exist; Mesa reads it once per process, so in a process of its
  own): the factory chooses the 4.1 path by itself and its images match the reference rasterizer, the CLI
  chooses it too, and the window opens a 4.1 context (after its 4.3 request is refused) and shows the demo;
- the 4.1 shaders declare `#version 410 core` and use nothing newer.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from npga_core.camera.cameras import frame_points
from tests.support.render import H, W, accumulated, off_centre_camera, psnr, random_cloud, reference

ROOT = Path(__file__).resolve().parents[2]
MESA_41 = {"MESA_GL_VERSION_OVERRIDE": "4.1FC", "MESA_GLSL_VERSION_OVERRIDE": "410"}


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ, **MESA_41, **extra)
    env.pop("NPGA_VIEW_GL", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


@pytest.fixture
def paths(ctx):
    from npga_view.rendering.factory import create_renderer

    # the 4.3 path with its GL colour pass: the 4.1 shaders are checked against the 4.3 ones
    r41, r43 = create_renderer(ctx, W, H, path="41"), create_renderer(ctx, W, H, path="43", cpu_colour=False)
    yield r41, r43
    r41.release()
    r43.release()


def _scenes():
    from npga_core.model.synthetic import make_synthetic_avatar

    avatar = make_synthetic_avatar(3000, latent_dim=5, seed=5).pose(None)
    return [
        ("anisotropic", random_cloud(1500, seed=1), off_centre_camera((0.4, 0.3, 3.0))),
        ("sh degree 3", random_cloud(800, seed=2, sh_degree=3, sh_rest=0.5), off_centre_camera((2.5, 1.0, -1.5))),
        ("camera inside", random_cloud(1500, seed=4, spread=0.6), off_centre_camera((0.1, 0.05, 0.3), (0, 0, -1), 70)),
        ("avatar", avatar, frame_points(avatar.means, W, H, direction="three_quarter_left")),
    ]


def test_same_fidelity_as_the_43_path(paths):
    """PSNR against 3DGS (the reference with early termination), measured here (Mesa llvmpipe), the same for both
    paths to 0.01 dB: anisotropic 81.83, SH degree 3 75.03, camera inside the cloud 82.40, synthetic avatar
    72.07 dB; the two paths' images agree to float rounding (141-152 dB, max difference < 1e-6)."""
    r41, r43 = paths
    bg = (0.1, 0.2, 0.3)
    for name, g, cam in _scenes():
        ref = reference(g, cam, background=bg)["rgb"]
        images = []
        for r in (r41, r43):
            r.set_gaussians(g)
            images.append(r.render(cam, bg))
        p41, p43 = psnr(images[0], ref), psnr(images[1], ref)
        assert p43 >= 40.0 and abs(p41 - p43) <= 0.05, f"{name}: 4.1 path {p41:.2f} dB, 4.3 path {p43:.2f} dB"
        assert psnr(images[0], images[1]) >= 100.0, name
        same = r41.drawn_mask() == r43.drawn_mask()
        assert same.mean() >= 0.999 and r41.drawn_count == pytest.approx(r43.drawn_count, abs=2), name


def test_other_passes_match_the_43_path(paths):
    r41, r43 = paths
    g = random_cloud(1200, seed=9, sh_degree=2, latent_dim=7)
    cam = off_centre_camera((0.3, -0.2, 3.0))
    out = []
    for r in (r41, r43):
        r.set_gaussians(g)
        res = {m: r.render(cam, mode=m) for m in ("depth", "alpha")}
        res["latent"] = r.render_latent(cam)
        res["ids"] = r.render_ids(cam)
        res["pick"] = r.pick(cam, W / 2, H / 2)
        for style in ("points", "ellipsoids"):
            r.style = style
            res[style] = r.render(cam)
        r.style = "splats"
        r.set_lines(g.means[:50], np.stack([np.arange(49), np.arange(1, 50)], axis=1), np.ones((49, 3)) * 0.8)
        res["lines"] = r.render(cam)
        r.clear_lines()
        out.append(res)
    a, b = out
    assert a["pick"] == b["pick"] is not None
    assert (a["ids"] == b["ids"]).mean() >= 0.999
    assert a["lines"].max() > 0.5 and not np.array_equal(a["lines"], a["points"])
    for key in ("depth", "alpha", "latent", "points", "ellipsoids", "lines"):
        np.testing.assert_allclose(a[key], b[key], atol=1e-4 * max(1.0, np.abs(b[key]).max()), err_msg=key)


def test_sliced_drawing_and_points_path(paths):
    """The scheduler's API: slices from `u_first` compose to one draw; points and quads give the same pixels."""
    r41, _ = paths
    g = random_cloud(3000, seed=3, scale=(0.005, 0.03))
    cam = off_centre_camera((0.0, 0.0, 3.0))
    r41.set_gaussians(g)
    r41.use_points = False
    quads = r41.render(cam)
    r41.use_points = True
    points = r41.render(cam)
    assert r41.last_timings["points"] == 1.0
    np.testing.assert_array_equal(points, quads)
    r41.begin_draw(cam)
    calls = 1
    while not r41.continue_draw(0.0):  # the smallest budget: one minimal slice per call
        calls += 1
    assert calls >= 2 and r41.last_timings["slices"] == calls
    np.testing.assert_array_equal(accumulated(r41)[..., :3], points)


def test_the_callers_arrays_may_be_reused_after_upload(paths):
    """The CPU pre-pass reads the cloud at every camera move: it keeps its own copies (a pose worker's shared
    memory slot is overwritten by the next pose)."""
    r41, _ = paths
    g = random_cloud(800, seed=21, sh_degree=3)
    cams = [off_centre_camera((0.0, 0.0, 3.0)), off_centre_camera((2.0, 0.5, 2.0))]
    r41.set_gaussians(g)
    first = r41.render(cams[0])
    for field in ("means", "quats", "scales", "opacities", "sh"):
        getattr(g, field)[:] = 0.5
    moved = r41.render(cams[1])
    fresh = random_cloud(800, seed=21, sh_degree=3)
    r41.set_gaussians(fresh)
    np.testing.assert_array_equal(r41.render(cams[1]), moved)
    np.testing.assert_array_equal(r41.render(cams[0]), first)


def test_choose_path(ctx, monkeypatch):
    from npga_view.rendering.factory import PATH_ENV, choose_path, create_renderer
    from npga_view.rendering.gl import GLUnavailableError
    from npga_view.rendering.renderer41 import SplatRenderer41

    class Old:  # a context as macOS gives it
        version_code = 410

    monkeypatch.delenv(PATH_ENV, raising=False)
    assert choose_path(ctx) == ("43" if ctx.version_code >= 430 else "41")
    assert choose_path(Old()) == "41"
    monkeypatch.setenv(PATH_ENV, "41")
    r = create_renderer(ctx, 8, 8)
    assert isinstance(r, SplatRenderer41) and "4.1" in r.path
    r.release()
    monkeypatch.setenv(PATH_ENV, "43")
    with pytest.raises(GLUnavailableError, match="4.3"):
        choose_path(Old())
    monkeypatch.setenv(PATH_ENV, "4")
    with pytest.raises(ValueError, match="NPGA_VIEW_GL"):
        choose_path(ctx)


def test_gl41_shaders_use_nothing_newer():
    from npga_view.rendering.renderer41 import load_shader41
    from npga_view.rendering.shader_source import SHADER_DIR

    names = sorted(p.name[len("gl41_"):] for p in SHADER_DIR.glob("gl41_*") if p.suffix != ".glsl")
    assert {"splat.vert", "splat_points.vert", "splat.frag", "splat_id.frag", "splat_latent.vert",
            "composite.frag", "fullscreen.vert", "lines.vert", "lines.frag"} <= set(names)
    newer = re.compile(r"\b(buffer|std430|std140|binding|image[123D]|imageLoad|imageStore|atomic\w*|"
                       r"local_size_\w|memoryBarrier\w*|gl_GlobalInvocationID|shared|readonly|writeonly)\b")
    for name in names:
        source = load_shader41(name, {"NUM_TARGETS": 2})
        assert source.splitlines()[0] == "#version 410 core", name
        assert source.count("#version") == 1, name
        code = re.sub(r"//[^\n]*", "", source)
        assert not newer.findall(code), f"{name}: {newer.findall(code)}"


REAL_41_SCRIPT = """
from npga_core.camera.cameras import frame_points
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.rendering.factory import create_renderer
from npga_view.rendering.gl import create_headless_context, version_text
from tests.support.render import H, W, off_centre_camera, psnr, random_cloud, reference

ctx = create_headless_context()
r = create_renderer(ctx, W, H)
print("context", version_text(ctx), "path", r.path)
avatar = make_synthetic_avatar(2000, latent_dim=5, seed=5).pose(None)
scenes = {
    "anisotropic": (random_cloud(1500, seed=1), off_centre_camera((0.4, 0.3, 3.0))),
    "sh degree 3": (random_cloud(800, seed=2, sh_degree=3, sh_rest=0.5), off_centre_camera((2.5, 1.0, -1.5))),
    "avatar": (avatar, frame_points(avatar.means, W, H, direction="three_quarter_left")),
}
for name, (g, cam) in scenes.items():
    r.set_gaussians(g)
    bg = (0.1, 0.2, 0.3)
    print("psnr", name.replace(" ", "_"), psnr(r.render(cam, bg), reference(g, cam, background=bg)["rgb"]))
r.release()
ctx.release()
"""


def test_the_41_path_in_a_real_gl41_context_matches_the_reference():
    """In a 4.1 core context (no compute shaders, no storage buffers) the factory picks the 4.1 path by itself
    and draws what the reference rasterizer draws (>= 40 dB, as the renderer tests ask of both paths)."""
    r = subprocess.run([sys.executable, "-c", REAL_41_SCRIPT], cwd=ROOT, env=_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert "context OpenGL 4.1 (Core Profile)" in r.stdout and "path OpenGL 4.1 (CPU pre-pass" in r.stdout, r.stdout
    values = dict(line.split()[1:] for line in r.stdout.splitlines() if line.startswith("psnr"))
    assert len(values) == 3 and all(float(v) >= 40.0 for v in values.values()), values


@pytest.mark.slow
def test_under_mesa_gl41_the_cli_chooses_the_41_path(tmp_path):
    script = textwrap.dedent("""
        from npga_view.rendering.gl import create_headless_context
        from npga_view.rendering.renderer import SplatRenderer
        ctx = create_headless_context()
        print("version", ctx.version_code)
        try:
            SplatRenderer(ctx, 8, 8)
            print("4.3 path: built")
        except Exception as exc:
            print("4.3 path: refused")
    """)
    r = subprocess.run([sys.executable, "-c", script], env=_env(), capture_output=True, text=True, timeout=120)
    assert "version 410" in r.stdout and "4.3 path: refused" in r.stdout, r.stdout + r.stderr
    out = tmp_path / "demo.png"
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "render", "demo", "--out", str(out), "--width",
                        "160", "--height", "200", "--no-cnn", "--verbose"], cwd=ROOT, env=_env(),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "renderer: OpenGL 4.1 (CPU pre-pass, texture splats) on OpenGL 4.1 (Core Profile)" in r.stderr
    import cv2

    image = cv2.imread(str(out))
    assert image is not None and image.std() > 10.0
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "info", "demo"], cwd=ROOT, env=_env(),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "renderer: OpenGL 4.1 path (headless: OpenGL 4.1 (Core Profile)" in r.stdout


WINDOW_SCRIPT = """
import sys, time
from npga_view.app import ViewerApp
app = ViewerApp(900, 700, vsync=False, threads=1, remember_recent=False)
print("window", app.ctx.version_code, app.renderer.path, flush=True)
assert app.open_avatar(sys.argv[1])
end = time.monotonic() + 120
while time.monotonic() < end:
    app.step()
    if app.engine is not None and app.engine.pending is None and app.draws.settled and app.info.image_status == "exact":
        break
for _ in range(5):
    app.step()
app.screenshot(sys.argv[2])
app.close()
print("done", flush=True)
"""


@pytest.mark.slow
@pytest.mark.gui
def test_window_under_mesa_gl41(tmp_path):
    from tests.support.xvfb import start_xvfb, stop

    try:
        proc, display = start_xvfb()
    except RuntimeError as exc:
        if os.environ.get("CI"):
            raise
        pytest.skip(str(exc))
    try:
        from npga_core.files.loading import DEMO_AVATAR

        avatar = "demo"
        if not DEMO_AVATAR.is_file():
            from npga_core.files.checkpoint import save_avatar
            from npga_core.model.synthetic import make_synthetic_avatar

            avatar = str(tmp_path / "syn.npga")
            save_avatar(make_synthetic_avatar(3000, seed=2), avatar)
        shot = tmp_path / "window41.png"
        r = subprocess.run([sys.executable, "-c", WINDOW_SCRIPT, avatar, str(shot)], cwd=ROOT,
                           env=_env(DISPLAY=display, XDG_CONFIG_HOME=str(tmp_path / "config")),
                           capture_output=True, text=True, timeout=300)
    finally:
        stop(proc)
    assert r.returncode == 0 and "done" in r.stdout, r.stdout + r.stderr[-3000:]
    assert "window 410 OpenGL 4.1 (CPU pre-pass, texture splats)" in r.stdout
    import cv2

    image = cv2.imread(str(shot))
    assert image is not None and image.std() > 10.0
    if os.environ.get("NPGA_KEEP_SCREENSHOT"):
        import shutil

        shutil.copy(shot, os.environ["NPGA_KEEP_SCREENSHOT"])
