"""The dynamics module: named networks (`networks.py`) and how their routed outputs pose a cloud.

Every network's output columns are routed to attributes (`Route`: columns, target columns, scale); a network may
be blended per Gaussian by one of the cloud's `blend_weights` columns (its rows with weight 0 do not depend on
it). The offset of an attribute is the sum over networks of ``weight * scale * columns``; `RULES` says, per
attribute, how that offset combines with the canonical value (the group operation), written once here in
`ATTRIBUTE_OPS`. NPGA's F(mu, f; z) and G(mu, f; z) are the networks "F" and "G" with weight 1 and scale 1.

The per-frame input of all networks is one vector, the frame vector ``[code (D_e), condition (D_c)]``: the
expression code, then an optional second condition (Gaussian-Head-Avatar's head pose, `condition` says what it
is). A tracked rigid head transform (rotation, translation, scale) is applied to the posed output by
`PosedGaussians.transformed`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from npga_core.errors import brief
from npga_core.model.gaussians import GaussianCloud, PosedGaussians
from npga_core.model.linear_rig import LinearRig
from npga_core.model.networks import (
    ACTIVATIONS,
    ATTRIBUTES,
    MAX_POS_FREQS,
    ConditionedMLP,
    MLPConfig,
    Route,
)

__all__ = ["ACTIVATIONS", "ATTRIBUTES", "ATTRIBUTE_OPS", "MAX_POS_FREQS", "RIG", "RULES", "ConditionedMLP", "Dynamics",
           "MLPConfig", "Offsets", "Route", "apply_offsets", "cloud_tensors", "output_widths",
           "to_posed_gaussians"]


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


def _add_raw_legacy(c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    q = c + d  # GHA before 2024-07-12: F.normalize over the Gaussians (dim 1 of (B, N, 4)), one norm per component
    return _normalize(q / q.norm(dim=0, keepdim=True).clamp_min(1e-12))


#: The group operations, written down once, by rule name ("attribute" or "attribute_variant").
ATTRIBUTE_OPS: dict[str, AttributeOp] = {
    "position": AttributeOp("mu + d", "0", lambda c, d: c + d),
    "rotation": AttributeOp("normalize(normalize((1,0,0,0) + d) * normalize(q))", "0 (identity rotation)",
                            _compose_rotation),
    "rotation_add": AttributeOp("normalize(normalize(q) + d)", "0", _add_rotation),
    "rotation_add_raw": AttributeOp("normalize(q + d), q as stored (Gaussian-Head-Avatar)", "0",
                                    lambda c, d: _normalize(c + d)),
    "rotation_add_raw_legacy": AttributeOp(
        "q + d divided by its norm over all Gaussians per component, then normalised (Gaussian-Head-Avatar "
        "before 2024-07-12)", "0", _add_raw_legacy),
    "scale": AttributeOp("log_s + d (scales multiply by exp(d))", "0 (factor 1)", lambda c, d: c + d),
    "opacity": AttributeOp("logit + d", "0", lambda c, d: c + d),
    "sh": AttributeOp("sh + d on the coefficients the routes reach", "0", lambda c, d: c + d),
    "latent": AttributeOp("h + d", "0", lambda c, d: c + d),
}

#: The rules each attribute may be composed by (first: the default); keys of `ATTRIBUTE_OPS` are
#: attribute or attribute_rule.
RULES: dict[str, tuple[str, ...]] = {
    "position": ("add",),
    "rotation": ("compose", "add", "add_raw", "add_raw_legacy"),
    "scale": ("add",),
    "opacity": ("add",),
    "sh": ("add",),
    "latent": ("add",),
}


def op_for(attribute: str, rule: str) -> AttributeOp:
    """The `ATTRIBUTE_OPS` entry of an attribute under a rule."""
    return ATTRIBUTE_OPS[attribute if rule == RULES[attribute][0] else f"{attribute}_{rule}"]


def output_widths(sh_degree: int, latent_dim: int) -> dict[str, int]:
    """Full width of each attribute's offset for a cloud layout."""
    return {"position": 3, "rotation": 4, "scale": 3, "opacity": 1, "sh": 3 * (sh_degree + 1) ** 2,
            "latent": latent_dim}


