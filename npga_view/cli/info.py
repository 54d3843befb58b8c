"""`npga-view info PATH`: a readable summary of an avatar file."""

from __future__ import annotations

import argparse
import os
import time

from npga_core.errors import shown
from npga_core.files.loading import load_avatar
from npga_core.model.avatar import Avatar


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")


def _mlp_lines(key: str, net) -> list[str]:
    c = net.config
    shapes = " -> ".join([str(c.encoded_input_dim)] + [str(o) for o, _ in c.layer_shapes()])
    outs = ", ".join(f"{n}:{w}" for n, w in c.outputs)
    enc = f"mu with {c.pos_freqs} frequencies" if c.pos_freqs else "mu raw"
    skips = f", skips at {c.skips}" if c.skips else ""
    return [
        f"  {key}: {c.depth} layers {shapes} ({c.activation}{skips})",
        f"     inputs: {enc} (3 -> {c.mu_encoded_dim}), f {c.feature_dim}, z {c.code_dim}",
        f"     outputs: {outs}; {c.flops_per_gaussian() / 1e6:.2f} MFLOP per Gaussian",
    ]


def summary(avatar: Avatar, path: str, load_s: float) -> str:
    """The text `info` prints."""
    c = avatar.cloud
    lines = [shown(path)]
    size = os.path.getsize(path) if os.path.isfile(path) else 0
    lines.append(f"  size on disk: {size / 1e6:.2f} MB, loaded in {load_s * 1000:.0f} ms")
    empty = "  (empty: nothing to draw)" if len(c) == 0 else ""
    lines.append(f"  gaussians: {len(c):,}  (units: {shown(avatar.units)}){empty}")
    lines.append(f"  SH degree: {c.sh_degree} ({c.sh.shape[1]} coefficients x 3)")
    lines.append(f"  features f: {c.feature_dim}   latent h: {c.latent_dim}")
    if c.part_ids is not None and c.part_names:
        import numpy as np

        counts = np.bincount(c.part_ids[c.part_ids >= 0].astype(np.int64), minlength=len(c.part_names))
        lines.append("  parts: " + ", ".join(f"{shown(n)} {k:,}" for n, k in zip(c.part_names, counts, strict=True)))
    if avatar.dynamics is None:
        lines.append("  dynamics: none (static)")
    else:
        lines.append(f"  dynamics (rotation op: {avatar.dynamics.rotation_op}):")
        for key, net in avatar.dynamics.networks().items():
            lines += _mlp_lines(key, net)
    if avatar.cnn is None:
        lines.append("  CNN: none")
    else:
        cfg = avatar.cnn.config
        layers = ", ".join(f"{lay.in_channels}->{lay.out_channels} k{lay.kernel} {lay.activation or 'linear'}"
                           for lay in cfg.layers)
        lines.append(f"  CNN: {len(cfg.layers)} layers ({layers}){', residual' if cfg.residual else ''}")
    lines.append(f"  expression dim: {avatar.code_dim}")
    ex = avatar.expression
    if ex is not None:
        top = ", ".join(f"{s:.3g}" for s in ex.std[:5])
        lines.append(f"  PCA components: {ex.n_components} (std of the first: {top})")
        if ex.named:
            lines.append(f"  named expressions: {', '.join(shown(n) for n in ex.named)}")
    prov = avatar.provenance
    if prov:
        keys = ("source", "created_at", "written_by", "builder", "seed")
        text = ", ".join(f"{k}={shown(str(prov[k]))}" for k in keys if k in prov)
        if text:
            lines.append(f"  provenance: {text}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    avatar = load_avatar(args.path)
    dt = time.perf_counter() - t0
    print(summary(avatar, avatar.source or args.path, dt))
    from npga_view.rendering.factory import headless_path_line

    print(headless_path_line())
    return 0
