"""Expression sequences: T codes at a frame rate, optional head pose, and the file formats they come in.

The project's own format, `.npzseq`, is an uncompressed npz (zip of .npy, read with pickles refused) with:
``codes`` (T, D) float32, ``fps`` () float64, optional ``pose`` (T, 4, 4) float64 canonical -> world head pose
with ``pose_source`` () unicode (what it came from), ``frame_names`` (T,) unicode, and ``name`` () unicode.
Files written before the 4x4 have ``rotation`` (T, 3) axis-angle, ``translation`` (T, 3), ``scale`` (T,)
instead, read as x_world = s R x + t (docs/FORMAT.md section 12).
"""

from __future__ import annotations

import io
from dataclasses import InitVar, dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.pose import SIMILARITY, checked_pose, similarity_pose
from npga_core.files.untrusted import FPS_RANGE, MAX_CODE, bounded_floats, npz_names, real_floats
from npga_core.files.untrusted import read_npz as read_npz_arrays

DEFAULT_FPS = 25.0
CODE_KEYS = ("codes", "expression", "expr", "z_exp", "exp", "expressions")
POSE_KEYS = ("rotation", "translation", "scale")
#: Largest sequence file read (all arrays together, as the headers claim them).
MAX_SEQUENCE_BYTES = 512 * 2**20


@dataclass
class ExpressionSequence:
    """T expression codes with a frame rate and an optional per-frame head pose: `pose` (T, 4, 4), canonical
    -> world (x_world = pose[t] @ [x, 1]), built by the reader from its tracker's definition
    (`npga_core.files.pose`), and `pose_source` saying which. The keyword arguments `rotation` (T, 3)
    axis-angle, `translation` (T, 3) and `scale` (T,) build `pose` as x_world = s R x + t."""

    codes: np.ndarray  # (T, D) float32
    fps: float = DEFAULT_FPS
    name: str = ""
    rotation: InitVar[np.ndarray | None] = None
    translation: InitVar[np.ndarray | None] = None
    scale: InitVar[np.ndarray | None] = None
    frame_names: list[str] | None = None
    pose: np.ndarray | None = None  # (T, 4, 4) float64, canonical -> world
    pose_source: str = ""
    notes: list[str] = field(default_factory=list)  # one-line notices of the reader (unmatched shapes, gaps)
    flame: dict[str, np.ndarray] | None = None  # GaussianAvatars: the frames' FLAME inputs (expr, rotation, ...)

    def __post_init__(self, rotation: npt.ArrayLike | None, translation: npt.ArrayLike | None,
                      scale: npt.ArrayLike | None) -> None:
        if rotation is None and translation is None and scale is None:
            return
        if self.pose is not None:
            raise ValueError("give either pose or rotation/translation/scale, not both")
        self.pose = similarity_pose(rotation, translation, scale, len(self), self.name or "sequence")
        self.pose_source = self.pose_source or SIMILARITY

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
        arrays: dict[str, np.ndarray | np.generic] = {"codes": np.asarray(self.codes, np.float32),
                                         "fps": np.float64(self.fps), "name": np.str_(self.name)}
        if self.pose is not None:
            arrays["pose"] = np.asarray(self.pose, np.float64)
            arrays["pose_source"] = np.str_(self.pose_source)
        if self.frame_names is not None:
            arrays["frame_names"] = np.array(self.frame_names, dtype=np.str_)
        buf = io.BytesIO()
        np.savez(buf, **arrays)  # type: ignore[arg-type]
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
    bounded_floats(c, path, "expression codes", MAX_CODE)
    if not (np.isfinite(seq.fps) and FPS_RANGE[0] <= seq.fps <= FPS_RANGE[1]):
        raise AvatarFileError(path, f"frame rate {seq.fps:.6g} is not in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}]")
    if seq.pose is not None:
        seq.pose = checked_pose(seq.pose, c.shape[0], path)
    return seq


def read_npz(path: Path) -> ExpressionSequence:
    """Read `.npzseq`/`.npz` through `untrusted.read_npz`: sizes checked from the headers, real finite numbers."""
    keys = npz_names(path)
    key = next((k for k in CODE_KEYS if k in keys), None)
    if key is None:
        raise AvatarFileError(path, f"no expression array under any of {', '.join(CODE_KEYS)} "
                              f"(keys: {', '.join(keys[:20]) or 'none'})")
    z = read_npz_arrays(path, MAX_SEQUENCE_BYTES, keys=(key, "fps", "name", "frame_names", "pose", "pose_source",
                                                        *POSE_KEYS),
                        kinds={"name": "US", "frame_names": "US", "pose_source": "US"})
    codes = real_floats(z[key], path, "expression codes")
    if codes.ndim == 3 and codes.shape[1] == 1:
        codes = codes[:, 0]
    fps = DEFAULT_FPS
    if "fps" in z:
        if z["fps"].size != 1:
            raise AvatarFileError(path, f"fps must be one number, got shape {z['fps'].shape}")
        fps = float(real_floats(z["fps"], path, "fps", np.float64).reshape(()))
    name = str(z["name"].reshape(-1)[0]) if "name" in z and z["name"].size == 1 else path.stem
    names = [str(s) for s in np.atleast_1d(z["frame_names"])] if "frame_names" in z else None
    if names is not None and len(names) != codes.shape[0]:
        raise AvatarFileError(path, f"{len(names)} frame names for {codes.shape[0]} frames")
    pose, source = _stored_pose(z, codes.shape[0] if codes.ndim == 2 else 0, path)
    return ExpressionSequence(codes, fps, name, frame_names=names, pose=pose, pose_source=source)


def _stored_pose(z: dict[str, np.ndarray], t: int, path: Path) -> tuple[np.ndarray | None, str]:
    """The head pose of an `.npzseq`/`.npz`: `pose` (T, 4, 4) as stored, or the old `rotation`/`translation`/
    `scale` as x_world = s R x + t; (None, "") without either or when the codes are no (T, D) table."""
    if t < 1:
        return None, ""
    if "pose" in z:
        if any(k in z for k in POSE_KEYS):
            raise AvatarFileError(path, f"has both pose and {'/'.join(k for k in POSE_KEYS if k in z)}")
        stored = z.get("pose_source")
        source = str(stored.reshape(-1)[0]) if stored is not None and stored.size == 1 else "as stored"
        return checked_pose(z["pose"], t, path), source
    if any(k in z for k in POSE_KEYS):
        return similarity_pose(z.get("rotation"), z.get("translation"), z.get("scale"), t, path), SIMILARITY
    return None, ""
