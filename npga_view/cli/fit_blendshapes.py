"""`npga-view fit-blendshapes --take TAKE --codes SEQUENCE --out basis.npz` (or `--into AVATAR.npga --out
NEW.npga`): a blendshape basis fitted by least squares from an ARKit take and the tracked expression codes of the
same frames, on its own or written into a copy of the avatar (format version 3). For a GaussianAvatars avatar
(`--into A.npga`) the codes may be a flame_param.npz of the take's frames: the basis then gives whole FLAME frame
vectors (expression, jaw, neck, eyes, head)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

#: A shape whose weights stay within this over the whole take is never excited: the fit cannot learn it.
UNEXCITED = 0.01


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--take", required=True, type=Path, help="ARKit take: Live Link Face .csv or ARKit .json")
    p.add_argument("--codes", required=True, type=Path,
                   help="the avatar's tracked codes of the same frames (.npzseq/.npz/.npy or a tracking folder)")
    p.add_argument("--out", required=True, type=Path,
                   help="the basis .npz to write, or with --into the new avatar .npga (the avatar with its basis)")
    p.add_argument("--into", type=Path, default=None,
                   help="an avatar .npga (or anything npga-view opens) to write the basis into: a copy of it with "
                        "the basis is written to --out (format version 3 or later); the avatar file is not changed")
    p.add_argument("--ridge", type=float, default=1e-6, help="ridge weight on the matrix (default 1e-6; > 0)")
    p.add_argument("--keep-unexcited", action="store_true",
                   help=f"keep shapes the take never moves (all weights <= {UNEXCITED}) in the basis (with zero "
                        "columns); default: leave them out and list them")


def run(args: argparse.Namespace) -> int:
    """Fit, print the error, write the basis (or the avatar with it); argument problems print one line and return
    2 (file problems raise AvatarFileError, printed by cli.main)."""
    from npga_core.errors import AvatarFileError, shown
    from npga_core.files.arkit_takes import read_take, resampled
    from npga_core.files.basis_file import save_basis
    from npga_core.files.blendshape_names import ANGLE_NAMES, IGNORED, canonical_arkit
    from npga_core.files.loading import load_sequence
    from npga_core.model.blendshapes import fit

    def fail(msg: str) -> int:
        print(f"npga-view fit-blendshapes: error: {msg}", file=sys.stderr)
        return 2

    want = ".npga" if args.into is not None else ".npz"
    if args.out.suffix.lower() != want:
        return fail(f"--out {shown(args.out)}: " + ("with --into the avatar is written as an .npga" if args.into
                                                   else "the basis is written as an .npz (or use --into AVATAR)"))
    if args.out.exists() and not args.out.is_file():
        return fail(f"--out {shown(args.out)} exists and is not a regular file")
    if not args.out.parent.is_dir():
        return fail(f"--out {shown(args.out)}: folder {shown(args.out.parent)} does not exist")
    if not (np.isfinite(args.ridge) and args.ridge > 0):
        return fail(f"--ridge {args.ridge} must be > 0 (0 leaves shapes the take does not separate undetermined)")
    take = read_take(args.take)
    skip = {n.lower() for n in (*IGNORED, *ANGLE_NAMES)}
    cols = [i for i, n in enumerate(take.names) if n.lower() not in skip]
    weights = resampled(take, cols, args.take)
    dead = [k for k in range(len(cols)) if float(np.abs(weights[:, k]).max(initial=0.0)) <= UNEXCITED]
    keep = list(range(len(cols))) if args.keep_unexcited else [k for k in range(len(cols)) if k not in dead]
    if not keep:
        return fail(f"{shown(args.take)}: no shape moves beyond {UNEXCITED} in the whole take")
    names = [canonical_arkit(take.names[cols[k]]) or take.names[cols[k]] for k in keep]
    avatar = None
    if args.into is not None:
        from npga_core.files.loading import load_avatar, load_sequence_for

        avatar = load_avatar(args.into)
        # a GaussianAvatars flame_param.npz gives the avatar's whole frame vectors (expression, jaw, neck, eyes, head)
        codes = load_sequence_for(avatar, args.codes).codes
    else:
        codes = load_sequence(args.codes).codes
    if len(weights) != len(codes):
        return fail(f"{shown(args.take)} has {len(weights)} frames (at {take.fps:g} fps), {shown(args.codes)} "
                    f"{len(codes)}: the takes must be paired frame by frame")
    if avatar is not None:
        d = avatar.code_dim - avatar.condition_dim
        if codes.shape[1] not in (d, avatar.code_dim):
            return fail(f"{shown(args.codes)} has {codes.shape[1]}-D codes, {shown(args.into)} takes {d}")
    try:
        result = fit(names, weights[:, keep], codes, args.ridge, source=f"least squares from {take.name}")
    except (ValueError, np.linalg.LinAlgError) as e:
        raise AvatarFileError(args.take, f"the fit failed ({e})") from None
    if not (np.isfinite(result.basis.matrix).all() and np.isfinite(result.basis.offset).all()):
        raise AvatarFileError(args.take, "the fit gave non-finite values (raise --ridge)")
    if avatar is not None:
        from npga_core.files.checkpoint import save_avatar

        avatar.blendshapes = result.basis
        # verify: the written file is read back by the reader that will open it before it takes the name
        save_avatar(avatar, args.out, {"blendshapes_from": f"{args.take.name} + {args.codes.name}"}, verify=True)
    else:
        save_basis(result.basis, args.out)
    print(f"fitted {len(names)} shapes -> {codes.shape[1]}-D codes from {len(codes)} frames at {take.fps:g} fps: "
          f"RMS residual {result.rms:.4g} per code dimension, {100 * result.relative:.2f}% of the codes' variation")
    if dead:
        listed = ", ".join(shown(take.names[cols[k]]) for k in dead)
        print(f"{len(dead)} shapes never move beyond {UNEXCITED} in the take "
              + ("(kept with zero columns)" if args.keep_unexcited else "(left out: weights of them have no "
                 "effect; --keep-unexcited keeps them)") + f": {listed}")
    print(f"wrote {shown(args.out)}" + (f" ({shown(args.into)} with the basis)" if avatar is not None else ""))
    return 0
