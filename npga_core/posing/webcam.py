"""A webcam as a Live Link Face source: MediaPipe's face landmarker (blendshape output) on camera frames, each
result sent as a Live Link Face packet (`npga_core.posing.livelink.encode`) to the viewer's receiver.

MediaPipe is an optional dependency (``pip install 'npga-view[webcam]'``), imported only here and only when a
stream starts; the model file (``face_landmarker.task``) is given by the user and never downloaded. The API used
(google-ai-edge/mediapipe, mediapipe/tasks/python/vision/face_landmarker.py): ``FaceLandmarkerOptions(
base_options=BaseOptions(model_asset_path=...), running_mode=VIDEO, num_faces=1, output_face_blendshapes=True)``,
``FaceLandmarker.create_from_options``, ``detect_for_video(mp.Image(image_format=SRGB, data=rgb), timestamp_ms)``
with increasing timestamps; the result's ``face_blendshapes`` holds per face a list of ``Category`` (``score``,
``category_name``), ``_neutral`` first and then ARKit's 52 names in camelCase (its ``Blendshapes`` enum).
"""

from __future__ import annotations

import importlib.util
import socket
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from npga_core.files.blendshape_names import ARKIT_52, canonical_arkit
from npga_core.posing.livelink import VALUES, encode

MODEL_URL = "https://developers.google.com/mediapipe/solutions/vision/face_landmarker"
INSTALL = "pip install 'npga-view[webcam]'"
_INDEX = {n: i for i, n in enumerate(ARKIT_52)}


def problem(model: str | Path | None) -> str | None:
    """One line saying what is missing to run the webcam source (the model file, then MediaPipe), else None."""
    if model is None or not Path(model).is_file():
        return (f"no face landmarker model at {model}: download face_landmarker.task from {MODEL_URL} and give it "
                "with --face-model")
    if importlib.util.find_spec("mediapipe") is None:
        return f"MediaPipe is not installed: {INSTALL} (or pip install mediapipe)"
    return None


def values_of(result: Any) -> np.ndarray | None:
    """The 61 Live Link Face values (52 shapes in `ARKIT_52` order, then 9 angles, left 0) of the first face
    of a FaceLandmarkerResult; None when no face was found. Unknown categories and ``_neutral`` are skipped."""
    faces = getattr(result, "face_blendshapes", None) or []
    if not faces:
        return None
    out = np.zeros(VALUES, np.float32)
    for cat in faces[0]:
        name = canonical_arkit(str(getattr(cat, "category_name", "") or ""))
        score = float(getattr(cat, "score", 0.0))
        if name is not None and np.isfinite(score):
            out[_INDEX[name]] = min(max(score, 0.0), 1.0)
    return out


def stream(frames: Iterable[tuple[np.ndarray, int]], detect: Callable[[np.ndarray, int], Any],
           send: Callable[[bytes], object], fps: int = 60, subject: str = "webcam") -> int:
    """Detect on each (RGB frame, timestamp ms) and send a packet per frame with a face; returns the count sent.
    Frame numbers are the frames of the day at `fps` (as Live Link Face counts them), increasing."""
    sent, last = 0, -1
    for rgb, t_ms in frames:
        values = values_of(detect(rgb, t_ms))
        if values is None:
            continue
        now = time.time()
        frame = max(int((now % 86400.0) * fps), last + 1)
        last = frame
        send(encode(values, frame, fps=fps, subject=subject))
        sent += 1
    return sent


def camera_frames(camera: int | str, max_frames: int | None = None) -> Iterator[tuple[np.ndarray, int]]:
    """RGB frames and increasing millisecond timestamps from an OpenCV capture (a camera index or a video)."""
    import cv2

    cap = cv2.VideoCapture(camera)
    if not cap.isOpened():
        raise RuntimeError(f"cannot open camera {camera}")
    t0, last, n = time.monotonic(), -1, 0
    try:
        while max_frames is None or n < max_frames:
            ok, bgr = cap.read()
            if not ok:
                return
            t_ms = max(int((time.monotonic() - t0) * 1000), last + 1)
            last, n = t_ms, n + 1
            yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), t_ms
    finally:
        cap.release()


def landmarker(model: str | Path) -> Callable[[np.ndarray, int], Any]:
    """MediaPipe's face landmarker in video mode with blendshapes, as a detect(rgb, t_ms) function."""
    import mediapipe as mp

    vision = mp.tasks.vision
    options = vision.FaceLandmarkerOptions(base_options=mp.tasks.BaseOptions(model_asset_path=str(model)),
                                           running_mode=vision.RunningMode.VIDEO, num_faces=1,
                                           output_face_blendshapes=True)
    task = vision.FaceLandmarker.create_from_options(options)

    def detect(rgb: np.ndarray, t_ms: int) -> Any:
        return task.detect_for_video(mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb)),
                                     t_ms)

    return detect


def worker(model: str, host: str, port: int, camera: int | str, parent_pid: int) -> None:
    """The child process: dies with its parent (`lifetime.start_parent_watch`), streams until the camera ends."""
    import sys

    from npga_core.posing.lifetime import start_parent_watch

    start_parent_watch(parent_pid, [])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        stream(camera_frames(camera), landmarker(model), lambda b: sock.sendto(b, (host, port)))
    except (RuntimeError, ValueError, OSError) as e:  # no camera, a model MediaPipe refuses, a bad address
        print(f"npga-view webcam: error: {' '.join(str(e).split())}", file=sys.stderr)
        sys.exit(2)
    finally:
        sock.close()
