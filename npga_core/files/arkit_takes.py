"""ARKit face-capture takes: Live Link Face CSV and ARKit-style JSON, read into weights and turned into codes.

- Live Link Face CSV (Epic's iPhone app): a header ``Timecode,BlendShapeCount,<52 shapes>,HeadYaw,...,
  RightEyeRoll`` (PascalCase; the app's column order is not its UDP packet order, so columns are read by
  name) and one row per frame; ``Timecode`` is ``HH:MM:SS:FF.sss`` (frame FF at the timecode's rate, .sss a
  fraction of a frame). The timecode's rate is the smallest common rate above every FF seen (`timecode_rate`);
  the take's own is its median row spacing snapped to whole timecode frames (`recorded_rate`: 30 on a 60 count). Head
  angles (radians) give the head pose; eye angles are kept; angle columns all zero mean "not recorded".
- JSON: LAM Audio2Expression's ``{"names", "metadata": {"fps"}, "frames": [{"weights", "time"}]}`` (a
  ``head_pose`` beside them, as in LAM_WebRender's example, is ignored and said so: `LAM_HEAD_POSE_IGNORED`);
  NVIDIA Audio2Face's blendshape export ``{"exportFps", "numPoses", "numFrames", "facsNames", "weightMat"}``
  (one row of ``numPoses`` weights per frame at ``exportFps``); ``{"names": [...], "values": [[...]]}``;
  MediaPipe face-landmarker category lists (per frame ``[{"categoryName"|"category_name", "score"}]``,
  optionally under ``categories``/``faceBlendshapes``, with ``timestampMs``/``timestamp_ms``), as a list, under
  ``frames``, or one FaceLandmarkerResult alone; one object per frame ``[{"time": t, "blendshapes": {name:
  value}}]``; and a plain ``{name: [values], "fps": rate}``.

Frames are timed by their timecodes: a take is resampled (linear) to a uniform grid at its rate from its
first frame, so dropped frames do not speed the take up. Through a `BlendshapeBasis` it becomes an
`ExpressionSequence` (names matched by `blendshape_names`; shapes the avatar lacks and frames not recorded are
one-line notes of the sequence, naming the file).
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.errors import AvatarFileError, shown
from npga_core.files.atomic import atomic_write
from npga_core.files.blendshape_names import ANGLE_NAMES, match_names
from npga_core.files.sequences import ExpressionSequence
from npga_core.files.untrusted import parse_json, read_bytes
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.schema import Name, SchemaError, decode, decode_file

#: Largest take file read (a 52-shape take at 60 fps is ~0.6 kB a frame: an hour is ~130 MB; 64 MiB bounds the
#: parsed form well under a gigabyte).
MAX_TAKE_BYTES = 64 * 2**20
#: Most frames and columns in a take.
MAX_FRAMES = 2_000_000
MAX_COLUMNS = 512
#: Most values (frames x shapes) a take's timing may make `resample` fill, and the largest angle (radians).
MAX_RESAMPLED_VALUES = 1 << 26
MAX_ANGLE = 1e3
#: Common frame rates a Live Link Face timecode's frame field may count at.
RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 100.0, 120.0, 240.0)
JSON_FPS = 30.0
#: Most timecode frames between a take's rows that still count as its recording rate (`recorded_rate`).
MAX_STEP = 8
TAKE_SUFFIXES = (".csv", ".json")
HEAD_POSE = "ARKit head angles (radians): x_world = Ry(yaw) Rx(pitch) Rz(roll) x"
#: LAM_WebRender's asset/test_expression_1s.json carries a `head_pose` (T x 3 small numbers) that no code of LAM's
#: produces or reads: LAM_Audio2Expression returns ``"headpose": None`` (engines/infer.py line 233, models/utils.py
#: line 136), LAM_WebRender's src/gaussianAvatar.ts (lines 53-66) reads only ``names`` and the frames' ``weights``
#: and its player (gaussian-splat-renderer-for-lam 0.0.8) never mentions it; aigc3d/LAM and OpenAvatarChat do
#: not either. Its axes, order and units are nowhere defined, so it is not guessed at.
LAM_HEAD_POSE_IGNORED = ("head_pose ignored: no LAM code writes or reads it (Audio2Expression returns no head pose, "
                         "the web player reads only the weights), so its axes and units are unknown")
_TIMECODE = re.compile(r"^(\d{1,2}):(\d{2}):(\d{2})[:;](\d{1,3})(?:\.(\d{1,9}))?$")


@dataclass
class Take:
    """Weights (T, B) over `names`, per-frame times (T,) in seconds, the rate, and angles when recorded."""

    weights: np.ndarray  # (T, B) float32
    names: tuple[str, ...]
    times: np.ndarray  # (T,) float64, strictly increasing
    fps: float
    head: np.ndarray | None = None  # (T, 3) yaw, pitch, roll in radians
    eyes: np.ndarray | None = None  # (T, 6) left yaw, pitch, roll, right yaw, pitch, roll
    name: str = ""
    ignored: str = ""  # one line: what of the file is not used, and why (shown by `info` and as a note)


# ------------------------------------------------------------------------------------------ timecodes


def parse_timecode(text: str) -> tuple[int, float]:
    """(whole seconds of the day, frame field + fraction) of ``HH:MM:SS:FF[.sss]``; ValueError if malformed."""
    m = _TIMECODE.match(text.strip())
    if m is None:
        raise ValueError(f"timecode {text.strip()[:40]!r} is not HH:MM:SS:FF.sss")
    h, mi, s, ff = (int(m.group(i)) for i in range(1, 5))
    if h > 23 or mi > 59 or s > 59:
        raise ValueError(f"timecode {text.strip()!r} is out of range")
    frac = float("0." + m.group(5)) if m.group(5) else 0.0
    return h * 3600 + mi * 60 + s, ff + frac


def timecode_rate(secs: np.ndarray, frames: np.ndarray) -> float:
    """The take's rate from its timecodes: the smallest common rate above every frame field seen when the take
    crosses a second; within one second that is ambiguous and Live Link Face's 60 is taken when it fits."""
    top = int(np.floor(np.max(frames))) if len(frames) else 0
    if len(secs) and secs.max() == secs.min() and top < 60:
        return 60.0
    for r in RATES:
        if top < r:
            return r
    raise ValueError(f"timecode frame field {top} exceeds every known rate")


