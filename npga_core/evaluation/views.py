"""One captured view made ready to score: its camera, image and mask, checked (shared by `evaluate` and the
window's Compare view, so both score the same pixels); the paper's protocol (`protocol_view`: its image size and
crop; `frontal_camera`: the held-out camera)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError
from npga_core.evaluation.capture import Capture, View
from npga_core.files.sequences import ExpressionSequence

MASK_KINDS = ("auto", "alpha", "face", "none")
NPGA_SIZE = (550, 802)  # (width, height) of the paper's metrics
#: NeRSemble's frontal camera, held out for evaluation in the paper: nersemble-benchmark's constants.py lists it
#: as the "center" of BENCHMARK_NVS_HOLD_OUT_SERIALS and as SERIALS[8]; GaussianAvatars' doc/offline_render.md
#: renders the NeRSemble "front view" with `--select_camera_id 8`
NERSEMBLE_FRONTAL = "222200037"


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


def protocol_view(cam: Camera, image: np.ndarray, mask: np.ndarray | None, size: tuple[int, int] = NPGA_SIZE,
                  source: str | Path = "") -> tuple[Camera, np.ndarray, np.ndarray | None]:
    """The paper's framing: scale so the image covers `size` (area filter), crop the centre; the camera alike.
    AvatarFileError naming `source` when the scaled image would exceed the pixel budget every image has."""
    import cv2

    from npga_core.files.untrusted import check_pixels
    w, h = size
    s = max(w / cam.width, h / cam.height)
    sw, sh = max(w, round(cam.width * s)), max(h, round(cam.height * s))
    check_pixels(sw, sh, source, f"the protocol's {w}x{h} crop of this {cam.width}x{cam.height} image needs a resize "
                 "to")
    x0, y0 = (sw - w) // 2, (sh - h) // 2

    def fit(a: np.ndarray) -> np.ndarray:
        return cv2.resize(a, (sw, sh), interpolation=cv2.INTER_AREA)[y0:y0 + h, x0:x0 + w]

    sx, sy = sw / cam.width, sh / cam.height
    c = Camera(cam.world_to_camera, cam.fx * sx, cam.fy * sy, cam.cx * sx - x0, cam.cy * sy - y0, w, h)
    return c, fit(image), None if mask is None else fit(mask)


def frontal_camera(capture: Capture) -> str:
    """NeRSemble's frontal serial when present, else the camera looking most along the rig's mean direction."""
    cams = capture.cameras
    if NERSEMBLE_FRONTAL in cams:
        return NERSEMBLE_FRONTAL
    first = {c: v.camera for (f, c), v in sorted(capture.views.items())}
    dirs = {c: cam.camera_to_world[:3, 2] for c, cam in first.items()}
    mean = np.mean(list(dirs.values()), axis=0)
    return max(dirs, key=lambda c: float(dirs[c] @ mean))
