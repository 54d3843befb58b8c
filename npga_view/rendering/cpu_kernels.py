"""Numba kernels of the CPU colour pass (`cpu_splats.py`): tile binning, the tiles' splats, the packed image.

Imported only where the colour pass runs on the CPU (a software GL); compiled once per machine into numba's cache
(`cache=True`: next to this file, or numba's per-user cache folder where this one is read-only).

A splat row is the 16 floats of the pre-pass's `Splat` (shaders/splat_common.glsl): centre x, y (window pixels),
depth, opacity; the quad's axes (unused here); the conic a, b, c (inverse 2D covariance) and a spare; colour r, g, b
and the point side. A pixel (x, y) has its centre at (x + 0.5, y + 0.5), as `gl_FragCoord`. A splat covers, as in the
GL pass (splat.frag), the pixels where its alpha = min(0.99, opacity exp(-0.5 (a dx^2 + c dy^2) - b dx dy)) is at
least 1/255: an ellipse, whose span on each row is computed in closed form, so that only those pixels are visited.
"""

from __future__ import annotations

import math
import os

from npga_view.rendering.gl import RASTER_THREADS_PER_CPU, usable_cpus

# Two threads per usable CPU unless the person set NUMBA_NUM_THREADS (read when numba is imported), as llvmpipe's
# rasterizer threads (gl.prefer_raster_threads): beside two busy processes on 2 cores the demo's full-resolution
# image took 231-259 ms with 4 threads against 289-307 ms with 2; idle, the same (docs/PERFORMANCE.md)
os.environ.setdefault("NUMBA_NUM_THREADS", str(RASTER_THREADS_PER_CPU * usable_cpus()))

import numba as nb  # noqa: E402
import numpy as np  # noqa: E402

#: Tile side in pixels (a power of two: tiles are found by shifts, integer division being slow per splat); a
#: tile's four float planes (64 KiB) stay in the CPU's cache while its splats are blended
TILE_SHIFT = 6
TILE = 1 << TILE_SHIFT
MIN_ALPHA = 1.0 / 255.0
MAX_ALPHA = 0.99
#: A tile's predicted work: its pixel-splat pairs' pixels plus this many pixels' worth per pair (the row set-up)
PAIR_WORK = 24.0
#: ... and its clearing this many per pixel of the tile
CLEAR_WORK = 0.1
#: Centres and half-extents beyond this many pixels are taken as not finite (the pre-pass's output of NaN, inf)
LIMIT = 1e30


@nb.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _ellipse(sp: np.ndarray, i: int) -> tuple[float, float, float, float, float, float]:
    """(L, det, half height, half width) of splat `i`'s alpha >= 1/255 ellipse, with its conic a and b; L <= 0
    when it covers nothing (culled, too faint, or not finite)."""
    o = np.float64(sp[i, 3])
    a, b, c = np.float64(sp[i, 8]), np.float64(sp[i, 9]), np.float64(sp[i, 10])
    det = a * c - b * b
    if not (o > MIN_ALPHA and a > 0.0 and det > 0.0 and abs(sp[i, 0]) < LIMIT and abs(sp[i, 1]) < LIMIT):
        return 0.0, 1.0, 0.0, 0.0, a, b
    L = math.log(255.0 * min(o, 1.0))  # alpha >= 1/255  <=>  0.5 (a dx^2 + c dy^2) + b dx dy <= L
    ry, rx = math.sqrt(2.0 * a * L / det), math.sqrt(2.0 * c * L / det)
    if not (rx < LIMIT and ry < LIMIT):
        return 0.0, 1.0, 0.0, 0.0, a, b
    return L, det, ry, rx, a, b


