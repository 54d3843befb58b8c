"""`npga-view bench --window`: what a person sees in the real window, measured on its pixels.

Drives the real `ViewerApp` (under the current DISPLAY, or a private Xvfb) at 1360x900 and reads the splat
view's pixels back every UI frame. For each avatar it measures, in the same run, frame-budgeted adaptive
drawing with live images from the merged level-of-detail cloud ("budget + LOD", the default), without it
("budget") and budgeting off (the behaviour before both):

- first pixels: from opening the window to the first frame whose view is not empty;
- slider move (PC 1 by +-1 sd, as the Expression panel sets it) -> first changed pixels, -> the exact
  full-resolution image on screen and, for an avatar with a CNN (shown refined by default), -> the CNN's image
  of it (median and p90 over the moves);
- orbit (2 degrees per UI frame): complete images per second (distinct view images) and UI frames per second,
  then the time from the last orbit step to the exact full-resolution image;
- live playback of a 25 fps sequence: distinct view images per second and the playback's achieved rate;
- baked playback: distinct view images per second;
both with the side panel scrolled to the Timeline (as a person who pressed Play sees it: its readout changes with
the images). The Live Link stream's figures are taken with the panel at its Live Link part.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_view.actions import Bake
from npga_view.frame_profile import SECTIONS
from npga_view.rendering.draw_plan import Target
from npga_view.rendering.renderer import camera_key
from npga_view.rendering.scheduler import DrawScheduler, ImageJob

if TYPE_CHECKING:
    from npga_core.model.avatar import Avatar
    from npga_core.model.expression import ExpressionSpace
    from npga_core.posing.livelink import LiveLinkReceiver
    from npga_view.app import ViewerApp

SIZE = (1360, 900)


def start_xvfb() -> subprocess.Popen | None:
    """A private Xvfb for the benchmarks when there is no DISPLAY (None when one is set); the caller stops it."""
    if os.environ.get("DISPLAY"):
        return None
    exe = shutil.which("Xvfb")
    if exe is None:
        raise RuntimeError("no DISPLAY and no Xvfb (apt-get install xvfb)")
    for n in range(150, 200):
        if Path(f"/tmp/.X{n}-lock").exists() or Path(f"/tmp/.X11-unix/X{n}").exists():
            continue
        proc = subprocess.Popen([exe, f":{n}", "-screen", "0", "1920x1200x24", "-nolisten", "tcp", "-noreset"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(100):
            if Path(f"/tmp/.X11-unix/X{n}").exists():
                os.environ["DISPLAY"] = f":{n}"
                return proc
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        proc.kill()
    raise RuntimeError("could not start Xvfb")


class _Watcher:
    """Steps the app and fingerprints the splat view's pixels after every UI frame."""

    def __init__(self, app: ViewerApp) -> None:
        self.app = app
        self.last: tuple[int, int] | None = None  # fingerprint of the last view image
        self.last_changed = False
        self.frames: list[dict[str, float]] | None = None  # while recording: the UI frames' sections + read-back

    def step(self) -> bool:
        """One UI frame; True if the view's pixels changed."""
        self.app.step()
        t0 = time.perf_counter()
        img = self.app.read_window(viewport_only=True)
        if self.frames is not None:
            self.frames.append({**self.app.profile.last, "readback": (time.perf_counter() - t0) * 1e3})
        fp = (zlib.crc32(img[::4, ::4].tobytes()), int(img.max()))
        changed = fp != self.last
        self.last = fp
        self.last_changed = changed
        return changed

    def until_changed(self, t0: float, timeout: float = 60.0) -> float | None:
        """Step until the view's pixels change; seconds since `t0` (when the change was caused), or None."""
        while time.perf_counter() - t0 < timeout:
            if self.step():
                return time.perf_counter() - t0
        return None

    def until(self, cond, timeout: float) -> float | None:
        """Step until `cond()`; seconds it took, or None on timeout."""
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < timeout:
            self.step()
            if cond():
                return time.perf_counter() - t0
        return None


