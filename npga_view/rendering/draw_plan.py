"""`plan(PlanInputs) -> Plan`: the draw scheduler's decision for one UI frame, as a pure function.

What the frame is (`FrameState`): IDLE (the image on screen is what is wanted: nothing to start), LIVE (start
an image at the live scale: the view is changing), REFINING (start the full-resolution image of a view that
has settled), WAITING_FOR_MERGE (the merged cloud of this pose is nearly there: cheaper than a live image of
every Gaussian, so wait a little). npga_view/rendering/scheduler.py gathers the inputs (timings, the merged
cloud's state) and carries the plan out; tests/view/test_draw_plan.py checks the decisions table by table.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple


class Target(NamedTuple):
    """What an image shows: the camera (its key at full resolution), the render mode, the content version."""

    camera_key: tuple
    mode: str
    version: int


@dataclass(frozen=True)
class ImageInfo:
    """An image on screen: its target, scale, whether the cloud was the exact pose, whether it was drawn live
    and whether it came from the merged cloud."""

    target: Target
    scale: float
    exact_content: bool
    live: bool = False
    merged: bool = False


class FrameState(Enum):
    IDLE = "idle"
    LIVE = "live"
    REFINING = "refining"
    WAITING_FOR_MERGE = "waiting for a merge"


class Source(Enum):
    FULL = "full"  # every Gaussian (the full cloud's renderer)
    MERGED = "merged"  # the merged level-of-detail cloud of this pose (a second renderer)
    MERGED_BEHIND = "merged behind"  # the newest merged pose, older than this one (playback outruns merging)


@dataclass(frozen=True)
class PlanInputs:
    """Everything `plan` decides from (no clocks: `waited_ms` is measured by the caller)."""

    target: Target
    live: bool  # interacting, or within the settle time of a camera move
    exact_content: bool  # the cloud on screen is the exact pose
    shown: ImageInfo | None  # the image on screen (None before the first)
    interactive_scale: float  # the live scale of images of every Gaussian (adapted to their cost)
    lod_scale: float  # the same for images of the merged cloud
    use_lod: bool = False  # live, an image of every Gaussian costs more than the budget, a merged cloud exists
    merged_ready: bool = False  # the merged cloud of `target.version` is uploaded
    merged_version: int = -1  # the version of the merged cloud that is uploaded (-1: none)
    merge_pending: bool = False  # the merge of `target.version` is on its way (and the merged cloud usable)
    merge_ms: float = 0.0  # how long merges take
    lod_wait_ms: float = 200.0  # the longest wait for a merge
    live_wall_ms: tuple[float | None, float | None] = (None, None)  # wall time of the last live image: full, merged
    waited_ms: float | None = None  # how long this view has waited for a merge so far (None: not waiting)


@dataclass(frozen=True)
class Plan:
    state: FrameState
    draw: Target | None = None  # what to start drawing (None: nothing)
    scale: float = 1.0
    source: Source = Source.FULL
    exact_content: bool = True  # what the new image will be labelled
    live: bool = False  # the new image is a live one (its cost adapts the live scale)


def _merge_bound_ms(i: PlanInputs, steady: bool) -> float | None:
    """How long a view may wait for its merge: `lod_wait_ms`; for a new pose (not an orbit) only as long as the
    merge and its image come sooner than a live image of every Gaussian would, and not at all when merges take
    longer than that (None)."""
    bound = i.lod_wait_ms
    full, merged = i.live_wall_ms
    if not steady and full is not None and merged is not None:
        bound = min(bound, full - merged)
        if i.merge_ms > bound:
            return None
    return bound


def plan(i: PlanInputs) -> Plan:
    """The decision for a frame with no image being drawn (see the module docstring)."""
    shown = i.shown
    source, want, draw, exact = Source.FULL, (i.interactive_scale if i.live else 1.0), i.target, i.exact_content
    use_lod = i.use_lod and shown is not None
    if use_lod and i.merged_ready:
        source, want = Source.MERGED, i.lod_scale
    elif use_lod and shown is not None and shown.target.version < i.merged_version < i.target.version:
        # the pose changes faster than it is merged (playback, a slider): the newest merged pose, newer than the
        # one on screen, labelled a preview (its sequence frame is the one counted as shown)
        source, want, exact = Source.MERGED_BEHIND, i.lod_scale, False
        draw = Target(i.target.camera_key, i.target.mode, i.merged_version)
    stale = shown is None or shown.target != i.target or shown.exact_content != exact \
        or (shown.merged and not i.live)  # (a merged cloud's image is never the final one, at any scale)
    # while live, a live image of this very target stays (the adapted scale moving a little is no reason to draw
    # it again: that only took the cores from the exact pose being computed)
    if shown is not None and not stale and not (shown.scale < want and not (i.live and shown.live)):
        return Plan(FrameState.IDLE)
    if use_lod and source is Source.FULL and i.merge_pending:
        bound = _merge_bound_ms(i, steady=shown is not None and shown.target.version == i.target.version)
        if bound is not None and (i.waited_ms or 0.0) < bound:
            return Plan(FrameState.WAITING_FOR_MERGE)
    if shown is None:  # first image: as fast as possible, refined right after
        want = i.interactive_scale
    live = i.live or shown is None
    state = FrameState.REFINING if want >= 1.0 and not i.live else FrameState.LIVE
    return Plan(state, draw, want, source, exact, live)
