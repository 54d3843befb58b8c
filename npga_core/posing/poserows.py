"""The row-side pieces of `FastPoser`: the combined offset layout, sets of rows and their inputs, devices, and the
attribute-major helpers used when offsets are applied (split out of fastpose.py; re-exported there)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import torch

from npga_core.model.dynamics import ConditionedMLP, attribute_widths, quat_multiply
from npga_core.model.networks import PER_GAUSSIAN_INPUTS


@dataclass(frozen=True)
class OffsetLayout:
    """Column blocks of the combined offset row: the summed offset of each attribute, in canonical order."""

    blocks: dict[str, tuple[int, int]]  # "position", "sh", ... -> (first column, width)

    @property
    def width(self) -> int:
        return sum(w for _, w in self.blocks.values())

    @staticmethod
    def of(networks: dict[str, ConditionedMLP], rig: bool | dict[str, int] = False) -> OffsetLayout:
        blocks, col = {}, 0
        for name, width in attribute_widths(networks, rig).items():
            blocks[name] = (col, width)
            col += width
        return OffsetLayout(blocks)

    def block(self, rows: torch.Tensor, key: str) -> torch.Tensor | None:
        """The columns of attribute `key` ("scale") of an offset chunk, or None if absent."""
        if key not in self.blocks:
            return None
        c, w = self.blocks[key]
        return rows[:, c : c + w]


@dataclass
class RowSet:
    """Per-Gaussian network inputs of a set of rows: the first-layer terms if cached, else (mu, f) to encode;
    the blend weights of blended networks on these rows and, per network, the contiguous range of rows it
    reaches (None: all of them)."""

    means: torch.Tensor
    features: torch.Tensor
    first: dict[str, torch.Tensor] | None = None
    index: np.ndarray | None = None  # the avatar rows these are (None: all, in order)
    weights: dict[str, torch.Tensor] = field(default_factory=dict)
    spans: dict[str, tuple[int, int]] = field(default_factory=dict)
    low: dict[str, torch.Tensor] | None = None  # bfloat16 path: per network its rows' `low_inputs`

    @property
    def n(self) -> int:
        return int(self.means.shape[0])

    def span(self, key: str, s: int, e: int) -> tuple[int, int]:
        """The rows of s:e that network `key` reaches (an empty range when none)."""
        a, b = self.spans.get(key, (0, self.n))
        lo, hi = max(s, a), min(e, b)
        return (lo, hi) if lo < hi else (s, s)



def support_span(weight: np.ndarray) -> tuple[int, int] | None:
    """The rows where a blend weight is not zero, as a range, if they are contiguous (else None)."""
    nz = np.flatnonzero(weight)
    if not len(nz):
        return (0, 0)
    return (int(nz[0]), int(nz[-1]) + 1) if nz[-1] - nz[0] + 1 == len(nz) else None


def encoding_key(net: ConditionedMLP) -> tuple:
    """Networks with equal keys encode (mu, f) identically (same per-Gaussian inputs, order, encodings and
    normalisation)."""
    c, key, col = net.config, [], 0
    for spec in c.specs:
        w = c.raw_width(spec)
        if spec.kind in PER_GAUSSIAN_INPUTS:
            key.append((spec, tuple(net.input_shift[col : col + w].tolist()),  # type: ignore[index]
                        tuple(net.input_scale[col : col + w].tolist())))  # type: ignore[index]
        col += w
    return tuple(key)


def unit_rows(q: torch.Tensor) -> torch.Tensor:
    """Rows (4, m) of quaternions, each column scaled to unit length (as `_normalize`, clamped at 1e-12)."""
    n2 = q[0] * q[0]
    for i in range(1, q.shape[0]):
        n2.addcmul_(q[i], q[i])
    return q / n2.sqrt_().clamp_min_(1e-12)


def compose_rotation_rows(c_unit: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """ATTRIBUTE_OPS["rotation"] on attribute-major rows: normalize(normalize(1 + d) * c_unit)."""
    r = d.clone()
    r[0] += 1.0
    return unit_rows(quat_multiply(unit_rows(r).t(), c_unit.t()).t())


def attribute_major(canonical: dict[str, torch.Tensor | None]) -> dict[str, torch.Tensor]:
    """Canonical attributes with the small ones transposed to (width, N), the wide ones flattened (N, width)."""
    present = cast(dict[str, torch.Tensor], canonical)  # every attribute but the latent is always there
    soa = {k: present[k].t().contiguous() for k in ("means", "log_scales", "quats")}
    soa["unit_quats"] = unit_rows(soa["quats"].clone())
    soa["opacity_logits"] = present["opacity_logits"].contiguous()
    soa["sh"] = present["sh"].reshape(present["sh"].shape[0], present["sh"].shape[1] * 3)
    latent = canonical.get("latent")
    if latent is not None:
        soa["latent"] = latent
    return soa


def posed_buffers(n: int, sh_coeffs: int, latent_dim: int) -> dict[str, np.ndarray]:
    """Freshly allocated float32 output arrays for `FastPoser.pose_into`."""
    shapes = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "sh": (n, sh_coeffs, 3)}
    if latent_dim:
        shapes["latent"] = (n, latent_dim)
    return {k: np.empty(s, np.float32) for k, s in shapes.items()}
