"""`bench`'s machine rates and precision figures, as ratios in one run: the fp32 gemm rate the dynamics are compared
with, a plain product in float32 vs bfloat16, and the exact F+G of each avatar in float32 vs bfloat16 (alternating
rounds, the same lanes), with the images' PSNR between the two."""

from __future__ import annotations

import platform
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np


def gemm_gflops(threads: int, n: int = 2048, repeat: int = 5, device: str = "cpu") -> float:
    """This machine's fp32 matrix-multiply rate (GFLOPS) on `threads` cores: the better of one n^3 product
    with `threads` intra-op threads and `threads` concurrent single-threaded n^3 products (best of `repeat`).
    On a GPU `device`, the rate of one n^3 product there."""
    import torch

    if device != "cpu":
        return _gpu_gemm_gflops(torch.device(device), 4 * n, repeat)

    saved = torch.get_num_threads()
    mats = [(torch.randn(n, n), torch.randn(n, n), torch.empty(n, n)) for _ in range(threads)]

    def one(i: int) -> None:
        a, b, c = mats[i]
        torch.mm(a, b, out=c)

    def best(fn) -> float:
        fn()
        t = float("inf")
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn()
            t = min(t, time.perf_counter() - t0)
        return t

    try:
        torch.set_num_threads(threads)
        intra = 2.0 * n**3 / best(lambda: one(0))
        torch.set_num_threads(1)
        with ThreadPoolExecutor(threads, initializer=torch.set_num_threads, initargs=(1,)) as pool:
            inter = threads * 2.0 * n**3 / best(lambda: list(pool.map(one, range(threads))))
    finally:
        torch.set_num_threads(saved)
    return max(intra, inter) / 1e9


def _gpu_gemm_gflops(device, n: int, repeat: int) -> float:
    import torch

    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    sync = torch.cuda.synchronize if device.type == "cuda" else torch.mps.synchronize
    torch.mm(a, b)
    sync()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        torch.mm(a, b)
        sync()
        best = min(best, time.perf_counter() - t0)
    return 2.0 * n**3 / best / 1e9


def cpu_name() -> str:
    """The CPU's model name and the flags that matter here (`precision.cpu_flags`)."""
    from npga_core.posing.precision import cpu_flags

    try:
        info = Path("/proc/cpuinfo").read_text()
        name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "")
    except OSError:
        name = platform.processor()
    return f"{name or platform.machine()} ({', '.join(cpu_flags())})"


def mm_ratio(rows: int = 80_000, width: int = 256, repeat: int = 5) -> dict[str, float]:
    """GFLOPS of one (rows x width) @ (width x width) `torch.mm` in float32 and in bfloat16 on torch's threads,
    alternating, best of `repeat` each, and their ratio."""
    import torch

    a, w = torch.randn(rows, width), torch.randn(width, width)
    pairs = {"fp32": (a, w), "bf16": (a.bfloat16(), w.bfloat16())}
    best = {k: float("inf") for k in pairs}
    for _ in range(repeat):
        for k, (x, y) in pairs.items():
            t0 = time.perf_counter()
            torch.mm(x, y)
            best[k] = min(best[k], time.perf_counter() - t0)
    flop = 2.0 * rows * width * width
    return {"mm_fp32_gflops": flop / best["fp32"] / 1e9, "mm_bf16_gflops": flop / best["bf16"] / 1e9,
            "mm_bf16_speedup": best["fp32"] / best["bf16"]}


