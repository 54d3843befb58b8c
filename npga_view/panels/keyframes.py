"""Keyframes: expression and camera keys on a timeline, their interpolation, playback and JSON files.

Reads ``info.keyframes`` (an `npga_core.editing.keyframes.KeyframeTimeline`, or None before one is made),
``info.avatar`` and ``info.sequence``, and, when the app provides them, ``info.keyframe_time`` (the playhead in
seconds, default 0) and ``info.keyframe_playing`` (default False). While the keyframe timeline plays, the app
shows ``code_at(keyframe_time)`` and ``camera_at(keyframe_time, w, h)`` instead of the sliders and the orbit
camera. Writes only `state.actions`: the keyframe actions of npga_view/actions.py (`NewKeyframes`,
`AddExpressionKey`, `AddCameraKey`, `UpdateKey`, `RemoveKey`, `ClearKeyframes`, `PlayKeyframes`,
`SeekKeyframes`, `SaveKeyframes`, `LoadKeyframes`), carried out by npga_view/controllers/editing.py.
"""

from __future__ import annotations

from imgui_bundle import imgui

from npga_core.editing.keyframes import INTERPOLATIONS, KeyframeTimeline
from npga_core.errors import shown
from npga_view import actions as A
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

SOURCES: tuple[A.KeySource, ...] = ("sliders", "frame", "preset")


class KeyframesPanel:
    """The Keyframes panel; owns the time, interpolation, source, preset and path widgets."""

    def __init__(self) -> None:
        self.time = 0.0
        self.interp = 1
        self.source = 0
        self.preset = 0
        self.path = 'keyframes.json'
        self.follow = True

    def draw(self, state: ViewerState, info: AppInfo) -> None:
        if not imgui.collapsing_header("Keyframes"):
            return
        tl: KeyframeTimeline | None = getattr(info, "keyframes", None)
        if tl is None:
            if imgui.button("New keyframe timeline"):
                state.actions.append(A.NewKeyframes())
            self._files(state, None)
            return
        now = float(getattr(info, "keyframe_time", 0.0))
        playing = bool(getattr(info, "keyframe_playing", False))
        self._transport(state, info, tl, now, playing)
        self._add_keys(state, info, tl, now)
        self._key_list(state, tl, "expression")
        self._key_list(state, tl, "camera")
        self._files(state, tl)

    def _transport(self, state: ViewerState, info: AppInfo, tl: KeyframeTimeline, now: float, playing: bool) -> None:
        if imgui.button("Pause##kf" if playing else "Play##kf"):
            state.actions.append(A.PlayKeyframes(not playing))
        remember(info, "kf_play")
        imgui.same_line()
        if imgui.button("|<##kf"):
            state.actions.append(A.SeekKeyframes(0.0))
        imgui.same_line()
        imgui.text(f"{now:6.2f} s / {tl.duration:.2f} s")
        end = max(tl.duration, 0.01)
        imgui.set_next_item_width(-1)
        changed, t = imgui.slider_float("##kfscrub", min(now, end), 0.0, end, "%.2f s")
        remember(info, "kf_scrub")
        if changed:
            state.actions.append(A.SeekKeyframes(float(t)))

    def _add_keys(self, state: ViewerState, info: AppInfo, tl: KeyframeTimeline, now: float) -> None:
        imgui.separator_text("Add key")
        _, self.follow = imgui.checkbox("At the playhead", self.follow)
        if self.follow:
            self.time = now
        else:
            imgui.same_line()
            imgui.set_next_item_width(100)
            _, self.time = imgui.input_float("Time (s)", self.time, 0.1, 1.0, "%.2f")
            self.time = max(0.0, self.time)
        avatar = info.avatar
        if avatar is not None and avatar.code_dim:
            sources = [s for s in SOURCES if s != "frame" or info.sequence is not None]
            self.source = min(self.source, len(sources) - 1)
            imgui.set_next_item_width(110)
            _, self.source = imgui.combo("##kfsource", self.source, [f"from {s}" for s in sources])
            source = sources[self.source]
            preset = None
            if source == "preset":
                names = list(avatar.expression.named) if avatar.expression is not None else []
                names += [p for p in state.presets if p not in names]
                if not names:
                    imgui.text_disabled("No presets.")
                    return
                self.preset = min(self.preset, len(names) - 1)
                imgui.same_line()
                imgui.set_next_item_width(120)
                _, self.preset = imgui.combo("##kfpreset", self.preset, [shown(n) for n in names])
                preset = names[self.preset]
            imgui.same_line()
            imgui.set_next_item_width(80)
            _, self.interp = imgui.combo("##kfinterp", self.interp, list(INTERPOLATIONS))
            imgui.same_line()
            if imgui.button("Add expression key"):
                state.actions.append(A.AddExpressionKey(float(self.time), source, preset, INTERPOLATIONS[self.interp]))
            remember(info, "kf_add_expression")
        if imgui.button("Add camera key (current view)"):
            state.actions.append(A.AddCameraKey(float(self.time)))
        remember(info, "kf_add_camera")

    def _key_list(self, state: ViewerState, tl: KeyframeTimeline, track: A.Track) -> None:
        keys = tl.keys(track)
        if not imgui.tree_node(f"{track.capitalize()} keys ({len(keys)})###kf{track}"):
            return
        for i, key in enumerate(keys):
            imgui.push_id(f"{track}{i}")
            changes: dict = {}
            imgui.set_next_item_width(70)
            # committed with Enter only: a new time re-sorts the keys, which must not happen mid-edit
            changed, t = imgui.input_float("##time", key.time, 0.0, 0.0, "%.2f",
                                           imgui.InputTextFlags_.enter_returns_true)
            if changed:
                changes["time"] = max(0.0, t)
            if track == "expression":
                imgui.same_line()
                imgui.set_next_item_width(75)
                changed, j = imgui.combo("##interp", INTERPOLATIONS.index(key.interp), list(INTERPOLATIONS))
                if changed:
                    changes["interp"] = INTERPOLATIONS[j]
            for name, label in (("ease_in", "in"), ("ease_out", "out")):
                imgui.same_line()
                imgui.set_next_item_width(55)
                changed, v = imgui.slider_float(f"##{name}", getattr(key, name), 0.0, 1.0, f"{label} %.2f")
                if changed:
                    changes[name] = v
            imgui.same_line()
            imgui.set_next_item_width(60)
            changed, h = imgui.drag_float("##hold", key.hold, 0.01, 0.0, 1e4, "hold %.2f")
            if changed:
                changes["hold"] = max(0.0, h)
            imgui.same_line()
            if imgui.small_button("go"):
                state.actions.append(A.SeekKeyframes(float(key.time)))
            imgui.same_line()
            if imgui.small_button("x"):
                state.actions.append(A.RemoveKey(track, i))
            if key.label:
                imgui.same_line()
                imgui.text_disabled(shown(key.label))
            if changes:
                state.actions.append(A.UpdateKey(track, i, changes))
            imgui.pop_id()
        imgui.tree_pop()

    def _files(self, state: ViewerState, tl: KeyframeTimeline | None) -> None:
        imgui.set_next_item_width(-150)
        _, self.path = imgui.input_text("##kfpath", self.path)
        path = self.path.strip()
        if tl is not None:
            imgui.same_line()
            if imgui.button("Save##kf") and path:
                state.actions.append(A.SaveKeyframes(path))
        imgui.same_line()
        if imgui.button("Load##kf") and path:
            state.actions.append(A.LoadKeyframes(path))
        if tl is not None:
            imgui.same_line()
            if imgui.button("Clear##kf"):
                state.actions.append(A.ClearKeyframes())
