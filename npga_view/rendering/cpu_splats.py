"""The "splats" colour pass on the CPU, where the OpenGL is a software renderer (Mesa's llvmpipe).

llvmpipe draws a splat as a generic GL primitive: it rasterises the square around the ellipse in 4x4 blocks and runs
the compiled fragment program on each (the demo at 1360x900: 38 M pixels of points for 17.7 M inside the ellipses;
docs/PERFORMANCE.md). Here the same splats (the GL pre-pass's output, read back) are binned into 64-pixel tiles in
draw order and each tile is blended by one thread on the CPU over exactly its ellipses' row spans, with the Gaussian
as a vectorised polynomial (`cpu_kernels.py`, numba). The image equals the GL pass's within the 16-bit target's
rounding and is written into the renderer's colour target, so everything after it (present, read-back, the CNN,
lines) is unchanged. A GPU's GL is left to draw: this module is used only on a software GL.

The kernels are compiled once per machine into numba's cache by a helper process, started when a renderer has
finished its first image (`warm_up`, so after the window's first pixels): compiling takes seconds of Python work,
which would stall the window's frames. Until the kernels are loaded, images are drawn by GL; a process that finds
the cache loads them in ~0.3 s.
"""

from __future__ import annotations

import atexit
import math
import multiprocessing as mp
import os
import threading
import time

import moderngl
import numpy as np

#: Parallel chunks per numba thread (tiles are interleaved over chunks, so uneven tiles balance)
CHUNKS_PER_THREAD = 4
#: ms per unit of predicted work (a pixel of a splat's ellipse) before the first image measures it
PRIOR_MS_PER_WORK = 8e-6
#: batches shorter than this (ms) do not move the measured rate: their time is mostly waking the threads (or a
#: preempted thread), and a 1-tile batch of 11 ms once raised the rate 500-fold, so that the next images of the
#: merged live cloud were drawn a few tiles per UI frame (110-150 ms per image where 30 ms of work was left)
RATE_MIN_MS = 2.0
#: the measured rate moves by at most these factors per batch
RATE_STEP = (0.5, 2.0)
#: GL_RENDERER names of software OpenGL implementations
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "swiftshader", "software rasterizer")
#: NPGA_CPU_SPLATS=0 keeps the GL colour pass on a software GL; 1 uses the CPU pass on any GL
ENV = "NPGA_CPU_SPLATS"

_lock = threading.Lock()  # one caller of the parallel kernels at a time (numba's thread pools are per process)
_state = {"status": "off", "error": ""}  # off, warming, loading, ready, failed
_kernels = None
_starting = threading.Lock()  # held while the helper process is started (`_stop_helper` waits for it)
_helper: mp.process.BaseProcess | None = None  # the compiling helper process, once started
_exiting = False  # set at exit: no helper is started after


def wanted(renderer_name: str) -> bool:
    """Whether a renderer on GL `renderer_name` should draw its colour pass on the CPU ($NPGA_CPU_SPLATS wins)."""
    env = os.environ.get(ENV, "").strip()
    if env in ("0", "1"):
        return env == "1"
    name = renderer_name.lower()
    return any(s in name for s in SOFTWARE_GL)


def _compile_in_child(parent_pid: int) -> None:
    """Helper process: compile the kernels into numba's cache (or find them there), then exit."""
    from npga_core.posing.lifetime import start_parent_watch

    start_parent_watch(parent_pid, [])
    _load()


def _load():
    """Import and run the kernels once on a tiny image (compiling them, or loading numba's cache)."""
    from npga_view.rendering import cpu_kernels as k

    sp = np.zeros((1, 16), np.float32)
    sp[0, [0, 1, 3, 8, 10]] = 1.0, 1.0, 0.5, 1.0, 1.0
    planes = np.zeros((4, 2, 2), np.float32)
    order = np.zeros(1, np.uint32)
    starts, lists, _ = k.bin_tiles(order, k.pixel_boxes(order, sp, 2, 2), 2, 2)
    k.draw_tiles(np.zeros(1, np.int32), 1, starts, lists, sp, planes, np.zeros(4, np.float32))
    k.pack_unorm16(planes, np.zeros((2, 2, 4), np.uint16), 0.5)
    k.pack_float(planes, np.zeros((2, 2, 4), np.float32), 1.0)
    return k


