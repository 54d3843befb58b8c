"""`PoseEngine`: evaluates the dynamics in a worker process so the UI never waits for them.

Why a process: moderngl holds the GIL during draw calls, and a dynamics thread in the viewer's process was
starved by it (measured when the engine was designed). The worker opens the avatar file itself (memory-mapped), computes
posed clouds, and writes them into one of two shared-memory slots; the viewer uploads from the slot and
releases it. Requests carry an id; the worker always takes the newest pending request and drops the rest,
so a fast slider never queues up work.

What the worker does, most urgent first:

1. the newest request: `request(z)` in mode "auto" answers at once with a *preview* (exact offsets of the
   last exact code plus probe deltas, `preview.py`) while exact poses take longer than
   `EngineOptions.instant_ms` and than two previews, else exactly; mode "exact" always answers exactly
   (live playback); `request_frame(i)` answers from the current bake;
2. the refinement of the last preview: the exact pose of the same code and request id, abandoned as soon as
   another message arrives (checked before every chunk and between F and G);
3. baking a sequence (`bake`), one stored frame per step, also abandoned and resumed around requests;
4. fitting the preview model (once per avatar content; cached next to the avatar).

An edited cloud is opened by the running worker (`reopen`: ~0.25 s for the demo instead of a new process's
~3-4 s of start); requests before it are dropped, as is the bake.

Every result says what it is: `PoseResult.preview` (an approximation: a preview, whose exact pose follows, or
a baked frame interpolated between stored ones), `.frame` and `.baked` for baked frames. Timings (ms):
"pose_total"; for exact poses "F", "G", "apply" (busy time per thread); for previews "probes" and
"spread_apply"; "peak_rss_mb" of the worker.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.process import BaseProcess
from typing import Any

import numpy as np

from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.lifetime import shutdown_in_background, shutdown_worker
from npga_core.posing.messages import (  # noqa: F401  (EngineOptions, BakeStatus, Layout, peak_rss_mb: public here)
    FREE,
    MODES,
    N_SLOTS,
    BakeRequest,
    BakeStatus,
    CancelBakeRequest,
    EngineOptions,
    ErrorReply,
    FrameRequest,
    Layout,
    PoseReply,
    PoseRequest,
    ReadyReply,
    ReopenRequest,
    StatusReply,
    peak_rss_mb,
)
from npga_core.posing.worker import worker_main


@dataclass
class PoseResult:
    """A posed cloud in a shared slot; call `release()` once it is uploaded."""

    request_id: int
    code: np.ndarray
    posed: PosedGaussians
    timings: dict[str, float]
    _engine: PoseEngine
    _slot: int
    preview: bool = False  # an approximation; the exact pose of the same request follows
    frame: int | None = None  # the sequence frame, for `request_frame` results
    baked: bool = False  # from the bake (quantised, or interpolated between stored frames when preview)

    def release(self) -> None:
        self._engine._release(self._slot)


class PoseEngine:
    """Asynchronous posing of one avatar file. Static avatars need no engine.

    Viewer API: `request(z, mode)` for slider codes ("auto": preview then exact) and live playback
    ("exact"); `bake(codes)` then `request_frame(i)` for baked playback; `poll()` every frame; results carry
    `preview`, `frame` and `baked`. `status` holds the worker's last report (preview model state, first-layer
    mode, device) and `bake_status` the bake's progress.
    """

    def __init__(self, path: str, n: int, sh_coeffs: int, latent_dim: int, threads: int = 2,
                 options: EngineOptions | None = None, **kw: Any) -> None:
        self.options = options or EngineOptions(**kw)
        self.layout = Layout(n, sh_coeffs, latent_dim)
        nbytes = max(4, self.layout.floats * 4)
        self._shms = [shared_memory.SharedMemory(create=True, size=nbytes) for _ in range(N_SLOTS)]
        self._views = [self.layout.views(s.buf) for s in self._shms]
        ctx = mp.get_context("spawn")
        self._slots = ctx.Array("i", [FREE] * N_SLOTS, lock=False)
        self._req: mp.Queue = ctx.Queue()
        self._res: mp.Queue = ctx.Queue()
        self._next_id = 0
        self.pending: int | None = None  # id of the newest request not answered yet
        self.refining = False  # the newest answer was a preview and its exact pose is still coming
        self.last_error: str | None = None
        self.status: dict = {}
        self.bake_status: BakeStatus | None = None
        self._bake_id = 0  # number of the newest bake or cancel request
        self._reopened = 0  # id of the newest `reopen`: answers to requests before it are dropped
        self.worker_peak_rss_mb = 0.0
        self._proc = ctx.Process(target=worker_main, daemon=True, name="npga-pose-worker",
                                 args=(path, self.layout, [s.name for s in self._shms], self._slots, self._req,
                                       self._res, threads, self.options, os.getpid()))
        # stops the worker and unlinks the slots when close() is called, the engine is dropped, or the
        # interpreter exits (SIGTERM/SIGINT handled by the CLI, exceptions); a killed parent is the worker's job
        self._finalizer = weakref.finalize(self, shutdown_worker, self._proc, self._req, self._shms)
        try:
            self._proc.start()
        except BaseException:
            self._finalizer()
            raise
        self.ready = False

    # -- requests --------------------------------------------------------------------------------------
    def request(self, z: np.ndarray, mode: str = "auto") -> int:
        """Ask for the cloud at code z; returns the request id. Older pending requests may be skipped.

        mode "auto": a preview first when exact poses are slow, then the exact pose of the same id;
        "exact": exact only (live playback); "preview": a preview whenever one is possible.
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        code = np.asarray(z, np.float32).copy()
        return self._send(lambda req_id: PoseRequest(req_id, code, mode))

    def request_frame(self, frame: int) -> int:
        """Ask for frame `frame` of the baked sequence (exact if that frame is not baked yet)."""
        return self._send(lambda req_id: FrameRequest(req_id, int(frame)))

    def _send(self, make: Callable[[int], PoseRequest | FrameRequest]) -> int:
        """Queue the request `make(new id)`; returns the id."""
        self._next_id += 1
        self.pending = self._next_id
        self.refining = False
        self._req.put(make(self._next_id))
        return self._next_id

    def bake(self, codes: np.ndarray, budget_mb: float = 1024.0, cache: bool = True, bits: int = 8) -> None:
        """Bake a sequence's codes (T, D) in the background (progress in `bake_status`); a cache file next to
        the avatar is reused when the avatar content, the codes and the parameters are unchanged."""
        codes = np.asarray(codes, np.float32)
        self.bake_status = BakeStatus(len(codes))
        self._bake_id += 1
        self._req.put(BakeRequest(self._bake_id, codes.copy(), float(budget_mb), bool(cache), int(bits)))

    def reopen(self, path: str, n: int, sh_coeffs: int, latent_dim: int) -> bool:
        """Have the running worker open `path` instead (an edited cloud of `n` Gaussians): no new process, the
        next poses are of the new file, earlier requests and the bake are dropped. False (nothing sent) when the
        worker is gone or the posed cloud would not fit the slots (then start a new engine)."""
        layout = Layout(n, sh_coeffs, latent_dim)
        if not self._proc.is_alive() or not self._views or layout.floats * 4 > min(s.size for s in self._shms):
            return False
        self._next_id += 1
        self._reopened = self._next_id
        self.layout = layout
        self._views = [layout.views(s.buf) for s in self._shms]
        self.pending, self.refining, self.ready = None, False, False
        self.bake_status = None
        self._req.put(ReopenRequest(self._reopened, str(path), layout))
        return True

    def cancel_bake(self) -> None:
        self._bake_id += 1
        self._req.put(CancelBakeRequest(self._bake_id))
        self.bake_status = None

    # -- results ---------------------------------------------------------------------------------------
    def poll(self) -> PoseResult | None:
        """The newest finished result, if any (older finished ones are released); never blocks."""
        newest = None
        while True:
            try:
                msg = self._res.get_nowait()
            except queue.Empty:
                break
            if isinstance(msg, ReadyReply | StatusReply):
                if msg.status.get("reopened", 0) < self._reopened:
                    continue  # the worker's state before the newest reopen
                self.ready = True
                if isinstance(msg, ReadyReply):
                    self.status = {}  # (a reopened worker starts its status afresh)
                self.status.update(msg.status)
                bake = msg.status.get("bake", ...)
                # every status carries the worker's bake: take it only once the worker has seen the newest
                # bake or cancel request (an older status would bring back the previous bake)
                if bake is not ... and msg.status.get("bake_id", 0) == self._bake_id:
                    self.bake_status = None if bake is None else BakeStatus(**bake)
            elif isinstance(msg, ErrorReply | PoseReply) and 0 < msg.req_id < self._reopened:
                if isinstance(msg, PoseReply):
                    self._release(msg.slot)  # a pose of the file before the newest reopen
            elif isinstance(msg, ErrorReply):
                self.last_error = msg.message
                if msg.req_id == self.pending:
                    self.pending = None
            elif isinstance(msg, PoseReply):
                if newest is not None:
                    newest.release()
                self.worker_peak_rss_mb = max(self.worker_peak_rss_mb, msg.timings.get("peak_rss_mb", 0.0))
                posed = PosedGaussians(**self._views[msg.slot])
                newest = PoseResult(msg.req_id, msg.code, posed, msg.timings, self, msg.slot, **msg.flags)
                if msg.req_id == self.pending:
                    self.pending = None
                    self.refining = newest.preview
                elif self.pending is None and msg.req_id == self._next_id:
                    self.refining = newest.preview and self.refining
            else:
                raise TypeError(f"the pose worker sent an unknown message {type(msg).__name__}")
        return newest

    def wait(self, timeout: float = 60.0, exact: bool = False) -> PoseResult | None:
        """Block until the newest request is answered (for scripts and tests); with `exact`, until its exact
        pose is in when the answer was a preview. Returns the newest result received meanwhile (None when
        nothing was outstanding, the request failed — see `last_error` — or the timeout passed)."""
        end = time.monotonic() + timeout
        result = None
        while True:
            r = self.poll()
            if r is not None:
                if result is not None:
                    result.release()
                result = r
            if self.pending is None and not (exact and self.refining):
                return result
            if not self._proc.is_alive():
                self.last_error = self.last_error or "pose worker exited"
                return result
            if time.monotonic() >= end:
                return result
            time.sleep(0.002)

    def wait_bake(self, timeout: float = 3600.0) -> BakeStatus | None:
        """Block until the bake finished or failed (for scripts and tests)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and self._proc.is_alive():
            r = self.poll()
            if r is not None:
                r.release()
            st = self.bake_status
            if st is not None and (st.finished or st.error):
                return st
            time.sleep(0.01)
        return self.bake_status

    def _release(self, slot: int) -> None:
        self._slots[slot] = FREE

    @property
    def alive(self) -> bool:
        return self._proc.is_alive()

    @property
    def process(self) -> BaseProcess:
        """The worker process; it outlives `close` as an object, so its end can be checked."""
        return self._proc

    @property
    def pid(self) -> int | None:
        """The worker's process id."""
        return self._proc.pid

    @property
    def shm_names(self) -> list[str]:
        """Names of the shared-memory slots (for leak checks)."""
        return [s.name for s in self._shms]

    def close(self, wait: bool = True) -> None:
        """Stop the worker and free the shared memory (idempotent); `wait=False`: in a background thread (a
        worker being replaced: the caller does not wait for its current job to end)."""
        self._views = []
        if wait:
            self._finalizer()
            return
        detached = self._finalizer.detach()
        if detached is not None:
            shutdown_in_background(*detached[2], self._res, self._slots)

    def __enter__(self) -> PoseEngine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

