"""Screen-space refinement in the viewer (npga_view/rendering/refinement.py): the `Refiner` against
`npga-view render`, the raw/refined and latent choices, the latent views against the reference rasterizer
(tests/support/reference_rasterizer.py compositing h), the worker thread, and presenting into a framebuffer."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from npga_core.camera.cameras import frame_points
from npga_core.files.checkpoint import read_avatar
from npga_core.inspection.colouring import FeaturePCA, colour_map, robust_range
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.state import ViewerState
from tests.support.reference_rasterizer import rasterize
from tests.support.render import COLOUR_ATOL

W, H = 96, 120
BG = (0.2, 0.3, 0.4)


@pytest.fixture(scope="module")
def avatar(small_npga):
    return read_avatar(small_npga)


@pytest.fixture(scope="module")
def camera(avatar):
    return frame_points(np.asarray(avatar.cloud.means), W, H)


@pytest.fixture(params=["43", "41"])
def renderer(ctx, request):
    """Both renderer paths (npga_view/rendering/factory.py): the refinement only uses their common API."""
    from npga_view.rendering.factory import create_renderer

    r = create_renderer(ctx, W, H, path=request.param)
    yield r
    r.release()


@pytest.fixture
def refiner(ctx, avatar):
    from npga_view.rendering.refinement import Refiner

    r = Refiner(ctx)
    r.set_avatar(avatar)
    yield r
    r.release()


def test_refined_image_equals_the_render_command(tmp_path, avatar, camera, renderer, refiner, small_npga):
    from npga_view.cli.main import main

    code = avatar.expression.named["sample"]
    np.save(tmp_path / "code.npy", code)
    camera.to_json(tmp_path / "cam.json")
    out = tmp_path / "refined.npy"
    assert main(["render", str(small_npga), "--out", str(out), "--camera", str(tmp_path / "cam.json"),
                 "--expr", str(tmp_path / "code.npy"), "--background", ",".join(map(str, BG))]) == 0
    renderer.set_gaussians(avatar.pose(code))
    mine = refiner.refine(renderer, camera, BG)
    want = np.load(out)
    assert mine.shape == want.shape == (H, W, 3)
    np.testing.assert_allclose(mine, want, atol=COLOUR_ATOL)  # the command composites in its own way
    assert {"latent", "cnn"} <= set(refiner.last_timings) and refiner.last_timings["cnn"] >= 0.0
    # and --no-cnn gives the raw splats, which the CNN changes
    raw_path = tmp_path / "raw.npy"
    assert main(["render", str(small_npga), "--out", str(raw_path), "--camera", str(tmp_path / "cam.json"),
                 "--expr", str(tmp_path / "code.npy"), "--background", ",".join(map(str, BG)), "--no-cnn"]) == 0
    raw = np.load(raw_path)
    np.testing.assert_allclose(raw, renderer.render(camera, BG), atol=COLOUR_ATOL)
    assert np.abs(mine - raw).max() > 0.01


def test_the_state_decides_what_is_shown(avatar, camera, renderer, refiner):
    state = ViewerState()
    renderer.set_gaussians(avatar.pose(None))
    raw = renderer.render(camera, BG)

    def shown():
        img = refiner.image_for(renderer, camera, BG, state.use_cnn, state.latent_view, state.latent_channel,
                                state.mode)
        return raw if img is None else img

    assert state.use_cnn and state.latent_view == "off"  # defaults: refined when the avatar has a CNN
    refined = shown()
    assert np.abs(refined - raw).max() > 0.01
    state.use_cnn = False
    np.testing.assert_array_equal(shown(), raw)
    state.use_cnn = True
    state.latent_view = "pca"
    pca = shown()
    assert np.abs(pca - refined).max() > 0.05
    state.latent_view, state.latent_channel = "channel", 2
    chan = shown()
    assert np.abs(chan - pca).max() > 0.05
    state.latent_view, state.mode = "off", "depth"
    assert refiner.shows(state.use_cnn, state.latent_view, state.mode) is None  # other passes are not refined


@pytest.mark.slow
def test_avatars_without_cnn_or_latent_are_left_alone(ctx, camera, renderer):
    from npga_view.rendering.refinement import Refiner

    r = Refiner(ctx)
    try:
        for av in (make_synthetic_avatar(300, seed=1), make_synthetic_avatar(300, latent_dim=3, seed=1)):
            r.set_avatar(av)
            renderer.set_gaussians(av.pose(None))
            assert not r.has_cnn
            assert r.image_for(renderer, camera, BG, True, "off") is None
            with pytest.raises(ValueError, match="no CNN"):
                r.refine(renderer, camera, BG)
        r.set_avatar(None)
        assert r.shows(True, "pca") is None
        # a CNN of an avatar without h takes the RGB image alone (3 input channels, FORMAT.md section 7)
        av = make_synthetic_avatar(300, with_cnn=True, seed=1)
        r.set_avatar(av)
        renderer.set_gaussians(av.pose(None))
        raw = renderer.render(camera, BG)
        np.testing.assert_allclose(r.image_for(renderer, camera, BG, True, "off"), av.cnn.refine(raw), atol=1e-6)
        assert r.shows(True, "pca") == "refined"  # no latent view without h
    finally:
        r.release()


def test_latent_views_match_the_reference_rasterizer(avatar, camera, renderer, refiner):
    code = avatar.expression.named["sample"]
    posed = avatar.pose(code)
    renderer.set_gaussians(posed)
    ref = rasterize(posed.means, posed.quats, posed.scales, posed.opacities, posed.sh, camera, latent=posed.latent,
                    early_stop=False, tile_rect=False)
    latent = renderer.render_latent(camera)
    scale = np.abs(ref["latent"]).max()
    assert np.mean(np.abs(latent - ref["latent"]) <= 2e-4 * scale) > 0.999
    # the views: mean latent per pixel (composite / alpha), coloured, over the background by alpha
    alpha = ref["alpha"][..., None]
    mean = (ref["latent"] / np.maximum(ref["alpha"], 1e-6)[..., None]).reshape(-1, posed.latent.shape[1])
    h = np.asarray(avatar.cloud.latent, np.float64)
    pca = FeaturePCA.fit(h).colours(mean).reshape(H, W, 3)
    want = pca * alpha + (1 - alpha) * np.asarray(BG)
    got = refiner.latent_view(renderer, camera, BG, "pca")
    assert np.mean(np.abs(got - want) < 0.02) > 0.99
    k = 1
    lo, hi = robust_range(h[:, k], symmetric=bool(h[:, k].min() < 0 < h[:, k].max()))
    cmap = "coolwarm" if lo < 0 < hi else "viridis"
    chan = colour_map((mean[:, k] - lo) / (hi - lo), cmap).reshape(H, W, 3)
    want = chan * alpha + (1 - alpha) * np.asarray(BG)
    got = refiner.latent_view(renderer, camera, BG, "channel", k)
    assert np.mean(np.abs(got - want) < 0.02) > 0.99
    with pytest.raises(ValueError, match="no latent channel"):
        refiner.latent_view(renderer, camera, BG, "channel", 99)


def test_the_worker_thread_gives_the_same_image(avatar, camera, renderer, refiner):
    renderer.set_gaussians(avatar.pose(None))
    want = refiner.refine(renderer, camera, BG)
    refiner.submit("k1", renderer, camera, BG)
    assert refiner.pending_key() == "k1"
    assert refiner.result("other") is None
    end = time.monotonic() + 60
    while (got := refiner.result("k1")) is None and time.monotonic() < end:
        time.sleep(0.01)
    assert got is not None
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert "cnn" in refiner.last_timings and not refiner.busy
    refiner.submit("k2", renderer, camera, BG)
    refiner.cancel()
    assert refiner.pending_key() is None and refiner.result("k2") is None


def test_the_cnn_input_is_assembled_on_the_worker_thread(monkeypatch, avatar, camera, renderer, refiner):
    """The window's thread draws the CNN's input (GL) and the worker assembles it: a new image of the whole view,
    ~70 ms at 960 x 900 that a UI frame waited for before; the refined image is the same."""
    import threading

    renderer.set_gaussians(avatar.pose(None))
    want = refiner.refine(renderer, camera, BG)
    threads = []
    assemble = refiner.cnn.assemble

    def spy(*args):
        threads.append(threading.current_thread())
        return assemble(*args)

    monkeypatch.setattr(refiner.cnn, "assemble", spy)
    refiner.submit("k", renderer, camera, BG)
    end = time.monotonic() + 60
    while (got := refiner.result("k")) is None and time.monotonic() < end:
        time.sleep(0.01)
    assert got is not None and len(threads) == 1
    assert threads[0] is not threading.current_thread() and threads[0].name.startswith("npga-cnn")
    assert "input" in refiner.last_timings
    np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.slow
def test_the_cpu_cnn_in_bands_equals_the_whole_image_and_stops_when_cancelled():
    """The window runs the CNN in bands of rows with the receptive radius as context (so a refinement of a view
    the person has left stops early): the bands give the whole image's output, and a cancel stops them."""
    from npga_core.model.cnn import CNNConfig, ConvLayer, ScreenCNN, run_cnn
    from npga_view.rendering.refinement import _run_banded

    torch.manual_seed(3)
    cfg = CNNConfig([ConvLayer(5, 8, 5, "leaky_relu"), ConvLayer(8, 8, 3, "relu"), ConvLayer(8, 3, 3, None)])
    cnn = ScreenCNN(cfg).eval()
    for conv in cnn.convs:  # large weights: a missing context row would change the output visibly
        torch.nn.init.normal_(conv.weight, std=0.5)
    image = np.random.default_rng(0).random((101, 37, 5)).astype(np.float32)
    cpu = torch.device("cpu")
    with torch.no_grad():
        whole = run_cnn(cnn, image, cpu)
        halo = sum(layer.kernel // 2 for layer in cfg.layers)
        assert halo == 4
        for rows in (1, 7, 16, 100, 200):
            np.testing.assert_allclose(_run_banded(cnn, cpu, image, halo, lambda: False, rows), whole, atol=1e-4)
        short = _run_banded(cnn, cpu, image, halo - 1, lambda: False, 16)  # too little context: not the same
        assert np.abs(short - whole).max() > 1e-3
        calls = []
        assert _run_banded(cnn, cpu, image, halo, lambda: calls.append(1) or len(calls) > 2, 16) is None
        assert len(calls) == 3  # stopped at the third band


def test_the_latent_pass_in_slices_equals_one_pass(avatar, camera, renderer):
    """The window draws the latent image in slices over UI frames (budget 0: the smallest slices); the slices
    blend the same sorted order, so the image is the one-pass image; a new upload drops the unfinished one."""
    posed = avatar.pose(None)
    renderer.set_gaussians(posed)
    whole = renderer.render_latent(camera)
    renderer.begin_latent(camera, first_slice=97)  # a small first slice, for a cloud this small
    calls = 0
    while (got := renderer.continue_latent(0.0)) is None:
        calls += 1
        assert renderer.latent_drawing and calls < 10_000
    assert calls >= 1 and renderer.last_timings["slices"] >= 2
    np.testing.assert_array_equal(got, whole)
    renderer.begin_latent(camera, first_slice=97)
    assert renderer.continue_latent(0.0) is None
    renderer.set_gaussians(posed)
    assert not renderer.latent_drawing and renderer.continue_latent(0.0) is None


def test_latent_slices_follow_their_predicted_cost(camera, renderer):
    """A budgeted latent pass sizes its slices by the splats' predicted cost (`SliceCost` on their footprints, its
    own rates): the same budget gives one slice where the pass is predicted cheap, several where it is predicted
    dear (the rate of the last slice, before, gave every image a first slice of 1,024 splats)."""
    from npga_core.model.gaussians import PosedGaussians
    from npga_view.rendering.slice_cost import SliceCost

    rng = np.random.default_rng(3)
    n = 4000
    means = rng.normal(0.0, 0.05, (n, 3)).astype(np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    posed = PosedGaussians(means, quats, np.full((n, 3), 0.004, np.float32), np.full(n, 0.5, np.float32),
                           rng.uniform(0, 1, (n, 1, 3)).astype(np.float32),
                           latent=rng.normal(0, 1, (n, 4)).astype(np.float32))
    renderer.set_gaussians(posed)
    whole = renderer.render_latent(camera)
    for coef, one_slice in (((1e-9, 1e-9), True), ((1e3, 1e3), False)):
        renderer.latent_slices = SliceCost(coef)  # (a weak prior: refitted from the first slice on)
        renderer.begin_latent(camera)
        while (got := renderer.continue_latent(50.0)) is None:
            pass
        assert (renderer.last_timings["slices"] == 1) is one_slice
        np.testing.assert_array_equal(got, whole)


def test_upload_and_present_show_the_image_upright(ctx, refiner):
    import moderngl

    rng = np.random.default_rng(0)
    image = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    image[0, :] = 1.0  # top row white
    tex = refiner.upload(image)
    assert tex.size == (W, H)
    target = ctx.texture((W, H), 4, dtype="f1")
    fbo = ctx.framebuffer([target])
    try:
        refiner.present(fbo, flip_y=False)  # an offscreen framebuffer keeps image row 0 in memory row 0
        got = np.frombuffer(fbo.read(components=3), np.uint8).reshape(H, W, 3)
        np.testing.assert_array_equal(got, np.clip(image * 255 + 0.5, 0, 255).astype(np.uint8))
        refiner.present(fbo, flip_y=True)  # a window's framebuffer has row 0 at the bottom
        got = np.frombuffer(fbo.read(components=3), np.uint8).reshape(H, W, 3)
        np.testing.assert_array_equal(got[-1], np.full((W, 3), 255, np.uint8))
    finally:
        fbo.release()
        target.release()
    assert isinstance(tex, moderngl.Texture)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_on_a_gpu_the_cnn_runs_there(ctx, avatar, camera, renderer):
    from npga_view.rendering.refinement import Refiner

    r = Refiner(ctx, device="cuda")
    try:
        r.set_avatar(avatar)
        assert r.cnn.device.type == "cuda"
        renderer.set_gaussians(avatar.pose(None))
        gpu = r.refine(renderer, camera, BG)
        np.testing.assert_allclose(gpu, avatar.cnn.refine(np.concatenate(
            [renderer.render(camera, BG), renderer.render_latent(camera)], axis=2)), atol=1e-4)
    finally:
        r.release()


def test_cuda_is_refused_where_there_is_none(ctx):
    from npga_view.rendering.refinement import Refiner

    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    with pytest.raises(ValueError, match="CUDA is not available"):
        Refiner(ctx, device="cuda")


# --- the View panel, driven headless through imgui input events (as tests/core/test_inspect.py does) -------------
@pytest.fixture
def panel_frame():
    imgui = pytest.importorskip("imgui_bundle").imgui
    context = imgui.create_context()
    io = imgui.get_io()
    io.set_ini_filename(None)
    io.display_size = imgui.ImVec2(520, 1200)
    io.backend_flags |= imgui.BackendFlags_.renderer_has_textures  # no renderer: imgui keeps the atlas to itself

    def frame(body) -> None:
        io.delta_time = 1 / 60
        imgui.new_frame()
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(520, 1200))
        imgui.begin("side")
        body()
        imgui.end()
        imgui.render()

    yield frame, io
    imgui.destroy_context(context)


def test_view_panel_toggles_raw_and_refined_and_offers_latent_views(avatar, panel_frame):
    from npga_view.panels.info import AppInfo
    from npga_view.panels.view import ViewPanel

    panel = ViewPanel()

    frame, io = panel_frame
    state, info = ViewerState(), AppInfo(avatar=avatar)

    def click(name: str) -> None:
        x0, y0, x1, y1 = info.rects[name]
        io.add_mouse_pos_event((x0 + x1) / 2, (y0 + y1) / 2)
        frame(lambda: panel.draw(state, info))
        io.add_mouse_button_event(0, True)
        frame(lambda: panel.draw(state, info))
        io.add_mouse_button_event(0, False)
        frame(lambda: panel.draw(state, info))

    frame(lambda: panel.draw(state, info))
    assert {"raw_splats", "cnn_refined", "latent_view"} <= set(info.rects)
    assert "latent_channel" not in info.rects
    click("raw_splats")
    assert state.use_cnn is False
    click("cnn_refined")
    assert state.use_cnn is True
    state.latent_view, state.latent_channel = "channel", 99
    frame(lambda: panel.draw(state, info))
    assert "latent_channel" in info.rects and state.latent_channel == avatar.cloud.latent_dim - 1  # clamped
    # an avatar without CNN and latent gets none of these widgets
    info2 = AppInfo(avatar=make_synthetic_avatar(100, seed=1))
    frame(lambda: panel.draw(ViewerState(), info2))
    assert not {"raw_splats", "cnn_refined", "latent_view"} & set(info2.rects)


def test_a_refinement_of_a_view_left_behind_is_cancelled():
    """RefineController: when the view changes (the splat image is no longer settled) the running CNN job is
    cancelled, so that it does not hold the cores while the person drags; the refined image on screen stays until
    a splat image of the new view is finished (no flash of the old raw splats), then the raw splats are shown."""
    from types import SimpleNamespace

    from npga_view.controllers.refining import RefineController
    from npga_view.panels.info import AppInfo

    calls = []
    refiner = SimpleNamespace(shows=lambda *a: "refined", cancel=lambda: calls.append("cancel"),
                              present=lambda *a, **k: calls.append("present"), latent_dim=4)
    draws = SimpleNamespace(settled=False, shown_target=("view 1",), images=0)
    state = ViewerState()
    renderer = SimpleNamespace(latent_dim=0)
    ctl = RefineController(refiner, renderer, draws, state, AppInfo())
    draws.settled = True  # nothing uploaded yet (the view of an empty renderer is settled at once): no error
    assert ctl.present(None, None, (0, 0, 10, 10)) is False and ctl.info.shown == "splats" and not state.errors
    draws.settled, renderer.latent_dim = False, 4
    assert ctl.present(None, None, (0, 0, 10, 10)) is False  # nothing refined yet
    assert calls == ["cancel"] and ctl.info.shown == "splats (refining)"
    assert not ctl.complete  # scripted screenshots wait
    calls.clear()
    bg = tuple(float(v) for v in state.background)
    ctl._key = (("view 1",), "refined", state.latent_view, state.latent_channel, bg)  # view 1 was refined
    assert ctl.present(None, None, (0, 0, 10, 10)) is True  # view 2 is being drawn: view 1's refined image stays
    assert calls == ["cancel", "present"] and ctl.info.shown == "refined" and ctl.complete
    calls.clear()
    draws.shown_target = ("view 2",)  # the splat image of view 2 is finished, its refinement not yet
    assert ctl.present(None, None, (0, 0, 10, 10)) is False
    assert calls == ["cancel"] and ctl.info.shown == "splats (refining)"



def test_a_refinement_waits_while_a_change_is_on_its_way():
    """RefineController: while the view is settled but the scheduler's last frame was an interaction (a Live Link
    packet's pose on its way, a drag not yet moved) no refinement work runs in the frame: a slice of the latent pass
    took ~40 ms of the frame in which a packet's pose arrived."""
    from types import SimpleNamespace

    from npga_view.controllers.refining import RefineController
    from npga_view.panels.info import AppInfo

    calls = []

    def front_image(bg):  # the first step of a refinement: the splat image on screen
        calls.append("compute")
        raise LookupError("stand-in")

    refiner = SimpleNamespace(shows=lambda *a: "refined", cancel=lambda: calls.append("cancel"),
                              present=lambda *a, **k: calls.append("present"), latent_dim=4)
    draws = SimpleNamespace(settled=True, interacting=True, shown_target=("view 1",), images=1)
    state = ViewerState()
    ctl = RefineController(refiner, SimpleNamespace(latent_dim=4, front_image=front_image), draws, state, AppInfo())
    assert ctl.present(None, None, (0, 0, 10, 10)) is False
    assert calls == [] and ctl.info.shown == "splats (refining)"  # nothing computed, nothing cancelled
    draws.interacting = False  # the interaction is over: the refinement runs
    with pytest.raises(LookupError):
        ctl.present(None, None, (0, 0, 10, 10))
    assert calls == ["compute"]
    # a splat image finished in this frame is shown in it; its refinement starts in the next frame (its read-back,
    # latent pass and CNN input had delayed the full-resolution image by 75-100 ms on llvmpipe)
    calls.clear()
    draws.images, draws.shown_target = 2, ("view 2",)
    assert ctl.present(None, None, (0, 0, 10, 10)) is False
    assert calls == [] and ctl.info.shown == "splats (refining)"
    with pytest.raises(LookupError):
        ctl.present(None, None, (0, 0, 10, 10))
    assert calls == ["compute"]


def test_an_avatar_of_0_gaussians_with_latent_features(ctx, camera, renderer):
    """Deleting every Gaussian of an avatar with h (and a CNN) leaves 0 rows: the refiner takes it (its ranges of h
    fall back to defaults) and the refined image of the empty view is the CNN of the background."""
    from npga_view.rendering.refinement import Refiner

    av = make_synthetic_avatar(0, latent_dim=3, with_cnn=True, seed=1)
    r = Refiner(ctx)
    try:
        r.set_avatar(av)  # raised ValueError (the min of an empty array) before
        assert r.latent_dim == 3 and r.has_cnn
        renderer.set_gaussians(av.pose(None))
        out = r.image_for(renderer, camera, BG, True, "off")
        assert out is not None and out.shape == (H, W, 3) and np.isfinite(out).all()
    finally:
        r.release()


def test_an_edit_keeps_the_cnn_copy_a_new_avatar_replaces_it(ctx, small_npga):
    """An edited cloud (the same avatar, its CNN untouched) keeps the refiner's CNN copy and trace (0.4 s of the
    edit's frame on the demo); another avatar's CNN, even an equal one, is copied again."""
    from npga_core.editing.commands import DeleteSelected
    from npga_core.editing.edits import EditSession
    from npga_view.rendering.refinement import Refiner

    avatar = read_avatar(small_npga)
    r = Refiner(ctx)
    try:
        r.set_avatar(avatar)
        copy, n = r.cnn, len(avatar)
        session = EditSession(avatar)
        session.select(np.arange(n) < 10)
        session.run(DeleteSelected())
        assert len(session.avatar) == n - 10
        r.set_avatar(session.avatar)
        assert r.cnn is copy  # (its trace is kept with it)
        r.set_avatar(read_avatar(small_npga))
        assert r.cnn is not copy and r.cnn is not None
        r.set_avatar(None)
        assert r.cnn is None and not r.has_cnn
    finally:
        r.release()
