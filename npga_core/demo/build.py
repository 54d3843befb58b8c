"""Build the bundled demo avatar: ``python -m npga_core.demo.build [--seed S] [--out assets/demo] [--quick]``.

Deterministic from the seed (on one machine and torch build). The base stage samples the ICT-FaceKit head into
a canonical Gaussian cloud, trains F and G on the CPU, measures their errors on held-out expressions, and
writes ``avatar.npga``, the sequences, the expression map, the kit's licence and a README. The refine stage
(``--stage refine``, `refine_stage.py`) then adds the latent features h, G's offsets of h and the screen-space
CNN, trained on the CPU against renders of the ICT head; ``--stage all`` (the default) runs both.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from npga_core.demo import train as tr
from npga_core.demo.basis import basis_from_provenance, basis_of_map
from npga_core.demo.canonical import FEATURE_DIM, build_canonical
from npga_core.demo.colors import eyelid_mask, lip_weight
from npga_core.demo.expression_map import ExpressionMap
from npga_core.demo.expressions import ExpressionSampler, named_weights
from npga_core.demo.ict import ICT_WHERE, IctHead, load_ict
from npga_core.demo.readme import DEFAULT_OUT, write_readme
from npga_core.demo.sampling import SurfaceSamples, interpolate, label_iris, uniform_samples
from npga_core.demo.sequences import build_sequences
from npga_core.demo.targets import AppearanceTargets, HeadTargets
from npga_core.files.basis_file import read_expression_map
from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.inspection.graph import knn
from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import Dynamics
from npga_core.model.expression import ExpressionSpace


@dataclass
class BuildConfig:
    """Sizes of one build; `quick` is a smoke-test version of the full one."""

    gaussians: int = 80000
    train_expressions: int = 50000
    test_expressions: int = 32
    extra_points: float = 0.5  # extra canonical points for F, as a fraction of the Gaussians
    f: tr.FConfig = field(default_factory=tr.FConfig)
    g: tr.GConfig = field(default_factory=tr.GConfig)

    @staticmethod
    def quick() -> BuildConfig:
        return BuildConfig(gaussians=20000, train_expressions=5000, test_expressions=8,
                           f=tr.FConfig(steps=300, batch=8192), g=tr.GConfig(steps=60, batch=4096))


def _stats(err: np.ndarray) -> dict[str, float]:
    e = err.ravel()
    return {"mean": round(float(e.mean()), 4), "p99": round(float(np.percentile(e, 99)), 4),
            "max": round(float(e.max()), 3)}


def _extra_points(head: IctHead, samples: SurfaceSamples, rng: np.random.Generator,
                  count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Uniform (not blue-noise) canonical points on the sampled triangles, for F's distillation."""
    tri, bary = uniform_samples(head, np.unique(samples.tri), count, rng)
    pts = interpolate(head.vertices, head.faces, tri, bary).astype(np.float32)
    nrm = interpolate(head.vertex_normals(), head.faces, tri, bary)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    part = label_iris(head, pts, head.tri_part[tri])
    return tri, bary, pts, nrm, part


