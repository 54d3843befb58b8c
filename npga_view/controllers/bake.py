"""`BakeController`: the window's side of baked playback.

The worker bakes (`PoseEngine.bake`: progress, memory budget, cache file next to the avatar); this decides
whether the timeline plays from the bake. A bake is used only while it is of the codes on the timeline: a
change of sequence or smoothing makes it stale, and an edit (the worker reopens the edited cloud) drops it. Until then
playback stays live (exact poses following the clock); frames not baked yet are posed exactly on request.
"""

from __future__ import annotations

from collections.abc import Callable

from npga_core.posing.engine import BakeStatus, PoseEngine
from npga_view.controllers.sequence_codes import SequenceCodes
from npga_view.document import AvatarOpened, CloudChanged, Subscriptions
from npga_view.state import ViewerState


class BakeController:
    """Start, cancel and judge the bake of the open sequence; see the module docstring.

    Handed in: the viewer state, the current pose engine (a getter: another avatar brings another) and the
    timeline's (smoothed) codes, whose key says what they are of (None without a sequence).
    """

    def __init__(self, state: ViewerState, engine: Callable[[], PoseEngine | None], codes: SequenceCodes):
        self._state = state
        self._engine = engine
        self._codes = codes
        self.key: tuple | None = None  # what the current bake is of: (sequence, smoothing) key

    def start(self) -> None:
        """Bake the timeline's (smoothed) codes and play from the bake."""
        tl, engine = self._state.timeline, self._engine()
        if engine is None or self._codes.key() is None:
            raise ValueError("bake: open an animatable avatar and a sequence first")
        engine.bake(self._codes.get(), budget_mb=tl.bake_budget_mb, cache=tl.bake_cache)
        self.key = self._codes.key()
        tl.baked = True

    def cancel(self) -> None:
        """Stop baking and drop the bake; playback goes back to live."""
        engine = self._engine()
        if engine is not None:
            engine.cancel_bake()
        self.key = None
        self._state.timeline.baked = False

    def subscriptions(self) -> Subscriptions:
        """Another avatar or an edited cloud has no bake: forget it."""
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._forget)
        s.subscribe(CloudChanged, self._forget)
        return s

    def _forget(self, e: AvatarOpened | CloudChanged) -> None:
        self.key = None

    @property
    def status(self) -> BakeStatus | None:
        eng = self._engine()
        return None if eng is None or self.key is None else eng.bake_status

    def state(self, codes_key: tuple | None = None) -> str:
        """"none", "baking", "ready", "stale" (of other codes than the timeline's) or "error". `codes_key`: the
        timeline's current key when the caller has it (else asked for)."""
        st = self.status
        if st is None:
            return "none"
        if st.error and not st.finished:
            return "error"
        if self.key != (self._codes.key() if codes_key is None else codes_key):
            return "stale"
        return "ready" if st.finished else "baking"

    def usable(self, codes_key: tuple | None = None) -> bool:
        """Play from the bake: asked for, and the bake (finished or in progress) is of the timeline's codes."""
        return self._state.timeline.baked and self.state(codes_key) in ("baking", "ready")