@dataclass
class Offsets:
    """Offsets at one frame vector: per network, per attribute (weighted and scaled, as they act)."""

    by_network: dict[str, dict[str, torch.Tensor]]

    def total(self, name: str) -> torch.Tensor | None:
        """The summed offset of an attribute over all networks (None if no network reaches it)."""
        parts = [o[name] for o in self.by_network.values() if name in o]
        if not parts:
            return None
        width = max(p.shape[1] for p in parts)
        out = torch.zeros(parts[0].shape[0], width, dtype=parts[0].dtype)
        for p in parts:
            out[:, : p.shape[1]] += p
        return out

    def totals(self) -> dict[str, torch.Tensor]:
        return {a: t for a in ATTRIBUTES if (t := self.total(a)) is not None}

    @property
    def f_position(self) -> torch.Tensor | None:
        """NPGA's F: its position offset (None without F)."""
        return self.by_network.get("F", {}).get("position")

    @property
    def g(self) -> dict[str, torch.Tensor]:
        """NPGA's G: its offsets by attribute (empty without G)."""
        return self.by_network.get("G", {})


#: The name under which a rig's offsets appear beside the networks' (`Offsets.by_network`).
RIG = "rig"


def attribute_widths(networks: dict[str, ConditionedMLP], rig: bool | dict[str, int] = False) -> dict[str, int]:
    """Width of the summed offset of each attribute the networks and a rig reach (the widest route end),
    canonical order; `rig`: the rig's `attributes` (True: position only)."""
    widths: dict[str, int] = dict(rig) if isinstance(rig, dict) else {"position": 3} if rig else {}
    for net in networks.values():
        for r in net.config.routes or []:
            widths[r.attribute] = max(widths.get(r.attribute, 0), r.to + r.width)
    return {a: widths[a] for a in ATTRIBUTES if a in widths}


def route_into(acc: dict[str, torch.Tensor], net: ConditionedMLP, out: torch.Tensor,
               weight: torch.Tensor | None) -> None:
    """Add a network's routed outputs (N, out_dim), times their scales and the blend `weight` (N,), into `acc`."""
    for r in net.config.routes or []:
        part = out[:, r.start : r.start + r.width] * r.scale
        if weight is not None:
            part = part * weight[:, None]
        dest = acc[r.attribute]
        dest[:, r.to : r.to + r.width] += part


