"""Multi-view captures laid out as their dataset code reads them, images read lazily within a memory budget.

- NeRSemble (the `nersemble` data manager's sequence folder): `camera_params.json` (world_2_cam per serial,
  shared intrinsics; `npga_core.files.rig`), `timesteps/frame_NNNNN/images[-Kx]/cam_SERIAL.{png,jpg}`, alpha
  mattes `timesteps/frame_NNNNN/alpha_map/cam_SERIAL.png` and, where present, face masks
  `timesteps/frame_NNNNN/facer_segmentation_masks/segmentation_cam_SERIAL.png`.
- GaussianHeadAvatar's preprocessed folders: `images/NNNN/image_CAM.jpg` with `mask_CAM.jpg`, and
  `cameras/NNNN/camera_CAM.npz` holding `extrinsic` (3x4 or 4x4 world -> camera, OpenCV) and `intrinsic` (3x3,
  pixels of a 2048x2048 image: scaled to the file's own size, see GHA_ORIGINAL_RESOLUTION).

A missing image, an unreadable file or a camera the rig lacks is one line in `problems`; the rest is evaluated.
Images are PNG or JPEG regular files whose size is read from their headers (by Pillow) before anything is decoded
(at most `MAX_IMAGE_SIDE` a side: a few bytes of PNG can claim gigapixels); camera values are checked as `Camera`
does.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
import warnings
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.files.rig import load_rig
from npga_core.files.sequences import ExpressionSequence
from npga_core.files.untrusted import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    check_pixels,
    open_regular,
    read_bytes,
    read_npz,
    real_floats,
)

_DECODE_LOCK = threading.Lock()  # one decode at a time owns descriptor 2
#: Largest image file read (a 16384-pixel-a-side PNG of noise is ~800 MB; captures are far smaller)
MAX_IMAGE_BYTES = 1 << 30

DEFAULT_BUDGET_BYTES = 1 << 30
#: GHA's `dataset.original_resolution` (config/config.py: "should match the intrinsic"): its preprocessing saves K
#: for 2048x2048 images (preprocess/preprocess_nersemble.py, SIZE), and its Dataset resizes every image it reads to
#: that size before using K (lib/dataset/Dataset.py, __getitem__), so K is in pixels of a 2048x2048 image whatever
#: the size of the file on disk (e.g. the 256x256 `image_lowres_` files)
GHA_ORIGINAL_RESOLUTION = 2048
NERSEMBLE, GHA = "nersemble", "gha"
_FRAME = re.compile(r"frame_(\d+)$")
_NUMBER = re.compile(r"(\d+)")


@dataclass
class View:
    """One frame seen by one camera: where its files are (mask may be None) and its camera."""

    frame: int
    camera_id: str
    camera: Camera
    image_path: Path
    mask_path: Path | None = None
    face_mask_path: Path | None = None


@dataclass
class Capture:
    """The views of a capture by (frame, camera), the problems found while listing it, and an image cache."""

    root: Path
    layout: str
    views: dict[tuple[int, str], View]
    problems: list[str] = field(default_factory=list)
    budget_bytes: int = DEFAULT_BUDGET_BYTES
    _cache: OrderedDict = field(default_factory=OrderedDict, repr=False)
    _cached_bytes: int = 0

    @property
    def frames(self) -> list[int]:
        return sorted({f for f, _ in self.views})

    @property
    def cameras(self) -> list[str]:
        return sorted({c for _, c in self.views})

    @property
    def has_face_masks(self) -> bool:
        return any(v.face_mask_path is not None for v in self.views.values())

    def image(self, path: Path, grey: bool = False) -> np.ndarray:
        """An image as float32 in [0, 1], (H, W, 3) RGB or (H, W) for masks; cached up to `budget_bytes`.
        AvatarFileError naming the file when it cannot be read."""
        key = (path, grey)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        img = read_image(path, grey)
        self._cache[key] = img
        self._cached_bytes += img.nbytes
        while self._cached_bytes > self.budget_bytes and len(self._cache) > 1:
            _, old = self._cache.popitem(last=False)
            self._cached_bytes -= old.nbytes
        return img

    @property
    def cached_bytes(self) -> int:
        return self._cached_bytes


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of a PNG or JPEG from its header (read by Pillow, nothing decoded); AvatarFileError when the
    file is missing, not a regular file, neither format, or more than `MAX_IMAGE_SIDE` pixels a side."""
    from PIL import Image

    if not path.is_file():
        raise AvatarFileError(path, "missing (no such image file)")
    try:
        with open_regular(path, "an image") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # sizes are bounded below
            with Image.open(fh, formats=("PNG", "JPEG")) as im:
                size: tuple[int, int] = im.size
    except Image.DecompressionBombError as e:  # Pillow's own bound, far above ours
        claimed = re.search(r"\((\d+) pixels\)", str(e))
        count = f"{int(claimed.group(1)):,}" if claimed else "too many"
        raise AvatarFileError(path, f"image of {count} pixels, more than the {MAX_IMAGE_PIXELS:,} allowed") from None
    except Image.UnidentifiedImageError:
        raise AvatarFileError(path, "unreadable image (not a PNG or JPEG, or its header is cut short)") from None
    except (OSError, ValueError, SyntaxError) as e:
        raise AvatarFileError(path, f"cannot read: {getattr(e, 'strerror', None) or e}") from None
    if min(size) < 1:
        raise AvatarFileError(path, "unreadable image (no image size in its header)")
    if max(size) > MAX_IMAGE_SIDE:
        raise AvatarFileError(path, f"image of {size[0]}x{size[1]} pixels, more than {MAX_IMAGE_SIDE} a side")
    check_pixels(size[0], size[1], path)
    return size


