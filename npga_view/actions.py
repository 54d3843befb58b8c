"""Actions: one small frozen dataclass per thing a user can ask for.

Panels, keys and drops never call the app: they append an action (e.g. ``OpenAvatar("a.npga")``) to
``state.actions``; once per frame the app hands each one to its `Dispatcher` (npga_view/dispatch.py, whose
names are re-exported here), which runs the handler registered for the action's *type*. Each controller
registers typed handlers (``handlers.register(OrbitBy, self._orbit)``), so mypy checks a handler against its
action's fields. An action type nobody handles, a queued object that is not an action, or a field of the wrong
type is an `ActionError`: raised in tests, logged and shown in the window otherwise; never a silent no-op.

Nothing here touches GL, glfw or imgui.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from npga_view.dispatch import STRICT_ENV as STRICT_ENV
from npga_view.dispatch import Action as Action
from npga_view.dispatch import ActionError as ActionError
from npga_view.dispatch import Dispatcher as Dispatcher
from npga_view.dispatch import Handlers as Handlers
from npga_view.dispatch import check_fields as check_fields

Point2 = tuple[float, float]
Point3 = tuple[float, float, float]
CombineMode = Literal["replace", "add", "subtract", "intersect"]
SelectToolName = Literal["rect", "lasso", "brush", "sphere", "box", "range"]
PresetName = Literal["front", "three_quarter", "side", "top"]
KeySource = Literal["sliders", "frame", "preset"]
Track = Literal["expression", "camera"]


# -- files, sessions, output -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OpenAvatar(Action):
    path: str


@dataclass(frozen=True)
class OpenSequence(Action):
    path: str


@dataclass(frozen=True)
class Screenshot(Action):
    path: str | None = None  # None: npga-view-<time>.png in the working folder


@dataclass(frozen=True)
class ToggleRecording(Action):
    pass


@dataclass(frozen=True)
class SaveSession(Action):
    path: str = "session.json"


@dataclass(frozen=True)
class LoadSession(Action):
    path: str = "session.json"


@dataclass(frozen=True)
class LoadRig(Action):
    path: str


@dataclass(frozen=True)
class LoadBasis(Action):
    path: str  # a blendshape basis .npz (fit-blendshapes) for the open avatar: takes and Live Link go through it


@dataclass(frozen=True)
class SetFlameModel(Action):
    path: str  # the user's FLAME pickle: GaussianAvatars folders open with it (remembered)


# -- camera ------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraPreset(Action):
    name: PresetName


@dataclass(frozen=True)
class FrameAvatar(Action):
    pass


@dataclass(frozen=True)
class ResetCamera(Action):
    pass


@dataclass(frozen=True)
class OrbitBy(Action):
    yaw: float  # degrees
    pitch: float


@dataclass(frozen=True)
class ZoomBy(Action):
    steps: float


@dataclass(frozen=True)
class RollBy(Action):
    degrees: float


@dataclass(frozen=True)
class CycleRigCamera(Action):
    step: int  # +1 next, -1 previous camera of the loaded rig


@dataclass(frozen=True)
class FocusGaussian(Action):
    index: int  # the orbit camera's target moves to this Gaussian's posed centre


# -- expression, playback, bake -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class ResetExpression(Action):
    pass


@dataclass(frozen=True)
class RandomExpression(Action):
    pass


@dataclass(frozen=True)
class SlidersFromFrame(Action):
    pass


@dataclass(frozen=True)
class ApplyPreset(Action):
    name: str


@dataclass(frozen=True)
class SavePreset(Action):
    name: str


@dataclass(frozen=True)
class TogglePlay(Action):
    pass


@dataclass(frozen=True)
class StepFrames(Action):
    delta: int


@dataclass(frozen=True)
class Bake(Action):
    pass


@dataclass(frozen=True)
class CancelBake(Action):
    pass


# -- selection (npga_core.editing) --------------------------------------------------------------------------------
@dataclass(frozen=True)
class SelectTool(Action):
    tool: SelectToolName
    mode: CombineMode = "replace"
    brush_radius: float = 20.0  # logical pixels


@dataclass(frozen=True)
class SelectRect(Action):
    rect: tuple[float, float, float, float]  # x0, y0, x1, y1 in view-camera pixels
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectLasso(Action):
    polygon: tuple[Point2, ...]
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectBrush(Action):
    centres: tuple[Point2, ...]
    radius: float
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectSphere(Action):
    centre: Point3
    radius: float
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectBox(Action):
    lo: Point3
    hi: Point3
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectRange(Action):
    attribute: str
    lo: float
    hi: float
    mode: CombineMode = "replace"


@dataclass(frozen=True)
class SelectGrow(Action):
    steps: int = 1


@dataclass(frozen=True)
class SelectShrink(Action):
    steps: int = 1


@dataclass(frozen=True)
class SelectInvert(Action):
    pass


@dataclass(frozen=True)
class SelectAll(Action):
    pass


@dataclass(frozen=True)
class SelectClear(Action):
    pass


# -- edits --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DeleteSelection(Action):
    pass


@dataclass(frozen=True)
class HideSelection(Action):
    pass


@dataclass(frozen=True)
class ShowAllHidden(Action):
    pass


@dataclass(frozen=True)
class ScaleSelectionOpacity(Action):
    factor: float


@dataclass(frozen=True)
class TintSelection(Action):
    rgb: Point3
    mode: Literal["multiply", "blend"] = "multiply"
    amount: float = 1.0


@dataclass(frozen=True)
class SetSelectionFeature(Action):
    channel: int
    value: float


@dataclass(frozen=True)
class ScaleSelectionFeature(Action):
    channel: int
    factor: float


@dataclass(frozen=True)
class PreviewFloaters(Action):
    k: int = 8
    distance_factor: float = 3.0
    min_opacity: float = 0.02


@dataclass(frozen=True)
class ClearFloaterPreview(Action):
    pass


@dataclass(frozen=True)
class RemoveFloaters(Action):
    k: int = 8
    distance_factor: float = 3.0
    min_opacity: float = 0.02
    within_selection: bool = False


@dataclass(frozen=True)
class Undo(Action):
    pass


@dataclass(frozen=True)
class Redo(Action):
    pass


@dataclass(frozen=True)
class SaveEdits(Action):
    path: str | None = None  # None: "Save" (to the last path or the source)
    overwrite_source: bool = False  # True only once the user agreed to overwrite the file it was opened from


@dataclass(frozen=True)
class ExportPly(Action):
    path: str  # the posed avatar at the current expression


@dataclass(frozen=True)
class RecoverEdits(Action):
    source: str  # open the autosaved edits of this file


@dataclass(frozen=True)
class DiscardAutosave(Action):
    pass


# -- keyframes ----------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NewKeyframes(Action):
    pass


@dataclass(frozen=True)
class AddExpressionKey(Action):
    time: float
    source: KeySource = "sliders"
    preset: str | None = None
    interp: str = "smooth"


@dataclass(frozen=True)
class AddCameraKey(Action):
    time: float


@dataclass(frozen=True)
class UpdateKey(Action):
    track: Track
    index: int
    changes: Mapping[str, object] = field(default_factory=dict)  # time, interp, ease_in, ease_out, hold, label


@dataclass(frozen=True)
class RemoveKey(Action):
    track: Track
    index: int


@dataclass(frozen=True)
class ClearKeyframes(Action):
    pass


@dataclass(frozen=True)
class PlayKeyframes(Action):
    playing: bool


@dataclass(frozen=True)
class SeekKeyframes(Action):
    time: float


@dataclass(frozen=True)
class SaveKeyframes(Action):
    path: str


@dataclass(frozen=True)
class LoadKeyframes(Action):
    path: str


# -- Live Link Face stream (npga_view/controllers/live_link.py) -------------------------------------------------
@dataclass(frozen=True)
class LiveLinkStart(Action):
    address: str  # "[HOST:]PORT", loopback when no host is given


@dataclass(frozen=True)
class LiveLinkStop(Action):
    pass


@dataclass(frozen=True)
class LiveLinkNeutral(Action):
    """Take the newest packet's weights as the rest pose."""


