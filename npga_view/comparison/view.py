"""`CompareView`: the window's comparison of the avatar against a capture, or against a second avatar (A/B).

What is compared: with a capture, the avatar (A) and optionally a second avatar (B) rendered at the capture
camera's own size and intrinsics, so pixels correspond, posed with the expression code of the capture's frame
(from the sequence opened with it, else the window's current code); without a capture, A and B through the
window's camera. `pair` picks the two images shown ("a-capture", "b-capture", "a-b"); the mode (wipe, blend,
difference heatmap, side by side) is `npga_core.evaluation.compare`'s.

Where the capture has a mask (alpha matte or face mask), every image shown is composited over the background
outside it, as `evaluate` scores them, so the heatmap shows the error the scores count.

The UI frame's budget is kept: capture images are read and both avatars posed (exact, as `evaluate` does) on a
worker thread; the splats are drawn in slices (`begin_draw`/`continue_draw`) and the latent image likewise; the CNN
(when the avatar has one and it is on) runs on its refiner's thread, all through `rendering/pipeline.py`'s
`ViewImage`, the pipeline of the window and the commands; composing and uploading one image is the only
whole-image work in a frame. Scores are computed as `evaluate` computes them (same masking), on the worker.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import cast

import moderngl
import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.evaluation.compare import CompareSettings, Mode, compose
from npga_core.evaluation.metrics import Scores, composite_background, score
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_view.comparison.snapshot import PAIRS
from npga_view.comparison.sources import CompareSources, Job, Prepared
from npga_view.rendering.factory import create_renderer
from npga_view.rendering.pipeline import ViewImage
from npga_view.rendering.refinement import Refiner
from npga_view.rendering.renderer import SplatRenderer


@dataclass
class _Drawing:
    """One avatar's image of the job being made: posed and uploaded ("pose"), then through the pipeline."""

    role: str
    view: ViewImage | None = None  # on its way through the one pipeline (rendering/pipeline.py)
    image: np.ndarray | None = None

    @property
    def stage(self) -> str:
        """pose -> splats -> latent -> cnn -> done"""
        return "done" if self.image is not None else "pose" if self.view is None else self.view.stage


@dataclass
class CompareStatus:
    """What the panel and the overlay show: the state in words and the scores of the images on screen."""

    text: str = "nothing to compare"
    scores: dict[str, Scores] = field(default_factory=dict)
    ready: bool = False


