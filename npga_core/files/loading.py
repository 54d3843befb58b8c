"""The one place that opens avatars and sequences: decides the format and dispatches to its reader.

`load_avatar` reads `.npga` checkpoints and 3DGS PLY files (by their first bytes), Gaussian-Head-Avatar checkpoint
folders (by their content) and the bundled demo;
`load_sequence` reads `.npzseq`/`.npz`, `.npy`, MonoNPHM tracking folders, GHA's params folders and the
NeRSemble / GaussianAvatars tracking npz files (recognised by their keys). The model knows no file format.
"""

from __future__ import annotations

from pathlib import Path

from npga_core.errors import AvatarFileError
from npga_core.files.arkit_takes import TAKE_SUFFIXES, read_take_sequence
from npga_core.files.checkpoint import MAGIC, read_avatar
from npga_core.files.gaussian_avatars import flame_sequence, import_gaussian_avatars, is_ga_folder
from npga_core.files.gha import import_gha, is_gha_folder, is_gha_params, read_gha_params
from npga_core.files.lam import is_zip, read_lam_zip
from npga_core.files.places import bundled_path
from npga_core.files.ply import read_ply
from npga_core.files.sequences import (
    DEFAULT_FPS,
    MAX_SEQUENCE_BYTES,
    ExpressionSequence,
    read_npz,
    validate_sequence,
)
from npga_core.files.trackers import tracker_of
from npga_core.files.tracking import load_mononphm_folder
from npga_core.files.untrusted import is_folder, npz_names, open_regular, read_npy, real_floats, regular_file
from npga_core.model.avatar import Avatar
from npga_core.model.blendshapes import BlendshapeBasis

#: Where the bundled demo avatar lives: package data (the repository's assets/demo), whatever the install.
DEMO_DIR = bundled_path("demo")
DEMO_AVATAR = DEMO_DIR / "avatar.npga"


def load_avatar(path: str | Path, flame_model: str | Path | None = None) -> Avatar:
    """Open a `.npga` checkpoint, a 3DGS `.ply`, a LAM avatar zip, or "demo"; raises AvatarFileError on bad input.
    With `flame_model` (the user's FLAME pickle) a GaussianAvatars output folder or point_cloud.ply.

    The type is decided by the file's first bytes, not its name.
    """
    if flame_model is not None:
        return import_gaussian_avatars(path, flame_model)
    if str(path) == "demo":
        if not DEMO_AVATAR.is_file():
            raise AvatarFileError(DEMO_AVATAR, "the bundled demo avatar is missing (build it with "
                                  "`python -m npga_core.demo.build`)")
        path = DEMO_AVATAR
    p = Path(path)
    if is_folder(p):
        if is_gha_folder(p):
            return import_gha(p)
        if is_ga_folder(p):
            raise AvatarFileError(p, "is a GaussianAvatars output folder: open it with --flame-model FLAME_PKL "
                                  "(your FLAME model), or import it with `npga-view import gaussian-avatars`")
        raise AvatarFileError(p, "is a directory, not an avatar file (nor a Gaussian-Head-Avatar checkpoint "
                              "folder: no gaussianhead_latest)")
    try:
        with open_regular(p, "an avatar file") as fh:  # no FIFO, device or directory: nothing read without end
            head = fh.read(len(MAGIC))
    except OSError as e:
        raise AvatarFileError(p, f"cannot read: {e.strerror or e}") from None
    if head and MAGIC.startswith(head):  # whole signature, or a file cut inside it
        return read_avatar(p)
    if is_zip(head):
        try:
            return read_lam_zip(p)
        except AvatarFileError as e:
            if e.problem.startswith("not a readable zip archive"):  # the signature alone was a zip's
                raise AvatarFileError(p, "not an .npga checkpoint, a PLY file or a LAM avatar zip ("
                                      + e.problem.replace("not a readable zip archive", "an unreadable zip archive",
                                                          1) + ")") from None
            raise
    if head.startswith(b"ply"):
        return Avatar(read_ply(p), provenance={"source": str(p), "format": "3dgs-ply"}, source=str(p))
    if not head:
        raise AvatarFileError(p, "file is empty")
    raise AvatarFileError(p, f"not an .npga checkpoint, a PLY file or a LAM zip (starts with {head[:8]!r})")


def load_sequence(path: str | Path, fps: float | None = None,
                  basis: BlendshapeBasis | None = None) -> ExpressionSequence:
    """Load `.npzseq`/`.npz` (codes under a common key), `.npy` (T, D), a MonoNPHM tracking folder, or a
    NeRSemble FLAME tracking / GaussianAvatars flame_param npz, with the head pose as that source defines it;
    ARKit takes (`.csv` Live Link Face, `.json`) through `basis` (a `BlendshapeBasis`; default the demo's)."""
    path = Path(path)
    if is_folder(path):
        seq = read_gha_params(path) if is_gha_params(path) else load_mononphm_folder(path)
    elif path.suffix == ".npy":
        codes = real_floats(read_npy(path, MAX_SEQUENCE_BYTES, "expression codes"), path, "expression codes")
        if codes.ndim == 1:
            codes = codes[None]
        elif codes.ndim == 3 and codes.shape[1] == 1:
            codes = codes[:, 0]
        seq = ExpressionSequence(codes, DEFAULT_FPS, path.stem)
    elif path.suffix.lower() in TAKE_SUFFIXES:  # resampled to --fps (not relabelled: timed by its timecodes)
        return validate_sequence(read_take_sequence(path, basis, fps), path)
    else:
        regular_file(path, "a sequence file")
        seq = (tracker_of(npz_names(path)) or read_npz)(path)
    if fps is not None:
        seq.fps = float(fps)
    return validate_sequence(seq, path)


def load_sequence_for(avatar: Avatar, path: str | Path, fps: float | None = None) -> ExpressionSequence:
    """`load_sequence` for an open avatar: an ARKit take goes through the avatar's own blendshape basis, and an
    avatar without one refuses a take in one line saying how to get one (no detour through the demo's map); a
    GaussianAvatars flame_param.npz drives an avatar posed by FLAME with all its inputs (`flame_sequence`)."""
    p = Path(path)
    if not p.is_dir() and p.suffix.lower() in TAKE_SUFFIXES and avatar.blendshapes is None:
        if avatar.rig is not None and avatar.rig.skin is not None:
            raise AvatarFileError(p, "is an ARKit take, and this FLAME-posed (GaussianAvatars) avatar has no ARKit "
                                  "basis (none ships: FLAME and ARKit need paired frames): fit one from a take and "
                                  "a flame_param.npz of the same frames with `npga-view fit-blendshapes --take TAKE "
                                  "--codes flame_param.npz --into AVATAR.npga --out WITH_BASIS.npga`")
        raise AvatarFileError(p, "is an ARKit take, and the avatar has no blendshape basis to turn its weights into "
                              "expression codes: fit one with `npga-view fit-blendshapes --take TAKE --codes "
                              "TRACKED --out basis.npz` (README, 'Driving the avatar from face captures')")
    seq = load_sequence(p, fps, basis=avatar.blendshapes)
    rig = avatar.rig
    if rig is not None and rig.skin is not None and seq.flame is not None and "neck_pose" in seq.flame:
        return validate_sequence(flame_sequence(avatar, seq), p)
    return seq
