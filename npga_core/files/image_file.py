"""Images written atomically, encoded by OpenCV and written by Python (OpenCV's own writing crashed the process,
SIGSEGV, on a path it cannot encode, e.g. one with an undecodable byte)."""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

from npga_core.errors import shown
from npga_core.files.atomic import atomic_write


class ImageWriteError(OSError):
    """An image could not be encoded or written: one line naming the file (escaped)."""


def write_image(path: Path, bgr: np.ndarray, params: list[int] | None = None) -> None:
    """`bgr` (H, W, 3) uint8/uint16 encoded by the file's suffix and written atomically; ImageWriteError else."""
    import cv2

    ext = path.suffix.lower()
    try:
        ok, data = cv2.imencode(ext, bgr, params or []) if ext.isascii() and ext.isprintable() else (False, None)
    except cv2.error:
        ok = False
    if not ok:
        raise ImageWriteError(f"{shown(path)}: cannot encode an image of type {shown(ext) or '(none)'}")
    encoded = cast(np.ndarray, data)  # present when ok
    try:
        atomic_write(path, lambda fh: fh.write(encoded.tobytes()))
    except OSError as e:
        raise ImageWriteError(f"{shown(path)}: could not write the image ({e.strerror or e})") from None
