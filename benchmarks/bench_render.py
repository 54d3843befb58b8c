"""Benchmark of the splat renderer: sort, upload, pre-pass and draw at 20k / 100k / 250k Gaussians.

Both renderer paths side by side in one run (#18): "43" (`SplatRenderer`: compute pre-pass, storage buffers)
and "41" (`SplatRenderer41`: CPU pre-pass, texture splats, what macOS gets), on the same context.

The cloud is head-like: Gaussians on an ellipsoid of head size (about 16 x 22 x 20 cm) with flattened,
randomly oriented scales sized so that the surface is covered a few times over at every N, SH degree 3,
seen by the default front camera at 550x802.

    python benchmarks/bench_render.py [--sizes 20000 100000 250000] [--repeat 5] [--paths 43 41] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from npga_core.camera.cameras import frame_points  # noqa: E402
from npga_core.model.gaussians import PosedGaussians, normalize_quats  # noqa: E402
from npga_view.rendering.factory import create_renderer  # noqa: E402
from npga_view.rendering.gl import create_headless_context  # noqa: E402
from npga_view.rendering.sorting import sort_back_to_front, view_depths  # noqa: E402


def head_cloud(n: int, seed: int = 0, sh_degree: int = 3) -> PosedGaussians:
    """A synthetic head-sized shell of `n` Gaussians (metres), about 3x surface coverage."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    radii = np.array([0.08, 0.11, 0.10])
    means = d * radii * (1.0 + 0.03 * rng.normal(size=(n, 1)))
    area = 4 * np.pi * 0.1**2
    s0 = np.sqrt(3.0 * area / n / np.pi)  # disc radius giving ~3x coverage
    scales = s0 * np.exp(0.4 * rng.normal(size=(n, 3))) * np.array([1.0, 1.0, 0.15])
    k = (sh_degree + 1) ** 2
    sh = rng.normal(0.0, 0.3, (n, k, 3)) * np.r_[1.0, [0.2] * (k - 1)][None, :, None]
    return PosedGaussians(
        means=means.astype(np.float32),
        quats=normalize_quats(rng.normal(size=(n, 4))),
        scales=scales.astype(np.float32),
        opacities=rng.uniform(0.3, 1.0, n).astype(np.float32),
        sh=sh.astype(np.float32),
    )


def _ms(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def bench(sizes: list[int], repeat: int, width: int, height: int, paths: tuple[str, ...] = ("43", "41")) -> list[dict]:
    """One row per size and renderer path (the sort figures are measured once per size)."""
    ctx = create_headless_context()
    renderers = {path: create_renderer(ctx, width, height, path=path) for path in paths}
    rows = []
    for n in sizes:
        cloud = head_cloud(n)
        camera = frame_points(cloud.means, width, height)
        z = view_depths(cloud.means, camera.world_to_camera)
        sorts = {
            "sort_float_argsort_ms": _ms(partial(np.argsort, -z, kind="stable"), repeat),
            "sort_uint16_ms": _ms(partial(sort_back_to_front, z, exact=False), repeat),
            "sort_exact_ms": _ms(partial(sort_back_to_front, z, exact=True), repeat),
        }
        for path, renderer in renderers.items():
            row = {"n": n, "path": path, **sorts,
                   "set_gaussians_ms": _ms(partial(renderer.set_gaussians, cloud), repeat)}
            renderer.render(camera)  # warm up
            frames = []
            for i in range(repeat):
                cam = frame_points(cloud.means, width, height, direction=(2.0 * i, 0.0))  # force a re-sort
                t0 = time.perf_counter()
                renderer.draw(cam)
                frames.append(dict(renderer.last_timings, frame=(time.perf_counter() - t0) * 1e3))
            for key in ("sort", "upload", "preprocess", "draw", "frame"):
                row[f"{key}_ms"] = statistics.median(f[key] for f in frames)
            rows.append(row)
    for renderer in renderers.values():
        renderer.release()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[20_000, 100_000, 250_000])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--width", type=int, default=550)
    parser.add_argument("--height", type=int, default=802)
    parser.add_argument("--paths", nargs="+", choices=("43", "41"), default=["43", "41"],
                        help="renderer paths: 43 (compute pre-pass), 41 (CPU pre-pass, OpenGL 4.1)")
    parser.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = parser.parse_args(argv)
    rows = bench(args.sizes, args.repeat, args.width, args.height, tuple(args.paths))
    cols = [("n", "N"), ("path", "GL path"), ("sort_float_argsort_ms", "argsort f32"), ("sort_uint16_ms", "sort u16"),
            ("sort_exact_ms", "sort exact"), ("set_gaussians_ms", "set_gaussians"), ("sort_ms", "frame: sort"),
            ("upload_ms", "upload"), ("preprocess_ms", "pre-pass"), ("draw_ms", "draw"), ("frame_ms", "total")]
    print(f"{args.width}x{args.height}, median of {args.repeat}, ms")
    print(" | ".join(f"{title:>13}" for _, title in cols))
    for row in rows:
        print(" | ".join(f"{row[k]:>13.2f}" if k not in ("n", "path") else f"{row[k]:>13}" for k, _ in cols))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
