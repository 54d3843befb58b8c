"""Camera rigs: NeRSemble-style `camera_params.json` (`world_2_cam` per serial, shared `intrinsics`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError


def load_rig(path: str | Path) -> dict[str, Camera]:
    """Cameras by serial. The image size is taken from `image_size` [w, h] if present, else 2*cx x 2*cy."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise AvatarFileError(path, "no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise AvatarFileError(path, f"not a readable JSON camera file ({e})") from None
    if not isinstance(d, dict) or "world_2_cam" not in d or "intrinsics" not in d:
        raise AvatarFileError(path, "expected keys 'world_2_cam' (per serial) and 'intrinsics'")
    try:
        k = np.asarray(d["intrinsics"], np.float64)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise ValueError(f"intrinsics must be a 3x3 matrix, got shape {k.shape}")
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        w, h = d.get("image_size") or (int(round(2 * cx)), int(round(2 * cy)))
        cams = {}
        for serial, m in d["world_2_cam"].items():
            cams[str(serial)] = Camera(np.asarray(m, np.float64), fx, fy, cx, cy, int(w), int(h))
    except (TypeError, ValueError, AttributeError) as e:
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
