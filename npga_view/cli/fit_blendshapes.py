"""`npga-view fit-blendshapes --take TAKE --codes SEQUENCE --out basis.npz`: a blendshape basis fitted by least
squares from an ARKit take and the tracked expression codes of the same frames."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--take", required=True, type=Path, help="ARKit take: Live Link Face .csv or ARKit .json")
    p.add_argument("--codes", required=True, type=Path,
                   help="the avatar's tracked codes of the same frames (.npzseq/.npz/.npy or a tracking folder)")
    p.add_argument("--out", required=True, type=Path, help="the basis .npz to write")
    p.add_argument("--ridge", type=float, default=1e-6, help="ridge weight on the matrix (default 1e-6)")


def run(args: argparse.Namespace) -> int:
    """Fit, print the error, write the basis; argument problems print one line and return 2 (file problems
    raise AvatarFileError, printed by cli.main)."""
    from npga_core.files.arkit_takes import read_take, resample
    from npga_core.files.basis_file import save_basis
    from npga_core.files.blendshape_names import ANGLE_NAMES, IGNORED, canonical_arkit
    from npga_core.files.loading import load_sequence
    from npga_core.model.blendshapes import fit

    def fail(msg: str) -> int:
        print(f"npga-view fit-blendshapes: error: {msg}", file=sys.stderr)
        return 2

    if args.out.suffix.lower() != ".npz":
        return fail(f"--out {args.out}: the basis is written as an .npz")
    if not args.out.parent.is_dir():
        return fail(f"--out {args.out}: folder {args.out.parent} does not exist")
    if not (np.isfinite(args.ridge) and args.ridge >= 0):
        return fail(f"--ridge {args.ridge} must be >= 0")
    take = read_take(args.take)
    skip = {n.lower() for n in (*IGNORED, *ANGLE_NAMES)}
    cols = [i for i, n in enumerate(take.names) if n.lower() not in skip]
    names = [canonical_arkit(take.names[i]) or take.names[i] for i in cols]
    weights = resample(take.times, take.weights[:, cols], take.fps)
    codes = load_sequence(args.codes).codes
    if len(weights) != len(codes):
        return fail(f"{args.take} has {len(weights)} frames (at {take.fps:g} fps), {args.codes} {len(codes)}: "
                    "the takes must be paired frame by frame")
    try:
        result = fit(names, weights, codes, args.ridge, source=f"least squares from {args.take.name}")
    except ValueError as e:
        return fail(str(e))
    save_basis(result.basis, args.out)
    print(f"fitted {len(names)} shapes -> {codes.shape[1]}-D codes from {len(codes)} frames: "
          f"RMS residual {result.rms:.4g} per code dimension, {100 * result.relative:.2f}% of the codes' variation")
    print(f"wrote {args.out}")
    return 0