def _profiled(w: _Watcher, key: str, dt: float) -> dict:
    """The recorded frames' median ms per section (`FrameProfile`) and the bench's own read-back, and the UI rate
    without that read-back (a person's window does not read its pixels back)."""
    frames, w.frames = w.frames or [], None
    if not frames:
        return {}
    medians = {s: float(np.median([f.get(s, 0.0) for f in frames])) for s in (*SECTIONS, "readback")}
    readback_s = sum(f["readback"] for f in frames) / 1e3
    return {f"{key}_frame_ms": medians, f"{key}_ui_fps_own": len(frames) / max(dt - readback_s, 1e-6)}


def _input_event() -> None:
    """Wake the window's loop as a real input event would (it may be waiting up to 1/30 s for input when idle;
    the bench changes the state directly, which sends no event)."""
    from npga_view.imgui_glfw import glfw

    glfw.post_empty_event()


def _exact(app) -> bool:
    eng = app.engine
    return (app.draws.settled and not app.poses.preview and not app.poses.canonical
            and (eng is None or eng.pending is None))


def _stats(values: Sequence[float | None]) -> dict:
    v = [x for x in values if x is not None]
    if not v:
        return {"median": None, "p90": None, "n": 0}
    return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)), "n": len(v)}


def warm_up(avatar: str, timeout: float = 600.0) -> str:
    """Open the avatar once and wait until the worker's preview model is fitted (it is cached per avatar), so
    that the measured runs all find it; returns the preview model's state."""
    from npga_view.app import ViewerApp

    app = ViewerApp(640, 480, vsync=False, threads=2, remember_recent=False)
    try:
        app.open_avatar(avatar)
        t0 = time.perf_counter()
        state = ""
        while time.perf_counter() - t0 < timeout:
            app.step()
            eng = app.engine
            state = str(eng.status.get("preview_model", "")) if eng is not None else "off"
            if app.poses.first_pose_shown and state not in ("", "pending", "geometric") \
                    and not state.startswith("fitting"):
                break
        return state
    finally:
        app.close()


class UnbudgetedScheduler(DrawScheduler):
    """The window's drawing before frame budgets (what `measure(budget=False)` compares with): every change of
    the view drawn at once at full resolution inside the frame, from every Gaussian."""

    def _frame(self, camera, mode, content_version, interacting, exact_content, now, frame_start) -> bool:
        target = Target(camera_key(camera), mode, content_version)
        self._target = target
        self._live = interacting
        shown = self._shown
        if shown is not None and shown.target == target and shown.scale >= 1.0:
            return False
        image = ImageJob(target, 1.0, exact_content, False, self.renderer)
        self._start(camera, mode, image, frame_start if now is None else now)
        return self._continue(math.inf, frame_start)


