"""`npga-view bench [AVATAR] [--gaussians N ...] [--json PATH]`: how fast the dynamics are on this machine.

For the demo avatar (or the given ones) and synthetic paper-sized avatars (6-layer 256-wide F and G, 100-D
codes, SH degree 3) it measures, in one run:

- the machine's fp32 matrix-multiply throughput (`gemm_gflops`: 2048^3 products measured between the rounds
  of each avatar's exact timing, the best of them), so every dynamics figure is also a ratio to this
  machine's limit;
- the exact path in process (`FastPoser`): F, G, offset application; GFLOPS and `roofline_ratio` (best over
  best) and `roofline_ratio_median` (per round, against the gemm rate measured next to it);
- the stages of a drawn frame: sort, upload, pre-pass, draw, and the CNN when the avatar has one;
- the viewer's path through `PoseEngine`: scrub latency (request -> posed arrays ready for upload),
  refinement to the exact pose after the slider stops, live (exact, wall-clock) and baked playback rates,
  bake time and cache reuse, and the peak resident memory of the viewer-side process and the worker;
- the preview error: images of preview and exact poses of the same codes after 1-std slider moves (PSNR).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_core.posing.precision import PRECISION_HELP
from npga_view.benchmarks.bench_precision import gemm_gflops

if TYPE_CHECKING:
    from npga_core.posing.fastpose import FastPoser

DEFAULT_SIZES = (20000, 100000, 250000)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatars", nargs="*", help="avatar files to measure (default: the demo avatar, if built)")
    p.add_argument("--gaussians", type=int, nargs="*", default=list(DEFAULT_SIZES),
                   help="sizes of synthetic paper-sized avatars (default: 20000 100000 250000; none: skip)")
    p.add_argument("--gha", type=int, nargs="*", default=[], metavar="N",
                   help="also sizes of synthetic Gaussian-Head-Avatar checkpoints at GHA's default network sizes "
                        "(opened as GHA folders; e.g. --gha 100000)")
    p.add_argument("--json", type=Path, help="also write the results as JSON")
    p.add_argument("--threads", type=int, default=2, help="threads of the dynamics (default 2)")
    p.add_argument("--device", default="cpu", help="dynamics device: cpu (default), cuda, mps or auto")
    p.add_argument("--repeat", type=int, default=3, help="repetitions of each timed step (median; default 3)")
    p.add_argument("--moves", type=int, default=12, help="slider moves per scrub (default 12)")
    p.add_argument("--live-seconds", type=float, default=4.0, help="length of the live playback run (default 4)")
    p.add_argument("--bake-frames", type=int, default=50, help="frames of the baked sequence (default 50)")
    p.add_argument("--bake-budget-mb", type=float, default=1024.0, help="bake memory budget (default 1024)")
    p.add_argument("--kernel", choices=("auto", "onednn", "aten"), default="auto",
                   help="hidden layers on oneDNN (fused bias + ReLU) or torch.mm (default auto: oneDNN if usable)")
    p.add_argument("--precision", default="auto", metavar="fp32|bf16|auto", help=PRECISION_HELP)
    p.add_argument("--peer", type=Path, metavar="PATH",
                   help="also draw the demo against GaussianSplattingViewer's OpenGL renderer from this checkout "
                   "(1360x900 window, 15-frame yaw orbit, alternating; npga_view/benchmarks/bench_peer.py)")
    p.add_argument("--no-render", action="store_true", help="skip OpenGL (no draw timings, no PSNR)")
    p.add_argument("--window", action="store_true",
                   help="measure the real window on its pixels instead (first pixels, slider, orbit, playback; "
                        "budgeting with and without the merged live cloud, and off; --gaussians sizes besides the "
                        "demo; Xvfb if no DISPLAY)")
    p.add_argument("--window-precision", nargs="*", choices=("auto", "fp32", "bf16"), metavar="P",
                   help="--window: the default drawing once per precision of the exact dynamics (e.g. fp32 bf16)")
    p.add_argument("--window-seconds", type=float, default=6.0, help="length of each window run (default 6)")
    p.add_argument("--beside-load", type=int, default=0, metavar="N",
                   help="--window: measure idle and again beside N busy processes the bench starts and ends itself "
                        "(a training run, a browser), one table")


# -- small measuring helpers -------------------------------------------------------------------------------
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two images in [0, 1] (clipped)."""
    mse = float(np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def _median(xs: list[float]) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def _p90(xs: list[float]) -> float:
    return float(np.percentile(xs, 90)) if xs else float("nan")


# -- the parts ---------------------------------------------------------------------------------------------
class _Renderer:
    """A headless renderer and the default camera framing an avatar."""

    def __init__(self, means: np.ndarray):
        from npga_core.camera.cameras import frame_points
        from npga_view.rendering.factory import create_renderer
        from npga_view.rendering.gl import create_headless_context

        self.ctx = create_headless_context()
        self.camera = frame_points(np.asarray(means))
        self.r = create_renderer(self.ctx, self.camera.width, self.camera.height)

    def image(self, posed) -> np.ndarray:
        self.r.set_gaussians(posed)
        return self.r.render(self.camera)

    def stages(self, posed, avatar, repeat: int) -> dict[str, float]:
        """Median ms of upload, sort, pre-pass, draw (+ latent draw and CNN when the avatar has a CNN)."""
        rows: dict[str, list[float]] = {}
        cam = self.camera
        for i in range(repeat + 1):
            t0 = time.perf_counter()
            self.r.set_gaussians(posed)
            upload = (time.perf_counter() - t0) * 1e3
            # a slightly different camera each time, so every frame sorts and runs the pre-pass
            w2c = cam.world_to_camera.copy()
            w2c[0, 3] += 1e-5 * (i + 1)
            c = replace(cam, world_to_camera=w2c)
            self.r.draw(c)
            t = self.r.last_timings
            if i == 0:
                continue
            for k, v in (("upload_ms", upload + t.get("upload", 0.0)), ("sort_ms", t.get("sort", 0.0)),
                         ("preprocess_ms", t.get("preprocess", 0.0)), ("draw_ms", t.get("draw", 0.0))):
                rows.setdefault(k, []).append(v)
            if avatar.cnn is not None and self.r.latent_dim:
                from npga_view.rendering.pipeline import cnn_input

                t0 = time.perf_counter()
                image = cnn_input(self.r, avatar.cnn, c)  # the image the window's CNN takes (its input size)
                t1 = time.perf_counter()
                avatar.cnn.refine(image)
                rows.setdefault("latent_draw_ms", []).append((t1 - t0) * 1e3)
                rows.setdefault("cnn_ms", []).append((time.perf_counter() - t1) * 1e3)
        return {k: _median(v) for k, v in rows.items()}


def _exact_in_process(avatar, args, out: dict) -> FastPoser:
    """F, G, apply timings of the exact path and the roofline figures."""
    import torch

    from npga_core.posing.fastpose import FastPoser, posed_buffers

    poser = FastPoser(avatar, device=args.device, threads=args.threads, kernel=args.kernel, precision=args.precision)
    gemm_device = str(poser.device.type)
    dest = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)
    z = avatar.expression.sample(np.random.default_rng(0)) if avatar.expression else avatar.neutral_code()
    poser.pose_into(z, dest)
    buf = torch.empty(len(avatar), poser.layout.width)
    runs, gemms = [], []
    for _ in range(max(5, args.repeat)):  # gemm and dynamics alternate, so that both see the same machine
        gemms.append(gemm_gflops(args.threads, repeat=2, device=gemm_device))
        t: dict[str, float] = {}
        t0 = time.perf_counter()
        poser.pose_into(z, dest, timings=t)
        t1 = time.perf_counter()
        poser.offsets(z, out=buf)  # F and G alone: what the roofline ratio is about
        t["pose"], t["offsets"] = (t1 - t0) * 1e3, (time.perf_counter() - t1) * 1e3
        runs.append(t)
    gemms.append(gemm_gflops(args.threads, repeat=2, device=gemm_device))
    med = {k: _median([r.get(k, 0.0) for r in runs]) for k in ("F", "G", "apply", "pose", "offsets")}
    out["network_ms"] = {k: _median([r.get(k, 0.0) for r in runs])
                         for k in [*poser.nets, *(["rig"] if poser.rig is not None else [])]}
    best = min(r["offsets"] for r in runs)  # best of the rounds, like the gemm rate it is compared with
    n = len(avatar)
    flop = n * poser.flops_per_gaussian
    out["gemm_gflops"] = max(gemms)
    out["gemm_gflops_rounds"] = gemms
    # per round: dynamics rate over the better of the gemm rates measured right before and after it
    paired = [flop / (r["offsets"] / 1e3) / 1e9 / max(gemms[i], gemms[i + 1]) for i, r in enumerate(runs)]
    out["first_layer"], out["kernel"], out["chunk"] = poser.first_layer, poser.kernel, poser.chunk
    out["precision"] = poser.precision
    out["F_ms"], out["G_ms"], out["apply_ms"], out["exact_pose_ms"] = med["F"], med["G"], med["apply"], med["pose"]
    out["dynamics_ms"], out["dynamics_median_ms"] = best, med["offsets"]
    out["mflop_per_gaussian"] = poser.flops_per_gaussian / 1e6
    out["dynamics_gflops"] = flop / (out["dynamics_ms"] / 1e3) / 1e9
    out["roofline_ratio"] = out["dynamics_gflops"] / out["gemm_gflops"]
    out["roofline_ratio_median"] = _median(paired)
    if avatar.source:  # the previous fast path (`Avatar.pose`), for comparison, on its own copy of the avatar
        from npga_core.files.loading import load_avatar

        other = load_avatar(avatar.source)
        t0 = time.perf_counter()
        other.pose(z)
        out["avatar_pose_ms"] = (time.perf_counter() - t0) * 1e3
        del other
    return poser


