"""A side panel drawn in a headless imgui context and clicked like a user (no window, no GL)."""

from __future__ import annotations


class PanelDriver:
    """Draws one panel per frame in a headless imgui context; `click(widget)` presses and releases the left
    mouse button over a widget whose rectangle the panel remembered."""

    def __init__(self, panel, state, info):
        from imgui_bundle import imgui

        self.imgui, self.panel, self.state, self.info = imgui, panel, state, info
        self.open = True  # the panel's header is opened (or closed) each frame
        self.ctx = imgui.create_context()
        io = imgui.get_io()
        io.set_ini_filename(None)
        io.display_size = imgui.ImVec2(700, 1400)
        io.backend_flags |= imgui.BackendFlags_.renderer_has_textures
        self.frame()

    def frame(self, pos: tuple[float, float] | None = None, down: bool = False) -> None:
        imgui, io = self.imgui, self.imgui.get_io()
        if pos is not None:
            io.add_mouse_pos_event(*pos)
        io.add_mouse_button_event(0, down)
        imgui.new_frame()
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(680, 1380))
        imgui.begin("side")
        imgui.set_next_item_open(self.open)
        self.panel.draw(self.state, self.info)
        imgui.end()
        imgui.render()

    def click(self, widget: str) -> None:
        x0, y0, x1, y1 = self.info.rects[widget]
        centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
        self.frame(centre)
        self.frame(centre, down=True)
        self.frame(centre, down=False)

    def close(self) -> None:
        self.imgui.destroy_context(self.ctx)