def _decode_quietly(data: bytes) -> tuple[np.ndarray | None, str]:
    """cv2.imdecode of `data` with the process's stderr (descriptor 2) captured: libjpeg and libpng write their
    warnings there ("Corrupt JPEG data: premature end of data segment") and still return an image; OpenCV's own
    warnings are switched to errors only. Returns (image or None, what the decoders said)."""
    import cv2

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    with _DECODE_LOCK, tempfile.TemporaryFile() as sink:
        sys.stderr.flush()
        saved = os.dup(2)
        try:
            os.dup2(sink.fileno(), 2)
            try:
                img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            except cv2.error:
                img = None
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        sink.seek(0)
        said = sink.read(4096).decode("utf-8", "replace").strip()
    return img, said


def read_image(path: Path, grey: bool = False) -> np.ndarray:
    """Float32 [0, 1] RGB (H, W, 3), or (H, W) with `grey` (the first channel of a colour file).

    The bytes are read through the untrusted-file gate and decoded from memory (OpenCV never sees the path: its
    reader crashed on a name that is not UTF-8); a JPEG without its end marker (truncated: libjpeg would fill the
    rest grey and only say so on stderr) or an image whose decoded size differs from its header is refused."""
    size = image_size(path)  # before decoding: a regular PNG/JPEG file of a bounded size
    data = read_bytes(path, MAX_IMAGE_BYTES, "an image")
    if data[:2] == b"\xff\xd8" and b"\xff\xd9" not in data[-1024:]:  # entropy-coded data never holds FFD9
        raise AvatarFileError(path, "unreadable image (a truncated JPEG: no end-of-image marker)")
    if data[:4] == b"\x89PNG" and b"IEND" not in data[-64:]:
        raise AvatarFileError(path, "unreadable image (a truncated PNG: no IEND chunk)")
    img, said = _decode_quietly(data)
    if said:  # libjpeg/libpng decoded what they could and said what was wrong on stderr: refused, not scored
        raise AvatarFileError(path, f"corrupt image ({said.splitlines()[0][:120]})")
    if img is None or img.shape[1::-1] != size:
        raise AvatarFileError(path, "unreadable image (not a PNG/JPEG OpenCV can decode)")
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    img = img.astype(np.float32) / scale
    if grey:
        return img if img.ndim == 2 else img[..., 2 if img.shape[2] >= 3 else 0]
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img[..., 2::-1][..., :3] if img.shape[2] >= 3 else np.repeat(img[..., :1], 3, 2))


def load_capture(root: str | Path, budget_bytes: int = DEFAULT_BUDGET_BYTES) -> Capture:
    """Recognise the layout of `root` (NeRSemble or GHA) and list its views; AvatarFileError if neither."""
    root = Path(root)
    if not root.is_dir():
        raise AvatarFileError(root, "not a folder (expected a NeRSemble or GHA capture)")
    if (root / "timesteps").is_dir():
        cap = _nersemble(root)
    elif (root / "images").is_dir() and (root / "cameras").is_dir():
        cap = _gha(root)
    else:
        raise AvatarFileError(root, "neither a NeRSemble capture (timesteps/, camera_params.json) nor GHA's "
                              "preprocessed folders (images/, cameras/)")
    cap.budget_bytes = budget_bytes
    if not cap.views:
        raise AvatarFileError(root, "no usable views: " + ("; ".join(cap.problems[:3]) or "no images"))
    return cap


def _rig_path(root: Path) -> Path:
    for p in (root / "camera_params.json", root / "calibration" / "camera_params.json",
              root.parent.parent / "calibration" / "camera_params.json"):
        if p.is_file():
            return p
    raise AvatarFileError(root / "camera_params.json", "missing (the capture's rig)")