def precision_ratio(avatar, args, renderer, codes: np.ndarray, rounds: int = 5) -> dict:
    """Exact F+G (offsets only) in float32 and bfloat16, alternating rounds (best and median of each), their
    ratio, the fidelity figure, and the PSNR of bfloat16's image against float32's over frames of `codes`."""
    from npga_core.model.gaussians import PosedGaussians
    from npga_core.posing.fastpose import FastPoser, posed_buffers
    from npga_core.posing.precision import bf16_native

    out: dict = {"bf16_native": bf16_native()}
    try:
        posers = {p: FastPoser(avatar, device=args.device, threads=args.threads, kernel=args.kernel, precision=p)
                  for p in ("fp32", "bf16")}
    except ValueError as e:  # no oneDNN (another build, a GPU)
        out["bf16_error"] = str(e)
        return out
    out["bf16_fidelity"] = posers["bf16"].fidelity()
    z = avatar.expression.sample(np.random.default_rng(0)) if avatar.expression else avatar.neutral_code()
    times: dict[str, list[float]] = {p: [] for p in posers}
    for p in posers.values():
        p.offsets(z)  # warm
    for _ in range(rounds):
        for name, p in posers.items():
            t0 = time.perf_counter()
            p.offsets(z)
            times[name].append((time.perf_counter() - t0) * 1e3)
    for name, ts in times.items():
        out[f"{name}_dynamics_ms"], out[f"{name}_dynamics_median_ms"] = min(ts), float(np.median(ts))
    out["bf16_speedup"] = out["fp32_dynamics_ms"] / out["bf16_dynamics_ms"]
    out["bf16_speedup_median"] = out["fp32_dynamics_median_ms"] / out["bf16_dynamics_median_ms"]
    if renderer is not None and len(codes):
        psnrs = []
        for code in codes[np.linspace(0, len(codes) - 1, min(4, len(codes))).astype(int)]:
            images = []
            for p in posers.values():
                dest = posed_buffers(len(avatar), avatar.cloud.sh.shape[1], avatar.cloud.latent_dim)
                p.pose_into(code, dest)
                images.append(renderer.image(PosedGaussians(**dest)))
            mse = float(np.mean((images[0].astype(np.float64) - images[1].astype(np.float64)) ** 2))
            psnrs.append(float("inf") if mse == 0 else 10 * np.log10(1.0 / mse))
        out["bf16_psnr_db"], out["bf16_psnr_mean_db"] = min(psnrs), float(np.mean(psnrs))
    return out


def print_precision(res: dict) -> None:
    """The precision line of one avatar."""
    if "bf16_speedup" not in res:
        print(f"  precision: bf16 not measured ({res.get('bf16_error', 'no oneDNN')})")
        return
    psnr = f", images {res['bf16_psnr_db']:.1f} dB min / {res['bf16_psnr_mean_db']:.1f} mean" \
        if "bf16_psnr_db" in res else ""
    print(f"  precision: exact F+G fp32 {res['fp32_dynamics_ms']:.1f} ms, bf16 {res['bf16_dynamics_ms']:.1f} ms "
          f"-> {res['bf16_speedup']:.2f}x (median rounds {res['bf16_speedup_median']:.2f}x; native "
          f"{res['bf16_native']}), offsets error {res['bf16_fidelity']:.4f}{psnr}; the viewer runs "
          f"{res.get('precision', '?')}")


def path_ratio(renderer, posed, scales: tuple[float, ...] = (1.0, 0.25), repeat: int = 3) -> dict:
    """The colour pass drawn as GL points and as quads, alternating, at the bench camera's size and at smaller
    scales of it: median draw ms of each and quads / points (> 1: points are faster there), and which path the
    measured choice (`drawcost.PathCosts`) takes after these draws."""
    from npga_view.rendering.scheduler import scaled_camera

    r = renderer.r
    out: dict[str, Any] = {}
    r.set_gaussians(posed)
    saved = r.use_points
    try:
        for scale in scales:
            cam = scaled_camera(renderer.camera, scale)
            times: dict[bool, list[float]] = {True: [], False: []}
            for _ in range(repeat):
                for points in (True, False):
                    r.use_points = points
                    r.draw(cam)
                    if bool(r.last_timings.get("points")) != points:
                        return out  # splats too large for GL points: only quads
                    times[points].append(r.last_timings["draw"])
            tag = f"{cam.width}x{cam.height}"
            pts, quads = float(np.median(times[True])), float(np.median(times[False]))
            out[tag] = {"points_ms": pts, "quads_ms": quads, "quads_over_points": quads / pts}
            r.use_points = None
            for _ in range(3):
                r.draw(cam)
            out[tag]["chosen"] = "points" if r.last_timings.get("points") else "quads"
    finally:
        r.use_points = saved
    return out
