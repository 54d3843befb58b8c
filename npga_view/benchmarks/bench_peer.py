"""Full-resolution draw against GaussianSplattingViewer's OpenGL renderer (github.com/limacv/GaussianSplattingViewer).

    python benchmarks/bench_peer.py --peer PATH/TO/GaussianSplattingViewer [--frames 15] [--size 1360x900]
           [--rounds 2] [--json out.json] [--screenshots DIR]
    npga-view bench --peer PATH ...   (the same figures within the bench run)

Same scene (the demo avatar at its mean expression, SH padded to degree 3 for both), same window size, the same
yaw orbit (`--frames` cameras from -40 to +40 degrees around the head), each renderer in its own glfw window
(its own GL context, so neither sees the other's state), frames alternating ours / peer in one run. A frame is
what a camera move costs each: ours sorts, runs the pre-pass, draws the splats into its float target and presents
it into the window; the peer sorts (its CPU `np.argsort`), uploads the order and draws into the window. Both end
with `glFinish` and a buffer swap. Reported: median ms per frame of each and the ratio peer / ours (> 1: ours is
faster). The peer's code is imported from the given checkout (its `renderer_ogl.py`, `util.py`, `util_gau.py`;
it needs PyOpenGL, PyGLM and plyfile); nothing of it is copied here. Without a checkout the benchmark says so
and exits 0. Under no DISPLAY it starts a private Xvfb (as `npga-view bench --window`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def _orbit(means: np.ndarray, width: int, height: int, frames: int, fov: float = 20.0) -> list:
    """Cameras of a yaw orbit around the framed head, at the default front camera's distance."""
    from npga_core.camera.cameras import direction_vector, frame_points, look_at

    front = frame_points(means, width, height, fov=fov)  # looks at the robust box centre, as below
    eye = -front.rotation.T @ front.world_to_camera[:3, 3]
    lo, hi = np.percentile(np.asarray(means, np.float64), [0.5, 99.5], axis=0)
    centre = 0.5 * (lo + hi)
    distance = float(np.linalg.norm(eye - centre))
    return [look_at(centre + distance * direction_vector((az, 0.0)), centre, (0.0, 1.0, 0.0), fov, width, height)
            for az in np.linspace(-40.0, 40.0, frames)]


def _scene():
    """The demo posed at its mean expression, SH padded to degree 3 (16 coefficients)."""
    from npga_core.files.loading import load_avatar
    from npga_core.model.gaussians import PosedGaussians

    g = load_avatar("demo").pose()
    sh = np.zeros((len(g), 16, 3), np.float32)
    sh[:, : g.sh.shape[1]] = g.sh
    return PosedGaussians(g.means, g.quats, g.scales, g.opacities, sh)


class _Window:
    def __init__(self, glfw, width: int, height: int, title: str):
        self.glfw = glfw
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        self.handle = glfw.create_window(width, height, title, None, None)
        if not self.handle:
            raise RuntimeError("glfw could not open a 4.3 window")

    def current(self) -> None:
        self.glfw.make_context_current(self.handle)
        self.glfw.swap_interval(0)


class Ours:
    def __init__(self, window: _Window, posed, width: int, height: int):
        from npga_view.rendering.gl import window_context
        from npga_view.rendering.renderer import SplatRenderer

        window.current()
        self.window, self.ctx = window, window_context()
        self.r = SplatRenderer(self.ctx, width, height)
        self.r.set_gaussians(posed)
        if self.r.cpu_pass is not None:  # a software GL: the CPU colour pass, ready ~1 s after a window opens
            from npga_view.rendering.cpu_splats import warm_up

            warm_up(wait=True)

    def frame(self, camera) -> dict:
        self.window.current()
        t0 = time.perf_counter()
        self.r.draw(camera)  # as the window: drawn upright, flipped when presented
        self.r.present(self.ctx.screen, background=(0.0, 0.0, 0.0))
        self.ctx.finish()
        ms = (time.perf_counter() - t0) * 1e3
        self.window.glfw.swap_buffers(self.window.handle)
        t = self.r.last_timings
        return {"ms": ms, "points": t.get("points", 0.0), "sort": t.get("sort", 0.0),
                "preprocess": t.get("preprocess", 0.0), "draw": t.get("draw", 0.0)}

    def read(self, width: int, height: int) -> np.ndarray:
        self.window.current()
        data = self.ctx.screen.read(viewport=(0, 0, width, height), components=3)
        return np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1]


