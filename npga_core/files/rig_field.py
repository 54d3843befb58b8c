"""The optional `rig` field of an `.npga` (format version 4, docs/FORMAT.md section 17): a `LinearRig`; with
carrier "triangle" (version 5, section 19) its `Skin`: header ``"points": V, "skin": {"joints": [J names],
"faces": F}`` and tensors ``rig.skin.joints`` (J, 3), ``joint_deltas`` (K, J, 3), ``parents`` (J,) int32,
``weights`` (V, J), ``posedirs`` (9 (J - 1), V, 3), ``faces`` (F, 3) int32, ``binding`` (N,) int32, with
``rig.vertices`` (V, 3) the rest mesh.

Header key ``"rig": {"channels": [K names], "support": S, "carrier": "gaussian"|"vertex", "vertices": bool,
"turns_covariance": bool, "source": str, "notes": {str: str}}`` and tensors ``rig.support`` (S,) int32
ascending rows, ``rig.deltas`` (K, S, 3), ``rig.scale`` (K,), ``rig.bias`` (K,), ``rig.transform`` (4, 4) and,
with ``"vertices": true``, ``rig.vertices`` (N, 3), all float32. The reader checks the entry before anything is
allocated, then the values (finite, support in range and ascending, deltas within +-MAX_POSITION). Kept apart
from `checkpoint.py`, which calls these functions.
"""

from __future__ import annotations

from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.errors import brief
from npga_core.model.linear_rig import CARRIERS, RESERVED_CARRIERS, LinearRig
from npga_core.model.skinning import SKIN_ARRAYS, Skin
from npga_core.schema import decode

#: The oldest format version that holds a rig, and one on a skinned mesh (carrier "triangle").
RIG_VERSION = 4
SKIN_VERSION = 5
MAX_POINTS = 2_000_000
MAX_JOINTS = 64
MAX_FACES = 4_000_000
HEADER_KEY = "rig"
MAX_CHANNELS = 1024
MAX_NAME = 128
MAX_TEXT = 4096
MAX_NOTES = 32


_Name = Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]
_Text = Annotated[str, Meta(max_length=MAX_TEXT)]


class _Skin(msgspec.Struct, forbid_unknown_fields=True):
    joints: Annotated[list[_Name], Meta(min_length=1, max_length=MAX_JOINTS)]
    faces: Annotated[int, Meta(ge=1, le=MAX_FACES)]


class Section(msgspec.Struct):
    """The header's ``rig`` entry, declared (`check_section` checks what depends on the file)."""

    channels: Annotated[list[_Name], Meta(min_length=1, max_length=MAX_CHANNELS)]
    support: Annotated[int, Meta(ge=0, le=2**31 - 1)]
    carrier: _Text = "gaussian"
    vertices: bool = False
    turns_covariance: bool = False
    source: _Text = ""
    notes: Annotated[dict[Annotated[str, Meta(max_length=MAX_NAME)], _Text], Meta(max_length=MAX_NOTES)] = {}
    points: Annotated[int, Meta(ge=3, le=MAX_POINTS)] | None = None  # carrier "triangle": the mesh's vertices
    skin: _Skin | None = None  # carrier "triangle"


def check_section(entry: Any, n: int, version: int = RIG_VERSION) -> None:
    """ValueError (naming the field) unless `entry` (the header's ``rig``, not null) is well formed for `n`
    Gaussians in a file of format `version`."""
    s = decode(entry, Section, "rig")
    if len(set(s.channels)) != len(s.channels):
        raise ValueError("rig.channels must be distinct names (one repeats)")
    if s.carrier == "triangle" and version < SKIN_VERSION:
        raise ValueError(f"rig.carrier 'triangle' needs format version {SKIN_VERSION}")
    points = n
    if s.carrier == "triangle":
        if s.points is None or s.skin is None:
            raise ValueError("rig.points and rig.skin are needed for carrier 'triangle' (the skinned mesh)")
        if len(set(s.skin.joints)) != len(s.skin.joints):
            raise ValueError("rig.skin.joints must be distinct names (one repeats)")
        points = s.points
    if s.support > points:
        raise ValueError(f"rig.support must be an integer in 0..{points} (the points some channel moves)")
    if s.carrier in RESERVED_CARRIERS:
        raise ValueError(f"rig.carrier {s.carrier!r} (Gaussians bound to a skinned mesh's triangles) is specified "
                         "but not supported by this version of npga-view")
    if s.carrier not in CARRIERS:
        raise ValueError(f"rig.carrier must be one of {', '.join(CARRIERS)}, got {brief(s.carrier)}")
    if (s.vertices and s.carrier == "gaussian") or (s.carrier == "triangle" and not s.vertices):
        raise ValueError("rig.vertices are stored for carrier 'vertex' (optionally) and 'triangle' (always)")


