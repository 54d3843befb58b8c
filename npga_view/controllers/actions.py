"""`ActionController`: runs what the panels and keys ask for (``state.actions``) that is not an edit.

Panels never call the app: they append ``(name, argument)`` to ``state.actions``; once per frame the app
hands the list here (edits and keyframes go to the `EditController` first). Also: sessions and the user's
expression presets, which live in the config folder.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.rig import load_rig
from npga_core.files.untrusted import json_dict, json_number, read_json
from npga_view.controllers.bake import BakeController
from npga_view.controllers.host import ViewerHost
from npga_view.controllers.posing import PoseController
from npga_view.state import MAX_SESSION_BYTES, config_dir


class ActionController:
    """Owned by the app; `run(name, arg)` performs one action. `toggle_recording` is the app's recorder switch."""

    def __init__(self, host: ViewerHost, poses: PoseController, bakes: BakeController,
                 toggle_recording: Callable[[], None]):
        self.host = host
        self.poses = poses
        self.bakes = bakes
        self.toggle_recording = toggle_recording
        self.rig: dict = {}  # camera name -> parameters of the loaded rig

    def run(self, name: str, arg) -> None:
        """Perform the action `name`; unknown names are ignored. Errors propagate to the caller's report."""
        host = self.host
        st, ex = host.state, (host.avatar.expression if host.avatar is not None else None)
        codes = self.poses.codes
        if name == "open_avatar":
            if arg:
                host.open_avatar(str(arg))
        elif name == "open_sequence":
            if arg:
                host.open_sequence(str(arg))
        elif name == "preset":
            st.camera.preset(arg)
            st.rig_index = -1
        elif name == "frame_avatar":
            host.frame_avatar()
        elif name == "reset_camera":
            host.frame_avatar(reset=True)
        elif name == "reset_expression":
            st.sliders[:] = 0
            st.follow_sequence = False
        elif name == "random_expression" and ex is not None:
            st.sliders[:] = 0
            k = min(st.n_sliders, st.sliders.size)
            st.sliders[:k] = np.clip(np.random.default_rng().standard_normal(k), -2.5, 2.5)
            st.follow_sequence = False
        elif name == "sliders_from_frame" and ex is not None and codes is not None:
            st.sliders = ex.to_sliders(codes[host.info.frame]).astype(np.float32)
            st.follow_sequence = False
        elif name == "apply_preset" and ex is not None:
            code = ex.named.get(arg)
            code = np.asarray(st.presets[arg], np.float32) if code is None else code
            st.sliders = ex.to_sliders(code).astype(np.float32)
            st.follow_sequence = False
        elif name == "save_preset" and ex is not None and arg:
            st.presets[str(arg)] = [float(v) for v in self.poses.slider_code()]
            self.save_presets()
        elif name == "step" and host.sequence is not None:
            tl = st.timeline
            tl.playing = False
            f = (host.info.frame + int(arg)) % len(host.sequence)
            tl.time_s = (f + 0.5) / host.sequence.fps
            st.follow_sequence = True
        elif name == "bake":
            self.bakes.start()
        elif name == "cancel_bake":
            self.bakes.cancel()
        elif name == "screenshot":
            stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
            host.screenshot(arg or f"npga-view-{stamp}.png")
        elif name == "record":
            self.toggle_recording()
        elif name == "save_session":
            st.save_session(arg or "session.json")
        elif name == "load_session":
            self.load_session(arg or "session.json")
        elif name == "inspect_focus":
            posed = host.shown_posed()
            if posed is not None and 0 <= int(arg) < len(posed):
                st.camera.target = [float(v) for v in posed.means[int(arg)]]
                st.rig_index = -1
        elif name == "load_rig" and arg:
            self.rig = load_rig(arg)
            st.rig_path = str(arg)
            st.rig_index = 0
            host.info.rig_names = list(self.rig)

    def load_session(self, path: str) -> None:
        """Restore camera, sliders, modes and open files from a session file."""
        host = self.host
        st = host.state
        old_avatar, old_seq = st.avatar_path, st.sequence_path
        st.load_session(path)
        cam, sliders = st.camera, st.sliders.copy()
        seq_path = st.sequence_path
        if st.avatar_path and st.avatar_path != old_avatar:
            host.open_avatar(st.avatar_path)
        if seq_path and seq_path != old_seq:
            host.open_sequence(seq_path)
        st.camera = cam
        if host.avatar is not None and sliders.size == st.sliders.size:
            st.sliders = sliders
        if st.rig_path:
            try:
                self.rig = load_rig(st.rig_path)
                host.info.rig_names = list(self.rig)
            except AvatarFileError as e:
                st.report(str(e))
                st.rig_index = -1

    # -------------------------------------------------------------------------------------------- presets
    @staticmethod
    def presets_file() -> Path:
        return config_dir() / "presets.json"

    def load_presets(self) -> None:
        """The user's saved expression presets (none if the file is missing; a broken file is reported)."""
        st, path = self.host.state, self.presets_file()
        st.presets = {}
        if not os.path.lexists(path):
            return
        try:
            st.presets = read_presets(path)
        except AvatarFileError as e:
            st.report(str(e))

    def save_presets(self) -> None:
        text = json.dumps(self.host.state.presets).encode()
        atomic_write(self.presets_file(), lambda fh: fh.write(text))


def read_presets(path: str | Path) -> dict[str, list[float]]:
    """Expression presets {name: code} from untrusted JSON (bounded; finite numbers only); AvatarFileError."""
    d = json_dict(read_json(path, MAX_SESSION_BYTES, what="a presets file"), path, "presets")
    if len(d) > 10000:
        raise AvatarFileError(path, f"{len(d)} presets, more than the 10000 allowed")
    out = {}
    for name, code in d.items():
        if not isinstance(code, list) or not code or len(code) > 4096:
            raise AvatarFileError(path, f"preset {name[:40]!r} must be a list of 1..4096 numbers")
        out[name] = [json_number(v, path, f"preset {name[:40]!r}") for v in code]
    return out