def _nersemble(root: Path) -> Capture:
    rig = load_rig(_rig_path(root))
    views: dict[tuple[int, str], View] = {}
    problems: list[str] = []
    sized: dict[str, Camera] = {}  # each camera's size from its first readable image (decoded once)
    for folder in sorted((root / "timesteps").iterdir()):
        m = _FRAME.match(folder.name)
        if not m or not folder.is_dir():
            continue
        frame = int(m.group(1))
        image_dirs = sorted(d for d in folder.iterdir() if d.is_dir() and d.name.startswith("images"))
        if not image_dirs:
            problems.append(f"{folder}: no images folder")
            continue
        found = set()
        for f in sorted(image_dirs[0].iterdir()):
            if not (f.name.startswith("cam_") and f.suffix.lower() in (".png", ".jpg", ".jpeg")):
                continue
            serial = f.stem[4:]
            found.add(serial)
            if serial not in rig:
                problems.append(f"{f}: camera {serial} is not in the rig")
                continue
            try:
                cam = sized.get(serial) or _at_size(rig[serial], f)
            except AvatarFileError as e:
                problems.append(str(e))
                continue
            sized[serial] = cam
            alpha = folder / "alpha_map" / f"cam_{serial}.png"
            face = folder / "facer_segmentation_masks" / f"segmentation_cam_{serial}.png"
            views[(frame, serial)] = View(frame, serial, cam, f, alpha if alpha.is_file() else None,
                                          face if face.is_file() else None)
        for serial in sorted(set(rig) - found):
            problems.append(f"{image_dirs[0] / f'cam_{serial}'}.*: missing image")
    return Capture(root, NERSEMBLE, views, problems)


def _at_size(cam: Camera, image: Path) -> Camera:
    """The rig camera scaled to the image's size (NeRSemble's images-Kx folders are downscaled)."""
    w, h = image_size(image)
    if (w, h) == (cam.width, cam.height):
        return cam
    sx, sy = w / cam.width, h / cam.height
    try:
        return Camera(cam.world_to_camera, cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, w, h)
    except ValueError as e:
        raise AvatarFileError(image, f"the rig's camera scaled to this image: {e}") from None


def _gha(root: Path) -> Capture:
    views: dict[tuple[int, str], View] = {}
    problems: list[str] = []
    for folder in sorted((root / "images").iterdir()):
        if not folder.is_dir() or not folder.name.isdigit():
            continue
        frame = int(folder.name)
        for f in sorted(folder.glob("image_*")):
            cam_id = f.stem[len("image_"):]
            cam_file = root / "cameras" / folder.name / f"camera_{cam_id}.npz"
            try:
                cam = _gha_camera(cam_file, f)
            except AvatarFileError as e:
                problems.append(str(e))
                continue
            masks = sorted(folder.glob(f"mask_{cam_id}.*"))
            views[(frame, cam_id)] = View(frame, cam_id, cam, f, masks[0] if masks else None)
    return Capture(root, GHA, views, problems)


def _gha_camera(path: Path, image: Path) -> Camera:
    if not path.is_file():
        raise AvatarFileError(path, "missing (the camera of " + image.name + ")")
    z = read_npz(path, 1 << 16, keys=("extrinsic", "intrinsic"))
    if "extrinsic" not in z or "intrinsic" not in z:
        raise AvatarFileError(path, "expected arrays 'extrinsic' and 'intrinsic'")
    ext = real_floats(z["extrinsic"], path, "extrinsic", np.float64)
    k = real_floats(z["intrinsic"], path, "intrinsic", np.float64)
    if ext.shape not in ((3, 4), (4, 4)) or k.shape != (3, 3):
        raise AvatarFileError(path, f"extrinsic {ext.shape} / intrinsic {k.shape}: expected 3x4 and 3x3")
    w2c = np.eye(4)
    w2c[:3] = ext[:3]
    w, h = image_size(image)
    sx, sy = w / GHA_ORIGINAL_RESOLUTION, h / GHA_ORIGINAL_RESOLUTION  # K is in pixels of a 2048x2048 image
    try:  # Camera checks focal lengths, principal point and a rigid world_to_camera
        return Camera(w2c, k[0, 0] * sx, k[1, 1] * sy, k[0, 2] * sx, k[1, 2] * sy, w, h)
    except ValueError as e:
        raise AvatarFileError(path, f"bad camera: {e}") from None


def code_index(sequence: ExpressionSequence, frame: int, position: int) -> int | None:
    """The sequence row of capture `frame` (its `position`-th frame): by the number in the sequence's frame
    names when it has them, else the frame number itself when in range, else None."""
    if sequence.frame_names:
        for i, name in enumerate(sequence.frame_names):
            nums = _NUMBER.findall(name)
            if nums and int(nums[-1]) == frame:
                return i
        return None
    return frame if 0 <= frame < len(sequence) else (position if position < len(sequence) else None)
