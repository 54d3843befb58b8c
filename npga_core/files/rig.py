"""Camera files: one camera (`Camera.to_json`'s layout, `render --camera`) and NeRSemble-style rigs
(`camera_params.json`: `world_2_cam` per serial, shared `intrinsics`), read as untrusted JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.files.untrusted import MAX_IMAGE_SIDE, read_json, shown
from npga_core.schema import Finite, decode, decode_file, number

#: Most cameras read from one rig file.
MAX_CAMERAS = 1024


_Row3 = tuple[Finite, Finite, Finite]
_Row4 = tuple[Finite, Finite, Finite, Finite]
_Matrix4 = tuple[_Row4, _Row4, _Row4, _Row4]


class CameraFile(msgspec.Struct):
    """One camera as `Camera.to_dict` writes it (width and height whole numbers; `Camera` checks the rest)."""

    width: Finite
    height: Finite
    fx: Finite
    fy: Finite
    cx: Finite
    cy: Finite
    world_to_camera: _Matrix4


def camera_of(data: object, where: str = "") -> Camera:
    """The `Camera` of a parsed camera object (`CameraFile`'s schema, then `Camera`'s own checks); ValueError
    naming the field after `where`."""
    c: CameraFile = decode(data, CameraFile, where)
    w, h = (number(v, f"{where}.{k}" if where else k, 1, 2**31 - 1, whole=True)
            for k, v in (("width", c.width), ("height", c.height)))
    try:
        return Camera(np.asarray(c.world_to_camera, np.float64), c.fx, c.fy, c.cx, c.cy, w, h)
    except ValueError as e:
        raise ValueError(f"{where}: {e}" if where else str(e)) from None


def load_camera(path: str | Path) -> Camera:
    """One camera as `Camera.to_json` writes it, read as untrusted JSON (regular file, size, depth and number
    bounds) and decoded by `CameraFile`; AvatarFileError naming the file and the problem."""
    path = Path(path)
    try:
        return camera_of(read_json(path, what="a camera file"))
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None


class _RigFile(msgspec.Struct):
    """NeRSemble's ``camera_params.json``: ``world_2_cam`` per serial (4x4), shared ``intrinsics`` (3x3) and an
    optional ``image_size`` [w, h] (integers; a float with an integral value is taken as one)."""

    world_2_cam: Annotated[dict[str, Any], Meta(max_length=MAX_CAMERAS)]  # each a `_Matrix4`
    intrinsics: tuple[_Row3, _Row3, _Row3]
    image_size: tuple[Finite, Finite] | None = None


def load_rig(path: str | Path) -> dict[str, Camera]:
    """Cameras by serial (escaped with `shown`: lone surrogates or newlines never reach the UI). The image
    size is taken from `image_size` [w, h] if present, else 2*cx x 2*cy.

    Read as untrusted JSON (regular file, size and depth bounds) and decoded by `_RigFile`'s schema; image sides
    must be within `MAX_IMAGE_SIDE`, at most `MAX_CAMERAS` cameras.
    """
    path = Path(path)
    rig = decode_file(read_json(path, what="a camera file"), _RigFile, path)
    k = np.asarray(rig.intrinsics, np.float64)
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    size = rig.image_size if rig.image_size is not None else (round(2 * cx), round(2 * cy))
    try:
        w, h = (number(v, f"image_size[{i}]", 1, MAX_IMAGE_SIDE, whole=True) for i, v in enumerate(size))
        cams = {}
        for serial, m in rig.world_2_cam.items():  # serials are shown (imgui): escaped
            w2c = decode_file(m, _Matrix4, path, f"world_2_cam[{shown(serial)[:60]!r}]")
            cams[shown(serial)] = Camera(np.asarray(w2c, np.float64), fx, fy, cx, cy, w, h)
    except (TypeError, ValueError, OverflowError) as e:
        raise AvatarFileError(path, f"bad camera data: {e}") from None
    if not cams:
        raise AvatarFileError(path, "no cameras in world_2_cam")
    return dict(sorted(cams.items()))


def fit_camera(cam: Camera, width: int, height: int) -> Camera:
    """The same view at another viewport size: scale to fit, keep the principal point's relative place."""
    s = min(width / cam.width, height / cam.height)
    ox = (width - cam.width * s) / 2.0
    oy = (height - cam.height * s) / 2.0
    return Camera(cam.world_to_camera, cam.fx * s, cam.fy * s, cam.cx * s + ox, cam.cy * s + oy, width, height)
