"""Refine stage of the demo build: latent features h, G's offsets of h and the screen-space CNN, trained.

``python -m npga_core.demo.build --stage refine`` (or ``python -m npga_core.demo.refine_stage``) starts from
the built ``avatar.npga`` (F, G and the cloud stay as they are) and trains, on the CPU,

- per-Gaussian latent features h (H channels),
- G's ``latent`` output block: new rows of G's last layer, a linear read-out of G's (frozen) last hidden layer,
  so G's other outputs do not change,
- the screen-space CNN ([RGB, latent image] -> refined RGB, residual),

end to end through the compositing: the latent image of a view is sum_i (h_i + delta_h_i(z)) w_i with the
blending weights w_i of the posed splats (`splat_raster.SplatImage`, which follows the GL renderer), so the
loss gradient reaches h and the read-out. The target is the ICT head itself, posed exactly and shaded per pixel
(`refine_targets.HeadRenderer`): what the 79k splats approximate, at full resolution. Training uses 128 x 128
crops of views at the window's pixel density (0.8-1.6 x the default 550 x 802 framing), random expressions,
directions and backgrounds; the report uses held-out expressions and views. See docs/DEMO.md.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch.nn import functional as nnf

from npga_core.camera.cameras import Camera, frame_points
from npga_core.demo.canonical import build_canonical
from npga_core.demo.colors import AlbedoModel
from npga_core.demo.expression_map import ExpressionMap
from npga_core.demo.expressions import ExpressionSampler
from npga_core.demo.ict import load_ict
from npga_core.demo.mesh_raster import crop_camera
from npga_core.demo.readme import DEFAULT_OUT, write_readme
from npga_core.demo.refine_targets import HeadRenderer
from npga_core.demo.sampling import sample_surface
from npga_core.demo.splat_raster import rasterize_splats
from npga_core.demo.train import lr_factor
from npga_core.files.checkpoint import save_avatar
from npga_core.files.loading import load_avatar
from npga_core.inspection.graph import knn, laplacian_penalty
from npga_core.model.avatar import Avatar
from npga_core.model.cnn import CNNConfig, ConvLayer, ScreenCNN
from npga_core.model.dynamics import ConditionedMLP, Dynamics, MLPConfig, cloud_tensors
from npga_core.model.gaussians import PosedGaussians

#: Backgrounds of the report: the window's default black and the documentation's light grey.
EVAL_BACKGROUNDS = ((0.0, 0.0, 0.0), (0.93, 0.93, 0.94))
#: Where crops are centred: a Gaussian of these parts (facing the camera), with these probabilities.
CROP_PARTS = {"face": 0.5, "head_neck": 0.2, "sclera_l": 0.05, "iris_l": 0.05, "sclera_r": 0.05, "iris_r": 0.05,
              "mouth_socket": 0.04, "gums_tongue": 0.03, "teeth": 0.03}


@dataclass
class RefineConfig:
    """Sizes of the refine stage; `quick` is a smoke-test version."""

    latent_dim: int = 6
    cnn_width: int = 16
    cnn_kernels: tuple[int, ...] = (3, 3, 3, 3)
    cnn_activation: str = "leaky_relu"
    train_expressions: int = 24
    crops_per_expression: int = 6
    test_expressions: int = 6
    test_crops_per_expression: int = 4
    crop: int = 128
    margin: int = 6  # border pixels left out of loss and report (the CNN zero-pads at crop borders)
    zoom: tuple[float, float] = (0.8, 1.6)  # pixel density relative to the default 550 x 802 framing
    yaw_deg: float = 60.0
    pitch_deg: float = 25.0
    steps: int = 2000
    batch: int = 8
    lr_cnn: float = 2e-3
    lr_latent: float = 1e-2
    lr_readout: float = 1e-3
    warmup: int = 50
    final_lr_fraction: float = 0.05
    laplacian_weight: float = 0.5  # 0.05 left dark blotches where few crops reach (neck under the chin)
    mse_weight: float = 10.0  # loss = L1 + mse_weight * MSE (on the inner crop)
    laplacian_anchors: int = 4096
    supersample: int = 2

    @staticmethod
    def quick() -> RefineConfig:
        return RefineConfig(train_expressions=4, crops_per_expression=3, test_expressions=2,
                            test_crops_per_expression=2, crop=64, steps=40, batch=4, warmup=5)


@dataclass
class Crop:
    """One training or test crop: the splat image and its blending matrix, the target, and the expression."""

    expr: int
    rgb: torch.Tensor  # (S, S, 3) premultiplied
    alpha: torch.Tensor  # (S, S, 1)
    target: torch.Tensor  # (S, S, 3) premultiplied
    coverage: torch.Tensor  # (S, S, 1)
    gaussians: np.ndarray  # (K,) Gaussian of each blending weight (until `link`)
    pixels: np.ndarray  # (K,) flat pixel of each weight
    weights: np.ndarray  # (K,) the weights a_i T_i
    blend: torch.Tensor | None = None  # (S*S, M) CSR: weights onto the expression's rows
    blend_t: torch.Tensor | None = None  # (M, S*S) CSR, its transpose (for the backward pass)

    def link(self, rows: np.ndarray) -> None:
        """Build the blending matrices against the expression's Gaussian rows (sorted)."""
        cols = np.searchsorted(rows, self.gaussians)
        n_pix = self.rgb.shape[0] * self.rgb.shape[1]
        self.blend = _csr(self.pixels, cols, self.weights, (n_pix, len(rows)))
        self.blend_t = _csr(cols, self.pixels, self.weights, (len(rows), n_pix))
        self.gaussians = self.pixels = self.weights = np.zeros(0)


