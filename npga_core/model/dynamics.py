"""The NPGA dynamics module: the MLPs F(mu, f; z) and G(mu, f; z) and how their offsets pose a cloud.

Both networks share one architecture (`MLPConfig`): the raw input is the concatenation
``[mu (3), f (F), z (D)]``, normalised as ``(x - input_shift) * input_scale``; optionally mu is expanded
with a sinusoidal positional encoding; then `depth` linear layers with an activation between them
(the last layer is linear). Layers listed in `skips` get the encoded input concatenated again.

The output columns of a network are named blocks (`OUTPUT_WIDTHS`): F has ``position``; G may have any
of ``position, rotation, scale, opacity, sh, latent``. `ATTRIBUTE_OPS` is the single place that says how an
offset combines with its canonical attribute (the group operation) and what its neutral element is.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from npga_core.model.gaussians import GaussianCloud, PosedGaussians


def strict_int(v: object, what: str) -> int:
    """`v` if it is a JSON integer (not a bool, float or string), else ValueError."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise ValueError(f"{what} must be an integer, got {v!r}")
    return v


def _strict_str(v: object, what: str) -> str:
    if not isinstance(v, str):
        raise ValueError(f"{what} must be a string, got {v!r}")
    return v


MAX_POS_FREQS = 20

ACTIVATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": torch.relu,
    "silu": nn.functional.silu,
    "gelu": nn.functional.gelu,
    "softplus": nn.functional.softplus,
    "tanh": torch.tanh,
    "elu": nn.functional.elu,
    "leaky_relu": nn.functional.leaky_relu,
}

#: The attributes an offset can act on, in canonical output order.
ATTRIBUTES: tuple[str, ...] = ("position", "rotation", "scale", "opacity", "sh", "latent")


@dataclass(frozen=True)
class AttributeOp:
    """How an offset d acts on a canonical attribute c (stored form), and the neutral element of d."""

    description: str
    neutral: str  # human-readable neutral element of the offset as the network outputs it
    apply: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a*b of (w, x, y, z) quaternions, batched over leading dims."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def _normalize(q: torch.Tensor) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _compose_rotation(c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=d.dtype, device=d.device)
    return _normalize(quat_multiply(_normalize(identity + d), _normalize(c)))


