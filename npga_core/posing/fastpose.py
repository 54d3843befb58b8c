"""`FastPoser`: the exact dynamics at the matrix-multiply limit, with persistent buffers.

Per frame only the code changes, so the per-Gaussian part of every network's first layer is computed once
(`ConditionedMLP.precompute`, shared with `Avatar`'s cache) and a code costs one (hidden,) vector. Then F and
G run chunk by chunk over the same rows; each chunk's offsets are applied (`ATTRIBUTE_OPS`, the same operation
order as `apply_offsets` + `to_posed_gaussians`) while the chunk is still in cache and written straight into the
caller's output arrays (e.g. a shared-memory slot). Chunk buffers are allocated once (oneDNN's calls return
chunk-sized blocks that the allocator recycles: no page faults per frame); a frame allocates nothing of size N.

Offsets of all networks are handled as one row per Gaussian (`OffsetLayout`): F's columns, then G's. The
preview model and the bake cache store and combine offsets in that layout.

The hidden layers of ReLU networks run on oneDNN's linear with a fused bias + ReLU epilogue and weights packed
once into its blocked layout (`kernel="onednn"`, torch's own `mkldnn` operators, the ones torch.compile uses on
the CPU); without them (another build, a GPU) the chain runs on `torch.mm` with the biases folded (`"aten"`).
"""

from __future__ import annotations

import copy
import functools
import platform
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch

from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import ATTRIBUTE_OPS, ConditionedMLP, cloud_tensors, quat_multiply

#: Offset blocks gathered into attribute-major rows before they are applied.
SMALL_BLOCKS = ("F.position", "G.position", "G.rotation", "G.scale", "G.opacity")
KERNELS = ("auto", "onednn", "aten")


@functools.cache
def onednn_available() -> bool:
    """True when torch has oneDNN's packed linear with a fused ReLU (`torch.ops.mkldnn._linear_pointwise`,
    private to torch but what its compiler emits on CPUs) and it matches a plain product on a small test
    (checked once per process)."""
    try:
        if not torch.backends.mkldnn.is_available():
            return False
        gen = torch.Generator().manual_seed(0)
        x, w, b = (torch.randn(s, generator=gen) for s in ((37, 64), (48, 64), (48,)))
        packed = torch.ops.mkldnn._reorder_linear_weight(w, 64)
        y = torch.ops.mkldnn._linear_pointwise(x, packed, b, "relu", [], "")
        return bool(torch.allclose(y, torch.relu(torch.addmm(b, x, w.t())), rtol=1e-4, atol=1e-4))
    except (AttributeError, RuntimeError, NotImplementedError):
        return False


@dataclass(frozen=True)
class OffsetLayout:
    """Column blocks of the combined offset row: F's outputs first, then G's."""

    nets: tuple[tuple[str, int, int], ...]  # (network key, first column, width)
    blocks: dict[str, tuple[int, int]]  # "F.position", "G.sh", ... -> (first column, width)

    @property
    def width(self) -> int:
        return sum(w for _, _, w in self.nets)

    @staticmethod
    def of(networks: dict[str, ConditionedMLP]) -> OffsetLayout:
        nets, blocks, col = [], {}, 0
        for key, net in networks.items():
            nets.append((key, col, net.config.out_dim))
            for name, width in net.config.outputs:
                blocks[f"{key}.{name}"] = (col, width)
                col += width
        return OffsetLayout(tuple(nets), blocks)

    def block(self, rows: torch.Tensor, key: str) -> torch.Tensor | None:
        """The columns of block `key` ("G.scale") of an offset chunk, or None if absent."""
        if key not in self.blocks:
            return None
        c, w = self.blocks[key]
        return rows[:, c : c + w]