def _csr(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, shape: tuple[int, int]) -> torch.Tensor:
    order = np.lexsort((cols, rows))
    crow = np.zeros(shape[0] + 1, np.int32)
    crow[1:] = np.cumsum(np.bincount(rows, minlength=shape[0]))
    return torch.sparse_csr_tensor(torch.from_numpy(crow), torch.from_numpy(cols[order].astype(np.int32)),
                                   torch.from_numpy(vals[order].astype(np.float32)), shape)


class _Blend(torch.autograd.Function):
    """blend @ x with the backward pass through the stored transpose (CSR times dense, both ways)."""

    @staticmethod
    def forward(ctx: Any, blend: torch.Tensor, blend_t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        ctx.blend_t = blend_t
        return torch.sparse.mm(blend, x)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[None, None, torch.Tensor]:
        return None, None, torch.sparse.mm(ctx.blend_t, grad.contiguous())


@dataclass
class ExpressionData:
    """The Gaussians the crops of one expression see, and G's last hidden layer for them (float16)."""

    weights: np.ndarray  # blendshape weights (E,)
    code: np.ndarray  # (D,)
    rows: torch.Tensor  # (M,) Gaussian indices
    hidden: torch.Tensor  # (M, hidden) float16
    crops: list[Crop] = field(default_factory=list)


# --- networks ------------------------------------------------------------------------------------------
@torch.no_grad()
def hidden_features(net: ConditionedMLP, first: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """G's last hidden layer (N, hidden) at code z from `net.precompute`'s first-layer term (ReLU, no skips)."""
    if net.config.activation != "relu" or net.config.skips or net.config.depth < 2:
        raise ValueError("the read-out needs a ReLU MLP without skips and with a hidden layer")
    h = torch.relu(first + net.code_term(z))
    for layer in net.layers[1:-1]:
        h = torch.relu(layer(h))
    return h


def with_latent_block(g: ConditionedMLP, weight: torch.Tensor, bias: torch.Tensor) -> ConditionedMLP:
    """G with a `latent` output block appended: rows `weight` (H, hidden), `bias` (H,) of the last layer."""
    c = g.config
    cfg = MLPConfig(c.feature_dim, c.code_dim, list(c.outputs) + [("latent", weight.shape[0])], hidden=c.hidden,
                    depth=c.depth, activation=c.activation, pos_freqs=c.pos_freqs, skips=list(c.skips))
    out = ConditionedMLP(cfg)
    state = {k: v.clone() for k, v in g.state_dict().items()}
    last = f"layers.{c.depth - 1}"
    state[f"{last}.weight"] = torch.cat([state[f"{last}.weight"], weight.detach().float()])
    state[f"{last}.bias"] = torch.cat([state[f"{last}.bias"], bias.detach().float()])
    out.load_state_dict(state)
    return out


def make_cnn(cfg: RefineConfig, seed: int) -> ScreenCNN:
    """The CNN: len(cnn_kernels) convolutions, cnn_width wide, `cnn_activation`, residual. The last layer starts
    at a tenth of PyTorch's default initialisation: near the raw splats, with gradients reaching every layer
    (a zero start with ReLU left most of the last hidden layer dead)."""
    torch.manual_seed(seed)
    k = cfg.cnn_kernels
    layers = [ConvLayer(3 + cfg.latent_dim if i == 0 else cfg.cnn_width, 3 if i == len(k) - 1 else cfg.cnn_width,
                        k[i], None if i == len(k) - 1 else cfg.cnn_activation) for i in range(len(k))]
    cnn = ScreenCNN(CNNConfig(layers, residual=True))
    with torch.no_grad():
        cnn.convs[-1].weight.mul_(0.1)  # type: ignore[operator]
        cnn.convs[-1].bias.zero_()  # type: ignore[operator]
    return cnn


# --- metrics -------------------------------------------------------------------------------------------
def psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """PSNR (dB, peak 1) of (..., 3, H, W) images, over `mask` (..., 1, H, W) if given."""
    err = (a - b).pow(2)
    if mask is not None:
        m = mask.expand_as(err)
        mse = float(err[m].mean()) if m.any() else 0.0
    else:
        mse = float(err.mean())
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def ssim(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean SSIM of (B, 3, H, W) images in [0, 1] (Gaussian window 11, sigma 1.5, as Wang et al. 2004)."""
    x = torch.arange(11, dtype=a.dtype) - 5
    g = torch.exp(-x * x / (2 * 1.5**2))
    g = g / g.sum()
    win = (g[:, None] * g[None, :]).expand(a.shape[1], 1, 11, 11)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return nnf.conv2d(t, win, groups=a.shape[1])

    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return float(s.mean())


# --- data ----------------------------------------------------------------------------------------------
class CropSampler:
    """Random views at the window's pixel density and crops centred on visible parts of the head."""

    def __init__(self, avatar: Avatar, cfg: RefineConfig, normals: np.ndarray):
        self.cfg = cfg
        m = np.asarray(avatar.cloud.means, np.float64)
        self.means = m
        self.head_points = m[m[:, 1] > np.percentile(m[:, 1], 12)]
        self.normals = normals
        part = np.asarray(avatar.cloud.part_ids)
        names = avatar.cloud.part_names
        self.groups = [(np.flatnonzero(part == names.index(k)), p) for k, p in CROP_PARTS.items() if k in names]

    def sample(self, rng: np.random.Generator) -> tuple[Camera, Camera]:
        """(crop camera, the whole view's camera)."""
        cfg = self.cfg
        direction = (rng.uniform(-cfg.yaw_deg, cfg.yaw_deg), rng.uniform(-cfg.pitch_deg, cfg.pitch_deg))
        base = frame_points(self.head_points, 550, 802, fov=20.0, direction=direction)
        zoom = math.exp(rng.uniform(*np.log(cfg.zoom)))
        cam = base.resized(round(550 * zoom), round(802 * zoom))
        probs = np.array([p for _, p in self.groups])
        for _ in range(50):  # a Gaussian facing the camera
            idx = self.groups[rng.choice(len(self.groups), p=probs / probs.sum())][0]
            g = idx[rng.integers(len(idx))]
            if np.dot(self.normals[g], cam.camera_center - self.means[g]) > 0:
                break
        u, v = cam.project(self.means[g:g + 1])[0] + rng.uniform(-0.25, 0.25, 2) * cfg.crop
        s = cfg.crop
        x0 = int(np.clip(round(u - s / 2), 0, cam.width - s))
        y0 = int(np.clip(round(v - s / 2), 0, cam.height - s))
        return crop_camera(cam, x0, y0, s, s), cam


def make_crop(posed: PosedGaussians, target: HeadRenderer, weights: np.ndarray, cameras: tuple[Camera, Camera],
              expr: int) -> Crop:
    """A crop (crop camera, whole view's camera) of the posed splats and the target (blending matrices built later
    by `Crop.link`)."""
    camera, view = cameras
    si = rasterize_splats(posed.means, posed.quats, posed.scales, posed.opacities, posed.sh, camera, fov_camera=view)
    tgt, cov = target.render(weights, camera)
    return Crop(expr, torch.from_numpy(si.rgb), torch.from_numpy(si.alpha)[..., None], torch.from_numpy(tgt),
                torch.from_numpy(cov)[..., None], si.gaussian, si.pixel, si.weight)


def build_data(avatar: Avatar, target: HeadRenderer, sampler: CropSampler, w: np.ndarray, z: np.ndarray,
               crops_each: int, rng: np.random.Generator, log: Callable[[str], object]) -> list[ExpressionData]:
    """Crops of every expression (posed by the avatar's F and G) with G's hidden layer on the Gaussians they see."""
    dyn = avatar.dynamics
    assert dyn is not None and dyn.G is not None  # the demo avatar has G
    g = dyn.G
    t = cloud_tensors(avatar.cloud)
    first = g.precompute(cast(torch.Tensor, t["means"]), cast(torch.Tensor, t["features"]))
    out = []
    for e in range(len(w)):
        posed = avatar.pose(z[e])
        crops = [make_crop(posed, target, w[e], sampler.sample(rng), e) for _ in range(crops_each)]
        rows = np.unique(np.concatenate([c.gaussians for c in crops]))
        for crop in crops:
            crop.link(rows)
        rows_t = torch.from_numpy(rows)
        hidden = hidden_features(g, first[rows_t], torch.from_numpy(z[e]))
        out.append(ExpressionData(w[e], z[e], rows_t, hidden.half(), crops))
        log(f"  expression {e + 1}/{len(w)}: {len(crops)} crops, {len(rows)} Gaussians seen")
    return out


# --- training ------------------------------------------------------------------------------------------
class RefineModel(torch.nn.Module):
    """h, the read-out (G's latent rows) and the CNN, and the forward pass from a crop to the refined image."""

    def __init__(self, h0: np.ndarray, hidden: int, cnn: ScreenCNN):
        super().__init__()
        self.h = torch.nn.Parameter(torch.from_numpy(h0.astype(np.float32)))
        self.readout_w = torch.nn.Parameter(torch.zeros(h0.shape[1], hidden))
        self.readout_b = torch.nn.Parameter(torch.zeros(h0.shape[1]))
        self.cnn = cnn

    def latent_rows(self, data: ExpressionData) -> torch.Tensor:
        """h + delta_h^G (M, H) of the Gaussians an expression's crops see."""
        return torch.index_select(self.h, 0, data.rows) + data.hidden.float() @ self.readout_w.T + self.readout_b

    def inputs(self, data: list[ExpressionData], crops: list[Crop], bgs: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """CNN inputs (B, 3+H, S, S) over the backgrounds and the targets (B, 3, S, S)."""
        xs, ts, rows = [], [], {}
        for crop, bg in zip(crops, bgs, strict=True):
            if crop.expr not in rows:
                rows[crop.expr] = self.latent_rows(data[crop.expr])
            size = crop.rgb.shape[0]
            lat = _Blend.apply(crop.blend, crop.blend_t, rows[crop.expr]).reshape(size, size, -1)
            rgb = crop.rgb + (1.0 - crop.alpha) * bg
            xs.append(torch.cat([rgb, lat], dim=2).permute(2, 0, 1))
            ts.append((crop.target + (1.0 - crop.coverage) * bg).permute(2, 0, 1))
        # channels-last: the CPU convolutions run about 3x faster on it (see model/cnn.py run_cnn)
        return torch.stack(xs).contiguous(memory_format=torch.channels_last), torch.stack(ts)


def random_backgrounds(n: int, gen: torch.Generator) -> torch.Tensor:
    """Black (40 %), light grey (30 %) or a random colour (30 %) per crop."""
    kind = torch.rand(n, generator=gen)
    rand = torch.rand(n, 3, generator=gen)
    light = torch.tensor([0.93, 0.93, 0.94])
    return torch.where((kind < 0.4)[:, None], torch.zeros(3), torch.where((kind < 0.7)[:, None], light, rand))


def train(model: RefineModel, data: list[ExpressionData], nbrs: torch.Tensor, cfg: RefineConfig, seed: int,
          log: Callable[[str], object]) -> list[float]:
    """Adam on L1 + mse_weight * MSE of the refined crops (inner part) + the Laplacian term on h; returns the L1
    curve."""
    gen = torch.Generator().manual_seed(seed)
    groups = [{"params": [model.h], "lr": cfg.lr_latent},
              {"params": [model.readout_w, model.readout_b], "lr": cfg.lr_readout},
              {"params": model.cnn.parameters(), "lr": cfg.lr_cnn}]
    opt = torch.optim.Adam(groups)
    base = [g["lr"] for g in opt.param_groups]
    m, s = cfg.margin, cfg.crop
    curve, run, t0 = [], 0.0, time.perf_counter()
    for step in range(cfg.steps):
        f = lr_factor(step, cfg.steps, cfg.warmup, cfg.final_lr_fraction)
        for g, lr in zip(opt.param_groups, base, strict=True):
            g["lr"] = lr * f
        # a batch from two expressions (h + delta_h is computed once per expression)
        exprs = torch.randint(0, len(data), (2,), generator=gen).tolist()
        batch = [data[exprs[i % 2]].crops[j % len(data[exprs[i % 2]].crops)] for i, j in enumerate(
            torch.randint(0, 1 << 30, (cfg.batch,), generator=gen).tolist())]
        x, t = model.inputs(data, batch, random_backgrounds(cfg.batch, gen))
        out = model.cnn(x)
        err = (out - t)[..., m:s - m, m:s - m]
        l1 = err.abs().mean()
        fit = l1 + cfg.mse_weight * err.pow(2).mean() if cfg.mse_weight else l1
        anchors = torch.randint(0, len(model.h), (cfg.laplacian_anchors,), generator=gen)
        loss = fit + cfg.laplacian_weight * laplacian_penalty(model.h, nbrs, anchors)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        l1v = float(l1.detach())
        run = 0.97 * run + 0.03 * l1v if step else l1v
        curve.append(l1v)
        if step % 100 == 0 or step == cfg.steps - 1:
            log(f"  step {step:5d}/{cfg.steps}  L1 {run:.4f}  lr x{f:.3f}  {time.perf_counter() - t0:6.1f} s")
    return curve


@torch.no_grad()
def evaluate(model: RefineModel, data: list[ExpressionData], cfg: RefineConfig) -> dict:
    """PSNR (whole inner crop and masked to the head) and SSIM of raw splats and CNN output vs the target, on
    every test crop over each report background."""
    m, s = cfg.margin, cfg.crop
    crops = [c for d in data for c in d.crops]
    res: dict[str, list[float]] = {k: [] for k in ("raw_psnr", "cnn_psnr", "raw_psnr_head", "cnn_psnr_head",
                                                   "raw_ssim", "cnn_ssim")}
    for bg in EVAL_BACKGROUNDS:
        bgs = torch.tensor([bg] * len(crops), dtype=torch.float32)
        x, t = model.inputs(data, crops, bgs)
        out = model.cnn(x).clamp(0.0, 1.0)
        raw = x[:, :3].clamp(0.0, 1.0)
        sl = (..., slice(m, s - m), slice(m, s - m))
        mask = torch.stack([torch.maximum(c.coverage, c.alpha).permute(2, 0, 1) for c in crops]) > 0.0
        for i in range(len(crops)):
            for name, img in (("raw", raw), ("cnn", out)):
                res[f"{name}_psnr"].append(psnr(img[i][sl], t[i][sl]))
                res[f"{name}_psnr_head"].append(psnr(img[i][sl], t[i][sl], mask[i][sl]))
                res[f"{name}_ssim"].append(ssim(img[i:i + 1][sl], t[i:i + 1][sl]))
    means = {k: round(float(np.mean(v)), 4) for k, v in res.items()}
    return means | {"crops": len(crops), "backgrounds": [list(b) for b in EVAL_BACKGROUNDS]}


def initial_latent(features: np.ndarray, dim: int) -> np.ndarray:
    """Start of h: channel 0 constant 1 (its image is the alpha), the others the leading principal components of
    the features f (unit variance); training moves all of them."""
    f = features - features.mean(axis=0)
    _, _, vt = np.linalg.svd(f, full_matrices=False)
    pcs = f @ vt[: dim - 1].T
    pcs /= np.maximum(pcs.std(axis=0), 1e-9)
    return np.concatenate([np.ones((len(f), 1)), pcs], axis=1).astype(np.float32)


# --- the stage -----------------------------------------------------------------------------------------
def refine(out: Path, seed: int = 0, cfg: RefineConfig | None = None, ict: Path | None = None, quick: bool = False,
           log: Callable[[str], object] = print) -> dict:
    """Train h, G's latent block and the CNN for `out`/avatar.npga and rewrite it; returns the stage summary."""
    cfg = cfg or (RefineConfig.quick() if quick else RefineConfig())
    t_start = time.perf_counter()

    def stamp(msg: str) -> None:
        log(f"[{time.perf_counter() - t_start:7.1f} s] refine: {msg}")

    path = Path(out) / "avatar.npga"
    avatar = load_avatar(path)
    if avatar.dynamics is None or avatar.dynamics.G is None:
        raise ValueError(f"{path}: no G to extend (build the base stage first)")
    if avatar.cloud.latent is not None or avatar.cnn is not None:
        raise ValueError(f"{path}: already has latent features or a CNN (rebuild the base stage first)")
    prov = dict(avatar.provenance)
    build_seed, n_target = int(prov.get("seed", seed)), 20000 if prov.get("quick") else 80000
    head = load_ict(ict)
    # the canonical samples and the colour model's random draws, exactly as the base stage made them
    canon = build_canonical(head, n_target, rng_for(build_seed, 1))
    g_rng = rng_for(build_seed, 1)
    samples = sample_surface(head, n_target, g_rng)
    albedo = AlbedoModel.draw(samples, g_rng)
    if len(samples) != len(avatar) or not np.array_equal(samples.points, np.asarray(avatar.cloud.means)):
        raise ValueError(f"{path}: its Gaussians are not the base stage's samples for seed {build_seed}")
    target = HeadRenderer(head, canon, albedo, cfg.supersample)
    emap = ExpressionMap.from_seed(build_seed, head.expression_names)
    sampler = ExpressionSampler(head.expression_names)
    w_train = sampler.sample(cfg.train_expressions, rng_for(seed, 20))
    w_test = sampler.sample(cfg.test_expressions, rng_for(seed, 24))  # streams 21, 23 served the tuning
    crops = CropSampler(avatar, cfg, samples.normals)
    stamp(f"{len(avatar)} Gaussians; making {cfg.train_expressions} x {cfg.crops_per_expression} training and "
          f"{cfg.test_expressions} x {cfg.test_crops_per_expression} test crops of {cfg.crop} px")
    train_data = build_data(avatar, target, crops, w_train, emap.encode(w_train), cfg.crops_per_expression,
                            rng_for(seed, 22), lambda m: stamp(m.strip()))
    test_data = build_data(avatar, target, crops, w_test, emap.encode(w_test), cfg.test_crops_per_expression,
                           rng_for(seed, 25), lambda m: stamp(m.strip()))
    t_data = time.perf_counter() - t_start
    model = RefineModel(initial_latent(np.asarray(avatar.cloud.features), cfg.latent_dim),
                        avatar.dynamics.G.config.hidden, make_cnn(cfg, seed + 7))
    before = evaluate(model, test_data, cfg)
    stamp(f"before training: raw PSNR {before['raw_psnr']:.2f} dB, initial CNN {before['cnn_psnr']:.2f} dB")
    nbrs = torch.from_numpy(knn(np.asarray(avatar.cloud.means), 8).astype(np.int64))
    stamp(f"training: {cfg.steps} steps of {cfg.batch} crops")
    t_train = time.perf_counter()
    curve = train(model, train_data, nbrs, cfg, seed + 8, lambda m: stamp(m.strip()))
    t_train = time.perf_counter() - t_train
    metrics = evaluate(model, test_data, cfg)
    metrics_train = evaluate(model, train_data[: max(1, len(test_data))], cfg)
    stamp(f"held-out: raw PSNR {metrics['raw_psnr']:.2f} dB -> CNN {metrics['cnn_psnr']:.2f} dB "
          f"(head only {metrics['raw_psnr_head']:.2f} -> {metrics['cnn_psnr_head']:.2f}), SSIM "
          f"{metrics['raw_ssim']:.4f} -> {metrics['cnn_ssim']:.4f}")
    with torch.no_grad():
        offsets = torch.cat([d.hidden.float() @ model.readout_w.T + model.readout_b for d in test_data])
    latent = model.h.detach().numpy().astype(np.float32)
    summary: dict[str, Any] = {
        "generator": "npga_core.demo.refine_stage",
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "seed": seed,
        "target": "ICT mesh posed by the blendshapes, shaded per pixel with the Gaussians' colour model "
                  "(npga_core/demo/refine_targets.py), 2x2 supersampled",
        "held_out": metrics,
        "held_out_initial_cnn": before,
        "training_crops_subset": metrics_train,
        "loss_first_last": [round(float(np.mean(curve[:20])), 5), round(float(np.mean(curve[-20:])), 5)],
        "latent_std": [round(float(v), 4) for v in latent.std(axis=0)],
        "latent_offset_std": [round(float(v), 4) for v in offsets.std(dim=0)],
        "data_seconds": round(t_data, 1),
        "train_seconds": round(t_train, 1),
        "machine": f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, "
                   f"torch {torch.__version__}",
    }
    new_cloud = avatar.cloud.copy()
    new_cloud.latent = latent
    g_new = with_latent_block(avatar.dynamics.G, model.readout_w, model.readout_b)
    dyn = Dynamics(avatar.dynamics.F, g_new, avatar.dynamics.rotation_op)
    summary["seconds"] = round(time.perf_counter() - t_start, 1)
    prov["refine"] = summary
    result = Avatar(new_cloud, dyn, cnn=model.cnn.eval(), expression=avatar.expression, provenance=prov,
                    units=avatar.units, blendshapes=avatar.blendshapes)
    # the posed latent of the saved networks (fast path) is what training composited
    d0 = test_data[0]
    with torch.no_grad():
        want = model.latent_rows(d0).numpy()
    posed_latent = result.pose(d0.code).latent
    assert posed_latent is not None  # the result has the trained latent block
    got = posed_latent[d0.rows.numpy()]
    summary["latent_check_max_abs"] = float(np.abs(got - want).max())
    if summary["latent_check_max_abs"] > 1e-2:
        raise RuntimeError(f"posed latent differs from the trained one by {summary['latent_check_max_abs']:.3g}")
    save_avatar(result, path)
    write_readme(Path(out), build_seed, bool(prov.get("quick")), prov)
    stamp(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MiB): h {cfg.latent_dim} channels, G + latent block, "
          f"CNN {[c.kernel for c in cast(ScreenCNN, result.cnn).config.layers]}")
    return summary


def rng_for(seed: int, stream: int) -> np.random.Generator:
    """The base stage's generator of `stream` (`build.build`'s rng)."""
    return np.random.default_rng(np.random.SeedSequence([seed, stream]))


def main(argv: list[str] | None = None) -> int:

    p = argparse.ArgumentParser(prog="python -m npga_core.demo.refine_stage", description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0, help="seed of the refine stage (default 0)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"folder with avatar.npga (default {DEFAULT_OUT})")
    p.add_argument("--quick", action="store_true", help="tiny stage for testing the pipeline")
    p.add_argument("--ict", type=Path, default=None, help="ICT-FaceKit folder or npz")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: small tensors, measured faster on a busy 2-core machine)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        summary = refine(args.out, args.seed, ict=args.ict, quick=args.quick)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps({"seconds": summary["seconds"], "held_out": summary["held_out"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
