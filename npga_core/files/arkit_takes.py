"""ARKit face-capture takes: Live Link Face CSV and ARKit-style JSON, read into weights and turned into codes.

- Live Link Face CSV (Epic's iPhone app): a header ``Timecode,BlendShapeCount,<52 shapes>,HeadYaw,...,
  RightEyeRoll`` (PascalCase; the app's column order is not its UDP packet order, so columns are read by
  name) and one row per frame; ``Timecode`` is ``HH:MM:SS:FF.sss`` (frame FF at the timecode's rate, .sss a
  fraction of a frame). The timecode's rate is the smallest common rate above every FF seen (`timecode_rate`);
  the take's own is its median row spacing snapped to whole timecode frames (`recorded_rate`: 30 on a 60 count). Head
  angles (radians) give the head pose; eye angles are kept; angle columns all zero mean "not recorded".
- JSON (declared and decoded in `npga_core.files.arkit_json`): LAM Audio2Expression's ``{"names", "metadata":
  {"fps"}, "frames": [{"weights", "time"}]}`` (a ``head_pose`` beside them, as in LAM_WebRender's example, is
  ignored and said so: `LAM_HEAD_POSE_IGNORED`);
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
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError, shown
from npga_core.files.arkit_json import JSON_FPS, LAM_HEAD_POSE_IGNORED, json_take  # noqa: F401  (their home)
from npga_core.files.atomic import atomic_write
from npga_core.files.blendshape_names import ANGLE_NAMES, match_names
from npga_core.files.sequences import ExpressionSequence
from npga_core.files.untrusted import parse_json, read_bytes
from npga_core.model.blendshapes import BlendshapeBasis

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
#: Most timecode frames between a take's rows that still count as its recording rate (`recorded_rate`).
MAX_STEP = 8
TAKE_SUFFIXES = (".csv", ".json")
HEAD_POSE = "ARKit head angles (radians): x_world = Ry(yaw) Rx(pitch) Rz(roll) x"
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


def _csv_header(rows: Iterator[list[str]], path: Path) -> tuple[list[str], int, list[int]]:
    """(the column names, the Timecode column, the value columns) of a Live Link Face CSV's first row."""
    try:
        header = [h.strip() for h in next(rows)]
    except StopIteration:
        raise AvatarFileError(path, "file is empty") from None
    low = [h.lower() for h in header]
    if "timecode" not in low:
        raise AvatarFileError(path, f"has no Timecode column (columns: {', '.join(header[:6])}...)")
    if len(header) > MAX_COLUMNS or len(set(low)) != len(low):
        raise AvatarFileError(path, f"has {len(header)} columns with repeated or too many names")
    return header, low.index("timecode"), [i for i, h in enumerate(low) if h not in ("timecode", "blendshapecount")]


def _csv_rows(rows: Iterator[list[str]], width: int, tc: int, value_cols: list[int],
              path: Path) -> tuple[list[str], np.ndarray]:
    """(the timecodes, the values (T, columns)) of a Live Link Face CSV's rows (blank rows skipped)."""
    codes: list[str] = []
    values: list[np.ndarray] = []
    for r, row in enumerate(rows, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != width:
            raise AvatarFileError(path, f"line {r} has {len(row)} fields, the header {width}")
        if len(values) >= MAX_FRAMES:
            raise AvatarFileError(path, f"has more than {MAX_FRAMES} frames")
        codes.append(row[tc])
        try:
            values.append(np.array([float(row[i]) for i in value_cols], np.float64))
        except ValueError:
            raise AvatarFileError(path, f"line {r} has a value that is not a number") from None
    if not values:
        raise AvatarFileError(path, "has no frames")
    return codes, np.stack(values).reshape(len(values), len(value_cols))


def read_livelink_csv(path: str | Path) -> Take:
    """A Live Link Face CSV take (columns by name)."""
    path = Path(path)
    rows = csv.reader(io.StringIO(_text(read_bytes(path, MAX_TAKE_BYTES, "a take file"), path)))
    try:
        header, tc, value_cols = _csv_header(rows, path)
        codes, table = _csv_rows(rows, len(header), tc, value_cols, path)
    except csv.Error as e:
        raise AvatarFileError(path, f"not a CSV file ({e})") from None
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


def read_arkit_json(path: str | Path) -> Take:
    """An ARKit JSON take in any of the layouts above."""
    path = Path(path)
    data = parse_json(read_bytes(path, MAX_TAKE_BYTES, "a take file"), path)
    names, w, t, fps, ignored = json_take(data, path)
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
