"""`PoseEngine`: evaluates the dynamics in a worker process so the UI never waits for them.

Why a process: moderngl holds the GIL during draw calls, and a dynamics thread in the viewer's process was
starved by it (design/MEASUREMENTS.md). The worker opens the avatar file itself (memory-mapped), computes
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

Every result says what it is: `PoseResult.preview` (an approximation: a preview, whose exact pose follows, or
a baked frame interpolated between stored ones), `.frame` and `.baked` for baked frames. Timings (ms):
"pose_total"; for exact poses "F", "G", "apply" (busy time per thread); for previews "probes" and
"spread_apply"; "peak_rss_mb" of the worker.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import queue
import signal
import time
import traceback
import weakref
from dataclasses import asdict, dataclass
from multiprocessing import shared_memory
from pathlib import Path

import numpy as np

from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.lifetime import shutdown_worker, start_parent_watch

N_SLOTS = 2
FREE, BUSY = 0, 1
MODES = ("auto", "exact", "preview")


@dataclass(frozen=True)
class Layout:
    """Where each posed array lives in a slot (float32 offsets in elements)."""

    n: int
    k: int
    h: int

    def shapes(self) -> dict[str, tuple[int, ...]]:
        s = {"means": (self.n, 3), "quats": (self.n, 4), "scales": (self.n, 3), "opacities": (self.n,),
             "sh": (self.n, self.k, 3)}
        if self.h:
            s["latent"] = (self.n, self.h)
        return s

    @property
    def floats(self) -> int:
        return sum(int(np.prod(s)) for s in self.shapes().values())

    def views(self, buf) -> dict[str, np.ndarray]:
        flat = np.ndarray((self.floats,), dtype=np.float32, buffer=buf)
        out, o = {}, 0
        for name, shape in self.shapes().items():
            size = int(np.prod(shape))
            out[name] = flat[o : o + size].reshape(shape)
            o += size
        return out


@dataclass
class EngineOptions:
    """How the worker computes (all have defaults that suit the viewer)."""

    device: str = "cpu"  # "cpu", "cuda", "mps" or "auto"; previews run only on the CPU path
    preview: bool = True  # answer slider moves with previews when exact poses are slow
    instant_ms: float = 50.0  # below this exact pose time, "auto" requests are answered exactly
    probes: int = 2048  # probe Gaussians of the preview (more, up to 4x, where blended networks reach few rows)
    neighbours: int = 8  # probes per Gaussian
    fit_codes: int = 8  # sampled codes the preview weights are fitted to (0: geometric weights only)
    cache_dir: str | None = None  # where preview models and bakes are cached (None: next to the avatar)
    write_cache: bool = True  # write the caches (reading them is always tried)
    first_layer: str = "auto"  # FastPoser first-layer mode
    cache_mb: float = 256.0  # first-layer cache limit for first_layer="auto"
    kernel: str = "auto"  # FastPoser kernel: "auto", "onednn" or "aten"
    precision: str = "fp32"  # FastPoser precision: "fp32", "bf16" or "auto" (the viewer and bench ask for auto)
    chunk: int | None = None  # rows per chunk (None: FastPoser's default for its kernel and device)
    # the exact refinement of a preview starts after this pause without a newer request: the window's image of
    # the preview gets the cores first, and a drag's next preview usually comes within it (#14, PERFORMANCE.md)
    refine_delay_ms: float = 120.0


@dataclass
class BakeStatus:
    """Progress of the current bake, as last reported by the worker."""

    frames: int
    stored: int = 0  # frames that will be stored (the others are interpolated)
    done: int = 0  # stored frames finished
    stride: int = 1
    megabytes: float = 0.0
    from_cache: bool = False
    cache_file: str | None = None
    finished: bool = False
    seconds: float = 0.0
    error: str | None = None

    @property
    def fraction(self) -> float:
        return self.done / max(1, self.stored)


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


@dataclass
class _BakeJob:
    store: object  # bake.BakeStore
    codes: np.ndarray
    status: BakeStatus
    started: float
    write: bool


def peak_rss_mb() -> float:
    """This process's peak resident memory in MB: Linux's VmHWM (of this address space only: `ru_maxrss` would
    include the parent's memory at fork time), else `ru_maxrss`."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    try:
        import resource  # POSIX only (absent on Windows)
    except ImportError:
        return 0.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _worker(path: str, layout: Layout, names: list[str], slot_state, req_q, res_q, threads: int,
            options: EngineOptions, parent_pid: int | None = None) -> None:
    if parent_pid is not None:
        start_parent_watch(parent_pid, names)
    with contextlib.suppress(ValueError, AttributeError):  # Ctrl+C in a terminal reaches the whole process
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # group: the parent decides when the worker stops
    shms = [shared_memory.SharedMemory(name=n) for n in names]
    try:
        _Worker(path, layout, [s.buf for s in shms], slot_state, req_q, res_q, threads, options).run()
    except Exception as e:  # report, never hang the viewer
        res_q.put(("error", -1, f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}", None))
    finally:
        for s in shms:
            s.close()


class _Worker:
    """The worker process's state and scheduling loop (see the module docstring)."""

    def __init__(self, path: str, layout: Layout, bufs: list, slot_state, req_q, res_q, threads: int,
                 options: EngineOptions):
        import torch

        from npga_core.files.loading import load_avatar
        from npga_core.posing.fastpose import FastPoser, resolve_device

        self.path, self.opts = path, options
        self.slot_state, self.req_q, self.res_q = slot_state, req_q, res_q
        self.views = [layout.views(b) for b in bufs]
        self.avatar = load_avatar(path)
        self.key = self.avatar.content_key()
        self.poser = None
        self.can_preview = False
        self.previewer = None
        self.fit = None
        self.job: _BakeJob | None = None
        self.exact_ms: float | None = None
        self.preview_ms: float | None = None
        self.want: tuple | None = None
        self.refine: tuple | None = None
        self._refine_at = 0.0  # when the refinement of the last preview may start (refine_delay_ms)
        self.status: dict = {}
        threads = max(1, threads)
        if not FastPoser.supported(self.avatar):
            torch.set_num_threads(threads)  # the generic path parallelises inside each operation
        else:
            # one chunk per thread at a time, each operation single-threaded: no barrier per operation, which
            # collapses when a core is shared with the renderer or another process (design/MEASUREMENTS.md)
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

    def _handle(self, msg) -> bool:
        """Take one message; False on the stop message."""
        if msg is None:
            return False
        kind = msg[0]
        if kind in ("pose", "frame"):
            self.want = msg
            self.refine = None
        elif kind == "bake":
            self.status["bake_id"] = msg[1]
            self._start_bake(*msg[2:])
        elif kind == "cancel_bake":
            if self.want is not None and self.want[0] == "frame" and self.job is not None:
                # a frame asked for before the cancel (same drain): answer it from the bake while there is one
                frame_msg, self.want = self.want, None
                self._answer_frame(frame_msg[1], frame_msg[2])
            self.job = None
            self._send_status(bake=None, bake_id=msg[1])
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

    def _send_status(self, **kw) -> None:
        self.status.update(kw)
        self.res_q.put(("status", 0, dict(self.status), None))

    # -- main loop -------------------------------------------------------------------------------------
    def run(self) -> None:
        self.res_q.put(("ready", 0, dict(self.status), None))
        while True:
            idle = self.want is None and self.refine is None and not self.baking and self.fit is None
            if not self._drain(block=idle):
                return
            if self.want is not None:
                msg, self.want = self.want, None
                if msg[0] == "frame":
                    self._answer_frame(msg[1], msg[2])
                else:
                    self._answer_pose(msg[1], msg[2], msg[3])
            elif self.refine is not None:
                pause = self._refine_at - time.perf_counter()
                if pause > 0:  # a newer request within the pause replaces the refinement
                    if not self._drain(block=True, timeout=pause):
                        return
                    continue
                req_id, z = self.refine
                if self._exact(req_id, z, cancellable=True):
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

    def _publish(self, req_id: int, slot: int, z: np.ndarray, timings: dict, **flags) -> None:
        timings["peak_rss_mb"] = peak_rss_mb()
        self.slot_state[slot] = BUSY
        self.res_q.put(("result", req_id, slot, (z, timings, flags)))

    def _answer_pose(self, req_id: int, z: np.ndarray, mode: str) -> None:
        try:
            z = self.avatar.check_code(z)
        except ValueError as e:
            self.res_q.put(("error", req_id, str(e), None))
            return
        pv = self.previewer
        if mode != "exact" and pv is not None and pv.ready and (mode == "preview" or self._preview_pays()):
            slot, timings = self._slot(), {}
            t0 = time.perf_counter()
            pv.pose_into(z, self.views[slot], timings)
            timings["pose_total"] = self.preview_ms = (time.perf_counter() - t0) * 1e3
            self._publish(req_id, slot, z, timings, preview=True)
            self.refine = (req_id, z)
            self._refine_at = time.perf_counter() + self.opts.refine_delay_ms / 1e3
        else:
            self._exact(req_id, z, cancellable=False)

    def _preview_pays(self) -> bool:
        """Previews answer "auto" requests while exact poses are slower than `instant_ms` and than 2 previews."""
        exact = float("inf") if self.exact_ms is None else self.exact_ms
        return exact > self.opts.instant_ms and (self.preview_ms is None or 2.0 * self.preview_ms < exact)

    def _exact(self, req_id: int, z: np.ndarray, cancellable: bool) -> bool:
        """Exact pose into a slot; with `cancellable`, give up (False) when another message arrives."""
        slot, timings = self._slot(), {}
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
                self.previewer.set_base(z, self.base)
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

        fit = self.fit
        if not fit.step(self._interrupted):
            self._send_status(preview_model=f"fitting {fit.done}/{fit.total}")
            return
        model, self.fit = fit.model, None
        model.key = self.key
        old, self.previewer = self.previewer, Previewer(self.poser, model)
        if old is not None and old.ready:
            self.previewer.set_base(old.base_code, old.base)
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
        job.status.done = int(job.store.done.sum())
        job.status.seconds = time.perf_counter() - job.started
        job.status.finished = job.store.complete
        self._send_status(bake=asdict(job.status))

    def _bake_step(self) -> None:
        job = self.job
        store = job.store
        if not store.complete:
            slot = int(np.flatnonzero(~store.done)[0])
            out = self.poser.offsets(job.codes[store.stored_frames[slot]], out=self.scratch, cancel=self._interrupted)
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
            self.res_q.put(("error", req_id, "no baked sequence (call bake first)", None))
            return
        store = job.store
        if not 0 <= frame < store.frames:
            self.res_q.put(("error", req_id, f"frame {frame} outside 0..{store.frames - 1}", None))
            return
        slot, timings = self._slot(), {}
        t0 = time.perf_counter()
        try:
            store.offsets_into(frame, self.scratch)
        except ValueError:  # not baked yet: pose it exactly
            self._exact(req_id, job.codes[frame], cancellable=False)
            return
        self.poser.apply_into(self.scratch, self.views[slot])
        timings["pose_total"] = (time.perf_counter() - t0) * 1e3
        self._publish(req_id, slot, job.codes[frame], timings, preview=not store.exact(frame), frame=frame,
                      baked=True)


class PoseEngine:
    """Asynchronous posing of one avatar file. Static avatars need no engine.

    Viewer API: `request(z, mode)` for slider codes ("auto": preview then exact) and live playback
    ("exact"); `bake(codes)` then `request_frame(i)` for baked playback; `poll()` every frame; results carry
    `preview`, `frame` and `baked`. `status` holds the worker's last report (preview model state, first-layer
    mode, device) and `bake_status` the bake's progress.
    """

    def __init__(self, path: str, n: int, sh_coeffs: int, latent_dim: int, threads: int = 2,
                 options: EngineOptions | None = None, **kw):
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
        self.worker_peak_rss_mb = 0.0
        self._proc = ctx.Process(target=_worker, daemon=True, name="npga-pose-worker",
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
        return self._send(("pose", None, np.asarray(z, np.float32).copy(), mode))

    def request_frame(self, frame: int) -> int:
        """Ask for frame `frame` of the baked sequence (exact if that frame is not baked yet)."""
        return self._send(("frame", None, int(frame)))

    def _send(self, msg: tuple) -> int:
        self._next_id += 1
        self.pending = self._next_id
        self.refining = False
        self._req.put((msg[0], self._next_id, *msg[2:]))
        return self._next_id

    def bake(self, codes: np.ndarray, budget_mb: float = 1024.0, cache: bool = True, bits: int = 8) -> None:
        """Bake a sequence's codes (T, D) in the background (progress in `bake_status`); a cache file next to
        the avatar is reused when the avatar content, the codes and the parameters are unchanged."""
        codes = np.asarray(codes, np.float32)
        self.bake_status = BakeStatus(len(codes))
        self._bake_id += 1
        self._req.put(("bake", self._bake_id, codes.copy(), float(budget_mb), bool(cache), int(bits)))

    def cancel_bake(self) -> None:
        self._bake_id += 1
        self._req.put(("cancel_bake", self._bake_id))
        self.bake_status = None

    # -- results ---------------------------------------------------------------------------------------
    def poll(self) -> PoseResult | None:
        """The newest finished result, if any (older finished ones are released); never blocks."""
        newest = None
        while True:
            try:
                kind, req_id, a, b = self._res.get_nowait()
            except queue.Empty:
                break
            if kind in ("ready", "status"):
                self.ready = True
                self.status.update(a)
                bake = a.get("bake", ...)
                # every status carries the worker's bake: take it only once the worker has seen the newest
                # bake or cancel request (an older status would bring back the previous bake)
                if bake is not ... and a.get("bake_id", 0) == self._bake_id:
                    self.bake_status = None if bake is None else BakeStatus(**bake)
            elif kind == "error":
                self.last_error = a
                if req_id == self.pending:
                    self.pending = None
            else:
                if newest is not None:
                    newest.release()
                z, timings, flags = b
                self.worker_peak_rss_mb = max(self.worker_peak_rss_mb, timings.get("peak_rss_mb", 0.0))
                posed = PosedGaussians(**self._views[a])
                newest = PoseResult(req_id, z, posed, timings, self, a, **flags)
                if req_id == self.pending:
                    self.pending = None
                    self.refining = newest.preview
                elif self.pending is None and req_id == self._next_id:
                    self.refining = newest.preview and self.refining
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
    def pid(self) -> int | None:
        """The worker's process id."""
        return self._proc.pid

    @property
    def shm_names(self) -> list[str]:
        """Names of the shared-memory slots (for leak checks)."""
        return [s.name for s in self._shms]

    def close(self) -> None:
        """Stop the worker and free the shared memory (idempotent)."""
        self._views = []
        self._finalizer()

    def __enter__(self) -> PoseEngine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

