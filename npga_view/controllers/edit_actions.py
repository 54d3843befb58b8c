"""The edit and keyframe actions that need only an `EditSession` or a `KeyframeTimeline`: two tables of
action type -> function, used by the `EditController` (and directly by tests, without a window). Each function
is registered by a typed decorator (`@edit(A.SelectSphere)`), so mypy checks it against its action's fields.

`apply_edit(session, action, view)` and `apply_keyframe(timeline, action)` return False for action types
not in their table; errors (ValueError, OSError, AvatarFileError) propagate for the app to report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from npga_core.editing import edits as E
from npga_core.editing.keyframes import KeyframeTimeline
from npga_view import actions as A


@dataclass
class EditView:
    """What screen-space selections and exports need of the window: the view camera, the posed centres on
    screen and the current expression code (each None where the caller has none)."""

    camera: Any = None
    means: np.ndarray | None = None
    code: np.ndarray | None = None

    def need_camera(self, what: str):
        if self.camera is None:
            raise ValueError(f"{what} needs the view camera")
        return self.camera


ActionT = TypeVar("ActionT", bound=A.Action)
EditFn = Callable[[E.EditSession, ActionT, EditView], object]  # (what an edit returns is not used)
KeyframeFn = Callable[[KeyframeTimeline, ActionT], object]

EDIT_TABLE: dict[type[A.Action], EditFn[Any]] = {}
KEYFRAME_TABLE: dict[type[A.Action], KeyframeFn[Any]] = {}


def edit(cls: type[ActionT]) -> Callable[[EditFn[ActionT]], EditFn[ActionT]]:
    """Register the decorated function as EDIT_TABLE's entry for `cls` (typed: mypy checks it takes a `cls`)."""
    def add(fn: EditFn[ActionT]) -> EditFn[ActionT]:
        EDIT_TABLE[cls] = fn
        return fn
    return add


def keyframe(cls: type[ActionT]) -> Callable[[KeyframeFn[ActionT]], KeyframeFn[ActionT]]:
    """Register the decorated function as KEYFRAME_TABLE's entry for `cls` (typed as `edit`)."""
    def add(fn: KeyframeFn[ActionT]) -> KeyframeFn[ActionT]:
        KEYFRAME_TABLE[cls] = fn
        return fn
    return add


# -- selections ---------------------------------------------------------------------------------------------
@edit(A.SelectRect)
def _rect(s: E.EditSession, a: A.SelectRect, v: EditView) -> None:
    s.select_rect(v.need_camera("SelectRect"), *a.rect, mode=a.mode, means=v.means)


@edit(A.SelectLasso)
def _lasso(s: E.EditSession, a: A.SelectLasso, v: EditView) -> None:
    s.select_lasso(v.need_camera("SelectLasso"), np.asarray(a.polygon, float), mode=a.mode, means=v.means)


@edit(A.SelectBrush)
def _brush(s: E.EditSession, a: A.SelectBrush, v: EditView) -> None:
    s.select_brush(v.need_camera("SelectBrush"), np.asarray(a.centres, float), a.radius, mode=a.mode,
                   means=v.means)


@edit(A.SelectSphere)
def _sphere(s: E.EditSession, a: A.SelectSphere, v: EditView) -> None:
    s.select_sphere(np.asarray(a.centre, np.float64), a.radius, mode=a.mode, means=v.means)


@edit(A.SelectBox)
def _box(s: E.EditSession, a: A.SelectBox, v: EditView) -> None:
    s.select_box(np.asarray(a.lo, np.float64), np.asarray(a.hi, np.float64), None, mode=a.mode, means=v.means)


@edit(A.SelectRange)
def _range(s: E.EditSession, a: A.SelectRange, v: EditView) -> None:
    s.select_range(a.attribute, a.lo, a.hi, mode=a.mode)


@edit(A.SelectGrow)
def _grow(s: E.EditSession, a: A.SelectGrow, v: EditView) -> None:
    s.grow(a.steps)


@edit(A.SelectShrink)
def _shrink(s: E.EditSession, a: A.SelectShrink, v: EditView) -> None:
    s.shrink(a.steps)


@edit(A.SelectInvert)
def _invert(s: E.EditSession, a: A.SelectInvert, v: EditView) -> None:
    s.invert()


@edit(A.SelectAll)
def _all(s: E.EditSession, a: A.SelectAll, v: EditView) -> None:
    s.select_all()


