"""`ViewerState`: the single source of truth of the viewer. Panels and input write it; the app reads it.

Nothing here touches GL, glfw or imgui, so a session can be saved, restored and tested without a window.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from npga_core.camera.orbit import OrbitCamera
from npga_core.files.atomic import atomic_write
from npga_core.inspection.inspector import InspectSettings

MAX_SLIDERS = 50
RENDER_MODES = ("rgb", "depth", "alpha")
SESSION_VERSION = 1


def config_dir() -> Path:
    """Per-user settings folder (recent files, presets)."""
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "npga-view"


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
    head_pose: bool = True  # move the head as tracked when the sequence has a head pose (npga_core/headpose.py)


@dataclass
class ViewerState:
    """Everything the user can set. Derived data (posed clouds, timings) lives in the app, not here."""

    avatar_path: str | None = None
    sequence_path: str | None = None
    camera: OrbitCamera = field(default_factory=OrbitCamera)
    mode: str = "rgb"
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    use_cnn: bool = True
    sliders: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # one per PCA component, in std
    n_sliders: int = 10  # how many are shown (at most MAX_SLIDERS)
    follow_sequence: bool = True  # the code comes from the sequence frame (else from the sliders)
    timeline: Timeline = field(default_factory=Timeline)
    inspect: InspectSettings = field(default_factory=InspectSettings)  # colour mode, style, kNN, filters, pick
    rig_path: str | None = None
    rig_index: int = -1  # -1: orbit camera
    errors: list[str] = field(default_factory=list)
    recent: list[str] = field(default_factory=list)
    presets: dict[str, list[float]] = field(default_factory=dict)  # user expression presets: name -> code
    actions: list[tuple[str, object]] = field(default_factory=list)  # requests from panels, run by the app

    def report(self, message: str) -> None:
        """Show an error in the UI (kept short, newest last, at most 5)."""
        self.errors = (self.errors + [" ".join(str(message).split())])[-5:]

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

    def apply_session(self, d: dict) -> None:
        """Restore from `to_session` output; unknown keys are ignored, bad values raise ValueError."""
        if not isinstance(d, dict) or d.get("npga_view_session") != SESSION_VERSION:
            raise ValueError("not an npga-view session file")
        self.avatar_path = d.get("avatar")
        self.sequence_path = d.get("sequence")
        self.camera = OrbitCamera.from_dict(d.get("camera", {}))
        mode = d.get("mode", "rgb")
        self.mode = mode if mode in RENDER_MODES else "rgb"
        bg = [float(v) for v in d.get("background", [0, 0, 0])][:3]
        self.background = (bg + [0.0] * 3)[:3]  # type: ignore[assignment]
        self.use_cnn = bool(d.get("use_cnn", True))
        sl = np.asarray(d.get("sliders", []), np.float32).reshape(-1)
        if not np.all(np.isfinite(sl)):
            raise ValueError("session sliders are not finite")
        self.sliders = sl
        self.n_sliders = int(np.clip(d.get("n_sliders", 10), 1, MAX_SLIDERS))
        self.follow_sequence = bool(d.get("follow_sequence", True))
        for k, v in (d.get("timeline") or {}).items():
            if k in Timeline.__dataclass_fields__ and k != "playing":
                setattr(self.timeline, k, type(getattr(self.timeline, k))(v))
        self.rig_path = d.get("rig")
        self.rig_index = int(d.get("rig_index", -1))

    def save_session(self, path: str | Path) -> None:
        text = json.dumps(self.to_session(), indent=1).encode()
        atomic_write(path, lambda fh: fh.write(text))

    def load_session(self, path: str | Path) -> None:
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: cannot read session ({e})") from None
        try:
            self.apply_session(d)
        except (TypeError, ValueError) as e:
            raise ValueError(f"{path}: {e}") from None

    # -- recent files (per user) ---------------------------------------------------------------------
    def load_recent(self) -> None:
        try:
            data = json.loads((config_dir() / "recent.json").read_text())
            self.recent = [str(p) for p in data if isinstance(p, str)][:10]
        except (OSError, ValueError):
            self.recent = []

    def save_recent(self) -> None:
        text = json.dumps(self.recent).encode()
        with contextlib.suppress(OSError):
            atomic_write(config_dir() / "recent.json", lambda fh: fh.write(text))
