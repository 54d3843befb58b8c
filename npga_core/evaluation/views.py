"""One captured view made ready to score: its camera, image and mask, checked (shared by `evaluate` and the
window's Compare view, so both score the same pixels)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.evaluation.capture import Capture, View
from npga_core.files.sequences import ExpressionSequence

MASK_KINDS = ("auto", "alpha", "face", "none")


@dataclass(frozen=True)
class ScoredView:
    """A view's camera (its own size and intrinsics), the captured image (H, W, 3) and the mask (H, W) or None."""

    camera: Camera
    image: np.ndarray
    mask: np.ndarray | None


def resolve_mask_kind(capture: Capture, kind: str) -> str:
    """`auto` becomes face masks when the capture has them, else alpha mattes."""
    if kind not in MASK_KINDS:
        raise ValueError(f"unknown mask kind {kind!r}; one of {', '.join(MASK_KINDS)}")
    if kind == "auto":
        return "face" if capture.has_face_masks else "alpha"
    return kind


def load_view(capture: Capture, view: View, mask_kind: str) -> ScoredView:
    """The view's image and mask (`mask_kind` resolved: face, alpha or none); AvatarFileError naming the file when
    one is unreadable or its size is not its camera's."""
    image = capture.image(view.image_path)
    path = {"face": view.face_mask_path, "alpha": view.mask_path}.get(mask_kind)
    mask = capture.image(path, grey=True) if path is not None else None
    if mask is not None and mask_kind == "face":
        mask = (mask > 0).astype(np.float32)
    cam = view.camera
    if image.shape[:2] != (cam.height, cam.width):
        raise AvatarFileError(view.image_path, f"{image.shape[1]}x{image.shape[0]}, other than its camera's "
                              f"{cam.width}x{cam.height}")
    if mask is not None and mask.shape[:2] != image.shape[:2]:
        raise AvatarFileError(str(path), f"mask {mask.shape[1]}x{mask.shape[0]}, other than its image's "
                              f"{image.shape[1]}x{image.shape[0]}")
    return ScoredView(cam, image, mask)


def frame_code(sequence: ExpressionSequence | None, frames: list[int], frame: int) -> tuple[bool, np.ndarray | None]:
    """(found, code) of capture `frame` in `sequence` (see `capture.code_index`); (True, None) without one."""
    from npga_core.evaluation.capture import code_index
    if sequence is None:
        return True, None
    k = code_index(sequence, frame, frames.index(frame) if frame in frames else 0)
    return (False, None) if k is None else (True, np.asarray(sequence.codes[k]))
