"""Keyframes: expression and camera keys on a timeline, their interpolation, playback and JSON files.

Reads ``info.keyframes`` (an `npga_core.editing.keyframes.KeyframeTimeline`, or None before one is made),
``info.avatar`` and ``info.sequence``, and, when the app provides them, ``info.keyframe_time`` (the playhead in
seconds, default 0) and ``info.keyframe_playing`` (default False). While the keyframe timeline plays, the app
shows ``code_at(keyframe_time)`` and ``camera_at(keyframe_time, w, h)`` instead of the sliders and the orbit
camera. Writes only `state.actions`; `apply(timeline, name, arg)` carries out the ones marked "timeline".
Actions and their args:

- ``("kf_new", None)``: app; start an empty timeline.
- ``("kf_add_expression", {"time": t, "source": "sliders"|"frame"|"preset", "preset": name or None,
  "interp": "linear"|"smooth"})``: app; the code comes from the sliders, the current sequence frame or a named
  preset (the avatar's or the user's), then ``timeline.add_expression(time, code, interp=..., label=...)``.
- ``("kf_add_camera", {"time": t})``: app; the current view camera, ``timeline.add_camera(time, camera)``.
- ``("kf_update", {"track": "expression"|"camera", "index": i, "changes": {field: value}})``: timeline;
  fields time, interp, ease_in, ease_out, hold, label.
- ``("kf_remove", {"track": ..., "index": i})``, ``("kf_clear", None)``: timeline.
- ``("kf_play", bool)``: app; start or stop playing from the playhead (looping over the duration).
- ``("kf_seek", t)``: app; move the playhead to t seconds (and stop playing).
- ``("kf_save", path)``: timeline; write the JSON file. ``("kf_load", path)``: app;
  ``KeyframeTimeline.load(path)`` (check ``check_code_dim(avatar.code_dim)``) replaces the timeline.
"""

from __future__ import annotations

from imgui_bundle import imgui

from npga_core.editing.keyframes import INTERPOLATIONS, KeyframeTimeline
from npga_core.errors import shown
from npga_view.panels.info import AppInfo, remember
from npga_view.state import ViewerState

SOURCES = ("sliders", "frame", "preset")
_ui: dict = {"time": 0.0, "interp": 1, "source": 0, "preset": 0, "path": "keyframes.json", "follow": True}


def draw(state: ViewerState, info: AppInfo) -> None:
    if not imgui.collapsing_header("Keyframes"):
        return
    tl: KeyframeTimeline | None = getattr(info, "keyframes", None)
    if tl is None:
        if imgui.button("New keyframe timeline"):
            state.actions.append(("kf_new", None))
        _files(state, None)
        return
    now = float(getattr(info, "keyframe_time", 0.0))
    playing = bool(getattr(info, "keyframe_playing", False))
    _transport(state, info, tl, now, playing)
    _add_keys(state, info, tl, now)
    _key_list(state, tl, "expression")
    _key_list(state, tl, "camera")
    _files(state, tl)


def _transport(state: ViewerState, info: AppInfo, tl: KeyframeTimeline, now: float, playing: bool) -> None:
    if imgui.button("Pause##kf" if playing else "Play##kf"):
        state.actions.append(("kf_play", not playing))
    remember(info, "kf_play")
    imgui.same_line()
    if imgui.button("|<##kf"):
        state.actions.append(("kf_seek", 0.0))
    imgui.same_line()
    imgui.text(f"{now:6.2f} s / {tl.duration:.2f} s")
    end = max(tl.duration, 0.01)
    imgui.set_next_item_width(-1)
    changed, t = imgui.slider_float("##kfscrub", min(now, end), 0.0, end, "%.2f s")
    remember(info, "kf_scrub")
    if changed:
        state.actions.append(("kf_seek", float(t)))


