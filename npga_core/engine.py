"""`PoseEngine`: evaluates the dynamics in a worker process so the UI never waits for them.

Why a process: moderngl holds the GIL during draw calls, and a dynamics thread in the viewer's process was
starved by it (design/MEASUREMENTS.md). The worker opens the avatar file itself (memory-mapped), computes
posed clouds, and writes them into one of two shared-memory slots; the viewer uploads from the slot and
releases it. Requests carry an id; the worker always takes the newest pending request and drops the rest,
so a fast slider never queues up work.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import queue
import time
import traceback
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from .gaussians import PosedGaussians

N_SLOTS = 2
FREE, BUSY = 0, 1


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
class PoseResult:
    """A posed cloud in a shared slot; call `release()` once it is uploaded."""

    request_id: int
    code: np.ndarray
    posed: PosedGaussians
    timings: dict[str, float]
    _engine: PoseEngine
    _slot: int

    def release(self) -> None:
        self._engine._release(self._slot)


def _worker(path: str, layout: Layout, names: list[str], slot_state, req_q, res_q, threads: int) -> None:
    import torch

    from .avatar import load_avatar

    torch.set_num_threads(max(1, threads))
    shms = [shared_memory.SharedMemory(name=n) for n in names]
    try:
        avatar = load_avatar(path)
        views = [layout.views(s.buf) for s in shms]
        res_q.put(("ready", 0, None, None))
        while True:
            msg = req_q.get()
            while True:  # newest request wins
                try:
                    msg = req_q.get_nowait()
                except queue.Empty:
                    break
            if msg is None:
                return
            req_id, z = msg
            slot = None
            while slot is None:
                for i in range(N_SLOTS):
                    if slot_state[i] == FREE:
                        slot = i
                        break
                else:
                    time.sleep(0.001)
            t0 = time.perf_counter()
            timings: dict[str, float] = {}
            try:
                posed = avatar.pose(z, timings=timings)
            except ValueError as e:
                res_q.put(("error", req_id, str(e), None))
                continue
            v = views[slot]
            for name in v:
                np.copyto(v[name], getattr(posed, name))
            timings["pose_total"] = (time.perf_counter() - t0) * 1000.0
            slot_state[slot] = BUSY
            res_q.put(("result", req_id, slot, (z, timings)))
    except Exception as e:  # report, never hang the viewer
        res_q.put(("error", -1, f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}", None))
    finally:
        for s in shms:
            s.close()


class PoseEngine:
    """Asynchronous posing of one avatar file. Static avatars need no engine."""

    def __init__(self, path: str, n: int, sh_coeffs: int, latent_dim: int, threads: int = 2):
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
        self.last_error: str | None = None
        self._proc = ctx.Process(target=_worker, daemon=True, name="npga-pose-worker",
                                 args=(path, self.layout, [s.name for s in self._shms], self._slots, self._req,
                                       self._res, threads))
        self._proc.start()
        self.ready = False

    def request(self, z: np.ndarray) -> int:
        """Ask for the cloud at code z; returns the request id. Older pending requests may be skipped."""
        self._next_id += 1
        self.pending = self._next_id
        self._req.put((self._next_id, np.asarray(z, np.float32).copy()))
        return self._next_id

    def poll(self) -> PoseResult | None:
        """The newest finished result, if any (older finished ones are released); never blocks."""
        newest = None
        while True:
            try:
                kind, req_id, a, b = self._res.get_nowait()
            except queue.Empty:
                break
            if kind == "ready":
                self.ready = True
            elif kind == "error":
                self.last_error = a
                if req_id == self.pending:
                    self.pending = None
            else:
                if newest is not None:
                    newest.release()
                z, timings = b
                posed = PosedGaussians(**self._views[a])
                newest = PoseResult(req_id, z, posed, timings, self, a)
                if req_id == self.pending:
                    self.pending = None
        return newest

    def wait(self, timeout: float = 60.0) -> PoseResult | None:
        """Block until the newest pending request is answered (for scripts and tests)."""
        end = time.monotonic() + timeout
        result = None
        while time.monotonic() < end:
            r = self.poll()
            if r is not None:
                if result is not None:
                    result.release()
                result = r
            if self.pending is None and result is not None:
                return result
            if self.pending is None and self.last_error:
                return None
            if not self._proc.is_alive():
                self.last_error = self.last_error or "pose worker exited"
                return result
            time.sleep(0.002)
        return result

    def _release(self, slot: int) -> None:
        self._slots[slot] = FREE

    @property
    def alive(self) -> bool:
        return self._proc.is_alive()

    def close(self) -> None:
        """Stop the worker and free the shared memory."""
        if self._proc.is_alive():
            self._req.put(None)
            self._proc.join(timeout=5)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(timeout=5)
        for s in self._shms:
            s.close()
            with contextlib.suppress(FileNotFoundError):
                s.unlink()
        self._views = []

    def __enter__(self) -> PoseEngine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
