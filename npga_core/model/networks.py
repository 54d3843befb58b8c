"""One dynamics network, described by data: its inputs, layers, activations, skips and where its outputs go.

A network (`MLPConfig`) is evaluated per Gaussian. Its raw input is the concatenation, in the declared order,
of some of: the canonical position mu (3), the per-Gaussian features f (F), the expression code (D_e) and a
second per-frame condition (D_c, e.g. Gaussian-Head-Avatar's head pose). Each is normalised as
``(x - input_shift) * input_scale`` and position and condition may be expanded by a positional encoding
(`ENCODINGS`). Then `depth` linear layers with the hidden activation between them (ReLU, leaky ReLU with its
slope, ...), an optional output activation (tanh), and skip layers that re-append the encoded input after the
hidden vector (``[h, x]``). The output columns are routed to attributes (`Route`): a column range, the
attribute's first column it lands on, and a scale.

NPGA's F and G are one case: inputs (mu, f, z), ReLU, no skips, no output activation, routes of scale 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

import msgspec
import torch
from msgspec import Meta
from torch import nn

from npga_core.errors import brief
from npga_core.schema import decode

MAX_POS_FREQS = 20
MAX_WIDTH = 65536

ACTIVATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": torch.relu,
    "silu": nn.functional.silu,
    "gelu": nn.functional.gelu,
    "softplus": nn.functional.softplus,
    "tanh": torch.tanh,
    "elu": nn.functional.elu,
    "leaky_relu": nn.functional.leaky_relu,
    "sigmoid": torch.sigmoid,
}

#: The attributes an offset can act on, in canonical order.
ATTRIBUTES: tuple[str, ...] = ("position", "rotation", "scale", "opacity", "sh", "latent")

#: Input kinds: per-Gaussian ones (position, features) and per-frame ones (code, condition).
INPUT_KINDS: tuple[str, ...] = ("position", "features", "code", "condition")
PER_GAUSSIAN_INPUTS = frozenset({"position", "features"})

#: Positional encodings: [x, sin(w_0 x), cos(w_0 x), ..., sin(w_(L-1) x), cos(w_(L-1) x)] with w_k = 2^k pi
#: ("nerf", NPGA's files of version 1) or w_k = 2^k (as Gaussian-Head-Avatar's `get_embedder`); "none" is x.
ENCODINGS = {"none": 0.0, "nerf": math.pi, "gha": 1.0}


# The header's description of a network, declared (msgspec; `MLPConfig.from_json` checks the rest).
_Int = Annotated[int, Meta(ge=-(2**31), le=2**31 - 1)]
_Float = Annotated[float, Meta(ge=-1e6, le=1e6)]
_Str = Annotated[str, Meta(max_length=64)]


class _InputJson(msgspec.Struct):
    kind: _Str
    encoding: _Str = "none"
    freqs: _Int = 0


class _RouteJson(msgspec.Struct):
    attribute: _Str
    start: _Int = msgspec.field(name="from")
    width: _Int
    to: _Int = 0
    scale: _Float = 1.0


class _MLPJson(msgspec.Struct):
    feature_dim: _Int
    code_dim: _Int
    outputs: list[tuple[_Str, _Int]] | None = None
    hidden: _Int = 256
    depth: _Int = 6
    activation: _Str = "relu"
    pos_freqs: _Int = 0
    skips: Annotated[list[_Int], Meta(max_length=256)] = []
    inputs: Annotated[list[_InputJson], Meta(max_length=16)] | None = None
    condition_dim: _Int = 0
    slope: _Float = 0.01
    output_activation: _Str = "none"
    routes: Annotated[list[_RouteJson], Meta(max_length=256)] | None = None
    out_dim: _Int | None = None
    blend: _Str | None = None


def activation(name: str, slope: float = 0.01) -> Callable[[torch.Tensor], torch.Tensor]:
    """The activation function `name` (leaky ReLU with `slope`)."""
    if name == "leaky_relu":
        return lambda x: nn.functional.leaky_relu(x, slope)
    return ACTIVATIONS[name]


@dataclass(frozen=True)
class InputSpec:
    """One input of a network: its kind and, for position and condition, a positional encoding."""

    kind: str
    encoding: str = "none"
    freqs: int = 0

    def encoded_width(self, raw: int) -> int:
        return raw * (1 + 2 * self.freqs) if self.encoding != "none" else raw

    def to_json(self) -> dict:
        d: dict = {"kind": self.kind}
        if self.encoding != "none":
            d.update(encoding=self.encoding, freqs=self.freqs)
        return d

    @staticmethod
    def from_json(d: _InputJson) -> InputSpec:
        """The checked input of a decoded description."""
        if d.kind not in INPUT_KINDS:
            raise ValueError(f"unknown input kind {brief(d.kind)} (known: {', '.join(INPUT_KINDS)})")
        if d.encoding not in ENCODINGS:
            raise ValueError(f"unknown encoding {brief(d.encoding)} (known: {', '.join(ENCODINGS)})")
        if d.encoding != "none" and d.kind not in ("position", "condition"):
            raise ValueError(f"a positional encoding applies to position and condition, not {d.kind}")
        if not 0 <= d.freqs <= MAX_POS_FREQS or (d.encoding == "none" and d.freqs):
            raise ValueError(f"freqs {d.freqs} outside 0..{MAX_POS_FREQS} (or given without an encoding)")
        return InputSpec(d.kind, d.encoding, d.freqs)


def encode(x: torch.Tensor, spec: InputSpec) -> torch.Tensor:
    """The positional encoding of `x` (..., w) by `spec` (x itself without one)."""
    if spec.encoding == "none":
        return x
    base = ENCODINGS[spec.encoding]
    parts = [x]
    for k in range(spec.freqs):
        w = (2.0**k) * base
        parts += [torch.sin(w * x), torch.cos(w * x)]
    return torch.cat(parts, dim=-1)


@dataclass(frozen=True)
class Route:
    """Output columns [start, start + width) of a network, times `scale`, added to columns [to, to + width) of
    `attribute`'s offset."""

    attribute: str
    start: int
    width: int
    to: int = 0
    scale: float = 1.0

    def to_json(self) -> dict:
        return {"attribute": self.attribute, "from": self.start, "width": self.width, "to": self.to,
                "scale": self.scale}

    @staticmethod
    def from_json(d: _RouteJson) -> Route:
        """The checked route of a decoded description."""
        if d.attribute not in ATTRIBUTES:
            raise ValueError(f"unknown attribute {brief(d.attribute)} (known: {', '.join(ATTRIBUTES)})")
        return Route(d.attribute, d.start, d.width, d.to, d.scale)


