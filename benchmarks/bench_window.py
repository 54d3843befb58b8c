"""Frame rate of the real window while the dynamics worker is busy (the UI must not stall).

Runs the viewer under the current DISPLAY (or a private Xvfb), plays a sequence so that the pose worker
is busy all the time, and reports UI frame times with and without the worker busy, the dynamics time per
pose, and how many poses reached the screen.

    python benchmarks/bench_window.py [--gaussians 20000 80000] [--seconds 8] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _avatar(n: int, folder: Path) -> tuple[str, str]:
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.synthetic import make_synthetic_avatar

    a = make_synthetic_avatar(n, seed=0)
    path = folder / f"syn{n}.npga"
    save_avatar(a, path)
    t = np.arange(250)
    codes = np.stack([a.expression.from_sliders(np.array([2 * np.sin(i / 6), 2 * np.cos(i / 9)])) for i in t])
    seq = folder / "seq.npzseq"
    ExpressionSequence(codes.astype(np.float32), 25.0).save(seq)
    return str(path), str(seq)


def _frames(app, seconds: float) -> np.ndarray:
    times = []
    end = time.perf_counter() + seconds
    last = time.perf_counter()
    while time.perf_counter() < end:
        app.step()
        now = time.perf_counter()
        times.append(now - last)
        last = now
    return np.array(times[1:]) * 1000.0


def measure(avatar: str, sequence: str | None, seconds: float, size: tuple[int, int]) -> dict:
    from npga_view.app import ViewerApp

    app = ViewerApp(*size, vsync=False, threads=2, remember_recent=False)
    try:
        app.open_avatar(avatar)
        while not app.first_pose_shown:
            app.step()
        idle = _frames(app, min(3.0, seconds))
        # camera orbiting: every frame re-sorts and redraws, no dynamics
        orbit_times = []
        for _ in range(20):
            app.state.camera.orbit(2.0, 0.0)
            t0 = time.perf_counter()
            app.step()
            orbit_times.append((time.perf_counter() - t0) * 1000)
        out = {"gaussians": len(app.avatar), "size": list(size), "idle_frame_ms_median": float(np.median(idle)),
               "orbit_frame_ms_median": float(np.median(orbit_times))}
        if sequence and app.avatar.dynamics is not None:
            app.open_sequence(sequence)
            app.state.timeline.playing = True
            app.playback.reset_stats()
            poses0 = app.playback.skipped
            busy = _frames(app, seconds)
            shown = len(app.playback._shown_times)
            out.update({
                "busy_frame_ms_median": float(np.median(busy)),
                "busy_frame_ms_p95": float(np.percentile(busy, 95)),
                "busy_frame_ms_max": float(busy.max()),
                "busy_ui_fps": float(1000.0 / np.mean(busy)),
                "dynamics_ms_F": app.info.timings.get("F"),
                "dynamics_ms_G": app.info.timings.get("G"),
                "poses_shown_per_s": shown / seconds,
                "sequence_frames_skipped": app.playback.skipped - poses0,
                "draw_ms": app.info.timings.get("draw"),
            })
        return out
    finally:
        app.close()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gaussians", type=int, nargs="*", default=[20000, 80000])
    p.add_argument("--demo", action="store_true", help="also measure the bundled demo avatar")
    p.add_argument("--seconds", type=float, default=8.0)
    p.add_argument("--size", default="1360x900")
    p.add_argument("--json")
    args = p.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    proc = None
    if not os.environ.get("DISPLAY"):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from xvfb import start_xvfb

        proc, disp = start_xvfb(1920, 1200)
        os.environ["DISPLAY"] = disp
    results = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for n in args.gaussians:
                path, seq = _avatar(n, Path(tmp))
                results.append(measure(path, seq, args.seconds, size))
                print(json.dumps(results[-1]), flush=True)
            if args.demo:
                from npga_core.files.loading import DEMO_DIR

                seqs = sorted((DEMO_DIR / "sequences").glob("*.npzseq"))
                results.append(measure("demo", str(seqs[0]) if seqs else None, args.seconds, size))
                print(json.dumps(results[-1]), flush=True)
    finally:
        if proc is not None:
            proc.terminate()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