def _load_here() -> None:
    """Load the kernels into this process (from numba's cache, or compiling them) and set the state."""
    global _kernels
    _state["status"] = "loading"
    try:
        with _lock:
            _kernels = _load()
        _state["status"] = "ready"
    except Exception as e:  # numba missing or refusing this machine: the GL pass stays
        _state.update(status="failed", error=f"{type(e).__name__}: {e}")


def _warm() -> None:
    """Thread: compile in a helper process (this process's frames go on meanwhile), then load the cache here."""
    global _helper
    try:
        with _starting:
            if _exiting:
                return
            proc = mp.get_context("spawn").Process(target=_compile_in_child, args=(os.getpid(),), daemon=True,
                                                   name="npga-cpu-splats-compile")
            proc.start()
            _helper = proc
        proc.join()
    except Exception as e:
        _state.update(status="failed", error=f"{type(e).__name__}: {e}")
        return
    _load_here()


@atexit.register
def _stop_helper() -> None:
    """At exit: no helper is started any more, one being started is started first (a process that exits while a
    thread starts one leaves the child reading its start data from a closed pipe: a traceback on stderr, seen after
    a one-image `npga-view render`), then ended."""
    global _exiting
    acquired = _starting.acquire(timeout=5.0)
    _exiting = True
    proc = _helper
    if acquired:
        _starting.release()
    if proc is not None and proc.is_alive():
        proc.terminate()
        proc.join(timeout=2.0)


def warm_up(wait: bool = False) -> bool:
    """Start compiling (first call) and say whether the kernels are ready; `wait` blocks until they are (tests,
    offline images)."""
    if _state["status"] == "off":
        if wait:
            _load_here()
        else:
            _state["status"] = "warming"
            threading.Thread(target=_warm, name="npga-cpu-splats-warm", daemon=True).start()
    while wait and _state["status"] in ("warming", "loading"):
        time.sleep(0.02)
    return _state["status"] == "ready"


def ready() -> bool:
    """The kernels are loaded (`warm_up` was called and has finished)."""
    return _state["status"] == "ready"


def status() -> str:
    """off, warming, loading, ready or failed (with the reason)."""
    s = _state["status"]
    return f"failed ({_state['error']})" if s == "failed" else s


