"""Live images from a merged level-of-detail cloud (#14): `LiveDetail` and the `DrawScheduler` using it.

Headless (EGL / OSMesa llvmpipe). The merge itself is tested in tests/core/test_lod.py; here: the thread delivers
the newest cloud, the scheduler draws live images from it, waits a moment for a merge on its way, and always
draws the full-resolution image from every Gaussian (the same pixels as a plain draw).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from npga_core.camera.cameras import frame_points
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.scheduler import DrawScheduler
from tests.support.render import accumulated

CLUSTERS = 1024


@pytest.fixture(scope="module")
def avatar():
    return make_synthetic_avatar(6000, seed=5)


@pytest.fixture()
def full(make_renderer, avatar):
    r = make_renderer(64, 64)
    r.set_gaussians(avatar.pose())
    yield r
    r.release()


@pytest.fixture()
def lod(make_renderer, full):
    detail = LiveDetail(lambda: make_renderer(64, 64), full, clusters=CLUSTERS)
    yield detail
    detail.close()


def _wait_for(cond, timeout: float = 60.0) -> bool:
    """A condition with a generous bound (the machine may be busy), not a rate."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        if cond():
            return True
        time.sleep(0.005)
    return False


def test_a_requested_cloud_is_merged_in_the_thread(lod, avatar):
    a, b = avatar.pose(), avatar.pose(np.full(avatar.code_dim, 0.5, np.float32))
    lod.submit(1, a)
    assert not lod.pending(1)  # a cloud shown is not merged until asked for
    assert lod.request(1) is None and lod.pending(1)
    lod.submit(2, b)
    assert lod.request(1) is None  # no longer the newest cloud: not asked for again
    # queued; until it is merged it is shown moved along from merge 1 if that one is done (Merge.shifted)
    r2 = lod.request(2)
    assert lod.pending(2) and (r2 is None or lod.shifted)
    assert _wait_for(lambda: lod.request(2) is not None and not lod.shifted)
    assert not lod.pending(2) and lod.request(1) is None
    merged = lod.request(2)
    assert merged.count == lod.count and CLUSTERS // 2 < merged.count <= CLUSTERS
    assert lod.merge_ms > 0 and lod.error is None


def test_small_clouds_and_other_styles_are_drawn_in_full(lod, full, avatar):
    small = avatar.pose().subset(np.arange(2 * CLUSTERS - 1))
    lod.submit(1, small)
    assert lod.request(1) is None and not lod.pending(1)  # below min_count: nothing to merge
    lod.submit(2, avatar.pose())
    assert _wait_for(lambda: lod.request(2) is not None)
    full.style = "points"
    try:
        assert not lod.usable() and lod.request(2) is None
    finally:
        full.style = "splats"
    assert lod.request(2) is not None


def test_reset_drops_what_was_merged_for_the_old_avatar(lod, avatar):
    lod.submit(1, avatar.pose())
    assert _wait_for(lambda: lod.request(1) is not None)
    lod.reset()
    assert lod.request(1) is None and not lod.pending(1)  # (the cloud shown was forgotten too)