def _v1_inputs(pos_freqs: int) -> list[InputSpec]:
    return [InputSpec("position", "nerf" if pos_freqs else "none", pos_freqs), InputSpec("features"),
            InputSpec("code")]


@dataclass
class MLPConfig:
    """Architecture of one network, as stored in the checkpoint header (see the module docstring).

    `outputs` (named blocks of columns, version 1) is kept for NPGA's F and G; `routes` is derived from it
    when not given. `code_dim` is the width of the expression-code input, `condition_dim` of the condition.
    """

    feature_dim: int
    code_dim: int
    outputs: list[tuple[str, int]] = field(default_factory=list)
    hidden: int = 256
    depth: int = 6
    activation: str = "relu"
    pos_freqs: int = 0
    skips: list[int] = field(default_factory=list)
    inputs: list[InputSpec] | None = None
    condition_dim: int = 0
    slope: float = 0.01
    output_activation: str = "none"
    routes: list[Route] | None = None
    out_width: int | None = None
    blend: str | None = None  # name of the per-Gaussian weight this network's outputs are multiplied by

    def __post_init__(self) -> None:
        if self.inputs is None:
            self.inputs = _v1_inputs(self.pos_freqs)
        if self.routes is None:
            routes, col = [], 0
            for name, width in self.outputs:
                routes.append(Route(name, col, width))
                col += width
            self.routes = routes
        if self.out_width is None:
            self.out_width = sum(w for _, w in self.outputs) if self.outputs else \
                max((r.start + r.width for r in self.routes), default=0)

    # -- widths ----------------------------------------------------------------------------------------
    def raw_width(self, spec: InputSpec) -> int:
        return {"position": 3, "features": self.feature_dim, "code": self.code_dim,
                "condition": self.condition_dim}[spec.kind]

    @property
    def specs(self) -> list[InputSpec]:
        assert self.inputs is not None
        return self.inputs

    @property
    def raw_input_dim(self) -> int:
        return sum(self.raw_width(s) for s in self.specs)

    @property
    def encoded_input_dim(self) -> int:
        return sum(s.encoded_width(self.raw_width(s)) for s in self.specs)

    @property
    def mu_encoded_dim(self) -> int:
        return sum(s.encoded_width(3) for s in self.specs if s.kind == "position")

    @property
    def gaussian_encoded_dim(self) -> int:
        """Width of the per-Gaussian part of the encoded input."""
        return sum(s.encoded_width(self.raw_width(s)) for s in self.specs if s.kind in PER_GAUSSIAN_INPUTS)

    @property
    def out_dim(self) -> int:
        assert self.out_width is not None
        return self.out_width

    def encoded_columns(self) -> tuple[list[int], list[int]]:
        """Columns of the encoded input that are per Gaussian, and those that are per frame."""
        g: list[int] = []
        c: list[int] = []
        col = 0
        for s in self.specs:
            w = s.encoded_width(self.raw_width(s))
            (g if s.kind in PER_GAUSSIAN_INPUTS else c).extend(range(col, col + w))
            col += w
        return g, c

    def layer_shapes(self) -> list[tuple[int, int]]:
        """(out, in) of each linear layer's weight."""
        shapes = []
        for i in range(self.depth):
            fan_in = self.encoded_input_dim if i == 0 else self.hidden
            if i in self.skips:
                fan_in += self.encoded_input_dim
            fan_out = self.out_dim if i == self.depth - 1 else self.hidden
            shapes.append((fan_out, fan_in))
        return shapes

    def flops_per_gaussian(self) -> int:
        """Multiply-adds x2 of one forward pass per Gaussian (all layers)."""
        return sum(2 * o * i for o, i in self.layer_shapes())

    @property
    def simple(self) -> bool:
        """Version 1 expressible: inputs (mu, f, z), no condition, output blocks of scale 1, no blend."""
        return (self.specs == _v1_inputs(self.pos_freqs) and self.condition_dim == 0 and bool(self.outputs)
                and self.output_activation == "none" and self.blend is None and self.slope == 0.01)

    def validate(self) -> None:
        """Raise ValueError if the configuration is inconsistent."""
        if self.depth < 1:
            raise ValueError(f"depth must be >= 1, got {self.depth}")
        for name in ("hidden", "feature_dim", "code_dim", "condition_dim", "pos_freqs", "out_dim"):
            v = getattr(self, name)
            if not 0 <= v <= MAX_WIDTH:
                raise ValueError(f"{name} {v} outside 0..{MAX_WIDTH}")
        if self.hidden < 1 or self.depth > 64:
            raise ValueError("hidden must be >= 1 and depth at most 64")
        if self.pos_freqs > MAX_POS_FREQS:
            raise ValueError(f"pos_freqs {self.pos_freqs} exceeds {MAX_POS_FREQS} (float32 sin/cos lose all meaning)")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {brief(self.activation)} (known: {', '.join(ACTIVATIONS)})")
        if self.output_activation != "none" and self.output_activation not in ACTIVATIONS:
            raise ValueError(f"unknown output activation {brief(self.output_activation)} (none or an activation)")
        if not 0.0 <= self.slope <= 1.0:
            raise ValueError(f"leaky ReLU slope {self.slope} outside 0..1")
        for s in self.skips:
            if not 1 <= s < self.depth:
                raise ValueError(f"skip layer {s} outside 1..{self.depth - 1}")
        kinds = [s.kind for s in self.specs]
        if len(set(kinds)) != len(kinds) or not kinds:
            raise ValueError(f"inputs {kinds} must be distinct and not empty")
        if "condition" in kinds and self.condition_dim == 0:
            raise ValueError("a condition input needs condition_dim > 0")
        self._validate_outputs()

    def _validate_outputs(self) -> None:
        """The output blocks and the routes of their columns."""
        seen = set()
        for name, width in self.outputs:
            if name not in ATTRIBUTES:
                raise ValueError(f"unknown output block {brief(name)} (known: {', '.join(ATTRIBUTES)})")
            if name in seen:
                raise ValueError(f"output block {brief(name)} listed twice")
            if width < 1:
                raise ValueError(f"output block {brief(name)} has width {width}")
            seen.add(name)
        if not self.routes:
            raise ValueError("no output blocks")
        for r in self.routes:
            if r.width < 1 or r.start < 0 or r.to < 0 or r.start + r.width > self.out_dim:
                raise ValueError(f"route to {r.attribute} takes columns {r.start}..{r.start + r.width}, "
                                 f"the network has {self.out_dim}")

    def to_json(self) -> dict:
        d: dict = {"feature_dim": self.feature_dim, "code_dim": self.code_dim}
        if self.simple:
            d["outputs"] = [[n, w] for n, w in self.outputs]
        d.update(hidden=self.hidden, depth=self.depth, activation=self.activation, pos_freqs=self.pos_freqs,
                 skips=list(self.skips))
        if not self.simple:
            d.update(inputs=[s.to_json() for s in self.specs], condition_dim=self.condition_dim, slope=self.slope,
                     output_activation=self.output_activation, out_dim=self.out_dim,
                     routes=[r.to_json() for r in self.routes or []], blend=self.blend)
        return d

    @staticmethod
    def from_json(d: object, where: str = "") -> MLPConfig:
        """The checked architecture of a header's description (`_MLPJson`); ValueError naming `where` and the
        field."""
        j: _MLPJson = decode(d, _MLPJson, where)
        try:
            if j.outputs is None and j.routes is None:
                raise ValueError("malformed MLP architecture: neither outputs nor routes given")
            cfg = MLPConfig(feature_dim=j.feature_dim, code_dim=j.code_dim, outputs=list(j.outputs or []),
                            hidden=j.hidden, depth=j.depth, activation=j.activation, pos_freqs=j.pos_freqs,
                            skips=list(j.skips), inputs=None if j.inputs is None else [InputSpec.from_json(s)
                                                                                      for s in j.inputs],
                            condition_dim=j.condition_dim, slope=j.slope, output_activation=j.output_activation,
                            routes=None if j.routes is None else [Route.from_json(r) for r in j.routes],
                            out_width=j.out_dim, blend=j.blend)
            cfg.validate()
        except ValueError as e:
            raise ValueError(f"{where}: {e}" if where else str(e)) from None
        return cfg


