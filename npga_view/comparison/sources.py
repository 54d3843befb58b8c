"""What the Compare view compares: a capture (its frame and camera, with the sequence that tracked it) and a second
avatar B. `job` turns the current choice into one `Job`; `prepare` reads and poses it on the worker thread."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.errors import AvatarFileError, shown
from npga_core.evaluation.capture import Capture, load_capture
from npga_core.evaluation.views import ScoredView, frame_code, load_view, resolve_mask_kind
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_view.rendering.renderer import camera_key


@dataclass(frozen=True)
class Job:
    """One comparison to make: what is drawn (`roles`), how (camera, background, CNN) and which pair is shown."""

    key: tuple
    label: str
    camera: Camera
    background: tuple[float, float, float]
    use_cnn: bool
    pair: tuple[str, str]
    roles: tuple[str, ...]
    view: object | None  # the capture's View, or None
    codes: dict[str, np.ndarray | None]
    avatars: dict[str, Avatar]


@dataclass
class Prepared:
    """A job's inputs, made on the worker: the captured view and each avatar's exact pose; or an error line."""

    capture: ScoredView | None
    posed: dict[str, PosedGaussians]
    avatars: dict[str, Avatar]
    error: str | None = None


class CompareSources:
    """The capture, its sequence and the second avatar, and the frame and camera chosen in the capture."""

    def __init__(self) -> None:
        self.capture: Capture | None = None
        self.sequence: ExpressionSequence | None = None
        self.sequence_path: Path | None = None
        self.avatar_b: Avatar | None = None
        self.b_name = ""
        self.b_version = 0
        self.frame_index = 0
        self.camera_index = 0
        self.mask = "auto"
        self._frames: list[int] = []  # the capture's frames and cameras, sorted once when it opens (asked for
        self._cameras: list[str] = []  # several times a UI frame)
        self._posed: dict[str, tuple[tuple, PosedGaussians]] = {}  # role -> (avatar, version, code), its pose

    # --- opening --------------------------------------------------------------------------------------
    def open_capture(self, path: str | Path, sequence: str | Path | None = None) -> None:
        """Open a capture folder (and the expression codes of its frames); AvatarFileError naming the file."""
        from npga_core.files.loading import load_sequence
        capture = load_capture(path)
        if not capture.views:
            raise AvatarFileError(path, "no views found in the capture")
        seq = load_sequence(sequence) if sequence else None
        self._frames, self._cameras = capture.frames, capture.cameras  # (before the capture: read by the UI)
        self.capture, self.sequence = capture, seq
        self.sequence_path = Path(sequence) if sequence else None
        self.frame_index = self.camera_index = 0

    def check_sequence(self, code_dim: int) -> None:
        if self.sequence is not None and self.sequence_path is not None:
            self.sequence.check_dim(code_dim, self.sequence_path)

    def close_capture(self) -> None:
        self.capture = self.sequence = self.sequence_path = None
        self._frames, self._cameras = [], []

    def set_b(self, avatar: Avatar | None, name: str = "") -> None:
        """The second avatar (None: none)."""
        self.avatar_b, self.b_name = avatar, name
        self.b_version += 1

    # --- choice ---------------------------------------------------------------------------------------
    @property
    def frames(self) -> list[int]:
        return self._frames

    @property
    def cameras(self) -> list[str]:
        return self._cameras

    def step(self, frames: int = 0, cameras: int = 0) -> None:
        """Move to another frame and/or camera of the capture (wrapping)."""
        if self.frames:
            self.frame_index = (self.frame_index + frames) % len(self.frames)
        if self.cameras:
            self.camera_index = (self.camera_index + cameras) % len(self.cameras)

    @property
    def current(self) -> tuple[int, str] | None:
        if not self.frames or not self.cameras:
            return None
        return self.frames[self.frame_index % len(self.frames)], self.cameras[self.camera_index % len(self.cameras)]

    def why_not(self, pair: str) -> str:
        """Why `job` has nothing to compare for `pair`."""
        if "capture" in pair and self.capture is None:
            return "open a capture to compare with"
        if "b" in pair.split("-") and self.avatar_b is None:
            return "open a second avatar (B)"
        if "capture" in pair and self.capture is not None and self.current not in self.capture.views:
            return "this frame has no image for this camera"
        return "no avatar"

    def job(self, avatar: Avatar | None, version: object, code: np.ndarray | None, camera: Camera,
            background: tuple[float, float, float], use_cnn: bool, pair: str) -> Job | None:
        """The comparison the current choice asks for, or None when something it needs is missing."""
        first, second = pair.split("-")
        if avatar is None or (self.avatar_b is None and "b" in (first, second)):
            return None
        view = None
        if "capture" in (first, second):
            cur = self.current
            if self.capture is None or cur is None or cur not in self.capture.views:
                return None
            view = self.capture.views[cur]
            camera = view.camera
            _, fc = frame_code(self.sequence, self.frames, cur[0])
            if self.sequence is not None:  # the frame's own code (None without one), else the window's
                code = fc
            label = f"frame {cur[0]}, camera {shown(cur[1])}"
        else:
            label = "A vs B, window camera"
        roles = tuple(r for r in ("a", "b") if r in (first, second) or (r == "b" and self.avatar_b is not None
                                                                         and view is not None))
        avatars = {"a": avatar} if self.avatar_b is None else {"a": avatar, "b": self.avatar_b}
        codes: dict[str, np.ndarray | None] = {r: code for r in roles}
        code_key = None if code is None else np.asarray(code, np.float32).tobytes()
        key = (version, self.b_version, id(self.capture), None if view is None else (view.frame, view.camera_id),
               camera_key(camera), code_key, tuple(background), use_cnn, roles, self.mask)
        rgb = cast(tuple[float, float, float], tuple(background))
        return Job(key, label, camera, rgb, use_cnn, (first, second), roles, view, codes,
                   {r: avatars[r] for r in roles})

    # --- on the worker --------------------------------------------------------------------------------
    def prepare(self, job: Job, cancel: threading.Event) -> Prepared:
        """Read the captured view and pose every avatar of `job` (exact). Errors become one line."""
        capture = None
        try:
            if job.view is not None and self.capture is not None:
                capture = load_view(self.capture, job.view, resolve_mask_kind(self.capture, self.mask))  # type: ignore[arg-type]
            posed: dict[str, PosedGaussians] = {}
            for role in job.roles:
                if cancel.is_set():
                    return Prepared(capture, {}, job.avatars, "cancelled")
                avatar = job.avatars[role]
                code = job.codes[role]
                if code is not None and len(code) != avatar.code_dim:
                    return Prepared(capture, {}, job.avatars,
                                    f"avatar {role.upper()} takes {avatar.code_dim}-D codes, the sequence has "
                                    f"{len(code)}-D")
                key = (id(avatar), avatar.version, None if code is None else np.asarray(code, np.float32).tobytes())
                cached = self._posed.get(role)
                if cached is None or cached[0] != key:  # another camera of the same frame: the same pose
                    cached = self._posed[role] = (key, avatar.pose(code))
                posed[role] = cached[1]
        except (AvatarFileError, ValueError) as e:
            return Prepared(capture, {}, job.avatars, str(e))
        return Prepared(capture, posed, job.avatars)
