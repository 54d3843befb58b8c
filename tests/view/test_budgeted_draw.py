"""Frame-budgeted drawing (#14): slices and points give the pixels of one quad draw; the scheduler's images.

Headless (EGL / OSMesa llvmpipe). The renderer's images are checked against the independent reference
rasterizer in tests/view/test_renderer.py; here the new paths are checked against the established quad path.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from npga_core.camera.cameras import frame_points
from npga_core.model.gaussians import PosedGaussians
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.rendering.scheduler import FIRST_SCALE, REFINE_BUDGETS, DrawScheduler, scaled_camera
from tests.support.render import accumulated


def gl_colour_pass(gl_path: str) -> None:
    """Skip a test of the GL colour pass's points and quads where the colour pass runs on the CPU."""
    if gl_path == "cpu":
        pytest.skip("points and quads are the GL colour pass's; the CPU pass draws each ellipse's spans")


@pytest.fixture(scope="module")
def posed() -> PosedGaussians:
    return make_synthetic_avatar(6000, seed=11).pose()


@pytest.fixture(scope="module")
def renderer(make_renderer, posed):
    r = make_renderer(64, 64)
    r.set_gaussians(posed)
    yield r
    r.release()


def test_points_path_equals_quads(renderer, posed, gl_path):
    gl_colour_pass(gl_path)
    cam = frame_points(posed.means, 160, 140)
    renderer.use_points = False
    quads = renderer.render(cam)
    assert renderer.last_timings["points"] == 0.0
    renderer.use_points = True
    points = renderer.render(cam)
    assert renderer.last_timings["points"] == 1.0
    assert quads.max() > 0.1
    np.testing.assert_array_equal(points, quads)


