"""Expression sequences: T codes at a frame rate, optional head pose, and the file formats they come in.

The project's own format, `.npzseq`, is an uncompressed npz (zip of .npy, read with pickles refused) with:
``codes`` (T, D) float32, ``fps`` () float64, optional ``rotation`` (T, 3) axis-angle, ``translation`` (T, 3),
``scale`` (T,) or (T, 1), ``frame_names`` (T,) unicode, and ``name`` () unicode.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.untrusted import npz_names, real_floats
from npga_core.files.untrusted import read_npz as read_npz_arrays

DEFAULT_FPS = 25.0
CODE_KEYS = ("codes", "expression", "expr", "z_exp", "exp", "expressions")
POSE_KEYS = ("rotation", "translation", "scale")
#: Largest sequence file read (all arrays together, as the headers claim them).
MAX_SEQUENCE_BYTES = 512 * 2**20


@dataclass
class ExpressionSequence:
    """T expression codes with a frame rate and optional per-frame head pose."""

    codes: np.ndarray  # (T, D) float32
    fps: float = DEFAULT_FPS
    name: str = ""
    rotation: np.ndarray | None = None  # (T, 3) axis-angle
    translation: np.ndarray | None = None  # (T, 3)
    scale: np.ndarray | None = None  # (T,)
    frame_names: list[str] | None = None

    def __len__(self) -> int:
        return int(self.codes.shape[0])

    @property
    def dim(self) -> int:
        return int(self.codes.shape[1])

    @property
    def duration(self) -> float:
        return len(self) / self.fps

    def save(self, path: str | Path) -> None:
        """Write the `.npzseq` format atomically."""
        path = Path(path)
        arrays: dict[str, np.ndarray] = {"codes": np.asarray(self.codes, np.float32),
                                         "fps": np.float64(self.fps), "name": np.str_(self.name)}
        for key in ("rotation", "translation", "scale"):
            if getattr(self, key) is not None:
                arrays[key] = np.asarray(getattr(self, key), np.float32)
        if self.frame_names is not None:
            arrays["frame_names"] = np.array(self.frame_names, dtype=np.str_)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write(path, lambda fh: fh.write(buf.getvalue()))

    def check_dim(self, expected: int, path: str | Path | None = None) -> None:
        """AvatarFileError if the code dimension differs from the avatar's."""
        if self.dim != expected:
            raise AvatarFileError(path or self.name or "sequence",
                                  f"codes have {self.dim} dims, the avatar expects {expected}")


def validate_sequence(seq: ExpressionSequence, path: Path) -> ExpressionSequence:
    c = seq.codes
    if c.ndim != 2 or c.shape[0] < 1 or c.shape[1] < 1:
        raise AvatarFileError(path, f"expression codes must be (T, D) with T, D >= 1, got shape {c.shape}")
    if not np.isfinite(c).all():
        raise AvatarFileError(path, "expression codes have NaN/Inf values")
    if not (np.isfinite(seq.fps) and 0 < seq.fps <= 1000):
        raise AvatarFileError(path, f"frame rate {seq.fps} is not in (0, 1000]")
    t = c.shape[0]
    for key, width in (("rotation", 3), ("translation", 3), ("scale", 1)):
        a = getattr(seq, key)
        if a is None:
            continue
        a = np.asarray(a, np.float32).reshape(t, -1) if a.size == t * width else a
        if a.shape != (t, width) or not np.isfinite(a).all():
            raise AvatarFileError(path, f"{key} must be finite with shape ({t}, {width}), got {a.shape}")
        if key == "scale" and not (a > 0).all():
            raise AvatarFileError(path, f"scale must be positive (frame {int(np.argmax(~(a[:, 0] > 0)))} is not)")
        setattr(seq, key, a[:, 0] if key == "scale" else a)
    return seq


def read_npz(path: Path) -> ExpressionSequence:
    """Read `.npzseq`/`.npz` through `untrusted.read_npz`: sizes checked from the headers, real finite numbers."""
    keys = npz_names(path)
    key = next((k for k in CODE_KEYS if k in keys), None)
    if key is None:
        raise AvatarFileError(path, f"no expression array under any of {', '.join(CODE_KEYS)} "
                              f"(keys: {', '.join(keys[:20]) or 'none'})")
    z = read_npz_arrays(path, MAX_SEQUENCE_BYTES, keys=(key, "fps", "name", "frame_names", *POSE_KEYS),
                        kinds={"name": "US", "frame_names": "US"})
    codes = real_floats(z[key], path, "expression codes")
    if codes.ndim == 3 and codes.shape[1] == 1:
        codes = codes[:, 0]
    fps = DEFAULT_FPS
    if "fps" in z:
        if z["fps"].size != 1:
            raise AvatarFileError(path, f"fps must be one number, got shape {z['fps'].shape}")
        fps = float(real_floats(z["fps"], path, "fps", np.float64).reshape(()))
    name = str(z["name"].reshape(-1)[0]) if "name" in z and z["name"].size == 1 else path.stem
    opt = {k: real_floats(z[k], path, k) for k in POSE_KEYS if k in z}
    names = [str(s) for s in np.atleast_1d(z["frame_names"])] if "frame_names" in z else None
    if names is not None and len(names) != codes.shape[0]:
        raise AvatarFileError(path, f"{len(names)} frame names for {codes.shape[0]} frames")
    return ExpressionSequence(codes, fps, name, frame_names=names, **opt)
