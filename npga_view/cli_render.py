"""`npga-view render AVATAR --out PATH`: headless rendering to PNG, NPY or (with --sequence) MP4."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from npga_core.cameras import DEFAULT_HEIGHT, DEFAULT_WIDTH, Camera, frame_points

RENDER_MODES = ("rgb", "depth", "alpha", "latent")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class RenderError(Exception):
    """A problem with the arguments or inputs of `render`, reported as one line with exit code 2."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")
    p.add_argument("--out", required=True, type=Path,
                   help="output: an image (.png/.jpg), raw floats (.npy), or a video (.mp4, needs --sequence)")
    p.add_argument("--camera", type=Path, help="camera JSON (width, height, fx, fy, cx, cy, world_to_camera); "
                   "default: a front view framing the head")
    p.add_argument("--background", default="0,0,0", help="background colour R,G,B in 0..1 (or 0..255)")
    p.add_argument("--width", type=int, help=f"image width (default: the camera's, else {DEFAULT_WIDTH})")
    p.add_argument("--height", type=int, help=f"image height (default: the camera's, else {DEFAULT_HEIGHT})")
    p.add_argument("--mode", choices=RENDER_MODES, default="rgb",
                   help="rgb colour, expected depth, accumulated alpha, or the latent feature image")
    p.add_argument("--expr", type=Path, help="expression code .npy, (D,) or (T, D) with --frame choosing the row")
    p.add_argument("--sequence", type=Path, help="expression sequence (.npzseq/.npz/.npy or a tracking folder)")
    p.add_argument("--frame", type=int, default=None, help="frame of --sequence/--expr for a single image")
    p.add_argument("--no-cnn", action="store_true", help="skip the avatar's screen-space CNN refinement")


