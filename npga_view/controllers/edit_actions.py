"""The edit and keyframe actions that need only an `EditSession` or a `KeyframeTimeline`: two tables of
action type -> function, used by the `EditController` (and directly by tests, without a window).

`apply_edit(session, action, view)` and `apply_keyframe(timeline, action)` return False for action types
not in their table; errors (ValueError, OSError, AvatarFileError) propagate for the app to report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

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


def _rect(s: E.EditSession, a: A.SelectRect, v: EditView) -> None:
    s.select_rect(v.need_camera("SelectRect"), *a.rect, mode=a.mode, means=v.means)


def _lasso(s: E.EditSession, a: A.SelectLasso, v: EditView) -> None:
    s.select_lasso(v.need_camera("SelectLasso"), np.asarray(a.polygon, float), mode=a.mode, means=v.means)


def _brush(s: E.EditSession, a: A.SelectBrush, v: EditView) -> None:
    s.select_brush(v.need_camera("SelectBrush"), np.asarray(a.centres, float), a.radius, mode=a.mode,
                   means=v.means)


EditFn = Callable[[E.EditSession, Any, EditView], None]

EDIT_TABLE: dict[type[A.Action], EditFn] = {
    A.SelectRect: _rect,
    A.SelectLasso: _lasso,
    A.SelectBrush: _brush,
    A.SelectSphere: lambda s, a, v: s.select_sphere(a.centre, a.radius, mode=a.mode, means=v.means),
    A.SelectBox: lambda s, a, v: s.select_box(a.lo, a.hi, None, mode=a.mode, means=v.means),
    A.SelectRange: lambda s, a, v: s.select_range(a.attribute, a.lo, a.hi, mode=a.mode),
    A.SelectGrow: lambda s, a, v: s.grow(a.steps),
    A.SelectShrink: lambda s, a, v: s.shrink(a.steps),
    A.SelectInvert: lambda s, a, v: s.invert(),
    A.SelectAll: lambda s, a, v: s.select_all(),
    A.SelectClear: lambda s, a, v: s.clear_selection(),
    A.DeleteSelection: lambda s, a, v: s.run(E.DeleteSelected()),
    A.HideSelection: lambda s, a, v: s.run(E.Hide()),
    A.ShowAllHidden: lambda s, a, v: s.run(E.ShowAll()),
    A.ScaleSelectionOpacity: lambda s, a, v: s.run(E.ScaleOpacity(a.factor)),
    A.TintSelection: lambda s, a, v: s.run(E.Tint(a.rgb, a.mode, a.amount)),
    A.SetSelectionFeature: lambda s, a, v: s.run(E.SetFeature(a.channel, a.value)),
    A.ScaleSelectionFeature: lambda s, a, v: s.run(E.ScaleFeature(a.channel, a.factor)),
    A.PreviewFloaters: lambda s, a, v: s.preview_floaters(a.k, a.distance_factor, a.min_opacity),
    A.ClearFloaterPreview: lambda s, a, v: s.clear_preview(),
    A.RemoveFloaters: lambda s, a, v: s.run(E.RemoveFloaters(a.k, a.distance_factor, a.min_opacity,
                                                             a.within_selection)),
    A.Undo: lambda s, a, v: s.undo(),
    A.Redo: lambda s, a, v: s.redo(),
    A.SaveEdits: lambda s, a, v: s.save(a.path, overwrite_source=a.overwrite_source),
    A.ExportPly: lambda s, a, v: s.export_posed_ply(a.path, v.code),
    A.DiscardAutosave: lambda s, a, v: s.discard_autosave(),
}


def apply_edit(s: E.EditSession, action: A.Action, view: EditView | None = None) -> bool:
    """Carry out an edit action on `s`; False if `action` is not one of EDIT_TABLE's types."""
    fn = EDIT_TABLE.get(type(action))
    if fn is None:
        return False
    A.check_fields(action)
    fn(s, action, view or EditView())
    return True


def _clear(tl: KeyframeTimeline) -> None:
    tl.expression.clear()
    tl.camera.clear()
    tl.code_dim = None


KEYFRAME_TABLE: dict[type[A.Action], Callable[[KeyframeTimeline, Any], None]] = {
    A.UpdateKey: lambda tl, a: tl.update_key(a.track, a.index, **dict(a.changes)),
    A.RemoveKey: lambda tl, a: tl.remove_key(a.track, a.index),
    A.ClearKeyframes: lambda tl, a: _clear(tl),
    A.SaveKeyframes: lambda tl, a: tl.save(a.path),
}


def apply_keyframe(tl: KeyframeTimeline, action: A.Action) -> bool:
    """Carry out a keyframe action that needs only the timeline; False for other action types."""
    fn = KEYFRAME_TABLE.get(type(action))
    if fn is None:
        return False
    A.check_fields(action)
    fn(tl, action)
    return True
