"""`ViewCamera`: which camera the splat view shows, and the mouse's moves of the orbit camera.

The camera comes, in this order, from the keyframe timeline while it plays camera keys, from the loaded rig
(NeRSemble cameras, `ActionController.rig`) when one is chosen, else from the orbit camera in the state; while
a sequence with a head pose is followed, the head's tracked pose of the frame on screen moves it (relative to
frame 1 for the orbit camera, as tracked for a rig camera).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from npga_core.camera.cameras import Camera
from npga_core.camera.orbit import OrbitCamera
from npga_core.files.rig import fit_camera
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.posing.headpose import has_head_pose, head_transform, posed_camera
from npga_view.controllers.editing import EditController
from npga_view.document import AvatarOpened, Subscriptions
from npga_view.state import ViewerState

ORBIT_DEG_PER_PX = 0.3  # mouse drags: degrees of orbit or roll per logical pixel


class ViewCamera:
    """Handed the state, the splat view's size (a getter: the window resizes), the keyframes' owner, the rig
    (a getter: it is loaded later), the open sequence and the sequence frame on screen."""

    def __init__(self, state: ViewerState, viewport: Callable[[], tuple[int, int, int, int]],
                 keyframes: EditController, rig: Callable[[], dict], sequence: Callable[[], ExpressionSequence | None],
                 frame_on_screen: Callable[[], int], live_head: Callable[[], np.ndarray | None] = lambda: None):
        self._state = state
        self._viewport = viewport
        self._kf = keyframes
        self._rig = rig
        self._sequence = sequence
        self._frame_on_screen = frame_on_screen
        self._live_head = live_head  # the Live Link stream's head transform, when it sends angles

    def current(self, ignore_keyframes: bool = False) -> Camera:
        """The splat view's camera (see the module docstring)."""
        st, kf, rig = self._state, self._kf, self._rig()
        _, _, w, h = self._viewport()
        use_rig = st.rig_index >= 0 and bool(rig)
        cam = None
        if not ignore_keyframes and kf.kf_playing:
            cam = kf.keyframes.camera_at(kf.kf_time, w, h)  # (None without camera keys)
        if cam is None and use_rig:
            names = list(rig)
            cam = fit_camera(rig[names[st.rig_index % len(names)]], w, h)
        elif cam is None:
            cam = st.camera.camera(w, h)
        seq = self._sequence()
        if seq is not None and st.follow_sequence and st.timeline.head_pose and has_head_pose(seq):
            cam = posed_camera(cam, head_transform(seq, self._frame_on_screen(), relative=not use_rig))
        elif (head := self._live_head()) is not None:  # the Live Link stream's head angles
            cam = posed_camera(cam, head)
        return cam

    def subscriptions(self) -> Subscriptions:
        """A new avatar is framed by a fresh orbit camera."""
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._opened)
        return s

    def _opened(self, e: AvatarOpened) -> None:
        self.frame_avatar(e.avatar, reset=True)

    def frame_avatar(self, avatar: Avatar | None, reset: bool = False) -> None:
        """Point the orbit camera at the avatar (from a fresh orbit camera with `reset`)."""
        if avatar is None or len(avatar) == 0:
            return
        cam = self._state.camera
        if reset:
            self._state.camera = cam = OrbitCamera(fov_y=cam.fov_y or 20.0)
        w, h = self._viewport()[2:]
        cam.frame(np.asarray(avatar.cloud.means), aspect=w / max(h, 1))

    def drag(self, dx: float, dy: float, buttons: tuple[bool, bool, bool], shift: bool, wheel: float,
             scale: float) -> None:
        """Mouse moves over the view: left drag orbits (rolls with Shift), right or middle drag pans, the wheel
        zooms; `scale` is framebuffer pixels per logical pixel. Rig cameras do not move."""
        cam = self._state.camera
        if (dx or dy) and self._state.rig_index < 0:
            if buttons[0] and shift:
                cam.roll += dx * ORBIT_DEG_PER_PX
            elif buttons[0]:
                cam.orbit(-dx * ORBIT_DEG_PER_PX, dy * ORBIT_DEG_PER_PX)
            elif buttons[1] or buttons[2]:
                cam.pan(dx * scale, dy * scale, self._viewport()[3])
        if wheel:
            cam.zoom(wheel)