def timecode_seconds(codes: list[str], path: str | Path) -> tuple[np.ndarray, float]:
    """Times (T,) in seconds from the first frame and the rate of Live Link Face timecodes."""
    try:
        parsed = [parse_timecode(c) for c in codes]
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    secs = np.array([p[0] for p in parsed], np.float64)
    frames = np.array([p[1] for p in parsed], np.float64)
    try:
        rate = timecode_rate(secs, frames)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    secs = np.where(secs < secs[0] - 43200, secs + 86400, secs)  # a take recorded across midnight
    t = (secs - secs[0]) + (frames - frames[0]) / rate
    return t, recorded_rate(t, rate)


def recorded_rate(t: np.ndarray, base: float) -> float:
    """The rate rows were recorded at on a timecode counting `base` frames a second: the median row spacing
    snapped to a whole number of timecode frames (Live Link Face writes 30 Hz takes on a 60-count timecode:
    its frame field steps by 2, and the take stays 30 fps, one frame per row)."""
    if len(t) < 3:
        return base
    k = float(np.median(np.diff(t))) * base
    step = round(k)
    # (up to 8 timecode frames a row: 30, 20, 15, ... on a 60 count; sparser rows are gaps, timed as they are)
    return base / step if 1 <= step <= MAX_STEP and abs(k - step) < 0.25 else base


def format_timecode(t: float, rate: float) -> str:
    """``HH:MM:SS:FF.sss`` of a time of day in seconds at `rate`."""
    whole = int(math.floor(t))
    f = round((t - whole) * rate, 6)  # k / rate read back as frame k, not k - 1 + 0.999999
    if f >= rate:
        whole, f = whole + 1, f - rate
    ff = int(math.floor(f))
    frac = min(max(f - ff, 0.0), 0.999)
    h, rem = divmod(whole % 86400, 3600)
    return f"{h:02d}:{rem // 60:02d}:{rem % 60:02d}:{ff:02d}.{int(round(frac * 1000)):03d}"


