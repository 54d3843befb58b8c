"""imgui panels. Each is an object that owns its widgets' state; `draw(state, info)` reads the state and the
frame's display snapshot `info` (npga_view/panels/info.py) and writes only the state: values, or actions
(npga_view/actions.py) appended to `state.actions`, which the app's controllers carry out."""

from __future__ import annotations

from dataclasses import dataclass, field

from npga_view.panels.edit import EditPanel
from npga_view.panels.expression import ExpressionPanel
from npga_view.panels.files import FilesPanel
from npga_view.panels.inspect import InspectPanel
from npga_view.panels.keyframes import KeyframesPanel
from npga_view.panels.stats import StatsOverlay
from npga_view.panels.timeline import TimelinePanel
from npga_view.panels.view import ViewPanel


@dataclass
class Panels:
    """The window's panels: `side` stacked in the side panel (in this order), `overlays` over the splat view."""

    files: FilesPanel
    view: ViewPanel = field(default_factory=ViewPanel)
    expression: ExpressionPanel = field(default_factory=ExpressionPanel)
    timeline: TimelinePanel = field(default_factory=TimelinePanel)
    inspect: InspectPanel = field(default_factory=InspectPanel)
    keyframes: KeyframesPanel = field(default_factory=KeyframesPanel)
    edit: EditPanel = field(default_factory=EditPanel)
    stats: StatsOverlay = field(default_factory=StatsOverlay)

    @property
    def side(self) -> tuple:
        return (self.files, self.view, self.expression, self.timeline, self.inspect, self.keyframes, self.edit)

    @property
    def overlays(self) -> tuple:
        return (self.stats,)