def resolve_device(name: str | None) -> torch.device:
    """"cpu" (default), "cuda", "cuda:N", "mps" or "auto" (a GPU when torch sees one); ValueError (a one-line
    message naming the flag) if the name is unknown or the device is not there."""
    name = (name or "cpu").strip().lower()
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        mps = getattr(torch.backends, "mps", None)
        return torch.device("mps" if mps is not None and mps.is_available() else "cpu")
    kind, _, index = name.partition(":")
    if kind not in ("cpu", "cuda", "mps") or (index and (kind != "cuda" or not index.isdigit())):
        raise ValueError(f"--device {name}: expected cpu, cuda, cuda:N, mps or auto")
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"--device {name}: torch sees no CUDA GPU")
        if index and int(index) >= torch.cuda.device_count():
            raise ValueError(f"--device {name}: torch sees {torch.cuda.device_count()} CUDA GPU(s)")
    if kind == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        raise ValueError("--device mps: torch sees no MPS device")
    return torch.device(name)


@dataclass
class RowSet:
    """Per-Gaussian network inputs of a set of rows: the first-layer terms if cached, else (mu, f) to encode."""

    means: torch.Tensor
    features: torch.Tensor
    first: dict[str, torch.Tensor] | None = None
    index: np.ndarray | None = None  # the avatar rows these are (None: all, in order)

    @property
    def n(self) -> int:
        return int(self.means.shape[0])


@dataclass
class _Lane:
    """One thread's scratch: its own copy of every chain's buffers and an offset chunk."""

    index: int
    chains: dict[str, _Chain]
    offsets: torch.Tensor
    scratch: _Scratch
    busy: dict[str, float] = field(default_factory=dict)  # seconds per stage in the last parallel run


class _Scratch:
    """Two activation buffers of one lane, shared by all its chains: each layer reads one and writes the other,
    so a chunk's working set stays two (chunk, width) blocks that fit in the core's L2 (one buffer per layer,
    as before, walked through 5 MB per network at 1024 rows and was about 10 % slower)."""

    def __init__(self, chunk: int, width: int, device: torch.device):
        self.flat = [torch.empty(chunk * width, device=device) for _ in range(2)]

    def view(self, i: int, m: int, width: int) -> torch.Tensor:
        """Buffer i (0 or 1) as a contiguous (m, width) block."""
        return self.flat[i][: m * width].view(m, width)


