"""`CompareController`: the Compare panel's actions, the files it opens (off the UI thread) and the view it shows.

Handed in: the window's GL context and the CNN device. Each UI frame the app calls `frame` with the avatar, the
window's code and camera and its budget, and `present` draws the comparison where the splat view would be. The
capture and the second avatar are read on a worker thread; errors come back as one line in `messages`."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError, shown
from npga_core.evaluation.compare import MODES
from npga_core.model.avatar import Avatar
from npga_view import actions as C
from npga_view.comparison.snapshot import PAIRS, CompareInfo, score_label
from npga_view.comparison.sources import CompareSources
from npga_view.comparison.view import CompareView
from npga_view.document import AvatarOpened, Subscriptions


class CompareController:
    """Owns the comparison's sources and view; see the module docstring."""

    def __init__(self, ctx: moderngl.Context, device: str = "cpu",
                 load_avatar: Callable[[str], Avatar] | None = None) -> None:
        from npga_core.files.loading import load_avatar as _load
        self.sources = CompareSources()
        self.view = CompareView(ctx, self.sources, device)
        self.active = False
        self.messages: list[str] = []
        self._load_avatar = load_avatar or _load
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="npga-compare-open")
        self._opening: tuple[str, Future] | None = None
        self._lock = threading.Lock()

    def handlers(self) -> C.Handlers:
        """The Compare panel's actions (npga_view/actions.py), each by a typed method."""
        h = C.Handlers()
        h.register(C.OpenCapture, self._open_capture)
        h.register(C.OpenAvatarB, self._open_b)
        h.register(C.ShowComparison, self._show)
        h.register(C.SetCompareMode, self._mode)
        h.register(C.SetComparePosition, self._position)
        h.register(C.SetComparePair, self._pair)
        h.register(C.SetCompareScale, self._scale)
        h.register(C.SetCompareCnn, self._cnn)
        h.register(C.SetCompareBackground, self._background)
        h.register(C.StepCapture, self._step)
        return h

    def subscriptions(self) -> Subscriptions:
        """A new avatar: the capture's codes must fit it (as a sequence must)."""
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._avatar_opened)
        return s

    def _avatar_opened(self, e: AvatarOpened) -> None:
        try:
            self.sources.check_sequence(e.avatar.code_dim)
        except AvatarFileError as err:
            self.sources.close_capture()
            self.messages.append(f"capture: {err}; capture closed")

    # --- actions --------------------------------------------------------------------------------------
    def _open_capture(self, a: C.OpenCapture) -> None:
        if not a.path:
            raise AvatarFileError("(no path)", "type the capture folder first")
        self._start("capture", lambda: self.sources.open_capture(a.path, a.sequence or None))

    def _open_b(self, a: C.OpenAvatarB) -> None:
        if not a.path:
            self.sources.set_b(None)
            if "b" in self.view.pair:
                self.view.set_pair("a-capture")
            return
        self._start("avatar B", lambda: self.sources.set_b(self._load_avatar(a.path), shown(a.path)))

    def _start(self, what: str, work: Callable[[], None]) -> None:
        self._opening = (what, self._pool.submit(work))
        self.active = True

    def _show(self, a: C.ShowComparison) -> None:
        self.active = bool(a.on)

    def _mode(self, a: C.SetCompareMode) -> None:
        if a.mode not in MODES:
            raise ValueError(f"unknown compare mode {a.mode!r}")
        self.view.set_mode(a.mode)

    def _position(self, a: C.SetComparePosition) -> None:
        self.view.set_position(a.t)

    def _pair(self, a: C.SetComparePair) -> None:
        self.view.set_pair(a.pair)

    def _step(self, a: C.StepCapture) -> None:
        self.sources.step(a.frames, a.cameras)

    def _scale(self, a: C.SetCompareScale) -> None:
        self.view.set_scale(a.vmax)

    def _cnn(self, a: C.SetCompareCnn) -> None:
        self.view.use_cnn = bool(a.on)

    def _background(self, a: C.SetCompareBackground) -> None:
        rgb = tuple(float(v) for v in a.rgb)
        if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
            raise ValueError(f"compare background must be three values in [0, 1], got {a.rgb!r}")
        self.view.background = rgb

    # --- per UI frame ---------------------------------------------------------------------------------
    def frame(self, avatar: Avatar | None, version: object, code: np.ndarray | None, camera: Camera,
              budget_ms: float) -> bool:
        """Collect finished opens; advance the comparison when shown. True when its image changed."""
        if self._opening is not None and self._opening[1].done():
            what, fut = self._opening
            self._opening = None
            try:
                fut.result()
                if what == "capture" and avatar is not None:
                    self.sources.check_sequence(avatar.code_dim)
                if what == "avatar B" and self.sources.capture is None:
                    self.view.set_pair("a-b")
            except (AvatarFileError, ValueError, OSError) as e:
                if what == "capture":
                    self.sources.close_capture()
                self.messages.append(f"{what}: {e}")
        if not self.active:
            return False
        return self.view.update(avatar, version, code, camera, budget_ms)

    def update(self, avatar: Avatar | None, code: np.ndarray | None, camera: Camera, budget_ms: float,
               report: Callable[[str], None]) -> bool:
        """One UI frame of the window: `frame`, errors to `report`; True when the comparison is shown and has an
        image (it replaces the splat view: `draw` it). The avatar's edits are seen through `Avatar.version`
        (bumped by every edit)."""
        version = None if avatar is None else (id(avatar), avatar.version)
        self.frame(avatar, version, code, camera, budget_ms)
        for msg in self.messages:
            report(msg)
        self.messages.clear()
        return self.active and self.view.has_image

    def draw(self, framebuffer: moderngl.Framebuffer, view: tuple[int, int, int, int],
             background: tuple[float, float, float]) -> None:
        """The comparison drawn into `view` of `framebuffer` (around it: the window's `background`)."""
        framebuffer.use()
        framebuffer.clear(*background, 1.0, viewport=view)
        self.present(framebuffer, view)

    @property
    def busy(self) -> bool:
        """Work is under way (the window keeps drawing frames until it is done)."""
        if self._opening is not None:
            return True
        return self.active and not self.view.status.ready

    def present(self, framebuffer: moderngl.Framebuffer, rect: tuple[int, int, int, int]) -> None:
        self.view.present(framebuffer, rect)

    def drag_divider(self, x: float) -> bool:
        """In wipe mode, move the divider under framebuffer column `x`; True when it moved."""
        if not self.active or self.view.settings.mode != "wipe":
            return False
        t = self.view.position_at(x)
        if t is None:
            return False
        self.view.set_position(t)
        return True

    def info(self) -> CompareInfo:
        s, v = self.sources, self.view
        cur = s.current
        return CompareInfo(self.active, "" if s.capture is None else shown(s.capture.root), tuple(s.cameras),
                           tuple(s.frames), None if cur is None else cur[0], None if cur is None else cur[1],
                           s.b_name, v.settings.mode, v.settings.t, v.pair, v.settings.vmax, v.use_cnn, v.background,
                           v.status.text, dict(v.status.scores),
                           "" if self._opening is None else f"opening {self._opening[0]}...",
                           tuple(self.overlay_lines()))

    def overlay_lines(self) -> list[str]:
        """The overlay's lines while the comparison is shown: what is compared and its scores."""
        if not self.active:
            return []
        st = self.view.status
        lines = [f"compare {self.view.pair} ({self.view.settings.mode}): {st.text}"]
        for role, sc in sorted(st.scores.items()):
            lp = "" if sc.lpips is None else f"  LPIPS {sc.lpips:.4f}"
            lines.append(f"  {score_label(role)}: PSNR {sc.psnr:.2f} dB  SSIM {sc.ssim:.4f}{lp}"
                         f"{'  (masked)' if sc.masked else ''}")
        return lines

    def release(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.view.release()


__all__ = ["PAIRS", "CompareController", "CompareInfo", "score_label"]
