"""`ActionController`: carries out the actions (npga_view/actions.py) that are not edits or keyframes: files,
camera, expression, playback, bake, output, sessions, rig. Also the user's expression presets, which live in
the config folder.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from msgspec import Meta

from npga_core.errors import AvatarFileError, brief
from npga_core.files.atomic import atomic_write
from npga_core.files.rig import load_rig
from npga_core.files.untrusted import read_json
from npga_core.model.expression import ExpressionSpace
from npga_core.schema import Finite, decode_file
from npga_view import actions as A
from npga_view.controllers.bake import BakeController
from npga_view.controllers.host import ViewerHost
from npga_view.controllers.posing import PoseController
from npga_view.state import MAX_SESSION_BYTES, config_dir


class ActionController:
    """Owned by the app; `handlers()` is its typed table of action type -> method (npga_view/dispatch.py).
    `toggle_recording` is the app's recorder switch; the loaded rig cameras are kept here."""

    def __init__(self, host: ViewerHost, poses: PoseController, bakes: BakeController,
                 toggle_recording: Callable[[], None]):
        self.host = host
        self.poses = poses
        self.bakes = bakes
        self.toggle_recording = toggle_recording
        self.rig: dict = {}  # camera name -> parameters of the loaded rig

    def handlers(self) -> A.Handlers:
        """The actions this controller carries out, each by a typed method (errors propagate to the app's
        report)."""
        h = A.Handlers()
        h.register(A.OpenAvatar, self._open_avatar)
        h.register(A.OpenSequence, self._open_sequence)
        h.register(A.CameraPreset, self._preset)
        h.register(A.FrameAvatar, self._frame_avatar)
        h.register(A.ResetCamera, self._reset_camera)
        h.register(A.OrbitBy, self._orbit)
        h.register(A.ZoomBy, self._zoom)
        h.register(A.RollBy, self._roll)
        h.register(A.CycleRigCamera, self._cycle_rig)
        h.register(A.FocusGaussian, self._focus)
        h.register(A.ResetExpression, self._reset_expression)
        h.register(A.RandomExpression, self._random_expression)
        h.register(A.SlidersFromFrame, self._sliders_from_frame)
        h.register(A.ApplyPreset, self._apply_preset)
        h.register(A.SavePreset, self._save_preset)
        h.register(A.TogglePlay, self._toggle_play)
        h.register(A.StepFrames, self._step)
        h.register(A.Bake, self._bake)
        h.register(A.CancelBake, self._cancel_bake)
        h.register(A.Screenshot, self._screenshot)
        h.register(A.ToggleRecording, self._toggle_recording)
        h.register(A.SaveSession, self._save_session)
        h.register(A.LoadSession, self._load_session)
        h.register(A.LoadRig, self._load_rig)
        h.register(A.LoadBasis, self._load_basis)
        h.register(A.SetFlameModel, self._set_flame_model)
        return h

    def _expression(self) -> ExpressionSpace | None:
        return self.host.doc.avatar.expression if self.host.doc.avatar is not None else None

    # -- files, camera (the camera object is read each time: Reset and sessions replace it) ----------------
    def _open_avatar(self, a: A.OpenAvatar) -> None:
        if a.path:
            self.host.opener.open_avatar(a.path)

    def _open_sequence(self, a: A.OpenSequence) -> None:
        if a.path:
            self.host.opener.open_sequence(a.path)

    def _frame_avatar(self, a: A.FrameAvatar) -> None:
        self.host.frame_avatar()

    def _reset_camera(self, a: A.ResetCamera) -> None:
        self.host.frame_avatar(reset=True)

    def _orbit(self, a: A.OrbitBy) -> None:
        self.host.state.camera.orbit(a.yaw, a.pitch)

    def _zoom(self, a: A.ZoomBy) -> None:
        self.host.state.camera.zoom(a.steps)

    def _roll(self, a: A.RollBy) -> None:
        self.host.state.camera.roll += a.degrees

    def _preset(self, a: A.CameraPreset) -> None:
        self.host.state.camera.preset(a.name)
        self.host.state.rig_index = -1

    def _cycle_rig(self, a: A.CycleRigCamera) -> None:
        if self.rig:
            self.host.state.rig_index = (self.host.state.rig_index + a.step) % len(self.rig)

    def _focus(self, a: A.FocusGaussian) -> None:
        posed, st = self.host.doc.posed, self.host.state
        if posed is not None and 0 <= a.index < len(posed):
            st.camera.target = [float(v) for v in posed.means[a.index]]
            st.rig_index = -1

    def _reset_expression(self, a: A.ResetExpression) -> None:
        st = self.host.state
        st.sliders[:] = 0
        st.follow_sequence = False

    def _random_expression(self, a: A.RandomExpression) -> None:
        st = self.host.state
        if self._expression() is None:
            return
        st.sliders[:] = 0
        k = min(st.n_sliders, st.sliders.size)
        rng = np.random.default_rng()
        avatar = self.host.doc.avatar
        if avatar is not None and avatar.slider_channels is not None:  # weights: a quarter of the channels on, 0..1
            st.sliders[:k] = rng.uniform(0.0, 1.0, k) * (rng.random(k) < 0.25)
        else:
            st.sliders[:k] = np.clip(rng.standard_normal(k), -2.5, 2.5)
        st.follow_sequence = False

    def _sliders_from_frame(self, a: A.SlidersFromFrame) -> None:
        st, ex, codes = self.host.state, self._expression(), self.poses.codes
        if ex is not None and codes is not None:
            st.sliders = ex.to_sliders(codes[self.poses.frame]).astype(np.float32)
            st.follow_sequence = False

    def _apply_preset(self, a: A.ApplyPreset) -> None:
        st, ex = self.host.state, self._expression()
        if ex is None:
            return
        code = ex.named.get(a.name)
        if code is None:
            if a.name not in st.presets:
                raise ValueError(f"no preset named {a.name!r}")
            code = np.asarray(st.presets[a.name], np.float32)
        st.sliders = ex.to_sliders(code).astype(np.float32)
        st.follow_sequence = False

    def _save_preset(self, a: A.SavePreset) -> None:
        if self._expression() is not None and a.name:
            self.host.state.presets[a.name] = [float(v) for v in self.poses.slider_code()]
            self.save_presets()

    def _toggle_play(self, a: A.TogglePlay) -> None:
        st = self.host.state
        if self.host.doc.sequence is not None:
            st.timeline.playing = not st.timeline.playing
            st.follow_sequence = True

    def _step(self, a: A.StepFrames) -> None:
        host, st = self.host, self.host.state
        if host.doc.sequence is None:
            return
        st.timeline.playing = False
        f = (self.poses.frame + a.delta) % len(host.doc.sequence)
        st.timeline.time_s = (f + 0.5) / host.doc.sequence.fps
        st.follow_sequence = True

    def _bake(self, a: A.Bake) -> None:
        self.bakes.start()

    def _cancel_bake(self, a: A.CancelBake) -> None:
        self.bakes.cancel()

    def _toggle_recording(self, a: A.ToggleRecording) -> None:
        self.toggle_recording()

    def _save_session(self, a: A.SaveSession) -> None:
        self.host.state.save_session(a.path or "session.json")

    def _load_session(self, a: A.LoadSession) -> None:
        self.load_session(a.path or "session.json")

    def _screenshot(self, a: A.Screenshot) -> None:
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        self.host.screenshot(a.path or f"npga-view-{stamp}.png")

    def _load_basis(self, a: A.LoadBasis) -> None:
        """Give the open avatar the basis at `a.path` (takes opened after it and the Live Link stream use it)."""
        from npga_core.files.basis_file import attach_basis

        avatar = self.host.doc.avatar
        if avatar is None or avatar.code_dim == 0:
            self.host.state.report(f"{a.path}: open an animatable avatar before its blendshape basis")
            return
        basis = attach_basis(avatar, a.path)
        self.host.state.report(f"{a.path}: blendshape basis of {len(basis.names)} shapes loaded for the avatar")

    def _set_flame_model(self, a: A.SetFlameModel) -> None:
        """Remember the user's FLAME pickle (read when a GaussianAvatars folder opens, never here)."""
        st = self.host.state
        if not Path(a.path).is_file():
            st.report(f"{a.path}: not a file (give your FLAME model, e.g. flame2023.pkl)")
            return
        st.flame_model = str(Path(a.path).resolve())
        if self.host.opener.remember_recent:
            st.save_flame_model()
        st.tell(f"FLAME model {st.flame_model}: GaussianAvatars folders now open with it")

    def _load_rig(self, a: A.LoadRig) -> None:
        if not a.path:
            return
        st = self.host.state
        self.rig = load_rig(a.path)
        st.rig_path = a.path
        st.rig_index = 0

    def load_session(self, path: str) -> None:
        """Restore camera, sliders, modes and open files from a session file."""
        host = self.host
        st = host.state
        old_avatar, old_seq = st.avatar_path, st.sequence_path
        st.load_session(path)
        cam, sliders = st.camera, st.sliders.copy()
        seq_path, time_s, follow = st.sequence_path, st.timeline.time_s, st.follow_sequence
        if st.avatar_path and st.avatar_path != old_avatar:
            host.opener.open_avatar(st.avatar_path)
        if seq_path and seq_path != old_seq and host.opener.open_sequence(seq_path):
            st.timeline.time_s, st.follow_sequence = time_s, follow  # the session's place, not the start
        st.camera = cam
        if host.doc.avatar is not None and sliders.size == st.sliders.size:
            st.sliders = sliders
        if st.rig_path:
            try:
                self.rig = load_rig(st.rig_path)
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
    """Expression presets {name: code} from untrusted JSON (bounded; finite numbers only); AvatarFileError naming
    the preset whose code is wrong."""
    d = decode_file(read_json(path, MAX_SESSION_BYTES, what="a presets file"), _Presets, path)
    return {name: decode_file(code, _Code, path, f"presets[{brief(name)}]") for name, code in d.items()}


_Presets = Annotated[dict[str, Any], Meta(max_length=10000)]
_Code = Annotated[list[Finite], Meta(min_length=1, max_length=4096)]
