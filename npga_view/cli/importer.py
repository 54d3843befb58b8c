"""`npga-view import gha CKPT_DIR [--config GHA_YAML] [--legacy-rotation] --out AVATAR.npga` and
`npga-view import lam AVATAR.zip --out AVATAR.npga` and `npga-view import gaussian-avatars OUTPUT_DIR --flame-model
FLAME_PKL [--flame-param NPZ] --out AVATAR.npga`: another method's avatar as an `.npga` (format version 2 for
GHA's networks, 4 for LAM's rig, 5 for GaussianAvatars' FLAME rig), written atomically."""

from __future__ import annotations

import argparse
from pathlib import Path

from npga_core.errors import AvatarFileError

KINDS = ("gha", "lam", "gaussian-avatars")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", choices=KINDS, help="the method the checkpoint comes from: gha = Gaussian-Head-Avatar "
                   "(a folder with gaussianhead_latest and, optionally, supres_latest); lam = a LAM avatar zip "
                   "as its web player loads it (offset.ply + skin.glb); gaussian-avatars = a GaussianAvatars output "
                   "folder (point_cloud/iteration_N/point_cloud.ply + flame_param.npz)")
    p.add_argument("checkpoint", help="the checkpoint folder (or the gaussianhead_latest file), the LAM zip, or the "
                   "GaussianAvatars output folder (or its point_cloud.ply)")
    p.add_argument("--flame-model", default=None, help="gaussian-avatars: your FLAME model (flame2023.pkl or FLAME "
                   "2020's generic_model.pkl; read without running code from it)")
    p.add_argument("--flame-param", default=None, help="gaussian-avatars: the avatar's flame_param.npz (default: "
                   "beside the point cloud)")
    p.add_argument("--config", default=None, help="GHA's YAML config the avatar was trained with (distance "
                   "thresholds, scales); default: the values of GHA's published training config")
    p.add_argument("--legacy-rotation", action="store_true", help="rotations as GHA's code before 2024-07-12 "
                   "normalised them (across the Gaussians); default: per Gaussian, as GHA does today")
    p.add_argument("--sequence", default=None, help="a GHA params folder (or any sequence of its frame vectors) "
                   "whose expression coefficients give the avatar's expression space (PCA) for the sliders")
    p.add_argument("--out", required=True, help="the .npga file to write")


def run(args: argparse.Namespace) -> int:
    from npga_core.files.atomic import check_output
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.gha import import_gha

    out = check_output(args.out, "the .npga file")  # before the import's work: a folder, FIFO, ... refused
    if args.kind == "lam":
        return _import_lam(args, out)
    if args.kind == "gaussian-avatars":
        return _import_ga(args, out)
    for flag in ("flame_model", "flame_param"):
        if getattr(args, flag):
            raise AvatarFileError(args.checkpoint, f"--{flag.replace('_', '-')} applies to gaussian-avatars imports")
    from npga_core.files.loading import load_sequence

    seq = load_sequence(args.sequence) if args.sequence else None
    avatar = import_gha(args.checkpoint, config=args.config, legacy_rotation=args.legacy_rotation, sequence=seq,
                        sequence_name=str(args.sequence or ""))
    save_avatar(avatar, out, verify=True)
    p = avatar.provenance
    g = p["groups"]
    n_nets = len(avatar.dynamics.networks()) if avatar.dynamics is not None else 0  # (an import always has them)
    print(f"{out}: {len(avatar):,} Gaussians ({g['near']:,} near, {g['blended']:,} blended, {g['far']:,} far), "
          f"{n_nets} networks, frame vector {avatar.code_dim} "
          f"(expression {avatar.code_dim - avatar.condition_dim} + head pose {avatar.condition_dim}), "
          f"super-resolution: {f'x{avatar.cnn.config.upsample} CNN' if avatar.cnn else 'none'}; "
          f"settings from {p['settings_from']}; rotation {p['rotation_normalisation']}")
    return 0


def _import_lam(args: argparse.Namespace, out: Path) -> int:
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.lam import read_lam_zip

    for flag in ("config", "sequence", "flame_model", "flame_param"):
        if getattr(args, flag):
            raise AvatarFileError(args.checkpoint, f"--{flag.replace('_', '-')} does not apply to a LAM zip")
    avatar = read_lam_zip(args.checkpoint)
    save_avatar(avatar, out, verify=True)
    rig = avatar.rig
    assert rig is not None
    print(f"{out}: {len(avatar):,} Gaussians, {rig.describe()}; {rig.notes['weights']}")
    return 0


def _import_ga(args: argparse.Namespace, out: Path) -> int:
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.gaussian_avatars import LICENCE, import_gaussian_avatars

    for flag in ("config", "sequence"):
        if getattr(args, flag):
            raise AvatarFileError(args.checkpoint, f"--{flag} applies to gha imports, not to GaussianAvatars")
    if not args.flame_model:
        raise AvatarFileError(args.checkpoint, "a GaussianAvatars avatar is posed by FLAME: give your FLAME model "
                              "with --flame-model FLAME_PKL")
    avatar = import_gaussian_avatars(args.checkpoint, args.flame_model, args.flame_param)
    save_avatar(avatar, out, verify=True)
    rig = avatar.rig
    assert rig is not None
    print(f"{out}: {len(avatar):,} Gaussians, {rig.describe()}; frame vector {avatar.code_dim}. This file {LICENCE}.")
    return 0
