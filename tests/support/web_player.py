"""Running LAM's web player in a real browser for tests: npga_view/web/ (the project's page) served on 127.0.0.1
with the player installed by npm from npga_view/web/package.json into the ignored folder .web-player/, opened in
Debian's headless `chromium` (WebGL through SwiftShader, every host but 127.0.0.1 unresolvable), the stable frame
POSTed back by the page.

`npm_player()` and `chromium()` skip the calling test with a reason where npm or chromium is missing (or the
install fails); `shoot(...)` returns the player's frame and its camera.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "npga_view" / "web"
INSTALL = ROOT / ".web-player"
PLAYER = "gaussian-splat-renderer-for-lam"
NPM_TIMEOUT_S = 180


def npm_player() -> Path:
    """The player's build folder, installed by npm (pinned by npga_view/web/package.json) into .web-player/."""
    npm = shutil.which("npm")
    if npm is None:
        pytest.skip("npm is not installed (apt-get install -y npm): the page needs LAM's player from npm")
    pinned = json.loads((PAGE / "package.json").read_text())["dependencies"][PLAYER]
    build = INSTALL / "node_modules" / PLAYER / "build"
    installed = INSTALL / "node_modules" / PLAYER / "package.json"
    if not (installed.is_file() and json.loads(installed.read_text()).get("version") == pinned):
        INSTALL.mkdir(exist_ok=True)
        shutil.copy(PAGE / "package.json", INSTALL / "package.json")
        try:
            r = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--ignore-scripts", "--no-save"],
                               cwd=INSTALL, capture_output=True, text=True, timeout=NPM_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pytest.skip(f"npm install {PLAYER}@{pinned} took more than {NPM_TIMEOUT_S} s")
        if r.returncode != 0 or not installed.is_file():
            pytest.skip(f"npm install {PLAYER}@{pinned} failed: {(r.stderr or r.stdout).strip()[-300:]}")
    return build


def chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("chromium is not installed (apt-get install -y chromium): the page runs in a real browser")


class PageServer:
    """The page, the player's build folder and named files on 127.0.0.1; POST /report is kept in `.report`."""

    def __init__(self, build: Path, files: dict[str, Path]):
        self.requests: list[str] = []
        self.log: list[str] = []
        self.report: dict | None = None
        self.done = threading.Event()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                path = self.path.split("?", 1)[0]
                server.requests.append(path)
                if path in ("/", "/index.html"):
                    src = PAGE / "index.html"
                elif path == "/page.js":
                    src = PAGE / "page.js"
                elif path.startswith("/player/") and "/" not in path[len("/player/"):]:
                    src = build / path[len("/player/"):]
                else:
                    src = files.get(path.lstrip("/"), Path("/nonexistent"))
                if not src.is_file():
                    self.send_error(404)
                    return
                data = src.read_bytes()
                kind = {".html": "text/html", ".js": "text/javascript", ".zip": "application/zip",
                        ".map": "application/json"}.get(src.suffix, "application/octet-stream")
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def do_POST(self) -> None:  # noqa: N802
                n = int(self.headers.get("Content-Length", "0"))
                body = self.rfile.read(n)
                self.send_response(204)
                self.end_headers()
                doc = json.loads(body)
                if self.path == "/report" and "log" in doc:
                    server.log.append(str(doc["log"]))
                elif self.path == "/report" and server.report is None:
                    server.report = doc
                    server.done.set()

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.httpd.server_address[1]
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def shoot(zip_path: Path, weights: dict[str, float], camera: dict[str, list[float]], width: int, height: int,
          profile: Path, timeout_s: float = 100.0) -> dict:
    """The player's stable frame of `zip_path` at ARKit `weights` from `camera` ({position, target}): a dict with
    `image` (H, W, 3) uint8 top row first, `view` and `projection` (4x4 numpy, three.js), `fov`, `aspect`,
    `stable`, `requests` (the paths the browser asked for), `seconds`."""
    build = npm_player()
    browser = chromium()
    server = PageServer(build, {"avatar.zip": zip_path})
    query = "&".join(f"{k}={quote(v)}" for k, v in {
        "zip": f"http://127.0.0.1:{server.port}/avatar.zip", "weights": json.dumps(weights),
        "camera": json.dumps(camera), "width": str(width), "height": str(height),
        "report": f"http://127.0.0.1:{server.port}/report"}.items())
    args = [browser, "--headless=new", "--no-sandbox", "--no-first-run", "--disable-extensions",
            "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
            "--force-device-scale-factor=1", f"--window-size={width},{height}", f"--user-data-dir={profile}",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--disable-background-networking",
            "--enable-logging=stderr",
            f"http://127.0.0.1:{server.port}/index.html?{query}"]
    t0 = time.monotonic()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        finished = server.done.wait(timeout_s)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # chromium's own process group (start_new_session), nothing else
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        server.close()
        remove_singleton_folder(profile)
    if not finished:
        raise AssertionError(f"the page sent no frame within {timeout_s:.0f} s; requests {server.requests}; "
                             f"page: {server.log[-8:]}; chromium: {err[-600:]}")
    rep = server.report
    assert rep is not None
    if "error" in rep:
        raise AssertionError(f"the page failed: {rep['error'][:600]}")
    w, h = rep["width"], rep["height"]
    rgba = np.frombuffer(base64.b64decode(rep["rgba"]), np.uint8).reshape(h, w, 4)
    return {"image": np.ascontiguousarray(rgba[::-1, :, :3]), "view": np.asarray(rep["view"]).reshape(4, 4).T,
            "projection": np.asarray(rep["projection"]).reshape(4, 4).T, "fov": rep["fov"], "aspect": rep["aspect"],
            "stable": rep["stable"], "frames": rep["frames"], "requests": list(server.requests),
            "seconds": time.monotonic() - t0}


