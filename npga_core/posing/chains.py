"""One network of `FastPoser` after its per-Gaussian first-layer term: the layers at the matrix-multiply limit.

The per-Gaussian part of layer 0 is cached (or recomputed from the encoded per-Gaussian inputs); the per-frame
part is one vector per frame (`code_term`). A skip layer's weight is split the same way: its hidden columns
multiply the activations, its per-frame columns become a constant added to the bias once per frame, and its
per-Gaussian columns multiply the chunk's encoded per-Gaussian inputs.

The hidden layers of ReLU and leaky-ReLU networks run on oneDNN's linear with a fused bias + activation epilogue
and weights packed once into its blocked layout (torch's own `mkldnn` operators, the ones torch.compile uses on the
CPU); without them (another build, a GPU) they run on `torch.mm`.

In bfloat16 (`low`, oneDNN only: AMX or AVX-512 BF16, `precision.py`) the weights and activations are bfloat16
and oneDNN accumulates in float32. Layer 0 is then one product of the encoded per-Gaussian inputs, stored once as
two bfloat16 halves (hi + lo, so the inputs keep about 16 bits: `low_inputs`), with the frame's bias and the
activation fused; the output layer's bias is added in float32 while the result is copied into the offsets.
"""

from __future__ import annotations

import functools

import torch

from npga_core.model.networks import ConditionedMLP