def tensors(entry: dict, n: int) -> dict[str, tuple[str, tuple[int, ...]]]:
    """The tensors a checked ``rig`` entry implies (name -> (dtype, shape))."""
    k, s = len(entry["channels"]), entry["support"]
    skin = entry.get("skin") if entry.get("carrier") == "triangle" else None
    out: dict[str, tuple[str, tuple[int, ...]]] = {
        "rig.support": ("int32", (s,)), "rig.deltas": ("float32", (k, s, 3)), "rig.scale": ("float32", (k,)),
        "rig.bias": ("float32", (k,)), "rig.transform": ("float32", (4, 4))}
    if entry.get("vertices", False):
        out["rig.vertices"] = ("float32", (n if skin is None else entry["points"], 3))
    if skin is not None:
        v, j, f = entry["points"], len(skin["joints"]), skin["faces"]
        out.update({"rig.skin.joints": ("float32", (j, 3)), "rig.skin.joint_deltas": ("float32", (k, j, 3)),
                    "rig.skin.parents": ("int32", (j,)), "rig.skin.weights": ("float32", (v, j)),
                    "rig.skin.posedirs": ("float32", (9 * (j - 1), v, 3)), "rig.skin.faces": ("int32", (f, 3)),
                    "rig.skin.binding": ("int32", (n,))})
    return out


def section(rig: LinearRig) -> tuple[dict, dict[str, np.ndarray]]:
    """The header entry and the arrays of `rig`."""
    entry = {"channels": list(rig.channels), "support": int(len(rig.support)), "carrier": rig.carrier,
             "vertices": rig.vertices is not None, "turns_covariance": bool(rig.turns_covariance),
             "source": rig.source, "notes": dict(rig.notes)}
    arrays: dict[str, np.ndarray] = {"rig.support": rig.support.astype(np.int32), "rig.deltas": rig.deltas,
              "rig.scale": rig.scale, "rig.bias": rig.bias,
              "rig.transform": np.asarray(rig.transform, np.float32)}
    if rig.vertices is not None:
        arrays["rig.vertices"] = rig.vertices
    if rig.skin is not None:
        entry["points"] = int(rig.n_points)
        entry["skin"] = {"joints": list(rig.skin.joint_names), "faces": int(len(rig.skin.faces))}
        for name in SKIN_ARRAYS:
            a = getattr(rig.skin, name)
            arrays[f"rig.skin.{name}"] = a.astype(np.int32 if a.dtype.kind == "i" else np.float32)
    return entry, arrays


def build(entry: dict, t: dict[str, np.ndarray], n: int, limit: float) -> LinearRig:
    """The rig of a checked entry from its tensors; ValueError if a value is out of bounds."""
    support = np.asarray(t["rig.support"], np.int64)
    skin_entry = entry.get("skin") if entry.get("carrier") == "triangle" else None
    points = n if skin_entry is None else entry["points"]
    if support.size and (support[0] < 0 or support[-1] >= points or np.any(np.diff(support) <= 0)):
        raise ValueError(f"rig.support must be ascending distinct rows within 0..{points - 1}")
    for key in ("rig.deltas", "rig.scale", "rig.bias", "rig.transform", "rig.vertices", "rig.skin.joints",
                "rig.skin.joint_deltas", "rig.skin.weights", "rig.skin.posedirs"):
        a = t.get(key)
        if a is not None and a.size and np.abs(a).max() > limit:
            raise ValueError(f"{key} has values beyond +-{limit:g}")
    m = np.array(t["rig.transform"], np.float64)
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise ValueError("rig.transform is not affine (its last row must be 0, 0, 0, 1)")
    m[3] = [0.0, 0.0, 0.0, 1.0]
    skin = None if skin_entry is None else Skin(tuple(skin_entry["joints"]),
                                                *(np.array(t[f"rig.skin.{k}"]) for k in SKIN_ARRAYS))
    return LinearRig(tuple(entry["channels"]), support, np.array(t["rig.deltas"]), points,
                     scale=np.array(t["rig.scale"]), bias=np.array(t["rig.bias"]),
                     carrier=entry.get("carrier", "gaussian"),
                     vertices=None if "rig.vertices" not in t else np.array(t["rig.vertices"]), transform=m,
                     turns_covariance=bool(entry.get("turns_covariance", False)),
                     source=entry.get("source", ""), notes=dict(entry.get("notes", {})), skin=skin)


def header_entry(header: dict) -> Any:
    """The header's ``rig`` entry; None when absent, null or empty, or in a file older than version 4."""
    if header.get("format_version", 1) < RIG_VERSION:  # (an integer: checked before)
        return None
    entry = header.get(HEADER_KEY)
    return entry if entry not in (None, {}) else None
