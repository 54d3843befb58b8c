"""Sensitivity of positions to the expression: exact Jacobian-vector products through F and G (and a rig).

`position_jvp` gives d mu_i / d s along an expression direction (`expression_direction`: one standard deviation
along a PCA direction) by forward-mode differentiation through the MLPs (`mlp_jvp`), at the current code.
"""

from __future__ import annotations

import warnings
from typing import cast

import numpy as np
import torch

from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import ConditionedMLP


def expression_direction(avatar: Avatar, k: int) -> np.ndarray:
    """The code change (D,) of one standard deviation along PCA direction k (0-based) of the expression space;
    without an expression space, the unit vector of code axis k."""
    d = avatar.code_dim
    ex = avatar.expression
    if ex is not None:
        if not 0 <= k < ex.n_components:
            raise ValueError(f"direction {k} outside 0..{ex.n_components - 1}")
        return (ex.std[k] * ex.basis[k]).astype(np.float32)
    if not 0 <= k < d:
        raise ValueError(f"direction {k} outside 0..{d - 1}")
    v = np.zeros(d, np.float32)
    v[k] = 1.0
    return v


def _activation_jvp(net: ConditionedMLP, pre: torch.Tensor, dpre: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(act(pre), act'(pre) * dpre) for the network's elementwise activation."""
    if net.config.activation == "relu":
        return torch.relu(pre), dpre * (pre > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch scripts its jvp decompositions once
        return cast(tuple[torch.Tensor, torch.Tensor], torch.func.jvp(net._act, (pre,), (dpre,)))


@torch.no_grad()
def mlp_jvp(net: ConditionedMLP, first: torch.Tensor, z: torch.Tensor, v: torch.Tensor, cols: slice,
            gaussian_inputs: tuple[torch.Tensor, torch.Tensor], chunk: int = 4096) -> torch.Tensor:
    """Forward-mode derivative of output columns `cols` of `net` along the code direction v at code z: (N, width).

    Mirrors `ConditionedMLP.evaluate` (`first` is `precompute`'s per-Gaussian first layer): only the code
    enters the first layer's tangent, a constant vector; each later layer maps (h, dh) to (W h + b, W dh), each
    activation multiplies dh by its derivative; skip inputs carry the code's tangent too.
    """
    c = net.config
    gw = c.mu_encoded_dim + c.feature_dim
    dz = v * net.input_scale[3 + c.feature_dim:]  # type: ignore[index]  # tangent of the normalised code
    dpre0 = net.layers[0].weight[:, gw:] @ dz  # type: ignore[index]
    zt = net.code_term(z)
    zc = net.encode_code(z) if c.skips else None
    n = first.shape[0]
    out = torch.empty(n, cols.stop - cols.start)
    if c.depth == 1:
        out[:] = dpre0[cols]
        return out
    last = net.layers[-1]
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        m = e - s
        pre, dpre = first[s:e] + zt, dpre0.expand(m, -1)
        for i in range(1, c.depth):
            h, dh = _activation_jvp(net, pre, dpre)
            if i in c.skips:
                mu, f = gaussian_inputs
                assert zc is not None  # encoded when the network has skips
                h = torch.cat([h, net.encode_gaussian(mu[s:e], f[s:e]), zc.expand(m, -1)], dim=-1)
                dh = torch.cat([dh, torch.zeros(m, gw), dz.expand(m, -1)], dim=-1)
            if i < c.depth - 1:
                layer = net.layers[i]
                pre, dpre = torch.addmm(layer.bias, h, layer.weight.t()), dh @ layer.weight.t()  # type: ignore[arg-type, operator]
        out[s:e] = dh @ last.weight[cols].t()  # type: ignore[index]
    return out


def position_jvp(avatar: Avatar, code: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """d mu / d t of every posed centre for z = code + t * direction at t = 0: (N, 3) float32.

    Exact forward-mode derivative of F's and G's position outputs with respect to the code (`mlp_jvp`), on the
    avatar's cached per-Gaussian first layers; about twice the cost of posing.
    """
    if avatar.dynamics is None:
        raise ValueError("this avatar has no dynamics")
    z = torch.from_numpy(avatar.check_code(code))
    v = torch.from_numpy(np.asarray(direction, np.float32).reshape(-1))
    t = avatar.canonical_tensors()
    total = torch.zeros(t["means"].shape[0], 3)
    for key, net in avatar.dynamics.networks().items():
        o, cols = 0, None
        for name, width in net.config.outputs:
            if name == "position":
                cols = slice(o, o + width)
            o += width
        if cols is None:
            continue
        first = avatar.first_layer_cache.get(key)  # the avatar's cache of `precompute`, shared with `Avatar.offsets`
        if first is None:
            first = avatar.first_layer_cache[key] = net.precompute(t["means"], t["features"])
        total += mlp_jvp(net, first, z, v, cols, (t["means"], t["features"]))
    rig = avatar.dynamics.rig
    if rig is not None and rig.skin is not None:  # a skinned mesh: central difference of the centres
        h, d = 1e-3, avatar.dynamics
        ahead = d.rig_attribute_offsets(z + h * v, t["means"])["position"]
        total += (ahead - d.rig_attribute_offsets(z - h * v, t["means"])["position"]) / (2 * h)
    elif rig is not None:  # linear: scale_k * delta_k per unit of channel k, then the rest transform's rotation
        total += rig.offsets(v[avatar.dynamics.network_dim :].numpy(), linear=True)
        if not rig.identity_transform:
            total = total @ torch.from_numpy(rig.transform[:3, :3].astype(np.float32)).t()
    return total.numpy()