def measure(avatar: str, sequence: str | None, budget: bool, moves: int = 6, seconds: float = 6.0,
            lod: bool = True, precision: str = "auto") -> dict:
    """All figures for one avatar with budgeting on or off, live images from the merged cloud (`lod`) or not."""
    from npga_view.app import ViewerApp

    t_open = time.perf_counter()
    app = ViewerApp(*SIZE, vsync=False, threads=2, remember_recent=False, level_of_detail=lod and budget,
                    scheduler=DrawScheduler if budget else UnbudgetedScheduler, precision=precision)
    if not budget:  # the window before budgeting: a blank view until the first pose, exact poses only in
        app.view.pacing.idle_wait_s = 0.0  # playback, and a loop that spins instead of waiting for input
        app.poses.canonical_first = app.poses.playback_previews = False
    w = _Watcher(app)
    out: dict = {"avatar": Path(avatar).name if avatar != "demo" else "demo", "budget": budget, "lod": budget and lod,
                 "precision": precision}
    try:
        app.state.show_stats = False  # the overlay's figures change every frame: only the splats are watched
        app.open_avatar(avatar)
        out["gaussians"] = len(cast("Avatar", app.avatar))
        w.until(lambda: int(app.read_window(viewport_only=True).max()) > 0, 120)
        out["first_pixels_s"] = time.perf_counter() - t_open
        w.until(lambda: _exact(app), 300)
        out["first_exact_s"] = time.perf_counter() - t_open
        # slider moves
        first, exact, refined = [], [], []
        cnn = app.refining.refiner.has_cnn and app.state.use_cnn  # the window shows the CNN's image when exact
        for k in range(moves):
            w.step()
            app.state.follow_sequence = False
            app.state.sliders[0] += 1.0 if k % 2 == 0 else -1.0
            _input_event()  # as the mouse event of a real slider move does, wake a window waiting for input
            t0 = time.perf_counter()
            first.append(w.until_changed(t0))
            done = w.until(lambda: _exact(app), 120)
            exact.append(None if done is None else time.perf_counter() - t0)
            if cnn:
                done = w.until(lambda: _exact(app) and app.refining.shown == "refined", 120)
                refined.append(None if done is None else time.perf_counter() - t0)
        out["slider_changed_s"] = _stats(first)
        out["slider_exact_s"] = _stats(exact)
        out["slider_refined_s"] = _stats(refined)
        # orbit
        frames0, images, t0 = app.frames, 0, time.perf_counter()
        w.frames = []
        while time.perf_counter() - t0 < seconds:
            app.state.camera.orbit(2.0, 0.0)
            images += w.step()
        dt = time.perf_counter() - t0
        out["orbit_images_per_s"] = images / dt
        out["orbit_ui_fps"] = (app.frames - frames0) / dt
        out.update(_profiled(w, "orbit", dt))
        out["orbit_scale"] = app.draws.scale
        out["orbit_merged"] = app.draws.shown_merged
        t0 = time.perf_counter()
        done = w.until(lambda: _exact(app), 120)
        out["orbit_exact_after_s"] = None if done is None else time.perf_counter() - t0
        if sequence and cast("Avatar", app.avatar).dynamics is not None:
            if not app.open_sequence(sequence):
                return {**out, "error": "; ".join(app.state.errors)}
            out.update(_playback(app, w, seconds, baked=False))
            app.state.timeline.playing = False
            app.state.actions.append(Bake())
            w.until(lambda: app.bakes.state() == "ready", 300)
            out.update(_playback(app, w, seconds, baked=True))
        return out
    finally:
        app.close()


def _playback(app, w: _Watcher, seconds: float, baked: bool) -> dict:
    """Playback with the side panel at the Timeline, as a person who pressed Play there sees it (its frame slider
    and readout change with the images)."""
    tl = app.state.timeline
    tl.playing, tl.time_s = True, 0.0
    app.state.follow_sequence = True
    app.panels.scroll_side()
    for _ in range(3):  # frames asked for before the start are not counted
        w.step()
    app.poses.playback.reset_stats()
    images, frames0, t0 = 0, app.frames, time.perf_counter()
    w.frames = []
    while time.perf_counter() - t0 < seconds:
        images += w.step()
    dt = time.perf_counter() - t0
    tl.playing = False
    key = "baked" if baked else "live"
    return {f"{key}_images_per_s": images / dt, f"{key}_achieved_fps": app.poses.playback.achieved_fps(),
            f"{key}_ui_fps": (app.frames - frames0) / dt, f"{key}_skipped": app.poses.playback.skipped,
            **_profiled(w, key, dt)}


