"""`CompareInfo`: what the Compare panel and the overlay show of the comparison (a snapshot)."""

from __future__ import annotations

from dataclasses import dataclass, field

from npga_core.evaluation.compare import DEFAULT_VMAX


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