# ------------------------------------------------------------------------------------------ checks


def _checked_times(times: np.ndarray, path: str | Path) -> np.ndarray:
    t = np.asarray(times, np.float64)
    if not np.isfinite(t).all():
        raise AvatarFileError(path, "frame times have NaN/Inf values")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise AvatarFileError(path, f"frame times must increase (frame {int(bad[0]) + 1} is not after "
                              f"frame {int(bad[0])})")
    if len(t) and t[-1] - t[0] > 86400:
        raise AvatarFileError(path, f"take lasts {t[-1] - t[0]:.0f} s, more than a day")
    return t


def _checked_weights(w: np.ndarray, path: str | Path) -> np.ndarray:
    if not np.isfinite(w).all():
        r, c = np.argwhere(~np.isfinite(w))[0]
        raise AvatarFileError(path, f"weight {int(c)} of frame {int(r)} is NaN/Inf")
    if np.abs(w).max(initial=0.0) > 1e3:
        raise AvatarFileError(path, f"weights reach {float(np.abs(w).max()):.3g}; blendshape weights are ~[0, 1]")
    return w.astype(np.float32)


def _angles(cols: dict[str, np.ndarray], names: tuple[str, ...], path: Path) -> np.ndarray | None:
    if not all(n in cols for n in names):
        return None
    a = np.stack([cols[n] for n in names], axis=1)
    if np.abs(a).max(initial=0.0) > MAX_ANGLE:
        raise AvatarFileError(path, f"angles reach {float(np.abs(a).max()):.3g} radians (at most {MAX_ANGLE:g})")
    return None if not np.any(a) else a


# ------------------------------------------------------------------------------------------ CSV


