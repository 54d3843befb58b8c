"""`npga-view webcam --face-model face_landmarker.task [--port P]`: drive a viewer from a webcam.

MediaPipe's face landmarker runs in a child process that dies with this one and sends Live Link Face packets
to the viewer (`npga-view --live-link PORT`, or the Timeline panel's Live Link). Needs the optional extra
(``pip install 'npga-view[webcam]'``) and the model file; without either it prints one line and exits 2.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from npga_core.posing.livelink import DEFAULT_PORT
    from npga_core.posing.webcam import MODEL_URL

    p.add_argument("--face-model", type=Path, required=True,
                   help=f"MediaPipe's face_landmarker.task (download it from {MODEL_URL}; never fetched here)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"the viewer's Live Link port (default {DEFAULT_PORT})")
    p.add_argument("--host", default="127.0.0.1", help="the viewer's address (default 127.0.0.1)")
    p.add_argument("--camera", default="0", help="camera index, or a video file to replay (default 0)")


def run(args: argparse.Namespace) -> int:
    """Check the requirements (one line, exit 2 when missing), then stream until the camera ends or Ctrl-C."""
    import multiprocessing as mp
    import os

    from npga_core.posing.webcam import problem, worker

    def fail(msg: str) -> int:
        print(f"npga-view webcam: error: {msg}", file=sys.stderr)
        return 2

    msg = problem(args.face_model)
    if msg is not None:
        return fail(msg)
    if not 0 < args.port < 65536:
        return fail(f"--port {args.port} is not a port number")
    camera: int | str = int(args.camera) if args.camera.isdigit() else args.camera
    if isinstance(camera, str) and not Path(camera).is_file():
        return fail(f"--camera {camera}: neither a camera index nor a video file")
    ctx = mp.get_context("spawn")
    proc = ctx.Process(target=worker, args=(str(args.face_model), args.host, args.port, camera, os.getpid()),
                       name="npga-webcam", daemon=True)
    proc.start()
    print(f"sending Live Link Face packets from camera {camera} to {args.host}:{args.port} (Ctrl-C stops)")
    signal.signal(signal.SIGTERM, lambda *_: proc.terminate())
    try:
        proc.join()
    except KeyboardInterrupt:
        proc.terminate()
        proc.join(timeout=5)
    if proc.exitcode in (0, -signal.SIGTERM):
        return 0
    return 2 if proc.exitcode == 2 else 1  # 2: the child printed its one-line error