class _Chain:
    """One network after its per-Gaussian first-layer term; activations go through the lane's `_Scratch`."""

    def __init__(self, net: ConditionedMLP, chunk: int, device: torch.device,
                 packed: list[torch.Tensor | None] | None = None):
        cfg = net.config
        if cfg.skips:
            raise ValueError("skip layers need the generic path (ConditionedMLP.evaluate)")
        self.net = net
        gw = cfg.mu_encoded_dim + cfg.feature_dim
        self.first_weight = net.layers[0].weight.detach()[:, :gw].t().contiguous()
        self.weights = [layer.weight.detach().t().contiguous() for layer in net.layers]
        self.biases = [layer.bias.detach() for layer in net.layers]
        self.widths = [o for o, _ in cfg.layer_shapes()]
        self.out_flat = torch.empty(chunk * cfg.out_dim, device=device)
        self.narrow = cfg.out_dim <= 8 and device.type == "cpu"
        self.last_rows = net.layers[-1].weight.detach().contiguous()  # (out, in), for the transposed product
        self.relu = cfg.activation == "relu"
        self.act = net._act
        self.packed = packed  # oneDNN weights of layers 1.. (None for the narrow output), or None: torch.mm
        self.folded = self._fold() if self.relu and packed is None and len(self.weights) > 2 else None
        self.flops_per_row = sum(2 * o * i for o, i in cfg.layer_shapes()[1:])

    def _fold(self) -> list[torch.Tensor]:
        """-B_i of hidden layers 1..depth-2, then the output layer's bias b_out + B_last W_out (see `run`)."""
        consts, shift = [], torch.zeros_like(self.biases[0])
        for i in range(1, len(self.weights)):
            shift = torch.addmv(self.biases[i], self.weights[i].t(), shift)
            consts.append(shift.neg() if i < len(self.weights) - 1 else shift)
        return consts

    @staticmethod
    def pack(net: ConditionedMLP, chunk: int) -> list[torch.Tensor | None]:
        """oneDNN's blocked copies of the weights of layers 1.. (read-only, shared by all lanes); None for a
        narrow output layer, which stays a transposed `torch.mm`."""
        layers = net.layers[1:]
        return [None if i == len(layers) - 1 and net.config.out_dim <= 8 else
                torch.ops.mkldnn._reorder_linear_weight(layer.weight.detach().contiguous(), chunk)
                for i, layer in enumerate(layers)]

    @property
    def scratch_width(self) -> int:
        """Widest hidden layer: the scratch buffers' width."""
        return max(self.widths[:-1], default=1)

    def _activate(self, h: torch.Tensor) -> torch.Tensor:
        if self.relu:
            return h.clamp_min_(0.0)
        h.copy_(self.act(h))
        return h

    def run(self, first_rows: torch.Tensor | None, encoded: torch.Tensor | None, code_term: torch.Tensor,
            first_bias: torch.Tensor, scratch: _Scratch, dest: torch.Tensor) -> None:
        """Write the outputs of m rows into `dest` (m, out), from their cached first-layer term or their
        encoded inputs. `code_term` is the code's part of layer 0; `first_bias` is layer 0's bias plus it.

        In ReLU chains layers 1 and up add no bias to their hidden blocks: with s_i = a_(i-1) W_i and
        a_i = relu(s_i + b_i) = max(s_i, -b_i) + b_i, each keeps only g_i = max(s_i, -B_i) (one pass instead of
        a bias copy and a clamp) and the B_i it leaves out goes into the next layer's bias,
        B_(i+1) = b_(i+1) + B_i W_(i+1) (constants of the network, `_fold`). Layer 0 keeps its bias: folding
        the code term too made the rounding error 5x larger, this way it stays within 1.5x of the plain forward.
        The output layer's bias is added while the result is copied into `dest`; a narrow output (F's 3
        columns) is computed transposed, (out, m) = W h^T, which MKL does 4x faster than h W at that width.

        With oneDNN weights (`packed`) each hidden layer is one call that adds the bias and applies the ReLU
        while the block is still in registers: no folding, the same operation order as the plain forward.
        """
        source = first_rows if first_rows is not None else encoded
        assert source is not None
        m = source.shape[0]
        depth = len(self.weights)
        if depth == 1:
            if first_rows is not None:
                torch.add(first_rows, code_term, out=dest)
            else:
                dest.copy_(torch.addmm(first_bias, source, self.first_weight))
            return
        h = scratch.view(0, m, self.widths[0])
        if first_rows is not None:
            torch.add(first_rows, code_term, out=h)
        else:
            torch.addmm(first_bias, source, self.first_weight, out=h)
        h = self._activate(h)
        if self.packed is not None:
            self._run_onednn(h, dest)
            return
        for i in range(1, depth - 1):
            out = scratch.view(i % 2, m, self.widths[i])
            if self.folded is not None:
                torch.mm(h, self.weights[i], out=out)
                h = torch.maximum(out, self.folded[i - 1], out=out)
            else:
                torch.addmm(self.biases[i], h, self.weights[i], out=out)
                h = self._activate(out)
        bias = self.biases[-1] if self.folded is None else self.folded[-1]
        width = self.widths[-1]
        if self.narrow:
            res = self.out_flat[: width * m].view(width, m)
            torch.mm(self.last_rows, h.t(), out=res)
            torch.add(res.t(), bias, out=dest)
        else:
            res = self.out_flat[: width * m].view(m, width)
            torch.mm(h, self.weights[-1], out=res)
            torch.add(res, bias, out=dest)

    def _run_onednn(self, h: torch.Tensor, dest: torch.Tensor) -> None:
        """Layers 1.. of `run` on oneDNN: fused linear + bias + ReLU per hidden layer. Each call returns a new
        (m, hidden) block; the allocator hands the same memory back every chunk (no page faults per frame)."""
        linear = torch.ops.mkldnn._linear_pointwise
        packed, biases = self.packed, self.biases
        for i in range(1, len(packed)):
            h = linear(h, packed[i - 1], biases[i], "relu", [], "")
        if packed[-1] is None:
            m, width = h.shape[0], self.widths[-1]
            res = self.out_flat[: width * m].view(width, m)
            torch.mm(self.last_rows, h.t(), out=res)
            torch.add(res.t(), biases[-1], out=dest)
        else:
            dest.copy_(linear(h, packed[-1], biases[-1], "none", [], ""))


