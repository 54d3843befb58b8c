"""`CompareInfo`: what the Compare panel and the overlay show of the comparison (a snapshot), with the names of the
pairs compared and their scores' labels (no GL here: the panel imports this, not the views)."""

from __future__ import annotations

from dataclasses import dataclass, field

from npga_core.evaluation.compare import DEFAULT_VMAX

PAIRS = ("a-capture", "b-capture", "a-b")  # what is compared: the avatar (A) or B against the capture, or A against B


def score_label(key: str) -> str:
    """"a" -> "A vs capture", "a-b" -> "A vs B"."""
    return "A vs B" if key == "a-b" else f"{key.upper()} vs capture"


@dataclass(frozen=True)
class CompareInfo:
    """What the Compare panel and the overlay show (a snapshot; panels never hold the controller)."""

    active: bool = False
    capture: str = ""
    cameras: tuple[str, ...] = ()
    frames: tuple[int, ...] = ()
    frame: int | None = None
    camera: str | None = None
    b_name: str = ""
    mode: str = "wipe"
    position: float = 0.5
    pair: str = "a-capture"
    vmax: float = DEFAULT_VMAX  # the heatmap's top (npga_core/evaluation/compare.py, the one heatmap)
    use_cnn: bool = True
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    status: str = ""
    scores: dict = field(default_factory=dict)
    loading: str = ""
    overlay: tuple[str, ...] = ()  # the statistics overlay's lines while the comparison is shown