@pytest.mark.slow
def test_live_images_come_from_the_merged_cloud_and_the_exact_one_from_all(lod, full, avatar):
    full.use_points = True
    # interactive_ms: as slow as llvmpipe (live images of the full cloud stay below full resolution)
    sched = DrawScheduler(full, budget_ms=math.inf, interactive_ms=1e-3, settle_s=0.0, lod=lod)
    sched.lod_above_ms = 0.0  # as if a full-resolution image did not fit in the budget (llvmpipe)
    cam = frame_points(avatar.pose().means, 200, 180)
    lod.submit(1, avatar.pose())
    sched.frame(cam, "rgb", content_version=1, interacting=True, now=0.0)
    assert sched.images == 1 and sched.shown_merged == 0  # a new pose: drawn in full, its merge not asked for
    assert not lod.pending(1)
    # the camera moves, the pose stays: its merge is asked for, waited for, and live images come from it
    moved = frame_points(avatar.pose().means, 200, 180, direction="three_quarter_right")
    assert not sched.frame(moved, "rgb", content_version=1, interacting=True, now=0.1)
    assert lod.pending(1) or lod.request(1) is not None
    assert _wait_for(lambda: lod.request(1) is not None)
    sched.frame(moved, "rgb", content_version=1, interacting=True, now=0.15)
    assert sched.images == 2 and sched.shown_merged == lod.count and sched.shown_renderer is lod.renderer
    assert sched.status == "preview"
    # a new pose while live (a slider, a stream's packet): drawn at once from the last merge moved along to it
    # (Merge.shifted), while its own merge is asked for
    pose2 = avatar.pose(np.full(avatar.code_dim, 0.3, np.float32))
    lod.submit(2, pose2)
    assert sched.frame(moved, "rgb", content_version=2, interacting=True, now=0.2)
    assert sched.shown_version == 2 and sched.shown_merged == lod.count and lod.shifted
    # its merge replaces the shifted cloud once it arrives
    assert _wait_for(lambda: lod.request(2) is not None and not lod.shifted)
    sched.frame(moved, "rgb", content_version=2, interacting=True, now=0.25)
    assert sched.shown_version == 2 and sched.shown_merged == lod.count
    # poses that change faster than they are merged (playback): each drawn shifted from the newest merge
    lod.submit(3, avatar.pose(np.full(avatar.code_dim, 0.6, np.float32)))
    assert _wait_for(lambda: lod.request(3) is not None and not lod.shifted)
    pose4 = avatar.pose(np.full(avatar.code_dim, 0.9, np.float32))
    lod.submit(4, pose4)
    assert sched.frame(moved, "rgb", content_version=4, interacting=True, now=0.3)
    assert sched.shown_version == 4 and sched.shown_merged == lod.count and sched.status == "preview"
    # input stops: full resolution from every Gaussian, the pixels of a plain draw
    full.set_gaussians(pose4)
    sched.frame(moved, "rgb", content_version=4, interacting=False, now=1.0)
    assert sched.settled and sched.status == "exact" and sched.shown_merged == 0 and sched.scale == 1.0
    exact = accumulated(full)
    full.draw(moved)
    np.testing.assert_array_equal(exact, accumulated(full))


class _SlowMerge:
    """A `LiveDetail` whose merge of every version is on its way and never arrives."""

    uploaded_version = -1

    def usable(self) -> bool:
        return True

    def pending(self, version: int) -> bool:
        return True

    def request(self, version: int):
        return None


def test_scheduler_waits_a_moment_for_a_merge_on_its_way(full, avatar):
    full.use_points = True
    sched = DrawScheduler(full, budget_ms=math.inf, interactive_ms=1e-3, settle_s=0.0, lod=_SlowMerge(),
                          lod_wait_ms=200.0)
    sched.lod_above_ms = 0.0
    cam = frame_points(avatar.pose().means, 160, 140)
    moved = frame_points(avatar.pose().means, 160, 140, direction="right")
    assert sched.frame(cam, "rgb", content_version=1, interacting=True, now=0.0)  # the first image never waits
    assert not sched.frame(moved, "rgb", content_version=1, interacting=True, now=1.0)  # waits for the merge
    assert not sched.frame(moved, "rgb", content_version=1, interacting=True, now=1.1)
    assert sched.images == 1
    assert sched.frame(moved, "rgb", content_version=1, interacting=True, now=1.25)  # waited long enough: in full
    assert sched.images == 2 and sched.shown_merged == 0
    # a new pose waits as well, bounded from when the waiting began (poses may change faster than any merge)
    assert not sched.frame(moved, "rgb", content_version=2, interacting=True, now=1.3)
    assert not sched.frame(moved, "rgb", content_version=3, interacting=True, now=1.45)
    assert sched.frame(moved, "rgb", content_version=4, interacting=True, now=1.55)
    assert sched.shown_version == 4 and sched.shown_merged == 0
    # not live: the full-resolution image is drawn at once, nothing is waited for
    assert sched.frame(cam, "rgb", content_version=3, interacting=False, now=5.0)
    assert sched.shown_version == 3 and sched.scale == 1.0


