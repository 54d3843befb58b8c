"""Byte-level helpers of the corpus's value cases (tests/support/hostile_corpus.py) and the degenerate avatars that must
open: broken compressed streams, PLY columns and cache tables set to extreme values, poses with huge
translations."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np


def _write_all(folder: Path, suffix: str, cases: dict[str, bytes]) -> dict[str, Path]:
    out = {}
    for i, (name, content) in enumerate(cases.items()):
        p = folder / f"case{i:02d}{suffix}"
        p.write_bytes(content)
        out[name] = p
    return out


def _broken_stream(members: dict[str, bytes], method: int) -> bytes:
    """A zip whose compressed member data (deflate or LZMA) is corrupted after its first bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    raw = bytearray(buf.getvalue())
    info = zipfile.ZipFile(io.BytesIO(bytes(raw))).infolist()[0]
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    for i in range(start + 8, start + min(info.compress_size, 400)):
        raw[i] ^= 0x5A
    return bytes(raw)


def _pose(t: int, translation: float) -> np.ndarray:
    pose = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    pose[:, :3, 3] = translation
    return pose


def _ply_column(body: np.ndarray, head: str, prop: str, value: float) -> bytes:
    """The binary vertex data with property `prop` set to `value` in every vertex."""
    names = [line.split()[-1] for line in head.splitlines() if line.startswith("property ")]
    rows = body.reshape(-1, len(names)).copy()
    rows[:, names.index(prop)] = value
    return rows.tobytes()


def _ply_column_array(body: np.ndarray, head: str, prop: str, value: float) -> np.ndarray:
    return np.frombuffer(_ply_column(body, head, prop, value), np.float32)


def _floats_set(data: bytes, start: int, stop: int, value: float) -> bytes:
    """`data` with the float32 values in bytes [start, stop) set to `value`."""
    out = bytearray(data)
    out[start:stop] = np.full((stop - start) // 4, value, np.float32).tobytes()
    return bytes(out)


def _with_header(src: Path, dst: Path, change) -> Path:
    """`src` (.npga) with its JSON header changed by `change(header)`, written as ASCII JSON (lone surrogates as
    \\u escapes, as a hostile writer may put them)."""
    raw = src.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    header = json.loads(raw[16:16 + hlen])
    change(header)
    t = json.dumps(header).encode()
    t += b" " * ((-(16 + len(t))) % 64)
    dst.write_bytes(raw[:8] + len(t).to_bytes(8, "little") + t + raw[16 + hlen:])
    return dst


def _odd_v2_names(header: dict) -> None:
    """A format-2 header whose condition description, blend notes and blend name hold lone surrogates, newlines
    and an escape sequence (#36: `info` died printing them)."""
    dyn = header["dynamics"]
    dyn["condition"]["description"] = "pose\ud800\n\x1b[31m"
    old, new = "pose", "po\udcffse\n"
    header["gaussians"]["blend_names"] = [new if b == old else b for b in header["gaussians"]["blend_names"]]
    dyn["blend"] = {(new if k == old else k): v + "\udc80" for k, v in dyn["blend"].items()}
    for net in dyn["networks"].values():
        if net.get("blend") == old:
            net["blend"] = new


def degenerate_avatars(folder: Path, good_ply: Path, good_npga: Path, guards: bool = False,
                       good_v2: Path | None = None) -> dict[str, Path]:
    """Valid but degenerate avatars, which must open, render an empty image and say so (exit 0, no traceback,
    no warning): 0 Gaussians, names with lone surrogates; with `guards`, also the cases today's code already
    took (all transparent, all at one point), which are no findings of the corpus."""
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar

    raw = good_ply.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    head = raw[:end].decode()
    n = int(head.split("element vertex ")[1].split()[0])
    body = np.frombuffer(raw[end:], np.float32).copy()
    cases = {
        "ASCII PLY of 0 vertices": head.replace(f"element vertex {n}", "element vertex 0")
        .replace("binary_little_endian", "ascii").encode(),
        "binary PLY of 0 vertices": head.replace(f"element vertex {n}", "element vertex 0").encode(),
    }
    if guards:
        cases["all transparent"] = head.encode() + _ply_column(body, head, "opacity", -80.0)
        cases["all at one point"] = head.encode() + _ply_column(_ply_column_array(body, head, "x", 0.0), head, "y",
                                                                0.0)
    out = _write_all(folder, ".ply", cases)
    zero = folder / "zero.npga"
    save_avatar(make_synthetic_avatar(0, seed=3), zero)
    out["avatar of 0 Gaussians"] = zero
    hraw = good_npga.read_bytes()
    hlen = int.from_bytes(hraw[8:16], "little")
    header = json.loads(hraw[16:16 + hlen])
    header["gaussians"]["part_names"] = ["face\ud800", "back\nhead", "neck\udcff"]
    header["provenance"]["source"] = "x\udc80\n\x1b[31m"
    t = json.dumps(header).encode()  # ASCII JSON: the surrogates as \u escapes, as a hostile writer may put them
    t += b" " * ((-(16 + len(t))) % 64)
    names = folder / "names.npga"
    names.write_bytes(hraw[:8] + len(t).to_bytes(8, "little") + t + hraw[16 + hlen:])
    out["lone surrogates and newlines in part names and provenance"] = names
    if good_v2 is not None:
        out["lone surrogates in a format-2 description and blend name"] = _with_header(
            good_v2, folder / "names-v2.npga", _odd_v2_names)
    return out
