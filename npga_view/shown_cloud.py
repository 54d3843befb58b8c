"""`ShownCloud`: the document's posed cloud as the renderer draws it: coloured as the Inspect settings say
(`InspectionCache`), with the edit highlights on top, uploaded when an image of the full cloud starts (poses that
arrive faster than images cost no upload each) and handed to the level-of-detail merge (`LiveDetail.submit`).

It subscribes to the document: a new avatar (or an edited cloud) gets a new inspector and a new level-of-detail
grouping, and an edited static avatar is posed again here (an animatable one by its worker).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.model.gaussians import PosedGaussians
from npga_view.controllers.editing import EditController, highlight
from npga_view.document import AvatarOpened, CloudChanged, Document, Subscriptions
from npga_view.inspection_cache import InspectionCache
from npga_view.rendering.live_detail import LiveDetail
from npga_view.rendering.renderer import NEAR, SplatRenderer
from npga_view.rendering.scheduler import DrawScheduler
from npga_view.state import ViewerState


class ShownCloud:
    """Handed the document, the state, the full cloud's renderer, the merged cloud, the scheduler, the edits (their
    highlights) and the view's camera (a getter); see the module docstring."""

    def __init__(self, doc: Document, state: ViewerState, renderer: SplatRenderer, lod: LiveDetail,
                 draws: DrawScheduler, edits: EditController, camera: Callable[[], Camera]) -> None:
        self.doc = doc
        self.state = state
        self.renderer = renderer
        self.lod = lod
        self.draws = draws
        self.edits = edits
        self.camera = camera
        self.inspection = InspectionCache()
        self.pending: PosedGaussians | None = None  # shown but not uploaded yet (`upload_pending`)
        draws.before_full_image = self.upload_now

    def subscriptions(self) -> Subscriptions:
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._opened)
        s.subscribe(CloudChanged, self._changed)
        return s

    def _opened(self, e: AvatarOpened) -> None:
        self.inspection.set_avatar(e.avatar)
        self.lod.reset()
        self.pending = None
        self.state.inspect.picked = None

    def _changed(self, e: CloudChanged) -> None:
        self.inspection.set_avatar(e.avatar)
        self.lod.reset()
        picked = self.state.inspect.picked
        if picked is not None and picked >= len(e.avatar):
            self.state.inspect.picked = None
        posed = self.doc.posed
        if self.doc.engine is None:  # (an animatable avatar's worker poses it)
            self.show(e.avatar.pose())
        elif e.kept is not None and posed is not None and len(posed) == len(e.kept):
            self.show(posed.subset(e.kept), self.doc.code)  # a deletion seen at once, before the worker's pose

    # --------------------------------------------------------------------------------------------- showing
    def show(self, posed: PosedGaussians, code: np.ndarray | None = None) -> None:
        """Make `posed` (of `code`) the cloud on screen; upload it as the Inspect settings colour it, with the
        edit highlights on top."""
        version = self.doc.shown(posed, code)
        session = self.edits.session
        selection = session.selection if session is not None and len(session) == len(posed) else None
        frame = self.inspection.frame(self.state.inspect, posed, code, self.camera, selection)
        self.pending = None
        if frame is None:
            uploaded = highlight(posed, session)
            self.renderer.clear_lines()
        else:  # style, point size and lines now; the Gaussians as below
            uploaded = frame.posed = highlight(frame.posed, session)
            self.renderer.show(frame, upload=False)
        if len(uploaded) == self.renderer.count > 0:
            # uploaded when an image of the full cloud starts (`before_full_image`): poses arriving faster than
            # images (a stream, playback; live images from the merged cloud) cost no upload each
            self.pending = uploaded
        else:
            self.renderer.set_gaussians(uploaded)
        self.lod.submit(version, uploaded)

    def reupload(self) -> None:
        """Upload the cloud on screen again (after a selection, hide or preview change)."""
        if self.doc.posed is not None:
            self.show(self.doc.posed, self.doc.code)

    def refresh(self) -> None:
        """Show the cloud again if the Inspect settings (or, for depth colouring, the camera) changed."""
        if self.doc.posed is not None and self.inspection.stale(self.state.inspect, self.camera):
            self.reupload()

    def upload_pending(self, force: bool = False) -> None:
        """Upload the newest shown cloud to the full cloud's renderer unless one of its images is in progress (or
        now, with `force`): poses that arrive faster than images are drawn (a Live Link stream, playback) cost one
        upload per image of the full cloud, not one per pose."""
        if self.pending is not None and (force or not self.draws.drawing_full):
            pending, self.pending = self.pending, None
            self.renderer.set_gaussians(pending)

    def upload_now(self) -> None:
        self.upload_pending(force=True)

    # --------------------------------------------------------------------------------------------- reading
    def pick(self, x: float, y: float) -> int | None:
        """Pick the Gaussian at view pixel (x, y) (top-left origin) for the inspector."""
        self.upload_now()
        idx = self.renderer.pick(self.camera(), x, y)
        self.state.inspect.picked = idx
        self.inspection.due = True
        return idx

    def update_figures(self, camera: Camera, interacting: bool) -> None:
        """The Inspect panel's figures, when due (`InspectionCache.update_figures`)."""
        self.inspection.update_figures(self.state.inspect, self.doc.posed, self.doc.code, camera,
                                       self.renderer.drawn_mask, NEAR, interacting, time.perf_counter())
