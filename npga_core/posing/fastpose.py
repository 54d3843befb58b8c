"""`FastPoser`: the exact dynamics at the matrix-multiply limit, with persistent buffers.

Per frame only the frame vector changes, so the per-Gaussian part of every network's first layer is computed
once (`ConditionedMLP.precompute`, shared with `Avatar`'s cache) and a frame costs one (hidden,) vector per
network. Then the networks run chunk by chunk over the same rows (`chains.Chain`); each network's outputs are
routed into the chunk's offset rows (scaled, times the blend weight of blended networks), and a network whose
blend weight is zero outside a contiguous range of rows (Gaussian-Head-Avatar's near/far Gaussians, sorted so at
import) runs on that range only. Each chunk's offsets are applied (`ATTRIBUTE_OPS` by the dynamics' rules, the
same operation order as `apply_offsets` + `to_posed_gaussians`) while the chunk is still in cache and written
straight into the caller's output arrays (e.g. a shared-memory slot). Chunk buffers are allocated once; a frame
allocates nothing of size N.

Offsets are handled as one row per Gaussian (`OffsetLayout`): the summed offset of every attribute the networks
reach. The preview model and the bake cache store and combine offsets in that layout.
"""

from __future__ import annotations

import copy
import platform
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch

from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import ATTRIBUTE_OPS, RIG, cloud_tensors
from npga_core.posing.chains import FUSED, Chain, Scratch, low_inputs, onednn_available
from npga_core.posing.device import resolve_device
from npga_core.posing.poserows import (
    OffsetLayout,
    RowSet,
    attribute_major,
    compose_rotation_rows,
    encoding_key,
    posed_buffers,
    support_span,
    unit_rows,
)
from npga_core.posing.precision import bf16_native, check_precision

#: Attributes gathered into attribute-major rows before they are applied.
SMALL_BLOCKS = ("position", "rotation", "scale", "opacity")
KERNELS = ("auto", "onednn", "aten")

__all__ = ["KERNELS", "FastPoser", "OffsetLayout", "RowSet", "onednn_available", "posed_buffers", "resolve_device",
           "support_span"]


@dataclass
class Lane:
    """One thread's scratch: its own copy of every chain's buffers, an offset chunk and a network output chunk
    (handed to the bodies that `FastPoser.parallel` runs; `index` tells a body which lane's buffers to use)."""

    index: int
    chains: dict[str, Chain]
    offsets: torch.Tensor
    scratch: Scratch
    net_out: torch.Tensor
    busy: dict[str, float] = field(default_factory=dict)  # seconds per stage in the last parallel run