@edit(A.SelectClear)
def _clear_selection(s: E.EditSession, a: A.SelectClear, v: EditView) -> None:
    s.clear_selection()


# -- edits of the selection -----------------------------------------------------------------------------------
@edit(A.DeleteSelection)
def _delete(s: E.EditSession, a: A.DeleteSelection, v: EditView) -> None:
    s.run(E.DeleteSelected())


@edit(A.HideSelection)
def _hide(s: E.EditSession, a: A.HideSelection, v: EditView) -> None:
    s.run(E.Hide())


@edit(A.ShowAllHidden)
def _show_all(s: E.EditSession, a: A.ShowAllHidden, v: EditView) -> None:
    s.run(E.ShowAll())


@edit(A.ScaleSelectionOpacity)
def _scale_opacity(s: E.EditSession, a: A.ScaleSelectionOpacity, v: EditView) -> None:
    s.run(E.ScaleOpacity(a.factor))


@edit(A.TintSelection)
def _tint(s: E.EditSession, a: A.TintSelection, v: EditView) -> None:
    s.run(E.Tint(a.rgb, a.mode, a.amount))


@edit(A.SetSelectionFeature)
def _set_feature(s: E.EditSession, a: A.SetSelectionFeature, v: EditView) -> None:
    s.run(E.SetFeature(a.channel, a.value))


@edit(A.ScaleSelectionFeature)
def _scale_feature(s: E.EditSession, a: A.ScaleSelectionFeature, v: EditView) -> None:
    s.run(E.ScaleFeature(a.channel, a.factor))


@edit(A.PreviewFloaters)
def _preview_floaters(s: E.EditSession, a: A.PreviewFloaters, v: EditView) -> None:
    s.preview_floaters(a.k, a.distance_factor, a.min_opacity)


@edit(A.ClearFloaterPreview)
def _clear_preview(s: E.EditSession, a: A.ClearFloaterPreview, v: EditView) -> None:
    s.clear_preview()


@edit(A.RemoveFloaters)
def _remove_floaters(s: E.EditSession, a: A.RemoveFloaters, v: EditView) -> None:
    s.run(E.RemoveFloaters(a.k, a.distance_factor, a.min_opacity, a.within_selection))


# -- history, files -------------------------------------------------------------------------------------------
@edit(A.Undo)
def _undo(s: E.EditSession, a: A.Undo, v: EditView) -> None:
    s.undo()


@edit(A.Redo)
def _redo(s: E.EditSession, a: A.Redo, v: EditView) -> None:
    s.redo()


@edit(A.SaveEdits)
def _save(s: E.EditSession, a: A.SaveEdits, v: EditView) -> None:
    s.save(a.path, overwrite_source=a.overwrite_source)


@edit(A.ExportPly)
def _export_ply(s: E.EditSession, a: A.ExportPly, v: EditView) -> None:
    s.export_posed_ply(a.path, v.code)


@edit(A.DiscardAutosave)
def _discard_autosave(s: E.EditSession, a: A.DiscardAutosave, v: EditView) -> None:
    s.discard_autosave()


def apply_edit(s: E.EditSession, action: A.Action, view: EditView | None = None) -> bool:
    """Carry out an edit action on `s`; False if `action` is not one of EDIT_TABLE's types."""
    fn = EDIT_TABLE.get(type(action))
    if fn is None:
        return False
    A.check_fields(action)
    fn(s, action, view or EditView())
    return True


@keyframe(A.UpdateKey)
def _update_key(tl: KeyframeTimeline, a: A.UpdateKey) -> None:
    tl.update_key(a.track, a.index, **dict(a.changes))


@keyframe(A.RemoveKey)
def _remove_key(tl: KeyframeTimeline, a: A.RemoveKey) -> None:
    tl.remove_key(a.track, a.index)


@keyframe(A.ClearKeyframes)
def _clear(tl: KeyframeTimeline, a: A.ClearKeyframes) -> None:
    tl.expression.clear()
    tl.camera.clear()
    tl.code_dim = None


@keyframe(A.SaveKeyframes)
def _save_keyframes(tl: KeyframeTimeline, a: A.SaveKeyframes) -> None:
    tl.save(a.path)


def apply_keyframe(tl: KeyframeTimeline, action: A.Action) -> bool:
    """Carry out a keyframe action that needs only the timeline; False for other action types."""
    fn = KEYFRAME_TABLE.get(type(action))
    if fn is None:
        return False
    A.check_fields(action)
    fn(tl, action)
    return True