def _preview_error(avatar, poser, model, renderer: _Renderer | None, args, out: dict) -> None:
    """Preview vs exact images after +-1 std moves of the leading sliders from random expressions."""
    import torch

    from npga_core.model.gaussians import PosedGaussians
    from npga_core.posing.fastpose import posed_buffers
    from npga_core.posing.preview import Previewer

    ex = avatar.expression
    if ex is None or renderer is None:
        return
    pv = Previewer(poser, model)
    rng = np.random.default_rng(7)
    n, k, h = len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim
    dest = posed_buffers(n, k, h)
    base = torch.empty(n, poser.layout.width)
    scores, stale, offset_err = [], [], []
    for trial in range(6):
        s0 = (0.7 * rng.standard_normal(ex.n_components)).astype(np.float32)
        s1 = s0.copy()
        s1[trial % min(3, ex.n_components)] += 1.0 if trial < 3 else -1.0
        z0, z1 = ex.from_sliders(s0), ex.from_sliders(s1)
        poser.pose_into(z0, dest, offsets_out=base)
        pv.set_base(z0, base)
        img0 = renderer.image(PosedGaussians(**dest))
        exact_off = poser.offsets(z1)
        poser.pose_into(z1, dest)
        img1 = renderer.image(PosedGaussians(**dest))
        pv.pose_into(z1, dest)
        imgp = renderer.image(PosedGaussians(**dest))
        scores.append(psnr(imgp, img1))
        stale.append(psnr(img0, img1))
        moved = (exact_off - base)[:, :3].norm(dim=1).mean()
        err = (pv.offsets(z1) - exact_off)[:, :3].norm(dim=1).mean()
        offset_err.append(float(err / moved.clamp_min(1e-12)))
    out["preview_psnr_db"] = min(scores)
    out["preview_psnr_mean_db"] = float(np.mean(scores))
    out["stale_psnr_db"] = min(stale)  # not updating at all, for scale
    out["preview_rel_offset_error"] = float(np.mean(offset_err))