@nb.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _pixels(lo: float, hi: float, first: int, last: int) -> tuple[int, int]:
    """The pixels first..last whose centres (i + 0.5) lie in [lo, hi] (clamped in floats, then converted)."""
    return (int(max(math.ceil(lo - 0.5), float(first))), int(min(math.floor(hi - 0.5), float(last))))


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=True, error_model="numpy")
def pixel_boxes(order: np.ndarray, sp: np.ndarray, width: int, height: int) -> np.ndarray:
    """The pixel box (x0, x1, y0, y1) in the image of each splat in `order`, in that order (x1 < x0 where it covers
    nothing): read in sequence by `bin_tiles`."""
    n = sp.shape[0]
    by_index = np.empty((n, 4), np.int32)  # computed in index order (the splats read in sequence), then gathered
    for i in nb.prange(n):
        L, det, ry, rx, a, b = _ellipse(sp, i)
        by_index[i, 0], by_index[i, 1], by_index[i, 2], by_index[i, 3] = 0, -1, 0, -1
        if L > 0.0:
            by_index[i, 0], by_index[i, 1] = _pixels(sp[i, 0] - rx, sp[i, 0] + rx, 0, width - 1)
            by_index[i, 2], by_index[i, 3] = _pixels(sp[i, 1] - ry, sp[i, 1] + ry, 0, height - 1)
    box = np.empty((order.shape[0], 4), np.int32)
    for k in nb.prange(order.shape[0]):
        for j in range(4):
            box[k, j] = by_index[order[k], j]
    return box


@nb.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def bin_tiles(order: np.ndarray, box: np.ndarray, width: int, height: int):
    """Splat indices per tile, in draw order (back to front): (starts (T + 1,), lists, work (T,)). Tiles are
    row-major, `TILE` pixels square; a splat goes to every tile its ellipse's pixel box (`box`, from `pixel_boxes`
    in the same order) touches."""
    tx_n = (width + TILE - 1) >> TILE_SHIFT
    ty_n = (height + TILE - 1) >> TILE_SHIFT
    counts = np.zeros(tx_n * ty_n + 1, np.int64)
    work = np.full(tx_n * ty_n, CLEAR_WORK * TILE * TILE, np.float64)  # every tile is cleared
    for k in range(order.shape[0]):
        x0, x1, y0, y1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
        if x1 < x0 or y1 < y0:
            continue
        for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
            rows = min(y1, (ty << TILE_SHIFT) + TILE - 1) - max(y0, ty << TILE_SHIFT) + 1
            for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                cols = min(x1, (tx << TILE_SHIFT) + TILE - 1) - max(x0, tx << TILE_SHIFT) + 1
                counts[ty * tx_n + tx + 1] += 1
                work[ty * tx_n + tx] += PAIR_WORK + 0.785 * rows * cols  # the ellipse: pi/4 of its box
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    lists = np.empty(starts[-1], np.int32)
    for k in range(order.shape[0]):
        x0, x1, y0, y1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
        if x1 < x0 or y1 < y0:
            continue
        for ty in range(y0 >> TILE_SHIFT, (y1 >> TILE_SHIFT) + 1):
            for tx in range(x0 >> TILE_SHIFT, (x1 >> TILE_SHIFT) + 1):
                t = ty * tx_n + tx
                lists[fill[t]] = order[k]
                fill[t] += 1
    return starts, lists, work


