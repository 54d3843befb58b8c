"""Camera files: one camera (`Camera.to_json`'s layout, `render --camera`) and NeRSemble-style rigs
(`camera_params.json`: `world_2_cam` per serial, shared `intrinsics`), read as untrusted JSON."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.files.untrusted import image_size, json_dict, read_json, shown

#: Most cameras read from one rig file.
MAX_CAMERAS = 1024


def load_camera(path: str | Path) -> Camera:
    """One camera as `Camera.to_json` writes it, read as untrusted JSON (regular file, size, depth and number
    bounds); AvatarFileError naming the file and the problem."""
    path = Path(path)
    data = read_json(path, what="a camera file")
    try:
        return Camera.from_dict(data, source="camera")
    except ValueError as e:
        raise AvatarFileError(path, str(e).removeprefix("camera: ")) from None


def load_rig(path: str | Path) -> dict[str, Camera]:
    """Cameras by serial (escaped with `shown`: lone surrogates or newlines never reach the UI). The image
    size is taken from `image_size` [w, h] if present, else 2*cx x 2*cy.

    Read as untrusted JSON (regular file, size and depth bounds); image sides must be within
    `MAX_IMAGE_SIDE`, at most `MAX_CAMERAS` cameras.
    """
    path = Path(path)
    d = json_dict(read_json(path, what="a camera file"), path, "a camera file")
    if "world_2_cam" not in d or "intrinsics" not in d:
        raise AvatarFileError(path, "expected keys 'world_2_cam' (per serial) and 'intrinsics'")
    w2c = json_dict(d["world_2_cam"], path, "world_2_cam")
    if len(w2c) > MAX_CAMERAS:
        raise AvatarFileError(path, f"{len(w2c)} cameras, more than the {MAX_CAMERAS} allowed")
    try:
        k = _matrix(d["intrinsics"], (3, 3), "intrinsics")
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        size = d.get("image_size")
        if size is None:
            size = (round(2 * cx), round(2 * cy))
        elif not isinstance(size, list) or len(size) != 2:
            raise ValueError("image_size must be [width, height]")
        w, h = image_size(size[0], size[1], path)
        cams = {}
        for serial, m in w2c.items():
            m44 = _matrix(m, (4, 4), f"world_2_cam[{shown(serial)!r}]")
            cams[shown(serial)] = Camera(m44, fx, fy, cx, cy, w, h)  # serials are shown (imgui): escaped
    except (TypeError, ValueError, AttributeError, OverflowError) as e:
        raise AvatarFileError(path, f"bad camera data: {e}") from None
    if not cams:
        raise AvatarFileError(path, "no cameras in world_2_cam")
    return dict(sorted(cams.items()))


def _matrix(value: object, shape: tuple[int, int], what: str) -> np.ndarray:
    """A finite real matrix of `shape` from parsed JSON (lists of numbers only)."""
    if not isinstance(value, list) or len(value) != shape[0] or not all(
            isinstance(row, list) and len(row) == shape[1] and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in row) for row in value):
        raise ValueError(f"{what} must be a {shape[0]}x{shape[1]} matrix of numbers")
    m = np.asarray(value, np.float64)
    if not np.isfinite(m).all():
        raise ValueError(f"{what} has non-finite values")
    return m


def fit_camera(cam: Camera, width: int, height: int) -> Camera:
    """The same view at another viewport size: scale to fit, keep the principal point's relative place."""
    s = min(width / cam.width, height / cam.height)
    ox = (width - cam.width * s) / 2.0
    oy = (height - cam.height * s) / 2.0
    return Camera(cam.world_to_camera, cam.fx * s, cam.fy * s, cam.cx * s + ox, cam.cy * s + oy, width, height)
