"""The Compare panel's actions (typed, dispatched like every other action; see npga_view/actions.py)."""

from __future__ import annotations

from dataclasses import dataclass

from npga_view.actions import Action


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
