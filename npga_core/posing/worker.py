"""The pose worker process (started by `PoseEngine`, npga_core/posing/engine.py): what it does, most urgent
first, is in engine.py's docstring; the messages it takes and sends are in messages.py."""

from __future__ import annotations

import contextlib
import queue
import signal
import time
import traceback
from collections.abc import MutableSequence
from dataclasses import asdict, dataclass
from multiprocessing import shared_memory
from multiprocessing.queues import Queue
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from npga_core.posing.lifetime import start_parent_watch
from npga_core.posing.messages import (
    BUSY,
    FREE,
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

if TYPE_CHECKING:
    import torch

    from npga_core.posing.bake import BakeStore
    from npga_core.posing.fastpose import FastPoser
    from npga_core.posing.preview import Previewer, PreviewFit


@dataclass
class _BakeJob:
    store: BakeStore
    codes: np.ndarray
    status: BakeStatus
    started: float
    write: bool


def worker_main(path: str, layout: Layout, names: list[str], slot_state: MutableSequence[int], req_q: Queue[Any],
                res_q: Queue[Any], threads: int,
                options: EngineOptions, parent_pid: int | None = None) -> None:
    """The worker process's entry (the `Process` target of `PoseEngine`): open the avatar at `path`, attach the
    shared-memory slots `names`, answer `req_q`'s requests on `res_q` until told to stop or the parent dies."""
    if parent_pid is not None:
        start_parent_watch(parent_pid, names)
    with contextlib.suppress(ValueError, AttributeError):  # Ctrl+C in a terminal reaches the whole process
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # group: the parent decides when the worker stops
    shms = [shared_memory.SharedMemory(name=n) for n in names]
    try:
        _Worker(path, layout, [s.buf for s in shms], slot_state, req_q, res_q, threads, options).run()
    except Exception as e:  # report, never hang the viewer
        res_q.put(ErrorReply(-1, f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"))
    finally:
        for s in shms:
            s.close()


class _Worker:
    """The worker process's state and scheduling loop (see the module docstring)."""

    def __init__(self, path: str, layout: Layout, bufs: list, slot_state: MutableSequence[int], req_q: Queue[Any],
                 res_q: Queue[Any], threads: int,
                 options: EngineOptions):
        self.opts, self.threads, self.bufs = options, max(1, threads), bufs
        self.slot_state, self.req_q, self.res_q = slot_state, req_q, res_q
        self.status: dict = {}
        self._open(path, layout)

    def _open(self, path: str, layout: Layout) -> None:
        """Open the avatar at `path` with posed clouds of `layout` in the slots; everything of the avatar before
        (pending requests, refinement, bake, preview model and its fit) is dropped."""
        import torch

        from npga_core.files.loading import load_avatar
        from npga_core.posing.device import resolve_device
        from npga_core.posing.fastpose import FastPoser

        options, threads = self.opts, self.threads
        self.path = path
        self.views = [layout.views(b) for b in self.bufs]
        self.poser: FastPoser | None = None  # (the last avatar's poser and tensors freed before the next loads)
        self.previewer: Previewer | None = None
        self.fit: PreviewFit | None = None
        self.job: _BakeJob | None = None
        for name in ("base", "scratch", "avatar"):
            self.__dict__.pop(name, None)
        self.can_preview = False
        self.exact_ms: float | None = None
        self.preview_ms: float | None = None
        self.want: PoseRequest | FrameRequest | None = None  # the newest pose or frame request, not answered yet
        self.refine: PoseRequest | None = None  # the preview answered last, whose exact pose is still to come
        self._refine_at = 0.0  # when the refinement of the last preview may start (refine_delay_ms)
        # a reopened worker's status: the bake it had is gone (said for the newest bake request it saw)
        self.status = {k: self.status[k] for k in ("bake_id", "reopened") if k in self.status}
        if "bake_id" in self.status:
            self.status["bake"] = None
        self.avatar = load_avatar(path)
        self.key = self.avatar.content_key()
        if not FastPoser.supported(self.avatar):
            torch.set_num_threads(threads)  # the generic path parallelises inside each operation
        else:
            # one chunk per thread at a time, each operation single-threaded: no barrier per operation, which
            # collapses when a core is shared with the renderer or another process (docs/PERFORMANCE.md)
            torch.set_num_threads(1)
            device = resolve_device(options.device)
            self.poser = FastPoser(self.avatar, chunk=options.chunk, device=device, first_layer=options.first_layer,
                                   cache_mb=options.cache_mb, threads=threads, kernel=options.kernel,
                                   precision=options.precision)
            width = self.poser.layout.width
            self.base = torch.empty(self.poser.n, width)  # exact offsets of the last exact pose
            self.scratch = torch.empty(self.poser.n, width)
            self.status["first_layer"] = self.poser.first_layer
            self.status["device"] = str(device)
            self.status["kernel"] = self.poser.kernel
            self.status["precision"] = self.poser.precision
            self.can_preview = options.preview and device.type == "cpu" and self.avatar.code_dim > 0
        self.status["preview_model"] = "pending" if self.can_preview else "off"

    # -- messages --------------------------------------------------------------------------------------
    def _interrupted(self) -> bool:
        return not self.req_q.empty()

    def _handle(self, msg: object) -> bool:
        """Take one message; False on the stop message."""
        if msg is None:
            return False
        if isinstance(msg, PoseRequest | FrameRequest):
            self.want = msg
            self.refine = None
        elif isinstance(msg, ReopenRequest):
            self._open(msg.path, msg.layout)
            self.status["reopened"] = msg.req_id
            self.res_q.put(ReadyReply(dict(self.status)))
        elif isinstance(msg, BakeRequest):
            self.status["bake_id"] = msg.bake_id
            self._start_bake(msg.codes, msg.budget_mb, msg.use_cache, msg.bits)
        elif isinstance(msg, CancelBakeRequest):
            if isinstance(self.want, FrameRequest) and self.job is not None:
                # a frame asked for before the cancel (same drain): answer it from the bake while there is one
                frame_msg, self.want = self.want, None
                self._answer_frame(frame_msg.req_id, frame_msg.frame)
            self.job = None
            self._send_status(bake=None, bake_id=msg.bake_id)
        else:
            raise TypeError(f"the pose worker got an unknown message {type(msg).__name__}")
        return True

    def _drain(self, block: bool, timeout: float = 0.5) -> bool:
        try:
            msg = self.req_q.get(timeout=timeout) if block else self.req_q.get_nowait()
        except queue.Empty:
            return True
        if not self._handle(msg):
            return False
        while True:
            try:
                msg = self.req_q.get_nowait()
            except queue.Empty:
                return True
            if not self._handle(msg):
                return False

    def _send_status(self, **kw: object) -> None:
        self.status.update(kw)
        self.res_q.put(StatusReply(dict(self.status)))

    # -- main loop -------------------------------------------------------------------------------------
    def run(self) -> None:
        self.res_q.put(ReadyReply(dict(self.status)))
        while True:
            idle = self.want is None and self.refine is None and not self.baking and self.fit is None
            if not self._drain(block=idle):
                return
            if self.want is not None:
                msg, self.want = self.want, None
                if isinstance(msg, FrameRequest):
                    self._answer_frame(msg.req_id, msg.frame)
                else:
                    self._answer_pose(msg.req_id, msg.code, msg.mode)
            elif self.refine is not None:
                pause = self._refine_at - time.perf_counter()
                if pause > 0:  # a newer request within the pause replaces the refinement
                    if not self._drain(block=True, timeout=pause):
                        return
                    continue
                if self._exact(self.refine.req_id, self.refine.code, cancellable=True):
                    self.refine = None
            elif self.baking:
                self._bake_step()
            elif self.fit is not None:
                self._fit_step()

    def _slot(self) -> int:
        while True:
            for i in range(N_SLOTS):
                if self.slot_state[i] == FREE:
                    return i
            time.sleep(0.001)

    def _publish(self, req_id: int, slot: int, z: np.ndarray, timings: dict, **flags: object) -> None:
        timings["peak_rss_mb"] = peak_rss_mb()
        self.slot_state[slot] = BUSY
        self.res_q.put(PoseReply(req_id, slot, z, timings, flags))

    def _answer_pose(self, req_id: int, z: np.ndarray, mode: str) -> None:
        try:
            z = self.avatar.check_code(z)
        except ValueError as e:
            self.res_q.put(ErrorReply(req_id, str(e)))
            return
        pv = self.previewer
        if mode != "exact" and pv is not None and pv.ready and (mode == "preview" or self._preview_pays()):
            slot, timings = self._slot(), cast(dict[str, float], {})
            t0 = time.perf_counter()
            pv.pose_into(z, self.views[slot], timings)
            timings["pose_total"] = self.preview_ms = (time.perf_counter() - t0) * 1e3
            self._publish(req_id, slot, z, timings, preview=True)
            self.refine = PoseRequest(req_id, z, mode)
            self._refine_at = time.perf_counter() + self.opts.refine_delay_ms / 1e3
        else:
            self._exact(req_id, z, cancellable=False)

    def _preview_pays(self) -> bool:
        """Previews answer "auto" requests while exact poses are slower than `instant_ms` and than 2 previews."""
        exact = float("inf") if self.exact_ms is None else self.exact_ms
        return exact > self.opts.instant_ms and (self.preview_ms is None or 2.0 * self.preview_ms < exact)

    def _exact(self, req_id: int, z: np.ndarray, cancellable: bool) -> bool:
        """Exact pose into a slot; with `cancellable`, give up (False) when another message arrives."""
        slot, timings = self._slot(), cast(dict[str, float], {})
        t0 = time.perf_counter()
        if self.poser is None:
            posed = self.avatar.pose(z, timings=timings)
            for name, v in self.views[slot].items():
                np.copyto(v, getattr(posed, name))
        else:
            cancel = self._interrupted if cancellable else None
            if not self.poser.pose_into(z, self.views[slot], self.scratch, cancel, timings):
                return False
            self.base, self.scratch = self.scratch, self.base
            if self.previewer is not None:
                self.previewer.set_base(z, self.base)
        timings["pose_total"] = (time.perf_counter() - t0) * 1e3
        self.exact_ms = timings["pose_total"]
        self._publish(req_id, slot, z, timings, preview=False)
        if self.can_preview and self.previewer is None:
            if self.exact_ms > self.opts.instant_ms:
                self._start_preview()
                cast("Previewer", self.previewer).set_base(z, self.base)
            elif self.status["preview_model"] == "pending":
                self._send_status(preview_model="idle")  # exact poses are fast enough for now
        return True

    # -- preview model ---------------------------------------------------------------------------------
    @property
    def _probes(self) -> int:
        """Probe count: the option, times up to 4 where blended networks reach only part of the rows, so the
        probes cost what `probes` probes cost with every network on every row (a probe runs only the networks
        that reach it)."""
        reach = self.poser.reach if self.poser is not None else 1.0
        return int(round(self.opts.probes * min(4.0, 1.0 / max(reach, 1e-6)) / 256)) * 256 or self.opts.probes

    def _preview_path(self) -> Path:
        from npga_core.posing.preview import preview_cache_path

        o = self.opts
        return preview_cache_path(self.path, self.key, self._probes, o.neighbours, o.fit_codes, o.cache_dir)

    def _start_preview(self) -> None:
        """Previews from the cached fitted model, else from geometric weights while the fit runs."""
        from npga_core.posing.preview import Previewer, PreviewFit, PreviewModel

        o, poser = self.opts, self.poser
        assert poser is not None
        model = PreviewModel.load(self._preview_path(), self.key, poser.n) if o.fit_codes else None
        if model is not None:
            self.status["preview_model"] = "cached"
        else:
            model = PreviewModel.geometric(self.avatar.cloud.means, self._probes, o.neighbours)
            self.status["preview_model"] = "geometric"
            if o.fit_codes:
                codes = PreviewModel.sample_codes(self.avatar, o.fit_codes)
                self.fit = PreviewFit(poser, codes, self.avatar.neutral_code(), self._probes, o.neighbours)
        self.previewer = Previewer(poser, model)
        self._send_status(preview_precision=self.previewer.precision)

    def _fit_step(self) -> None:
        from npga_core.posing.preview import Previewer

        fit, poser = self.fit, self.poser
        assert fit is not None and poser is not None
        if not fit.step(self._interrupted):
            self._send_status(preview_model=f"fitting {fit.done}/{fit.total}")
            return
        model, self.fit = fit.model, None
        assert model is not None  # the fit finished
        model.key = self.key
        old, self.previewer = self.previewer, Previewer(poser, model)
        if old is not None and old.ready:
            self.previewer.set_base(cast(np.ndarray, old.base_code), cast("torch.Tensor", old.base))
        state = "fitted"
        if self.opts.write_cache:
            try:
                model.save(self._preview_path())
            except OSError as e:
                state = f"fitted (cache not written: {e.strerror or e})"
        self._send_status(preview_model=state)

    # -- bake ------------------------------------------------------------------------------------------
    def _start_bake(self, codes: np.ndarray, budget_mb: float, use_cache: bool, bits: int) -> None:
        from npga_core.posing.bake import BakeStore, bake_key, cache_path

        t0 = time.perf_counter()
        codes = np.asarray(codes, np.float32)
        self.job = None
        try:
            if self.poser is None:
                raise ValueError("baking needs the fast path (networks without skip layers)")
            if codes.ndim != 2 or codes.shape[1] != self.avatar.code_dim or not len(codes):
                raise ValueError(f"bake codes must be (T, {self.avatar.code_dim}), got {codes.shape}")
            budget = int(budget_mb * 2**20)
            key = bake_key(self.key, codes, bits, budget)
            path = cache_path(self.path, key, self.opts.cache_dir) if use_cache else None
            store = BakeStore.open(path, key, self.poser.n, self.poser.layout.width) if path is not None else None
            if store is not None and store.frames != len(codes):
                store = None
            status = BakeStatus(len(codes), cache_file=str(path) if path else None, from_cache=store is not None)
            if store is None:
                store = BakeStore.create(key, len(codes), self.poser.n, self.poser.layout.width, bits, budget)
        except (ValueError, MemoryError) as e:
            self._send_status(bake=asdict(BakeStatus(len(codes), error=str(e))))
            return
        status.stored, status.stride, status.megabytes = len(store.done), store.stride, store.nbytes / 2**20
        self.job = _BakeJob(store, codes, status, t0, use_cache and self.opts.write_cache and not status.from_cache)
        self._bake_report()

    @property
    def baking(self) -> bool:
        return self.job is not None and not self.job.status.finished

    def _bake_report(self) -> None:
        job = self.job
        assert job is not None
        job.status.done = int(job.store.done.sum())
        job.status.seconds = time.perf_counter() - job.started
        job.status.finished = job.store.complete
        self._send_status(bake=asdict(job.status))

    def _bake_step(self) -> None:
        job, poser = self.job, self.poser
        assert job is not None and poser is not None
        store = job.store
        if not store.complete:
            slot = int(np.flatnonzero(~store.done)[0])
            out = poser.offsets(job.codes[store.stored_frames[slot]], out=self.scratch, cancel=self._interrupted)
            if out is None:
                return
            store.put(slot, out)
        if store.complete and job.write and job.status.cache_file:
            try:
                store.save(job.status.cache_file)
            except OSError as e:
                job.status.error = f"cache not written: {e.strerror or e}"
        self._bake_report()

    def _answer_frame(self, req_id: int, frame: int) -> None:
        job = self.job
        if job is None:
            self.res_q.put(ErrorReply(req_id, "no baked sequence (call bake first)"))
            return
        store = job.store
        if not 0 <= frame < store.frames:
            self.res_q.put(ErrorReply(req_id, f"frame {frame} outside 0..{store.frames - 1}"))
            return
        slot, timings = self._slot(), cast(dict[str, float], {})
        t0 = time.perf_counter()
        try:
            store.offsets_into(frame, self.scratch)
        except ValueError:  # not baked yet: pose it exactly
            self._exact(req_id, job.codes[frame], cancellable=False)
            return
        cast("FastPoser", self.poser).apply_into(self.scratch, self.views[slot])
        timings["pose_total"] = (time.perf_counter() - t0) * 1e3
        self._publish(req_id, slot, job.codes[frame], timings, preview=not store.exact(frame), frame=frame,
                      baked=True)

