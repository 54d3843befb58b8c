"""The optional `rig` field of an `.npga` (format version 4, docs/FORMAT.md section 17): a `LinearRig`.

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

#: The oldest format version that holds a rig.
RIG_VERSION = 4
HEADER_KEY = "rig"
MAX_CHANNELS = 1024
MAX_NAME = 128
MAX_TEXT = 4096
MAX_NOTES = 32


def check_section(entry: Any, n: int) -> None:
    """ValueError unless `entry` (the header's ``rig``, not null) is well formed for `n` Gaussians."""
    if not isinstance(entry, dict):
        raise ValueError("rig must be an object or null")
    names = entry.get("channels")
    if not isinstance(names, list) or not 1 <= len(names) <= MAX_CHANNELS:
        raise ValueError(f"rig.channels must be a list of 1..{MAX_CHANNELS} names")
    if not all(isinstance(c, str) and 0 < len(c) <= MAX_NAME for c in names) or len(set(names)) != len(names):
        raise ValueError(f"rig.channels must be distinct non-empty strings of at most {MAX_NAME} characters")
    support = entry.get("support")
    if isinstance(support, bool) or not isinstance(support, int) or not 0 <= support <= n:
        raise ValueError(f"rig.support must be an integer in 0..{n} (the Gaussians some channel moves)")
    carrier = entry.get("carrier", "gaussian")
    if carrier in RESERVED_CARRIERS:
        raise ValueError(f"rig.carrier {carrier!r} (Gaussians bound to a skinned mesh's triangles) is specified "
                         "but not supported by this version of npga-view")
    if carrier not in CARRIERS:
        raise ValueError(f"rig.carrier must be one of {', '.join(CARRIERS)}, got {carrier!r}")
    for key in ("vertices", "turns_covariance"):
        if not isinstance(entry.get(key, False), bool):
            raise ValueError(f"rig.{key} must be true or false")
    if entry.get("vertices", False) and carrier != "vertex":
        raise ValueError("rig.vertices are stored only for carrier 'vertex'")
    if not isinstance(entry.get("source", ""), str) or len(entry.get("source", "")) > MAX_TEXT:
        raise ValueError(f"rig.source must be a string of at most {MAX_TEXT} characters")
    notes = entry.get("notes", {})
    if not isinstance(notes, dict) or len(notes) > MAX_NOTES or not all(
            isinstance(k, str) and isinstance(v, str) and len(k) <= MAX_NAME and len(v) <= MAX_TEXT
            for k, v in notes.items()):
        raise ValueError(f"rig.notes must map at most {MAX_NOTES} short names to strings")


def tensors(entry: dict, n: int) -> dict[str, tuple[str, tuple[int, ...]]]:
    """The tensors a checked ``rig`` entry implies (name -> (dtype, shape))."""
    k, s = len(entry["channels"]), entry["support"]
    out: dict[str, tuple[str, tuple[int, ...]]] = {
        "rig.support": ("int32", (s,)), "rig.deltas": ("float32", (k, s, 3)), "rig.scale": ("float32", (k,)),
        "rig.bias": ("float32", (k,)), "rig.transform": ("float32", (4, 4))}
    if entry.get("vertices", False):
        out["rig.vertices"] = ("float32", (n, 3))
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
    return entry, arrays


def build(entry: dict, t: dict[str, np.ndarray], n: int, limit: float) -> LinearRig:
    """The rig of a checked entry from its tensors; ValueError if a value is out of bounds."""
    support = np.asarray(t["rig.support"], np.int64)
    if support.size and (support[0] < 0 or support[-1] >= n or np.any(np.diff(support) <= 0)):
        raise ValueError(f"rig.support must be ascending distinct rows within 0..{n - 1}")
    for key in ("rig.deltas", "rig.scale", "rig.bias", "rig.transform", "rig.vertices"):
        a = t.get(key)
        if a is not None and a.size and np.abs(a).max() > limit:
            raise ValueError(f"{key} has values beyond +-{limit:g}")
    m = np.array(t["rig.transform"], np.float64)
    if not np.allclose(m[3], [0, 0, 0, 1]):
        raise ValueError("rig.transform is not affine (its last row must be 0, 0, 0, 1)")
    m[3] = [0.0, 0.0, 0.0, 1.0]
    return LinearRig(tuple(entry["channels"]), support, np.array(t["rig.deltas"]), n,
                     scale=np.array(t["rig.scale"]), bias=np.array(t["rig.bias"]),
                     carrier=entry.get("carrier", "gaussian"),
                     vertices=None if "rig.vertices" not in t else np.array(t["rig.vertices"]), transform=m,
                     turns_covariance=bool(entry.get("turns_covariance", False)),
                     source=entry.get("source", ""), notes=dict(entry.get("notes", {})))


def header_entry(header: dict) -> Any:
    """The header's ``rig`` entry; None when absent, null or empty, or in a file older than version 4."""
    version = header.get("format_version", 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < RIG_VERSION:
        return None
    entry = header.get(HEADER_KEY)
    return entry if entry not in (None, {}) else None
