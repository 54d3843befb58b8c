"""`ViewInput`: the mouse and the keyboard of the window, turned into camera moves, picks, selections and
actions. Keys go through the table in npga_view/keys.py; Ctrl-drags in the view select (EditController);
a click picks a Gaussian when the Inspect panel asks for it; other drags move the camera (ViewCamera)."""

from __future__ import annotations

from collections.abc import Callable

from npga_view.controllers.editing import EditController
from npga_view.imgui_glfw import imgui
from npga_view.keys import all_key_names, bindings_for
from npga_view.state import ViewerState
from npga_view.view_camera import ViewCamera

KEY_NAMES = sorted(all_key_names())  # the keys npga_view/keys.py binds (imgui.Key member names)
CLICK_PX = 4  # a press and release closer than this (logical pixels) is a click, not a drag


class ViewInput:
    """Handed the state, the window's geometry (getters), the edit controller, the view camera and the pick."""

    def __init__(self, state: ViewerState, scale: Callable[[], float],
                 viewport: Callable[[], tuple[int, int, int, int]], edits: EditController, camera: ViewCamera,
                 pick: Callable[[float, float], object], divider: Callable[[float], bool] | None = None):
        self._state = state
        self._scale = scale
        self._viewport = viewport
        self._edits = edits
        self._camera = camera
        self._pick = pick
        self._divider = divider  # a wipe's divider that follows a left drag (the Compare panel), when shown
        self._click_pos: tuple[float, float] | None = None

    def mouse(self) -> None:
        io = imgui.get_io()
        if io.want_capture_mouse:
            return
        scale = self._scale()
        x0 = self._viewport()[0] / scale
        if io.mouse_pos.x < x0 and not self._edits.dragging:
            return
        if self._edits.mouse((x0, 0.0), scale):
            return
        if self._state.inspect.pick_on_click:
            if imgui.is_mouse_clicked(0):
                self._click_pos = (io.mouse_pos.x, io.mouse_pos.y)
            elif imgui.is_mouse_released(0) and self._click_pos is not None:
                cx, cy = self._click_pos
                self._click_pos = None
                if abs(io.mouse_pos.x - cx) + abs(io.mouse_pos.y - cy) < CLICK_PX:
                    self._pick((cx - x0) * scale, cy * scale)
        if self._divider is not None and imgui.is_mouse_down(0) and self._divider(io.mouse_pos.x * scale):
            return
        buttons = (imgui.is_mouse_down(0), imgui.is_mouse_down(1), imgui.is_mouse_down(2))
        self._camera.drag(io.mouse_delta.x, io.mouse_delta.y, buttons, io.key_shift, io.mouse_wheel, scale)

    def keys(self) -> None:
        """Keys pressed this frame -> actions appended to `state.actions`."""
        io = imgui.get_io()
        if io.want_capture_keyboard:
            return
        pressed = [name for name in KEY_NAMES if imgui.is_key_pressed(getattr(imgui.Key, name))]
        if not pressed:
            return
        held = frozenset(m for m, on in (("ctrl", io.key_ctrl), ("shift", io.key_shift), ("alt", io.key_alt)) if on)
        self._state.actions.extend(b.action for b in bindings_for(pressed, held))