class FastPoser:
    """Exact posed clouds (and offsets) of an avatar at any code, fast; see the module docstring.

    `first_layer`: "cache" keeps every Gaussian's first-layer term (N x hidden floats per network, shared with
    `Avatar`'s cache); "recompute" encodes each chunk's (mu, f) again, a GEMM of width mu_enc + F that costs
    about (mu_enc + F) / code_dim of layer 0 and nothing of memory; "auto" caches while the terms of all
    networks fit `cache_mb`. `device` may be a GPU ("cuda", "mps"); results always land in CPU arrays.
    Networks with skip layers are not supported (none of the paper's have them); see `supported`.

    `chunk`: rows per chunk (None: the kernel's best, measured). `kernel`: "onednn" runs the hidden layers of
    ReLU networks on oneDNN's packed linear with a fused bias and ReLU (about 5 % faster here, see
    docs/PERFORMANCE.md), "aten" on `torch.mm`; "auto" takes oneDNN on x86-64 CPUs when `onednn_available()`.
    Networks with another activation always use "aten".

    `threads` lanes each take the next chunk and run it with single-threaded operations (torch's thread count
    is 1 while a pose runs): no barrier per operation, which with torch's own threads costs 10x or more as
    soon as a core is busy with something else (the renderer, another process).
    """

    def __init__(self, avatar: Avatar, chunk: int | None = None, device: str | torch.device | None = None,
                 first_layer: str = "auto", cache_mb: float = 256.0, threads: int = 1, kernel: str = "auto"):
        dynamics = avatar.dynamics
        if dynamics is None or not self.supported(avatar):
            raise ValueError("the fast path needs dynamics without skip layers")
        self.avatar = avatar
        self.version = avatar.version  # the avatar's edit version these buffers were built from
        self.device = device if isinstance(device, torch.device) else resolve_device(device)
        self.n = len(avatar)
        nets = dynamics.networks()
        self.layout = OffsetLayout.of(nets)
        self.rotation_op = dynamics.rotation_op
        if self.device.type == "cpu":
            self.nets = nets
            self.canonical = avatar._tensors()
        else:
            self.nets = {k: copy.deepcopy(n).to(self.device).eval() for k, n in nets.items()}
            self.canonical = {k: None if v is None else v.to(self.device)
                              for k, v in cloud_tensors(avatar.cloud).items()}
        if first_layer == "auto":
            need = self.n * sum(n.config.hidden for n in nets.values()) * 4 / 2**20
            first_layer = "cache" if need <= cache_mb else "recompute"
        if first_layer not in ("cache", "recompute"):
            raise ValueError(f"first_layer must be 'auto', 'cache' or 'recompute', got {first_layer!r}")
        self.first_layer = first_layer
        self.rows = RowSet(self.canonical["means"], self.canonical["features"], self._first_terms())
        self.threads = max(1, int(threads)) if self.device.type == "cpu" else 1
        if kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
        fused = {k for k, n in self.nets.items() if n.config.activation == "relu" and n.config.depth > 1}
        self.kernel = self._pick_kernel(kernel) if fused else "aten"  # oneDNN is only used for ReLU networks
        # rows per chunk: oneDNN measured best at 2048, torch.mm at 1024 (two blocks in a 2 MB L2); GPUs take more
        default = 65536 if self.device.type != "cpu" else 2048 if self.kernel == "onednn" else 1024
        self.chunk = int(chunk) if chunk else default
        packs = {k: _Chain.pack(n, self.chunk) if self.kernel == "onednn" and k in fused else None
                 for k, n in self.nets.items()}
        self._lanes = []
        for i in range(self.threads):
            chains = {k: _Chain(n, self.chunk, self.device, packs[k]) for k, n in self.nets.items()}
            width = max(c.scratch_width for c in chains.values())
            self._lanes.append(_Lane(i, chains, torch.empty(self.chunk, self.layout.width, device=self.device),
                                     _Scratch(self.chunk, width, self.device)))
        # OpenMP's thread count is per thread and a new thread starts with the default (all cores): without the
        # initializer each lane's GEMM forks its own team, lanes x cores threads on the cores (~20 % slower)
        self._pool = ThreadPoolExecutor(self.threads - 1, "fastpose", initializer=torch.set_num_threads,
                                        initargs=(1,)) if self.threads > 1 else None
        self._enc_key = {key: _encoding_key(net) for key, net in self.nets.items()}
        chains = self._lanes[0].chains.values()
        self.flops_per_gaussian = sum(c.flops_per_row for c in chains)
        if first_layer == "recompute":
            self.flops_per_gaussian += sum(2 * c.first_weight.numel() for c in chains)
        self._soa = _attribute_major(self.canonical)
        small = [(k, self.layout.blocks[k]) for k in SMALL_BLOCKS if k in self.layout.blocks]
        self._small: dict[str, tuple[int, int]] = {}
        cols, o = [], 0
        for key, (c, w) in small:
            self._small[key] = (o, w)
            cols += range(c, c + w)
            o += w
        contiguous = cols == list(range(cols[0], cols[0] + len(cols))) if cols else False
        self._small_cols: slice | torch.Tensor = slice(cols[0], cols[0] + len(cols)) if contiguous else \
            torch.tensor(cols, dtype=torch.int64, device=self.device)

    def _pick_kernel(self, kernel: str) -> str:
        usable = self.device.type == "cpu" and onednn_available()
        if kernel == "onednn" and not usable:
            raise ValueError("kernel 'onednn': this torch build or device has no usable oneDNN linear")
        # "auto" takes it only where it was measured (x86-64); elsewhere on request
        measured = platform.machine().lower() in ("x86_64", "amd64")
        return "onednn" if usable and (kernel == "onednn" or (kernel == "auto" and measured)) else "aten"

    def _first_terms(self) -> dict[str, torch.Tensor] | None:
        if self.first_layer != "cache":
            return None
        c = self.canonical
        if self.device.type != "cpu":
            return {k: n.precompute(c["means"], c["features"]) for k, n in self.nets.items()}
        cache = self.avatar._first_layer  # share Avatar's cache: one copy of N x hidden per network
        for key, net in self.nets.items():
            if key not in cache:
                cache[key] = net.precompute(c["means"], c["features"])
        return {key: cache[key] for key in self.nets}

    @staticmethod
    def supported(avatar: Avatar) -> bool:
        """True when the avatar's networks fit this path (dynamics without skip layers)."""
        return avatar.dynamics is not None and not any(n.config.skips for n in avatar.dynamics.networks().values())

    @property
    def cache_bytes(self) -> int:
        """Bytes held by the first-layer cache (0 when recomputed per chunk)."""
        return 0 if self.rows.first is None else sum(t.numel() * 4 for t in self.rows.first.values())

    # -- offsets ------------------------------------------------------------------------------------------
    @torch.no_grad()
    def code_terms(self, z: np.ndarray) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """Per network: the code's part of layer 0 and layer 0's bias plus it."""
        if self.avatar.version != self.version:
            raise RuntimeError("the avatar was edited after this FastPoser was built (invalidate_caches); "
                               "build a new one")
        zt = torch.from_numpy(self.avatar.check_code(z)).to(self.device)
        terms = {}
        for key, net in self.nets.items():
            t = net.code_term(zt)
            terms[key] = (t, net.layers[0].bias.detach() + t)
        return terms

    def _chunk_offsets(self, lane: _Lane, rows: RowSet, terms: dict, s: int, e: int,
                       cancel: Callable[[], bool] | None = None,
                       into: torch.Tensor | None = None) -> torch.Tensor | None:
        """Combined offsets (e - s, width) of rows s:e of `rows`, in `into` (on the poser's device) or else the
        lane's chunk buffer (None when `cancel()` turned true between two networks)."""
        out_rows = lane.offsets[: e - s] if into is None else into
        encoded: dict[tuple, torch.Tensor] = {}
        for i, (key, col, width) in enumerate(self.layout.nets):
            if i and cancel is not None and cancel():
                return None
            t0 = time.perf_counter()
            net = self.nets[key]
            first = enc = None
            if rows.first is not None:
                first = rows.first[key][s:e]
            else:  # networks with the same input normalisation share one encoding per chunk
                ident = self._enc_key[key]
                if ident not in encoded:
                    encoded[ident] = net.encode_gaussian(rows.means[s:e], rows.features[s:e])
                enc = encoded[ident]
            lane.chains[key].run(first, enc, *terms[key], lane.scratch, out_rows[:, col : col + width])
            lane.busy[key] = lane.busy.get(key, 0.0) + time.perf_counter() - t0
        return out_rows

    def _parallel(self, tasks: list[int], body: Callable[[_Lane, int], bool | None],
                  cancel: Callable[[], bool] | None = None, timings: dict[str, float] | None = None) -> bool:
        """Run `body(lane, task)` for every task on all lanes (each lane pulls the next task); False if
        `cancel()` turned true before some task or a body returned False. Per-stage busy times, divided by the
        lanes, go to `timings`."""
        pending = iter(tasks)
        lock = threading.Lock()
        stop = [False]

        def work(lane: _Lane) -> None:
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
        return list(range(0, n, self._chunk_for(n)))

    def _chunk_for(self, n: int) -> int:
        """Rows per task: the chunk size, smaller for small row sets so that every lane gets work."""
        return max(1, min(self.chunk, -(-n // self.threads)))

    def subset(self, index: np.ndarray) -> RowSet:
        """The rows `index` with their first-layer terms cached, for repeated `offsets(..., rows=)` calls."""
        idx = torch.from_numpy(np.asarray(index, np.int64)).to(self.device)
        mu, f = self.rows.means.index_select(0, idx), self.rows.features.index_select(0, idx)
        return RowSet(mu, f, {k: n.precompute(mu, f) for k, n in self.nets.items()}, np.asarray(index, np.int64))

    @torch.no_grad()
    def offsets(self, z: np.ndarray, out: torch.Tensor | None = None, rows: RowSet | None = None,
                timings: dict[str, float] | None = None,
                cancel: Callable[[], bool] | None = None) -> torch.Tensor | None:
        """Combined offsets (N, or the rows of a `subset`, width) at code z, on the CPU (None if cancelled)."""
        rows = self.rows if rows is None else rows
        if out is None:
            out = torch.empty(rows.n, self.layout.width)
        terms = self.code_terms(z)
        step = self._chunk_for(rows.n)

        direct = out.device == self.device  # the networks write straight into `out`, else through the lane

        def body(lane: _Lane, s: int) -> bool:
            e = min(rows.n, s + step)
            chunk = self._chunk_offsets(lane, rows, terms, s, e, cancel, out[s:e] if direct else None)
            if chunk is not None and not direct:
                out[s:e].copy_(chunk)
            return chunk is not None

        return out if self._parallel(self._starts(rows.n), body, cancel, timings) else None

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
        step = self._chunk_for(self.n)

        def body(lane: _Lane, s: int) -> bool:
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

        return self._parallel(self._starts(self.n), body, cancel, timings)

    @torch.no_grad()
    def apply_into(self, offsets: torch.Tensor, dest: dict[str, np.ndarray], chunk: int = 8192) -> None:
        """Posed cloud from precomputed combined offsets (N, width) on the CPU, written into `dest`."""
        out = {k: torch.from_numpy(v) for k, v in dest.items() if v is not None}

        def body(lane: _Lane, s: int) -> None:
            e = min(self.n, s + chunk)
            self.apply_rows(offsets[s:e].to(self.device), s, e, out)

        self._parallel(list(range(0, self.n, chunk)), body)

    def apply_rows(self, rows: torch.Tensor, s: int, e: int, out: dict[str, torch.Tensor]) -> None:
        """Apply combined offsets of rows s:e to the canonical cloud and write activated values into `out`.

        The same operations as `apply_offsets` followed by `to_posed_gaussians`; the small blocks (position,
        rotation, scale, opacity) are first gathered into attribute-major rows so every operation runs on
        contiguous vectors.
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
            return None if hit is None else small[hit[0] : hit[0] + hit[1]]

        d, f = block("G.position"), block("F.position")
        d = f if d is None else (d if f is None else d + f)
        means = soa["means"][:, s:e]
        out["means"][s:e].copy_((means if d is None else ATTRIBUTE_OPS["position"].apply(means, d)).t())
        q = soa["unit_quats"][:, s:e]
        if (d := block("G.rotation")) is not None:
            q = _compose(q, d) if self.rotation_op == "compose" else _unit(q + d)
        out["quats"][s:e].copy_(_unit(q).t())
        log_s = soa["log_scales"][:, s:e]
        if (d := block("G.scale")) is not None:
            log_s = ATTRIBUTE_OPS["scale"].apply(log_s, d)
        out["scales"][s:e].copy_(torch.exp(log_s).t())
        op = soa["opacity_logits"][s:e]
        if (d := block("G.opacity")) is not None:
            op = ATTRIBUTE_OPS["opacity"].apply(op, d[0])
        out["opacities"][s:e].copy_(torch.sigmoid(op))
        self._add_wide(rows, s, e, "sh", out["sh"], lay.blocks.get("G.sh"))
        if "latent" in out and soa.get("latent") is not None:
            self._add_wide(rows, s, e, "latent", out["latent"], lay.blocks.get("G.latent"))

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


def _encoding_key(net: ConditionedMLP) -> tuple:
    """Networks with equal keys encode (mu, f) identically."""
    c = net.config
    return (c.pos_freqs, c.feature_dim, tuple(net.input_shift[: 3 + c.feature_dim].tolist()),
            tuple(net.input_scale[: 3 + c.feature_dim].tolist()))


def _unit(q: torch.Tensor) -> torch.Tensor:
    """Rows (4, m) of quaternions, each column scaled to unit length (as `_normalize`, clamped at 1e-12)."""
    n2 = q[0] * q[0]
    for i in range(1, q.shape[0]):
        n2.addcmul_(q[i], q[i])
    return q / n2.sqrt_().clamp_min_(1e-12)


def _compose(c_unit: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """ATTRIBUTE_OPS["rotation"] on attribute-major rows: normalize(normalize(1 + d) * c_unit)."""
    r = d.clone()
    r[0] += 1.0
    return _unit(quat_multiply(_unit(r).t(), c_unit.t()).t())


def _attribute_major(canonical: dict[str, torch.Tensor | None]) -> dict[str, torch.Tensor]:
    """Canonical attributes with the small ones transposed to (width, N), the wide ones flattened (N, width)."""
    soa = {k: canonical[k].t().contiguous() for k in ("means", "log_scales")}
    soa["unit_quats"] = _unit(canonical["quats"].t().contiguous())
    soa["opacity_logits"] = canonical["opacity_logits"].contiguous()
    soa["sh"] = canonical["sh"].reshape(canonical["sh"].shape[0], -1)
    if canonical.get("latent") is not None:
        soa["latent"] = canonical["latent"]
    return soa


def posed_buffers(n: int, sh_coeffs: int, latent_dim: int) -> dict[str, np.ndarray]:
    """Freshly allocated float32 output arrays for `FastPoser.pose_into`."""
    shapes = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "sh": (n, sh_coeffs, 3)}
    if latent_dim:
        shapes["latent"] = (n, latent_dim)
    return {k: np.empty(s, np.float32) for k, s in shapes.items()}
