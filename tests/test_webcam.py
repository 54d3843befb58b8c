"""`npga-view webcam`: the requirement messages, MediaPipe's result mapped to Live Link Face packets, streaming.

MediaPipe's layout (google-ai-edge/mediapipe at 055accec, mediapipe/tasks/python/vision/face_landmarker.py):
the `Blendshapes` enum (lines 66-120) lists NEUTRAL = 0 and then the 52 shapes in alphabetical order
(BROW_DOWN_LEFT = 1 ... NOSE_SNEER_RIGHT = 51; no tongueOut); `FaceLandmarkerResult.face_blendshapes` (lines
123-135) is a list per face of `Category(index, score, display_name, category_name)`, the category name being
the model's label (`_neutral`, `browDownLeft`, ...).
"""

from __future__ import annotations

import importlib.util
import time
from types import SimpleNamespace

import numpy as np

from npga_core.files.blendshape_names import ARKIT_52
from npga_core.posing import webcam
from npga_core.posing.livelink import LiveLinkReceiver, decode
from npga_view.cli.main import main

# MediaPipe's 52 categories in its enum order: _neutral, then ARKit's names sorted (tongueOut is not one of them)
MEDIAPIPE_NAMES = ["_neutral", *sorted(n for n in ARKIT_52 if n != "tongueOut")]


def _result(scores: dict[str, float]):
    cats = [SimpleNamespace(index=i, score=scores.get(n, 0.0), display_name="", category_name=n)
            for i, n in enumerate(MEDIAPIPE_NAMES)]
    return SimpleNamespace(face_landmarks=[[]], face_blendshapes=[cats], facial_transformation_matrixes=[])


def test_without_the_model_one_line_and_exit_2(tmp_path, capsys):
    assert main(["webcam", "--face-model", str(tmp_path / "face_landmarker.task")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "face_landmarker.task" in err
    assert "https://developers.google.com/mediapipe/solutions/vision/face_landmarker" in err


def test_without_mediapipe_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    model = tmp_path / "face_landmarker.task"
    model.write_bytes(b"not really a model")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "mediapipe" else real(name, *a))
    assert main(["webcam", "--face-model", str(model)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "pip install 'npga-view[webcam]'" in err


def test_a_landmarker_result_becomes_the_packet_values():
    scores = {"eyeBlinkLeft": 0.9, "jawOpen": 0.4, "browInnerUp": 0.25, "_neutral": 0.7, "mouthSmileRight": 1.3}
    v = webcam.values_of(_result(scores))
    assert v.shape == (61,)
    assert v[ARKIT_52.index("eyeBlinkLeft")] == np.float32(0.9)
    assert v[ARKIT_52.index("jawOpen")] == np.float32(0.4)
    assert v[ARKIT_52.index("browInnerUp")] == np.float32(0.25)
    assert v[ARKIT_52.index("mouthSmileRight")] == 1.0  # clipped to the weight range
    assert np.count_nonzero(v) == 4 and not v[52:].any()  # _neutral is no shape; no head angles from a webcam
    assert webcam.values_of(SimpleNamespace(face_blendshapes=[])) is None  # no face: nothing to send


def test_stream_sends_packets_the_receiver_reads(tmp_path):
    results = [_result({"eyeBlinkLeft": 0.2 * k, "jawOpen": 0.1}) for k in range(5)]
    results[2] = SimpleNamespace(face_blendshapes=[])  # a frame without a face is skipped
    seen_ts = []

    def detect(rgb, t_ms):
        seen_ts.append(t_ms)
        assert rgb.shape == (4, 4, 3)
        return results[len(seen_ts) - 1]

    frames = [(np.zeros((4, 4, 3), np.uint8), 10 * k) for k in range(5)]
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        import socket

        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        packets = []

        def send(b: bytes) -> None:
            packets.append(decode(b))
            sock.sendto(b, rx.address)

        assert webcam.stream(frames, detect, send) == 4
        sock.close()
        end = time.monotonic() + 20
        while rx.counters.received < 4 and time.monotonic() < end:
            time.sleep(0.01)
        assert rx.counters.received == 4 and rx.counters.bad == 0 and rx.counters.late == 0
        w, _ = rx.latest()
    assert seen_ts == [0, 10, 20, 30, 40]
    assert [p.frame for p in packets] == sorted({p.frame for p in packets})  # increasing frame numbers
    assert w[ARKIT_52.index("eyeBlinkLeft")] == np.float32(0.8) and w[ARKIT_52.index("jawOpen")] == np.float32(0.1)
