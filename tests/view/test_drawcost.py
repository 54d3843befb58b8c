"""The colour pass's path (GL points or quads) follows the measured cost per image size (#27); images are the same."""

from __future__ import annotations

import numpy as np

from npga_core.camera.cameras import frame_points
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.rendering.drawcost import EXPLORE, PRIOR_PIXELS, PathCosts
from npga_view.rendering.renderer import SplatRenderer


def test_unmeasured_sizes_follow_the_prior_then_the_cheaper_path():
    costs = PathCosts()
    assert costs.choose(240, 225) is True and costs.choose(2560, 1440) is False  # the prior
    assert 1360 * 900 < PRIOR_PIXELS < 2560 * 1440  # cross-over
    costs.record(2560, 1440, False, 200.0, 80_000)
    # the measured path until the EXPLORE-th image of the size, which tries the other one to compare
    assert [costs.choose(2560, 1440) for _ in range(EXPLORE - 2)] == [False] * (EXPLORE - 2)
    assert costs.choose(2560, 1440) is True
    costs.record(2560, 1440, True, 300.0, 80_000)
    picks = [costs.choose(2560, 1440) for _ in range(3 * EXPLORE)]
    assert picks.count(False) >= 3 * EXPLORE - 3 and picks.count(True) >= 2  # cheaper quads, points re-measured
    costs.record(2560, 1440, True, 100.0, 80_000)
    costs.record(2560, 1440, True, 100.0, 80_000)  # points became cheaper (an average of the measurements)
    assert [costs.choose(2560, 1440) for _ in range(EXPLORE)].count(True) >= EXPLORE - 1
    assert costs.bucket(2560, 1440) == costs.bucket(2520, 1440) != costs.bucket(1280, 720)


def test_renderer_measures_both_paths_and_keeps_the_image(ctx):
    posed = make_synthetic_avatar(4000, seed=21).pose()
    r = SplatRenderer(ctx, 64, 64, cpu_colour=False)  # the GL colour pass's two paths
    try:
        r.set_gaussians(posed)
        cam = frame_points(posed.means, 200, 180)
        assert r.use_points is None  # measured choice by default
        images, paths = [], []
        for _ in range(EXPLORE):
            images.append(r.render(cam))
            paths.append(r.last_timings["points"])
        # the prior (points at this size) until the EXPLORE-th image, which draws quads once to compare
        assert paths == [1.0] * (EXPLORE - 1) + [0.0]
        b = r.path_costs.bucket(200, 180)
        assert (b, True) in r.path_costs.cost and (b, False) in r.path_costs.cost
        # (read before the third image: its own time updates the costs, which on a busy machine may flip them)
        cheaper = r.path_costs.cost[(b, True)] <= r.path_costs.cost[(b, False)]
        images.append(r.render(cam))
        assert r.last_timings["points"] == float(cheaper)
        for image in images[1:]:
            np.testing.assert_array_equal(image, images[0])
        r.use_points = False  # forced paths are not recorded
        before = dict(r.path_costs.cost)
        r.render(cam)
        assert r.last_timings["points"] == 0.0 and r.path_costs.cost == before
    finally:
        r.release()