def parse_background(text: str) -> tuple[float, float, float]:
    """'R,G,B' in 0..1, or 0..255 when any value exceeds 1."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise RenderError(f"--background {text!r}: expected three numbers R,G,B") from None
    if len(values) != 3 or not all(np.isfinite(values)) or min(values) < 0:
        raise RenderError(f"--background {text!r}: expected three non-negative numbers R,G,B")
    if max(values) > 1.0:
        if max(values) > 255.0:
            raise RenderError(f"--background {text!r}: values must be in 0..1 or 0..255")
        values = [v / 255.0 for v in values]
    return values[0], values[1], values[2]


def _camera(args, framing_points: np.ndarray) -> Camera:
    for name in ("width", "height"):
        value = getattr(args, name)
        if value is not None and not 1 <= value <= 16384:
            raise RenderError(f"--{name} {value}: must be in 1..16384")
    if args.camera is not None:
        try:
            cam = Camera.from_json(args.camera)
        except ValueError as exc:
            raise RenderError(str(exc)) from None
        if args.width or args.height:
            cam = cam.resized(args.width or cam.width, args.height or cam.height)
        return cam
    return frame_points(framing_points, args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT)


def _codes(args, avatar) -> tuple[np.ndarray | None, float]:
    """(T, D) codes to render (None: the mean code) and the frame rate."""
    from npga_core.sequences import load_sequence

    source = args.sequence or args.expr
    if args.sequence is not None and args.expr is not None:
        raise RenderError("give either --expr or --sequence, not both")
    if source is None:
        if args.frame is not None:
            raise RenderError("--frame needs --sequence or --expr")
        return None, 25.0
    if avatar.code_dim == 0:
        raise RenderError(f"{source}: the avatar is static (no dynamics), it takes no expression codes")
    seq = load_sequence(source)
    seq.check_dim(avatar.code_dim, source)
    codes = seq.codes
    if args.frame is not None:
        if not 0 <= args.frame < len(codes):
            raise RenderError(f"--frame {args.frame}: {source} has frames 0..{len(codes) - 1}")
        codes = codes[args.frame:args.frame + 1]
    return codes, seq.fps


def to_display(image: np.ndarray, mode: str, alpha: np.ndarray | None = None) -> np.ndarray:
    """An (H,W,3) uint8 RGB picture of a render: colour clipped; depth (surface depth = expected depth / alpha)
    near-bright over its range; alpha grey; latent's first three channels scaled by their range."""
    if mode == "rgb":
        rgb = image
    elif mode == "depth":
        surface = image / np.maximum(alpha, 1e-6) if alpha is not None else image
        mask = (alpha > 0.5) if alpha is not None else image > 0
        rgb = np.zeros(image.shape + (3,), np.float32)
        if mask.any():
            lo, hi = np.percentile(surface[mask], [1, 99])
            norm = 1.0 - np.clip((surface - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
            rgb[:] = np.where(mask, 0.1 + 0.9 * norm, 0.0)[..., None]
    elif mode == "alpha":
        rgb = np.repeat(image[..., None], 3, axis=2)
    else:
        chans = image[..., :3]
        if chans.shape[2] < 3:
            chans = np.concatenate([chans, np.zeros(chans.shape[:2] + (3 - chans.shape[2],), np.float32)], 2)
        lo = chans.reshape(-1, 3).min(0)
        hi = chans.reshape(-1, 3).max(0)
        rgb = (chans - lo) / np.maximum(hi - lo, 1e-9)
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


class _Frames:
    """Renders the avatar at a code in the requested mode."""

    def __init__(self, avatar, renderer, camera: Camera, mode: str, background, use_cnn: bool) -> None:
        self.avatar, self.renderer, self.camera = avatar, renderer, camera
        self.mode, self.background = mode, background
        self.use_cnn = use_cnn and mode == "rgb" and avatar.cnn is not None and avatar.cloud.latent is not None

    def render(self, code: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(raw float image, uint8 RGB picture)."""
        r, cam = self.renderer, self.camera
        r.set_gaussians(self.avatar.pose(code))
        if self.mode == "latent":
            if r.latent_dim == 0:
                raise RenderError("--mode latent: the avatar has no latent features")
            image = r.render_latent(cam)
            return image, to_display(image, "latent")
        if self.mode == "depth":
            image = r.render(cam, mode="depth")
            return image, to_display(image, "depth", r.render(cam, mode="alpha"))
        image = r.render(cam, self.background, self.mode)
        if self.use_cnn:
            latent = r.render_latent(cam)
            image = self.avatar.cnn.refine(np.concatenate([image, latent], axis=2))
        return image, to_display(image, self.mode)


def _write_image(path: Path, picture: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(picture[..., ::-1])):
        raise RenderError(f"{path}: could not write the image")


def _progress(done: int, total: int, started: float) -> None:
    width = 30
    filled = int(width * done / total)
    rate = done / max(time.perf_counter() - started, 1e-9)
    sys.stderr.write(f"\rrendering [{'#' * filled}{'.' * (width - filled)}] {done}/{total} frames, {rate:.1f} fps")
    if done == total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def _render(args) -> int:
    from npga_core.avatar import load_avatar
    from npga_view.gl import GLUnavailableError, create_headless_context
    from npga_view.renderer import SplatRenderer

    out: Path = args.out
    suffix = out.suffix.lower()
    if suffix not in IMAGE_SUFFIXES + (".npy", ".mp4"):
        raise RenderError(f"--out {out}: unsupported extension (use .png, .jpg, .npy or .mp4)")
    if suffix == ".mp4" and args.sequence is None:
        raise RenderError("--out .mp4 needs --sequence")
    if suffix != ".mp4" and args.sequence is not None and args.frame is None:
        raise RenderError("a single image from --sequence needs --frame K (or write a .mp4)")
    if not out.parent.is_dir():
        raise RenderError(f"--out {out}: folder {out.parent} does not exist")
    background = parse_background(args.background)
    avatar = load_avatar(args.avatar)
    codes, fps = _codes(args, avatar)
    camera = _camera(args, avatar.cloud.means)
    try:
        ctx = create_headless_context()
    except GLUnavailableError as exc:
        raise RenderError(str(exc)) from None
    renderer = SplatRenderer(ctx, camera.width, camera.height)
    frames = _Frames(avatar, renderer, camera, args.mode, background, not args.no_cnn)
    if suffix != ".mp4":
        image, picture = frames.render(None if codes is None else codes[0])
        if suffix == ".npy":
            np.save(out, image.astype(np.float32))
        else:
            _write_image(out, picture)
        return 0

    import cv2

    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (camera.width, camera.height))
    if not writer.isOpened():
        raise RenderError(f"{out}: could not open an mp4v video writer")
    started = time.perf_counter()
    try:
        for i, code in enumerate(codes):
            _, picture = frames.render(code)
            writer.write(np.ascontiguousarray(picture[..., ::-1]))
            _progress(i + 1, len(codes), started)
    finally:
        writer.release()
    return 0


def run(args: argparse.Namespace) -> int:
    """Run `render`; argument and input problems print one line on stderr and return 2."""
    try:
        return _render(args)
    except (RenderError, ValueError, OSError) as exc:
        print(f"npga-view render: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
