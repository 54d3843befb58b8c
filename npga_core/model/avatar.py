"""`Avatar`: canonical cloud + dynamics + optional CNN + expression space (loading lives in `npga_core.files`)."""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.cnn import ScreenCNN
from npga_core.model.dynamics import (
    RIG,
    Dynamics,
    Offsets,
    apply_offsets,
    attribute_widths,
    blend_tensors,
    cloud_tensors,
    route_into,
    to_posed_gaussians,
)
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import GaussianCloud, PosedGaussians
from npga_core.model.linear_rig import LinearRig
from npga_core.model.rigid import transform_posed
from npga_core.model.skinning import SKIN_ARRAYS


@dataclass
class Avatar:
    """An NPGA avatar. A static scene (e.g. from a PLY) has no dynamics and code_dim 0."""

    cloud: GaussianCloud
    dynamics: Dynamics | None = None
    cnn: ScreenCNN | None = None
    expression: ExpressionSpace | None = None
    provenance: dict = field(default_factory=dict)
    units: str = "m"
    source: str | None = None  # path it was loaded from, if any
    blendshapes: BlendshapeBasis | None = None  # named blendshape weights -> expression code, if known
    version: int = field(default=0, init=False, repr=False)  # incremented by every `invalidate_caches`
    _first_layer: dict[str, torch.Tensor] = field(default_factory=dict, init=False, repr=False)
    _canonical: dict | None = field(default=None, init=False, repr=False)
    _content_key: str | None = field(default=None, init=False, repr=False)

    @property
    def code_dim(self) -> int:
        """Width of the frame vector the dynamics take: the expression code, then the condition (if any)."""
        return 0 if self.dynamics is None else self.dynamics.code_dim

    @property
    def condition_dim(self) -> int:
        """Width of the condition part of the frame vector (0 without one)."""
        return 0 if self.dynamics is None else self.dynamics.condition_dim

    @property
    def rig(self) -> LinearRig | None:
        """The linear blendshape rig of the dynamics, if any (its weights end the frame vector)."""
        return None if self.dynamics is None else self.dynamics.rig

    @property
    def slider_channels(self) -> tuple[str, ...] | None:
        """The rig's channel names when the expression sliders are its weights (an avatar posed by a rig alone whose
        expression space is its channels: identity directions, unit std, mean 0); None for PCA directions."""
        rig, ex = self.rig, self.expression
        if rig is None or ex is None or self.dynamics is None or self.dynamics.network_dim:
            return None
        k = rig.n_inputs
        if ex.n_components != k or not (np.array_equal(ex.basis, np.eye(k, dtype=ex.basis.dtype))
                                         and np.all(ex.std == 1) and not ex.mean.any()):
            return None
        return rig.input_names

    def __len__(self) -> int:
        return len(self.cloud)

    def neutral_code(self) -> np.ndarray:
        """The mean code of the expression space (zeros without one)."""
        if self.expression is not None:
            return self.expression.mean.copy()
        return np.zeros(self.code_dim, np.float32)

    def check_code(self, z: np.ndarray) -> np.ndarray:
        """A float32 (D,) frame vector, or ValueError naming both dimensions. An expression code without the
        condition part gets the neutral condition (zeros: Gaussian-Head-Avatar's head pose of a front view)."""
        z = np.asarray(z, dtype=np.float32).reshape(-1)
        if self.condition_dim and z.shape[0] == self.code_dim - self.condition_dim:
            assert self.dynamics is not None  # (a condition part comes with dynamics)
            e = self.dynamics.expression_dim  # the rig's weights, if any, follow the condition
            z = np.concatenate([z[:e], np.zeros(self.condition_dim, np.float32), z[e:]])
        if z.shape[0] != self.code_dim:
            raise ValueError(f"expression code has {z.shape[0]} dims, the avatar expects {self.code_dim}")
        if not np.all(np.isfinite(z)):
            raise ValueError("expression code has NaN or Inf values")
        return z

    @property
    def first_layer_cache(self) -> dict[str, torch.Tensor]:
        """Each network's first layer on the canonical cloud (`precompute`), shared by `offsets`, FastPoser and
        sensitivity; emptied by `invalidate_caches`."""
        return self._first_layer

    def invalidate_caches(self) -> None:
        """Drop cached per-Gaussian terms (call after editing the cloud or the networks); bumps `version`."""
        self._first_layer.clear()
        self._canonical = None
        self._content_key = None
        self.version += 1

    def content_key(self) -> str:
        """Hex hash of everything posing depends on: cloud arrays, network weights, rotation op (cached per
        `version`). Derived caches (preview model, baked sequences) are keyed by it."""
        if self._content_key is None:
            h = hashlib.blake2b(digest_size=20)
            arrays = sorted(self.cloud.arrays().items())
            if self.dynamics is not None:
                h.update(repr(sorted(self.dynamics.rules.items())).encode())
                h.update(repr([n.config.to_json() for n in self.dynamics.networks().values()]).encode())
                arrays += [(k, t.detach().cpu().numpy()) for k, t in sorted(self.dynamics.state_dict().items())]
                rig = self.dynamics.rig
                if rig is not None:
                    h.update(repr((rig.channels, rig.carrier, rig.turns_covariance)).encode())
                    arrays += [("rig.support", rig.support), ("rig.deltas", rig.deltas), ("rig.scale", rig.scale),
                               ("rig.bias", rig.bias), ("rig.transform", rig.transform)]
                    if rig.vertices is not None:
                        arrays.append(("rig.vertices", rig.vertices))
                    if rig.skin is not None:
                        h.update(repr(rig.skin.joint_names).encode())
                        arrays += [(f"rig.skin.{k}", getattr(rig.skin, k)) for k in SKIN_ARRAYS]
            for name, arr in arrays:
                a = np.ascontiguousarray(arr)
                h.update(f"{name}{a.dtype.str}{a.shape}".encode())
                h.update(a.reshape(-1).view(np.uint8))  # type: ignore[arg-type]
            self._content_key = h.hexdigest()
        return self._content_key

    def canonical_tensors(self) -> dict:
        """The canonical cloud as torch tensors (cached until `invalidate_caches`), as posing reads it."""
        if self._canonical is None:
            self._canonical = cloud_tensors(self.cloud)
        return self._canonical

    @torch.no_grad()
    def offsets(self, z: np.ndarray, chunk: int = 2048, timings: dict[str, float] | None = None) -> Offsets:
        """Offsets at code z by the fast path (first layer's per-Gaussian part cached).

        If `timings` is given, the milliseconds spent in each network are stored under "F" and "G".
        """
        if self.dynamics is None:
            raise ValueError("this avatar has no dynamics")
        zfull = self.check_code(z)
        zt = torch.from_numpy(zfull[: self.dynamics.network_dim])
        t = self.canonical_tensors()
        blend = blend_tensors(t, self.cloud.blend_names)
        by = {}
        for key, net in self.dynamics.networks().items():
            if key not in self._first_layer:
                self._first_layer[key] = net.precompute(t["means"], t["features"])
            gi = (t["means"], t["features"]) if net.config.skips else None
            t0 = time.perf_counter()
            out = net.evaluate(self._first_layer[key], zt, chunk=chunk, gaussian_inputs=gi)
            acc = {a: torch.zeros(len(out), w) for a, w in attribute_widths({key: net}).items()}
            route_into(acc, net, out, None if net.config.blend is None else blend[net.config.blend])
            by[key] = acc
            if timings is not None:
                timings[key] = (time.perf_counter() - t0) * 1000.0
        if self.dynamics.rig is not None:
            t0 = time.perf_counter()
            by[RIG] = self.dynamics.rig_attribute_offsets(zfull, t["means"])
            if timings is not None:
                timings[RIG] = (time.perf_counter() - t0) * 1000.0
        return Offsets(by)

    @torch.no_grad()
    def offsets_reference(self, z: np.ndarray) -> Offsets:
        """Offsets by the plain forward passes (slow; the definition the fast path is tested against)."""
        if self.dynamics is None:
            raise ValueError("this avatar has no dynamics")
        t = self.canonical_tensors()
        return self.dynamics.offsets(t["means"], t["features"], torch.from_numpy(self.check_code(z)),
                                     blend_tensors(t, self.cloud.blend_names))

    @torch.no_grad()
    def pose(self, z: np.ndarray | None = None, reference: bool = False, timings: dict[str, float] | None = None,
             head: np.ndarray | None = None) -> PosedGaussians:
        """Posed, activated Gaussians at frame vector z (None: the mean code; static avatars ignore z), moved by
        the rigid head transform `head` (4x4 similarity, canonical -> world) when given."""
        if self.dynamics is None:
            posed = self.cloud.posed_static()
        else:
            z = self.neutral_code() if z is None else z
            off = self.offsets_reference(z) if reference else self.offsets(z, timings=timings)
            posed = to_posed_gaussians(apply_offsets(self.canonical_tensors(), off, self.dynamics.rules))
            rig = self.dynamics.rig
            if rig is not None and not rig.identity_transform:
                posed = rig_transformed(posed, rig)
        return posed if head is None else transform_posed(posed, head)


def rig_transformed(posed: PosedGaussians, rig: LinearRig) -> PosedGaussians:
    """Posed Gaussians through the rig's rest transform: the centres only unless the rig turns covariances."""
    if rig.turns_covariance:
        return transform_posed(posed, rig.transform)
    return PosedGaussians(rig.move_centres(posed.means), posed.quats, posed.scales, posed.opacities, posed.sh,
                          posed.latent)
