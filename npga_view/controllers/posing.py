"""`PoseController`: which expression the window shows, and keeping the pose worker asked for it.

Every frame the controller picks the target code (the sequence frame on the clock, a keyframe, or the
sliders), asks the worker for it when it changed (a preview first and then the exact pose for slider moves,
exact poses or baked frames for playback), and takes what the worker answered: the posed cloud goes to the
host's screen (`show`), and the frame bookkeeping tells playback which frame is on screen. It subscribes to the
document (npga_view/document.py): a new avatar resets it and shows its first pixels, an edit or a new worker asks
again, a sequence opened or closed sets up playback.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from npga_core.model.gaussians import PosedGaussians
from npga_view.controllers.bake import BakeController
from npga_view.controllers.host import ViewerHost
from npga_view.controllers.playback import Playback
from npga_view.controllers.sequence_codes import SequenceCodes
from npga_view.display import AppInfo
from npga_view.document import AvatarOpened, CloudChanged, SequenceChanged, Subscriptions

#: the longest real-time playback holds its next request back for the view (`PoseController._hold`)
HOLD_S = 0.5


class PoseController:
    """Owned by the app; `update(dt)` runs once per UI frame. See the module docstring."""

    def __init__(self, host: ViewerHost, sequence_codes: SequenceCodes, bakes: BakeController,
                 keyframe_code: Callable[[], np.ndarray | None], playback_previews: bool = True,
                 taken_version: Callable[[], int] | None = None):
        self.host = host
        #: the newest content version the view has put into an image (drawn or being drawn); real-time playback
        #: asks for its next frame only once the last pose is in one (`_hold`)
        self.taken_version = taken_version
        self.playback_previews = playback_previews  # real-time playback may show previews to keep the clock
        self.canonical_first = True  # show the canonical cloud at once when an avatar opens, until its first pose
        self.seq_codes = sequence_codes
        self.bakes = bakes
        self._keyframe_code = keyframe_code
        self.first_pose_shown = False
        self.changed = False  # a new pose arrived this frame (the image must be redrawn)
        self.playback: Playback | None = None  # the open sequence's clock (None without a sequence)
        self.frame = 0  # the sequence frame the clock is on
        self.timings: dict[str, float] = {}  # the worker's last F and G times, ms
        self._asked_at = 0.0  # when the last request was sent (perf_counter)
        self.held = 0  # UI frames in which playback held its next request back (`_hold`)
        self.reset()

    def reset(self) -> None:
        """Forget what was asked and shown (a new avatar)."""
        self.requested: np.ndarray | None = None
        self.shown_frame: int | None = None
        self.presented_frame: int | None = None  # the sequence frame of the image on screen (`presented`)
        self.requested_frame: int | None = None
        self._frame_of_request: dict[int, int | None] = {}  # pending request id -> sequence frame it shows
        self._frame_of_version: dict[int, int] = {}  # content version uploaded -> sequence frame it shows
        self._newest_taken: tuple[int, int] = (0, 0)  # (id of the engine, request id) of the newest answer shown
        self.canonical = False  # the cloud on screen is the canonical one (the first pose has not arrived)
        self.preview = False  # ... the worker's fast approximation (the exact pose is on its way)
        self.baked = False  # ... a baked frame
        self.interpolated = False  # ... interpolated between two stored frames of the bake

    def subscriptions(self) -> Subscriptions:
        """What this controller does when the document changes (npga_view/document.py)."""
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._opened)
        s.subscribe(CloudChanged, self._cloud_changed)
        s.subscribe(SequenceChanged, self._sequence_changed)
        return s

    def _opened(self, e: AvatarOpened) -> None:
        """Forget the last avatar's poses; the first pixels at once: the canonical cloud (labelled) until the
        worker's first pose arrives, or the pose of an avatar without a worker."""
        self.reset()
        self.first_pose_shown = False
        if self.host.doc.engine is None:
            self.host.screen.show(e.avatar.pose())
            self.first_pose_shown = True
        elif self.canonical_first:
            self.canonical = True
            self.host.screen.show(e.avatar.cloud.posed_static())

    def _cloud_changed(self, e: CloudChanged) -> None:
        """The worker is on the edited cloud now: ask it for the current code again. A deletion's kept rows are on
        screen meanwhile (`ShownCloud`): drawn as a pose about to be replaced (live images) until the worker's."""
        self.requested = None
        self._frame_of_request = {}
        self.preview = self.preview or (e.kept is not None and self.host.doc.engine is not None)

    def _sequence_changed(self, e: SequenceChanged) -> None:
        seq = e.sequence
        self.playback = None if seq is None else Playback(len(seq), seq.fps)
        self.presented_frame = None
        self.seq_codes.forget()

    @property
    def shown_code(self) -> np.ndarray | None:
        """The expression code of the cloud on screen (the document's)."""
        return self.host.doc.code

    @property
    def codes(self) -> np.ndarray | None:
        """The sequence's smoothed codes (None until first asked for, or without a sequence)."""
        return self.seq_codes.codes

    @property
    def exact(self) -> bool:
        """The cloud on screen is the exact pose of what is asked for (not a preview, canonical or interpolated)."""
        return not (self.preview or self.canonical or self.interpolated)

    # ------------------------------------------------------------------------------------------- codes
    def slider_code(self) -> np.ndarray:
        """The code the expression sliders describe."""
        avatar = self.host.doc.avatar
        assert avatar is not None and avatar.expression is not None, "sliders need an expression space"
        st, ex = self.host.state, avatar.expression
        return ex.from_sliders(st.sliders) if st.sliders.size else ex.mean.copy()

    def sequence_codes(self) -> np.ndarray:
        return self.seq_codes.get()

    def code_for_keyframe(self, source: str, preset: str | None) -> np.ndarray:
        """The code a new expression keyframe takes: from the sliders, the sequence frame or a preset."""
        avatar = self.host.doc.avatar
        ex = avatar.expression if avatar is not None else None
        if ex is None:
            raise ValueError("this avatar has no expression space")
        if source == "frame":
            if self.codes is None:
                raise ValueError("no sequence frame: open a sequence first")
            return self.codes[self.frame].copy()
        if source == "preset":
            if preset in ex.named:
                return ex.named[preset].copy()
            if preset in self.host.state.presets:
                return np.asarray(self.host.state.presets[preset], np.float32)
            raise ValueError(f"no preset named {preset!r}")
        return self.slider_code()

    def frame_on_screen(self) -> int:
        """The sequence frame on screen (the clock's until the first one is shown)."""
        return self.shown_frame if self.shown_frame is not None else self.frame

    def following(self) -> bool:
        return self.host.doc.sequence is not None and self.host.state.follow_sequence

    def target_code(self, dt: float) -> np.ndarray | None:
        """The code to show now; advances the playback clock while a sequence is followed."""
        host = self.host
        a = host.doc.avatar
        if a is None or a.dynamics is None:
            return None
        if self.following():
            codes = self.sequence_codes()
            shown = self.shown_frame == self.requested_frame
            assert self.playback is not None  # (a sequence is followed)
            frame = self.playback.advance(host.state.timeline, dt, shown)
            self.frame = frame
            self.requested_frame = frame
            return codes[frame]
        kf = self._keyframe_code()
        if kf is not None:
            return kf
        if a.expression is None:
            return a.neutral_code()
        return self.slider_code()

    # ----------------------------------------------------------------------------------------- per frame
    def update(self, dt: float) -> None:
        """Ask the worker for the target code if it changed, and take its answer."""
        host = self.host
        code = self.target_code(dt)
        eng = host.doc.engine
        self.changed = False
        if eng is None:
            return
        following = self.following()
        if code is not None and (self.requested is None or not np.array_equal(code, self.requested)) \
                and not self._hold(following):
            tl = host.state.timeline
            if following and self.requested_frame is not None and self.bakes.usable(self.seq_codes.key()):
                req = eng.request_frame(self.requested_frame)
            else:  # sliders and real-time playback: a fast preview while exact poses are slow, then the exact
                # pose (abandoned when the clock has moved on); every-frame playback: exact poses only
                exact_only = following and ((tl.playing and tl.every_frame) or not self.playback_previews)
                req = eng.request(code, mode="exact" if exact_only else "auto")
            self.requested = code.copy()
            self._asked_at = time.perf_counter()
            self._frame_of_request[req] = self.requested_frame if following else None
        elif following and code is not None and self.shown_frame != self.requested_frame \
                and eng.pending is None and self.shown_code is not None and np.array_equal(code, self.shown_code):
            # a frame with the code already on screen (a held expression): it is shown as it is, and the head
            # pose of the new frame applies. If the image of that pose has not reached the screen yet, it will
            # count as this frame (presenting it now, and the earlier frame when the image came, moved the readout
            # back and counted a whole loop of skipped frames: the demo's frames 81-91 hold one code)
            self.shown_frame = self.requested_frame
            if self._frame_of_version and self.shown_frame is not None:
                self._frame_of_version[max(self._frame_of_version)] = self.shown_frame
            else:
                self.presented_frame = self.shown_frame
                if self.playback is not None and self.shown_frame is not None:
                    self.playback.shown(self.shown_frame, time.perf_counter(), host.state.timeline.playing)
        self._take(eng.poll())
        if eng.last_error:
            host.state.report(eng.last_error)
            eng.last_error = None

    def _hold(self, following: bool) -> bool:
        """Real-time playback waits with its next request while the last one is unanswered or its pose is not in
        an image yet (at most `HOLD_S`): the view draws fewer images a second than the sequence has frames (llvmpipe:
        8-10 of 25), and every pose asked for and not drawn took the worker's time (0.7 of 2 cores for the demo's
        previews) and the window's (taking it) from the images. The next frame is posed while an image is drawn."""
        tl = self.host.state.timeline
        eng = self.host.doc.engine
        if not (following and tl.playing and not tl.every_frame) or self.taken_version is None or eng is None \
                or time.perf_counter() - self._asked_at > HOLD_S:
            return False
        held = eng.pending is not None or self.taken_version() < self.host.doc.version
        self.held += held
        return held

    def publish(self, info: AppInfo) -> None:
        """Copy what the panels show into the frame's display snapshot."""
        eng = self.host.doc.engine
        info.frame = self.frame
        info.presented_frame = self.frame if self.presented_frame is None else self.presented_frame
        info.frame_sliders = self._frame_sliders(info.presented_frame)
        info.posing = eng is not None and eng.pending is not None
        info.engine_status = eng.status if eng is not None else {}
        if self.playback is not None:
            info.achieved_fps = self.playback.achieved_fps()
            info.skipped = self.playback.skipped
        info.jitter_raw, info.jitter_smoothed = self.seq_codes.jitter_raw, self.seq_codes.jitter_smoothed
        info.canonical, info.preview = self.canonical, self.preview
        info.baked, info.interpolated = self.baked, self.interpolated
        info.timings.update(self.timings)

    @property
    def newest_answer(self) -> int:
        """Request id of the newest worker answer shown (0 before the first of this worker)."""
        return self._newest_taken[1] if self._newest_taken[0] == id(self.host.doc.engine) else 0

    def _frame_sliders(self, frame: int) -> np.ndarray | None:
        """The slider values of sequence frame `frame`'s code while the sequence is followed (the Expression panel
        shows where the played frames lie along the directions), else None."""
        a, codes = self.host.doc.avatar, self.codes
        if not self.following() or a is None or a.expression is None or codes is None or not 0 <= frame < len(codes):
            return None
        return a.expression.to_sliders(codes[frame]).astype(np.float32)  # (one small projection a frame)

    def _take(self, result) -> None:
        """Show a worker answer (a preview, an exact pose or a baked frame) and do its frame bookkeeping."""
        if result is None:
            return
        host = self.host
        engine = id(host.doc.engine)
        if self._newest_taken[0] == engine and result.request_id < self._newest_taken[1]:
            # an answer older than one shown (an exact pose that finished after a newer request's preview, its
            # cancel not seen in time): shown, it would move the face back a few frames
            result.release()
            return
        refines = self._newest_taken == (engine, result.request_id)  # the exact pose of the preview on screen
        self._newest_taken = (engine, result.request_id)
        self.canonical = False
        frame = self._frame_of_request.get(result.request_id)
        if refines and frame is not None and self.shown_frame is not None:
            frame = self.shown_frame  # (a held expression may have moved on since: the frames that show this code)
        if host.doc.avatar is not None and len(result.posed) == len(host.doc.avatar):
            p = result.posed
            host.screen.show(PosedGaussians(p.means.copy(), p.quats.copy(), p.scales.copy(), p.opacities.copy(),
                                            p.sh.copy(), None if p.latent is None else p.latent.copy()), result.code)
            if frame is not None:
                self._frame_of_version[host.doc.version] = frame
        result.release()
        self.timings.update({k: v for k, v in result.timings.items() if k in ("F", "G")})
        self.preview = bool(result.preview) and not result.baked
        self.baked, self.interpolated = result.baked, result.baked and result.preview
        if frame is not None:  # a preview shows its frame too (playback follows the clock with previews)
            self.shown_frame = frame
        if self.preview:  # the exact pose of this request follows: keep its frame bookkeeping
            return
        self._frame_of_request = {k: v for k, v in self._frame_of_request.items() if k > result.request_id}
        self.first_pose_shown = True
        self.changed = True

    def presented(self, version: int) -> None:
        """An image of content `version` reached the screen: the sequence frame it shows counts as shown
        (playback's achieved rate and skipped count are of frames on screen, not of poses computed)."""
        done = [v for v in self._frame_of_version if v <= version]
        if not done:
            return
        frame = self._frame_of_version[max(done)]
        for v in done:
            del self._frame_of_version[v]
        self.presented_frame = frame
        pb = self.playback
        if pb is not None:
            pb.shown(frame, time.perf_counter(), self.host.state.timeline.playing)