def build(out: Path, seed: int = 0, cfg: BuildConfig | None = None, ict: Path | None = None, quick: bool = False,
          log: Callable[[str], object] = print) -> dict:
    """Run the whole build and write `out`; returns the summary (also stored in the avatar's provenance)."""
    cfg = cfg or (BuildConfig.quick() if quick else BuildConfig())
    t_start = time.perf_counter()

    def stamp(msg: str) -> None:
        log(f"[{time.perf_counter() - t_start:7.1f} s] {msg}")

    def rng(stream: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([seed, stream]))

    head = load_ict(ict)
    stamp(f"ICT-FaceKit: {len(head.vertices)} vertices, {len(head.faces)} triangles, "
          f"{head.n_expressions} expressions ({head.source})")

    canon = build_canonical(head, cfg.gaussians, rng(1))
    s = canon.samples
    counts = {n: int((s.part == i).sum()) for i, n in enumerate(canon.cloud.part_names)}
    stamp(f"canonical cloud: {len(s)} Gaussians " + ", ".join(f"{k} {v}" for k, v in counts.items()))

    emap = ExpressionMap.from_seed(seed, head.expression_names)
    sampler = ExpressionSampler(head.expression_names)
    named = named_weights(head.expression_names)
    w_train = np.concatenate([sampler.sample(cfg.train_expressions, rng(2)), np.stack(list(named.values()))])
    w_test = sampler.sample(cfg.test_expressions, rng(3))
    z_train, z_test = emap.encode(w_train), emap.encode(w_test)
    w_named = np.stack(list(named.values()))
    z_named = emap.encode(w_named)

    targets = HeadTargets(head, s.tri, s.bary)
    unit_disp = targets.unit_displacements()
    features0 = tr.init_features(unit_disp, FEATURE_DIM)
    nbrs = knn(s.points, 8)
    et, eb, ep, en, epart = _extra_points(head, s, rng(4), int(cfg.extra_points * len(s)))
    extra = tr.make_extra_points(HeadTargets(head, et, eb), s.points, s.normals, s.part, ep, en, epart)
    stamp(f"targets ready: {len(extra.targets)} extra canonical points, kNN graph k=8")

    stamp(f"training F: {cfg.f.steps} steps of {cfg.f.batch} (Gaussian, expression) pairs")
    net_f, features = tr.train_f(s.points, features0, targets, extra, w_train, z_train, nbrs, unit_disp, cfg.f,
                              seed, log=lambda m: stamp(m.strip()))
    lips = lip_weight(head, s.points, s.part) > 0.5
    lids = eyelid_mask(head, s.tri, s.bary, s.part)
    err = tr.f_errors(net_f, s.points, features, targets, w_test, z_test)
    err_named = tr.f_errors(net_f, s.points, features, targets, w_named, z_named)
    mag = tr.offset_magnitudes(targets, w_test)
    f_metrics: dict[str, Any] = {
        "held_out": {"all": _stats(err), "lips": _stats(err[:, lips]), "eyelids": _stats(err[:, lids]),
                     "target_offsets": _stats(mag)},
        "named": {"all": _stats(err_named), "lips": _stats(err_named[:, lips]),
                  "eyelids": _stats(err_named[:, lids])},
        "counts": {"lips": int(lips.sum()), "eyelids": int(lids.sum())},
    }
    h = f_metrics["held_out"]
    stamp("F error on held-out expressions (mm): " + "; ".join(
        f"{k} mean {h[k]['mean']:.3f} p99 {h[k]['p99']:.3f}" for k in ("all", "lips", "eyelids")))
    t, nm = h["target_offsets"], f_metrics["named"]["all"]
    stamp(f"  (target offsets: mean {t['mean']:.3f} mm, p99 {t['p99']:.3f} mm; named expressions: "
          f"mean {nm['mean']:.3f} p99 {nm['p99']:.3f})")

    app = AppearanceTargets(head, s.tri, s.bary, canon.frames, canon.colour, s.part,
                            dc_scale=1.0 - canon.facing)
    stamp(f"training G: {cfg.g.steps} steps of {cfg.g.batch} pairs, {cfg.g.expressions_per_step} expressions each")
    net_g = tr.train_g(s.points, features, app, w_train, z_train, nbrs, unit_disp, cfg.g, seed + 1,
                       log=lambda m: stamp(m.strip()))
    g_metrics = {k: round(v, 4) for k, v in tr.g_errors(net_g, s.points, features, app, w_test, z_test).items()}
    stamp("G error on held-out expressions: " + ", ".join(f"{k} {v}" for k, v in g_metrics.items()))

    cloud = canon.cloud
    cloud.features = features.astype(np.float32)
    space = ExpressionSpace.from_codes(z_train, n_components=head.n_expressions)  # codes span a 53-D subspace
    space.named = {k: emap.encode(v) for k, v in named.items()}
    out = Path(out)
    seq_dir = out / "sequences"
    seq_dir.mkdir(parents=True, exist_ok=True)
    sequences = build_sequences(emap, seed)
    summary = {
        "generator": "npga_core.demo.build",
        "seed": seed,
        "quick": quick,
        "source": "ICT-FaceKit light head model (USC ICT), MIT licence: LICENSE.ict-facekit",
        "gaussians": len(cloud),
        "test_expressions": len(w_test),
        "part_counts": counts,
        "expression_map": {"kind": "z = M w + b, w = M^T (z - b); M 100x53 orthonormal columns (seeded Haar "
                           "rotation), b seeded normal (std 0.25)", "seed": seed, "file": "expression_map.npz",
                           "names": list(emap.names)},
        "f_config": {k: v for k, v in vars(cfg.f).items()},
        "g_config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(cfg.g).items()},
        "f_error_mm": f_metrics,
        "g_error": g_metrics,
        "sequences": sorted(sequences),
        "machine": f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, "
                   f"torch {torch.__version__}",
    }
    summary["build_seconds"] = round(time.perf_counter() - t_start, 1)
    avatar = Avatar(cloud, Dynamics(net_f, net_g), expression=space, provenance=summary, units="m",
                    blendshapes=basis_of_map(emap))
    save_avatar(avatar, out / "avatar.npga")
    for name, seq in sequences.items():
        seq.save(seq_dir / f"{name}.npzseq")
    np.savez(out / "expression_map.npz", M=emap.matrix, b=emap.offset, names=np.array(emap.names, dtype=np.str_))
    shutil.copyfile(head.source.parent / "LICENSE", out / "LICENSE.ict-facekit")
    write_readme(out, seed, quick, summary)
    size = (out / "avatar.npga").stat().st_size / 2**20
    stamp(f"wrote {out} (avatar.npga {size:.1f} MiB, {len(sequences)} sequences)")
    return summary