def _synthetic(n: int, folder: Path) -> tuple[str, str]:
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.sequences import ExpressionSequence
    from npga_core.model.synthetic import make_synthetic_avatar

    a = make_synthetic_avatar(n, seed=0)
    path = folder / f"syn{n // 1000}k.npga"
    save_avatar(a, path)
    t = np.arange(200)
    ex = cast("ExpressionSpace", a.expression)  # a synthetic avatar has one
    codes = np.stack([ex.from_sliders(np.array([2 * np.sin(i / 6), 2 * np.cos(i / 9)])) for i in t])
    seq = folder / f"seq{n}.npzseq"
    ExpressionSequence(codes.astype(np.float32), 25.0).save(seq)
    return str(path), str(seq)


#: A busy process for `--beside-load`: spins until its deadline or until its parent is gone (it never outlives
#: the bench), checking both every ~10 ms of work.
_HOG = ("import os, sys, time\n"
        "parent, end = int(sys.argv[1]), time.monotonic() + float(sys.argv[2])\n"
        "while time.monotonic() < end and os.getppid() == parent:\n"
        "    sum(range(100000))\n")
HOG_LIMIT_S = 3600.0  # the longest a busy process runs (a bench of every case takes minutes)


def start_load(n: int) -> list[subprocess.Popen]:
    """`n` busy processes (bounded: `HOG_LIMIT_S`, and they end when this process does)."""
    return [subprocess.Popen([sys.executable, "-c", _HOG, str(os.getpid()), str(HOG_LIMIT_S)],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for _ in range(n)]


def stop_load(procs: list[subprocess.Popen]) -> None:
    """End the busy processes this bench started (by their handles) and reap them."""
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run(gaussians: list[int], demo: bool, json_path: Path | None, moves: int = 6, seconds: float = 6.0,
        precisions: tuple[str, ...] | None = None, avatars: Sequence[str] = (), beside_load: int = 0) -> list[dict]:
    """`measure_all` on an idle machine and, with `beside_load` N > 0, again beside N busy processes of its own
    (each row's avatar says which); one table."""
    results: list[dict] = []
    lives: list[dict] = []
    proc = start_xvfb()  # one display for every pass
    try:
        for load in ([0, beside_load] if beside_load > 0 else [0]):
            hogs = start_load(load)
            try:
                r, lv = _measure_all(gaussians, demo, moves, seconds, precisions, avatars)
            finally:
                stop_load(hogs)
            tag = f" (beside {load} busy)" if load else (" (idle)" if beside_load else "")
            for row in r + lv:
                row["avatar"] += tag
                row["beside_load"] = load
            results += r
            lives += lv
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
    if json_path is not None:
        json_path.write_text(json.dumps(results + lives, indent=1))
    print(table(results))
    print(profile_table(results))
    for live in lives:
        print(json.dumps(live))
        print(live_link_table(live))
    return results


def _measure_all(gaussians: list[int], demo: bool, moves: int, seconds: float,
                 precisions: tuple[str, ...] | None, avatars: Sequence[str]) -> tuple[list[dict], list[dict]]:
    """The rows of the demo, the given avatars and synthetic avatars of the given sizes (budgeting on with and
    without the merged live cloud, and off), and their Live Link rows. With `precisions` (e.g. fp32 bf16): the
    default drawing only, once per precision of the exact dynamics, alternating in the same run."""
    from npga_core.files.loading import DEMO_DIR

    results, lives = [], []
    with tempfile.TemporaryDirectory() as tmp:
        cases = []
        if demo:
            demo_seq = DEMO_DIR / "sequences" / "talking.npzseq"
            cases.append(("demo", str(demo_seq) if demo_seq.is_file() else None))
        cases += [(str(a), None) for a in avatars]
        cases += [_synthetic(n, Path(tmp)) for n in gaussians]
        for avatar, seq in cases:
            print(f"warm-up {avatar}: preview model {warm_up(avatar)}", flush=True)
            modes = [(True, True, p) for p in precisions] if precisions else \
                [(True, True, "auto"), (True, False, "auto"), (False, False, "auto")]
            for budget, lod, precision in modes:
                results.append(measure(avatar, seq, budget, moves, seconds, lod, precision))
                print(json.dumps(results[-1]), flush=True)
        for avatar in (["demo"] if demo else []) + [str(a) for a in avatars]:  # #25: Live Link -> pixels
            lives.append(measure_live_link(avatar, seconds=seconds))
    return results, lives


def profile_table(results: list[dict]) -> str:
    """A markdown table of the UI frames while orbiting and playing: UI rate with and without the bench's own
    read-back, and the median ms of each section of a frame (`FrameProfile`)."""
    rows = ["| avatar | drawing | while | UI fps | UI fps without read-back | "
            + " | ".join(f"{s} ms" for s in SECTIONS) + " | read-back ms |",
            "|---|---|---|---:|---:|" + "---:|" * (len(SECTIONS) + 1)]
    for r in results:
        drawing = ("budget + LOD" if r.get("lod") else "budget") if r["budget"] else "off"
        for key in ("orbit", "live", "baked"):
            ms = r.get(f"{key}_frame_ms")
            if not ms:
                continue
            fps, own = r[f"{key}_ui_fps"], r[f"{key}_ui_fps_own"]
            rows.append(f"| {r['avatar']} | {drawing} | {key} | {fps:.1f} | {own:.1f} | "
                        + " | ".join(f"{ms[s]:.1f}" for s in (*SECTIONS, "readback")) + " |")
    return "\n".join(rows)


def table(results: list[dict]) -> str:
    """A markdown table of the figures (one row per avatar and mode)."""
    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    rows = ["| avatar | drawing | precision | first pixels s | slider -> changed s (med / p90) "
            "| slider -> exact s (med) | slider -> CNN image s (med) | orbit images/s | orbit UI fps "
            "| orbit -> exact s | live images/s | baked images/s |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        sc, se = r.get("slider_changed_s", {}), r.get("slider_exact_s", {})
        sr = r.get("slider_refined_s", {})
        drawing = ("budget + LOD" if r.get("lod") else "budget") if r["budget"] else "off"
        rows.append(f"| {r['avatar']} | {drawing} | {r.get('precision', 'auto')} | {f(r.get('first_pixels_s'))} | "
                    f"{f(sc.get('median'))} / {f(sc.get('p90'))} | {f(se.get('median'))} | {f(sr.get('median'))} | "
                    f"{f(r.get('orbit_images_per_s'), '{:.1f}')} | {f(r.get('orbit_ui_fps'), '{:.1f}')} | "
                    f"{f(r.get('orbit_exact_after_s'))} | {f(r.get('live_images_per_s'), '{:.1f}')} | "
                    f"{f(r.get('baked_images_per_s'), '{:.1f}')} |")
    return "\n".join(rows)


def measure_live_link(avatar: str = "demo", samples: int = 12, seconds: float = 6.0, rate: float = 60.0) -> dict:
    """The Live Link Face stream into the window, on its pixels (#25): packet -> first changed pixels (median,
    p90 over `samples` packets, each sent once the view has settled on the previous one), and a `rate`
    packets/s stream for `seconds`: packets received, taken by the window (at most one per UI frame, the newest),
    dropped (replaced before a UI frame took them), late and bad, distinct view images per second and UI frames
    per second. It keeps up when the window takes every packet (nothing dropped)."""
    import socket
    import threading

    from npga_core.files.blendshape_names import ARKIT_52
    from npga_core.posing.livelink import encode
    from npga_view.app import ViewerApp

    app = ViewerApp(*SIZE, vsync=False, threads=2, remember_recent=False)
    w = _Watcher(app)
    out: dict = {"avatar": Path(avatar).name if avatar != "demo" else "demo", "rate": rate}
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        app.state.show_stats = False
        app.open_avatar(avatar)
        if app.avatar is None or app.avatar.blendshapes is None:
            return {**out, "error": "the avatar has no blendshape basis"}
        w.until(lambda: _exact(app), 300)
        ref = []  # the same measure for slider moves, in the same run: the machine's load sets both
        for k in range(max(2, samples // 2)):
            w.until(lambda: _exact(app), 120)
            w.step()
            app.state.follow_sequence = False
            app.state.sliders[0] += 1.0 if k % 2 == 0 else -1.0
            _input_event()
            ref.append(w.until_changed(time.perf_counter()))
        out["slider_changed_s"] = _stats(ref)
        if not app.live.start("127.0.0.1:0"):
            return {**out, "error": "; ".join(app.state.errors)}
        app.panels.scroll_side()  # at the Live Link part (its counters in view), as after pressing Listen there
        addr = cast("LiveLinkReceiver", app.live.receiver).address  # started
        jaw, blink = ARKIT_52.index("jawOpen"), ARKIT_52.index("eyeBlinkLeft")
        frame = [int(time.time() % 86400 * 60)]

        def packet(a: float) -> bytes:
            v = np.zeros(61, np.float32)
            v[jaw], v[blink] = a, 1.0 - a
            frame[0] += 1
            return encode(v, frame[0], fps=60, subject="bench")

        lat = []
        for k in range(samples):
            w.until(lambda: _exact(app), 120)
            w.step()
            t0 = time.perf_counter()
            sock.sendto(packet(0.8 if k % 2 == 0 else 0.1), addr)
            lat.append(w.until_changed(t0))
        out["packet_changed_s"] = _stats(lat)
        w.until(lambda: _exact(app), 120)
        c0 = dict(vars(cast("LiveLinkReceiver", app.live.receiver).counters))
        taken0, frames0, images = app.live.taken, app.frames, 0
        stop = threading.Event()
        sent = [0]

        def sender() -> None:
            t_start = time.perf_counter()
            while not stop.is_set():
                due = t_start + sent[0] / rate
                now = time.perf_counter()
                if now < due:
                    time.sleep(min(due - now, 0.005))
                    continue
                sock.sendto(packet(0.5 + 0.45 * np.sin(sent[0] / rate * 2 * np.pi)), addr)
                sent[0] += 1

        th = threading.Thread(target=sender, daemon=True)
        t0 = time.perf_counter()
        th.start()
        while time.perf_counter() - t0 < seconds:
            images += w.step()
        stop.set()
        th.join()
        dt = time.perf_counter() - t0
        for _ in range(3):
            w.step()
        c = vars(cast("LiveLinkReceiver", app.live.receiver).counters)
        out.update({"sent": sent[0], "sent_per_s": sent[0] / dt,
                    **{k: c[k] - c0[k] for k in ("received", "dropped", "late", "bad")},
                    "taken": app.live.taken - taken0, "images_per_s": images / dt,
                    "ui_fps": (app.frames - frames0) / dt})
        out["keeps_up"] = out["dropped"] == 0 and out["received"] == out["sent"]
        return out
    finally:
        sock.close()
        app.close()


def live_link_table(r: dict) -> str:
    """Markdown rows of `measure_live_link`'s figures."""
    if "error" in r:
        return f"Live Link ({r['avatar']}): {r['error']}"
    p = {k: ("-" if v is None else f"{v:.3f}") for k, v in r["packet_changed_s"].items()}
    s = {k: ("-" if v is None else f"{v:.3f}") for k, v in r["slider_changed_s"].items()}
    return "\n".join([
        "| avatar | packet -> changed pixels s (median / p90) | slider -> changed s (median / p90) "
        "| packets sent/s | received | taken by UI frames | dropped | late | bad | view images/s | UI fps | keeps up |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        f"| {r['avatar']} | {p['median']} / {p['p90']} | {s['median']} / {s['p90']} | {r['sent_per_s']:.1f} | "
        f"{r['received']} | {r['taken']} | {r['dropped']} | {r['late']} | {r['bad']} | {r['images_per_s']:.1f} | "
        f"{r['ui_fps']:.1f} | {'yes' if r['keeps_up'] else 'no'} |"])
