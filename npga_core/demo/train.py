"""Training the demo's dynamics on the CPU: F (positions, with learned per-Gaussian features) and G.

F is distilled from the blendshape model as in NPGA's prior distillation: supervised on the Gaussians and on
extra canonical surface points (whose features are interpolated from the nearest Gaussians), with a small
penalty on the offset size and the Laplacian smoothness term on the kNN graph of the features. G is then
trained with the features frozen, to the frame rotation, axis stretch and shading targets, with the
Laplacian term on its offsets. Both run in fp32 on large random batches of (point, expression) pairs.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from npga_core.demo.targets import AppearanceTargets, HeadTargets
from npga_core.inspection.graph import laplacian_penalty
from npga_core.model.dynamics import ConditionedMLP, MLPConfig
from npga_core.model.gaussians import SH_C0

Log = Callable[[str], None]
MM = 1000.0


@dataclass
class FConfig:
    steps: int = 5400
    batch: int = 8192
    lr: float = 2e-3
    feature_lr: float = 3e-3
    warmup: int = 100
    final_lr_fraction: float = 0.02
    out_scale: float = 0.005  # metres per unit of the raw last layer during training
    extra_fraction: float = 0.2  # share of each batch drawn from the extra canonical points
    offset_weight: float = 1e-4  # R_delta on F's offsets (in mm^2)
    laplacian_weight: float = 0.02  # R_lap on the features
    loss: str = "mixed"  # "l2": squared error (mm^2); "norm": Charbonnier of the error length (mm); "mixed": both
    uniform_fraction: float = 0.3  # share of Gaussians drawn uniformly; the rest where the expression moves them
    laplacian_rows: int = 8192
    hidden: int = 256
    depth: int = 6
    pos_freqs: int = 4
    activation: str = "relu"


@dataclass
class GConfig:
    steps: int = 900
    batch: int = 8192
    expressions_per_step: int = 16
    uniform_fraction: float = 0.3
    lr: float = 2e-3
    warmup: int = 50
    final_lr_fraction: float = 0.02
    pos_freqs: int = 6
    laplacian_weight: float = 0.05
    laplacian_anchors: int = 512
    out_scales: tuple[tuple[str, float], ...] = (("rotation", 0.05), ("scale", 0.1), ("sh", 0.5))


def lr_factor(step: int, steps: int, warmup: int, final: float) -> float:
    """Linear warm-up, then cosine decay to `final` times the peak."""
    if step < warmup:
        return (step + 1) / warmup
    t = (step - warmup) / max(1, steps - warmup)
    return final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * t))


def standardise_inputs(net: ConditionedMLP, means: np.ndarray, features: np.ndarray, codes: np.ndarray) -> None:
    """Set the input normalisation so mu, f and z enter with zero mean and unit std per dimension."""
    raw = [means, features, codes]
    shift = np.concatenate([a.mean(axis=0) for a in raw])
    scale = np.concatenate([1.0 / np.maximum(a.std(axis=0), 1e-6) for a in raw])
    net.input_shift.copy_(torch.from_numpy(shift.astype(np.float32)))  # type: ignore[operator]
    net.input_scale.copy_(torch.from_numpy(scale.astype(np.float32)))  # type: ignore[operator]


@torch.no_grad()
def fold_output_scale(net: ConditionedMLP, scales: dict[str, float]) -> None:
    """Multiply the last layer's rows of each output block by its training-time scale (exact)."""
    last = net.layers[-1]
    o = 0
    for name, width in net.config.outputs:
        s = scales.get(name, 1.0)
        last.weight[o:o + width] *= s  # type: ignore[index, operator]
        last.bias[o:o + width] *= s  # type: ignore[index, operator]
        o += width


def _scale_vector(net: ConditionedMLP, scales: dict[str, float]) -> torch.Tensor:
    return torch.cat([torch.full((w,), scales.get(n, 1.0)) for n, w in net.config.outputs])


def init_features(unit_disp: torch.Tensor, dim: int) -> np.ndarray:
    """Initial features: the leading principal components of each point's motion under every single shape
    (each shape scaled to a largest motion of 1), whitened. Smooth over the surface, and different on surfaces
    that move differently (upper and lower lip, eyelid and eyeball)."""
    x = unit_disp.double()
    x = x / x.norm(dim=2).amax(dim=0)[None, :, None].clamp_min(1e-9)  # every shape counts alike
    x = x.reshape(x.shape[0], -1)
    x = x - x.mean(dim=0)
    cov = x.T @ x / x.shape[0]
    evals, evecs = torch.linalg.eigh(cov)
    comps = evecs[:, -dim:].flip(1)
    f = x @ comps
    f = f / f.std(dim=0).clamp_min(1e-12)
    return f.float().numpy()


