"""`ViewerState`: the single source of truth of the viewer. Panels and input write it; the app reads it.

Nothing here touches GL, glfw or imgui, so a session can be saved, restored and tested without a window.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.camera.orbit import OrbitCamera
from npga_core.errors import AvatarFileError, shown
from npga_core.files.atomic import atomic_write
from npga_core.files.places import user_config_dir
from npga_core.files.untrusted import read_json
from npga_core.inspection.inspector import InspectSettings
from npga_core.posing.smoothing import check_playback
from npga_core.schema import FilePath, decode, decode_file
from npga_view.actions import Action

MAX_SLIDERS = 64  # PCA directions, or a rig's channels (ARKit's 52 and more)
RENDER_MODES = ("rgb", "depth", "alpha")
SESSION_VERSION = 1
MAX_SESSION_BYTES = 4 * 2**20  # sessions, recent files and presets are small JSON files


_Wide = Annotated[float, Meta(ge=-1e12, le=1e12)]
_Angle = Annotated[float, Meta(ge=-1e6, le=1e6)]
_Unset = msgspec.UnsetType


class _Camera(msgspec.Struct):
    """A session's orbit camera (`OrbitCamera.to_dict`); a field left out keeps its default."""

    target: tuple[_Wide, _Wide, _Wide] | _Unset = msgspec.UNSET
    yaw: _Angle | _Unset = msgspec.UNSET
    pitch: _Angle | _Unset = msgspec.UNSET
    roll: _Angle | _Unset = msgspec.UNSET
    distance: Annotated[float, Meta(ge=1e-6, le=1e6)] | _Unset = msgspec.UNSET
    fov_y: Annotated[float, Meta(ge=1.0, le=170.0)] | _Unset = msgspec.UNSET


class _Timeline(msgspec.Struct):
    """A session's playback settings (`Timeline` but `playing`, which is never restored)."""

    loop: bool | _Unset = msgspec.UNSET
    speed: _Wide | _Unset = msgspec.UNSET
    time_s: _Wide | _Unset = msgspec.UNSET
    every_frame: bool | _Unset = msgspec.UNSET
    smoothing: Annotated[str, Meta(max_length=64)] | _Unset = msgspec.UNSET
    smooth_alpha: _Wide | _Unset = msgspec.UNSET
    euro_min_cutoff: _Wide | _Unset = msgspec.UNSET
    euro_beta: _Wide | _Unset = msgspec.UNSET
    baked: bool | _Unset = msgspec.UNSET
    bake_budget_mb: _Wide | _Unset = msgspec.UNSET
    bake_cache: bool | _Unset = msgspec.UNSET
    head_pose: bool | _Unset = msgspec.UNSET


class _Session(msgspec.Struct):
    """A session file (`ViewerState.to_session`); unknown fields are ignored."""

    npga_view_session: int
    avatar: FilePath | None = None
    sequence: FilePath | None = None
    rig: FilePath | None = None
    camera: _Camera = msgspec.field(default_factory=_Camera)
    mode: Annotated[str, Meta(max_length=64)] = "rgb"
    background: Annotated[list[Annotated[float, Meta(ge=0.0, le=1.0)]], Meta(max_length=16)] = msgspec.field(
        default_factory=lambda: [0.0, 0.0, 0.0])
    use_cnn: bool = True
    sliders: Annotated[list[_Wide], Meta(max_length=4096)] = []
    n_sliders: _Wide = 10
    follow_sequence: bool = True
    timeline: _Timeline | None = None
    rig_index: Annotated[float, Meta(ge=-1, le=4096)] = -1


def _given(struct: msgspec.Struct) -> dict:
    """The fields a file gave (not UNSET) of a struct."""
    return {k: v for k, v in msgspec.structs.asdict(struct).items() if v is not msgspec.UNSET}


def _apply_timeline(timeline: Timeline, value: _Timeline | None) -> None:
    """Set `timeline`'s fields from a session's ("playing" is not restored)."""
    for k, v in ({} if value is None else _given(value)).items():
        setattr(timeline, k, v)
    check_playback(timeline)  # settings smooth() or the bake would refuse later, in the frame loop


