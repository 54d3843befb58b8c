"""Real-time playback in the real window (Xvfb): the worker is asked for the frames the view can show, not for every
frame the clock passes (npga_view/controllers/posing.py, `PoseController._hold`)."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.sequences import ExpressionSequence
from tests.support.window import run_until, settle

pytestmark = pytest.mark.gui


def _play(app, avatar_path, tmp_path, fps: float, hold: int = 1) -> None:
    """Open the avatar and a 400-frame sequence at `fps` (each code held for `hold` frames), and play it."""
    assert app.open_avatar(avatar_path)
    ex = app.avatar.expression
    codes = np.stack([ex.from_sliders(np.array([2.5 * np.sin(i // hold / 4.0), 2 * np.cos(i // hold / 5.0)]))
                      for i in range(400)])
    path = tmp_path / "wave.npzseq"
    ExpressionSequence(codes.astype(np.float32), fps, "wave").save(path)
    assert app.open_sequence(str(path))
    settle(app)
    app.state.timeline.playing = True


def _count_requests(app, monkeypatch) -> list[int]:
    eng = app.engine
    sent: list[int] = []
    for name in ("request", "request_frame"):
        real = getattr(eng, name)
        monkeypatch.setattr(eng, name, lambda *a, _real=real, **k: sent.append(1) or _real(*a, **k))
    return sent


def test_playback_asks_for_the_frames_the_view_draws(app, avatar_path, tmp_path, monkeypatch):
    """A view whose images take 4 UI frames (as the demo's do on llvmpipe) and a clock that passes a frame every UI
    frame: each pose asked for reaches an image before the next is asked for (one may be on its way), instead of
    one pose per frame of the clock, most of them never drawn."""
    _play(app, avatar_path, tmp_path, fps=240.0)
    real_frame, calls = app.draws.frame, [0]

    def slow_frame(*a, **k):  # the scheduler works in one UI frame of four: images take four UI frames
        calls[0] += 1
        return real_frame(*a, **k) if calls[0] % 4 == 0 else False

    monkeypatch.setattr(app.draws, "frame", slow_frame)
    sent = _count_requests(app, monkeypatch)
    taken: set[int] = set()

    def enough() -> bool:
        taken.add(app.draws.taken_version)
        return len(taken) >= 12

    assert run_until(app, enough, timeout=180), "playback should draw new poses"
    assert len(sent) <= len(taken) + 2, (len(sent), len(taken))
    assert app.poses.held > 0
    assert app.poses.playback.skipped > 0  # (the clock ran ahead of the images: frames were skipped, not asked for)


def test_playback_asks_again_when_the_view_takes_no_image(app, avatar_path, tmp_path, monkeypatch):
    """A view that draws nothing (the scheduler never takes a pose) holds playback's requests back at most
    `HOLD_S` each: the poses keep coming."""
    from npga_view.controllers import posing

    _play(app, avatar_path, tmp_path, fps=25.0)
    monkeypatch.setattr(posing, "HOLD_S", 0.2)
    monkeypatch.setattr(app.draws, "frame", lambda *a, **k: False)
    sent = _count_requests(app, monkeypatch)
    assert run_until(app, lambda: len(sent) >= 4, timeout=120), sent


def test_the_sliders_show_the_played_frame_and_a_drag_takes_over_from_it(app, avatar_path, tmp_path, monkeypatch):
    """While a sequence is followed, the Expression panel's sliders show where the frame on screen lies along the
    directions (they used to keep their own values); dragging one takes the sliders over from that frame."""
    from imgui_bundle import imgui

    from tests.window.test_gui import drag

    drawn: dict[str, float] = {}
    real = imgui.slider_float

    def slider(label, v, *a, **k):
        drawn[label.split("##")[-1]] = v
        return real(label, v, *a, **k)

    monkeypatch.setattr(imgui, "slider_float", slider)
    _play(app, avatar_path, tmp_path, fps=25.0)
    ex = app.avatar.expression
    matched: set[int] = set()

    def three_frames_shown_on_the_sliders() -> bool:
        # (the panels are drawn before the frame's pose is taken: they show what the last frame published)
        frame = app.info.presented_frame
        drawn.clear()
        app.step()
        want = ex.to_sliders(app.poses.codes[frame])
        if np.allclose([drawn["pc0"], drawn["pc1"]], want[:2], atol=1e-4):
            matched.add(frame)
        return len(matched) >= 3

    assert run_until(app, three_frames_shown_on_the_sliders, timeout=120), matched
    app.state.timeline.playing = False
    settle(app)
    frame = ex.to_sliders(app.poses.codes[app.info.presented_frame])
    drag(app, "slider0", 0.9)
    st = app.state
    assert not st.follow_sequence and st.sliders[0] > 1.0  # (0.9 of the slider's width: about +2.4 sd)
    np.testing.assert_allclose(st.sliders[1], frame[1], atol=1e-4)  # the other directions from the frame


def test_held_expressions_play_forward(app, avatar_path, tmp_path):
    """A sequence whose code holds for several frames (the demo's frames 81-91): the frame on screen only moves
    forward and the skipped count stays that of the frames passed (a held frame was counted as shown before the
    image of its pose came, and that image then moved the readout back and counted a whole loop as skipped)."""
    _play(app, avatar_path, tmp_path, fps=25.0, hold=6)
    shown: list[int] = []

    def far_enough() -> bool:
        frame = app.poses.presented_frame
        if frame is not None and (not shown or shown[-1] != frame):
            shown.append(frame)
        return frame is not None and frame >= 80

    assert run_until(app, far_enough, timeout=180), shown
    back = [(a, b) for a, b in zip(shown, shown[1:], strict=False) if b < a]
    assert not back, (back, shown)
    assert app.poses.playback.skipped <= shown[-1], app.poses.playback.skipped


def test_an_answer_older_than_the_one_shown_is_dropped(app, avatar_path, tmp_path):
    """An exact pose that finishes after a newer request's preview was shown (its cancel came too late) would move
    the face back: it is released, not shown."""
    from npga_core.posing.engine import PoseResult

    _play(app, avatar_path, tmp_path, fps=25.0)
    assert run_until(app, lambda: (app.poses.presented_frame or 0) >= 3, timeout=120)
    app.state.timeline.playing = False
    settle(app)
    newest = app.poses.newest_answer
    assert newest > 1
    released: list[int] = []

    class Old(PoseResult):
        def release(self) -> None:
            released.append(self.request_id)

    version, eng = app.doc.version, app.engine
    stale = Old(newest - 1, app.doc.code, app.doc.posed, {}, eng, 0)
    real_poll = eng.poll
    eng.poll = lambda: stale if not released else real_poll()  # the worker's late answer, as poll hands it over
    app.step()
    eng.poll = real_poll
    assert released == [newest - 1] and app.doc.version == version  # released, nothing shown
    assert app.poses.newest_answer == newest