@pytest.mark.slow
def test_no_merged_cloud_where_a_full_image_fits_in_the_budget(lod, full, avatar):
    """On a GPU a full-resolution image of every Gaussian fits in the frame budget: the merged cloud is never
    asked for."""
    full.use_points = True
    sched = DrawScheduler(full, budget_ms=1e9, interactive_ms=1e9, settle_s=0.0, lod=lod)
    lod.submit(1, avatar.pose())
    cam = frame_points(avatar.pose().means, 120, 100)
    t = 0.0
    for direction in ("front", "right", "left", "three_quarter_right", "front", "right"):
        sched.frame(frame_points(avatar.pose().means, 120, 100, direction=direction), "rgb", 1, True, now=t)
        t += 0.1
    assert sched.images == 6 and sched.shown_merged == 0 and not lod.pending(1) and lod.renderer is None
    assert sched.frame(cam, "rgb", 1, False, now=t + 1) and sched.settled


def test_a_failed_merge_is_reported_not_waited_for(lod, avatar, monkeypatch):
    """A merge that raises leaves an error to show and nothing pending (a dead thread would keep the view waiting)."""
    import npga_view.rendering.live_detail as live_detail

    class Broken:
        def __init__(self, *a, **k):
            raise RuntimeError("no memory for the grouping")

    monkeypatch.setattr(live_detail, "LevelOfDetail", Broken)
    lod.submit(1, avatar.pose())
    assert lod.request(1) is None
    assert _wait_for(lambda: lod.error is not None)
    assert "no memory for the grouping" in lod.error and not lod.pending(1)


def test_a_new_pose_is_not_waited_for_when_merging_is_slower_than_drawing(lod, full, avatar):
    """A large avatar's merge can take longer than a live image of all its Gaussians: then a new pose is drawn in
    full at once (an orbit, one merge for many images, still waits)."""
    full.use_points = True
    sched = DrawScheduler(full, budget_ms=math.inf, interactive_ms=1e-3, settle_s=0.0, lod=lod)
    sched.lod_above_ms = 0.0
    cam = frame_points(avatar.pose().means, 160, 140)
    lod.submit(1, avatar.pose())
    assert sched.frame(cam, "rgb", content_version=1, interacting=True, now=0.0)
    sched._live_wall_ms = [150.0, 20.0]
    lod.merge_ms = 400.0  # the last merge took longer than a full live image
    lod.submit(2, avatar.pose(np.full(avatar.code_dim, 0.3, np.float32)))
    assert sched.frame(cam, "rgb", content_version=2, interacting=True, now=0.1)
    assert sched.shown_version == 2 and sched.shown_merged == 0


def test_merges_of_poses_that_keep_changing_rest_between(lod, avatar, monkeypatch):
    """While poses keep coming (playback, a stream), a merge of M ms is followed by at least REST x M ms without
    one (the poses meanwhile are shown shifted from it): merges took 0.35 of 2 cores during the demo's playback."""
    from npga_core.model.lod import LevelOfDetail
    from npga_view.rendering import live_detail

    starts: list[float] = []
    real = LevelOfDetail.merge_keeping

    def slow_merge(self, posed):  # a merge of at least 30 ms, whatever the machine
        starts.append(time.perf_counter())
        time.sleep(0.03)
        return real(self, posed)

    monkeypatch.setattr(LevelOfDetail, "merge_keeping", slow_merge)
    poses = [avatar.pose(np.full(avatar.code_dim, v, np.float32)) for v in (0.0, 0.5)]
    version, t_end = 0, time.perf_counter() + 60
    while len(starts) < 4 and time.perf_counter() < t_end:  # a new pose asked for every 5 ms
        version += 1
        lod.submit(version, poses[version % 2])
        lod.request(version)
        time.sleep(0.005)
    assert len(starts) == 4
    assert version >= 4 * 4, "poses came faster than merges (the test would prove nothing)"
    gaps = np.diff(starts)
    assert live_detail.REST >= 1 and (gaps >= (1 + live_detail.REST) * 0.03 - 1e-3).all(), gaps