class Dynamics(nn.Module):
    """Named networks with their composition rules; NPGA's F and G are `Dynamics(F, G)`.

    `rules` maps attributes to their rule (`RULES`; default for missing ones), `condition` describes the
    condition part of the frame vector (None: no condition), `blend_notes` how each blend weight was made.
    """

    def __init__(self, F: ConditionedMLP | None = None, G: ConditionedMLP | None = None,
                 rotation_op: str = "compose", *, networks: dict[str, ConditionedMLP] | None = None,
                 rules: dict[str, str] | None = None, condition: dict | None = None,
                 blend_notes: dict[str, str] | None = None, rig: LinearRig | None = None):
        super().__init__()
        if networks is None:
            networks = {k: m for k, m in (("F", F), ("G", G)) if m is not None}
        if not networks and rig is None:
            raise ValueError("Dynamics needs at least one network or a rig")
        self.rig = rig
        self.nets = nn.ModuleDict(networks)
        self.rules = {a: RULES[a][0] for a in RULES}
        self.rules["rotation"] = rotation_op
        self.rules.update(rules or {})
        for a, r in self.rules.items():
            if r not in RULES[a]:
                raise ValueError(f"{a} rule {brief(r)} is not one of {', '.join(RULES[a])}")
        self.condition = condition
        self.blend_notes = dict(blend_notes or {})
        dims = {(n.config.code_dim, n.config.condition_dim, n.config.feature_dim) for n in networks.values()}
        if len(dims) > 1:
            raise ValueError(f"the networks disagree on (code, condition, feature) widths: {sorted(dims)}")
        if self.condition_dim and not condition:
            raise ValueError("a condition part of the frame vector needs a description")
        if rig is not None and rig.skin is not None and (networks or self.rules["rotation"] != "compose"):
            raise ValueError("a rig on a skinned mesh poses its avatar alone, with the 'compose' rotation rule")

    @property
    def F(self) -> ConditionedMLP | None:  # noqa: N802 - the paper's name
        return self.networks().get("F")

    @property
    def G(self) -> ConditionedMLP | None:  # noqa: N802 - the paper's name
        return self.networks().get("G")

    @property
    def rotation_op(self) -> str:
        return self.rules["rotation"]

    def _first(self) -> MLPConfig | None:
        return next(iter(self.nets.values())).config if len(self.nets) else None  # type: ignore[return-value]

    @property
    def expression_dim(self) -> int:
        """D_e: width of the expression code part of the frame vector the networks take (0 without networks)."""
        first = self._first()
        return 0 if first is None else first.code_dim

    @property
    def condition_dim(self) -> int:
        """D_c: width of the condition part of the frame vector (0 without one)."""
        first = self._first()
        return 0 if first is None else first.condition_dim

    @property
    def network_dim(self) -> int:
        """Width of the part [code, condition] of the frame vector that the networks take."""
        return self.expression_dim + self.condition_dim

    @property
    def rig_dim(self) -> int:
        """Width of the rig's part of the frame vector (its channel weights; 0 without a rig)."""
        return 0 if self.rig is None else self.rig.n_inputs

    @property
    def code_dim(self) -> int:
        """Width of the frame vector [code, condition, rig weights]."""
        return self.network_dim + self.rig_dim

    @property
    def feature_dim(self) -> int:
        first = self._first()
        return 0 if first is None else first.feature_dim

    def rig_offsets(self, z: torch.Tensor | np.ndarray, rows: slice | np.ndarray | None = None) -> torch.Tensor:
        """The rig's position displacement of `rows` at frame vector z (its last `rig_dim` values)."""
        assert self.rig is not None
        w = np.asarray(z, np.float32).reshape(-1)[self.network_dim :]
        return self.rig.offsets(w, rows)

    def rig_attribute_offsets(self, z: torch.Tensor | np.ndarray, means: torch.Tensor,
                              rows: slice | np.ndarray | None = None) -> dict[str, torch.Tensor]:
        """The rig's offsets by attribute of `rows` (canonical centres `means`) at frame vector z."""
        assert self.rig is not None
        return self.rig.attribute_offsets(self.rig.frame(np.asarray(z, np.float32).reshape(-1)[self.network_dim :]),
                                          rows, means)

    def networks(self) -> dict[str, ConditionedMLP]:
        return dict(self.nets.items())  # type: ignore[arg-type]

    @property
    def simple(self) -> bool:
        """Expressible in format version 1 (F and/or G of the fixed architecture, no blend, no condition)."""
        return (self.rig is None and len(self.nets) > 0
                and set(self.nets) <= {"F", "G"} and all(n.config.simple for n in self.networks().values())
                and self.rules["rotation"] in ("compose", "add")
                and all(r == RULES[a][0] for a, r in self.rules.items() if a != "rotation")
                and (self.F is None or [n for n, _ in self.F.config.outputs] == ["position"]))

    def attribute_widths(self) -> dict[str, int]:
        return attribute_widths(self.networks(), {} if self.rig is None else self.rig.attributes)

    def offsets(self, mu: torch.Tensor, f: torch.Tensor, z: torch.Tensor,
                blend: dict[str, torch.Tensor] | None = None) -> Offsets:
        """Reference offsets (plain forward passes); `blend` maps blend names to (N,) weights."""
        by = {}
        zn = z[: self.network_dim]
        for key, net in self.nets.items():
            out = net(mu, f, zn)
            widths = attribute_widths({key: net})  # type: ignore[dict-item]
            acc = {a: torch.zeros(out.shape[0], w, dtype=out.dtype) for a, w in widths.items()}
            w = None if net.config.blend is None else (blend or {})[net.config.blend]  # type: ignore[index, union-attr]
            route_into(acc, net, out, w)  # type: ignore[arg-type]
            by[key] = acc
        if self.rig is not None:
            by[RIG] = self.rig_attribute_offsets(z, mu)
        return Offsets(by)

    def validate_for(self, cloud: GaussianCloud) -> None:
        """Raise ValueError if the networks do not fit the cloud's layout."""
        widths = output_widths(cloud.sh_degree, cloud.latent_dim)
        if self.rig is not None and (self.rig.n_gaussians or self.rig.n_points) != len(cloud):
            raise ValueError(f"the rig moves {self.rig.n_gaussians or self.rig.n_points} Gaussians, the cloud has "
                             f"{len(cloud)}")
        for key, net in self.networks().items():
            c = net.config
            if c.feature_dim != cloud.feature_dim:
                raise ValueError(f"{key} expects {c.feature_dim} features, the cloud has {cloud.feature_dim}")
            if c.blend is not None and c.blend not in cloud.blend_names:
                raise ValueError(f"{key} is blended by {brief(c.blend)}, which the cloud's blend weights lack")
            for r in c.routes or []:
                if r.to + r.width > widths[r.attribute]:
                    raise ValueError(f"{key} writes {r.attribute} columns {r.to}..{r.to + r.width}, the cloud has "
                                     f"{widths[r.attribute]}")
                if r.attribute == "sh" and (r.to % 3 or r.width % 3):
                    raise ValueError(f"{key} sh route does not cover whole RGB coefficients")