def attach_basis(out: str | Path) -> dict:
    """Give a built ``out/avatar.npga`` its blendshape basis (the build's expression map, as written to
    ``expression_map.npz`` and as derived from the seed in its provenance: both must agree) without retraining;
    the stages ``base`` and ``refine`` write it themselves. Returns a short report."""
    out = Path(out)
    path = out / "avatar.npga"
    avatar = read_avatar(path)
    basis = read_expression_map(out / "expression_map.npz")
    derived = basis_from_provenance(avatar.provenance, path)
    if derived.names != basis.names or not np.allclose(derived.matrix, basis.matrix, atol=1e-6) \
            or not np.allclose(derived.offset, basis.offset, atol=1e-6):
        raise ValueError(f"{out / 'expression_map.npz'} is not the map of {path}'s seed")
    avatar.blendshapes = basis
    save_avatar(avatar, path)
    return {"blendshapes": len(basis.names), "code_dim": basis.code_dim}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m npga_core.demo.build", description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument("--quick", action="store_true", help="small, fast build for testing the pipeline")
    p.add_argument("--ict", type=Path, default=None, help=f"ICT-FaceKit folder or npz (else: {ICT_WHERE})")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads of the base stage (default 2)")
    p.add_argument("--refine-threads", type=int, default=1,
                   help="torch CPU threads of the refine stage (default 1: small tensors, measured faster on a "
                   "busy 2-core machine)")
    p.add_argument("--stage", choices=("all", "base", "refine", "basis"), default="all",
                   help="base: cloud, F, G, sequences; refine: latent h, G's latent block and the screen-space CNN "
                   "on top of OUT/avatar.npga; all: both (default); basis: only add the blendshape basis "
                   "(the expression map) to an OUT/avatar.npga built before bases were stored")
    args = p.parse_args(argv)
    from npga_core.demo.refine_stage import refine  # torch-heavy: imported only when the build runs

    report: dict = {}
    try:
        if args.stage in ("all", "base"):
            torch.set_num_threads(args.threads)
            summary = build(args.out, args.seed, ict=args.ict, quick=args.quick)
            report |= {"build_seconds": summary["build_seconds"], "f_error_mm": summary["f_error_mm"]["held_out"]}
        if args.stage == "basis":
            report |= attach_basis(args.out)
        if args.stage in ("all", "refine"):
            torch.set_num_threads(args.refine_threads)
            summary = refine(args.out, args.seed, ict=args.ict, quick=args.quick)
            report |= {"refine_seconds": summary["seconds"], "refine_held_out": summary["held_out"]}
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
