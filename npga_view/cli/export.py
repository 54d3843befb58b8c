"""`npga-view export AVATAR --out posed.ply`: the avatar posed at one expression as a standard 3DGS `.ply`;
`--format lam-zip --out AVATAR.zip`: the avatar as a LAM web avatar (`export_lam.py`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from npga_core.errors import CommandError
from npga_core.posing.precision import PRECISION_HELP


class ExportError(CommandError):
    """A problem with the arguments of `export`, reported as one line with exit code 2."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")
    p.add_argument("--flame-model", default=None, help="your FLAME model pickle: opens a GaussianAvatars output "
                   "folder (or its point_cloud.ply) as the avatar")
    p.add_argument("--out", required=True, type=Path, help="the .ply file to write (a .zip with --format lam-zip)")
    p.add_argument("--format", choices=("ply", "lam-zip"), default="ply",
                   help="ply: the posed Gaussians (default); lam-zip: a LAM-style web avatar that LAM's web player "
                   "(gaussian-splat-renderer-for-lam) plays live from ARKit weights, exact for a LAM avatar, "
                   "fitted for neural ones, with AVATAR.fidelity.json beside it")
    p.add_argument("--expr", help="expression code .npy, (D,) or (T, D) with --frame choosing the row (default row "
                   "0); or a named expression of the avatar ('jaw open'); or weights 'jawOpen=0.8,eyeBlinkLeft=1'")
    p.add_argument("--basis", type=Path, default=None,
                   help="a blendshape basis .npz (npga-view fit-blendshapes) for the avatar: ARKit takes "
                        "go through it instead of the avatar's own")
    p.add_argument("--sequence", type=Path, help="expression sequence (.npzseq/.npz/.npy or a tracking folder); "
                   "needs --frame")
    p.add_argument("--frame", type=int, default=None, help="frame of --sequence/--expr")
    p.add_argument("--head-pose", choices=("off", "relative", "absolute"), default="off",
                   help="move the Gaussians by the --sequence frame's tracked head pose, relative to its first "
                   "frame or as tracked (into the tracking's world); SH turn with the head. Default off")
    p.add_argument("--precision", default="fp32", metavar="fp32|bf16|auto", help=PRECISION_HELP)
    from npga_view.cli import export_lam

    export_lam.add_arguments(p)


def expression_code(args: argparse.Namespace, avatar) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The code selected by --expr/--sequence/--frame (None: the avatar's mean code), the same rules as
    `npga-view render` for a single image, and the frame's head transform (4x4) with --head-pose."""
    from npga_core.posing.headpose import head_transforms

    if args.sequence is not None and args.expr is not None:
        raise ExportError("give either --expr or --sequence, not both")
    source = args.sequence or args.expr
    if args.head_pose != "off" and args.sequence is None:
        raise ExportError("--head-pose needs --sequence")
    if source is None:
        if args.frame is not None:
            raise ExportError("--frame needs --sequence or --expr")
        return None, None
    if args.sequence is not None and args.frame is None:
        raise ExportError("--sequence needs --frame K to choose the expression")
    if avatar.code_dim == 0:
        raise ExportError(f"{source}: the avatar is static (no dynamics), it takes no expression codes")
    from npga_view.cli.expr_arg import expr_code, load_with_notes

    named = None if args.expr is None else expr_code(args.expr, avatar, args.frame, ExportError)
    if named is not None:
        return named, None
    seq = load_with_notes(avatar, source)
    seq.check_dim(avatar.code_dim, source)
    frame = 0 if args.frame is None else args.frame
    if not 0 <= frame < len(seq):
        raise ExportError(f"--frame {frame}: {source} has frames 0..{len(seq) - 1}")
    transform = None if args.head_pose == "off" else head_transforms(seq, [frame], args.head_pose, source)[0]
    return seq.codes[frame], transform


def run(args: argparse.Namespace) -> int:
    """Write the posed `.ply`; argument problems print one line and return 2, file problems raise
    AvatarFileError (cli.main prints it and exits 2)."""
    from npga_core.files.loading import load_avatar
    from npga_core.files.ply import save_posed_ply
    from npga_core.files.untrusted import finite_output

    if getattr(args, "format", "ply") == "lam-zip":
        from npga_view.cli import export_lam

        return export_lam.run(args)
    out: Path = args.out
    if getattr(args, "take", None) or getattr(args, "test_take", None):
        print("npga-view export: error: --take and --test-take are for --format lam-zip", file=sys.stderr)
        return 2
    try:
        if out.suffix.lower() != ".ply":
            raise ExportError(f"--out {out}: the output must be a .ply file")
        if not out.parent.is_dir():
            raise ExportError(f"--out {out}: folder {out.parent} does not exist")
        from npga_core.posing.precision import check_precision

        precision = check_precision(getattr(args, "precision", "fp32"))
        avatar = load_avatar(args.avatar, args.flame_model)
        if args.basis is not None:
            from npga_core.files.basis_file import attach_basis

            attach_basis(avatar, args.basis)
        code, transform = expression_code(args, avatar)
    except (ExportError, ValueError) as e:
        print(f"npga-view export: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    from npga_core.posing.oneshot import ExactPoses

    posed = ExactPoses(avatar, precision).pose(code)
    if transform is not None:
        from npga_core.posing.headpose import transform_posed

        posed = transform_posed(posed, transform)
    fields = {k: getattr(posed, k) for k in ("means", "quats", "scales", "opacities", "sh")}
    finite_output(fields, args.sequence or args.expr or args.avatar, "the posed Gaussians")
    save_posed_ply(posed, out)
    print(f"wrote {len(posed):,} Gaussians to {out}")
    return 0