@dataclass(frozen=True)
class LiveLinkGain(Action):
    name: str  # an ARKit shape, any spelling
    gain: float  # 0..10


@dataclass(frozen=True)
class LiveLinkRecord(Action):
    path: str | None = None  # None: start recording; a path: stop and write the take (.csv)


# -- checking and dispatch ----------------------------------------------------------------------------------------
# -- comparison (the Compare panel: npga_view/comparison) ---------------------------------------------------------
@dataclass(frozen=True)
class OpenCapture(Action):
    """Open a capture folder (NeRSemble or GHA layout) and, optionally, the codes of its frames."""

    path: str
    sequence: str = ""


@dataclass(frozen=True)
class OpenAvatarB(Action):
    """Open a second avatar to compare with (a .npga, a 3DGS .ply, "demo"); "" closes it."""

    path: str


@dataclass(frozen=True)
class ShowComparison(Action):
    """Show the comparison in the view instead of the avatar (or go back)."""

    on: bool


@dataclass(frozen=True)
class SetCompareMode(Action):
    """How the two images are shown: wipe, blend, difference, side, a or b (npga_core.evaluation.compare)."""

    mode: str


@dataclass(frozen=True)
class SetComparePosition(Action):
    """The wipe divider / blend weight in [0, 1]."""

    t: float


@dataclass(frozen=True)
class SetComparePair(Action):
    """Which two images: "a-capture", "b-capture" or "a-b"."""

    pair: str


@dataclass(frozen=True)
class SetCompareScale(Action):
    """The difference heatmap's top (mean absolute error shown as yellow)."""

    vmax: float


@dataclass(frozen=True)
class SetCompareCnn(Action):
    """Compare the CNN's images (when the avatars have one) or the raw splats."""

    on: bool


@dataclass(frozen=True)
class SetCompareBackground(Action):
    """The background of the compared renders and outside the capture's masks (as `evaluate --background`)."""

    rgb: tuple[float, float, float]


@dataclass(frozen=True)
class StepCapture(Action):
    """Move to another frame and/or camera of the capture."""

    frames: int = 0
    cameras: int = 0


def action_types() -> list[type[Action]]:
    """Every concrete action type defined here."""
    return [c for c in globals().values() if isinstance(c, type) and issubclass(c, Action) and c is not Action]


