"""Actions (npga_view/actions.py) and the key table (npga_view/keys.py), without a window: an unknown action or
a bad field is an error, never a silent no-op; keys resolve by modifiers; the README shows the key table."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest

from npga_view import actions as A
from npga_view.keys import KEYS, bindings_for, readme_table

ROOT = Path(__file__).resolve().parents[2]


def test_dispatch_runs_the_handler_registered_for_the_type():
    seen = []
    d = A.Dispatcher(strict=True)
    d.register(A.OpenAvatar, seen.append)
    d.register(A.StepFrames, seen.append)
    d.dispatch(A.OpenAvatar("a.npga"))
    d.dispatch(A.StepFrames(-1))
    assert seen == [A.OpenAvatar("a.npga"), A.StepFrames(-1)]
    with pytest.raises(A.ActionError, match="handled twice: OpenAvatar"):
        d.register(A.OpenAvatar, seen.append)


def test_a_controller_table_is_included_once():
    seen: list[A.Action] = []
    table = A.Handlers()
    table.register(A.Bake, seen.append)
    table.register(A.CancelBake, seen.append)
    d = A.Dispatcher(strict=True)
    d.include(table)
    assert set(d) == {A.Bake, A.CancelBake} and len(d) == 2
    d.dispatch(A.CancelBake())
    assert seen == [A.CancelBake()]
    with pytest.raises(A.ActionError, match="handled twice: Bake, CancelBake"):
        d.include(table)


def test_unknown_action_or_bad_field_raises_when_strict():
    d = A.Dispatcher(strict=True)
    d.register(A.OpenAvatar, lambda a: None)
    with pytest.raises(A.ActionError, match="no handler for the action Bake"):
        d.dispatch(A.Bake())
    with pytest.raises(A.ActionError, match="not an action"):
        d.dispatch(("open_avatar", "a.npga"))  # the old (name, dict) tuples are refused
    with pytest.raises(A.ActionError, match=r"OpenAvatar.path: expected <class 'str'>, got 3"):
        d.dispatch(A.OpenAvatar(3))
    with pytest.raises(A.ActionError, match="SelectRect.rect"):
        A.check_fields(A.SelectRect((0, 0, 1)))  # three numbers for a rectangle
    with pytest.raises(A.ActionError, match="SelectTool.mode"):
        A.check_fields(A.SelectTool("rect", "xor"))
    with pytest.raises(A.ActionError, match="StepFrames.delta"):
        A.check_fields(A.StepFrames(True))  # a bool is not a frame count
    A.check_fields(A.SelectLasso(((0, 0), (1.5, 2)), "add"))  # ints and floats are numbers
    with pytest.raises(A.ActionError):
        d.run_all([A.Bake()], report=lambda msg: None)


def test_lenient_dispatcher_reports_and_goes_on():
    seen, reports = [], []
    d = A.Dispatcher(strict=False)
    d.register(A.OpenAvatar, seen.append)
    d.register(A.LoadRig, lambda a: (_ for _ in ()).throw(ValueError("bad rig")))
    d.run_all([A.Bake(), A.LoadRig("r.json"), A.OpenAvatar("a.npga")], reports.append, expected=(ValueError,))
    assert seen == [A.OpenAvatar("a.npga")]
    assert reports == ["internal error: no handler for the action Bake", "bad rig"]


def test_every_action_type_is_a_frozen_checkable_dataclass():
    types = A.action_types()
    assert len(types) > 50 and len({t.__name__ for t in types}) == len(types)
    for t in types:
        assert t.__dataclass_params__.frozen, t
        typing.get_type_hints(t)  # every annotation resolves (check_fields relies on it)


def test_keys_pick_the_most_specific_binding():
    names = lambda bs: [type(b.action).__name__ for b in bs]  # noqa: E731
    assert names(bindings_for(["z"], frozenset({"ctrl"}))) == ["Undo"]
    assert names(bindings_for(["z"], frozenset({"ctrl", "shift"}))) == ["Redo"]
    assert names(bindings_for(["z"], frozenset())) == []
    assert names(bindings_for(["h"], frozenset())) == ["HideSelection"]
    assert names(bindings_for(["h"], frozenset({"alt"}))) == ["ShowAllHidden"]
    assert names(bindings_for(["h"], frozenset({"ctrl"}))) == []  # Ctrl must match exactly
    assert names(bindings_for(["left_arrow"], frozenset({"shift"}))) == ["OrbitBy"]
    assert names(bindings_for(["equal", "keypad_add"], frozenset())) == ["ZoomBy"]  # one binding, once


def test_key_table_has_no_clashes_and_imgui_knows_every_key():
    from imgui_bundle import imgui

    seen = set()
    for b in KEYS:
        A.check_fields(b.action)
        for key in b.keys:
            assert (key, b.modifiers) not in seen, key
            seen.add((key, b.modifiers))
            assert hasattr(imgui.Key, key), key


def test_readme_key_section_is_the_table():
    text = (ROOT / "README.md").read_text()
    begin, end = "<!-- keys:begin (generated from npga_view/keys.py) -->\n", "<!-- keys:end -->"
    assert begin in text and end in text
    section = text.split(begin, 1)[1].split(end, 1)[0]
    assert section == readme_table(), "README keys differ: paste npga_view.keys.readme_table() between the markers"