def opencv_camera(shot: dict, width: int, height: int) -> dict:
    """npga-view's camera JSON (OpenCV: x right, y down, z forward) of the player's three.js camera."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    fy = (height / 2.0) / np.tan(np.radians(shot["fov"]) / 2.0)
    return {"width": width, "height": height, "fx": fy, "fy": fy, "cx": width / 2.0, "cy": height / 2.0,
            "world_to_camera": (flip @ shot["view"]).tolist()}


def _session_dying_with_parent() -> None:
    """In a child before exec: a process group of its own (killed as one) that gets SIGTERM when the test dies."""
    from tests.support.xvfb import _die_with_parent

    _die_with_parent()


def chromium_args(url: str, width: int, height: int, profile: Path) -> list[str]:
    """Headless chromium on SwiftShader WebGL that can reach 127.0.0.1 only."""
    return [chromium(), "--headless=new", "--no-sandbox", "--no-first-run", "--disable-extensions",
            "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
            "--force-device-scale-factor=1", f"--window-size={width},{height}", f"--user-data-dir={profile}",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--disable-background-networking", url]


def start(args: list[str], env: dict | None = None, stdout: int = subprocess.DEVNULL) -> subprocess.Popen:
    """A child in its own process group that dies with the test process (`stop` ends it by its id)."""
    return subprocess.Popen(args, stdout=stdout, stderr=subprocess.PIPE, env=env, start_new_session=True,
                            preexec_fn=_session_dying_with_parent)


def remove_singleton_folder(profile: Path) -> None:
    """Remove the folder a stopped chromium with user data in `profile` made in the system's temp folder for its
    singleton socket (the profile's SingletonSocket links into it; a browser ended by a signal leaves it)."""
    link = Path(profile) / "SingletonSocket"
    if link.is_symlink():
        folder = Path(os.readlink(link)).parent
        if folder.name.startswith("org.chromium.Chromium."):
            shutil.rmtree(folder, ignore_errors=True)


def stop(proc: subprocess.Popen) -> str:
    """End a child started by `start` (its own process group, nothing else); its stderr. A browser's
    singleton folder is removed (`remove_singleton_folder`)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    args = proc.args if isinstance(proc.args, list) else []
    profile = next((str(a).split("=", 1)[1] for a in args if str(a).startswith("--user-data-dir=")), None)
    if profile is not None:
        remove_singleton_folder(Path(profile))
    return proc.stderr.read().decode(errors="replace") if proc.stderr else ""


class Collector:
    """POSTs of the page's `report=` on 127.0.0.1 (another port than the page's): frames decoded as they come."""

    def __init__(self) -> None:
        self.frames: list[dict] = []
        self.log: list[str] = []
        self.errors: list[str] = []
        self.cond = threading.Condition()
        collector = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:
                pass

            def do_POST(self) -> None:  # noqa: N802
                body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
                self.send_response(204)
                self.end_headers()
                doc = json.loads(body)
                with collector.cond:
                    if "log" in doc:
                        collector.log.append(str(doc["log"]))
                    elif "error" in doc:
                        collector.errors.append(str(doc["error"]))
                    else:
                        rgba = np.frombuffer(base64.b64decode(doc.pop("rgba")), np.uint8)
                        doc["image"] = rgba.reshape(doc["height"], doc["width"], 4)[::-1, :, :3]
                        collector.frames.append(doc)
                    collector.cond.notify_all()

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/report"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def wait_for(self, test: Any, timeout_s: float, what: str) -> dict:
        """The first frame (from now on) for which `test(frame)` holds; AssertionError after `timeout_s`."""
        with self.cond:
            seen = len(self.frames)
            end = time.monotonic() + timeout_s
            while True:
                for f in self.frames[seen:]:
                    if test(f):
                        return f
                seen = len(self.frames)
                left = end - time.monotonic()
                if left <= 0 or self.errors:
                    raise AssertionError(f"no frame with {what} within {timeout_s:.0f} s ({len(self.frames)} frames; "
                                         f"page errors {self.errors[-2:]}; page log {self.log[-4:]})")
                self.cond.wait(min(left, 1.0))

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def masked_psnr(a: np.ndarray, b: np.ndarray, background: float = 255.0, tol: float = 2.0) -> tuple[float, float]:
    """PSNR (dB) of two uint8 images over the pixels where either differs from the background, and that share."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    mask = (np.abs(a - background).max(axis=2) > tol) | (np.abs(b - background).max(axis=2) > tol)
    mse = float(np.mean((a - b)[mask] ** 2)) if mask.any() else 0.0
    return (99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)), float(mask.mean())
