"""`OrbitCamera`: the viewer's interactive camera (orbit, pan, zoom, roll) producing OpenCV `Camera`s."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from npga_core.camera.cameras import MAX_POSITION, Camera, direction_vector, focal_from_fov, framing

PRESETS = {"front": (0.0, 0.0), "three_quarter": (35.0, 5.0), "side": (90.0, 0.0), "back": (180.0, 0.0),
           "top": (0.0, 89.0)}


@dataclass
class OrbitCamera:
    """Camera on a sphere around `target`: yaw/pitch in degrees (0, 0 = in front, on +z), roll about the
    viewing axis, `distance` from the target, vertical field of view `fov_y` in degrees. Heads look along +z
    with y up."""

    target: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    distance: float = 1.0
    fov_y: float = 20.0

    def eye(self) -> np.ndarray:
        return np.asarray(self.target, np.float64) + self.distance * direction_vector((self.yaw, self.pitch))

    def axes(self) -> np.ndarray:
        """Rows: camera right, down, forward in world coordinates (OpenCV), roll applied."""
        fwd = -direction_vector((self.yaw, self.pitch))
        up = np.array([0.0, 1.0, 0.0])
        if abs(float(fwd @ up)) > 0.9999:  # looking straight up/down: use -z as the image up
            up = np.array([0.0, 0.0, -1.0]) * np.sign(fwd[1])
        right = np.cross(fwd, up)
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        c, s = math.cos(math.radians(self.roll)), math.sin(math.radians(self.roll))
        right, down = c * right + s * down, -s * right + c * down
        return np.stack([right, down, fwd])

    def camera(self, width: int, height: int) -> Camera:
        """The OpenCV camera for a viewport of `width` x `height` pixels (square pixels, centred)."""
        rot = self.axes()
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ self.eye()
        f = focal_from_fov(self.fov_y, height)
        return Camera(w2c, f, f, width / 2.0, height / 2.0, width, height)

    # -- interaction ---------------------------------------------------------------------------------
    def orbit(self, dx_deg: float, dy_deg: float) -> None:
        self.yaw = (self.yaw + dx_deg + 180.0) % 360.0 - 180.0
        self.pitch = float(np.clip(self.pitch + dy_deg, -89.0, 89.0))

    def pan(self, dx_px: float, dy_px: float, viewport_height: int) -> None:
        """Move the target so the scene follows the mouse by (dx, dy) pixels."""
        per_px = 2.0 * self.distance * math.tan(math.radians(self.fov_y) / 2.0) / max(viewport_height, 1)
        right, down, _ = self.axes()
        self.target = list(np.asarray(self.target) - per_px * (dx_px * right + dy_px * down))

    def zoom(self, steps: float) -> None:
        """Positive steps move closer (10 % per step)."""
        self.distance = float(np.clip(self.distance * 0.9**steps, 1e-4, 1e4))

    def preset(self, name: str) -> None:
        self.yaw, self.pitch = PRESETS[name]
        self.roll = 0.0

    def frame(self, points: np.ndarray, aspect: float = 550 / 802) -> None:
        """Centre on `points` and set the distance so they fill the view from the current direction, within the
        zoom's range of distances and with the eye within the position limit (a cloud at the limit is framed
        as far as a camera may be, not refused)."""
        h = 802
        w = max(1, int(round(h * aspect)))
        centre, distance = framing(points, w, h, self.fov_y, (self.yaw, self.pitch))
        self.distance = float(np.clip(distance, 1e-4, 1e4))
        room = max(MAX_POSITION - self.distance, 0.0)
        norm = float(np.linalg.norm(centre))
        if norm > room:
            centre = centre * (room / norm)
        self.target = [float(v) for v in centre]

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> OrbitCamera:
        cam = OrbitCamera()
        for k in asdict(cam):
            if k in d:
                setattr(cam, k, [float(v) for v in d[k]] if k == "target" else float(d[k]))
        return cam