def _add_keys(state: ViewerState, info: AppInfo, tl: KeyframeTimeline, now: float) -> None:
    imgui.separator_text("Add key")
    _, _ui["follow"] = imgui.checkbox("At the playhead", _ui["follow"])
    if _ui["follow"]:
        _ui["time"] = now
    else:
        imgui.same_line()
        imgui.set_next_item_width(100)
        _, _ui["time"] = imgui.input_float("Time (s)", _ui["time"], 0.1, 1.0, "%.2f")
        _ui["time"] = max(0.0, _ui["time"])
    avatar = info.avatar
    if avatar is not None and avatar.code_dim:
        sources = [s for s in SOURCES if s != "frame" or info.sequence is not None]
        _ui["source"] = min(_ui["source"], len(sources) - 1)
        imgui.set_next_item_width(110)
        _, _ui["source"] = imgui.combo("##kfsource", _ui["source"], [f"from {s}" for s in sources])
        source = sources[_ui["source"]]
        preset = None
        if source == "preset":
            names = list(avatar.expression.named) if avatar.expression is not None else []
            names += [p for p in state.presets if p not in names]
            if not names:
                imgui.text_disabled("No presets.")
                return
            _ui["preset"] = min(_ui["preset"], len(names) - 1)
            imgui.same_line()
            imgui.set_next_item_width(120)
            _, _ui["preset"] = imgui.combo("##kfpreset", _ui["preset"], [shown(n) for n in names])
            preset = names[_ui["preset"]]
        imgui.same_line()
        imgui.set_next_item_width(80)
        _, _ui["interp"] = imgui.combo("##kfinterp", _ui["interp"], list(INTERPOLATIONS))
        imgui.same_line()
        if imgui.button("Add expression key"):
            state.actions.append(("kf_add_expression", {"time": float(_ui["time"]), "source": source,
                                                        "preset": preset, "interp": INTERPOLATIONS[_ui["interp"]]}))
        remember(info, "kf_add_expression")
    if imgui.button("Add camera key (current view)"):
        state.actions.append(("kf_add_camera", {"time": float(_ui["time"])}))
    remember(info, "kf_add_camera")


def _key_list(state: ViewerState, tl: KeyframeTimeline, track: str) -> None:
    keys = tl.keys(track)
    if not imgui.tree_node(f"{track.capitalize()} keys ({len(keys)})###kf{track}"):
        return
    for i, key in enumerate(keys):
        imgui.push_id(f"{track}{i}")
        changes: dict = {}
        imgui.set_next_item_width(70)
        # committed with Enter only: a new time re-sorts the keys, which must not happen mid-edit
        changed, t = imgui.input_float("##time", key.time, 0.0, 0.0, "%.2f", imgui.InputTextFlags_.enter_returns_true)
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
            state.actions.append(("kf_seek", key.time))
        imgui.same_line()
        if imgui.small_button("x"):
            state.actions.append(("kf_remove", {"track": track, "index": i}))
        if key.label:
            imgui.same_line()
            imgui.text_disabled(shown(key.label))
        if changes:
            state.actions.append(("kf_update", {"track": track, "index": i, "changes": changes}))
        imgui.pop_id()
    imgui.tree_pop()


def _files(state: ViewerState, tl: KeyframeTimeline | None) -> None:
    imgui.set_next_item_width(-150)
    _, _ui["path"] = imgui.input_text("##kfpath", _ui["path"])
    path = _ui["path"].strip()
    if tl is not None:
        imgui.same_line()
        if imgui.button("Save##kf") and path:
            state.actions.append(("kf_save", path))
    imgui.same_line()
    if imgui.button("Load##kf") and path:
        state.actions.append(("kf_load", path))
    if tl is not None:
        imgui.same_line()
        if imgui.button("Clear##kf"):
            state.actions.append(("kf_clear", None))


def apply(tl: KeyframeTimeline, name: str, arg) -> bool:
    """Carry out the actions that need only the timeline (kf_update, kf_remove, kf_clear, kf_save); False for
    the others. ValueError/OSError propagate for the app to report."""
    if name == "kf_update":
        tl.update_key(arg["track"], int(arg["index"]), **arg["changes"])
    elif name == "kf_remove":
        tl.remove_key(arg["track"], int(arg["index"]))
    elif name == "kf_clear":
        tl.expression.clear()
        tl.camera.clear()
        tl.code_dim = None
    elif name == "kf_save":
        tl.save(arg)
    else:
        return False
    return True