def _bake_error(avatar, poser, path: str, codes: np.ndarray, renderer: _Renderer | None, args, out: dict) -> None:
    """PSNR of baked (quantised) frames against exact ones."""
    from npga_core.model.gaussians import PosedGaussians
    from npga_core.posing.bake import BakeStore, bake_key, cache_path
    from npga_core.posing.fastpose import posed_buffers

    if renderer is None:
        return
    key = bake_key(avatar.content_key(), codes, 8, int(args.bake_budget_mb * 2**20))
    store = BakeStore.open(cache_path(path, key, args.cache_dir), key)
    if store is None:
        return
    import torch

    dest = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)
    buf = torch.empty(len(avatar), poser.layout.width)
    scores = []
    for f in sorted({0, len(codes) // 2, len(codes) - 1}):
        poser.pose_into(codes[f], dest)
        exact = renderer.image(PosedGaussians(**dest))
        store.offsets_into(f, buf)
        poser.apply_into(buf, dest)
        scores.append(psnr(renderer.image(PosedGaussians(**dest)), exact))
    out["bake_psnr_db"] = min(scores)


def _engine_run(path: str, avatar, codes: np.ndarray, fps: float, renderer: _Renderer | None, args,
                out: dict) -> None:
    """The viewer's path: scrub latency, refine, live and baked playback, memory."""
    from npga_core.posing.engine import EngineOptions, PoseEngine

    opts = EngineOptions(device=args.device, cache_dir=args.cache_dir, kernel=args.kernel, precision=args.precision)
    ex = avatar.expression
    n = len(avatar)
    with PoseEngine(path, n, avatar.cloud.sh.shape[1], avatar.cloud.latent_dim, args.threads, opts) as eng:
        t0 = time.perf_counter()
        eng.request(avatar.neutral_code(), mode="exact")
        r = eng.wait(timeout=600)
        if r is None:
            raise RuntimeError(f"pose worker failed: {eng.last_error}")
        r.release()
        out["first_pose_ms"] = (time.perf_counter() - t0) * 1e3
        # let the worker fit the preview model (or load it from the cache) before scrubbing
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 3600:
            eng.poll()
            state = str(eng.status.get("preview_model", "pending"))
            if not state.startswith(("pending", "fitting", "geometric")) or not eng.alive:
                break
            time.sleep(0.05)
        out["preview_model"] = eng.status.get("preview_model")
        out["preview_precision"] = eng.status.get("preview_precision")
        out["preview_fit_s"] = time.perf_counter() - t0
        latencies, computes, refines, flags = [], [], [], []
        rng = np.random.default_rng(3)
        for drag in range(3):
            s = (0.7 * rng.standard_normal(ex.n_components)).astype(np.float32) if ex else None
            for _ in range(args.moves):
                if ex is not None:
                    cast(np.ndarray, s)[drag % ex.n_components] += 1.0 / args.moves
                    z = ex.from_sliders(s)
                else:
                    z = avatar.neutral_code()
                t0 = time.perf_counter()
                rid = eng.request(z)
                r = eng.wait(timeout=600)
                latencies.append((time.perf_counter() - t0) * 1e3)
                flags.append(bool(r is not None and r.preview))
                if r is not None:
                    computes.append(r.timings.get("pose_total", float("nan")))
                    r.release()
                time.sleep(0.015)  # the refine starts meanwhile and must give way to the next move
            t0 = time.perf_counter()
            r = eng.wait(timeout=600, exact=True)
            if r is not None and r.request_id == rid and not r.preview:
                refines.append((time.perf_counter() - t0) * 1e3)
                r.release()
        out["scrub_latency_ms"] = _median(latencies)
        out["scrub_latency_p90_ms"] = _p90(latencies)
        out["scrub_compute_ms"] = _median(computes)  # the worker's own time, without messaging
        out["scrub_preview_fraction"] = float(np.mean(flags))
        out["exact_refine_ms"] = _median(refines)
        # the worker's peak so far: the viewer's memory without a bake (a bake adds at most its budget)
        eng.poll()
        out["worker_peak_rss_mb"] = eng.worker_peak_rss_mb
        seconds = max(args.live_seconds, 5e-3 * out["exact_refine_ms"]) if refines else args.live_seconds
        out["live_playback_fps"] = _live(eng, codes, fps, seconds)
        # bake, play, bake again (from the cache)
        t0 = time.perf_counter()
        eng.bake(codes, budget_mb=args.bake_budget_mb)
        st = eng.wait_bake()
        out["bake_s"] = time.perf_counter() - t0
        if st is None or st.error or not st.finished:
            out["bake_error"] = st.error if st is not None else eng.last_error
        else:
            out["bake_mb"], out["bake_stride"] = st.megabytes, st.stride
            out["baked_playback_fps"] = _baked(eng, len(codes))
            if renderer is not None:
                out["baked_playback_drawn_fps"] = _baked(eng, len(codes), renderer)
            t0 = time.perf_counter()
            eng.bake(codes, budget_mb=args.bake_budget_mb)
            st2 = eng.wait_bake()
            out["bake_cached_s"] = time.perf_counter() - t0
            out["bake_cache_reused"] = bool(st2 is not None and st2.from_cache)
        eng.poll()
        out["worker_peak_rss_with_bake_mb"] = eng.worker_peak_rss_mb


def _live(eng, codes: np.ndarray, fps: float, seconds: float) -> float:
    """Frames shown per second when following the wall clock with exact poses (newest frame wins)."""
    start = time.perf_counter()
    shown: set[tuple] = set()
    requested = None
    while time.perf_counter() - start < seconds:
        frame = int((time.perf_counter() - start) * fps) % len(codes)
        if frame != requested:
            eng.request(codes[frame], mode="exact")
            requested = frame
        r = eng.poll()
        if r is not None:
            shown.add((r.request_id, len(shown)))
            r.release()
        time.sleep(0.002)
    elapsed = time.perf_counter() - start
    eng.wait(timeout=600)
    return len(shown) / elapsed


def _baked(eng, frames: int, renderer: _Renderer | None = None) -> float:
    """Frames per second delivered from the bake, back to back (with `renderer`: each also uploaded and drawn,
    one after the other, where the viewer would overlap the two)."""
    t0 = time.perf_counter()
    for f in range(frames):
        eng.request_frame(f)
        r = eng.wait(timeout=60)
        if r is None:
            continue
        if renderer is not None:
            renderer.r.set_gaussians(r.posed)
        r.release()
        if renderer is not None:
            renderer.r.draw(renderer.camera)
    return frames / (time.perf_counter() - t0)


def _sequence(avatar, frames: int) -> tuple[np.ndarray, float]:
    """The demo's talking sequence when there is one next to the avatar, else a smooth random walk."""
    from npga_core.files.loading import load_sequence

    if avatar.source:
        seq_file = Path(avatar.source).parent / "sequences" / "talking.npzseq"
        if seq_file.is_file():
            seq = load_sequence(seq_file)
            return seq.codes[:frames], seq.fps
    rng = np.random.default_rng(11)
    ex = avatar.expression
    k = ex.n_components if ex else avatar.code_dim
    t = np.arange(frames)[:, None] / 25.0
    phase, freq = rng.uniform(0, 2 * np.pi, k), rng.uniform(0.3, 1.5, k)
    sliders = (0.8 * np.sin(2 * np.pi * freq * t + phase)).astype(np.float32)
    return (ex.from_sliders(sliders) if ex else sliders).astype(np.float32), 25.0


def viewer_side(path: str, args) -> dict:
    """The engine figures, measured in a fresh process that holds what the viewer holds (the avatar, a
    renderer, the engine and its slots), so that its peak resident memory is the viewer's."""
    from npga_core.files.loading import load_avatar
    from npga_core.posing.engine import peak_rss_mb

    avatar = load_avatar(path)
    out: dict = {}
    codes, fps = _sequence(avatar, args.bake_frames)
    renderer = None if args.no_render else _Renderer(avatar.cloud.means)
    _engine_run(path, avatar, codes, fps, renderer, args, out)
    out["viewer_peak_rss_mb"] = peak_rss_mb()
    return out


def _helper_init(parent_pid: int) -> None:
    """Start of bench's helper process: exit when bench is gone; SIGTERM unwinds like in the CLI."""
    from npga_core.posing.lifetime import start_parent_watch
    from npga_view import signals

    start_parent_watch(parent_pid, [])
    signals.install()


def bench_avatar(name: str, path: str, args) -> dict:
    """All figures of one avatar file."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from npga_core.files.loading import load_avatar
    from npga_core.posing.preview import PreviewModel, preview_cache_path

    # the viewer side runs in a helper process; it must not outlive bench (#16): it watches its parent, and a
    # bench ended by a signal (or an error) stops it instead of waiting for its task
    pool = ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=_helper_init,
                               initargs=(os.getpid(),))
    try:
        viewer = pool.submit(viewer_side, path, args).result()
    except BaseException:
        for proc in list((getattr(pool, "_processes", None) or {}).values()):  # no public way before 3.14
            proc.terminate()  # SIGTERM: its handler unwinds, closing its PoseEngine
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    gc.collect()
    avatar = load_avatar(path)
    out: dict = {"name": name, "gaussians": len(avatar), "path": path, **viewer}
    out["peak_rss_mb"] = out["viewer_peak_rss_mb"] + out["worker_peak_rss_mb"]
    codes, _ = _sequence(avatar, args.bake_frames)
    renderer = None if args.no_render else _Renderer(avatar.cloud.means)
    poser = _exact_in_process(avatar, args, out)
    from npga_view.benchmarks.bench_precision import precision_ratio

    out.update(precision_ratio(avatar, args, renderer, codes))
    if renderer is not None:
        from npga_core.model.gaussians import PosedGaussians
        from npga_core.posing.fastpose import posed_buffers

        dest = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)
        poser.pose_into(avatar.neutral_code(), dest)
        out.update(renderer.stages(PosedGaussians(**dest), avatar, args.repeat))
        from npga_view.benchmarks.bench_precision import path_ratio

        out["draw_paths"] = path_ratio(renderer, PosedGaussians(**dest), repeat=args.repeat)
    from npga_core.posing.engine import EngineOptions

    o = EngineOptions(cache_dir=args.cache_dir)
    key = avatar.content_key()
    model = PreviewModel.load(preview_cache_path(path, key, o.probes, o.neighbours, o.fit_codes, o.cache_dir), key,
                              len(avatar))
    if model is not None:
        _preview_error(avatar, poser, model, renderer, args, out)
    _bake_error(avatar, poser, path, codes, renderer, args, out)
    if renderer is not None:
        renderer.r.release()
        renderer.ctx.release()
    return out


def _print(res: dict) -> None:
    def f(key: str, unit: str = "", fmt: str = "{:.1f}") -> str:
        v = res.get(key)
        return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else fmt.format(v) + unit

    print(f"\n{res['name']}: {res['gaussians']:,} Gaussians ({res.get('first_layer', '?')} first layer, "
          f"{res.get('kernel', '?')} kernel, chunks of {res.get('chunk', '?')})")
    nets = res.get("network_ms") or {"F": res.get("F_ms"), "G": res.get("G_ms")}
    times = "  ".join(f"{k} {'-' if v is None else f'{v:.1f} ms'}" for k, v in nets.items())
    print(f"  gemm {f('gemm_gflops', ' GFLOPS')}  |  {times}  apply "
          f"{f('apply_ms', ' ms')}  exact pose {f('exact_pose_ms', ' ms')}"
          f"  ->  networks {f('dynamics_gflops', ' GFLOPS')} = "
          f"{f('roofline_ratio', '', '{:.2f}')} "
          f"of gemm (median round {f('roofline_ratio_median', '', '{:.2f}')})  "
          f"(Avatar.pose {f('avatar_pose_ms', ' ms')})")
    from npga_view.benchmarks.bench_precision import print_precision

    print_precision(res)
    for size, d in (res.get("draw_paths") or {}).items():
        print(f"  draw at {size}: points {d['points_ms']:.1f} ms, quads {d['quads_ms']:.1f} ms -> quads / points "
              f"{d['quads_over_points']:.2f} (measured choice: {d['chosen']})")
    print(f"  frame: upload {f('upload_ms', ' ms')}  sort {f('sort_ms', ' ms')}  pre-pass {f('preprocess_ms', ' ms')}"
          f"  draw {f('draw_ms', ' ms')}  CNN {f('cnn_ms', ' ms')}")
    print(f"  scrub: {f('scrub_latency_ms', ' ms')} median, {f('scrub_latency_p90_ms', ' ms')} p90 "
          f"(previews {f('scrub_preview_fraction', '', '{:.0%}')}), exact after {f('exact_refine_ms', ' ms')}; "
          f"preview PSNR {f('preview_psnr_db', ' dB')} min / {f('preview_psnr_mean_db', ' dB')} mean "
          f"(not updating: {f('stale_psnr_db', ' dB')}), model {res.get('preview_model')} "
          f"({res.get('preview_precision')} probes) in "
          f"{f('preview_fit_s', ' s')}")
    print(f"  playback: live {f('live_playback_fps', ' fps', '{:.2f}')}  baked {f('baked_playback_fps', ' fps')} "
          f"({f('baked_playback_drawn_fps', ' fps')} with upload + draw) "
          f"(bake {f('bake_s', ' s')}, {f('bake_mb', ' MB', '{:.0f}')}, stride {res.get('bake_stride', '-')}, "
          f"PSNR {f('bake_psnr_db', ' dB')}; again from cache {f('bake_cached_s', ' s', '{:.2f}')})")
    print(f"  memory: viewer {f('viewer_peak_rss_mb', ' MB', '{:.0f}')} + worker "
          f"{f('worker_peak_rss_mb', ' MB', '{:.0f}')} = {f('peak_rss_mb', ' MB', '{:.0f}')} peak resident "
          f"(worker with the bake: {f('worker_peak_rss_with_bake_mb', ' MB', '{:.0f}')})")


def run(args: argparse.Namespace) -> int:
    if args.window:
        from npga_view.benchmarks.bench_window import run as run_window

        sizes = [n for n in args.gaussians if n != 20000] if args.gaussians == list(DEFAULT_SIZES) else args.gaussians
        run_window(sizes, demo=not args.avatars, json_path=args.json, moves=min(args.moves, 6),
                   seconds=args.window_seconds, precisions=tuple(args.window_precision or ()) or None,
                   avatars=args.avatars, beside_load=max(0, min(args.beside_load, 64)))
        return 0
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.loading import DEMO_AVATAR
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_core.posing.device import resolve_device

    try:
        args.device = str(resolve_device(args.device))
    except ValueError as e:
        print(f"npga-view bench: error: {e}", file=sys.stderr)
        return 2

    targets = [(f"{Path(p).parent.name}/{Path(p).name}", str(p)) for p in args.avatars]
    if not targets and DEMO_AVATAR.is_file():
        targets.append(("demo", str(DEMO_AVATAR)))
    from npga_core.posing.precision import check_precision, cpu_flags
    from npga_view.benchmarks.bench_precision import cpu_name, mm_ratio

    try:
        args.precision = check_precision(args.precision)
    except ValueError as e:
        print(f"npga-view bench: error: {e}", file=sys.stderr)
        return 2
    machine = {"python": platform.python_version(), "cpu": cpu_name(), "cpu_flags": list(cpu_flags()),
               "cores": os.cpu_count(), "threads": args.threads, "device": args.device, **mm_ratio()}
    try:
        import torch

        machine["torch"] = torch.__version__
    except ImportError:
        pass
    print(f"npga-view bench: {machine}")
    print(f"torch.mm 80k x 256 x 256: fp32 {machine['mm_fp32_gflops']:.0f} GFLOPS, bf16 "
          f"{machine['mm_bf16_gflops']:.0f} GFLOPS -> bf16 {machine['mm_bf16_speedup']:.2f}x")
    if not args.no_render:
        from npga_view.rendering.gl import GLUnavailableError, create_headless_context

        try:
            create_headless_context().release()
        except GLUnavailableError as e:
            print(f"no OpenGL ({e}): measuring without drawing (no draw timings, no PSNR)")
            args.no_render = True
    results = []
    with tempfile.TemporaryDirectory(prefix="npga-bench-") as tmp:
        args.cache_dir = tmp
        for n in args.gaussians or []:
            path = Path(tmp) / f"synthetic-{n}.npga"
            save_avatar(make_synthetic_avatar(n, latent_dim=4, with_cnn=True), path)  # CNN: times that stage too
            targets.append((f"synthetic {n // 1000}k", str(path)))
        for n in args.gha:
            from npga_core.files.gha_synthetic import write_gha_folder

            targets.append((f"GHA synthetic {n // 1000}k", str(write_gha_folder(Path(tmp) / f"gha-{n}", n))))
        for name, target in targets:
            res = bench_avatar(name, target, args)
            results.append(res)
            _print(res)
            sys.stdout.flush()
    peer = None
    if args.peer is not None and not args.no_render:
        from npga_view.benchmarks.bench_peer import run as run_peer

        peer = run_peer(args.peer, 1360, 900, 15, 2, None)
    if args.json:
        args.json.write_text(json.dumps({"machine": machine, "results": results, "peer": peer}, indent=1,
                                        default=float))
        print(f"\nwrote {args.json}")
    return 0
