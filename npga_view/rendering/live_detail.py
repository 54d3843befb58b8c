"""`LiveDetail`: the level-of-detail cloud the window draws its live images from, merged in a thread.

On llvmpipe an image costs about a microsecond of vertex work per splat at any resolution (the demo's 79k
Gaussians: ~70 ms even at 144x135), so live images (a drag, a slider, playback) cannot come faster than that
from the full cloud. While the view changes the `DrawScheduler` draws them from a merged cloud of at most
`clusters` Gaussians instead (`npga_core.model.lod`: moment matching over a fixed k-d grouping), with a
second renderer of the same path; once input stops the full-resolution image is drawn from every Gaussian.

Every cloud the window shows is `submit`ted with its content version (kept, not merged yet). The scheduler
asks for the merged cloud of a version with `request(version)`: it is uploaded if it has been merged, else its
merge is queued (a newer request replaces one not yet started) for a daemon thread that merges while the UI
goes on (numpy releases the GIL in the heavy parts). Until it is merged, a newer pose is shown by the last
merge moved along (`Merge.shifted`: every merged centre and base colour by its members' mean change, ~1 ms),
so a live image of a new pose (a stream's packet, a slider step) never waits for its merge. `pending(version)`
says that one is on its way, so the scheduler can wait a moment for it instead of drawing the full cloud
(before the first merge), and `uploaded_version` which merged pose the renderer holds (playback draws the
newest one when poses come faster than merges). An orbit needs one merge for all its images.
Clouds of fewer than `min_count` Gaussians are drawn in full (a merge would save little), as are inspection
styles that draw every Gaussian ("points", "ellipsoids") and views with line overlays.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from npga_core.model.gaussians import PosedGaussians
from npga_core.model.lod import CLUSTERS, LevelOfDetail, Merge
from npga_view.rendering.renderer import SplatRenderer

#: after a merge of M ms the next one starts no sooner than REST x M ms later: while poses change continuously
#: (playback, a stream) merges took 0.35 of the 2 cores of the machine that draws the images
REST = 2.0


class LiveDetail:
    """See the module docstring. `make_renderer()` creates the second renderer (on first use, in the UI thread);
    `full` is the window's renderer, whose style and overlays decide whether a merged cloud may stand in."""

    def __init__(self, make_renderer: Callable[[], SplatRenderer], full: SplatRenderer, clusters: int = CLUSTERS,
                 min_count: int | None = None, enabled: bool = True) -> None:
        self._make_renderer = make_renderer
        self.full = full
        self.clusters = clusters
        self.min_count = 2 * clusters if min_count is None else min_count
        self.enabled = enabled
        self.renderer: SplatRenderer | None = None
        self._cond = threading.Condition()
        self._latest: tuple[int, PosedGaussians] | None = None  # the newest cloud shown
        self._request: tuple[int, PosedGaussians] | None = None  # the cloud to merge next
        self._working = -1  # version being merged
        self._done: tuple[int, Merge] | None = None  # newest merge, not uploaded yet
        self._base: Merge | None = None  # the newest merge taken (what newer poses are shifted from)
        self._uploaded = -1  # version in the renderer
        self.shifted = False  # the renderer holds `Merge.shifted` of that version, not its merge
        self._grouping: LevelOfDetail | None = None
        self._generation = 0  # bumped by `reset`: a merge started before is thrown away
        self._rest_until = 0.0  # the next merge starts no sooner (perf_counter)
        self._stop = False
        self._thread: threading.Thread | None = None
        self.merge_ms = 0.0  # the last merge (grouping included when it was built for it)
        self.error: str | None = None  # why the last merge failed, if it did

    # ------------------------------------------------------------------------------------------ input
    def submit(self, version: int, posed: PosedGaussians) -> None:
        """The window shows `posed` as content `version` (merged when `request`ed)."""
        self._latest = (version, posed) if len(posed) >= self.min_count else None

    def reset(self) -> None:
        """The avatar changed: group its Gaussians anew with the next cloud."""
        with self._cond:
            self._grouping = None
            self._request = self._done = self._latest = self._base = None
            self._uploaded = -1
            self.shifted = False
            self._generation += 1
            self._rest_until = 0.0

    # ----------------------------------------------------------------------------------------- output
    def usable(self) -> bool:
        """A merged cloud may stand in for the full one now (on, and the full renderer draws plain splats)."""
        return self.enabled and self.full.style == "splats" and not self.full.line_count

    def pending(self, version: int) -> bool:
        """A merge of `version` is queued or running."""
        with self._cond:
            return self._working == version or (self._request is not None and self._request[0] == version)

    def request(self, version: int) -> SplatRenderer | None:
        """The renderer holding the merged cloud of `version` (uploaded now if it has just been merged), or None;
        then its merge is started unless it is on its way (or `version` is not the newest cloud submitted)."""
        if not self.usable():
            return None
        with self._cond:
            done, self._done = self._done, None
            latest = self._latest
            started = {self._working, done[0] if done is not None else -1,
                       self._request[0] if self._request is not None else -1}
            if not self.shifted:
                started.add(self._uploaded)
            if latest is not None and latest[0] == version and version not in started:
                self._request = latest
                self._cond.notify()
        if done is not None:
            self._base = done[1]
            if done[0] >= self._uploaded:  # (not over a shift of a newer pose)
                self._upload(done[0], done[1].cloud, shifted=False)
        base = self._base
        if self._uploaded != version and latest is not None and latest[0] == version and base is not None \
                and len(latest[1]) == len(base.source_means):
            self._upload(version, base.shifted(latest[1].means, latest[1].sh), shifted=True)
        if self._request is not None and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="npga-live-detail", daemon=True)
            self._thread.start()
        return self.renderer if self._uploaded == version and self.renderer is not None else None

    def _upload(self, version: int, cloud: PosedGaussians, shifted: bool) -> None:
        if self.renderer is None:
            self.renderer = self._make_renderer()
        self.renderer.set_gaussians(cloud)
        self._uploaded, self.shifted = version, shifted

    @property
    def uploaded_version(self) -> int:
        """Content version of the merged cloud in the renderer (-1 if none); `request` uploads new ones."""
        return self._uploaded if self.renderer is not None else -1

    @property
    def count(self) -> int:
        """Gaussians in the uploaded merged cloud (0 before the first)."""
        return 0 if self.renderer is None else self.renderer.count

    def close(self) -> None:
        """Stop the thread and free the renderer (call with the window's context current)."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.renderer is not None:
            self.renderer.release()
            self.renderer = None

    # ----------------------------------------------------------------------------------------- thread
    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and (self._request is None or time.perf_counter() < self._rest_until):
                    self._cond.wait(None if self._request is None else self._rest_until - time.perf_counter())
                if self._stop:
                    return
                request = self._request
                assert request is not None
                (version, posed), self._request = request, None
                self._working = version
                grouping, generation = self._grouping, self._generation
            t0 = time.perf_counter()
            try:
                if grouping is None or grouping.count != len(posed):
                    grouping = LevelOfDetail(posed.means, self.clusters)
                merged = grouping.merge_keeping(posed)
            except Exception as e:  # noqa: BLE001 (a thread that died would leave the view waiting for it)
                with self._cond:
                    self.error, self._working = f"level of detail: {e}", -1
                continue
            with self._cond:
                self._working = -1
                if generation != self._generation:
                    continue
                self.merge_ms = (time.perf_counter() - t0) * 1e3
                # the next merge waits REST times as long (poses shown meanwhile are this one shifted)
                self._rest_until = time.perf_counter() + REST * self.merge_ms / 1e3
                self._grouping = grouping
                self._done = (version, merged)