@dataclass
class ExtraPoints:
    """Extra canonical points for distillation: their targets, and features interpolated from Gaussians."""

    targets: HeadTargets
    neighbours: torch.Tensor  # (M, k) Gaussian indices
    weights: torch.Tensor  # (M, k) interpolation weights, rows sum to 1

    def features(self, gaussian_features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return (gaussian_features[self.neighbours[idx]] * self.weights[idx][..., None]).sum(dim=1)


def make_extra_points(targets: HeadTargets, gauss_points: np.ndarray, gauss_normals: np.ndarray,
                      gauss_part: np.ndarray, points: np.ndarray, normals: np.ndarray, part: np.ndarray,
                      k: int = 4) -> ExtraPoints:
    """Inverse-distance weights over the k nearest Gaussians of the same part facing the same way."""
    nb = np.zeros((len(points), k), np.int64)
    wt = np.zeros((len(points), k), np.float32)
    for pid in np.unique(part):
        g = np.flatnonzero(gauss_part == pid)
        m = np.flatnonzero(part == pid)
        dist, j = cKDTree(gauss_points[g]).query(points[m], k=k)
        idx = g[j]
        agree = (gauss_normals[idx] * normals[m][:, None]).sum(-1) > 0.3
        agree[:, 0] |= ~agree.any(axis=1)  # always keep at least the nearest
        w = agree / np.maximum(dist, 1e-5)
        nb[m], wt[m] = idx, w / w.sum(axis=1, keepdims=True)
    return ExtraPoints(targets, torch.from_numpy(nb), torch.from_numpy(wt))


class ShapeSampler:
    """Draws points where an expression moves them: pick one of its shapes with probability proportional to
    its weight, then a point with probability proportional to its motion under that shape. Without this the
    few hundred eyelid points barely appear in a batch next to the tens of thousands the jaw moves."""

    def __init__(self, unit_disp: torch.Tensor):
        motion = unit_disp.norm(dim=2).T.double()  # (E, N)
        motion = motion + 1e-12
        self.cdf = (motion.cumsum(dim=1) / motion.sum(dim=1, keepdim=True)).float()
        self.cdf[:, -1] = 1.0

    def sample(self, w: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        shapes = torch.multinomial(w + 1e-6, 1, generator=gen).squeeze(1)
        u = torch.rand(len(w), generator=gen)
        out = torch.empty(len(w), dtype=torch.long)
        for k in torch.unique(shapes).tolist():
            m = shapes == k
            out[m] = torch.searchsorted(self.cdf[k], u[m]).clamp(max=self.cdf.shape[1] - 1)
        return out


def train_f(means: np.ndarray, features0: np.ndarray, targets: HeadTargets, extra: ExtraPoints | None,
            weights: np.ndarray, codes: np.ndarray, nbrs: np.ndarray, unit_disp: torch.Tensor, cfg: FConfig,
            seed: int, log: Log = print) -> tuple[ConditionedMLP, np.ndarray]:
    """Train F and the features; returns F (output scale folded in, ready to save) and the features."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    net = ConditionedMLP(MLPConfig(features0.shape[1], codes.shape[1], [("position", 3)], hidden=cfg.hidden,
                                   depth=cfg.depth, pos_freqs=cfg.pos_freqs, activation=cfg.activation))
    standardise_inputs(net, means, features0, codes)
    feats = torch.nn.Parameter(torch.from_numpy(features0.copy()))
    opt = torch.optim.Adam([{"params": net.parameters(), "lr": cfg.lr},
                            {"params": [feats], "lr": cfg.feature_lr}])
    base_lrs = [g["lr"] for g in opt.param_groups]
    mu = torch.from_numpy(means)
    w_all, z_all = torch.from_numpy(weights), torch.from_numpy(codes)
    nbrs_t = torch.from_numpy(nbrs.astype(np.int64))
    shape_sampler = ShapeSampler(unit_disp)
    n_extra = int(cfg.batch * cfg.extra_fraction) if extra is not None else 0
    n_main = cfg.batch - n_extra
    n_uniform = int(n_main * cfg.uniform_fraction)
    scale = cfg.out_scale * MM
    t0 = time.perf_counter()
    run = 0.0
    for step in range(cfg.steps):
        f = lr_factor(step, cfg.steps, cfg.warmup, cfg.final_lr_fraction)
        for g, lr in zip(opt.param_groups, base_lrs, strict=True):
            g["lr"] = lr * f
        ei = torch.randint(0, len(w_all), (cfg.batch,), generator=gen)
        w, z = w_all[ei], z_all[ei]
        gi = torch.cat([torch.randint(0, len(mu), (n_uniform,), generator=gen),
                        shape_sampler.sample(w[n_uniform:n_main], gen)])
        mu_b, f_b = mu[gi], feats[gi]
        tgt = targets.offsets(gi, w[:n_main])
        if n_extra:
            assert extra is not None  # n_extra is 0 without extra points
            xi = torch.randint(0, len(extra.targets), (n_extra,), generator=gen)
            mu_b = torch.cat([mu_b, extra.targets.rest[xi]])
            f_b = torch.cat([f_b, extra.features(feats, xi)])
            tgt = torch.cat([tgt, extra.targets.offsets(xi, w[n_main:])])
        pred = net(mu_b, f_b, z) * scale  # mm
        err = (pred - tgt * MM).pow(2).sum(dim=1)
        charbonnier = (err + 0.01).sqrt().mean()
        data = {"l2": err.mean(), "norm": charbonnier, "mixed": charbonnier + 0.1 * err.mean()}[cfg.loss]
        loss = data + cfg.offset_weight * pred.pow(2).sum(dim=1).mean()
        rows = torch.randint(0, len(mu), (cfg.laplacian_rows,), generator=gen)
        loss = loss + cfg.laplacian_weight * laplacian_penalty(feats, nbrs_t, rows)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        run = 0.98 * run + 0.02 * float(err.detach().mean()) if step else float(err.detach().mean())
        if step % 200 == 0 or step == cfg.steps - 1:
            log(f"  F step {step:5d}/{cfg.steps}  rms {math.sqrt(run):.3f} mm  lr x{f:.3f}  "
                f"{time.perf_counter() - t0:6.1f} s")
    fold_output_scale(net, {"position": cfg.out_scale})
    return net, feats.detach().numpy().copy()


@torch.no_grad()
def f_errors(net: ConditionedMLP, means: np.ndarray, features: np.ndarray, targets: HeadTargets,
             weights: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Position error (T, N) in mm of F on every point at each expression (fast evaluation path)."""
    mu, f = torch.from_numpy(means), torch.from_numpy(features)
    first = net.precompute(mu, f)
    idx = torch.arange(len(mu))
    out = np.empty((len(weights), len(mu)), np.float32)
    for t in range(len(weights)):
        pred = net.evaluate(first, torch.from_numpy(codes[t]))
        w = torch.from_numpy(weights[t]).expand(len(mu), -1)
        out[t] = ((pred - targets.offsets(idx, w)).norm(dim=1) * MM).numpy()
    return out


@torch.no_grad()
def offset_magnitudes(targets: HeadTargets, weights: np.ndarray) -> np.ndarray:
    """Target offset lengths (T, N) in mm (the size of what F has to reproduce)."""
    idx = torch.arange(len(targets))
    return np.stack([(targets.offsets(idx, torch.from_numpy(w).expand(len(idx), -1)).norm(dim=1) * MM).numpy()
                     for w in weights])


def train_g(means: np.ndarray, features: np.ndarray, targets: AppearanceTargets, weights: np.ndarray,
            codes: np.ndarray, nbrs: np.ndarray, unit_disp: torch.Tensor, cfg: GConfig, seed: int,
            log: Log = print) -> ConditionedMLP:
    """Train G (rotation, scale and SH-DC offsets) with the features frozen; returns G ready to save."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    outputs = [("rotation", 4), ("scale", 3), ("sh", 3)]
    net = ConditionedMLP(MLPConfig(features.shape[1], codes.shape[1], outputs, pos_freqs=cfg.pos_freqs))
    standardise_inputs(net, means, features, codes)
    scales = dict(cfg.out_scales)
    out_scale = _scale_vector(net, scales)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    mu, f = torch.from_numpy(means), torch.from_numpy(features)
    w_all, z_all = torch.from_numpy(weights), torch.from_numpy(codes)
    nbrs_t = torch.from_numpy(nbrs.astype(np.int64))
    n = len(mu)
    shape_sampler = ShapeSampler(unit_disp)
    n_uniform = int(cfg.batch * cfg.uniform_fraction)
    t0 = time.perf_counter()
    norm = None
    run = 0.0
    for step in range(cfg.steps):
        fac = lr_factor(step, cfg.steps, cfg.warmup, cfg.final_lr_fraction)
        for g in opt.param_groups:
            g["lr"] = cfg.lr * fac
        ei = torch.randint(0, len(w_all), (cfg.expressions_per_step,), generator=gen)
        w = w_all[ei]
        fv = targets.vertex_gradients(w)
        slot = torch.randint(0, cfg.expressions_per_step, (cfg.batch,), generator=gen)
        gi = torch.cat([torch.randint(0, n, (n_uniform,), generator=gen),
                        shape_sampler.sample(w[slot[n_uniform:]], gen)])
        tg = targets.g_targets(gi, slot, w, fv)
        tgt = torch.cat([tg.rotation, tg.scale, tg.sh], dim=1) / out_scale
        if norm is None:  # per-column loss weights: targets of every block count alike
            norm = 1.0 / tgt.std(dim=0).clamp_min(0.05)
        pred = net(mu[gi], f[gi], z_all[ei][slot])
        err = ((pred - tgt) * norm).pow(2).mean()
        # Laplacian smoothness of the offsets on the kNN graph, at one expression
        anchors = torch.randint(0, n, (cfg.laplacian_anchors,), generator=gen)
        ring = torch.cat([anchors[:, None], nbrs_t[anchors]], dim=1).reshape(-1)
        out_ring = net(mu[ring], f[ring], z_all[ei[0]]).reshape(len(anchors), -1, pred.shape[1])
        lap = (out_ring[:, 1:].mean(dim=1) - out_ring[:, 0]).mul(norm).pow(2).mean()
        loss = err + cfg.laplacian_weight * lap
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        run = 0.98 * run + 0.02 * float(err.detach()) if step else float(err.detach())
        if step % 100 == 0 or step == cfg.steps - 1:
            log(f"  G step {step:5d}/{cfg.steps}  normalised mse {run:.4f}  {time.perf_counter() - t0:6.1f} s")
    fold_output_scale(net, scales)
    return net


@torch.no_grad()
def g_errors(net: ConditionedMLP, means: np.ndarray, features: np.ndarray, targets: AppearanceTargets,
             weights: np.ndarray, codes: np.ndarray, per_expression: int = 20000, seed: int = 0) -> dict[str, float]:
    """Mean absolute errors of G's blocks against its targets on held-out expressions (random points), also over
    the points that turn by more than 2 degrees or darken by more than 0.01, with the targets' size there."""
    gen = torch.Generator().manual_seed(seed)
    mu, f = torch.from_numpy(means), torch.from_numpy(features)
    keys = ("rotation_deg", "rotation_deg_moving", "target_rotation_deg_moving", "scale", "sh_rgb",
            "sh_rgb_shaded", "target_sh_rgb_shaded")
    sums = dict.fromkeys(keys, 0.0)
    w_all = torch.from_numpy(weights)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0])
    for t in range(len(weights)):
        fv = targets.vertex_gradients(w_all[t:t + 1])
        gi = torch.randint(0, len(mu), (per_expression,), generator=gen)
        tg = targets.g_targets(gi, torch.zeros_like(gi), w_all[t:t + 1], fv)
        out = net.split(net(mu[gi], f[gi], torch.from_numpy(codes[t])))  # type: ignore[operator]
        q_pred = out["rotation"] + identity
        q_pred = q_pred / q_pred.norm(dim=1, keepdim=True)
        q_tgt = tg.rotation + identity
        ang = torch.rad2deg(2 * torch.arccos((q_pred * q_tgt).sum(dim=1).abs().clamp(max=1.0)))
        ang_tgt = torch.rad2deg(2 * torch.arccos(q_tgt[:, 0].clamp(max=1.0)))
        moving = ang_tgt > 2.0  # points whose frame turns by more than 2 degrees
        sh_err = ((out["sh"] - tg.sh) * SH_C0).abs().mean(dim=1)
        shaded = (tg.sh * SH_C0).abs().mean(dim=1) > 0.01  # points darkened by more than 1 % (of 255)
        sums["rotation_deg"] += float(ang.mean())
        sums["rotation_deg_moving"] += float(ang[moving].mean()) if moving.any() else 0.0
        sums["target_rotation_deg_moving"] += float(ang_tgt[moving].mean()) if moving.any() else 0.0
        sums["scale"] += float((out["scale"] - tg.scale).abs().mean())
        sums["sh_rgb"] += float(sh_err.mean())
        sums["sh_rgb_shaded"] += float(sh_err[shaded].mean()) if shaded.any() else 0.0
        sums["target_sh_rgb_shaded"] += float((tg.sh[shaded] * SH_C0).abs().mean()) if shaded.any() else 0.0
    return {k: v / len(weights) for k, v in sums.items()}
