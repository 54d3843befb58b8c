"""The window's Compare view (npga_view/comparison) headless: a capture of reference-rasterizer renders (as in
test_evaluate.py), the avatar drawn at the capture camera in budgeted slices, composed, scored like `evaluate`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from npga_core.evaluation.compare import CompareSettings, compose
from npga_core.evaluation.metrics import composite_background, score
from tests.support.captures import SERIALS, capture_cameras, write_capture
from tests.support.reference_rasterizer import rasterize

pytestmark = pytest.mark.slow  # a module fixture takes over 10 s

BG = (1.0, 1.0, 1.0)


@pytest.fixture(scope="module")
def demo():
    from npga_core import load_avatar
    return load_avatar("demo")


@pytest.fixture(scope="module")
def capture(tmp_path_factory, demo) -> Path:
    p = demo.pose(None)
    cams = capture_cameras(demo)
    images = {s: (o["rgb"], o["alpha"]) for s, cam in cams.items()
              for o in [rasterize(p.means, p.quats, p.scales, p.opacities, p.sh, cam, BG)]}
    root = tmp_path_factory.mktemp("capture")
    write_capture(root, cams, images)
    return root


@pytest.fixture(scope="module")
def ctx():
    from npga_view.rendering.gl import GLUnavailableError, create_headless_context
    try:
        c = create_headless_context()
    except GLUnavailableError as e:
        pytest.skip(str(e))
    yield c
    c.release()


def _run(view, avatar, camera, budget_ms=2.0, code=None, version=0, limit_s=120.0):
    """update() until the comparison is on screen (a generous bound), counting the calls."""
    calls = 0
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        view.update(avatar, version, code, camera, budget_ms)
        calls += 1
        if view.status.ready and view.has_image and view.status.scores:
            return calls
        time.sleep(0.002)
    raise AssertionError(f"comparison not ready: {view.status.text}")


def _view(ctx, capture=None):
    from npga_view.comparison.sources import CompareSources
    from npga_view.comparison.view import CompareView
    sources = CompareSources()
    if capture is not None:
        sources.open_capture(capture)
    return CompareView(ctx, sources)


def test_capture_view_is_drawn_in_slices_at_the_capture_camera_and_scored_like_evaluate(ctx, demo, capture):
    from npga_view.rendering.factory import create_renderer
    view = _view(ctx, capture)
    view.use_cnn = False
    view.set_mode("a")
    try:
        view.sources.camera_index = view.sources.cameras.index(SERIALS[1])
        any_camera = capture_cameras(demo)[SERIALS[0]]
        calls = _run(view, demo, any_camera, budget_ms=0.0)
        assert calls > 2  # a zero budget draws one slice per call: the work is spread over UI frames
        cam = view.sources.capture.views[(0, SERIALS[1])].camera
        r = create_renderer(ctx, cam.width, cam.height)
        r.set_gaussians(demo.pose(None))
        expected = r.render(cam, BG)
        # scored as evaluate scores: the capture's image and alpha mask, the same background
        assert view.prepared is not None
        captured = view.prepared.capture
        # shown as scored: both composited over the background outside the capture's mask
        shown = composite_background(expected, captured.mask, BG).astype(np.float32)
        np.testing.assert_allclose(view.composed(), shown, atol=1e-5)
        s = score(np.clip(expected, 0, 1), captured.image, captured.mask, BG)
        got = view.status.scores["a"]
        assert got.psnr == pytest.approx(s.psnr, abs=0.01) and got.ssim == pytest.approx(s.ssim, abs=1e-4)
        assert got.psnr > 30.0 and got.masked
        # the wipe shows the render left of the divider and the capture right of it
        view.set_mode("wipe", 0.5)
        view.update(demo, 0, None, any_camera, 2.0)
        cap_shown = composite_background(captured.image, captured.mask, BG).astype(np.float32)
        assert np.allclose(view.composed(), compose(shown, cap_shown, CompareSettings("wipe", 0.5)), atol=1e-5)
    finally:
        view.release()


def test_stepping_the_camera_keeps_render_and_capture_aligned(ctx, demo, capture):
    view = _view(ctx, capture)
    view.use_cnn = False
    try:
        for _ in range(2):
            _run(view, demo, capture_cameras(demo)[SERIALS[0]])
            frame, cam = view.sources.current
            assert view.status.scores["a"].psnr > 30.0, (frame, cam)  # aligned: a shifted camera scores far lower
            view.sources.step(cameras=1)
    finally:
        view.release()


def test_a_b_difference_of_an_avatar_and_its_edited_copy(ctx, demo):
    import copy
    b = copy.deepcopy(demo)
    logits = np.array(b.cloud.opacity_logits)
    logits[: len(logits) // 2] = -30.0  # half the Gaussians made transparent
    b.cloud.opacity_logits = logits
    b.invalidate_caches()  # as every edit does
    view = _view(ctx)
    view.use_cnn = False
    view.set_pair("a-b")
    view.set_mode("difference")
    view.sources.set_b(b, "edited")
    cam = capture_cameras(demo)[SERIALS[1]]
    try:
        _run(view, demo, cam)
        heat = view.composed()
        dark = np.array([0.001462, 0.000466, 0.013866])
        near = np.abs(heat - dark).max(axis=2) < 0.02
        assert 0.05 < near.mean() < 0.99  # some pixels equal, some differ
        view.sources.set_b(copy.deepcopy(demo), "same")
        _run(view, demo, cam)
        assert np.abs(view.composed() - dark).max() < 0.02  # equal: dark everywhere (no bar on a thumbnail)
    finally:
        view.release()


def test_missing_inputs_say_what_to_open(ctx, demo):
    view = _view(ctx)
    try:
        assert not view.update(demo, 0, None, capture_cameras(demo)[SERIALS[1]], 2.0)
        assert "capture" in view.status.text
        view.set_pair("a-b")
        view.update(demo, 0, None, capture_cameras(demo)[SERIALS[1]], 2.0)
        assert "second avatar" in view.status.text
        with pytest.raises(ValueError):
            view.set_pair("a-c")
    finally:
        view.release()
