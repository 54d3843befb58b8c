"""What the viewer and the pose worker exchange (npga_core/posing/engine.py, worker.py): the slot layout, the
options the worker starts with, the bake's progress, and every message as a named tuple.

Requests (viewer -> worker, on the request queue; ``None`` stops the worker): `PoseRequest`, `FrameRequest`,
`BakeRequest`, `CancelBakeRequest`. Replies (worker -> viewer): `ReadyReply` and `StatusReply` (the worker's
status dict), `PoseReply` (a posed cloud in a shared slot) and `ErrorReply`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

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

    def views(self, buf: memoryview | None) -> dict[str, np.ndarray]:
        """Arrays of this layout over a shared-memory block's buffer (None: the block is closed, an error)."""
        if buf is None:
            raise ValueError("the shared-memory block is closed")
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



# -- requests ---------------------------------------------------------------------------------------------
class PoseRequest(NamedTuple):
    req_id: int
    code: np.ndarray
    mode: str  # one of MODES


class FrameRequest(NamedTuple):
    req_id: int
    frame: int  # of the current bake


class BakeRequest(NamedTuple):
    bake_id: int
    codes: np.ndarray  # (T, D)
    budget_mb: float
    use_cache: bool
    bits: int


class CancelBakeRequest(NamedTuple):
    bake_id: int


class ReopenRequest(NamedTuple):
    """Open another file of the avatar (an edited cloud) in the running worker: requests before `req_id` are
    dropped, the posed clouds take `layout` (no larger than the slots)."""

    req_id: int
    path: str
    layout: Layout


Request = PoseRequest | FrameRequest | BakeRequest | CancelBakeRequest | ReopenRequest


# -- replies ----------------------------------------------------------------------------------------------
class ReadyReply(NamedTuple):
    status: dict  # "reopened": the id of the `ReopenRequest` it answers (absent: the worker's start)


class StatusReply(NamedTuple):
    status: dict  # may carry "bake" (a BakeStatus as a dict, or None) with the "bake_id" it answers


class PoseReply(NamedTuple):
    req_id: int
    slot: int
    code: np.ndarray
    timings: dict
    flags: dict  # preview, frame, baked (PoseResult's fields)


class ErrorReply(NamedTuple):
    req_id: int  # -1: the worker failed
    message: str


Reply = ReadyReply | StatusReply | PoseReply | ErrorReply


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