class Peer:
    def __init__(self, window: _Window, checkout: Path, posed, width: int, height: int):
        window.current()
        self.window, self.width, self.height = window, width, height
        sys.path.insert(0, str(checkout))
        cwd = os.getcwd()
        os.chdir(checkout)  # it loads its shaders by relative path
        try:
            import renderer_ogl  # type: ignore[import-not-found]
            import util  # type: ignore[import-not-found]
            import util_gau  # type: ignore[import-not-found]

            self.gl, self.util = renderer_ogl.gl, util
            self.r = renderer_ogl.OpenGLRenderer(width, height)
        finally:
            os.chdir(cwd)
        data = util_gau.GaussianData(posed.means.astype(np.float32), posed.quats.astype(np.float32),
                                     posed.scales.astype(np.float32), posed.opacities.reshape(-1, 1),
                                     posed.sh.reshape(len(posed), -1).astype(np.float32))
        self.r.update_gaussian_data(data)
        self.r.set_scale_modifier(1.0)
        self.r.set_render_mod(3)  # its colour mode (SH up to the data's degree)
        self.cam = util.Camera(height, width)

    def frame(self, camera) -> dict:
        gl = self.gl
        self.window.current()
        eye = -camera.rotation.T @ camera.world_to_camera[:3, 3]
        forward = camera.rotation[2]
        self.cam.position = eye.astype(np.float32)
        self.cam.target = (eye + forward).astype(np.float32)
        self.cam.up = (-camera.rotation[1]).astype(np.float32)  # the image's up (OpenCV y points down)
        self.cam.fovy = 2.0 * np.arctan(camera.height / (2.0 * camera.fy))
        t0 = time.perf_counter()
        self.r.update_camera_pose(self.cam)
        self.r.update_camera_intrin(self.cam)
        self.r.sort_and_update(self.cam)
        gl.glClearColor(0.0, 0.0, 0.0, 1.0)
        gl.glClear(gl.GL_COLOR_BUFFER_BIT)
        self.r.draw()
        gl.glFinish()
        ms = (time.perf_counter() - t0) * 1e3
        self.window.glfw.swap_buffers(self.window.handle)
        return {"ms": ms}

    def read(self, width: int, height: int) -> np.ndarray:
        self.window.current()
        gl = self.gl
        gl.glReadBuffer(gl.GL_BACK)
        data = gl.glReadPixels(0, 0, width, height, gl.GL_RGB, gl.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, np.uint8).reshape(height, width, 3)[::-1]


def run(peer: Path | None, width: int, height: int, frames: int, rounds: int, screenshots: Path | None) -> dict | None:
    """The figures, or None (with a message) when the peer's checkout is absent."""
    if peer is None or not (peer / "renderer_ogl.py").is_file():
        print(f"bench_peer: skipped: no GaussianSplattingViewer checkout at {peer} (give --peer PATH or set "
              "NPGA_PEER_GSV)")
        return None
    from npga_view.benchmarks.bench_precision import cpu_name
    from npga_view.benchmarks.bench_window import start_xvfb
    from npga_view.imgui_glfw import glfw
    from npga_view.rendering.gl import prefer_raster_threads, release_current_egl

    xvfb = start_xvfb()
    try:
        release_current_egl()  # a current headless context (the bench's) would make the windows' GLX fail
        prefer_raster_threads()  # as the viewer's window does (the peer, in this process, gets the same count)
        if not glfw.init():
            raise RuntimeError("glfw could not initialise")
        posed = _scene()
        cams = _orbit(posed.means, width, height, frames)
        ours = Ours(_Window(glfw, width, height, "npga-view"), posed, width, height)
        theirs = Peer(_Window(glfw, width, height, "GaussianSplattingViewer"), peer, posed, width, height)
        ours.frame(cams[0]), theirs.frame(cams[0])  # warm-up (shader compilation, first uploads)
        times: dict[str, list[float]] = {"ours": [], "peer": []}
        points: list[float] = []
        parts: dict[str, list[float]] = {"sort": [], "preprocess": [], "draw": []}
        for _ in range(rounds):
            for cam in cams:
                o = ours.frame(cam)
                times["ours"].append(o["ms"])
                points.append(o["points"])
                for k, v in parts.items():
                    v.append(o[k])
                times["peer"].append(theirs.frame(cam)["ms"])
        if screenshots is not None:
            from PIL import Image

            screenshots.mkdir(parents=True, exist_ok=True)
            mid = cams[len(cams) // 2]
            ours.frame(mid), theirs.frame(mid)
            Image.fromarray(ours.read(width, height)).save(screenshots / "ours.png")
            Image.fromarray(theirs.read(width, height)).save(screenshots / "peer.png")
        med = {k: statistics.median(v) for k, v in times.items()}
        res = {"cpu": cpu_name(), "size": [width, height], "frames": frames, "rounds": rounds,
               "raster_threads": os.environ.get("LP_NUM_THREADS"),
               "gaussians": len(posed), "ours_ms": med["ours"], "peer_ms": med["peer"],
               "ours_ms_all": times["ours"], "peer_ms_all": times["peer"],
               "ours_points_fraction": float(np.mean(points)), "peer_over_ours": med["peer"] / med["ours"],
               **{f"ours_{k}_ms": statistics.median(v) for k, v in parts.items()}}
        print(f"{len(posed):,} Gaussians at {width}x{height}, {frames} frames x {rounds} rounds, alternating: "
              f"ours {med['ours']:.0f} ms, peer {med['peer']:.0f} ms per frame (median) -> ours "
              f"{res['peer_over_ours']:.2f}x the peer's speed (points in {res['ours_points_fraction']:.0%} of ours; "
              f"ours: sort {res['ours_sort_ms']:.1f}, pre-pass {res['ours_preprocess_ms']:.1f}, splats "
              f"{res['ours_draw_ms']:.0f} ms, the rest presenting; LP_NUM_THREADS {res['raster_threads']})")
        return res
    finally:
        glfw.terminate()
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait(5)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--peer", type=Path, default=os.environ.get("NPGA_PEER_GSV"),
                   help="a checkout of limacv/GaussianSplattingViewer (default: $NPGA_PEER_GSV)")
    p.add_argument("--size", default="1360x900")
    p.add_argument("--frames", type=int, default=15)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--json", type=Path)
    p.add_argument("--screenshots", type=Path, help="save both windows' middle frame as PNGs here")
    args = p.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    res = run(args.peer, w, h, args.frames, args.rounds, args.screenshots)
    if res is not None and args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0
