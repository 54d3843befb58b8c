"""The JSON layouts of an ARKit take, declared (msgspec Structs) and decoded: LAM Audio2Expression, NVIDIA
Audio2Face's blendshape export, names/values tables, MediaPipe face-landmarker results, keyed frames and plain
series (`npga_core.files.arkit_takes` reads the file and makes the take; see its docstring for the layouts and the
authors' code they follow). `json_take` picks a layout by the keys a file has and decodes it by that layout's
schema; messages name the field path (``frames[3].weights: expected 52 values (one per name), got 51``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.errors import AvatarFileError, shown
from npga_core.schema import Name, SchemaError, decode, decode_file

JSON_FPS = 30.0
#: LAM_WebRender's asset/test_expression_1s.json carries a `head_pose` (T x 3 small numbers) that no code of LAM's
#: produces or reads: LAM_Audio2Expression returns ``"headpose": None`` (engines/infer.py line 233, models/utils.py
#: line 136), LAM_WebRender's src/gaussianAvatar.ts (lines 53-66) reads only ``names`` and the frames' ``weights``
#: and its player (gaussian-splat-renderer-for-lam 0.0.8) never mentions it; aigc3d/LAM and OpenAvatarChat do
#: not either. Its axes, order and units are nowhere defined, so it is not guessed at.
LAM_HEAD_POSE_IGNORED = ("head_pose ignored: no LAM code writes or reads it (Audio2Expression returns no head pose, "
                         "the web player reads only the weights), so its axes and units are unknown")

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
Layout = tuple[list[str], np.ndarray, np.ndarray | None, float, str]
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


def _lam_layout(data: dict, path: Path, fps: float) -> Layout:
    lam = decode_file(data, _Lam, path)
    w = _rows([f.weights for f in lam.frames], len(lam.names), path, "frames[{}].weights")
    ignored = LAM_HEAD_POSE_IGNORED if "head_pose" in data else ""
    return list(lam.names), w, _times([f.time for f in lam.frames]), fps, ignored


def _keyed_frames(frames: list, path: Path, fps: float, where: str) -> Layout:
    """``[{"time": t, "blendshapes": {name: value}}]``: one object per frame, weights by name."""
    keyed = decode_file(frames, list[_Keyed], path, where)
    names = list(keyed[0].blendshapes)
    for i, f in enumerate(keyed):
        if set(f.blendshapes) != set(names):
            raise AvatarFileError(path, f"{where}[{i}].blendshapes must name the same {len(names)} blendshapes as "
                                  "frame 0")
    w = np.array([[f.blendshapes[n] for n in names] for f in keyed], np.float64).reshape(len(keyed), len(names))
    return names, w, _times([f.time for f in keyed]), fps, ""


def _scores(cats: list[_Category], path: Path, where: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for c in cats:
        name = c.categoryName if c.categoryName is not None else c.category_name
        if name is None:
            raise AvatarFileError(path, f"{where} has a category without a name")
        out[name] = c.score
    return out


def _category_frame(frame: list[_Category] | _Result, path: Path, where: str) -> tuple[dict[str, float],
                                                                                      float | None]:
    """({name: score}, time in seconds or None) of one MediaPipe frame."""
    if isinstance(frame, list):
        return _scores(frame, path, where), None
    ms = frame.timestampMs if frame.timestampMs is not None else frame.timestamp_ms
    seconds = frame.time if frame.time is not None else frame.timestamp
    stamp = ms * 1e-3 if ms is not None else seconds
    faces = frame.faceBlendshapes if frame.faceBlendshapes is not None else frame.face_blendshapes
    if faces is not None and not faces:
        raise AvatarFileError(path, f"{where} has no face")
    face = frame if faces is None else faces[0]
    cats = face if isinstance(face, list) else face.categories
    if cats is None:
        raise AvatarFileError(path, f"{where} is no list of blendshape categories")
    return _scores(cats, path, where), stamp


def _category_frames(frames: Any, path: Path, fps: float, where: str | None) -> Layout:
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


def _series(data: dict, path: Path, fps: float) -> Layout:
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


def _frames(frames: list, path: Path, fps: float, where: str) -> Layout:
    """A list of frames: keyed by name, or MediaPipe categories."""
    if frames and isinstance(frames[0], dict) and "blendshapes" in frames[0]:
        return _keyed_frames(frames, path, fps, where)
    return _category_frames(frames, path, fps, where)


def json_take(data: Any, path: Path) -> Layout:
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


