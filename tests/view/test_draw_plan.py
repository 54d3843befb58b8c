"""The draw scheduler's decision (`npga_view.rendering.draw_plan.plan`), table by table: which image a frame
starts (its target, scale, source and label) or why it starts none (idle, waiting for a merge)."""

from __future__ import annotations

import pytest

from npga_view.rendering.draw_plan import FrameState, ImageInfo, PlanInputs, Source, Target, plan

T1 = Target(("cam",), "rgb", 1)
T2 = Target(("cam",), "rgb", 2)
MOVED = Target(("cam2",), "rgb", 1)


def inputs(**kw) -> PlanInputs:
    base = dict(target=T1, live=False, exact_content=True, shown=None, interactive_scale=0.4, lod_scale=0.6)
    return PlanInputs(**(base | kw))


def shown(target=T1, scale=1.0, exact=True, live=False) -> ImageInfo:
    return ImageInfo(target, scale, exact, live)


# (name, inputs, expected state, expected (draw target, scale, source, exact label, live) or None)
CASES = [
    ("first image: as fast as possible, live", inputs(),
     FrameState.LIVE, (T1, 0.4, Source.FULL, True, True)),
    ("settled and on screen: nothing to draw", inputs(shown=shown()),
     FrameState.IDLE, None),
    ("a camera move while live: live scale", inputs(target=MOVED, live=True, shown=shown()),
     FrameState.LIVE, (MOVED, 0.4, Source.FULL, True, True)),
    ("input stopped on a live image: refine to full", inputs(shown=shown(scale=0.4, live=True)),
     FrameState.REFINING, (T1, 1.0, Source.FULL, True, False)),
    ("live, a live image of this target stays", inputs(live=True, shown=shown(scale=0.3, live=True)),
     FrameState.IDLE, None),
    ("live, a full image stays", inputs(live=True, shown=shown()),
     FrameState.IDLE, None),
    ("input stopped on a merged cloud's image at full scale: every Gaussian at full resolution",
     inputs(shown=ImageInfo(T1, 1.0, True, True, merged=True)),
     FrameState.REFINING, (T1, 1.0, Source.FULL, True, False)),
    ("a new pose while settled: refine it", inputs(target=T2, shown=shown()),
     FrameState.REFINING, (T2, 1.0, Source.FULL, True, False)),
    ("the exact pose of a preview on screen", inputs(shown=shown(exact=False)),
     FrameState.REFINING, (T1, 1.0, Source.FULL, True, False)),
    ("merged cloud of this pose ready", inputs(target=T2, live=True, shown=shown(), use_lod=True, merged_ready=True),
     FrameState.LIVE, (T2, 0.6, Source.MERGED, True, True)),
    ("poses outrun merging: the newest merged one, as a preview",
     inputs(target=Target(("cam",), "rgb", 5), live=True, shown=shown(), use_lod=True, merged_version=3),
     FrameState.LIVE, (Target(("cam",), "rgb", 3), 0.6, Source.MERGED_BEHIND, False, True)),
    ("the merged pose is not newer than the screen's: every Gaussian",
     inputs(target=Target(("cam",), "rgb", 5), live=True, shown=shown(), use_lod=True, merged_version=1),
     FrameState.LIVE, (Target(("cam",), "rgb", 5), 0.4, Source.FULL, True, True)),
    ("merge on its way: wait", inputs(target=MOVED, live=True, shown=shown(), use_lod=True, merge_pending=True),
     FrameState.WAITING_FOR_MERGE, None),
    ("waited long enough: draw every Gaussian",
     inputs(target=MOVED, live=True, shown=shown(), use_lod=True, merge_pending=True, waited_ms=250.0),
     FrameState.LIVE, (MOVED, 0.4, Source.FULL, True, True)),
    ("a new pose whose merge is slower than a live image of every Gaussian: no wait",
     inputs(target=T2, live=True, shown=shown(), use_lod=True, merge_pending=True, merge_ms=90.0,
            live_wall_ms=(100.0, 30.0)),
     FrameState.LIVE, (T2, 0.4, Source.FULL, True, True)),
    ("a new pose whose merge is quicker: wait up to the difference",
     inputs(target=T2, live=True, shown=shown(), use_lod=True, merge_pending=True, merge_ms=20.0,
            live_wall_ms=(100.0, 30.0), waited_ms=60.0),
     FrameState.WAITING_FOR_MERGE, None),
    ("... and no longer", inputs(target=T2, live=True, shown=shown(), use_lod=True, merge_pending=True,
                                 merge_ms=20.0, live_wall_ms=(100.0, 30.0), waited_ms=75.0),
     FrameState.LIVE, (T2, 0.4, Source.FULL, True, True)),
    ("no merged cloud before the first image", inputs(live=True, use_lod=True, merged_ready=True, merge_pending=True),
     FrameState.LIVE, (T1, 0.4, Source.FULL, True, True)),
]


@pytest.mark.parametrize(("name", "given", "state", "image"), CASES, ids=[c[0] for c in CASES])
def test_plan(name, given, state, image):
    p = plan(given)
    assert p.state is state
    if image is None:
        assert p.draw is None
    else:
        assert (p.draw, p.scale, p.source, p.exact_content, p.live) == image