class CompareView:
    """Composes and presents the comparison; `update` once per UI frame within a budget, `present` to draw it."""

    def __init__(self, ctx: moderngl.Context, sources: CompareSources, device: str = "cpu") -> None:
        self.ctx = ctx
        self.sources = sources
        self.settings = CompareSettings("wipe")
        self.pair = "a-capture"
        self.use_cnn = True
        self.background = (1.0, 1.0, 1.0)  # of the renders and outside the masks, as `evaluate --background`
        self.status = CompareStatus()
        self._device = device
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="npga-compare")
        self._renderers: dict[str, SplatRenderer] = {}
        self._uploaded: dict[str, PosedGaussians] = {}  # what each renderer holds (not uploaded again)
        self._refiners: dict[str, Refiner] = {}
        self._refined: dict[str, Avatar] = {}  # the avatar each refiner was set to (set again only for another)
        self._presenter: Refiner | None = None
        self._job: Job | None = None
        self._future: Future | None = None
        self._prepared: Prepared | None = None
        self._drawings: dict[str, _Drawing] = {}
        self._composed_key: tuple | None = None
        self._scores: dict[str, Scores] = {}
        self._masked: tuple[int, dict[str, np.ndarray]] | None = None  # images composited outside the mask
        self._score_future: Future | None = None
        self._cancel = threading.Event()
        self.viewport: tuple[int, int, int, int] | None = None  # where the image was last presented

    # --- settings -------------------------------------------------------------------------------------
    def set_mode(self, mode: str, t: float | None = None) -> None:
        self.settings = replace(self.settings, mode=cast(Mode, mode), t=self.settings.t if t is None else t)
        self._composed_key = None

    def set_position(self, t: float) -> None:
        """The wipe divider / blend weight, clamped to [0, 1]."""
        t = float(t) if math.isfinite(t) else 0.5
        self.settings = replace(self.settings, t=min(max(t, 0.0), 1.0))
        self._composed_key = None

    def set_scale(self, vmax: float) -> None:
        """The difference heatmap's top."""
        self.settings = replace(self.settings, vmax=float(vmax))
        self._composed_key = None

    def set_pair(self, pair: str) -> None:
        if pair not in PAIRS:
            raise ValueError(f"unknown comparison {pair!r}; one of {', '.join(PAIRS)}")
        self.pair = pair
        self._composed_key = None

    def position_at(self, x: float) -> float | None:
        """The divider position under window framebuffer column `x`, or None off the image."""
        if self.viewport is None:
            return None
        vx, _, vw, _ = self.viewport
        return None if vw <= 0 else min(max((x - vx) / vw, 0.0), 1.0)

    # --- per UI frame ---------------------------------------------------------------------------------
    def update(self, avatar: Avatar | None, avatar_version: object, code: np.ndarray | None, camera: Camera,
               budget_ms: float) -> bool:
        """Advance the comparison of the current inputs by about `budget_ms` of GL work; True when the image on
        screen changed. `camera` and `code` are the window's (used where no capture decides them)."""
        job = self.sources.job(avatar, avatar_version, code, camera, self.background, self.use_cnn, self.pair)
        if job is None:
            self._drop()
            self.status = CompareStatus(self.sources.why_not(self.pair))
            return False
        if self._job is None or job.key != self._job.key:
            self._start(job)
        if self._prepared is None:
            if self._future is None or not self._future.done():
                return False
            self._prepared = self._future.result()
            if self._prepared.error:
                self.status = CompareStatus(self._prepared.error)
                return False
            self._drawings = {r: _Drawing(r) for r in self._prepared.posed}
        changed = self._draw(budget_ms)
        return self._compose() or changed

    def _start(self, job: Job) -> None:
        self._cancel.set()
        self._cancel = threading.Event()
        for d in self._drawings.values():
            if d.view is not None:
                d.view.cancel()
        for f in self._refiners.values():
            f.cancel()
        self._job, self._prepared, self._drawings, self._composed_key = job, None, {}, None
        self._scores, self._score_future, self._masked = {}, None, None
        self._future = self._pool.submit(self.sources.prepare, job, self._cancel)
        self.status = CompareStatus(f"{job.label}: reading and posing")

    def _drop(self) -> None:
        if self._job is not None:
            self._cancel.set()
        self._job, self._prepared, self._drawings, self._composed_key = None, None, {}, None

    def _renderer(self, role: str, camera: Camera) -> SplatRenderer:
        r = self._renderers.get(role)
        if r is None:
            r = self._renderers[role] = create_renderer(self.ctx, camera.width, camera.height)
        return r

    def _refiner(self, role: str, avatar: Avatar) -> Refiner:
        f = self._refiners.get(role)
        if f is None:
            f = self._refiners[role] = Refiner(self.ctx, self._device)
        if self._refined.get(role) is not avatar:
            f.set_avatar(avatar)
            self._refined[role] = avatar
        return f

    def _draw(self, budget_ms: float) -> bool:
        """Advance the next unfinished avatar image by the budget (`ViewImage`: the splats in slices, the latent
        pass in slices, the CNN on the role's refiner thread when the avatar has one and it is on)."""
        prep, job = self._prepared, self._job
        assert prep is not None and job is not None
        for role, d in self._drawings.items():
            if d.image is not None:
                continue
            if d.view is None:
                r = self._renderer(role, job.camera)
                if self._uploaded.get(role) is not prep.posed[role]:
                    r.set_gaussians(prep.posed[role])
                    self._uploaded[role] = prep.posed[role]
                avatar = prep.avatars[role]
                refiner = self._refiner(role, avatar) if job.use_cnn and avatar.cnn is not None else None
                d.view = ViewImage(r, job.camera, job.background, refiner if refiner and refiner.has_cnn else None,
                                   job.key + (role,))
            if not d.view.advance(budget_ms):
                return False
            d.image = d.view.image
        return False

    def _images(self) -> dict[str, np.ndarray]:
        """The images to compose: with a capture that has a mask, every image is composited over the background
        outside it, as the scores see them (`npga_core.evaluation.metrics.score`)."""
        prep, job = self._prepared, self._job
        out = {role: d.image for role, d in self._drawings.items() if d.image is not None}
        if prep is not None and prep.capture is not None:
            out["capture"] = prep.capture.image
            if prep.capture.mask is not None and job is not None:
                if self._masked is None or self._masked[0] != len(out):
                    m = prep.capture.mask
                    self._masked = (len(out), {k: composite_background(v, m, job.background).astype(np.float32)
                                               for k, v in out.items()})
                return self._masked[1]
        return out

    def _compose(self) -> bool:
        """Compose the pair once both images exist (and again when the mode moves); score it on the worker."""
        job, prep = self._job, self._prepared
        if job is None or prep is None:
            return False
        images = self._images()
        first, second = job.pair
        done = sum(d.stage == "done" for d in self._drawings.values())
        waiting = [r for r in (first, second) if r not in images]
        if waiting:
            stages = ", ".join(f"{d.role}: {d.stage}" for d in self._drawings.values() if d.stage != "done")
            self.status = CompareStatus(f"{job.label}: drawing ({stages or 'images'}; {done} done)",
                                        dict(self._scores))
            return False
        self._start_scores(prep)
        key = (job.key, self.settings)
        if key == self._composed_key:
            self._collect_scores(job)
            return False
        composed = compose(images[first], images[second], self.settings)
        if self._presenter is None:
            self._presenter = Refiner(self.ctx, "cpu")
        self._presenter.upload(composed)
        self._composed_key = key
        self._collect_scores(job)
        return True

    def _start_scores(self, prep: Prepared) -> None:
        """Score on the worker, as `evaluate` does (from the raw images: `score` applies the mask itself): each
        avatar against the capture, or A against B without one."""
        raw = {role: d.image for role, d in self._drawings.items() if d.image is not None}
        if self._score_future is not None or len(raw) < len(prep.posed) or self._job is None:
            return
        cap, bg = prep.capture, self._job.background
        if cap is not None:
            self._score_future = self._pool.submit(
                lambda: {role: score(img, cap.image, cap.mask, bg) for role, img in raw.items()})
        elif "a" in raw and "b" in raw:
            self._score_future = self._pool.submit(lambda: {"a-b": score(raw["a"], raw["b"])})

    def _collect_scores(self, job: Job) -> None:
        f = self._score_future
        if f is not None and f.done() and not self._scores:
            self._scores = f.result()
        self.status = CompareStatus(job.label, dict(self._scores), ready=True)

    # --- on screen ------------------------------------------------------------------------------------
    @property
    def prepared(self) -> Prepared | None:
        """The last job's inputs as the worker made them (the captured view, each avatar's pose), once taken."""
        return self._prepared

    @property
    def has_image(self) -> bool:
        return self._composed_key is not None and self._presenter is not None

    def present(self, framebuffer: moderngl.Framebuffer, view: tuple[int, int, int, int]) -> None:
        """Draw the composed image into `view` (x, y, w, h of the framebuffer), letterboxed to its aspect."""
        if not self.has_image or self._presenter is None or self._presenter.texture is None:
            return
        tw, th = self._presenter.texture.size
        x, y, w, h = view
        s = min(w / tw, h / th)
        vw, vh = max(1, int(tw * s)), max(1, int(th * s))
        self.viewport = (x + (w - vw) // 2, y + (h - vh) // 2, vw, vh)
        self._presenter.present(framebuffer, self.viewport)

    def composed(self) -> np.ndarray | None:
        """The composed image as last presented (for tests and screenshots), or None."""
        if not self.has_image or self._job is None:
            return None
        images = self._images()
        first, second = self._job.pair
        return compose(images[first], images[second], self.settings)

    def release(self) -> None:
        """Stop the worker and free the GL objects."""
        self._cancel.set()
        self._pool.shutdown(wait=True, cancel_futures=True)
        for r in self._renderers.values():
            r.release()
        for f in self._refiners.values():
            f.release()
        if self._presenter is not None:
            self._presenter.release()
        self._renderers, self._refiners, self._presenter, self._uploaded, self._refined = {}, {}, None, {}, {}

