"""imgui panels. Each `draw(state, info)` reads the state and the app's read-only `info`, and writes only the
state (values, or requests appended to `state.actions` that the app carries out)."""

from npga_view.panels import edit, expression, files, inspect, keyframes, stats, timeline, view

SIDE = (files, view, expression, timeline, inspect, keyframes, edit)  # stacked in the side panel
OVERLAYS = (stats,)  # own windows over the splat view
