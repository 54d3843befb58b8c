"""GaussianAvatars output folders opened in the window: imported once into the user's cache as an `.npga`.

The window and its pose worker open avatars by path (the worker reopens the file in its own process), so a
GaussianAvatars folder plus the user's FLAME pickle becomes a file first: `cached_import` imports it
(`import_gaussian_avatars`, the FLAME pickle read first and without running code) into
`<user cache>/gaussian-avatars/<key>.npga`, where the key is a hash of the bytes of the three inputs (the point
cloud, its flame_param.npz, the FLAME pickle) and of this import's version: the same inputs open the cached file
at once, a changed input imports again. The cache keeps the `KEEP` most recently used imports. Those files carry
FLAME-derived data (MPI's licence), as any import does; they never leave the user's cache folder.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path

from npga_core.errors import AvatarFileError
from npga_core.files.flame_pickle import MAX_FLAME_BYTES
from npga_core.files.gaussian_avatars import find_ply, import_gaussian_avatars, is_ga_folder
from npga_core.files.places import user_cache_dir
from npga_core.files.sequences import MAX_SEQUENCE_BYTES
from npga_core.files.untrusted import is_folder, open_regular

CACHE_KIND = "gaussian-avatars"
#: bumped when the import's output changes for the same inputs (a cached file of an older import is not reused)
IMPORT_VERSION = b"npga-view gaussian-avatars import 1"
KEEP = 4
MAX_PLY_BYTES = 8 * 2**30


def is_ga_source(path: str | Path) -> bool:
    """A GaussianAvatars output folder, or a point_cloud .ply with a flame_param.npz beside it."""
    p = Path(path)
    if is_folder(p):
        return is_ga_folder(p)
    return p.suffix.lower() == ".ply" and (p.parent / "flame_param.npz").is_file()


def input_key(src: str | Path, flame_model: str | Path, flame_param: str | Path | None = None) -> str:
    """Hash (hex, 32 characters) of the import's inputs: the bytes of the point cloud, flame_param.npz and FLAME
    pickle (each length-prefixed) and `IMPORT_VERSION`."""
    ply = find_ply(src)
    param = Path(flame_param) if flame_param is not None else ply.parent / "flame_param.npz"
    h = hashlib.sha256(IMPORT_VERSION)
    for path, cap, what in ((ply, MAX_PLY_BYTES, "a point cloud"), (param, MAX_SEQUENCE_BYTES, "a flame_param.npz"),
                            (flame_model, MAX_FLAME_BYTES, "a FLAME model pickle")):
        _hash_file(h, path, cap, what)
    return h.hexdigest()[:32]


def _hash_file(h: hashlib._Hash, path: str | Path, cap: int, what: str) -> None:
    with open_regular(path, what) as fh:  # no FIFO or device: nothing hashed without end
        size = os.fstat(fh.fileno()).st_size
        if size > cap:
            raise AvatarFileError(path, f"is {size:,} bytes, more than {what} may be ({cap:,})")
        h.update(size.to_bytes(8, "little"))
        while chunk := fh.read(1 << 22):
            h.update(chunk)


def cached_import(src: str | Path, flame_model: str | Path, flame_param: str | Path | None = None,
                  cache: str | Path | None = None) -> tuple[Path, str]:
    """The `.npga` of the GaussianAvatars avatar `src` posed by `flame_model` (imported now, or the cached file of
    the same inputs) and one line saying which; AvatarFileError for bad inputs (nothing written then)."""
    from npga_core.files.atomic import check_output
    from npga_core.files.checkpoint import read_avatar, save_avatar

    folder = Path(cache) if cache is not None else user_cache_dir(CACHE_KIND)
    out = folder / f"{input_key(src, flame_model, flame_param)}.npga"
    if out.is_file():
        try:
            read_avatar(out)
        except AvatarFileError:  # a cached file spoiled since (disk, a hand edit): import again
            pass
        else:
            out.touch()
            return out, f"opened {src} with the FLAME model {flame_model} from its cached import {out}"
    avatar = import_gaussian_avatars(src, flame_model, flame_param)  # the FLAME pickle first: nothing written
    save_avatar(avatar, check_output(out, "a cached import"), verify=True)
    _prune(folder, keep=out)
    return out, (f"imported {src} with the FLAME model {flame_model} into {out} ({len(avatar):,} Gaussians; "
                 "the cached file carries FLAME-derived data under MPI's licence)")


def _prune(folder: Path, keep: Path) -> None:
    """Remove all but the `KEEP` most recently used cached imports (never `keep`)."""
    try:
        files = sorted(folder.glob("*.npga"), key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return
    for p in files[KEEP:]:
        if p != keep:
            with contextlib.suppress(OSError):
                p.unlink()
