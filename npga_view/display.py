"""`AppInfo`: what the panels show, a display snapshot the app copies each frame from the controllers' own state
(`ViewerApp._publish_info`, `PoseController.publish`, `EditController.publish`) and from its drawing figures.
Read-only for the panels; nothing decides from it (decisions read the controllers and `ViewerState`). It sits at the
bottom of npga_view (no GL, no imgui), so that controllers write it without importing a panel."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from npga_core.editing.edits import EditSession
from npga_core.editing.keyframes import KeyframeTimeline
from npga_core.files.sequences import ExpressionSequence
from npga_core.inspection.inspector import InspectInfo
from npga_core.model.avatar import Avatar
from npga_core.posing.engine import BakeStatus
from npga_view.comparison.snapshot import CompareInfo


@dataclass
class AppInfo:
    avatar: Avatar | None = None
    sequence: ExpressionSequence | None = None
    frame: int = 0  # the sequence frame the playback clock is on
    presented_frame: int = 0  # the sequence frame whose image is on screen (the clock's until one is)
    frame_sliders: np.ndarray | None = None  # the slider values of that frame while a sequence is followed
    fps: float = 0.0  # UI frames per second
    quiet: bool = False  # the window has nothing to do: its loop waits for input (the last frame's)
    frame_profile: list[str] = field(default_factory=list)  # where the UI frames' time goes (FrameProfile.lines)
    timings: dict[str, float] = field(default_factory=dict)  # ms per stage
    gaussians_drawn: int = 0
    posing: bool = False  # a dynamics request is pending
    preview: bool = False  # the cloud on screen is the engine's fast approximation (exact pose pending)
    baked: bool = False  # the cloud on screen is a baked frame (8-bit offsets)
    interpolated: bool = False  # ... interpolated between two stored frames of the bake
    bake: BakeStatus | None = None  # progress of the sequence's bake
    bake_state: str = "none"  # BakeController.state()
    compare: CompareInfo | None = None  # the Compare panel's snapshot (CompareController.info)
    engine_status: dict = field(default_factory=dict)  # the pose worker's report: device, first layer, preview
    achieved_fps: float = 0.0
    skipped: int = 0
    jitter_raw: float = 0.0
    jitter_smoothed: float = 0.0
    recording: bool = False
    rig_names: list[str] = field(default_factory=list)
    last_screenshot: str | None = None
    rects: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)  # widget -> x0, y0, x1, y1
    edit: EditSession | None = None  # the edit session of the open avatar
    keyframes: KeyframeTimeline | None = None
    keyframe_time: float = 0.0
    keyframe_playing: bool = False
    inspect: InspectInfo | None = None  # legend, counts, histogram, picked record (Inspect panel)
    shown: str = "splats"  # what the view shows: "splats", "refined" (CNN output), "latent", or "splats (refining)"
    cnn_ms: float = 0.0  # time of the last CNN refinement (Refiner.last_timings["cnn"])
    cnn_device: str = ""  # where the CNN runs (torch device)
    canonical: bool = False  # the cloud on screen is the canonical one (the first pose has not arrived)
    draw_scale: float = 1.0  # resolution scale of the splat image on screen
    image_status: str = "exact"  # DrawScheduler.status: "preview", "refining" or "exact"
    image_ms: float = 0.0  # drawing time of the last finished splat image
    draw_progress: float = 1.0  # fraction of the image being drawn
    merged_splats: int = 0  # the image on screen was drawn from a merged level-of-detail cloud of this many (0: all)
    renderer_path: str = ""  # the splat renderer's path (SplatRenderer.path: OpenGL 4.3 or 4.1)
    live_link: str = ""  # the Live Link receiver's status ("off", "listening on HOST:PORT", a message)
    live_counters: str = ""  # its packet counters, for the overlay ("" when not listening)
    live_listening: bool = False
    live_recording: bool = False
    live_unmatched: str = ""  # the stream's shapes the avatar's basis lacks
