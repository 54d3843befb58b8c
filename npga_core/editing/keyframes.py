"""Keyframe timelines: expression-code keys and camera keys, interpolated over time, stored as JSON.

Each track is a list of keys sorted by time. Between key i and key i+1 the value stays at key i for its
`hold` seconds, then moves to key i+1, arriving exactly at key i+1's time. The move is eased: `ease_out` of
key i and `ease_in` of key i+1 (0 = constant speed, 1 = start/stop at rest) reshape the time within the
segment. Expression codes move linearly or smoothly (cubic Hermite through the keys, tangents from the
neighbouring keys, zero at held keys), as chosen by the key the segment leaves. Cameras always move smoothly:
rotation by slerp, centre by the same Hermite curve, intrinsics linearly. Before the first key and after
the last one the track holds its end values. At a key's time the key's value is returned unchanged.

Camera intrinsics are kept relative to the key's image height (cx relative to its width), so `camera_at`
can render at any resolution with the same vertical field of view and square pixels stay square.

File format (`save` / `load`)::

    {"npga_keyframes": 1, "code_dim": D or null,
     "expression": [{"time": s, "code": [D numbers], "interp": "linear"|"smooth",
                     "ease_in": 0..1, "ease_out": 0..1, "hold": s, "label": "..."}, ...],
     "camera": [{"time": s, "camera": {Camera.to_dict()}, "ease_in": .., "ease_out": .., "hold": s,
                 "label": "..."}, ...]}
"""

from __future__ import annotations

import bisect
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
import numpy as np
from msgspec import Meta
from scipy.spatial.transform import Rotation, Slerp

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError, brief
from npga_core.files.atomic import atomic_write
from npga_core.files.rig import camera_of
from npga_core.files.untrusted import (
    MAX_CODE,
    MAX_FRAMES,
    MAX_IMAGE_SIDE,
    MAX_JSON_BYTES,
    MAX_JSON_DEPTH,
    MAX_TIME_S,
    read_json,
)
from npga_core.schema import Text, decode

FORMAT_VERSION = 1
INTERPOLATIONS = ("linear", "smooth")
TRACKS = ("expression", "camera")
SAME_TIME = 1e-6  # keys closer than this (seconds) are the same key
MAX_KEYS = 10000  # keys per track read from a file


@dataclass
class ExpressionKey:
    """An expression code at a time."""

    time: float
    code: np.ndarray  # (D,) float32
    interp: str = "smooth"  # how the segment leaving this key moves
    ease_in: float = 0.0
    ease_out: float = 0.0
    hold: float = 0.0  # seconds the code stays after `time` before moving on
    label: str = ""


@dataclass
class CameraKey:
    """A camera at a time (always interpolated smoothly)."""

    time: float
    camera: Camera
    ease_in: float = 0.0
    ease_out: float = 0.0
    hold: float = 0.0
    label: str = ""


Key = ExpressionKey | CameraKey


def ease(u: float, ease_out: float, ease_in: float) -> float:
    """Time warp of a segment, 0 -> 0 and 1 -> 1, with end slopes 1 - ease_out and 1 - ease_in (monotone)."""
    u2, u3 = u * u, u * u * u
    return (-2 * u3 + 3 * u2) + (u3 - 2 * u2 + u) * (1.0 - ease_out) + (u3 - u2) * (1.0 - ease_in)


