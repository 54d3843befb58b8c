"""`ViewerHost`: what the window's controllers may use of the app, as an interface.

The controllers (editing, baking, posing, actions) are handed an object with these members (the `ViewerApp`)
instead of importing the app, so that they can be read, tested and replaced on their own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from npga_core.camera.cameras import Camera
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.avatar import Avatar
    from npga_core.model.gaussians import PosedGaussians
    from npga_core.posing.engine import PoseEngine
    from npga_view.panels.info import AppInfo
    from npga_view.state import ViewerState


class ViewerHost(Protocol):
    """The app as its controllers see it: shared state, the open files and a few operations."""

    state: ViewerState
    info: AppInfo
    avatar: Avatar | None
    engine: PoseEngine | None
    sequence: ExpressionSequence | None
    content_version: int  # incremented by every `show`
    remember_recent: bool  # per-user lists and settings are saved (not in tests)

    def adopt_avatar(self, avatar: Avatar, path: str) -> None:
        """Show `avatar` (loaded from `path`) as the open avatar."""

    def open_avatar(self, path: str) -> bool:
        """Load and show an avatar file; errors go to the UI."""

    def open_sequence(self, path: str) -> bool:
        """Load a sequence file for the open avatar; errors go to the UI."""

    def current_camera(self, ignore_keyframes: bool = False) -> Camera:
        """The camera of the splat view."""

    def shown_means(self) -> np.ndarray:
        """Centres of the Gaussians on screen."""

    def shown_posed(self) -> PosedGaussians | None:
        """The posed cloud on screen (before highlighting), if any."""

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        """The code of a new expression key: from the sliders, the sequence frame or a preset."""

    def shown_code(self) -> np.ndarray | None:
        """The expression code of the cloud on screen."""

    def show(self, posed: PosedGaussians) -> None:
        """Make `posed` the cloud on screen."""

    def cloud_changed(self, worker_path: str | None) -> None:
        """The canonical cloud was edited: re-pose it."""

    def reupload(self) -> None:
        """Upload the cloud on screen again (selection or visibility changed)."""

    def frame_avatar(self, reset: bool = False) -> None:
        """Point the orbit camera at the avatar."""

    def screenshot(self, path: str, viewport_only: bool = False) -> str:
        """Save the window as PNG."""