class CpuColourPass:
    """One image at a time: `begin` bins the splats, `step` blends tiles within a time budget, `pixels` packs the
    finished image for the colour target."""

    def __init__(self) -> None:
        self._planes: np.ndarray | None = None
        self._packed: dict[str, np.ndarray] = {}
        self.ms_per_work = PRIOR_MS_PER_WORK
        self._tiles = np.zeros(0, np.int32)
        self._work = np.zeros(0)
        self._next = 0
        self._bins: tuple | None = None
        self._sp: np.ndarray | None = None  # the pre-pass's splats, read back
        self._key: object = None
        self._source: tuple | None = None  # (buffer, count, order, width, height) of the image begun
        self._clear = np.zeros(4, np.float32)

    @property
    def progress(self) -> float:
        """Fraction of the image's predicted work done."""
        if self._bins is None:
            return 0.0
        total = float(self._work.sum()) if len(self._work) else 0.0
        return 1.0 if total <= 0 else float(self._work[: self._next].sum()) / total

    def begin(self, buffer: moderngl.Buffer, count: int, order: np.ndarray, width: int, height: int,
              clear: tuple[float, float, float, float]) -> None:
        """Start an image of `width` x `height` from the pre-pass's `count` splats in `buffer`, drawn in `order` (the
        pre-pass's own array: its splats are read back once per pre-pass), on a target cleared to `clear`. The
        read-back and the binning are the first `step`'s work, within its budget."""
        assert _kernels is not None, "warm_up() first"
        self._source = (buffer, count, order, width, height)
        self._bins, self._next = None, 0
        if self._planes is None or self._planes.shape[1:] != (height, width):
            self._planes, self._packed = np.empty((4, height, width), np.float32), {}
        self._clear = np.asarray(clear, np.float32).reshape(4)

    def _bin(self) -> None:
        """Read the splats back (once per pre-pass) and bin them into tiles."""
        k = _kernels
        assert k is not None and self._source is not None
        buffer, count, order, width, height = self._source
        if self._sp is None or self._sp.shape[0] != count:
            self._sp, self._key = np.empty((count, 16), np.float32), None
        if self._key is not order:
            buffer.read_into(self._sp, size=count * 64)
            self._key = order
        with _lock:
            order = np.ascontiguousarray(order, np.uint32)
            starts, lists, work = k.bin_tiles(order, k.pixel_boxes(order, self._sp, width, height), width, height)
        self._bins = (starts, lists)
        self._tiles = np.arange(len(work), dtype=np.int32)
        self._work = work

    def step(self, budget_ms: float, texture: moderngl.Texture, scale: float) -> bool:
        """Blend tiles for about `budget_ms` (at least one batch; the first step bins the splats first); when the
        image is finished, write it into `texture` (as the GL pass would have drawn it: colour times `scale`) and
        return True."""
        t_start = time.perf_counter()
        if self._bins is None:
            self._bin()
            budget_ms -= (time.perf_counter() - t_start) * 1e3
            if budget_ms <= 0:  # the binning was this step's progress: the tiles begin with the next budget
                return False
        k, bins, planes = _kernels, self._bins, self._planes
        assert k is not None and bins is not None and planes is not None
        n = len(self._tiles)
        end = n
        threads = k.nb.get_num_threads()
        if math.isfinite(budget_ms) and self._next < n:
            predicted = np.cumsum(self._work[self._next:]) * self.ms_per_work
            # at least one tile (not one per thread: beside busy processes a batch waits for its slowest thread, and
            # 4 tiles of a 9-tile live image took 20-28 ms of an 8 ms budget)
            end = self._next + max(1, int(np.searchsorted(predicted, budget_ms, side="right")))
        if self._next < end:
            with _lock:
                t0 = time.perf_counter()
                k.draw_tiles(self._tiles[self._next:end], CHUNKS_PER_THREAD * threads, bins[0], bins[1], self._sp,
                             planes, self._clear)
                ms = (time.perf_counter() - t0) * 1e3
            work = float(self._work[self._next:end].sum())
            if work > 0 and ms >= RATE_MIN_MS:  # a damped running average of the machine's rate
                lo, hi = RATE_STEP
                rate = min(hi * self.ms_per_work, max(lo * self.ms_per_work, ms / work))
                self.ms_per_work = 0.5 * self.ms_per_work + 0.5 * rate
            self._next = end
        if end < n:
            return False
        texture.write(self.pixels(texture.dtype, scale))
        return True

    def pixels(self, dtype: str, scale: float) -> np.ndarray:
        """The finished image as a colour target of `dtype` stores it: (H, W, 4) uint16 for "nu2" (colour times
        `scale`, clamped to [0, 1]) or float32, rows as drawn."""
        k, planes = _kernels, self._planes
        assert k is not None and planes is not None
        _, height, width = planes.shape
        out = self._packed.get(dtype)
        if out is None:
            out = self._packed[dtype] = np.empty((height, width, 4), np.uint16 if dtype == "nu2" else np.float32)
        with _lock:
            (k.pack_unorm16 if dtype == "nu2" else k.pack_float)(planes, out, scale)
        return out

    def release(self) -> None:
        """Drop the image and its buffers."""
        self._planes, self._packed, self._bins, self._sp, self._key, self._source = None, {}, None, None, None, None