def read_livelink_csv(path: str | Path) -> Take:
    """A Live Link Face CSV take (columns by name)."""
    path = Path(path)
    text = _text(read_bytes(path, MAX_TAKE_BYTES, "a take file"), path)
    rows = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(rows)]
    except StopIteration:
        raise AvatarFileError(path, "file is empty") from None
    except csv.Error as e:
        raise AvatarFileError(path, f"not a CSV file ({e})") from None
    low = [h.lower() for h in header]
    if "timecode" not in low:
        raise AvatarFileError(path, f"has no Timecode column (columns: {', '.join(header[:6])}...)")
    if len(header) > MAX_COLUMNS or len(set(low)) != len(low):
        raise AvatarFileError(path, f"has {len(header)} columns with repeated or too many names")
    tc = low.index("timecode")
    value_cols = [i for i, h in enumerate(low) if h not in ("timecode", "blendshapecount")]
    codes: list[str] = []
    values: list[np.ndarray] = []
    try:
        for r, row in enumerate(rows, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise AvatarFileError(path, f"line {r} has {len(row)} fields, the header {len(header)}")
            if len(values) >= MAX_FRAMES:
                raise AvatarFileError(path, f"has more than {MAX_FRAMES} frames")
            codes.append(row[tc])
            try:
                values.append(np.array([float(row[i]) for i in value_cols], np.float64))
            except ValueError:
                raise AvatarFileError(path, f"line {r} has a value that is not a number") from None
    except csv.Error as e:
        raise AvatarFileError(path, f"not a CSV file ({e})") from None
    if not values:
        raise AvatarFileError(path, "has no frames")
    table = np.stack(values).reshape(len(values), len(value_cols))
    if not np.isfinite(table).all():
        r, c = np.argwhere(~np.isfinite(table))[0]
        raise AvatarFileError(path, f"column {header[value_cols[c]]} of frame {int(r)} is NaN/Inf")
    times, rate = timecode_seconds(codes, path)
    cols = {header[i]: table[:, k] for k, i in enumerate(value_cols)}
    angle_keys = {n.lower() for n in ANGLE_NAMES}
    shape_names = tuple(n for n in cols if n.lower() not in angle_keys)
    by_low = {n.lower(): n for n in cols}
    picked = {n: cols[by_low[n.lower()]] for n in ANGLE_NAMES if n.lower() in by_low}
    if not shape_names:
        raise AvatarFileError(path, "has no blendshape columns")
    w = np.stack([cols[n] for n in shape_names], axis=1)
    return Take(_checked_weights(w, path), shape_names, _checked_times(times, path), rate,
                _angles(picked, ANGLE_NAMES[:3], path), _angles(picked, ANGLE_NAMES[3:], path), path.stem)


def write_livelink_csv(path: str | Path, take: Take, start: float = 0.0) -> None:
    """Write a take in Live Link Face's CSV layout (atomically); times are offset by `start` seconds of day."""
    names = list(take.names)
    angles = np.zeros((len(take.weights), 9))
    if take.head is not None:
        angles[:, :3] = take.head
    if take.eyes is not None:
        angles[:, 3:] = take.eyes
    out = io.StringIO()
    out.write(",".join(["Timecode", "BlendShapeCount", *names, *ANGLE_NAMES]) + "\n")
    for t, w, a in zip(take.times, take.weights, angles, strict=True):
        vals = ",".join(repr(float(v)) for v in (*w, *a))
        out.write(f"{format_timecode(start + float(t), take.fps)},{len(names) + 9},{vals}\n")
    data = out.getvalue().encode("utf-8")
    atomic_write(Path(path), lambda fh: fh.write(data))


def _text(data: bytes, path: Path) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise AvatarFileError(path, f"not UTF-8 text ({e.reason} at byte {e.start})") from None


# ------------------------------------------------------------------------------------------ JSON


# The layouts, declared (unknown fields are ignored; what a file names is checked against these before use).
_Weight = Annotated[float, Meta(ge=-1e6, le=1e6)]  # a weight, a time or a timestamp in ms
_Fps = Annotated[float, Meta(ge=1e-3, le=1000.0)]
_Row = list[_Weight]


class _Metadata(msgspec.Struct):
    fps: _Fps | None = None


class _Rates(msgspec.Struct):
    """The frame rate a JSON take states: LAM's metadata.fps, Audio2Face's exportFps or a plain fps."""

    metadata: _Metadata | None = None
    exportFps: _Fps | None = None
    fps: _Fps | None = None


class _LamFrame(msgspec.Struct):
    weights: _Row
    time: _Weight | None = None


class _Lam(msgspec.Struct):
    """LAM Audio2Expression: ``{"names", "metadata": {"fps"}, "frames": [{"weights", "time"}]}``."""

    names: list[Name]
    frames: list[_LamFrame]
    head_pose: Any = None


class _Audio2Face(msgspec.Struct):
    """NVIDIA Audio2Face's blendshape export: one row of weights per frame at ``exportFps``."""

    facsNames: list[Name]
    weightMat: list[_Row]


class _Table(msgspec.Struct):
    """``{"names": [...], "values": [[...]]}``."""

    names: list[Name]
    values: list[_Row]


class _Keyed(msgspec.Struct):
    """One frame of ``[{"time": t, "blendshapes": {name: value}}]``."""

    blendshapes: dict[Name, _Weight]
    time: _Weight | None = None


class _Category(msgspec.Struct):
    """One MediaPipe blendshape category (Python's or JavaScript's spelling)."""

    score: _Weight
    categoryName: Name | None = None
    category_name: Name | None = None


class _Face(msgspec.Struct):
    categories: list[_Category]


class _Result(msgspec.Struct):
    """A MediaPipe FaceLandmarkerResult (or a frame holding one face's categories), with its time."""

    timestampMs: _Weight | None = None
    timestamp_ms: _Weight | None = None
    time: _Weight | None = None
    timestamp: _Weight | None = None
    faceBlendshapes: list[_Face | list[_Category]] | None = None
    face_blendshapes: list[_Face | list[_Category]] | None = None
    categories: list[_Category] | None = None


#: (names, weights (T, B), times or None, fps, what of the file is ignored)
_Layout = tuple[list[str], np.ndarray, np.ndarray | None, float, str]
_NO_TAKE = ("is no ARKit take (expected LAM's names/frames, Audio2Face's facsNames/weightMat, names/values, "
            "MediaPipe category lists, [{time, blendshapes}] or {name: [values]})")


def _rows(rows: list[list[float]], width: int, path: Path, key: str) -> np.ndarray:
    """(T, width) of decoded rows, each of `width` numbers (`key` names row i with a `{}`)."""
    for i, r in enumerate(rows):
        if len(r) != width:
            raise AvatarFileError(path, f"{key.format(i)}: expected {width} values (one per name), got {len(r)}")
    return np.array(rows, np.float64).reshape(len(rows), width)


def _times(times: list[float | None]) -> np.ndarray | None:
    """The frames' times when every frame has one."""
    return np.array(times, np.float64) if times and None not in times else None


def _lam_layout(data: dict, path: Path, fps: float) -> _Layout:
    lam = decode_file(data, _Lam, path)
    w = _rows([f.weights for f in lam.frames], len(lam.names), path, "frames[{}].weights")
    ignored = LAM_HEAD_POSE_IGNORED if "head_pose" in data else ""
    return list(lam.names), w, _times([f.time for f in lam.frames]), fps, ignored


def _keyed_frames(frames: list, path: Path, fps: float, where: str) -> _Layout:
    """``[{"time": t, "blendshapes": {name: value}}]``: one object per frame, weights by name."""
    keyed = decode_file(frames, list[_Keyed], path, where)
    names = list(keyed[0].blendshapes)
    for i, f in enumerate(keyed):
        if set(f.blendshapes) != set(names):
            raise AvatarFileError(path, f"{where}[{i}].blendshapes must name the same {len(names)} blendshapes as "
                                  "frame 0")
    w = np.array([[f.blendshapes[n] for n in names] for f in keyed], np.float64).reshape(len(keyed), len(names))
    return names, w, _times([f.time for f in keyed]), fps, ""


def _category_frame(frame: list[_Category] | _Result, path: Path, where: str) -> tuple[dict[str, float],
                                                                                      float | None]:
    """({name: score}, time in seconds or None) of one MediaPipe frame."""
    stamp, cats = None, frame
    if isinstance(frame, _Result):
        ms = frame.timestampMs if frame.timestampMs is not None else frame.timestamp_ms
        s = frame.time if frame.time is not None else frame.timestamp
        stamp = ms * 1e-3 if ms is not None else s
        faces = frame.faceBlendshapes if frame.faceBlendshapes is not None else frame.face_blendshapes
        if faces is not None and not faces:
            raise AvatarFileError(path, f"{where} has no face")
        face = frame if faces is None else faces[0]
        cats = face.categories if isinstance(face, _Face | _Result) else face
    if cats is None:
        raise AvatarFileError(path, f"{where} is no list of blendshape categories")
    out: dict[str, float] = {}
    for c in cats:
        name = c.categoryName if c.categoryName is not None else c.category_name
        if name is None:
            raise AvatarFileError(path, f"{where} has a category without a name")
        out[name] = c.score
    return out, stamp


def _category_frames(frames: Any, path: Path, fps: float, where: str | None) -> _Layout:
    """MediaPipe face-landmarker results: per frame a list of categories (or a result object holding them);
    `where` None: one result alone (`frames` is the file's object)."""
    if where is None:
        parsed = [_category_frame(decode_file(frames, _Result, path), path, "the result")]
    else:
        results = decode_file(frames, list[list[_Category] | _Result], path, where)
        parsed = [_category_frame(f, path, f"{where}[{i}]") for i, f in enumerate(results)]
    names = list(dict.fromkeys(n for d, _ in parsed for n in d))
    if parsed and any(set(d) != set(names) for d, _ in parsed):
        raise AvatarFileError(path, "frames name different blendshape categories")
    w = np.array([[d[n] for n in names] for d, _ in parsed], np.float64).reshape(len(parsed), len(names))
    return names, w, _times([st for _, st in parsed]), fps, ""


def _series(data: dict, path: Path, fps: float) -> _Layout:
    """A plain ``{name: [values], "fps": rate}``."""
    try:
        series = decode({k: v for k, v in data.items() if k not in ("fps", "metadata")}, dict[str, list[Any]])
    except SchemaError:
        raise AvatarFileError(path, _NO_TAKE) from None
    lengths = {len(v) for v in series.values()}
    if len(lengths) > 1:
        raise AvatarFileError(path, f"blendshape series have different lengths {sorted(lengths)[:4]}")
    if not series:
        raise AvatarFileError(path, _NO_TAKE)
    names = list(series)
    w = np.array([decode_file(series[n], _Row, path, shown(n)[:60]) for n in names], np.float64).T
    return names, w.reshape(lengths.pop(), len(names)), None, fps, ""


def _frames(frames: list, path: Path, fps: float, where: str) -> _Layout:
    """A list of frames: keyed by name, or MediaPipe categories."""
    if frames and isinstance(frames[0], dict) and "blendshapes" in frames[0]:
        return _keyed_frames(frames, path, fps, where)
    return _category_frames(frames, path, fps, where)


def _json_take(data: Any, path: Path) -> _Layout:
    """(names, weights (T, B), times or None, fps, ignored) of any of the JSON layouts (the module docstring):
    which one by the keys a file has, then decoded by the layout's schema."""
    if isinstance(data, list):
        return _frames(data, path, JSON_FPS, "")
    if not isinstance(data, dict):
        raise AvatarFileError(path, f"is no ARKit take (top level is {type(data).__name__})")
    rates = decode_file(data, _Rates, path)
    meta = None if rates.metadata is None else rates.metadata.fps
    fps = next((f for f in (meta, rates.exportFps, rates.fps) if f is not None), JSON_FPS)
    if "names" in data and "frames" in data:  # LAM Audio2Expression
        return _lam_layout(data, path, fps)
    if "facsNames" in data and "weightMat" in data:  # NVIDIA Audio2Face's blendshape export
        a2f = decode_file(data, _Audio2Face, path)
        return list(a2f.facsNames), _rows(a2f.weightMat, len(a2f.facsNames), path, "weightMat[{}]"), None, fps, ""
    if "names" in data and "values" in data:  # names and a (T, B) table
        table = decode_file(data, _Table, path)
        return list(table.names), _rows(table.values, len(table.names), path, "values[{}]"), None, fps, ""
    if "faceBlendshapes" in data or "face_blendshapes" in data:  # one MediaPipe FaceLandmarkerResult
        return _category_frames(data, path, fps, None)
    if isinstance(data.get("frames"), list):
        return _frames(data["frames"], path, fps, "frames")
    return _series(data, path, fps)


def read_arkit_json(path: str | Path) -> Take:
    """An ARKit JSON take in any of the layouts above."""
    path = Path(path)
    data = parse_json(read_bytes(path, MAX_TAKE_BYTES, "a take file"), path)
    names, w, t, fps, ignored = _json_take(data, path)
    if len(w) == 0 or not names:
        raise AvatarFileError(path, "has no frames")
    if len(w) > MAX_FRAMES or len(names) > MAX_COLUMNS:
        raise AvatarFileError(path, f"has {len(w)} frames of {len(names)} shapes, more than allowed")
    if len(set(names)) != len(names):
        raise AvatarFileError(path, "repeats a blendshape name")
    times = np.arange(len(w), dtype=np.float64) / fps if t is None else t - t[0]
    return Take(_checked_weights(w, path), tuple(names), _checked_times(times, path), fps, name=path.stem,
                ignored=ignored)


def read_take(path: str | Path) -> Take:
    """A take by its suffix: ``.csv`` Live Link Face, ``.json`` ARKit JSON."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_livelink_csv(path)
    if path.suffix.lower() == ".json":
        return read_arkit_json(path)
    raise AvatarFileError(path, f"is no ARKit take ({', '.join(TAKE_SUFFIXES)})")


# ------------------------------------------------------------------------------------------ to a sequence


def resample(times: np.ndarray, values: np.ndarray, fps: float) -> np.ndarray:
    """`values` (T, K) at `times` linearly resampled to a uniform grid at `fps` from the first time; a take with
    exactly one row per frame of that grid (nothing dropped) is returned as it is."""
    n = int(math.floor((times[-1] - times[0]) * fps + 0.5)) + 1
    grid = times[0] + np.arange(n, dtype=np.float64) / fps
    if n == len(times):  # one row per frame slot (sub-frame jitter only): the rows as they are
        return np.asarray(values, np.float64)
    v = np.asarray(values, np.float64)
    return np.stack([np.interp(grid, times, v[:, k]) for k in range(v.shape[1])], axis=1).reshape(n, v.shape[1])


def grid_frames(take: Take, rate: float, width: int, path: str | Path) -> int:
    """The frames `resample` fills for a take at `rate`, within the frame and value bounds every take has."""
    n = int(math.floor((take.times[-1] - take.times[0]) * rate + 0.5)) + 1
    if n > MAX_FRAMES or n * max(width, 1) > MAX_RESAMPLED_VALUES:
        raise AvatarFileError(path, f"its times span {n} frames at {rate:g} fps ({len(take.times)} rows recorded), "
                              f"more than the {MAX_FRAMES} frames or {MAX_RESAMPLED_VALUES} values a take may fill")
    return n


def resampled(take: Take, cols: list[int], path: str | Path, fps: float | None = None) -> np.ndarray:
    """Columns `cols` of a take's weights on its frame grid (at `fps` or its own rate), within `grid_frames`'s
    bounds."""
    rate = take.fps if fps is None else float(fps)
    grid_frames(take, rate, len(cols), path)
    return resample(take.times, take.weights[:, cols], rate)


def head_pose(angles: np.ndarray) -> np.ndarray:
    """Canonical -> world 4x4 (T, 4, 4) of (yaw, pitch, roll) radians: x_world = Ry(yaw) Rx(pitch) Rz(roll) x."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(angles, np.float64)
    pose = np.tile(np.eye(4), (len(a), 1, 1))
    pose[:, :3, :3] = Rotation.from_euler("YXZ", a[:, [0, 1, 2]]).as_matrix()
    return pose


def take_sequence(take: Take, basis: BlendshapeBasis, path: str | Path,
                  fps: float | None = None) -> tuple[ExpressionSequence, str]:
    """The take as codes through `basis` at its own rate (one frame per row where none was dropped; gaps
    interpolated) or resampled to `fps`, and the one-line report of unmatched names; the sequence's `notes`
    say what was matched, missing or interpolated."""
    try:
        match = match_names(take.names, basis.names)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    rate = take.fps if fps is None else float(fps)
    if not (math.isfinite(rate) and 0.01 <= rate <= 1000):
        raise AvatarFileError(path, f"--fps {rate:g} is outside 0.01..1000")
    n = grid_frames(take, rate, len(take.names), path)
    w = resample(take.times, match.apply(take.weights), rate)
    seq = ExpressionSequence(basis.codes(w), rate, take.name or Path(path).stem)
    if take.head is not None:
        seq.pose = head_pose(resample(take.times, take.head, rate))
        seq.pose_source = HEAD_POSE
    if take.ignored:
        seq.notes.append(f"{shown(path)}: {take.ignored}")
    report = match.report()
    if report:  # (names from the file: escaped, never a raw bidi control, newline or lone surrogate)
        seq.notes.append(shown(f"{path}: {report}"))
    if fps is None and n > len(take.times):
        seq.notes.append(f"{shown(path)}: {n - len(take.times)} of {n} frames at {rate:g} fps were not recorded "
                         "(interpolated from their neighbours)")
    elif fps is not None and abs(rate - take.fps) > 1e-9:
        seq.notes.append(f"{shown(path)}: resampled from {take.fps:g} to {rate:g} fps")
    return seq, report


def default_basis() -> BlendshapeBasis:
    """The basis a take is read with when none is given: the bundled demo's."""
    from npga_core.files.basis_file import bundled_demo_basis

    return bundled_demo_basis()


def read_take_sequence(path: str | Path, basis: BlendshapeBasis | None = None,
                       fps: float | None = None) -> ExpressionSequence:
    """`read_take` then `take_sequence` (the demo's basis when none is given); what did not match and what was
    interpolated are one-line `notes` of the sequence (shown once by the CLI and the window)."""
    return take_sequence(read_take(path), basis or default_basis(), path, fps)[0]
