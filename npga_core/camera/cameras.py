"""Pinhole cameras in the OpenCV convention (x right, y down, z forward), as in 3DGS and NeRSemble.

A pixel (i, j) covers [i, i+1) x [j, j+1) and has its centre at (i + 0.5, j + 0.5); a camera-space point
(x, y, z) projects to u = fx * x / z + cx, v = fy * y / z + cy. The OpenGL projection used by the renderer
is derived from these intrinsics in one place, `Camera.opengl_projection`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

#: Largest focal length or principal-point coordinate in pixels (`npga_core.files.untrusted` shares it).
MAX_FOCAL = 1e7
#: Largest camera translation (scene units).
MAX_POSITION = 1e4

#: Default image size of the viewer (the NPGA / NeRSemble evaluation resolution).
DEFAULT_WIDTH = 550
DEFAULT_HEIGHT = 802

#: Directions for `frame_points`, as (azimuth, elevation) in degrees around +y; azimuth 0 = in front (+z side).
VIEW_DIRECTIONS: dict[str, tuple[float, float]] = {
    "front": (0.0, 0.0),
    "three_quarter_left": (-45.0, 0.0),
    "three_quarter_right": (45.0, 0.0),
    "left": (-90.0, 0.0),
    "right": (90.0, 0.0),
    "top": (0.0, 35.0),
}


def rigid_error(w2c: np.ndarray, tol: float = 1e-3) -> str | None:
    """Why a 4x4 world-to-camera matrix is no similarity transform within `tol` (a singular or skewed block, a
    translation beyond `MAX_POSITION`, a last row other than 0 0 0 1); None when it is one."""
    if np.abs(w2c[3] - (0.0, 0.0, 0.0, 1.0)).max() > tol:
        return "has a last row other than 0 0 0 1"
    if not np.abs(w2c[:3, 3]).max() <= MAX_POSITION:
        return f"has a translation beyond +-{MAX_POSITION:g}"
    r = w2c[:3, :3]
    gram = r.T @ r
    s2 = float(np.trace(gram)) / 3.0  # a uniform scale (a head pose's s) is allowed
    if not (1e-12 <= s2 <= 1e12 and np.abs(gram / s2 - np.eye(3)).max() <= tol and np.linalg.det(r) > 0):
        return "is not a (scaled) rotation and translation: singular, skewed or mirrored"
    return None


@dataclass
class Camera:
    """A pinhole camera: extrinsics `world_to_camera` (4x4) and intrinsics in pixels."""

    world_to_camera: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        w2c = np.asarray(self.world_to_camera, dtype=np.float64)
        if w2c.shape != (4, 4) or not np.all(np.isfinite(w2c)):
            raise ValueError(f"world_to_camera must be a finite 4x4 matrix, got shape {w2c.shape}")
        self.world_to_camera = w2c
        self.fx, self.fy, self.cx, self.cy = (float(v) for v in (self.fx, self.fy, self.cx, self.cy))
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and math.isfinite(self.fx) and math.isfinite(self.fy)):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not max(self.fx, self.fy, abs(self.cx), abs(self.cy)) <= MAX_FOCAL:
            raise ValueError(f"fx, fy, cx, cy must be within {MAX_FOCAL:g} pixels, got fx={self.fx:.4g}, "
                             f"fy={self.fy:.4g}, cx={self.cx:.4g}, cy={self.cy:.4g}")
        why = rigid_error(w2c)
        if why is not None:
            raise ValueError(f"world_to_camera {why}")

    # --- derived quantities -------------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation (3x3)."""
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """World-to-camera translation (3,)."""
        return self.world_to_camera[:3, 3]

    @property
    def camera_to_world(self) -> np.ndarray:
        """Inverse of `world_to_camera`."""
        return np.linalg.inv(self.world_to_camera)

    @property
    def camera_center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,) (also right for a scaled or sheared world_to_camera)."""
        return -np.linalg.solve(self.rotation, self.translation)

    @property
    def tan_half_fov_x(self) -> float:
        """tan(fov_x / 2) = W / (2 fx), the quantity 3DGS clamps its Jacobian with."""
        return self.width / (2.0 * self.fx)

    @property
    def tan_half_fov_y(self) -> float:
        """tan(fov_y / 2) = H / (2 fy)."""
        return self.height / (2.0 * self.fy)

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(self.tan_half_fov_y))

    def intrinsics(self) -> np.ndarray:
        """The 3x3 matrix K."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def world_to_view(self, points: np.ndarray) -> np.ndarray:
        """Points (N,3) in world space to camera space (N,3), float64."""
        p = np.asarray(points, dtype=np.float64)
        r, t = self.rotation, self.translation
        # by columns, not `p @ r.T`: BLAS's (N, 3) x (3, 3) wakes its thread pool, 21 ms a call for the demo's 79k
        # centres in the window beside llvmpipe's threads (0.6 ms this way)
        out = np.empty((p.shape[0], 3))
        for i in range(3):
            out[:, i] = p[:, 0] * r[i, 0] + p[:, 1] * r[i, 1] + p[:, 2] * r[i, 2] + t[i]
        return out

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (N,3) to pixel coordinates (N,2) (u right, v down; pixel centres at +0.5)."""
        t = self.world_to_view(points)
        z = t[:, 2]
        return np.stack([self.fx * t[:, 0] / z + self.cx, self.fy * t[:, 1] / z + self.cy], axis=1)

    def opengl_projection(self, near: float = 0.01, far: float = 100.0, flip_y: bool = False) -> np.ndarray:
        """4x4 matrix from OpenCV camera space (x right, y down, z forward) to OpenGL clip space.

        NDC x = 2u/W - 1. With `flip_y=False`, NDC y = 2v/H - 1: image row v lands on framebuffer row v, so
        reading an offscreen framebuffer back gives rows top to bottom (use this offscreen). With
        `flip_y=True`, NDC y = 1 - 2v/H, upright on a window. Depth maps z=near..far to NDC -1..1.
        """
        w, h = float(self.width), float(self.height)
        p = np.zeros((4, 4), dtype=np.float64)
        p[0, 0] = 2.0 * self.fx / w
        p[0, 2] = 2.0 * self.cx / w - 1.0
        p[1, 1] = 2.0 * self.fy / h
        p[1, 2] = 2.0 * self.cy / h - 1.0
        if flip_y:
            p[1] *= -1.0
        p[2, 2] = (far + near) / (far - near)
        p[2, 3] = -2.0 * far * near / (far - near)
        p[3, 2] = 1.0
        return p

    def resized(self, width: int, height: int) -> Camera:
        """The same view at another resolution (intrinsics scaled per axis)."""
        sx, sy = width / self.width, height / self.height
        return Camera(self.world_to_camera.copy(), self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
                      width, height)

    # --- files ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict (keys width, height, fx, fy, cx, cy, world_to_camera)."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "world_to_camera": self.world_to_camera.tolist(),
        }

    def to_json(self, path: str | Path) -> None:
        """Write the camera as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @staticmethod
    def from_dict(data: object, source: str = "camera") -> Camera:
        """Build a camera from a dict as written by `to_dict`; ValueError names `source` and the problem."""
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a JSON object, got {type(data).__name__}")
        keys = ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera")
        missing = [k for k in keys if k not in data]
        if missing:
            raise ValueError(f"{source}: missing key(s) {', '.join(missing)}")
        try:
            w2c = np.asarray(data["world_to_camera"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{source}: world_to_camera is not a numeric 4x4 matrix") from None
        if w2c.shape != (4, 4):
            raise ValueError(f"{source}: world_to_camera must be 4x4, got shape {w2c.shape}")
        try:
            scalars = {k: float(data[k]) for k in ("fx", "fy", "cx", "cy")}
            width, height = data["width"], data["height"]
            if isinstance(width, bool) or isinstance(height, bool) or int(width) != width or int(height) != height:
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"{source}: width/height must be integers and fx, fy, cx, cy numbers") from None
        try:
            return Camera(w2c, width=int(width), height=int(height), **scalars)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None


def focal_from_fov(fov_y_deg: float, height: int) -> float:
    """Focal length in pixels for a vertical field of view."""
    if not 0.0 < fov_y_deg < 180.0:
        raise ValueError(f"field of view must be in (0, 180) degrees, got {fov_y_deg}")
    return 0.5 * height / math.tan(math.radians(fov_y_deg) / 2.0)


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike = (0.0, 1.0, 0.0), fov_y_deg: float = 20.0,
            width: int = DEFAULT_WIDTH,
            height: int = DEFAULT_HEIGHT) -> Camera:
    """A camera at `eye` looking at `target`, with `up` pointing up in the image; square pixels, centred cx, cy."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    forward = target - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    forward /= norm
    # OpenCV axes: right = forward x up, down = forward x right (right x down = forward, right-handed).
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = -rot @ eye
    f = focal_from_fov(fov_y_deg, height)
    return Camera(w2c, f, f, width / 2.0, height / 2.0, width, height)


def direction_vector(direction: str | tuple[float, float]) -> np.ndarray:
    """Unit vector from the object towards the camera for a named direction or (azimuth, elevation) degrees."""
    if isinstance(direction, str):
        if direction not in VIEW_DIRECTIONS:
            raise ValueError(f"unknown view direction {direction!r}; choose from {', '.join(VIEW_DIRECTIONS)}")
        direction = VIEW_DIRECTIONS[direction]
    az, el = (math.radians(a) for a in direction)
    return np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])


def framing(points: np.ndarray, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT, fov: float = 20.0,
            direction: str | tuple[float, float] = "front", margin: float = 1.1,
            robust: bool = True) -> tuple[np.ndarray, float]:
    """(centre, distance) of the view that frames a point cloud along `direction` (see `frame_points`). Points
    are taken within the position limit (+-MAX_POSITION: a cloud at 3e38 would put the eye on its target in
    float64) and non-finite ones are ignored."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:  # an empty cloud (a valid avatar of 0 Gaussians): a head-sized box at the origin
        pts = np.array([[-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]])
    pts = np.clip(pts[np.all(np.isfinite(pts), axis=1)], -MAX_POSITION, MAX_POSITION)
    if len(pts) == 0:
        raise ValueError("frame_points: no finite points to frame")
    if robust and len(pts) >= 100:
        lo, hi = np.percentile(pts, [0.5, 99.5], axis=0)
    else:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    extent = max(float(np.linalg.norm(hi - lo)), 1e-6)
    axes = look_at(direction_vector(direction), np.zeros(3), (0.0, 1.0, 0.0), fov, width, height).rotation
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    rel = (corners - centre) @ axes.T  # camera axes: right, down, forward
    tan_y = math.tan(math.radians(fov) / 2.0)
    tan_x = tan_y * width / height
    distance = np.max(np.maximum(margin * np.abs(rel[:, 0]) / tan_x, margin * np.abs(rel[:, 1]) / tan_y) - rel[:, 2])
    return centre, max(float(distance), float(np.max(-rel[:, 2])) + 0.05 * extent)


def frame_points(points: np.ndarray, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                 fov: float = 20.0, direction: str | tuple[float, float] = "front", margin: float = 1.1,
                 robust: bool = True) -> Camera:
    """A camera that frames a point cloud (a head looks along +z with y up, so "front" sits on +z).

    `fov` is the vertical field of view in degrees. The camera looks at the centre of the bounding box
    (of the 0.5..99.5 percentiles per axis when `robust`, so stray points do not shrink the subject) and
    backs off until all eight box corners project inside the image shrunk by `margin`. Other directions:
    "three_quarter_left/right", "left", "right", "top" or (azimuth, elevation) in degrees. Without any
    points, a 20 cm box at the origin is framed.
    """
    centre, distance = framing(points, width, height, fov, direction, margin, robust)
    eye = centre + distance * direction_vector(direction)
    return look_at(eye, centre, (0.0, 1.0, 0.0), fov, width, height)