@nb.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _draw_tile(t: int, starts: np.ndarray, lists: np.ndarray, sp: np.ndarray, planes: np.ndarray,
               clear: np.ndarray) -> None:
    """Clear tile `t` of `planes` (4, H, W: premultiplied r, g, b and alpha) to `clear`, then blend its splats
    back to front ("over"), each on its ellipse's rows and spans."""
    height, width = planes.shape[1], planes.shape[2]
    tx_n = (width + TILE - 1) >> TILE_SHIFT
    ty0 = (t // tx_n) << TILE_SHIFT
    tx0 = (t % tx_n) << TILE_SHIFT
    ty1 = min(ty0 + TILE, height) - 1
    tx1 = min(tx0 + TILE, width) - 1
    for ch in range(4):
        planes[ch, ty0:ty1 + 1, tx0:tx1 + 1] = clear[ch]
    for j in range(starts[t], starts[t + 1]):
        i = lists[j]
        L, det, ry, rx, a, b = _ellipse(sp, i)
        cx, cy, c = sp[i, 0], sp[i, 1], sp[i, 10]
        y0, y1 = _pixels(cy - ry, cy + ry, ty0, ty1)
        op = np.float32(sp[i, 3])
        cr, cg, cb = np.float32(sp[i, 12]), np.float32(sp[i, 13]), np.float32(sp[i, 14])
        # exp(p) = (exp(p / 16))^16 with exp(p / 16) by Taylor to degree 7: p >= -L >= -5.54 on the ellipse, so
        # |p / 16| <= 0.35 and the error is ~1e-7 (relative), below the 16-bit target's step
        qa = np.float32(-0.5 * a / 16.0)
        for y in range(y0, y1 + 1):
            dy = y + 0.5 - cy
            disc = 2.0 * a * L - det * dy * dy
            if disc < 0.0:
                continue
            s = math.sqrt(disc)
            x0, x1 = _pixels(cx + (-b * dy - s) / a, cx + (-b * dy + s) / a, tx0, tx1)
            n = x1 + 1 - x0
            if n <= 0:
                continue
            qb = np.float32(-b * dy / 16.0)
            qc = np.float32(-0.5 * c * dy * dy / 16.0)
            fx = np.float32(x0 + 0.5 - cx)
            # slices indexed from 0: numba then knows the index is not negative and LLVM vectorises the loop
            pr, pg = planes[0, y, x0:x1 + 1], planes[1, y, x0:x1 + 1]
            pb, pa = planes[2, y, x0:x1 + 1], planes[3, y, x0:x1 + 1]
            for k in range(n):
                dx = np.float32(k) + fx
                u = (qa * dx + qb) * dx + qc
                e = np.float32(1.0) + u * (np.float32(1.0) + u * (np.float32(1 / 2) + u * (np.float32(1 / 6) + u * (
                    np.float32(1 / 24) + u * (np.float32(1 / 120) + u * (np.float32(1 / 720)
                                                                         + u * np.float32(1 / 5040)))))))
                e = e * e
                e = e * e
                e = e * e
                e = e * e
                alpha = min(np.float32(MAX_ALPHA), op * e)
                alpha = alpha if alpha >= np.float32(MIN_ALPHA) else np.float32(0.0)
                keep = np.float32(1.0) - alpha
                pr[k] = cr * alpha + keep * pr[k]
                pg[k] = cg * alpha + keep * pg[k]
                pb[k] = cb * alpha + keep * pb[k]
                pa[k] = alpha + keep * pa[k]


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=True, error_model="numpy")
def draw_tiles(tiles: np.ndarray, chunks: int, starts: np.ndarray, lists: np.ndarray, sp: np.ndarray,
               planes: np.ndarray, clear: np.ndarray) -> None:
    """Draw the tiles `tiles` (indices), interleaved over `chunks` parallel chunks (a tile is drawn whole by one
    thread, so tiles need no locks)."""
    for ch in nb.prange(chunks):
        for k in range(ch, tiles.shape[0], chunks):
            _draw_tile(tiles[k], starts, lists, sp, planes, clear)


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=True, error_model="numpy")
def pack_unorm16(planes: np.ndarray, out: np.ndarray, scale: float) -> None:
    """`planes` (4, H, W) into `out` (H, W, 4) uint16 as a normalised 16-bit target stores them: colour times
    `scale`, alpha as it is (the GL pass writes them so)."""
    height, width = planes.shape[1], planes.shape[2]
    for y in nb.prange(height):
        for ch in range(4):
            f = np.float32(65535.0 * (scale if ch < 3 else 1.0))
            src = planes[ch, y]
            dst = out[y, :, ch]
            for x in range(width):
                v = src[x] * f + np.float32(0.5)
                dst[x] = np.uint16(min(max(v, np.float32(0.0)), np.float32(65535.0)))


@nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def pack_float(planes: np.ndarray, out: np.ndarray, scale: float) -> None:
    """`planes` (4, H, W) into `out` (H, W, 4) float32: colour times `scale`, alpha as it is."""
    height = planes.shape[1]
    for y in nb.prange(height):
        for ch in range(4):
            out[y, :, ch] = planes[ch, y] * np.float32(scale if ch < 3 else 1.0)