def test_points_of_turned_elongated_splats_equal_quads(make_renderer, gl_path):
    gl_colour_pass(gl_path)
    """A GL point holds the bounding box of a splat's ellipse, not of its quad (splat_common.glsl point_side):
    thin opaque splats turned 0-90 degrees in the image, drawn as points, keep every pixel of the quad path, on
    both GL paths; the side is that of the ellipse's box (at 45 degrees 15 % smaller than the quad's box here)."""
    from npga_core.camera.cameras import look_at

    angles = np.radians(np.arange(0.0, 91.0, 15.0))
    n = len(angles)
    means = np.stack([np.linspace(-0.3, 0.3, n), np.zeros(n), np.zeros(n)], 1).astype(np.float32)
    quats = np.stack([np.cos(angles / 2), np.zeros(n), np.zeros(n), np.sin(angles / 2)], 1).astype(np.float32)  # z
    scales = np.tile(np.float32([0.03, 0.004, 0.004]), (n, 1))
    sh = np.zeros((n, 1, 3), np.float32)
    sh[:, 0] = 1.0
    posed = PosedGaussians(means, quats, scales, np.full(n, 0.98, np.float32), sh)
    cam = look_at((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 320, 120)
    r = make_renderer(64, 64)
    try:
        r.set_gaussians(posed)
        r.use_points = False
        quads = r.render(cam)
        r.use_points = True
        points = r.render(cam)
        assert r.last_timings["points"] == 1.0 and quads.max() > 0.5
        np.testing.assert_array_equal(points, quads)
        if gl_path == "43":  # the 4.3 path's splat buffer: the point side against the quad's box
            sp = np.frombuffer(r._buffers["splats"].read(size=n * 64), np.float32).reshape(n, 16)
            quad_box = 2 * np.maximum(np.abs(sp[:, 4]) + np.abs(sp[:, 6]), np.abs(sp[:, 5]) + np.abs(sp[:, 7])) + 1
            turned = int(np.argmin(np.abs(angles - np.pi / 4)))
            assert np.all(sp[:, 15] <= quad_box + 1e-3) and sp[turned, 15] < 0.9 * quad_box[turned]
    finally:
        r.release()


def test_oversize_splats_fall_back_to_quads(make_renderer, posed):
    """A splat larger than the largest GL point is drawn as a quad: the image still equals the quad path's."""
    big = PosedGaussians(posed.means.copy(), posed.quats.copy(), posed.scales.copy(), posed.opacities.copy(),
                         posed.sh.copy())
    big.scales[0] = 0.5  # half a metre: hundreds of pixels wide
    big.opacities[0] = 0.5
    r = make_renderer(64, 64)
    try:
        r.set_gaussians(big)
        cam = frame_points(posed.means, 400, 350)
        points_allowed = r.render(cam)
        assert r.last_timings["oversize"] >= 1 and r.last_timings["points"] == 0.0
        r.use_points = False
        np.testing.assert_array_equal(points_allowed, r.render(cam))
    finally:
        r.release()


@pytest.mark.parametrize("points", [False, True])
def test_slices_compose_to_one_draw(renderer, posed, points):
    renderer.use_points = points
    cam = frame_points(posed.means, 200, 180, direction="three_quarter_right")
    renderer.draw(cam)
    one = accumulated(renderer)
    renderer.begin_draw(cam)
    steps = 0
    while not renderer.continue_draw(0.0):  # the smallest budget: one minimal slice per call
        steps += 1  # (the CPU pass's first slice bins the splats: no tile drawn yet)
        assert renderer.drawing and (renderer.progress > 0.0 or (steps == 1 and renderer.cpu_pass is not None))
        assert renderer.progress < 1.0
    assert renderer.last_timings["slices"] >= 2 and steps >= 1
    np.testing.assert_array_equal(accumulated(renderer), one)


def test_finished_image_stays_in_front_while_the_next_is_drawn(renderer, posed):
    renderer.use_points = True
    front = frame_points(posed.means, 120, 100, direction="front")
    side = frame_points(posed.means, 120, 100, direction="right")
    renderer.draw(front)
    first = accumulated(renderer)
    renderer.begin_draw(side)
    assert not renderer.continue_draw(0.0)
    np.testing.assert_array_equal(accumulated(renderer), first)  # the unfinished side view is not shown
    renderer.continue_draw(math.inf)
    assert not np.array_equal(accumulated(renderer), first)


def test_another_prepass_drops_the_unfinished_image(renderer, posed):
    cam = frame_points(posed.means, 150, 130)
    renderer.begin_draw(cam)
    renderer.continue_draw(0.0)
    renderer.pick(frame_points(posed.means, 151, 130), 70, 60)  # a different camera: a new pre-pass
    assert not renderer.drawing


def test_scheduler_reduces_scale_while_live_and_refines_after(renderer, posed):
    renderer.use_points = True
    sched = DrawScheduler(renderer, budget_ms=1.0, interactive_ms=1e-3, min_scale=0.25, settle_s=0.0)
    cam = frame_points(posed.means, 240, 200)
    t = 0.0
    # live: images at the reduced scale, several UI frames each
    frames = 0
    while sched.images < 3:  # 0.5, then damped steps down to the minimum
        sched.frame(cam, "rgb", content_version=sched.images, interacting=True, now=t)
        t += 0.04
        frames += 1
        assert frames < 500
    assert sched.scale == pytest.approx(0.25) and sched.status == "preview"
    assert renderer.image_size == (60, 50)
    # input stops: the current view is refined to full resolution, then drawing stops
    version = sched.shown_version
    while not sched.settled:
        sched.frame(cam, "rgb", content_version=version, interacting=False, now=t)
        t += 0.04
        frames += 1
        assert frames < 2000
    assert sched.scale == 1.0 and sched.status == "exact" and renderer.image_size == (240, 200)
    refined = accumulated(renderer)
    assert not sched.frame(cam, "rgb", content_version=version, interacting=False, now=t)  # nothing to draw
    renderer.draw(cam)
    np.testing.assert_array_equal(refined, accumulated(renderer))


def test_scheduler_labels_a_preview_pose_until_the_exact_one(renderer, posed):
    sched = DrawScheduler(renderer, budget_ms=math.inf, settle_s=0.0)
    cam = frame_points(posed.means, 120, 100)
    for _ in range(5):
        sched.frame(cam, "rgb", content_version=1, interacting=False, exact_content=False, now=0.0)
    assert sched.settled and sched.status == "preview"
    sched.frame(cam, "rgb", content_version=2, interacting=False, exact_content=True, now=1.0)
    sched.frame(cam, "rgb", content_version=2, interacting=False, exact_content=True, now=1.0)
    assert sched.status == "exact"


def test_unbudgeted_scheduler_draws_each_change_at_once(renderer, posed):
    """The window benchmark's comparison (npga_view/benchmarks/bench_window.py): drawing as before frame budgets."""
    from npga_view.benchmarks.bench_window import UnbudgetedScheduler

    sched = UnbudgetedScheduler(renderer)
    cam = frame_points(posed.means, 130, 110)
    assert sched.frame(cam, "rgb", 1, interacting=True)
    assert sched.scale == 1.0 and renderer.image_size == (130, 110)
    assert not sched.frame(cam, "rgb", 1, interacting=True)


def test_scaled_camera_keeps_the_field_of_view(posed):
    cam = frame_points(posed.means, 400, 300)
    small = scaled_camera(cam, 0.25)
    assert (small.width, small.height) == (100, 75)
    assert small.tan_half_fov_x == pytest.approx(cam.tan_half_fov_x, rel=1e-6)
    assert small.tan_half_fov_y == pytest.approx(cam.tan_half_fov_y, rel=1e-6)


def test_scheduler_draws_a_live_view_once(renderer, posed):
    """While the view stays live (a preview pose on screen, no camera move), its live image is not drawn again
    when the adapted live scale moves: redrawing it only took the cores from the exact pose being computed."""
    renderer.use_points = True
    sched = DrawScheduler(renderer, budget_ms=math.inf, interactive_ms=1e6, settle_s=0.0)  # the scale grows
    cam = frame_points(posed.means, 240, 200)
    sched.frame(cam, "rgb", content_version=1, interacting=True, exact_content=False, now=0.0)
    assert sched.images == 1 and sched.interactive_scale > sched.scale  # adapted upward after the image
    for k in range(5):
        assert not sched.frame(cam, "rgb", content_version=1, interacting=True, exact_content=False, now=0.1 * k)
    assert sched.images == 1 and sched.status == "preview"
    # a new pose (the next preview) is drawn; input stopping refines to full resolution
    sched.frame(cam, "rgb", content_version=2, interacting=True, exact_content=False, now=1.0)
    assert sched.images == 2
    sched.frame(cam, "rgb", content_version=2, interacting=False, exact_content=False, now=2.0)
    assert sched.images == 3 and sched.scale == 1.0


def test_first_live_image_after_a_settled_view_gets_several_budgets(renderer, posed, monkeypatch):
    """A change after a settled view (a Live Link packet, a click) is answered with FIRST_BUDGETS budgets in its
    first frame, at FIRST_SCALE times the live scale; the live images after it leave the UI its rate (here the UI
    is slow, so they get a third of it)."""
    renderer.use_points = False
    given: list[float] = []
    draw = renderer.continue_draw
    monkeypatch.setattr(renderer, "continue_draw", lambda ms: given.append(ms) or draw(ms))
    sched = DrawScheduler(renderer, budget_ms=300.0, settle_s=0.0)  # (large: a busy machine's pre-pass fits)
    cam = frame_points(posed.means, 240, 200)
    while not sched.settled:
        sched.frame(cam, "rgb", content_version=1, interacting=False, now=0.0)
    sched.ui_ms = 40.0  # a UI slower than the target rate: live frames would get a third of the budget
    given.clear()
    live_scale = sched.interactive_scale
    sched.frame(cam, "rgb", content_version=2, interacting=True, now=1.0)
    assert given and given[0] > 300.0  # more than one budget (4 x 300 ms less what the frame had spent)
    assert renderer.image_size == (round(240 * live_scale * FIRST_SCALE), round(200 * live_scale * FIRST_SCALE))
    for _ in range(1000):  # that image finished (drawing continues while frames come)
        if sched.shown_version == 2:
            break
        sched.frame(cam, "rgb", content_version=2, interacting=True, now=1.0)
    assert sched.shown_version == 2
    given.clear()
    sched.ui_ms = 40.0
    sched.frame(cam, "rgb", content_version=3, interacting=True, now=1.1)  # the stream goes on: a live image
    assert given and given[0] <= 100.0 + 1e-6  # a third of the budget


def test_live_budget_has_no_cliff(renderer):
    """A live frame gets what the UI's own time leaves of the target rate, between a third of the budget and all of
    it, for the full and the merged cloud alike: a UI slowed by other work (beside two busy processes) no longer
    hands live images the whole budget (that held the demo at 17-19 UI fps there; 28-32 since)."""
    s = DrawScheduler(renderer, budget_ms=25.0)
    period = 1e3 / s.target_fps
    s.ui_ms, s.over_ms = period - 30.0, 0.0  # plenty left: the budget
    assert s.frame_budget(True) == pytest.approx(25.0)
    s.ui_ms = period - 12.0  # 12 ms left: 12 ms
    assert s.frame_budget(True) == pytest.approx(12.0)
    assert s.live_budget_ms == pytest.approx(12.0)
    for ui in (period - 5.0, period, 2 * period):  # little or nothing left: a third of the budget, never more
        s.ui_ms = ui
        assert s.frame_budget(True) == pytest.approx(25.0 / 3)
    s.ui_ms = 200.0  # a refinement (not live) takes up to 4 budgets beside a slow UI
    assert s.frame_budget(False) == pytest.approx(100.0)
    s.ui_ms = 5.0  # and at least REFINE_BUDGETS beside a quick one (the view is still)
    assert s.frame_budget(False) == pytest.approx(REFINE_BUDGETS * 25.0)


def test_released_drag_refines_at_once_and_a_programmatic_move_settles_first(renderer, posed):
    """A drag let go (interacting -> not) has stopped: the next frame starts the full-resolution image. A camera
    moved without input (a script, the keyboard) is refined only `settle_s` after its last move."""
    renderer.use_points = True
    cams = [frame_points(posed.means, 240, 200, direction=d) for d in ("front", "three_quarter_left")]
    for interacting in (True, False):
        sched = DrawScheduler(renderer, budget_ms=math.inf, interactive_ms=1e-3, min_scale=0.25, settle_s=10.0)
        for _ in range(3):  # (the first pixels come from a cheaper image)
            sched.frame(cams[0], "rgb", content_version=1, interacting=False, now=0.0)
        assert sched.settled
        sched.frame(cams[1], "rgb", content_version=1, interacting=interacting, now=1.0)  # moved: a live image
        assert sched.scale < 1.0
        sched.frame(cams[1], "rgb", content_version=1, interacting=False, now=1.1)
        assert sched.settled is interacting  # released: refined at once; moved by a script: within settle_s


def test_a_live_image_unfinished_when_the_view_stops_gives_way_to_the_stopped_views_image(renderer, posed):
    """A drag let go while a live image is still being drawn: that image is dropped and the full-resolution image of
    the stopped view starts in the same frame (finishing the live one first took another 30-125 ms and a redraw of a
    busy machine); the last finished image stays in front meanwhile."""
    renderer.use_points = True
    cams = [frame_points(posed.means, 240, 200, direction=d) for d in ("front", "three_quarter_left")]
    sched = DrawScheduler(renderer, budget_ms=math.inf, interactive_ms=1e-3, min_scale=0.5, settle_s=10.0)
    for _ in range(3):
        sched.frame(cams[0], "rgb", content_version=1, interacting=False, now=0.0)
    assert sched.settled
    front = sched.shown_target
    sched.budget_ms, sched.interactive_scale = 1e-3, 0.5  # one minimal slice a frame: the live image takes many frames
    sched.frame(cams[1], "rgb", content_version=1, interacting=True, now=1.0)
    assert renderer.drawing and sched.status == "preview" and sched.shown_target == front  # a live image under way
    sched.frame(cams[1], "rgb", content_version=1, interacting=False, now=1.1)  # let go
    assert renderer.drawing and sched.status == "refining" and sched.shown_target == front


def test_a_still_views_cheap_first_image_is_kept_through_its_frames(renderer, posed):
    """With no image on screen, a still view's first pixels come from a cheaper image (planned like a live one);
    drawn in many small slices it is kept until it finishes: only a view that stops drops a live image (a rule
    without the stop dropped it in every frame, and the window never drew)."""
    sched = DrawScheduler(renderer, budget_ms=1e-3, settle_s=0.0)  # one minimal slice a frame
    sched.interactive_scale = 0.5
    cam = frame_points(posed.means, 240, 200)
    for k in range(2000):
        sched.frame(cam, "rgb", content_version=1, interacting=False, now=float(k))
        if sched.images:
            break
    assert sched.images == 1 and sched.scale == 0.5


def test_points_equal_quads_at_any_subpixel_position(make_renderer, gl_path):
    gl_colour_pass(gl_path)
    """A point's square is the ellipse's box plus POINT_MARGIN (0.05 px, splat_common.glsl): small and large,
    round and thin splats at random sub-pixel positions, opacities near 1/255 (a box of almost nothing) and near
    1, drawn as points keep exactly the quad path's pixels, on both GL paths."""
    from tests.support.render import off_centre_camera, random_cloud

    g = random_cloud(3000, seed=7)
    rng = np.random.default_rng(7)
    g.opacities[:] = np.where(rng.random(len(g)) < 0.3, rng.uniform(1.0 / 255.0, 0.02, len(g)),
                              rng.uniform(0.02, 1.0, len(g))).astype(np.float32)
    r = make_renderer(64, 64)
    try:
        r.set_gaussians(g)
        for i, eye in enumerate([(0.4, 0.3, 3.0), (0.13, -0.27, 2.3), (-1.9, 0.71, 2.2)]):
            cam = off_centre_camera(eye)
            r.use_points = False
            quads = r.render(cam)
            r.use_points = True
            points = r.render(cam)
            assert r.last_timings["points"] == 1.0 and quads.max() > 0.2, i
            np.testing.assert_array_equal(points, quads)
    finally:
        r.release()


def test_a_still_views_work_stops_after_the_budget_in_progress_when_input_arrives(renderer):
    """`bounded`: a still view's work (several budgets a UI frame) goes one budget at a time and asks the window
    for input between them; input ends the frame's share (a drag waits for one budget, not for all); without a
    probe the whole budget goes in one call."""
    sched = DrawScheduler(renderer, budget_ms=10.0)
    calls: list[float] = []
    asked: list[int] = []

    def step(ms: float) -> bool:
        calls.append(ms)
        time.sleep(0.011)  # a slice that uses its budget
        return len(calls) == 100

    sched.input_probe = lambda: bool(asked.append(1)) or len(asked) >= 2
    assert not sched.bounded(step, 1e6)  # input arrived at the second ask: two budgets drawn
    assert len(calls) == 2 and all(ms <= 10.0 for ms in calls)
    calls.clear()
    asked.clear()
    sched.input_probe = lambda: bool(asked.append(1))  # no input: budget after budget until the share is spent
    t0 = time.perf_counter()
    assert not sched.bounded(step, 35.0)
    assert (time.perf_counter() - t0) * 1e3 >= 35.0 and len(calls) <= 4 and all(ms <= 10.0 for ms in calls)
    assert len(asked) == len(calls) - 1  # asked between budgets, not after the last
    calls.clear()
    asked.clear()
    sched.input_probe = None  # (no window to ask: the whole budget in one call)
    assert not sched.bounded(step, 1000.0)
    assert len(calls) == 1 and calls[0] > 10.0 and not asked
