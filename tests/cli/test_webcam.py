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


# ------------------------------------------------------------------------------------------ the real command
FAKE_MEDIAPIPE = '''
"""A stand-in for MediaPipe with the calls npga_core.posing.webcam makes (its real API: see the test module)."""
import time
from types import SimpleNamespace


class ImageFormat:
    SRGB = "srgb"


class Image:
    def __init__(self, image_format, data):
        assert image_format == ImageFormat.SRGB and data.ndim == 3 and data.shape[2] == 3
        self.data = data


class FaceLandmarker:
    @classmethod
    def create_from_options(cls, options):
        assert options["output_face_blendshapes"] and options["base_options"]["model_asset_path"]
        return cls()

    def detect_for_video(self, image, timestamp_ms):
        time.sleep(DELAY)
        cats = [SimpleNamespace(index=0, score=0.9, category_name="_neutral"),
                SimpleNamespace(index=25, score=float(image.data.mean()) / 255.0, category_name="jawOpen")]
        return SimpleNamespace(face_blendshapes=[cats])


DELAY = 0.0
tasks = SimpleNamespace(BaseOptions=lambda **k: k,
                        vision=SimpleNamespace(FaceLandmarkerOptions=lambda **k: k,
                                               RunningMode=SimpleNamespace(VIDEO="video"),
                                               FaceLandmarker=FaceLandmarker))
'''


def _video(path, frames: int, level: int) -> None:
    import cv2

    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    assert out.isOpened()
    for _ in range(frames):
        out.write(np.full((48, 64, 3), level, np.uint8))
    out.release()


def _children(pid: int) -> list[int]:
    from pathlib import Path

    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


def _command(tmp_path, video, delay: float):
    import os
    import subprocess
    import sys

    fake = tmp_path / "fake" / "mediapipe"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(FAKE_MEDIAPIPE.replace("DELAY = 0.0", f"DELAY = {delay}"))
    model = tmp_path / "face_landmarker.task"
    model.write_bytes(b"model")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "fake"), os.environ.get("PYTHONPATH", "")]))
    return lambda port: subprocess.Popen(
        [sys.executable, "-m", "npga_view", "webcam", "--face-model", str(model), "--camera", str(video),
         "--port", str(port)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_the_command_streams_a_video_through_the_landmarker(tmp_path):
    """`npga-view webcam` with a video as the camera: the child reads it, the landmarker (a stand-in with
    MediaPipe's calls) sees its RGB frames, and the viewer's receiver gets one packet per frame."""
    video = tmp_path / "grey.avi"
    _video(video, 20, 128)
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        proc = _command(tmp_path, video, 0.0)(rx.address[1])
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        end = time.monotonic() + 10
        while rx.counters.received < 20 and time.monotonic() < end:
            time.sleep(0.02)
        assert rx.counters.received == 20 and rx.counters.bad == 0, (rx.counters, err)
        w, _ = rx.latest()
    assert abs(w[ARKIT_52.index("jawOpen")] - 128 / 255) < 0.02
    assert np.count_nonzero(w) == 1


def test_the_landmarker_process_dies_with_its_parent(tmp_path):
    import os
    import signal

    video = tmp_path / "long.avi"
    _video(video, 600, 100)
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        proc = _command(tmp_path, video, 0.05)(rx.address[1])
        try:
            end = time.monotonic() + 120
            while rx.counters.received < 3 and time.monotonic() < end:
                time.sleep(0.05)
            assert rx.counters.received >= 3, proc.stderr.read() if proc.poll() is not None else "no packets"
            kids = _children(proc.pid)
            assert kids, "the landmarker runs in a child process"
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
            end = time.monotonic() + 20
            while time.monotonic() < end and any(os.path.exists(f"/proc/{k}") and _alive(k) for k in kids):
                time.sleep(0.1)
            assert not any(_alive(k) for k in kids), "the landmarker outlived its parent"
        finally:
            if proc.poll() is None:
                proc.kill()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False