def _hermite(p0: np.ndarray, p1: np.ndarray, m0: np.ndarray, m1: np.ndarray, s: float) -> np.ndarray:
    s2, s3 = s * s, s * s * s
    return (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1


def _velocities(keys: list, values: np.ndarray) -> np.ndarray:
    """Per-key velocity (value per second): mean of the adjacent segment slopes, zero at held keys."""
    n = len(keys)
    vel = np.zeros_like(values, dtype=np.float64)
    if n < 2:
        return vel
    dur = np.array([_move_duration(keys, i) for i in range(n - 1)])
    steps = dur <= 0  # held up to the next key: the value jumps, that segment gives no slope
    slopes = (values[1:] - values[:-1]) / np.where(steps, 1.0, dur)[:, None]
    slopes[steps] = 0.0
    vel[0], vel[-1] = slopes[0], slopes[-1]
    vel[1:-1] = 0.5 * (slopes[:-1] + slopes[1:])
    for i, k in enumerate(keys):
        if k.hold > 0:
            vel[i] = 0.0
    return vel


def _move_duration(keys: list, i: int) -> float:
    return keys[i + 1].time - min(keys[i].time + keys[i].hold, keys[i + 1].time)


def _locate(keys: list, t: float) -> tuple[int, float | None]:
    """(i, s): the segment i -> i+1 at eased parameter s, or (i, None) when the value is key i's exactly."""
    t = float(t)
    if t <= keys[0].time:
        return 0, None
    if t >= keys[-1].time:
        return len(keys) - 1, None
    i = bisect.bisect_right([k.time for k in keys], t) - 1
    k0, k1 = keys[i], keys[i + 1]
    start = min(k0.time + k0.hold, k1.time)
    if t <= start:
        return i, None
    u = (t - start) / (k1.time - start)
    return i, ease(u, k0.ease_out, k1.ease_in)


def _norm_intrinsics(cam: Camera) -> np.ndarray:
    return np.array([cam.fx / cam.height, cam.fy / cam.height, cam.cx / cam.width, cam.cy / cam.height])


def _at_size(cam: Camera, width: int, height: int) -> Camera:
    """The camera at another image size, keeping the vertical field of view and the principal point's place."""
    if (width, height) == (cam.width, cam.height):
        return Camera(cam.world_to_camera.copy(), cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    fx, fy, cx, cy = _norm_intrinsics(cam)
    return Camera(cam.world_to_camera.copy(), fx * height, fy * height, cx * width, cy * height, width, height)


@dataclass
class KeyframeTimeline:
    """Expression and camera keyframes; `code_at(t)` and `camera_at(t, w, h)` evaluate them."""

    expression: list[ExpressionKey] = field(default_factory=list)
    camera: list[CameraKey] = field(default_factory=list)
    code_dim: int | None = None

    # -- building ---------------------------------------------------------------------------------
    @property
    def duration(self) -> float:
        """Seconds from 0 to the end of the last key (its hold included); 0 when empty."""
        keys: list[ExpressionKey | CameraKey] = [*self.expression, *self.camera]
        ends = [k.time + k.hold for k in keys]
        return max(ends, default=0.0)

    def is_empty(self) -> bool:
        return not self.expression and not self.camera

    def add_expression(self, time: float, code: np.ndarray, interp: str = "smooth", ease_in: float = 0.0,
                       ease_out: float = 0.0, hold: float = 0.0, label: str = "") -> int:
        """Add (or replace, at the same time) an expression key; returns its index."""
        code = np.asarray(code, dtype=np.float32).reshape(-1).copy()
        if self.code_dim is not None and code.shape[0] != self.code_dim:
            raise ValueError(f"expression key has {code.shape[0]} dims, the timeline has {self.code_dim}")
        if not np.all(np.isfinite(code)):
            raise ValueError("expression key code has NaN or Inf values")
        key = ExpressionKey(float(time), code, interp, float(ease_in), float(ease_out), float(hold), str(label))
        _check_key(key)
        self.code_dim = int(code.shape[0])
        return _insert(self.expression, key)

    def add_camera(self, time: float, camera: Camera, ease_in: float = 0.0, ease_out: float = 0.0,
                   hold: float = 0.0, label: str = "") -> int:
        """Add (or replace, at the same time) a camera key; returns its index. For the viewer's orbit camera
        pass ``orbit.camera(width, height)``."""
        key = CameraKey(float(time), _at_size(camera, camera.width, camera.height), float(ease_in), float(ease_out),
                        float(hold), str(label))
        _check_key(key)
        return _insert(self.camera, key)

    def keys(self, track: str) -> list:
        if track not in TRACKS:
            raise ValueError(f"unknown keyframe track {brief(track)}; choose from {', '.join(TRACKS)}")
        return self.expression if track == "expression" else self.camera

    def update_key(self, track: str, index: int, **changes: object) -> int:
        """Change fields of a key (time, interp, ease_in, ease_out, hold, label, code/camera); returns its new
        index (keys stay sorted; moving onto another key's time replaces that key)."""
        keys = self.keys(track)
        old = keys[index]
        unknown = set(changes) - set(old.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown key field(s) {', '.join(sorted(unknown))}")
        new = replace(old, **changes)
        for name in ("time", "ease_in", "ease_out", "hold"):
            setattr(new, name, float(getattr(new, name)))
        if isinstance(new, ExpressionKey):
            new.code = np.asarray(new.code, np.float32).reshape(-1).copy()
            if new.code.shape != old.code.shape or not np.all(np.isfinite(new.code)):
                raise ValueError(f"expression key code must be {old.code.shape[0]} finite numbers")
        _check_key(new)
        del keys[index]
        return _insert(keys, new)

    def remove_key(self, track: str, index: int) -> None:
        del self.keys(track)[index]
        if not self.expression:
            self.code_dim = None

    # -- evaluating -----------------------------------------------------------------------------------
    def code_at(self, t: float) -> np.ndarray | None:
        """The expression code at time t (float32 (D,)); None without expression keys."""
        keys = self.expression
        if not keys:
            return None
        i, s = _locate(keys, t)
        if s is None:
            return keys[i].code.copy()
        p0, p1 = keys[i].code.astype(np.float64), keys[i + 1].code.astype(np.float64)
        if keys[i].interp == "linear":
            return ((1.0 - s) * p0 + s * p1).astype(np.float32)
        vel = _velocities(keys, np.stack([k.code for k in keys]).astype(np.float64))
        d = _move_duration(keys, i)
        return _hermite(p0, p1, vel[i] * d, vel[i + 1] * d, s).astype(np.float32)

    def camera_at(self, t: float, width: int | None = None, height: int | None = None) -> Camera | None:
        """The camera at time t for a `width` x `height` image (default: the first camera key's size); None
        without camera keys."""
        keys = self.camera
        if not keys:
            return None
        width = keys[0].camera.width if width is None else int(width)
        height = keys[0].camera.height if height is None else int(height)
        i, s = _locate(keys, t)
        if s is None:
            return _at_size(keys[i].camera, width, height)
        c0, c1 = keys[i].camera, keys[i + 1].camera
        rots = Rotation.from_matrix(np.stack([c0.rotation, c1.rotation]))
        rot = Slerp([0.0, 1.0], rots)([s]).as_matrix()[0]
        centres = np.stack([k.camera.camera_center for k in keys])
        vel = _velocities(keys, centres)
        d = _move_duration(keys, i)
        centre = _hermite(centres[i], centres[i + 1], vel[i] * d, vel[i + 1] * d, s)
        fx, fy, cx, cy = (1.0 - s) * _norm_intrinsics(c0) + s * _norm_intrinsics(c1)
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ centre
        return Camera(w2c, fx * height, fy * height, cx * width, cy * height, width, height)

    def frame_times(self, fps: float) -> np.ndarray:
        """Times i / fps from 0 through the duration (at least one frame)."""
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"frame rate must be positive, got {fps}")
        frames = self.duration * fps
        if not frames < MAX_FRAMES:
            raise ValueError(f"{self.duration:.6g} s at {fps:g} fps is more than the {MAX_FRAMES} frames allowed")
        n = int(math.floor(frames + 1e-9)) + 1
        return np.arange(n, dtype=np.float64) / fps

    # -- files ------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        def common(k: Key) -> dict:
            return {"time": k.time, "ease_in": k.ease_in, "ease_out": k.ease_out, "hold": k.hold, "label": k.label}

        return {
            "npga_keyframes": FORMAT_VERSION,
            "code_dim": self.code_dim,
            "expression": [{**common(k), "code": [float(v) for v in k.code], "interp": k.interp}
                           for k in self.expression],
            "camera": [{**common(k), "camera": k.camera.to_dict()} for k in self.camera],
        }

    def save(self, path: str | Path) -> None:
        """Write the timeline as JSON, atomically."""
        text = (json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n").encode()
        atomic_write(path, lambda fh: fh.write(text))

    @staticmethod
    def from_dict(data: object, source: str | Path = "keyframes") -> KeyframeTimeline:
        """Build from `to_dict` output; AvatarFileError("source: problem") for anything malformed."""
        try:
            return _parse(data)
        except ValueError as e:
            raise AvatarFileError(source, str(e)) from None

    @staticmethod
    def load(path: str | Path) -> KeyframeTimeline:
        """Read a timeline JSON file; AvatarFileError("path: problem") when it is missing or malformed."""
        path = Path(path)
        try:
            data = read_json(path, MAX_JSON_BYTES, MAX_JSON_DEPTH, "a keyframe file")
        except OSError as e:
            raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
        return KeyframeTimeline.from_dict(data, path)

    def check_code_dim(self, dim: int, source: str | Path = "keyframes") -> None:
        """AvatarFileError if the expression keys do not fit an avatar with `dim`-dimensional codes."""
        if self.code_dim is not None and self.code_dim != dim:
            raise AvatarFileError(source, f"expression keys have {self.code_dim} dims, the avatar expects {dim}")


# --------------------------------------------------------------------------------------------------
# helpers


def _insert(keys: list, key: Key) -> int:
    """Insert into the sorted `keys`, replacing a key at the same time; O(log n) search."""
    j = bisect.bisect_left(keys, key.time - SAME_TIME, key=_time)
    if j < len(keys) and abs(keys[j].time - key.time) < SAME_TIME:
        keys[j] = key
        return j
    j = bisect.bisect_left(keys, key.time, key=_time)
    keys.insert(j, key)
    return j


def _time(key: Key) -> float:
    return key.time


def _check_key(key: Key) -> None:
    if not (math.isfinite(key.time) and 0 <= key.time <= MAX_TIME_S):
        raise ValueError(f"key time must be in 0..{MAX_TIME_S:g} seconds, got {key.time:.6g}")
    for name in ("ease_in", "ease_out"):
        v = getattr(key, name)
        if not (math.isfinite(v) and 0.0 <= v <= 1.0):
            raise ValueError(f"{name} must be in 0..1, got {v}")
    if not (math.isfinite(key.hold) and 0 <= key.hold <= MAX_TIME_S):
        raise ValueError(f"hold must be in 0..{MAX_TIME_S:g} seconds, got {key.hold:.6g}")
    if isinstance(key, ExpressionKey) and not np.all(np.abs(key.code) <= MAX_CODE):
        raise ValueError(f"code values must be finite within +-{MAX_CODE:g}")
    if isinstance(key, ExpressionKey) and key.interp not in INTERPOLATIONS:
        raise ValueError(f"interp {brief(key.interp)} is not one of {', '.join(INTERPOLATIONS)}")


_Seconds = Annotated[float, Meta(ge=0.0, le=MAX_TIME_S)]
_Ease = Annotated[float, Meta(ge=0.0, le=1.0)]
_Code = Annotated[list[Annotated[float, Meta(ge=-MAX_CODE, le=MAX_CODE)]], Meta(min_length=1, max_length=65536)]


class _Key(msgspec.Struct, kw_only=True):
    """What every key of a file holds (unknown fields are ignored)."""

    time: _Seconds
    ease_in: _Ease = 0.0
    ease_out: _Ease = 0.0
    hold: _Seconds = 0.0
    label: Text = ""


class _ExpressionKey(_Key):
    code: _Code
    interp: Literal["linear", "smooth"] = "smooth"


class _CameraKey(_Key):
    camera: Any  # a `CameraFile`, decoded by `camera_of`


class _File(msgspec.Struct):
    """A keyframe file (`KeyframeTimeline.to_dict`)."""

    npga_keyframes: int
    code_dim: Annotated[int, Meta(ge=1, le=2**31 - 1)] | None = None
    expression: Annotated[list[_ExpressionKey], Meta(max_length=MAX_KEYS)] = []
    camera: Annotated[list[_CameraKey], Meta(max_length=MAX_KEYS)] = []


def _common(k: _Key) -> dict[str, Any]:
    return {"ease_in": k.ease_in, "ease_out": k.ease_out, "hold": k.hold, "label": k.label}


def _distinct_times(track: str, keys: list[_ExpressionKey] | list[_CameraKey]) -> None:
    """ValueError naming the later of two keys of a track closer than `SAME_TIME`."""
    seen: list[float] = []
    for j, k in enumerate(keys):
        i = bisect.bisect_left(seen, k.time - SAME_TIME)
        if i < len(seen) and abs(seen[i] - k.time) < SAME_TIME:
            raise ValueError(f"{track}[{j}]: two {track} keys at time {k.time:g}")
        bisect.insort(seen, k.time)


def _add_camera(tl: KeyframeTimeline, c: _CameraKey) -> None:
    cam = camera_of(c.camera, "camera")
    if max(cam.width, cam.height) > MAX_IMAGE_SIDE:
        raise ValueError(f"camera image {cam.width}x{cam.height} is larger than {MAX_IMAGE_SIDE} pixels on a side")
    tl.add_camera(c.time, cam, **_common(c))


def _parse(data: object) -> KeyframeTimeline:
    """The timeline of a file's parsed JSON: its version, then `_File`'s schema, then each key added (ValueError
    naming the field or the key)."""
    if not isinstance(data, dict) or "npga_keyframes" not in data:
        raise ValueError("not an npga-view keyframe file (no 'npga_keyframes' version)")
    if data["npga_keyframes"] != FORMAT_VERSION:
        raise ValueError(f"keyframe format version {brief(data['npga_keyframes'])} is not supported (expected "
                         f"{FORMAT_VERSION})")
    f: _File = decode(data, _File)
    _distinct_times("expression", f.expression)
    _distinct_times("camera", f.camera)
    tl = KeyframeTimeline(code_dim=f.code_dim)
    where = ""
    try:
        for j, e in enumerate(f.expression):
            where = f"expression[{j}]"
            tl.add_expression(e.time, np.asarray(e.code, np.float64), e.interp, **_common(e))
        for j, c in enumerate(f.camera):
            where = f"camera[{j}]"
            _add_camera(tl, c)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    if f.code_dim is not None and tl.expression and tl.code_dim != f.code_dim:
        raise ValueError(f"expression codes have {tl.code_dim} dims, code_dim says {f.code_dim}")
    return tl