class FastPoser:
    """Exact posed clouds (and offsets) of an avatar at any frame vector, fast; see the module docstring.

    `first_layer`: "cache" keeps every Gaussian's first-layer term (rows x hidden floats per network, shared with
    `Avatar`'s cache where a network reaches every row); "recompute" encodes each chunk's (mu, f) again, a GEMM
    of the per-Gaussian input width that costs nothing of memory; "auto" caches while the terms of all networks
    fit `cache_mb`. `device` may be a GPU ("cuda", "mps"); results always land in CPU arrays.

    `chunk`: rows per chunk (None: the kernel's best, measured). `kernel`: "onednn" runs the hidden layers of
    ReLU and leaky-ReLU networks on oneDNN's packed linear with a fused bias and activation (about 5 % faster
    here, see docs/PERFORMANCE.md), "aten" on `torch.mm`; "auto" takes oneDNN on x86-64 CPUs when
    `onednn_available()`. Networks with another activation always use "aten".

    `threads` lanes each take the next chunk and run it with single-threaded operations (torch's thread count
    is 1 while a pose runs): no barrier per operation, which with torch's own threads costs 10x or more as
    soon as a core is busy with something else (the renderer, another process).

    `precision`: "fp32", "bf16" (layers 1.. in bfloat16 on oneDNN, see `chains`) or "auto": bfloat16 where the CPU
    multiplies it natively (`precision.bf16_native`) and `fidelity()` stays within `BF16_TOLERANCE`, else float32.
    """

    #: "auto" keeps bfloat16 when the offsets' error against float32 (RMS over a sample of rows and codes,
    #: per attribute block, relative to the block's RMS offset) is at most this. Measured: demo 0.008, synthetic
    #: 100k 0.014, synthetic 3k 0.027 (its 1-column opacity block); the images stay >= 45 dB (tests).
    BF16_TOLERANCE = 0.05

    def __init__(self, avatar: Avatar, chunk: int | None = None, device: str | torch.device | None = None,
                 first_layer: str = "auto", cache_mb: float = 256.0, threads: int = 1, kernel: str = "auto",
                 precision: str = "fp32"):
        dynamics = avatar.dynamics
        if dynamics is None:
            raise ValueError("the fast path needs an avatar with dynamics")
        self.avatar = avatar
        self.version = avatar.version  # the avatar's edit version these buffers were built from
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        self.n = len(avatar)
        nets = dynamics.networks()
        self.rig = dynamics.rig
        # the rig's rest transform of the centres (None: the identity), applied to every chunk by `apply_rows`
        self._rig_move = None if self.rig is None or self.rig.identity_transform else \
            torch.from_numpy(self.rig.transform.astype(np.float32)).to(self.device)
        self.layout = OffsetLayout.of(nets, rig={} if self.rig is None else self.rig.attributes)
        self.rules = dict(dynamics.rules)
        self.rotation_op = dynamics.rotation_op
        if self.device.type == "cpu":
            self.nets = nets
            self.canonical = avatar.canonical_tensors()
        else:
            self.nets = {k: copy.deepcopy(n).to(self.device).eval() for k, n in nets.items()}
            self.canonical = {k: None if v is None else v.to(self.device)
                              for k, v in cloud_tensors(avatar.cloud).items()}
        weights, spans = self._blend(avatar)
        if first_layer == "auto":
            rows = {k: (spans[k][1] - spans[k][0]) if k in spans else self.n for k in nets}
            need = sum(rows[k] * n.config.hidden for k, n in nets.items()) * 4 / 2**20
            first_layer = "cache" if need <= cache_mb else "recompute"
        if first_layer not in ("cache", "recompute"):
            raise ValueError(f"first_layer must be 'auto', 'cache' or 'recompute', got {first_layer!r}")
        self.first_layer = self._first_mode = first_layer
        self.rows = RowSet(self.canonical["means"], self.canonical["features"], None, None, weights, spans)
        self.threads = max(1, int(threads)) if self.device.type == "cpu" else 1
        if kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
        fused = {k for k, n in self.nets.items() if n.config.activation in FUSED and n.config.depth > 1}
        self.kernel = self._pick_kernel(kernel) if fused else "aten"  # oneDNN only for (leaky) ReLU networks
        # rows per chunk: oneDNN measured best at 2048, torch.mm at 1024 (two blocks in a 2 MB L2); GPUs take more
        default = 65536 if self.device.type != "cpu" else 2048 if self.kernel == "onednn" else 1024
        self.chunk = int(chunk) if chunk else default
        self._fused = fused
        requested = check_precision(precision)
        low_ok = self.kernel == "onednn"  # bfloat16 runs on oneDNN's packed linear only
        if requested == "bf16" and not low_ok:
            raise ValueError("--precision bf16: needs the oneDNN kernel on a CPU (this build or device has none)")
        self.precision = "bf16" if requested == "bf16" or (requested == "auto" and low_ok and bf16_native()) \
            else "fp32"
        self._set_precision(self.precision)
        # OpenMP's thread count is per thread and a new thread starts with the default (all cores): without the
        # initializer each lane's GEMM forks its own team, lanes x cores threads on the cores (~20 % slower)
        self._pool = ThreadPoolExecutor(self.threads - 1, "fastpose", initializer=torch.set_num_threads,
                                        initargs=(1,)) if self.threads > 1 else None
        self._enc_key = {key: encoding_key(net) for key, net in self.nets.items()}
        chains = self.chains
        share = {k: (spans[k][1] - spans[k][0]) / max(self.n, 1) if k in spans else 1.0 for k in chains}
        self.flops_per_gaussian = sum(c.flops_per_row * share[k] for k, c in chains.items())
        if first_layer == "recompute" or self.precision == "bf16":
            self.flops_per_gaussian += sum(2 * c.first_weight.numel() * share[k] for k, c in chains.items())
        self._soa = attribute_major(self.canonical)
        small = [(k, self.layout.blocks[k]) for k in SMALL_BLOCKS if k in self.layout.blocks]
        self._small: dict[str, tuple[int, int]] = {}
        cols: list[int] = []
        o = 0
        for key, (c, w) in small:
            self._small[key] = (o, w)
            cols += range(c, c + w)
            o += w
        contiguous = cols == list(range(cols[0], cols[0] + len(cols))) if cols else False
        self._small_cols: slice | torch.Tensor = slice(cols[0], cols[0] + len(cols)) if contiguous else \
            torch.tensor(cols, dtype=torch.int64, device=self.device)
        self.fidelity_error: float | None = None  # the last `fidelity()` figure (None: not measured)
        if requested == "auto" and self.precision == "bf16" and self.fidelity() > self.BF16_TOLERANCE:
            self._set_precision("fp32")

    def _set_precision(self, precision: str) -> None:
        """Lanes and per-Gaussian inputs for "fp32" (first-layer terms, cached or not) or "bf16" (`low_inputs`)."""
        self.precision = precision
        low = precision == "bf16"
        self.first_layer = "bf16 inputs" if low else self._first_mode
        self.rows.first = None if low else self._first_terms()
        self.rows.low = self._low_rows(self.rows) if low else None
        self._lanes = [self._lane(i, low) for i in range(self.threads)]

    @torch.no_grad()
    def _low_rows(self, rows: RowSet) -> dict[str, torch.Tensor]:
        """Per network the `low_inputs` of the rows it reaches (its span, else all rows), in chunks."""
        out = {}
        for key, net in self.nets.items():
            a, b = rows.spans.get(key, (0, rows.n))
            block = torch.empty(b - a, 2 * net.split_weight(0)[0].shape[1], dtype=torch.bfloat16)
            for s in range(a, b, 16384):
                e = min(b, s + 16384)
                low_inputs(net.encode_gaussian(rows.means[s:e], rows.features[s:e]), block[s - a : e - a])
            out[key] = block
        return out

    def _lane(self, index: int, low: bool) -> Lane:
        """A lane's chains and buffers, in bfloat16 (`low`) or float32."""
        dtype = torch.bfloat16 if low else torch.float32
        chains = {k: Chain(n, self.chunk, self.device,
                           Chain.pack(n, self.chunk, dtype) if self.kernel == "onednn" and k in self._fused else None,
                           low)
                  for k, n in self.nets.items()}
        width = max((c.scratch_width for c in chains.values()), default=1)
        out_width = max((n.config.out_dim for n in self.nets.values()), default=1)
        return Lane(index, chains, torch.empty(self.chunk, self.layout.width, device=self.device),
                     Scratch(self.chunk, width, self.device), torch.empty(self.chunk * out_width, device=self.device))

    @torch.no_grad()
    def fidelity(self, rows: int = 2048, codes: int = 3, seed: int = 0) -> float:
        """How far this poser's offsets are from float32's: per attribute block the RMS error over `rows` sampled
        Gaussians at `codes` frame vectors (the neutral one and samples of the expression space), relative to the
        block's RMS offset; the worst block and code. 0.0 for a float32 poser."""
        if self.precision == "fp32":
            self.fidelity_error = 0.0
            return 0.0
        rng = np.random.default_rng(seed)
        index = np.unique(rng.choice(self.n, size=min(rows, self.n), replace=False)) if self.n else np.zeros(0, int)
        sub = self.subset(index)
        exact = self._lane(-1, False)
        zs = [self.avatar.neutral_code()]
        space = self.avatar.expression
        for _ in range(codes - 1):
            zs.append(space.sample(rng) if space is not None else rng.standard_normal(self.avatar.code_dim))
        worst = 0.0
        for z in zs:
            terms = self.code_terms(np.asarray(z, np.float32))
            got, ref = (torch.empty(sub.n, self.layout.width) for _ in range(2))
            for s in range(0, sub.n, self.chunk):
                e = min(sub.n, s + self.chunk)
                self._chunk_offsets(self._lanes[0], sub, terms, s, e, into=got[s:e])
                self._chunk_offsets(exact, sub, terms, s, e, into=ref[s:e])
            for c, w in self.layout.blocks.values():
                r = ref[:, c : c + w]
                scale = float(r.square().mean().sqrt())
                err = float((got[:, c : c + w] - r).square().mean().sqrt())
                worst = max(worst, err / scale if scale > 0 else (0.0 if err == 0 else float("inf")))
        self._lanes[0].busy.clear()
        self.fidelity_error = worst
        return worst

    def _blend(self, avatar: Avatar) -> tuple[dict[str, torch.Tensor], dict[str, tuple[int, int]]]:
        """Per blended network: its weights on all rows, and the range of rows it reaches when contiguous."""
        weights, spans = {}, {}
        cloud = avatar.cloud
        for key, net in self.nets.items():
            name = net.config.blend
            if name is None:
                continue
            column = np.asarray(cloud.blend_weights, np.float32)[:, cloud.blend_names.index(name)]
            weights[key] = torch.from_numpy(np.ascontiguousarray(column)).to(self.device)
            span = support_span(column)
            if span is not None:
                spans[key] = span
        return weights, spans

    def _pick_kernel(self, kernel: str) -> str:
        usable = self.device.type == "cpu" and onednn_available()
        if kernel == "onednn" and not usable:
            raise ValueError("kernel 'onednn': this torch build or device has no usable oneDNN linear")
        # "auto" takes it only where it was measured (x86-64); elsewhere on request
        measured = platform.machine().lower() in ("x86_64", "amd64")
        return "onednn" if usable and (kernel == "onednn" or (kernel == "auto" and measured)) else "aten"

    def _first_terms(self) -> dict[str, torch.Tensor] | None:
        """Per network the first-layer terms of the rows it reaches (its span, else all rows)."""
        if self._first_mode != "cache":
            return None
        c, rows = self.canonical, self.rows
        out = {}
        cache = self.avatar.first_layer_cache  # share Avatar's cache: one copy of N x hidden per network
        for key, net in self.nets.items():
            a, b = rows.spans.get(key, (0, self.n))
            if self.device.type != "cpu":
                out[key] = net.precompute(c["means"][a:b], c["features"][a:b])
                continue
            ident = key if (a, b) == (0, self.n) else f"{key}[{a}:{b}]"
            if ident not in cache:
                cache[ident] = net.precompute(c["means"][a:b], c["features"][a:b])
            out[key] = cache[ident]
        return out

    @staticmethod
    def supported(avatar: Avatar) -> bool:
        """True when the avatar has dynamics (every network description runs on this path; a rig too, unless its
        rest transform turns the covariances, which `Avatar.pose` does)."""
        rig = avatar.rig
        return avatar.dynamics is not None and (rig is None or rig.identity_transform or not rig.turns_covariance)

    @property
    def cache_bytes(self) -> int:
        """Bytes held by the first-layer cache (0 when recomputed per chunk)."""
        return 0 if self.rows.first is None else sum(t.numel() * 4 for t in self.rows.first.values())

    # -- offsets ------------------------------------------------------------------------------------------
    @torch.no_grad()
    def code_terms(self, z: np.ndarray) -> dict[str, tuple]:
        """Per network: the frame's part of layer 0, layer 0's bias plus it, and the skip layers' constants."""
        if self.avatar.version != self.version:
            raise RuntimeError("the avatar was edited after this FastPoser was built (invalidate_caches); "
                               "build a new one")
        zfull = self.avatar.check_code(z)
        dynamics = self.avatar.dynamics
        assert dynamics is not None
        zt = torch.from_numpy(zfull[: dynamics.network_dim]).to(self.device)
        terms: dict[str, tuple] = {}
        if self.rig is not None:  # the rig's per-frame part (runtime weights; a skin's face motions) once a frame
            terms[RIG] = (self.rig.frame(zfull[dynamics.network_dim :]),)
        chains = self.chains
        for key, net in self.nets.items():
            t = net.code_term(zt)
            consts = chains[key].frame_constants(net.encode_code(zt)) if net.config.skips else None
            terms[key] = (t, net.layers[0].bias.detach() + t, consts)  # type: ignore[operator]
        return terms

    def _chunk_offsets(self, lane: Lane, rows: RowSet, terms: dict, s: int, e: int,
                       cancel: Callable[[], bool] | None = None,
                       into: torch.Tensor | None = None) -> torch.Tensor | None:
        """Combined offsets (e - s, width) of rows s:e of `rows`, in `into` (on the poser's device) or else the
        lane's chunk buffer (None when `cancel()` turned true between two networks)."""
        out_rows = lane.offsets[: e - s] if into is None else into
        out_rows.zero_()
        encoded: dict[tuple, torch.Tensor] = {}
        for i, (key, net) in enumerate(self.nets.items()):
            if i and cancel is not None and cancel():
                return None
            lo, hi = rows.span(key, s, e)
            if lo == hi:
                continue
            t0 = time.perf_counter()
            chain = lane.chains[key]
            first = enc = low = None
            if rows.low is not None and chain.low:
                a = rows.spans.get(key, (0, 0))[0]
                low = rows.low[key][lo - a : hi - a]
            elif rows.first is not None:
                a = rows.spans.get(key, (0, 0))[0]
                first = rows.first[key][lo - a : hi - a]
            if (rows.first is None and low is None) or net.config.skips:  # shared by equal encodings
                ident = (self._enc_key[key], lo, hi)
                if ident not in encoded:
                    encoded[ident] = net.encode_gaussian(rows.means[lo:hi], rows.features[lo:hi])
                enc = encoded[ident]
            t, bias, consts = terms[key]
            dest = lane.net_out[: (hi - lo) * net.config.out_dim].view(hi - lo, net.config.out_dim)
            chain.run(first, enc, t, bias, lane.scratch, dest, consts, low)
            self.route(key, dest, rows, lo, hi, out_rows[lo - s : hi - s])
            lane.busy[key] = lane.busy.get(key, 0.0) + time.perf_counter() - t0
        if self.rig is not None:
            t0 = time.perf_counter()
            which = slice(s, e) if rows.index is None else rows.index[s:e]
            for name, d in self.rig.attribute_offsets(terms[RIG][0], which, rows.means[s:e].cpu()).items():
                c, w = self.layout.blocks[name]
                out_rows[:, c : c + w] += d.to(out_rows.device)
            lane.busy[RIG] = lane.busy.get(RIG, 0.0) + time.perf_counter() - t0
        return out_rows

    @property
    def chains(self) -> dict[str, Chain]:
        """Each network's compiled chain (weights, biases, activations) as the first lane runs it."""
        return self._lanes[0].chains

    def route(self, key: str, out: torch.Tensor, rows: RowSet, lo: int, hi: int, dest: torch.Tensor) -> None:
        """Add network `key`'s outputs of rows lo:hi of `rows` (scaled, times its blend weight) into offset rows
        `dest`, where the layout puts each output (for callers that run a network their own way, as the
        previews' bf16 probes)."""
        weight = rows.weights.get(key)
        w = None if weight is None else weight[lo:hi, None]
        for r in self.nets[key].config.routes or []:
            c, _ = self.layout.blocks[r.attribute]
            target = dest[:, c + r.to : c + r.to + r.width]
            part = out[:, r.start : r.start + r.width]
            if w is None:
                target.add_(part, alpha=r.scale)
            else:
                target.addcmul_(part, w, value=r.scale)

    def parallel(self, tasks: list[int], body: Callable[[Lane, int], bool | None],
                  cancel: Callable[[], bool] | None = None, timings: dict[str, float] | None = None) -> bool:
        """Run `body(lane, task)` for every task on all lanes (each lane pulls the next task; each operation
        runs on one thread); False if `cancel()` turned true before some task or a body returned False.
        Per-stage busy times, divided by the lanes, go to `timings`. Callers outside (posing/preview.py) split
        their rows with `chunk_for`."""
        pending = iter(tasks)
        lock = threading.Lock()
        stop = [False]

        def work(lane: Lane) -> None:
            torch.set_grad_enabled(False)
            while True:
                with lock:
                    task = None if stop[0] else next(pending, None)
                if task is None:
                    return
                if (cancel is not None and cancel()) or body(lane, task) is False:
                    stop[0] = True
                    return

        for lane in self._lanes:
            lane.busy.clear()
        saved = torch.get_num_threads()
        if saved != 1:  # lanes are the parallelism: each operation runs on one thread (see the class docstring)
            torch.set_num_threads(1)
        try:
            futures = [self._pool.submit(work, lane) for lane in self._lanes[1:]] if self._pool else []
            work(self._lanes[0])
            for f in futures:
                f.result()
        finally:
            if saved != 1:
                torch.set_num_threads(saved)
        if timings is not None:
            for lane in self._lanes:
                for k, v in lane.busy.items():
                    timings[k] = timings.get(k, 0.0) + v * 1e3 / len(self._lanes)
        return not stop[0]

    def _starts(self, n: int) -> list[int]:
        return list(range(0, n, self.chunk_for(n)))

    def chunk_for(self, n: int) -> int:
        """Rows per task of `parallel` for `n` rows: the chunk size, smaller for small row sets so that every
        lane gets work."""
        return max(1, min(self.chunk, -(-n // self.threads)))

    def subset(self, index: np.ndarray) -> RowSet:
        """The rows `index` with their first-layer terms cached, for repeated `offsets(..., rows=)` calls (every
        network runs on every row of a subset; blend weights zero what a network does not reach)."""
        index = np.asarray(index, np.int64)
        idx = torch.from_numpy(index).to(self.device)
        mu, f = self.rows.means.index_select(0, idx), self.rows.features.index_select(0, idx)
        weights = {k: w.index_select(0, idx) for k, w in self.rows.weights.items()}
        spans = {}
        if len(index) and np.all(index[1:] > index[:-1]):  # ascending rows: a network's range stays a range
            spans = {k: (int(np.searchsorted(index, a)), int(np.searchsorted(index, b)))
                     for k, (a, b) in self.rows.spans.items()}
        first = {}
        for k, n in self.nets.items():
            a, b = spans.get(k, (0, len(index)))
            first[k] = n.precompute(mu[a:b], f[a:b])
        sub = RowSet(mu, f, first, index, weights, spans)
        if self.precision == "bf16":
            sub.low = self._low_rows(sub)
        return sub

    @property
    def reach(self) -> float:
        """The share of the work of every network on every row that the exact path does (1 without blended
        networks; less where blended networks run only on the rows they reach)."""
        chains = self.chains
        full = sum(c.flops_per_row for c in chains.values())
        share = {k: (b - a) / max(self.n, 1) for k, (a, b) in self.rows.spans.items()}
        return sum(c.flops_per_row * share.get(k, 1.0) for k, c in chains.items()) / max(full, 1)

    @torch.no_grad()
    def offsets(self, z: np.ndarray, out: torch.Tensor | None = None, rows: RowSet | None = None,
                timings: dict[str, float] | None = None,
                cancel: Callable[[], bool] | None = None) -> torch.Tensor | None:
        """Combined offsets (N, or the rows of a `subset`, width) at frame vector z, on the CPU (None if
        cancelled)."""
        rows = self.rows if rows is None else rows
        if out is None:
            out = torch.empty(rows.n, self.layout.width)
        terms = self.code_terms(z)
        step = self.chunk_for(rows.n)

        direct = out.device == self.device  # the networks write straight into `out`, else through the lane

        def body(lane: Lane, s: int) -> bool:
            e = min(rows.n, s + step)
            chunk = self._chunk_offsets(lane, rows, terms, s, e, cancel, out[s:e] if direct else None)
            if chunk is not None and not direct:
                out[s:e].copy_(chunk)
            return chunk is not None

        return out if self.parallel(self._starts(rows.n), body, cancel, timings) else None

    # -- posing --------------------------------------------------------------------------------------------
    @torch.no_grad()
    def pose_into(self, z: np.ndarray, dest: dict[str, np.ndarray], offsets_out: torch.Tensor | None = None,
                  cancel: Callable[[], bool] | None = None, timings: dict[str, float] | None = None) -> bool:
        """Write the exact posed cloud at z into `dest` (float32 arrays shaped as `PosedGaussians`).

        `offsets_out` (N, width), if given, receives the combined offsets too. Returns False if `cancel()`
        became true (checked before each chunk and between the networks; `dest` is then partly written).
        """
        terms = self.code_terms(z)
        out = {k: torch.from_numpy(v) for k, v in dest.items() if v is not None}
        step = self.chunk_for(self.n)

        def body(lane: Lane, s: int) -> bool:
            e = min(self.n, s + step)
            rows = self._chunk_offsets(lane, self.rows, terms, s, e, cancel)
            if rows is None:
                return False
            if offsets_out is not None:
                offsets_out[s:e].copy_(rows)
            t0 = time.perf_counter()
            self.apply_rows(rows, s, e, out)
            lane.busy["apply"] = lane.busy.get("apply", 0.0) + time.perf_counter() - t0
            return True

        done = self.parallel(self._starts(self.n), body, cancel, timings)
        if done:
            self._finish(out)
        return done

    @torch.no_grad()
    def apply_into(self, offsets: torch.Tensor, dest: dict[str, np.ndarray], chunk: int = 8192) -> None:
        """Posed cloud from precomputed combined offsets (N, width) on the CPU, written into `dest`."""
        out = {k: torch.from_numpy(v) for k, v in dest.items() if v is not None}

        def body(lane: Lane, s: int) -> None:
            e = min(self.n, s + chunk)
            self.apply_rows(offsets[s:e].to(self.device), s, e, out)

        self.parallel(list(range(0, self.n, chunk)), body)
        self._finish(out)

    def _finish(self, out: dict[str, torch.Tensor]) -> None:
        """What needs every row first: the legacy rotation rule's norms over all Gaussians."""
        if self.layout.blocks.get("rotation") and self.rules["rotation"] == "add_raw_legacy":
            q = out["quats"]  # raw q + d from `apply_rows`
            q.div_(q.norm(dim=0, keepdim=True).clamp_min(1e-12))
            q.div_(q.norm(dim=1, keepdim=True).clamp_min(1e-12))

    def apply_rows(self, rows: torch.Tensor, s: int, e: int, out: dict[str, torch.Tensor]) -> None:
        """Apply combined offsets of rows s:e to the canonical cloud and write activated values into `out`.

        The same operations as `apply_offsets` followed by `to_posed_gaussians`; the small blocks (position,
        rotation, scale, opacity) are first gathered into attribute-major rows so every operation runs on
        contiguous vectors. Under the legacy rotation rule the raw sums are written (`_finish` normalises).
        """
        soa, lay = self._soa, self.layout
        if not self._small:
            small = None
        elif isinstance(self._small_cols, slice):
            small = rows[:, self._small_cols].t().contiguous()
        else:
            small = torch.index_select(rows, 1, self._small_cols).t().contiguous()

        def block(name: str) -> torch.Tensor | None:
            hit = self._small.get(name)
            return None if hit is None or small is None else small[hit[0] : hit[0] + hit[1]]

        d = block("position")
        means = soa["means"][:, s:e]
        out["means"][s:e].copy_((means if d is None else ATTRIBUTE_OPS["position"].apply(means, d)).t())
        if (m := self._rig_move) is not None:  # the centres only (`supported`)
            m = m.to(out["means"].device)
            out["means"][s:e] = out["means"][s:e] @ m[:3, :3].t() + m[:3, 3]
        out["quats"][s:e].copy_(self._rotate(block("rotation"), s, e).t())
        log_s = soa["log_scales"][:, s:e]
        if (d := block("scale")) is not None:
            log_s = ATTRIBUTE_OPS["scale"].apply(log_s, d)
        out["scales"][s:e].copy_(torch.exp(log_s).t())
        op = soa["opacity_logits"][s:e]
        if (d := block("opacity")) is not None:
            op = ATTRIBUTE_OPS["opacity"].apply(op, d[0])
        out["opacities"][s:e].copy_(torch.sigmoid(op))
        self._add_wide(rows, s, e, "sh", out["sh"], lay.blocks.get("sh"))
        if "latent" in out and soa.get("latent") is not None:
            self._add_wide(rows, s, e, "latent", out["latent"], lay.blocks.get("latent"))

    def _rotate(self, d: torch.Tensor | None, s: int, e: int) -> torch.Tensor:
        """Posed quaternions (4, m) of rows s:e by the rotation rule (raw sums under the legacy rule)."""
        rule = self.rules["rotation"]
        if d is None:
            return self._soa["unit_quats"][:, s:e]
        if rule == "compose":
            return unit_rows(compose_rotation_rows(self._soa["unit_quats"][:, s:e], d))
        if rule == "add":
            return unit_rows(self._soa["unit_quats"][:, s:e] + d)
        raw = self._soa["quats"][:, s:e] + d
        return raw if rule == "add_raw_legacy" else unit_rows(raw)

    def _add_wide(self, rows: torch.Tensor, s: int, e: int, name: str, dest: torch.Tensor,
                  cols: tuple[int, int] | None) -> None:
        """dest[s:e] = canonical + offset on the leading columns (SH, latent: row-major, no reordering)."""
        canon = self._soa[name][s:e]
        target = dest[s:e].view(e - s, -1)
        if cols is None:
            target.copy_(canon)
            return
        c, w = cols
        if target.device == canon.device:
            torch.add(canon[:, :w], rows[:, c : c + w], out=target[:, :w])
        else:  # a GPU pose writing into CPU arrays
            target[:, :w].copy_(canon[:, :w] + rows[:, c : c + w])
        if w < canon.shape[1]:
            target[:, w:].copy_(canon[:, w:])