def blend_tensors(cloud_t: dict, names: list[str]) -> dict[str, torch.Tensor]:
    """The cloud's blend weights by name (from `cloud_tensors`)."""
    w = cloud_t.get("blend_weights")
    return {} if w is None else {n: w[:, i] for i, n in enumerate(names)}


def apply_offsets(cloud_t: dict[str, torch.Tensor], off: Offsets | dict[str, torch.Tensor],
                  rules: dict[str, str] | str = "compose") -> dict:
    """Posed stored-form attributes from canonical tensors and offsets, by the rules' `ATTRIBUTE_OPS`.

    `cloud_t` holds torch tensors means, quats, log_scales, opacity_logits (N,), sh (N,K,3), latent (or None);
    `off` the offsets (an `Offsets` or summed offsets by attribute); `rules` the attribute rules (a string is
    the rotation rule). Returns the same keys, posed (still in stored form: log scales, logits).
    """
    if isinstance(rules, str):
        rules = {"rotation": rules}
    totals = off.totals() if isinstance(off, Offsets) else off
    posed = dict(cloud_t)
    n = cloud_t["means"].shape[0]
    if (d := totals.get("position")) is not None:
        posed["means"] = ATTRIBUTE_OPS["position"].apply(cloud_t["means"], d)
    if (d := totals.get("rotation")) is not None:
        posed["quats"] = op_for("rotation", rules.get("rotation", "compose")).apply(cloud_t["quats"], d)
    if (d := totals.get("scale")) is not None:
        posed["log_scales"] = ATTRIBUTE_OPS["scale"].apply(cloud_t["log_scales"], d)
    if (d := totals.get("opacity")) is not None:
        posed["opacity_logits"] = ATTRIBUTE_OPS["opacity"].apply(cloud_t["opacity_logits"], d[:, 0])
    if (d := totals.get("sh")) is not None:
        sh = cloud_t["sh"].clone().reshape(n, cloud_t["sh"].shape[1] * 3)
        w = d.shape[1]
        sh[:, :w] = ATTRIBUTE_OPS["sh"].apply(sh[:, :w], d)
        posed["sh"] = sh.reshape(cloud_t["sh"].shape)
    if (d := totals.get("latent")) is not None and cloud_t.get("latent") is not None:
        lat = cloud_t["latent"].clone()
        w = d.shape[1]
        lat[:, :w] = ATTRIBUTE_OPS["latent"].apply(lat[:, :w], d)
        posed["latent"] = lat
    return posed


def cloud_tensors(cloud: GaussianCloud) -> dict[str, torch.Tensor | None]:
    """Canonical arrays of a cloud as float32 torch tensors (copies, so read-only maps are fine)."""
    t = {}
    for k in ("means", "quats", "log_scales", "opacity_logits", "sh", "features", "latent", "blend_weights"):
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
