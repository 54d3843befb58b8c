"""Random checkpoints in Gaussian-Head-Avatar's layout, for tests and benchmarks (no GHA checkpoint is public).

`gha_state_dicts` returns what GHA's `torch.save(module.state_dict())` holds for `gaussianhead_latest` and
`supres_latest`: the key names and shapes of lib/module/GaussianHeadModule.py (xyz, feature,
landmarks_3d_neutral, scales, rotation, opacity and six `*_mlp.convN` Conv1d layers) and lib/network/Upsampler.py,
with GHA's default sizes from config/train_gaussianhead_N031.yaml. The head is a shell with the landmarks on its
face, so near, blended and far Gaussians are all present; the features are smooth over the head as GHA
initialises them; weights are random but scaled so that the colours, offsets and deformations stay in plausible
ranges.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

#: GHA's default MLP sizes (dims lists of config/train_gaussianhead_N031.yaml), feature width and pose encoding.
DEFAULT_DIMS = {
    "exp_color": [192, 256, 256, 32], "pose_color": [182, 128, 32],
    "exp_deform": [91, 256, 256, 256, 256, 256, 3], "pose_deform": [81, 256, 256, 3],
    "exp_attributes": [192, 256, 256, 256, 8], "pose_attributes": [182, 128, 128, 8],
}
FEATURE_DIM, EXP_DIM, POS_FREQ, SUPRES_CAPACITY = 128, 64, 4, 32


def _dims(feature_dim: int, exp_dim: int, hidden: int, channels: int, freqs: int) -> dict[str, list[int]]:
    pos, pose = 3 * (1 + 2 * freqs), 6 * (1 + 2 * freqs)
    if (feature_dim, exp_dim, hidden, channels, freqs) == (FEATURE_DIM, EXP_DIM, 256, 32, POS_FREQ):
        return {k: list(v) for k, v in DEFAULT_DIMS.items()}
    h2 = max(hidden // 2, 1)
    return {"exp_color": [feature_dim + exp_dim, hidden, hidden, channels],
            "pose_color": [feature_dim + pose, h2, channels],
            "exp_deform": [pos + exp_dim, hidden, hidden, hidden, 3], "pose_deform": [pos + pose, hidden, 3],
            "exp_attributes": [feature_dim + exp_dim, hidden, hidden, 8],
            "pose_attributes": [feature_dim + pose, h2, h2, 8]}


def _smooth_features(xyz: torch.Tensor, width: int, g: torch.Generator) -> torch.Tensor:
    """Features as GHA starts them (train_gaussianhead.py: atanh of its mesh head's per-vertex features, a tanh MLP
    of the encoded position, so smooth over the head), plus a little per-Gaussian variation from training."""
    enc = torch.cat([xyz] + [f(xyz * 2.0**k) for k in range(4) for f in (torch.sin, torch.cos)], 1)
    hidden = torch.relu(enc @ (torch.randn(enc.shape[1], 64, generator=g) * 0.8))
    field = torch.tanh(hidden @ (torch.randn(64, width, generator=g) * 0.3)).clamp(-0.95, 0.95)
    return torch.atanh(field) + 0.05 * torch.randn(len(xyz), width, generator=g)


def gha_state_dicts(n: int = 2000, seed: int = 0, feature_dim: int = FEATURE_DIM, exp_dim: int = EXP_DIM,
                    hidden: int = 256, channels: int = 32, freqs: int = POS_FREQ,
                    capacity: int = SUPRES_CAPACITY) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """(gaussianhead state dict, supres state dict) of a random GHA-layout avatar with `n` Gaussians."""
    rng = np.random.default_rng(seed)
    g = torch.Generator().manual_seed(seed)
    # a head-sized ellipsoid shell (GHA's units: its model_bbox spans about 3.2 x 3.5 x 3.5), face towards +z
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz = d * np.array([1.0, 1.25, 1.1]) * (1.0 + 0.03 * rng.standard_normal((n, 1)))
    lm_dir = rng.standard_normal((68, 3)) * np.array([0.35, 0.35, 0.1]) + np.array([0.0, 0.0, 1.0])
    lm_dir /= np.linalg.norm(lm_dir, axis=1, keepdims=True)
    landmarks = lm_dir * np.array([1.0, 1.25, 1.1])
    spacing = np.sqrt(4 * np.pi * 1.2**2 / n)
    state: dict[str, torch.Tensor] = {
        "xyz": torch.tensor(xyz, dtype=torch.float32),
        "feature": _smooth_features(torch.tensor(xyz, dtype=torch.float32), feature_dim, g),
        "landmarks_3d_neutral": torch.tensor(landmarks, dtype=torch.float32),
        "scales": torch.full((n, 3), float(np.log(spacing * 0.6))) + 0.2 * torch.randn(n, 3, generator=g),
        "rotation": torch.cat([torch.ones(n, 1), torch.zeros(n, 3)], 1) + 0.3 * torch.randn(n, 4, generator=g),
        "opacity": torch.full((n, 1), 2.0) + 0.5 * torch.randn(n, 1, generator=g),
    }
    skin = torch.tensor([0.75, 0.55, 0.45] + [0.5] * (channels - 3))
    for name, dims in _dims(feature_dim, exp_dim, hidden, channels, freqs).items():
        skip = len(dims) // 2
        for i in range(len(dims) - 1):
            fan_in = dims[i] + (dims[0] if i == skip else 0)
            last = i == len(dims) - 2
            gain = (0.004 if name.endswith("color") else 0.05) if last else np.sqrt(2.0 / fan_in)
            state[f"{name}_mlp.conv{i}.weight"] = torch.randn(dims[i + 1], fan_in, 1, generator=g) * gain
            bias = 0.02 * torch.randn(dims[i + 1], generator=g)
            if last and name.endswith("color"):
                bias = bias + skin[: dims[-1]]
            state[f"{name}_mlp.conv{i}.bias"] = bias
    supres: dict[str, torch.Tensor] = {}
    c4, c2, c1 = 4 * capacity, 2 * capacity, capacity
    for prefix, (c_in, c_mid, c_out) in {"upsampler.inc.double_conv": (channels, c4, c4),
                                         "upsampler.up1.conv.double_conv": (c4, c2, c2),
                                         "upsampler.up2.conv.double_conv": (c2, c1, c1)}.items():
        supres[f"{prefix}.0.weight"] = torch.randn(c_mid, c_in, 3, 3, generator=g) * np.sqrt(2.0 / (9 * c_in))
        supres[f"{prefix}.3.weight"] = torch.randn(c_out, c_mid, 3, 3, generator=g) * np.sqrt(2.0 / (9 * c_mid))
    supres["upsampler.outc.conv.weight"] = torch.randn(3, c1, 1, 1, generator=g) * 0.1
    supres["upsampler.outc.conv.bias"] = torch.zeros(3)
    return state, supres


def write_gha_folder(folder: str | Path, n: int = 2000, seed: int = 0, supres: bool = True, **kw: Any) -> Path:
    """Write `gaussianhead_latest` (and `supres_latest`) as GHA's Recorder does (torch.save of state dicts)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    head, sr = gha_state_dicts(n, seed, **kw)
    torch.save(head, folder / "gaussianhead_latest")
    if supres:
        torch.save(sr, folder / "supres_latest")
    return folder


def write_gha_params(root: str | Path, frames: int = 8, exp_dim: int = EXP_DIM, seed: int = 0) -> Path:
    """A GHA dataset's `params/NNNN/params.npz` frames (exp_coeff (1, E), pose (1, 6), scale (1,)), as its
    preprocessing writes them and lib/dataset/Dataset.py reads them."""
    rng = np.random.default_rng(seed)
    root = Path(root)
    for t in range(frames):
        d = root / "params" / f"{t:04d}"
        d.mkdir(parents=True, exist_ok=True)
        pose = np.concatenate([0.15 * np.sin(0.4 * t + np.arange(3)), 0.05 * rng.standard_normal(3)])[None]
        np.savez(d / "params.npz", exp_coeff=(0.5 * rng.standard_normal((1, exp_dim))).astype(np.float32),
                 pose=pose.astype(np.float32), scale=np.array([1.0 + 0.01 * t], np.float32))
    return root
