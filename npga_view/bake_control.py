"""`BakeController`: the window's side of baked playback.

The worker bakes (`PoseEngine.bake`: progress, memory budget, cache file next to the avatar); this decides
whether the timeline plays from the bake. A bake is used only while it is of the codes on the timeline: a
change of sequence or smoothing makes it stale, and an edit (which restarts the worker) drops it. Until then
playback stays live (exact poses following the clock); frames not baked yet are posed exactly on request.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from npga_core.engine import BakeStatus

if TYPE_CHECKING:
    from .app import ViewerApp


class BakeController:
    """Start, cancel and judge the bake of the open sequence; see the module docstring."""

    def __init__(self, app: ViewerApp):
        self.app = app
        self.key: tuple | None = None  # what the current bake is of: (sequence, smoothing) key

    def _current_key(self) -> tuple | None:
        app = self.app
        if app.sequence is None:
            return None
        app._sequence_codes()  # refreshes the smoothing key
        return app._smooth_key

    def start(self) -> None:
        """Bake the timeline's (smoothed) codes and play from the bake."""
        app, tl = self.app, self.app.state.timeline
        if app.engine is None or app.sequence is None:
            raise ValueError("bake: open an animatable avatar and a sequence first")
        codes = app._sequence_codes()
        app.engine.bake(codes, budget_mb=tl.bake_budget_mb, cache=tl.bake_cache)
        self.key = self._current_key()
        tl.baked = True

    def cancel(self) -> None:
        """Stop baking and drop the bake; playback goes back to live."""
        if self.app.engine is not None:
            self.app.engine.cancel_bake()
        self.key = None
        self.app.state.timeline.baked = False

    def forget(self) -> None:
        """The worker was restarted (an edit, another avatar): its bake is gone."""
        self.key = None

    @property
    def status(self) -> BakeStatus | None:
        eng = self.app.engine
        return None if eng is None or self.key is None else eng.bake_status

    def state(self) -> str:
        """"none", "baking", "ready", "stale" (of other codes than the timeline's) or "error"."""
        st = self.status
        if st is None:
            return "none"
        if st.error and not st.finished:
            return "error"
        if self.key != self._current_key():
            return "stale"
        return "ready" if st.finished else "baking"

    def usable(self) -> bool:
        """Play from the bake: asked for, and the bake (finished or in progress) is of the timeline's codes."""
        return self.app.state.timeline.baked and self.state() in ("baking", "ready")
