"""Reading and writing the two parts of a .npga file, for tests that tamper with files."""

from __future__ import annotations

import json
from pathlib import Path

from npga_core.files.checkpoint import ALIGN, MAGIC


def split_npga(path: Path) -> tuple[dict, bytes]:
    """(header, data section) of a .npga file, for tests that tamper with files."""
    raw = path.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    return json.loads(raw[16 : 16 + hlen]), raw[16 + hlen :]


def write_npga(path: Path, header: dict, data: bytes) -> Path:
    """Write a header and data section with correct framing (the inverse of split_npga)."""
    text = json.dumps(header).encode()
    pad = (-(16 + len(text))) % ALIGN
    text += b" " * pad
    path.write_bytes(MAGIC + len(text).to_bytes(8, "little") + text + data)
    return path