def low_inputs(encoded: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """Encoded per-Gaussian inputs (m, k) as bfloat16 [hi, lo] (m, 2k) with hi + lo close to the float32 values
    (written into `out` when given)."""
    m, k = encoded.shape
    out = torch.empty(m, 2 * k, dtype=torch.bfloat16) if out is None else out
    hi = out[:, :k]
    hi.copy_(encoded)
    out[:, k:].copy_(encoded - hi.float())
    return out


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


#: Hidden activations oneDNN fuses into the linear (name -> its scalars from the config).
FUSED = ("relu", "leaky_relu")


class Scratch:
    """Two activation buffers of one lane, shared by all its chains: each layer reads one and writes the other,
    so a chunk's working set stays two (chunk, width) blocks that fit in the core's L2 (one buffer per layer,
    as before, walked through 5 MB per network at 1024 rows and was about 10 % slower)."""

    def __init__(self, chunk: int, width: int, device: torch.device):
        self.flat = [torch.empty(chunk * width, device=device) for _ in range(2)]
        self.low = torch.empty(chunk * width, device=device, dtype=torch.bfloat16)

    def view(self, i: int, m: int, width: int) -> torch.Tensor:
        """Buffer i (0 or 1) as a contiguous (m, width) block."""
        return self.flat[i][: m * width].view(m, width)

    def view_low(self, m: int, width: int) -> torch.Tensor:
        """The bfloat16 buffer (layer 0's activations on the bfloat16 path) as a contiguous (m, width) block."""
        return self.low[: m * width].view(m, width)


class Chain:
    """One network after its per-Gaussian first-layer term; activations go through the lane's `Scratch`."""

    def __init__(self, net: ConditionedMLP, chunk: int, device: torch.device,
                 packed: list[torch.Tensor | None] | None = None, low: bool = False):
        cfg = net.config
        self.net = net
        self.skips = set(cfg.skips)
        wg, _, _ = net.split_weight(0)
        self.first_weight = wg.t().contiguous()
        self.weights = [layer.weight.detach().t().contiguous() for layer in net.layers]  # type: ignore[operator]
        self.biases = [layer.bias.detach() for layer in net.layers]  # type: ignore[operator]
        # skip layers: hidden columns (transposed, for h @ W), per-Gaussian and per-frame input columns
        self.skip_parts = {}
        for i in self.skips:
            g, c, hid = net.split_weight(i)
            assert hid is not None
            self.skip_parts[i] = (hid.t().contiguous(), g.t().contiguous(), c)
        self.widths = [o for o, _ in cfg.layer_shapes()]
        self.out_flat = torch.empty(chunk * cfg.out_dim, device=device)
        self.narrow = cfg.out_dim <= 8 and device.type == "cpu" and cfg.depth - 1 not in self.skips
        self.last_rows = net.layers[-1].weight.detach().contiguous()  # type: ignore[operator]  # (out, in), for the transposed product
        self.relu = cfg.activation == "relu"
        self.kind = cfg.activation
        self.slope = cfg.slope
        self.act = net._act
        self.out_act = cfg.output_activation
        self.packed = packed  # oneDNN weights of layers 1.. (None for the narrow output), or None: torch.mm
        self.low = bool(low and packed is not None)  # bfloat16 after layer 0 (packed holds bfloat16 weights)
        if self.low:
            self.first_low = torch.ops.mkldnn._reorder_linear_weight(
                torch.cat([wg, wg], dim=1).to(torch.bfloat16).contiguous(), chunk)  # for [hi, lo] inputs
            self.biases_low = [b.to(torch.bfloat16) for b in self.biases]
            self.last_rows_low = self.last_rows.to(torch.bfloat16)
            self.skip_low = {i: hid.to(torch.bfloat16) for i, (hid, _, _) in self.skip_parts.items()}
        plain = self.relu and not self.skips
        self.folded = self._fold() if plain and packed is None and len(self.weights) > 2 else None
        self.flops_per_row = sum(2 * o * i for o, i in cfg.layer_shapes()[1:])

    def _fold(self) -> list[torch.Tensor]:
        """-B_i of hidden layers 1..depth-2, then the output layer's bias b_out + B_last W_out (see `run`)."""
        consts, shift = [], torch.zeros_like(self.biases[0])
        for i in range(1, len(self.weights)):
            shift = torch.addmv(self.biases[i], self.weights[i].t(), shift)
            consts.append(shift.neg() if i < len(self.weights) - 1 else shift)
        return consts

    @staticmethod
    def pack(net: ConditionedMLP, chunk: int, dtype: torch.dtype = torch.float32) -> list[torch.Tensor | None]:
        """oneDNN's blocked copies of the weights of layers 1.. in `dtype` (read-only, shared by all lanes; a skip
        layer's hidden columns only); None for a narrow output layer, which stays a transposed `torch.mm`."""
        layers = net.layers[1:]
        packed: list[torch.Tensor | None] = []
        for i, layer in enumerate(layers, start=1):
            w = layer.weight.detach()  # type: ignore[operator]
            if i in net.config.skips:
                w = w[:, : net.config.hidden]
            narrow = i == len(layers) and net.config.out_dim <= 8 and i not in net.config.skips
            w = w.to(dtype).contiguous()
            packed.append(None if narrow else torch.ops.mkldnn._reorder_linear_weight(w, chunk))
        return packed

    @property
    def scratch_width(self) -> int:
        """Widest hidden layer: the scratch buffers' width."""
        return max(self.widths[:-1], default=1)

    def frame_constants(self, zc: torch.Tensor) -> dict[int, torch.Tensor]:
        """Per skip layer: its bias plus its per-frame input columns times the encoded frame vector `zc`."""
        return {i: self.biases[i] + c @ zc for i, (_, _, c) in self.skip_parts.items()}

    def _activate(self, h: torch.Tensor) -> torch.Tensor:
        if self.relu:
            return h.clamp_min_(0.0)
        if self.kind == "leaky_relu":
            return torch.nn.functional.leaky_relu_(h, self.slope)
        h.copy_(self.act(h))
        return h

    def run(self, first_rows: torch.Tensor | None, encoded: torch.Tensor | None, code_term: torch.Tensor,
            first_bias: torch.Tensor, scratch: Scratch, dest: torch.Tensor,
            skip_consts: dict[int, torch.Tensor] | None = None, low_rows: torch.Tensor | None = None) -> None:
        """Write the outputs of m rows into `dest` (m, out), from their cached first-layer term or their
        encoded per-Gaussian inputs (`encoded`, also needed by skip layers). `code_term` is the frame's part of
        layer 0; `first_bias` is layer 0's bias plus it; `skip_consts` the skip layers' `frame_constants`.

        In plain ReLU chains layers 1 and up add no bias to their hidden blocks: with s_i = a_(i-1) W_i and
        a_i = relu(s_i + b_i) = max(s_i, -b_i) + b_i, each keeps only g_i = max(s_i, -B_i) (one pass instead of
        a bias copy and a clamp) and the B_i it leaves out goes into the next layer's bias,
        B_(i+1) = b_(i+1) + B_i W_(i+1) (constants of the network, `_fold`). Layer 0 keeps its bias: folding
        the code term too made the rounding error 5x larger, this way it stays within 1.5x of the plain forward.
        The output layer's bias is added while the result is copied into `dest`; a narrow output (F's 3
        columns) is computed transposed, (out, m) = W h^T, which MKL does 4x faster than h W at that width.

        With oneDNN weights (`packed`) each hidden layer is one call that adds the bias and applies the
        activation while the block is still in registers: no folding, the same operation order as the plain
        forward. A skip layer adds its per-Gaussian and per-frame input terms before its activation.

        `low_rows`: on the bfloat16 path, the chunk's `low_inputs` (layer 0 is then one fused product).
        """
        if low_rows is not None and self.low and len(self.weights) > 1:
            attr = self.kind if self.kind in FUSED else "none"
            h = torch.ops.mkldnn._linear_pointwise(low_rows, self.first_low, first_bias.to(torch.bfloat16), attr,
                                                   [self.slope] if attr == "leaky_relu" else [], "")
            if attr == "none":
                h = self._activate(h)
            for i in range(1, len(self.weights)):
                last = i == len(self.weights) - 1
                h = self._layer_low(i, h, dest, self.packed[i - 1], encoded, skip_consts, last)  # type: ignore
            self._output(dest)
            return
        source = first_rows if first_rows is not None else encoded
        assert source is not None
        m = source.shape[0]
        depth = len(self.weights)
        h = scratch.view(0, m, self.widths[0]) if depth > 1 else dest
        if self.low and depth > 1:
            if first_rows is not None:  # rounded to bfloat16 as it is written
                h = torch.add(first_rows, code_term, out=scratch.view_low(m, self.widths[0]))
            else:
                torch.addmm(first_bias, source, self.first_weight, out=h)
                h = scratch.view_low(m, self.widths[0]).copy_(self._activate(h))
        elif first_rows is not None:
            torch.add(first_rows, code_term, out=h)
        else:
            torch.addmm(first_bias, source, self.first_weight, out=h)
        if depth > 1:
            h = self._activate(h)
            for i in range(1, depth):
                last = i == depth - 1
                target = dest if last else scratch.view(i % 2, m, self.widths[i])
                h = self._layer(i, h, target, encoded, skip_consts, last)
        self._output(dest)

    def _output(self, dest: torch.Tensor) -> None:
        """The output activation, in place."""
        if self.out_act == "tanh":
            dest.tanh_()
        elif (act := self.net.output_act) is not None:
            dest.copy_(act(dest))

    def _layer(self, i: int, h: torch.Tensor, target: torch.Tensor, encoded: torch.Tensor | None,
               skip_consts: dict[int, torch.Tensor] | None, last: bool) -> torch.Tensor:
        """Layer i on activations h, activated unless it is the last layer; the result is in `target` when it is
        the last layer (else possibly a block oneDNN returned)."""
        packed = None if self.packed is None else self.packed[i - 1]
        if self.low:
            return self._layer_low(i, h, target, packed, encoded, skip_consts, last)
        if i in self.skips:
            hid, g, _ = self.skip_parts[i]
            assert encoded is not None and skip_consts is not None
            if packed is not None:
                out = torch.ops.mkldnn._linear_pointwise(h, packed, skip_consts[i], "none", [], "")
            else:
                out = torch.addmm(skip_consts[i], h, hid, out=target)
            out.addmm_(encoded, g)
        elif packed is not None:
            fuse = not last and self.kind in FUSED
            attr = self.kind if fuse else "none"
            out = torch.ops.mkldnn._linear_pointwise(h, packed, self.biases[i], attr,
                                                     [self.slope] if attr == "leaky_relu" else [], "")
            if fuse:
                return out
        elif last:
            return self._last(h, target)
        elif self.folded is not None:
            torch.mm(h, self.weights[i], out=target)
            return torch.maximum(target, self.folded[i - 1], out=target)
        else:
            out = torch.addmm(self.biases[i], h, self.weights[i], out=target)
        if last:
            if out is not target:
                target.copy_(out)
            return target
        return self._activate(out)

    def _layer_low(self, i: int, h: torch.Tensor, target: torch.Tensor, packed: torch.Tensor | None,
                   encoded: torch.Tensor | None, skip_consts: dict[int, torch.Tensor] | None,
                   last: bool) -> torch.Tensor:
        """`_layer` on bfloat16 activations h: a bfloat16 block back, or the float32 `target` for the last layer."""
        if i in self.skips:
            hid, g, _ = self.skip_parts[i]
            assert encoded is not None and skip_consts is not None
            out = torch.mm(h, self.skip_low[i]).float() if packed is None else \
                torch.ops.mkldnn._linear_pointwise(h, packed, None, "none", [], "").float()
            out.add_(skip_consts[i]).addmm_(encoded, g)  # per-frame and per-Gaussian terms in float32
            if last:
                return target.copy_(out)
            return self._activate(out).to(torch.bfloat16)
        if packed is None:  # a narrow output layer, transposed: (out, m) = W h^T, bias added in float32
            res = torch.mm(self.last_rows_low, h.t())
            return torch.add(res.t(), self.biases[-1], out=target)
        if last:
            out = torch.ops.mkldnn._linear_pointwise(h, packed, None, "none", [], "")
            return torch.add(out, self.biases[i], out=target)
        fuse = self.kind in FUSED
        attr = self.kind if fuse else "none"
        out = torch.ops.mkldnn._linear_pointwise(h, packed, self.biases_low[i], attr,
                                                 [self.slope] if attr == "leaky_relu" else [], "")
        return out if fuse else self._activate(out)

    def _last(self, h: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """The output layer by torch.mm (transposed for a narrow output), its bias added into `target`."""
        m = h.shape[0]
        bias = self.biases[-1] if self.folded is None else self.folded[-1]
        width = self.widths[-1]
        if self.narrow:
            res = self.out_flat[: width * m].view(width, m)
            torch.mm(self.last_rows, h.t(), out=res)
            torch.add(res.t(), bias, out=target)
        else:
            res = self.out_flat[: width * m].view(m, width)
            torch.mm(h, self.weights[-1], out=res)
            torch.add(res, bias, out=target)
        return target