class ConditionedMLP(nn.Module):
    """One network: encoded inputs -> output columns (see the module docstring).

    `forward` is the plain reference. `precompute` + `evaluate` is the generic fast path: the per-Gaussian part
    of the first layer (bias included) is computed once; per frame only a (hidden,) vector is added.
    """

    def __init__(self, config: MLPConfig):
        super().__init__()
        config.validate()
        self.config = config
        self.layers = nn.ModuleList(nn.Linear(i, o) for o, i in config.layer_shapes())
        self.register_buffer("input_shift", torch.zeros(config.raw_input_dim))
        self.register_buffer("input_scale", torch.ones(config.raw_input_dim))
        self._act = activation(config.activation, config.slope)
        self._out_act = None if config.output_activation == "none" else activation(config.output_activation)
        g, c = config.encoded_columns()
        self._gcols = torch.tensor(g, dtype=torch.int64)
        self._ccols = torch.tensor(c, dtype=torch.int64)
        self._contiguous = g == list(range(len(g))) and c == list(range(len(g), len(g) + len(c)))

    @property
    def output_act(self) -> Callable[[torch.Tensor], torch.Tensor] | None:
        """The activation after the last layer (None for "none"), for callers that run the layers themselves."""
        return self._out_act

    # -- input conditioning -------------------------------------------------------------------------
    def _encode(self, parts: dict[str, torch.Tensor], per_gaussian: bool) -> torch.Tensor:
        """Normalised, encoded inputs of one side (per Gaussian or per frame), in declared order."""
        out, col = [], 0
        for s in self.config.specs:
            w = self.config.raw_width(s)
            if (s.kind in PER_GAUSSIAN_INPUTS) == per_gaussian:
                x = (parts[s.kind] - self.input_shift[col : col + w]) * self.input_scale[col : col + w]  # type: ignore[index]
                out.append(encode(x, s))
            col += w
        if not out:
            lead = next(iter(parts.values())).shape[:-1]
            return torch.zeros(*lead, 0)
        return torch.cat(out, dim=-1)

    def encode_gaussian(self, mu: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """Normalised, encoded per-Gaussian inputs (N, gaussian_encoded_dim)."""
        return self._encode({"position": mu, "features": f}, True)

    def encode_code(self, z: torch.Tensor) -> torch.Tensor:
        """Normalised, encoded per-frame inputs of a frame vector z = [code, condition] (..., width)."""
        c = self.config
        total = z.shape[-1]
        return self._encode({"code": z[..., : total - _cond_width(c, total)],
                             "condition": z[..., total - _cond_width(c, total):]}, False)

    def assemble(self, g: torch.Tensor, zc: torch.Tensor) -> torch.Tensor:
        """The full encoded input from its per-Gaussian (N, .) and per-frame (N, .) parts, in declared order."""
        if self._contiguous:
            return torch.cat([g, zc], dim=-1)
        x = torch.empty(g.shape[0], g.shape[1] + zc.shape[1], dtype=g.dtype)
        x[:, self._gcols] = g
        x[:, self._ccols] = zc
        return x

    # -- reference forward --------------------------------------------------------------------------
    def forward(self, mu: torch.Tensor, f: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Plain forward. z (the frame vector) is (D,) shared by all Gaussians or (N, D)."""
        g = self.encode_gaussian(mu, f)
        zc = self.encode_code(z)
        if zc.dim() == 1:
            zc = zc.expand(g.shape[0], -1)
        x = self.assemble(g, zc)
        h = x
        for i, layer in enumerate(self.layers):
            if i in self.config.skips:
                h = torch.cat([h, x], dim=-1)
            h = layer(h)
            if i < len(self.layers) - 1:
                h = self._act(h)
        return h if self._out_act is None else self._out_act(h)

    # -- generic fast path -------------------------------------------------------------------------
    def split_weight(self, i: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Layer i's weight as (per-Gaussian input columns, per-frame input columns, hidden columns or None)."""
        w = self.layers[i].weight.detach()  # type: ignore[operator]
        hid = None
        if i > 0:
            hid, w = w[:, : self.config.hidden], w[:, self.config.hidden :]
        return w[:, self._gcols], w[:, self._ccols], hid

    @torch.no_grad()
    def precompute(self, mu: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """Per-Gaussian part of the first layer, bias included: (N, width of layer 0)."""
        g = self.encode_gaussian(mu, f)
        wg, _, _ = self.split_weight(0)
        return torch.addmm(self.layers[0].bias, g, wg.t())  # type: ignore[arg-type]

    @torch.no_grad()
    def code_term(self, z: torch.Tensor) -> torch.Tensor:
        """Per-frame part of the first layer for one frame vector z (D,): (width of layer 0,)."""
        _, wc, _ = self.split_weight(0)
        return wc @ self.encode_code(z)

    @torch.no_grad()
    def evaluate(self, first: torch.Tensor, z: torch.Tensor, out: torch.Tensor | None = None, chunk: int = 2048,
                 gaussian_inputs: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """Outputs for all Gaussians at frame vector z from `precompute`'s result, in chunks.

        `gaussian_inputs` (mu, f) is needed only when the architecture has skip layers.
        """
        c = self.config
        n = first.shape[0]
        if out is None:
            out = torch.empty(n, c.out_dim, dtype=first.dtype)
        zt = self.code_term(z)
        zc = self.encode_code(z)
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            h = first[s:e] + zt
            for i in range(1, c.depth):
                h = self._act(h)
                inp = h
                if i in c.skips:
                    mu, f = gaussian_inputs  # type: ignore[misc]
                    x = self.assemble(self.encode_gaussian(mu[s:e], f[s:e]), zc.expand(e - s, -1))
                    inp = torch.cat([h, x], dim=-1)
                h = self.layers[i](inp)
            out[s:e] = h if self._out_act is None else self._out_act(h)
        return out


def _cond_width(c: MLPConfig, total: int) -> int:
    """Columns of a frame vector of width `total` that are the condition (its last condition_dim)."""
    return min(c.condition_dim, total)