def _add_rotation(c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    return _normalize(_normalize(c) + d)


#: The group operations, written down once. Keys are attribute names; "rotation" has two conventions,
#: chosen per avatar by the header key `dynamics.rotation_op` ("compose" default, "add" as in GaussianHeadAvatar).
ATTRIBUTE_OPS: dict[str, AttributeOp] = {
    "position": AttributeOp("mu + d", "0", lambda c, d: c + d),
    "rotation": AttributeOp("normalize(normalize((1,0,0,0) + d) * normalize(q))", "0 (identity rotation)",
                            _compose_rotation),
    "rotation_add": AttributeOp("normalize(normalize(q) + d)", "0", _add_rotation),
    "scale": AttributeOp("log_s + d (scales multiply by exp(d))", "0 (factor 1)", lambda c, d: c + d),
    "opacity": AttributeOp("logit + d", "0", lambda c, d: c + d),
    "sh": AttributeOp("sh + d on the first d.shape/3 coefficients", "0", lambda c, d: c + d),
    "latent": AttributeOp("h + d", "0", lambda c, d: c + d),
}


def output_widths(sh_degree: int, latent_dim: int) -> dict[str, int]:
    """Full width of each attribute's offset block for a cloud layout."""
    return {
        "position": 3,
        "rotation": 4,
        "scale": 3,
        "opacity": 1,
        "sh": 3 * (sh_degree + 1) ** 2,
        "latent": latent_dim,
    }


@dataclass
class MLPConfig:
    """Architecture of one conditioned MLP (F or G), as stored in the checkpoint header."""

    feature_dim: int
    code_dim: int
    outputs: list[tuple[str, int]]
    hidden: int = 256
    depth: int = 6
    activation: str = "relu"
    pos_freqs: int = 0
    skips: list[int] = field(default_factory=list)

    @property
    def raw_input_dim(self) -> int:
        return 3 + self.feature_dim + self.code_dim

    @property
    def mu_encoded_dim(self) -> int:
        return 3 * (1 + 2 * self.pos_freqs)

    @property
    def encoded_input_dim(self) -> int:
        return self.mu_encoded_dim + self.feature_dim + self.code_dim

    @property
    def out_dim(self) -> int:
        return sum(w for _, w in self.outputs)

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

    def validate(self) -> None:
        """Raise ValueError if the configuration is inconsistent."""
        if self.depth < 1:
            raise ValueError(f"depth must be >= 1, got {self.depth}")
        if self.hidden < 1 or self.feature_dim < 0 or self.code_dim < 0 or self.pos_freqs < 0:
            raise ValueError("hidden, feature_dim, code_dim and pos_freqs must be non-negative (hidden >= 1)")
        if self.pos_freqs > MAX_POS_FREQS:
            raise ValueError(f"pos_freqs {self.pos_freqs} exceeds {MAX_POS_FREQS} (float32 sin/cos lose all meaning)")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {self.activation!r} (known: {', '.join(ACTIVATIONS)})")
        for s in self.skips:
            if not 1 <= s < self.depth:
                raise ValueError(f"skip layer {s} outside 1..{self.depth - 1}")
        seen = set()
        for name, width in self.outputs:
            if name not in ATTRIBUTES:
                raise ValueError(f"unknown output block {name!r} (known: {', '.join(ATTRIBUTES)})")
            if name in seen:
                raise ValueError(f"output block {name!r} listed twice")
            if width < 1:
                raise ValueError(f"output block {name!r} has width {width}")
            seen.add(name)
        if not self.outputs:
            raise ValueError("no output blocks")

    def to_json(self) -> dict:
        return {
            "feature_dim": self.feature_dim,
            "code_dim": self.code_dim,
            "outputs": [[n, w] for n, w in self.outputs],
            "hidden": self.hidden,
            "depth": self.depth,
            "activation": self.activation,
            "pos_freqs": self.pos_freqs,
            "skips": list(self.skips),
        }

    @staticmethod
    def from_json(d: dict) -> MLPConfig:
        try:
            cfg = MLPConfig(
                feature_dim=strict_int(d["feature_dim"], "feature_dim"),
                code_dim=strict_int(d["code_dim"], "code_dim"),
                outputs=[(_strict_str(n, "output name"), strict_int(w, f"width of {n}")) for n, w in d["outputs"]],
                hidden=strict_int(d.get("hidden", 256), "hidden"),
                depth=strict_int(d.get("depth", 6), "depth"),
                activation=_strict_str(d.get("activation", "relu"), "activation"),
                pos_freqs=strict_int(d.get("pos_freqs", 0), "pos_freqs"),
                skips=[strict_int(s, "skip") for s in d.get("skips", [])],
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"malformed MLP architecture: {e}") from None
        cfg.validate()
        return cfg


class ConditionedMLP(nn.Module):
    """One NPGA MLP: (mu, f, z) -> named offset blocks.

    `forward` is the plain reference. `precompute` + `evaluate` is the fast path: the per-Gaussian part
    of the first layer (mu and f columns, plus bias) is computed once; per code only a (hidden,) vector is
    added, then the remaining layers run in cache-sized chunks with preallocated buffers.
    """

    def __init__(self, config: MLPConfig):
        super().__init__()
        config.validate()
        self.config = config
        self.layers = nn.ModuleList(nn.Linear(i, o) for o, i in config.layer_shapes())
        self.register_buffer("input_shift", torch.zeros(config.raw_input_dim))
        self.register_buffer("input_scale", torch.ones(config.raw_input_dim))
        self._act = ACTIVATIONS[config.activation]

    # -- input conditioning -------------------------------------------------------------------------
    def encode_gaussian(self, mu: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """Normalised, encoded per-Gaussian inputs [enc(mu), f] (N, mu_encoded_dim + F)."""
        c = self.config
        shift, scale = self.input_shift, self.input_scale
        mu_n = (mu - shift[:3]) * scale[:3]
        f_n = (f - shift[3 : 3 + c.feature_dim]) * scale[3 : 3 + c.feature_dim]
        parts = [mu_n]
        for k in range(c.pos_freqs):
            w = (2.0**k) * math.pi
            parts += [torch.sin(w * mu_n), torch.cos(w * mu_n)]
        return torch.cat(parts + [f_n], dim=-1)

    def encode_code(self, z: torch.Tensor) -> torch.Tensor:
        """Normalised code (..., D)."""
        off = 3 + self.config.feature_dim
        return (z - self.input_shift[off:]) * self.input_scale[off:]

    # -- reference forward --------------------------------------------------------------------------
    def forward(self, mu: torch.Tensor, f: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Plain forward. z is (D,) shared by all Gaussians or (N, D)."""
        g = self.encode_gaussian(mu, f)
        zc = self.encode_code(z)
        if zc.dim() == 1:
            zc = zc.expand(g.shape[0], -1)
        x = torch.cat([g, zc], dim=-1)
        h = x
        for i, layer in enumerate(self.layers):
            if i in self.config.skips:
                h = torch.cat([h, x], dim=-1)
            h = layer(h)
            if i < len(self.layers) - 1:
                h = self._act(h)
        return h

    # -- fast path ----------------------------------------------------------------------------------
    @torch.no_grad()
    def precompute(self, mu: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """Per-Gaussian part of the first layer, bias included: (N, width of layer 0)."""
        g = self.encode_gaussian(mu, f)
        w0 = self.layers[0].weight
        return torch.addmm(self.layers[0].bias, g, w0[:, : g.shape[1]].t())

    @torch.no_grad()
    def code_term(self, z: torch.Tensor) -> torch.Tensor:
        """Code part of the first layer for one code z (D,): (width of layer 0,)."""
        gw = self.config.mu_encoded_dim + self.config.feature_dim
        return self.layers[0].weight[:, gw:] @ self.encode_code(z)

    @torch.no_grad()
    def evaluate(
        self,
        first: torch.Tensor,
        z: torch.Tensor,
        out: torch.Tensor | None = None,
        chunk: int = 2048,
        gaussian_inputs: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Outputs for all Gaussians at code z from `precompute`'s result, in chunks.

        `gaussian_inputs` (mu, f) is needed only when the architecture has skip layers.
        """
        c = self.config
        n = first.shape[0]
        if out is None:
            out = torch.empty(n, c.out_dim, dtype=first.dtype)
        zt = self.code_term(z)
        zc = self.encode_code(z) if c.skips else None
        bufs = [torch.empty(chunk, o, dtype=first.dtype) for o, _ in c.layer_shapes()[:-1]]
        act_ = {"relu": torch.relu_}.get(c.activation)
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            m = e - s
            if c.depth == 1:
                torch.add(first[s:e], zt, out=out[s:e])
                continue
            h = bufs[0][:m]
            torch.add(first[s:e], zt, out=h)
            h = act_(h) if act_ else self._act(h)
            for i in range(1, c.depth):
                layer = self.layers[i]
                inp = h
                if i in c.skips:
                    mu, f = gaussian_inputs  # type: ignore[misc]
                    x = torch.cat([self.encode_gaussian(mu[s:e], f[s:e]), zc.expand(m, -1)], dim=-1)
                    inp = torch.cat([h, x], dim=-1)
                if i == c.depth - 1:
                    torch.addmm(layer.bias, inp, layer.weight.t(), out=out[s:e])
                else:
                    nxt = bufs[i][:m]
                    torch.addmm(layer.bias, inp, layer.weight.t(), out=nxt)
                    h = act_(nxt) if act_ else self._act(nxt)
        return out

    def split(self, out: torch.Tensor) -> dict[str, torch.Tensor]:
        """Named output blocks (views into `out`)."""
        blocks, o = {}, 0
        for name, width in self.config.outputs:
            blocks[name] = out[:, o : o + width]
            o += width
        return blocks


@dataclass
class Offsets:
    """Offsets of every attribute at one code: F's position offset and G's named blocks."""

    f_position: torch.Tensor | None
    g: dict[str, torch.Tensor]

    def total(self, name: str) -> torch.Tensor | None:
        """Sum of F and G offsets for an attribute (F contributes only to position)."""
        d = self.g.get(name)
        if name == "position" and self.f_position is not None:
            d = self.f_position if d is None else d + self.f_position
        return d


class Dynamics(nn.Module):
    """F (coarse position offsets) and G (offsets of every attribute); either may be absent."""

    def __init__(self, F: ConditionedMLP | None, G: ConditionedMLP | None, rotation_op: str = "compose"):
        super().__init__()
        if F is None and G is None:
            raise ValueError("Dynamics needs at least one of F and G")
        if F is not None and [n for n, _ in F.config.outputs] != ["position"]:
            raise ValueError("F must output exactly the 'position' block")
        if rotation_op not in ("compose", "add"):
            raise ValueError(f"rotation_op must be 'compose' or 'add', got {rotation_op!r}")
        self.F = F
        self.G = G
        self.rotation_op = rotation_op

    @property
    def code_dim(self) -> int:
        return (self.F or self.G).config.code_dim  # type: ignore[union-attr]

    @property
    def feature_dim(self) -> int:
        return (self.F or self.G).config.feature_dim  # type: ignore[union-attr]

    def networks(self) -> dict[str, ConditionedMLP]:
        return {k: m for k, m in (("F", self.F), ("G", self.G)) if m is not None}

    def offsets(self, mu: torch.Tensor, f: torch.Tensor, z: torch.Tensor) -> Offsets:
        """Reference offsets (plain forward passes)."""
        fp = self.F(mu, f, z) if self.F is not None else None
        g = self.G.split(self.G(mu, f, z)) if self.G is not None else {}
        return Offsets(fp, g)

    def validate_for(self, cloud: GaussianCloud) -> None:
        """Raise ValueError if the networks do not fit the cloud's layout."""
        widths = output_widths(cloud.sh_degree, cloud.latent_dim)
        for key, net in self.networks().items():
            c = net.config
            if c.feature_dim != cloud.feature_dim:
                raise ValueError(f"{key} expects {c.feature_dim} features, the cloud has {cloud.feature_dim}")
            if c.code_dim != self.code_dim:
                raise ValueError(f"{key} expects codes of {c.code_dim} dims, the other network {self.code_dim}")
            for name, w in c.outputs:
                if name == "sh":
                    if w % 3 or w > widths["sh"]:
                        raise ValueError(f"{key} sh block of width {w} does not fit {widths['sh']} SH values")
                elif w != widths[name]:
                    raise ValueError(f"{key} {name} block has width {w}, the cloud needs {widths[name]}")


def apply_offsets(cloud_t: dict[str, torch.Tensor], off: Offsets, rotation_op: str = "compose") -> dict:
    """Posed stored-form attributes from canonical tensors and offsets, by `ATTRIBUTE_OPS`.

    `cloud_t` holds torch tensors means, quats, log_scales, opacity_logits (N,), sh (N,K,3), latent (or None).
    Returns the same keys, posed (still in stored form: log scales, logits).
    """
    posed = dict(cloud_t)
    n = cloud_t["means"].shape[0]
    d = off.total("position")
    if d is not None:
        posed["means"] = ATTRIBUTE_OPS["position"].apply(cloud_t["means"], d)
    if (d := off.g.get("rotation")) is not None:
        op = ATTRIBUTE_OPS["rotation" if rotation_op == "compose" else "rotation_add"]
        posed["quats"] = op.apply(cloud_t["quats"], d)
    if (d := off.g.get("scale")) is not None:
        posed["log_scales"] = ATTRIBUTE_OPS["scale"].apply(cloud_t["log_scales"], d)
    if (d := off.g.get("opacity")) is not None:
        posed["opacity_logits"] = ATTRIBUTE_OPS["opacity"].apply(cloud_t["opacity_logits"], d[:, 0])
    if (d := off.g.get("sh")) is not None:
        sh = cloud_t["sh"].clone()
        k = d.shape[1] // 3
        sh[:, :k] = ATTRIBUTE_OPS["sh"].apply(sh[:, :k], d.reshape(n, k, 3))
        posed["sh"] = sh
    if (d := off.g.get("latent")) is not None and cloud_t.get("latent") is not None:
        posed["latent"] = ATTRIBUTE_OPS["latent"].apply(cloud_t["latent"], d)
    return posed


def cloud_tensors(cloud: GaussianCloud) -> dict[str, torch.Tensor | None]:
    """Canonical arrays of a cloud as float32 torch tensors (copies, so read-only maps are fine)."""
    t = {}
    for k in ("means", "quats", "log_scales", "opacity_logits", "sh", "features", "latent"):
        a = getattr(cloud, k)
        t[k] = None if a is None else torch.from_numpy(np.array(a, dtype=np.float32, copy=True))
    return t


def to_posed_gaussians(posed: dict[str, torch.Tensor]) -> PosedGaussians:
    """Activate stored-form posed tensors into a `PosedGaussians` for rendering."""
    q = posed["quats"]
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    lat = posed.get("latent")
    return PosedGaussians(
        means=np.ascontiguousarray(posed["means"].numpy(), dtype=np.float32),
        quats=np.ascontiguousarray(q.numpy(), dtype=np.float32),
        scales=np.ascontiguousarray(torch.exp(posed["log_scales"]).numpy(), dtype=np.float32),
        opacities=np.ascontiguousarray(torch.sigmoid(posed["opacity_logits"]).numpy(), dtype=np.float32),
        sh=np.ascontiguousarray(posed["sh"].numpy(), dtype=np.float32),
        latent=None if lat is None else np.ascontiguousarray(lat.numpy(), dtype=np.float32),
    )
