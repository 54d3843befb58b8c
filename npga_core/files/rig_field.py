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

from typing import Any

import numpy as np

from npga_core.model.linear_rig import CARRIERS, RESERVED_CARRIERS, LinearRig
from npga_core.model.skinning import SKIN_ARRAYS, Skin

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


def check_section(entry: Any, n: int, version: int = RIG_VERSION) -> None:
    """ValueError unless `entry` (the header's ``rig``, not null) is well formed for `n` Gaussians in a file of
    format `version`."""
    if not isinstance(entry, dict):
        raise ValueError("rig must be an object or null")
    names = entry.get("channels")
    if not isinstance(names, list) or not 1 <= len(names) <= MAX_CHANNELS:
        raise ValueError(f"rig.channels must be a list of 1..{MAX_CHANNELS} names")
    if not all(isinstance(c, str) and 0 < len(c) <= MAX_NAME for c in names) or len(set(names)) != len(names):
        raise ValueError(f"rig.channels must be distinct non-empty strings of at most {MAX_NAME} characters")
    carrier = entry.get("carrier", "gaussian")
    if carrier == "triangle" and version < SKIN_VERSION:
        raise ValueError(f"rig.carrier 'triangle' needs format version {SKIN_VERSION}")
    points = _check_skin(entry, n) if carrier == "triangle" else n
    support = entry.get("support")
    if isinstance(support, bool) or not isinstance(support, int) or not 0 <= support <= points:
        raise ValueError(f"rig.support must be an integer in 0..{points} (the points some channel moves)")
    if carrier in RESERVED_CARRIERS:
        raise ValueError(f"rig.carrier {carrier!r} (Gaussians bound to a skinned mesh's triangles) is specified "
                         "but not supported by this version of npga-view")
    if carrier not in CARRIERS:
        raise ValueError(f"rig.carrier must be one of {', '.join(CARRIERS)}, got {carrier!r}")
    for key in ("vertices", "turns_covariance"):
        if not isinstance(entry.get(key, False), bool):
            raise ValueError(f"rig.{key} must be true or false")
    if (entry.get("vertices", False) and carrier == "gaussian") or (carrier == "triangle"
                                                                    and not entry.get("vertices", False)):
        raise ValueError("rig.vertices are stored for carrier 'vertex' (optionally) and 'triangle' (always)")
    if not isinstance(entry.get("source", ""), str) or len(entry.get("source", "")) > MAX_TEXT:
        raise ValueError(f"rig.source must be a string of at most {MAX_TEXT} characters")
    notes = entry.get("notes", {})
    if not isinstance(notes, dict) or len(notes) > MAX_NOTES or not all(
            isinstance(k, str) and isinstance(v, str) and len(k) <= MAX_NAME and len(v) <= MAX_TEXT
            for k, v in notes.items()):
        raise ValueError(f"rig.notes must map at most {MAX_NOTES} short names to strings")


def _check_skin(entry: dict, n: int) -> int:
    """The mesh's vertex count V of a triangle rig's entry, after its checks."""
    points, skin = entry.get("points"), entry.get("skin")
    if isinstance(points, bool) or not isinstance(points, int) or not 3 <= points <= MAX_POINTS:
        raise ValueError(f"rig.points must be an integer in 3..{MAX_POINTS} (the skinned mesh's vertices)")
    if not isinstance(skin, dict) or set(skin) != {"joints", "faces"}:
        raise ValueError("rig.skin must be an object with joints and faces")
    joints, faces = skin["joints"], skin["faces"]
    if not isinstance(joints, list) or not 1 <= len(joints) <= MAX_JOINTS or len(set(map(str, joints))) != len(
            joints) or not all(isinstance(j, str) and 0 < len(j) <= MAX_NAME for j in joints):
        raise ValueError(f"rig.skin.joints must be 1..{MAX_JOINTS} distinct short names")
    if isinstance(faces, bool) or not isinstance(faces, int) or not 1 <= faces <= MAX_FACES:
        raise ValueError(f"rig.skin.faces must be an integer in 1..{MAX_FACES}")
    return points


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
    version = header.get("format_version", 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < RIG_VERSION:
        return None
    entry = header.get(HEADER_KEY)
    return entry if entry not in (None, {}) else None
