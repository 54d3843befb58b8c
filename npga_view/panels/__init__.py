"""imgui panels. Each is an object that owns its widgets' state; `draw(state, info)` reads the state and the
frame's display snapshot `info` (npga_view/panels/info.py) and writes only the state: values, or actions
(npga_view/actions.py) appended to `state.actions`, which the app's controllers carry out."""

from __future__ import annotations

from dataclasses import dataclass, field

from imgui_bundle import imgui

from npga_view.panels.compare import ComparePanel
from npga_view.panels.edit import EditPanel
from npga_view.panels.errors import ErrorsPanel
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
    compare: ComparePanel = field(default_factory=ComparePanel)
    stats: StatsOverlay = field(default_factory=StatsOverlay)
    errors: ErrorsPanel = field(default_factory=ErrorsPanel)
    scroll_to: float | None = None  # where the side panel is scrolled in the next frame (`scroll_side`)

    @property
    def side(self) -> tuple:
        return (self.errors, self.files, self.view, self.expression, self.timeline, self.compare, self.inspect,
                self.keyframes, self.edit)

    @property
    def overlays(self) -> tuple:
        return (self.stats,)

    def stale(self, state, info) -> bool:
        """Whether the side panel drawn this frame shows other figures than `info` now has for the image that just
        finished (the Timeline's readout while playing: `TimelinePanel.stale`)."""
        return self.timeline.stale(state, info)

    def scroll_side(self, y: float = 1e9) -> None:
        """Scroll the side panel to `y` pixels from its top in the next frame (imgui clamps it: by default its
        end, where the Timeline and its Live Link part are)."""
        self.scroll_to = y

    def draw_side(self, state, info, width: float, height: float) -> None:
        """The side panel: `side` stacked in one fixed window of `width` x `height` at the window's top left."""
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(width, height))
        if self.scroll_to is not None:
            imgui.set_next_window_scroll(imgui.ImVec2(0.0, self.scroll_to))
            self.scroll_to = None
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("npga-view", None, flags)
        for panel in self.side:
            panel.draw(state, info)
        imgui.end()
