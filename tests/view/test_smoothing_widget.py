"""The one smoothing widget (npga_view/panels/smoothing.py) in the Timeline panel and in its Live Link part, drawn
headless: both offer the one method list, a method picked in either is the timeline's, and the codes of the
sequence and of the stream are then smoothed by the same settings."""

from __future__ import annotations

import numpy as np


def test_the_timeline_and_live_link_draw_one_smoothing_widget(monkeypatch):
    from imgui_bundle import imgui

    from npga_core.files.sequences import ExpressionSequence
    from npga_core.posing.smoothing import METHODS, Smoothing, SmoothingFilter
    from npga_view.controllers.sequence_codes import SequenceCodes
    from npga_view.panels.info import AppInfo
    from npga_view.panels.timeline import TimelinePanel
    from npga_view.state import ViewerState
    from tests.support.panels import PanelDriver

    combos: list[tuple[str, list[str]]] = []
    sliders: list[str] = []
    pick: dict[str, str] = {}  # combo label -> the method "the user" picks in it on the next frame
    real_combo, real_slider = imgui.combo, imgui.slider_float

    def combo(label, idx, items):
        combos.append((label, list(items)))
        changed, i = real_combo(label, idx, items)
        return (True, list(items).index(pick.pop(label))) if label in pick else (changed, i)

    def slider_float(label, *args):
        sliders.append(label)
        return real_slider(label, *args)

    monkeypatch.setattr(imgui, "combo", combo)
    monkeypatch.setattr(imgui, "slider_float", slider_float)
    rng = np.random.default_rng(3)
    seq = ExpressionSequence(np.cumsum(rng.normal(0, 0.1, (40, 3)), axis=0).astype(np.float32), 30.0)
    state, info = ViewerState(), AppInfo(sequence=seq, live_listening=True, live_link="listening on 127.0.0.1:0")
    driver = PanelDriver(TimelinePanel(), state, info)
    try:
        methods = {label: items for label, items in combos if label.startswith("Smoothing")}
        assert methods == {"Smoothing": list(METHODS), "Smoothing##live": list(METHODS)}
        assert not any(s.startswith(("Alpha", "Min cutoff", "Beta")) for s in sliders)  # "none": no settings
        pick["Smoothing##live"] = "exponential"  # picked in the Live Link part ...
        driver.frame()
        assert state.timeline.smoothing == "exponential"
        sliders.clear()
        driver.frame()
        assert {"Alpha", "Alpha##live"} <= set(sliders)  # ... both copies show its setting
        pick["Smoothing"] = "one_euro"  # and in the Timeline's copy
        driver.frame()
        sliders.clear()
        driver.frame()
        assert state.timeline.smoothing == "one_euro"
        assert {"Min cutoff (Hz)", "Beta", "Min cutoff (Hz)##live", "Beta##live"} <= set(sliders)
    finally:
        driver.close()
    settings = Smoothing.of(state.timeline)
    assert settings.method == "one_euro"
    codes = SequenceCodes(state, lambda: seq)
    np.testing.assert_array_equal(codes.get(), SmoothingFilter(settings).run(seq.codes, seq.fps))
    assert codes.jitter_smoothed < codes.jitter_raw