def config_dir() -> Path:
    """Per-user settings folder (recent files, presets): the platform's own (`npga_core.files.places`)."""
    return user_config_dir()


@dataclass
class Timeline:
    """Playback of the loaded sequence."""

    playing: bool = False
    loop: bool = True
    speed: float = 1.0
    time_s: float = 0.0  # position in the sequence, seconds
    every_frame: bool = False  # play every frame (wait for the dynamics) instead of following the clock
    smoothing: str = "none"  # none | exponential | one_euro
    smooth_alpha: float = 0.5  # exponential: weight of the new frame
    euro_min_cutoff: float = 1.0
    euro_beta: float = 0.5
    baked: bool = False  # play from the bake of the sequence (when one is of these codes), else live
    bake_budget_mb: float = 1024.0  # memory of a bake; longer sequences store every k-th frame and interpolate
    bake_cache: bool = True  # keep the bake in a cache file next to the avatar, reused while nothing changed
    head_pose: bool = True  # move the head as tracked when the sequence has a head pose (npga_core/posing/headpose.py)


@dataclass
class ViewerState:
    """Everything the user can set. Derived data (posed clouds, timings) lives in the app, not here."""

    avatar_path: str | None = None
    sequence_path: str | None = None
    camera: OrbitCamera = field(default_factory=OrbitCamera)
    mode: str = "rgb"
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    show_stats: bool = True  # the statistics overlay over the splat view
    use_cnn: bool = True  # show the CNN-refined image (avatars with a CNN), else the raw splats
    merged_live: bool = True  # live images (drag, slider, playback) from the merged level-of-detail cloud
    latent_view: str = "off"  # "off" | "pca" (PCA of h as RGB) | "channel" (h[latent_channel]): the latent image
    latent_channel: int = 0
    sliders: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # one per PCA component, in std
    n_sliders: int = 10  # how many are shown (at most MAX_SLIDERS)
    follow_sequence: bool = True  # the code comes from the sequence frame (else from the sliders)
    timeline: Timeline = field(default_factory=Timeline)
    inspect: InspectSettings = field(default_factory=InspectSettings)  # colour mode, style, kNN, filters, pick
    rig_path: str | None = None
    rig_index: int = -1  # -1: orbit camera
    errors: list[str] = field(default_factory=list)
    notices: list[str] = field(default_factory=list)  # what opening a file did (`tell`), above the panels
    recent: list[str] = field(default_factory=list)
    flame_model: str | None = None  # the user's FLAME pickle: GaussianAvatars folders open with it (remembered)
    presets: dict[str, list[float]] = field(default_factory=dict)  # user expression presets: name -> code
    actions: list[Action] = field(default_factory=list)  # requests from panels and keys (npga_view/actions.py)

    def report(self, message: str, note: bool = False) -> None:
        """Show an error in the UI (kept short, newest last, at most 5); `note`: a note on a file that was
        opened (a take's unmatched shapes): a status line (`tell`), no failure of a scripted run."""
        if note:
            self.tell(message)
            return
        self.errors = (self.errors + [shown(" ".join(str(message).split()))])[-5:]

    def tell(self, message: str) -> None:
        """Show what happened (not an error) in the UI's status lines (newest last, at most 3)."""
        self.notices = (self.notices + [shown(" ".join(str(message).split()))])[-3:]

    def add_recent(self, path: str) -> None:
        path = str(Path(path).resolve()) if path != "demo" else path
        self.recent = ([path] + [p for p in self.recent if p != path])[:10]

    # -- sessions ------------------------------------------------------------------------------------
    def to_session(self) -> dict:
        t = self.timeline
        return {
            "npga_view_session": SESSION_VERSION,
            "avatar": self.avatar_path,
            "sequence": self.sequence_path,
            "camera": self.camera.to_dict(),
            "mode": self.mode,
            "background": list(self.background),
            "use_cnn": self.use_cnn,
            "sliders": [float(v) for v in self.sliders],
            "n_sliders": self.n_sliders,
            "follow_sequence": self.follow_sequence,
            "timeline": {k: getattr(t, k) for k in t.__dataclass_fields__ if k != "playing"},
            "rig": self.rig_path,
            "rig_index": self.rig_index,
        }

    def apply_session(self, d: object) -> None:
        """Restore from `to_session` output; unknown keys are ignored, bad values raise ValueError naming the
        field (`decode`'s SchemaError)."""
        if not isinstance(d, dict) or d.get("npga_view_session") != SESSION_VERSION:
            raise ValueError("not an npga-view session file")
        s: _Session = decode(d, _Session)
        self.avatar_path, self.sequence_path, self.rig_path = s.avatar, s.sequence, s.rig
        self.camera = OrbitCamera.from_dict(_given(s.camera))
        self.mode = s.mode if s.mode in RENDER_MODES else "rgb"
        r, g, b = (list(s.background) + [0.0] * 3)[:3]
        self.background = (r, g, b)
        self.use_cnn = s.use_cnn
        self.sliders = np.asarray(s.sliders, np.float32).reshape(-1)
        self.n_sliders = int(np.clip(s.n_sliders, 1, MAX_SLIDERS))
        self.follow_sequence = s.follow_sequence
        _apply_timeline(self.timeline, s.timeline)
        self.rig_index = int(s.rig_index)

    def save_session(self, path: str | Path) -> None:
        text = json.dumps(self.to_session(), indent=1).encode()
        atomic_write(path, lambda fh: fh.write(text))

    def load_session(self, path: str | Path) -> None:
        """Restore a session file (untrusted JSON: regular file, size and depth bounds); AvatarFileError."""
        try:
            d = read_json(path, MAX_SESSION_BYTES, what="a session file")
        except OSError as e:
            raise AvatarFileError(path, f"cannot read session ({e.strerror or e})") from None
        try:
            self.apply_session(d)
        except (TypeError, ValueError, OverflowError) as e:
            raise AvatarFileError(path, str(e)) from None

    # -- recent files (per user) ---------------------------------------------------------------------
    def load_recent(self) -> None:
        """The recent-files list from the config folder; a missing file is an empty list, a broken one is
        reported (and ignored)."""
        path = recent_file()
        self.recent = []
        try:
            if os.path.lexists(path):
                self.recent = read_recent(path)
            if os.path.lexists(flame_model_file()):
                self.flame_model = read_flame_setting(flame_model_file())
        except AvatarFileError as e:
            self.report(str(e))

    def save_recent(self) -> None:
        text = json.dumps(self.recent).encode()
        with contextlib.suppress(OSError):
            atomic_write(recent_file(), lambda fh: fh.write(text))


    def save_flame_model(self) -> None:
        text = json.dumps({"flame_model": self.flame_model}).encode()
        with contextlib.suppress(OSError):
            atomic_write(flame_model_file(), lambda fh: fh.write(text))


class _FlameSetting(msgspec.Struct):
    """The remembered FLAME model: ``{"flame_model": PATH}``."""

    flame_model: FilePath | None = None


def flame_model_file() -> Path:
    """Where the FLAME model last given (`--flame-model`, the Files panel) is remembered."""
    return config_dir() / "flame_model.json"


def read_flame_setting(path: str | Path) -> str | None:
    """The remembered FLAME model path (untrusted JSON `{"flame_model": PATH}`); AvatarFileError when broken."""
    try:
        data = read_json(path, MAX_SESSION_BYTES, what="a FLAME model setting")
    except OSError as e:
        raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
    return decode_file(data, _FlameSetting, path).flame_model


def recent_file() -> Path:
    return config_dir() / "recent.json"


def read_recent(path: str | Path) -> list[str]:
    """The recent-files list (untrusted JSON: at most 10 paths kept); AvatarFileError when it is broken."""
    try:
        data = read_json(path, MAX_SESSION_BYTES, what="a recent-files list")
    except OSError as e:
        raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
    return [p for p in decode_file(data, list[str], path) if 0 < len(p) < 4096 and "\0" not in p][:10]
