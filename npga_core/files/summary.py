"""Readable summaries of files, as `npga-view info` prints them: an avatar (size, Gaussians, dynamics and their
networks, rig, CNN, expression space, blendshapes, provenance) and an ARKit take (rows, rate, dropped frames,
channels, head pose). Every name from a file is escaped (`shown`)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from npga_core.errors import shown

if TYPE_CHECKING:
    from npga_core.model.avatar import Avatar
    from npga_core.model.linear_rig import LinearRig
    from npga_core.model.networks import ConditionedMLP


def _mlp_lines(key: str, net: ConditionedMLP) -> list[str]:
    c = net.config
    shapes = " -> ".join([str(c.encoded_input_dim)] + [str(o) for o, _ in c.layer_shapes()])
    act = c.activation + (f" {c.slope:g}" if c.activation == "leaky_relu" else "")
    act += f", output {c.output_activation}" if c.output_activation != "none" else ""
    skips = f", skips at {c.skips}" if c.skips else ""
    names = {"position": "mu", "features": "f", "code": "z", "condition": "condition"}
    inputs = []
    for spec in c.specs:
        w = c.raw_width(spec)
        enc = f" {spec.encoding} x{spec.freqs} ({w} -> {spec.encoded_width(w)})" if spec.encoding != "none" else ""
        inputs.append(f"{names[spec.kind]} {w}{enc}")
    routes = ", ".join(f"{r.attribute}[{r.to}:{r.to + r.width}]" + (f" x{r.scale:.4g}" if r.scale != 1 else "")
                       for r in c.routes or [])
    blend = f"; blended by {c.blend}" if c.blend else ""
    return [
        f"  {key}: {c.depth} layers {shapes} ({act}{skips})",
        f"     inputs: {', '.join(inputs)}",
        f"     outputs: {routes}{blend}; {c.flops_per_gaussian() / 1e6:.2f} MFLOP per Gaussian",
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
        dyn = avatar.dynamics
        lines.append(f"  dynamics (rotation rule: {dyn.rotation_op}):" if dyn.networks() else
                     "  dynamics: a linear rig, no networks")
        if dyn.condition:
            lines.append(f"  frame vector: expression {dyn.expression_dim} + condition {dyn.condition_dim} "
                         f"({dyn.condition.get('description', dyn.condition.get('kind', ''))})")
        for name, note in dyn.blend_notes.items():
            lines.append(f"  blend weight {name}: {note}")
        for key, net in dyn.networks().items():
            lines += _mlp_lines(key, net)
        if dyn.rig is not None:
            lines += _rig_lines(dyn.rig, dyn.network_dim)
    if avatar.cnn is None:
        lines.append("  CNN: none")
    else:
        cfg = avatar.cnn.config
        if cfg.simple:
            layers = ", ".join(f"{lay.in_channels}->{lay.out_channels} k{lay.kernel} {lay.activation or 'linear'}"
                               for lay in cfg.layers)
        else:
            layers = " ".join(f"conv{o['in']}->{o['out']}k{o['kernel']}" if o["op"] == "conv" else
                              f"up{o['factor']}" if o["op"] == "upsample" else
                              "IN" if o["op"] == "instance_norm" else o["name"] for o in cfg.ops or [])
        scale = f", x{cfg.upsample} upsampling" if cfg.upsample > 1 else ""
        lines.append(f"  CNN: {len(cfg.layers)} layers on {cfg.input} ({layers})"
                     f"{', residual' if cfg.residual else ''}{scale}, {cfg.macs_per_pixel() / 1e6:.2f} MMAC/pixel")
    lines += _expression_lines(avatar)
    bs = avatar.blendshapes
    if bs is not None:
        lines.append(f"  blendshapes: {len(bs.names)} -> {bs.code_dim}-D codes ({shown(bs.source)}): "
                     + ", ".join(shown(n) for n in bs.names))
    prov = avatar.provenance
    if prov:
        keys = ("source", "path", "settings_from", "rotation_normalisation", "super_resolution", "created_at",
                "written_by", "builder", "seed")
        text = ", ".join(f"{k}={shown(str(prov[k]))}" for k in keys if k in prov)
        if text:
            lines.append(f"  provenance: {text}")
    return "\n".join(shown(line) for line in lines)  # every line escaped: any name in a file may be hostile


def _expression_lines(avatar: Avatar) -> list[str]:
    """The expression code's width, its PCA directions (not for a rig's channel sliders), named expressions."""
    lines = [f"  expression dim: {avatar.code_dim}"]
    ex = avatar.expression
    if ex is not None:
        if avatar.slider_channels is None:
            top = ", ".join(f"{s:.3g}" for s in ex.std[:5])
            lines.append(f"  PCA components: {ex.n_components} (std of the first: {top})")
        if ex.named:
            lines.append(f"  named expressions: {', '.join(shown(n) for n in ex.named)}")
    return lines


def _rig_lines(rig: LinearRig, first: int) -> list[str]:
    """The rig: its channels, what moves, the runtime rescaling and what the source's runtime does."""
    lines = [f"  rig: {shown(rig.describe())}",
             f"  rig channels (frame vector {first}..{first + rig.n_channels - 1}"
             + (", sliders 0..1): " if rig.skin is None else "): ")
             + ", ".join(shown(c) + ("" if s == 1.0 else f" x{s:g}") + ("" if b == 0.0 else f" {b:+g}")
                         for c, s, b in zip(rig.channels, rig.scale, rig.bias, strict=True))]
    if rig.skin is not None:
        lines.append(f"  rig pose inputs (frame vector {first + rig.n_channels}..{first + rig.n_inputs - 1}, "
                     "axis-angle radians, then translation): " + ", ".join(shown(n) for n in rig.skin.input_names()))
    for key, note in rig.notes.items():
        lines.append(f"  rig {shown(key)}: {shown(note)}")
    return lines


def take_summary(path: str) -> str:
    """What `info` prints for an ARKit take: frames, rate, duration, gaps, channels, head pose."""
    import numpy as np

    from npga_core.files.arkit_takes import read_take
    from npga_core.files.blendshape_names import ARKIT_52, canonical_arkit

    take = read_take(path)
    n = int(round((take.times[-1] - take.times[0]) * take.fps)) + 1
    w = np.asarray(take.weights)
    still = [nm for k, nm in enumerate(take.names) if float(np.abs(w[:, k]).max()) <= STILL]
    arkit = {canonical_arkit(nm) for nm in take.names} - {None}
    lines = [shown(path),
             f"  ARKit take: {len(take.times):,} rows at {take.fps:g} fps, {take.times[-1] - take.times[0]:.2f} s"
             + (f"; {n - len(take.times):,} of {n:,} frames not recorded (interpolated)" if n > len(take.times)
                else "; no frame dropped"),
             f"  channels: {len(take.names)} ({len(arkit)} of ARKit's 52"
             + (f"; not ARKit: {', '.join(shown(x) for x in take.names if canonical_arkit(x) is None)[:200]}"
                if len(arkit) < len(take.names) else "") + ")",
             f"  never moving (<= {STILL:g}): {len(still)}"
             + (f": {', '.join(shown(x) for x in still)}" if still else ""),
             f"  absent: {', '.join(x for x in ARKIT_52 if x not in arkit) or 'none'}",
             "  head pose: " + (take.ignored if take.ignored else
                                "none recorded (the angle columns are absent or all zero)" if take.head is None else
                                f"recorded (yaw/pitch/roll up to {float(np.abs(take.head).max()):.3g} rad)")]
    return "\n".join(lines)


#: A take's channel whose values stay within this is reported as never moving.
STILL = 0.01
