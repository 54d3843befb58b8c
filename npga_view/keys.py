"""The keyboard: one table of (keys, modifiers) -> action, used by the window and printed in the README.

`KEYS` is the only place a key is bound. `bindings_for(pressed, held)` picks, for the keys pressed this frame,
the binding whose modifiers are all held, Ctrl matching exactly, the most specific first (so Ctrl+Shift+Z
is Redo, not Undo). `readme_table()` renders the table as the README's "Keys" section (tests/view/test_actions.py
checks the README carries exactly this text). Key names are imgui's (`imgui.Key.<name>`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from npga_view import actions as A


@dataclass(frozen=True)
class Binding:
    keys: tuple[str, ...]  # imgui.Key member names; any of them triggers the binding
    modifiers: frozenset[str]  # of "ctrl", "shift", "alt"
    action: A.Action
    what: str  # for the README


def _b(keys: str, mods: str, action: A.Action, what: str) -> Binding:
    return Binding(tuple(keys.split()), frozenset(mods.split()), action, what)


KEYS: tuple[Binding, ...] = (
    _b("left_arrow", "", A.OrbitBy(-10, 0), "orbit left 10 degrees"),
    _b("right_arrow", "", A.OrbitBy(10, 0), "orbit right 10 degrees"),
    _b("up_arrow", "", A.OrbitBy(0, 10), "orbit up 10 degrees"),
    _b("down_arrow", "", A.OrbitBy(0, -10), "orbit down 10 degrees"),
    _b("equal keypad_add", "", A.ZoomBy(1), "zoom in"),
    _b("minus keypad_subtract", "", A.ZoomBy(-1), "zoom out"),
    _b("q", "", A.RollBy(-5), "roll -5 degrees"),
    _b("e", "", A.RollBy(5), "roll +5 degrees"),
    _b("f", "", A.FrameAvatar(), "frame the avatar"),
    _b("r", "", A.ResetCamera(), "reset the camera"),
    _b("_1", "", A.CameraPreset("front"), "front view"),
    _b("_2", "", A.CameraPreset("three_quarter"), "three-quarter view"),
    _b("_3", "", A.CameraPreset("side"), "side view"),
    _b("_4", "", A.CameraPreset("top"), "top view"),
    _b("left_bracket", "", A.CycleRigCamera(-1), "previous rig camera"),
    _b("right_bracket", "", A.CycleRigCamera(1), "next rig camera"),
    _b("space", "", A.TogglePlay(), "play / pause the sequence"),
    _b("comma", "", A.StepFrames(-1), "previous frame"),
    _b("period", "", A.StepFrames(1), "next frame"),
    _b("p", "", A.Screenshot(), "screenshot (npga-view-<time>.png)"),
    _b("delete backspace", "", A.DeleteSelection(), "delete the selected Gaussians"),
    _b("h", "", A.HideSelection(), "hide the selected Gaussians"),
    _b("h", "alt", A.ShowAllHidden(), "show all hidden Gaussians"),
    _b("escape", "", A.SelectClear(), "clear the selection"),
    _b("a", "ctrl", A.SelectAll(), "select all"),
    _b("i", "ctrl", A.SelectInvert(), "invert the selection"),
    _b("z", "ctrl", A.Undo(), "undo"),
    _b("z", "ctrl shift", A.Redo(), "redo"),
)

KEY_LABELS = {"left_arrow": "Left", "right_arrow": "Right", "up_arrow": "Up", "down_arrow": "Down", "equal": "=",
              "keypad_add": "keypad +", "minus": "-", "keypad_subtract": "keypad -", "left_bracket": "[",
              "right_bracket": "]", "space": "Space", "comma": ",", "period": ".", "delete": "Delete",
              "backspace": "Backspace", "escape": "Esc"}


def bindings_for(pressed: Iterable[str], held: frozenset[str]) -> list[Binding]:
    """The bindings the keys `pressed` this frame trigger with the modifiers `held` (see the module docstring)."""
    out = []
    pressed = set(pressed)
    for key in sorted(pressed):
        fits = [b for b in KEYS
                if key in b.keys and b.modifiers <= held and ("ctrl" in b.modifiers) == ("ctrl" in held)]
        if fits:
            best = max(fits, key=lambda b: len(b.modifiers))
            if best not in out:
                out.append(best)
    return out


def all_key_names() -> set[str]:
    return {k for b in KEYS for k in b.keys}


def _label(b: Binding) -> str:
    mods = [m.capitalize() for m in ("ctrl", "shift", "alt") if m in b.modifiers]
    keys = " / ".join(f"`{'+'.join([*mods, KEY_LABELS.get(k, k.lstrip('_').upper())])}`" for k in b.keys)
    return keys


def readme_table() -> str:
    """The README's key table (Markdown), generated from `KEYS`."""
    rows = ["| Key | Action |", "| --- | --- |"]
    rows += [f"| {_label(b)} | {b.what} |" for b in KEYS]
    return "\n".join(rows) + "\n"
