"""`InspectionCache`: the Inspect panel's view of the cloud on screen, computed only when it is out of date.

`frame(...)` colours a posed cloud as the Inspect settings say (or None for the plain colours); `stale(...)`
says when the settings (or, for depth colouring, the camera) changed since; `figures(...)` recomputes the
panel's counts, histogram and picked record after a draw, at most every `INSPECT_INFO_LIVE_S` while the view
changes (playback brings a pose every frame; ~25 ms for the demo) and at once when it has settled.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.inspection.colouring import Colouring
from npga_core.inspection.inspector import InspectFrame, InspectInfo, Inspector, InspectSettings
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians

INSPECT_INFO_LIVE_S = 0.5  # seconds between the Inspect panel's figures while the view changes


class InspectionCache:
    """The open avatar's `Inspector`, the key of the frame on screen and the panel's last figures."""

    def __init__(self) -> None:
        self.inspector: Inspector | None = None
        self.key: tuple | None = None  # (settings key, camera key) of the frame on screen
        self.colouring: Colouring | None = None  # legend of the current colour mode (None: plain colours)
        self.figures: InspectInfo | None = None  # what the Inspect panel shows (`AppInfo.inspect`)
        self.due = False  # the figures are out of date
        self._t = -math.inf  # when they were last computed

    def set_avatar(self, avatar: Avatar | None) -> None:
        self.inspector = None if avatar is None else Inspector(avatar)

    def camera_key(self, settings: InspectSettings, camera: Callable[[], Camera]) -> tuple | None:
        """What of the camera the frame depends on (None unless the colour mode is camera-dependent)."""
        if self.inspector is None or not Inspector.camera_dependent(settings):
            return None
        return (camera().world_to_camera.tobytes(),)

    def stale(self, settings: InspectSettings, camera: Callable[[], Camera]) -> bool:
        return (settings.key(), self.camera_key(settings, camera)) != self.key

    def frame(self, settings: InspectSettings, posed: PosedGaussians, code: np.ndarray | None,
              camera: Callable[[], Camera], selection: np.ndarray | None) -> InspectFrame | None:
        """`posed` coloured as `settings` say, or None for the plain colours (also when colouring failed: the
        error goes to the figures)."""
        self.key = (settings.key(), self.camera_key(settings, camera))
        self.due = True
        frame = None
        if self.inspector is not None and len(posed) == len(self.inspector.avatar):
            try:
                cam = camera() if Inspector.camera_dependent(settings) else None  # (only depth colours use it)
                frame = self.inspector.frame(settings, posed, code, cam, selection)
            except ValueError as e:
                self.figures = self.figures or InspectInfo()
                self.figures.error = str(e)
        self.colouring = None if frame is None else frame.colouring
        return frame

    def update_figures(self, settings: InspectSettings, posed: PosedGaussians | None, code: np.ndarray | None,
                       camera: Camera, drawn_mask: Callable[[], np.ndarray | None], near: float, interacting: bool,
                       now: float) -> None:
        """Recompute the panel's figures when they are due (see the module docstring)."""
        throttled = interacting and now - self._t < INSPECT_INFO_LIVE_S
        inspector = self.inspector
        if not self.due or throttled or inspector is None or posed is None or len(posed) != len(inspector.avatar):
            return
        self.due = False
        self._t = now
        err = self.figures.error if self.figures is not None else None
        self.figures = inspector.info(settings, posed, code, self.colouring, camera, drawn_mask(), near)
        self.figures.error = self.figures.error or err
