"""The Timeline panel while a sequence plays: the frame slider and the readout follow the frame whose image is on
screen, so imgui's output changes with the images and not with every tick of the playback clock (the window does not
draw a frame again whose imgui output and view image are those on screen); paused, they follow the clock. The Live
Link stream's counters (a change with every packet) are refreshed every REFRESH_S as the stats overlay's figures
are."""

from __future__ import annotations

import numpy as np


def test_playing_readout_changes_with_the_image_not_the_clock(monkeypatch):
    from imgui_bundle import imgui

    from npga_core.files.sequences import ExpressionSequence
    from npga_view.panels import timeline
    from npga_view.panels.info import AppInfo
    from npga_view.state import ViewerState
    from npga_view.window import draw_data_fingerprint
    from tests.support.panels import PanelDriver

    texts: list[str] = []
    sliders: dict[str, int] = {}
    real_text, real_slider = imgui.text, imgui.slider_int

    def text(s: str) -> None:
        texts.append(s)
        real_text(s)

    def slider_int(label, value, *args):
        sliders[label] = value
        return real_slider(label, value, *args)

    monkeypatch.setattr(imgui, "text", text)
    monkeypatch.setattr(imgui, "slider_int", slider_int)
    seq = ExpressionSequence(np.zeros((100, 3), np.float32), 25.0)
    state, info = ViewerState(), AppInfo(sequence=seq)
    state.timeline.playing = True
    info.frame, info.presented_frame, state.timeline.time_s = 10, 7, 0.42
    driver = PanelDriver(timeline.TimelinePanel(), state, info)

    def frame() -> tuple[int, list[str]]:
        texts.clear()
        driver.frame()
        return draw_data_fingerprint(imgui.get_draw_data()), list(texts)

    try:
        first, lines = frame()
        assert sliders["Frame"] == 7 and lines[0].startswith("frame 8/100") and "0.28 s" in lines[0]
        for k in range(1, 6):  # the clock runs on, the image on screen stays: the same output every frame
            info.frame, state.timeline.time_s = 10 + k, 0.42 + 0.04 * k
            info.achieved_fps, info.skipped = 5.0 + k, k
            again, lines = frame()
            assert again == first, k
        info.presented_frame = 12  # a new image reached the screen: the readout is of it, with today's figures
        moved, lines = frame()
        assert moved != first and sliders["Frame"] == 12
        assert lines[0].startswith("frame 13/100") and "achieved  10.0 frames/s, skipped 5" in lines[1]
        state.timeline.playing = False  # paused: the clock's frame and time, as they change
        paused, lines = frame()
        assert sliders["Frame"] == 15 and lines[0].startswith("frame 16/100") and "0.62 s" in lines[0]
        info.frame, state.timeline.time_s = 16, 0.66
        stepped, lines = frame()
        assert stepped != paused and sliders["Frame"] == 16
    finally:
        driver.close()


def test_live_link_counters_every_refresh(monkeypatch):
    from imgui_bundle import imgui

    from npga_view.panels.info import AppInfo
    from npga_view.panels.live_link import LiveLinkPanel
    from npga_view.panels.stats import REFRESH_S
    from npga_view.state import ViewerState
    from tests.support.panels import PanelDriver

    texts: list[str] = []
    real_text = imgui.text

    def text(s: str) -> None:
        texts.append(s)
        real_text(s)

    monkeypatch.setattr(imgui, "text", text)
    clock = [50.0]
    info = AppInfo(live_listening=True, live_link="listening on 127.0.0.1:11111")

    def counters(n: int, recording: bool = False) -> str:
        return f"Live Link: {n} received, 0 dropped, 0 late, 0 bad" + (" (recording)" if recording else "")

    info.live_counters = counters(1)
    driver = PanelDriver(LiveLinkPanel(clock=lambda: clock[0]), ViewerState(), info)

    def shown() -> str:
        texts.clear()
        driver.frame()
        return next(t for t in texts if t.startswith("Live Link:"))

    try:
        assert shown() == counters(1)
        for n in range(2, 6):  # packets every frame: the line stays until REFRESH_S has passed
            clock[0] += 0.03
            info.live_counters = counters(n)
            assert shown() == counters(1)
        clock[0] += REFRESH_S
        assert shown() == counters(5)
        clock[0] += 0.01
        info.live_counters, info.live_recording = counters(6, recording=True), True  # recording starts: at once
        assert shown() == counters(6, recording=True)
    finally:
        driver.close()


def test_stale_when_an_image_finished_after_the_panel_was_drawn():
    """`TimelinePanel.stale`: while playing, the readout drawn this frame is of another frame than the image that
    finished after it (the window then holds that image one frame, to draw it with its readout); not when paused,
    nor when the Timeline is collapsed."""
    from npga_core.files.sequences import ExpressionSequence
    from npga_view.panels import timeline
    from npga_view.panels.info import AppInfo
    from npga_view.state import ViewerState
    from tests.support.panels import PanelDriver

    seq = ExpressionSequence(np.zeros((100, 3), np.float32), 25.0)
    state, info = ViewerState(), AppInfo(sequence=seq)
    state.timeline.playing, info.presented_frame = True, 7
    panel = timeline.TimelinePanel()
    driver = PanelDriver(panel, state, info)
    try:
        driver.frame()
        assert not panel.stale(state, info)
        info.presented_frame = 8  # an image of frame 8 finished after the panel was drawn
        assert panel.stale(state, info)
        driver.frame()
        assert not panel.stale(state, info)
        state.timeline.playing = False
        info.presented_frame = 9
        driver.frame()
        assert not panel.stale(state, info)
        state.timeline.playing = True
        driver.open = False  # the Timeline collapsed: nothing of the readout is drawn
        driver.frame()
        info.presented_frame = 10
        assert not panel.stale(state, info)
    finally:
        driver.close()


def test_a_frame_is_held_for_stale_panels_only_while_a_sequence_plays():
    """`ViewFrame._hold`: a frame whose panels are stale waits (one frame, never two in a row) while a sequence
    plays; not while paused, recording, streaming, or with a drag or widget held."""
    from types import SimpleNamespace

    from npga_view.panels.info import AppInfo
    from npga_view.state import ViewerState
    from npga_view.view_frame import ViewFrame

    state, streaming, held = ViewerState(), [False], [False]
    vf = ViewFrame(state=state, info=AppInfo(), doc=SimpleNamespace(sequence=object()), draws=None, lod=None,
                   screen=None, poses=None, refining=None, compare=None,
                   live=SimpleNamespace(busy=lambda: streaming[0]), edits=SimpleNamespace(kf_playing=False),
                   camera=lambda: None, viewport=lambda: (0, 0, 1, 1))
    vf._held = lambda: held[0]  # (imgui's input state)
    state.follow_sequence, state.timeline.playing = True, True
    assert [vf._hold(True, False) for _ in range(4)] == [True, False, True, False]
    assert not vf._hold(False, False)
    assert not vf._hold(True, True)  # recording: every frame is drawn
    streaming[0] = True
    assert not vf._hold(True, False)
    streaming[0], held[0] = False, True
    assert not vf._hold(True, False)
    held[0], state.timeline.playing = False, False
    assert not vf._hold(True, False)
