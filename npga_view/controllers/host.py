"""`ViewerHost`: what the window's controllers may use of the app, as an interface.

The controllers (editing, posing, actions, Live Link) are handed an object with these members (the `ViewerApp`)
instead of importing the app, so that they can be read, tested and replaced on their own. The open avatar, its
worker, sequence and the cloud on screen are the document's (`doc`, npga_view/document.py); what a controller
resets when an avatar opens it subscribes to there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from npga_core.camera.cameras import Camera
    from npga_core.model.gaussians import PosedGaussians
    from npga_view.document import Document
    from npga_view.opening import Opener
    from npga_view.state import ViewerState


class Screen(Protocol):
    """The cloud on screen (`npga_view.shown_cloud.ShownCloud`)."""

    def show(self, posed: PosedGaussians, code: np.ndarray | None = None) -> None:
        """Make `posed` (of `code`) the cloud on screen."""

    def reupload(self) -> None:
        """Upload the cloud on screen again (selection or visibility changed)."""


class ViewerHost(Protocol):
    """The app as its controllers see it: shared state, the document, opening files and a few operations."""

    state: ViewerState
    doc: Document  # the open avatar, worker, sequence and posed cloud, and their events
    opener: Opener  # opening avatars and sequences (errors go to the UI)

    @property
    def screen(self) -> Screen:
        """The cloud on screen: `show` a pose, `reupload` after a selection change."""

    def current_camera(self, ignore_keyframes: bool = False) -> Camera:
        """The camera of the splat view."""

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        """The code of a new expression key: from the sliders, the sequence frame or a preset."""

    def frame_avatar(self, reset: bool = False) -> None:
        """Point the orbit camera at the avatar."""

    def screenshot(self, path: str, viewport_only: bool = False) -> str:
        """Save the window as PNG."""
