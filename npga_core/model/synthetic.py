"""Random but well-formed avatars of any size, for tests and benchmarks.

The cloud is a head-sized ellipsoid shell (metres) with smooth colours and features; F and G are
paper-sized MLPs (6 layers, 256 wide, 100-D codes by default) whose last layers are scaled so that offsets are
millimetres for position and small for the other attributes, as in a trained avatar.
"""

from __future__ import annotations

import numpy as np
import torch

from npga_core.model.avatar import Avatar
from npga_core.model.cnn import CNNConfig, ConvLayer, ScreenCNN
from npga_core.model.dynamics import ConditionedMLP, Dynamics, MLPConfig, output_widths
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import GaussianCloud, logit, rgb_to_sh0, sh_coeff_count

HEAD_RADII = np.array([0.075, 0.10, 0.09], np.float32)


def _shell_points(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    d = rng.standard_normal((n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = 1.0 + 0.02 * rng.standard_normal((n, 1)).astype(np.float32)
    return d * r * HEAD_RADII, d


def _random_mlp(cfg: MLPConfig, gen: torch.Generator, out_scale: torch.Tensor, mu_scale: float,
                code_std: np.ndarray | None) -> ConditionedMLP:
    net = ConditionedMLP(cfg)
    with torch.no_grad():
        for layer in net.layers:
            bound = np.sqrt(6.0 / layer.weight.shape[1])  # type: ignore[index]  # He-uniform keeps activations O(1) through depth
            layer.weight.uniform_(-bound, bound, generator=gen)  # type: ignore[arg-type, operator]
            layer.bias.uniform_(-0.1, 0.1, generator=gen)  # type: ignore[operator]
        last = net.layers[-1]
        last.weight.mul_(out_scale[:, None])  # type: ignore[operator]
        last.bias.mul_(out_scale)  # type: ignore[operator]
        net.input_scale[:3] = 1.0 / mu_scale  # type: ignore[operator]
        if code_std is not None:
            net.input_scale[3 + cfg.feature_dim :] = torch.from_numpy(1.0 / np.maximum(code_std, 1e-6))  # type: ignore[operator]
    net.eval()
    return net


def make_synthetic_avatar(
    n: int,
    *,
    sh_degree: int = 3,
    feature_dim: int = 8,
    latent_dim: int = 0,
    code_dim: int = 100,
    hidden: int = 256,
    depth: int = 6,
    with_f: bool = True,
    with_g: bool = True,
    with_cnn: bool = False,
    n_components: int = 30,
    parts: bool = True,
    seed: int = 0,
) -> Avatar:
    """A random avatar with `n` Gaussians; deterministic in `seed`."""
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    means, normals = _shell_points(rng, n)
    spacing = float(np.sqrt(4 * np.pi * HEAD_RADII.mean() ** 2 / max(n, 1)))
    log_scales = np.log(spacing * np.exp(0.3 * rng.standard_normal((n, 3)))).astype(np.float32)
    log_scales[:, 2] += np.log(0.2)
    quats = rng.standard_normal((n, 4)).astype(np.float32)
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    base = 0.55 + 0.25 * np.sin(3.0 * normals + rng.uniform(0, np.pi, 3)).astype(np.float32)
    sh = np.zeros((n, sh_coeff_count(sh_degree), 3), np.float32)
    sh[:, 0] = rgb_to_sh0(np.clip(base + 0.03 * rng.standard_normal((n, 3)), 0, 1))
    if sh_degree:
        sh[:, 1:] = 0.05 * rng.standard_normal(sh[:, 1:].shape)
    phases = rng.uniform(0, 2 * np.pi, (feature_dim, 3)).astype(np.float32)
    features = np.sin(normals @ (2.0 * phases.T) + phases[:, 0]).astype(np.float32) if feature_dim else \
        np.zeros((n, 0), np.float32)
    latent = (0.1 * rng.standard_normal((n, latent_dim))).astype(np.float32) if latent_dim else None
    part_names = ["face", "back_head", "neck"] if parts else []
    part_ids = None
    if parts:
        part_ids = np.where(normals[:, 2] > 0.2, 0, np.where(normals[:, 1] < -0.6, 2, 1)).astype(np.int16)
    cloud = GaussianCloud(means, quats, log_scales, logit(rng.uniform(0.6, 0.99, n)), sh, features, latent,
                          part_ids, part_names)

    code_std = (1.0 / (1.0 + 0.15 * np.arange(code_dim))).astype(np.float32)
    codes = rng.standard_normal((max(400, 2 * code_dim), code_dim)).astype(np.float32) * code_std
    dynamics = None
    if with_f or with_g:
        F = G = None
        mu_scale = float(HEAD_RADII.max())
        if with_f:
            cfg = MLPConfig(feature_dim, code_dim, [("position", 3)], hidden, depth)
            F = _random_mlp(cfg, gen, torch.full((3,), 2e-3), mu_scale, code_std)
        if with_g:
            widths = output_widths(sh_degree, latent_dim)
            outputs = [(k, widths[k]) for k in ("position", "rotation", "scale", "opacity", "sh", "latent")
                       if widths[k]]
            scale_of = {"position": 5e-4, "rotation": 0.02, "scale": 0.05, "opacity": 0.1, "sh": 0.05, "latent": 0.05}
            out_scale = torch.cat([torch.full((w,), scale_of[k]) for k, w in outputs])
            G = _random_mlp(MLPConfig(feature_dim, code_dim, outputs, hidden, depth), gen, out_scale, mu_scale,
                            code_std)
        dynamics = Dynamics(F, G)
    cnn = None
    if with_cnn:
        c_in = 3 + latent_dim
        cnn = ScreenCNN(CNNConfig([ConvLayer(c_in, 16, 3, "relu"), ConvLayer(16, 16, 3, "relu"),
                                   ConvLayer(16, 3, 3, None)], residual=True))
        with torch.no_grad():
            for p in cnn.parameters():
                p.uniform_(-0.05, 0.05, generator=gen)
        cnn.eval()
    expression = ExpressionSpace.from_codes(codes, n_components) if (with_f or with_g) else None
    if expression is not None:
        expression.named = {"neutral": expression.mean.copy(), "sample": codes[0].copy()}
    return Avatar(cloud, dynamics, cnn, expression, provenance={"source": "synthetic", "seed": seed}, units="m")
