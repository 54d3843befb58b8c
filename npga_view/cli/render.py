"""`npga-view render AVATAR --out PATH`: headless rendering to PNG, NPY or (with --sequence) MP4.

Besides rgb, depth, alpha and latent, `--mode` takes the inspection modes of `npga_core.inspection.inspector` (features,
feature:K, latent:K, offset, laplacian, sensitivity, opacity, scale) and the views points, ellipsoids and knn;
their pictures get a legend strip (colour bar, value range, label) below the image (`--no-legend` omits it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_core.camera.cameras import DEFAULT_HEIGHT, DEFAULT_WIDTH, Camera, frame_points
from npga_core.errors import CommandError
from npga_core.posing.precision import PRECISION_HELP

if TYPE_CHECKING:
    from npga_core.inspection.inspector import InspectSettings

RENDER_MODES = ("rgb", "depth", "alpha", "latent")
#: inspection modes (npga_core.inspection.inspector); feature:K and latent:K take a channel
INSPECT_MODES = ("features", "feature:K", "latent:K", "offset", "laplacian", "sensitivity", "opacity", "scale",
                 "points", "ellipsoids", "knn")
_Vec3 = tuple[float, float, float]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class RenderError(CommandError):
    """A problem with the arguments or inputs of `render`, reported as one line with exit code 2."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")
    p.add_argument("--flame-model", default=None, help="your FLAME model pickle: opens a GaussianAvatars output "
                   "folder (or its point_cloud.ply) as the avatar")
    p.add_argument("--out", required=True, type=Path,
                   help="output: an image (.png/.jpg), raw floats (.npy), or a video (.mp4, needs --sequence)")
    p.add_argument("--camera", type=Path, help="camera JSON (width, height, fx, fy, cx, cy, world_to_camera); "
                   "default: a front view framing the head")
    p.add_argument("--background", default="0,0,0", help="background colour R,G,B in 0..1 (or 0..255)")
    p.add_argument("--width", type=int, help=f"image width (default: the camera's, else {DEFAULT_WIDTH})")
    p.add_argument("--height", type=int, help=f"image height (default: the camera's, else {DEFAULT_HEIGHT})")
    p.add_argument("--mode", type=_mode, default="rgb", metavar="MODE",
                   help="rgb; depth (.npy: expected depth per pixel; picture: camera depth per Gaussian); alpha; "
                   "latent (.npy: the composited latent channels; picture: PCA colours of h); " + ", ".join(
                       INSPECT_MODES[:-3]) + " (colour modes, see npga_core/inspection/inspector.py); points, "
                   "ellipsoids (geometry views); knn (the kNN graph over the splats)")
    g = p.add_argument_group("inspection modes")
    g.add_argument("--offset-source", default="sum", metavar="NET",
                   help="offset mode: sum (all networks) or one network by name (F, G; an imported avatar's own)")
    g.add_argument("--offset-attr", choices=("position", "rotation", "scale", "opacity", "colour"),
                   default="position", help="offset mode: which attribute's offset (all but position come from G)")
    g.add_argument("--laplacian-of", default="features", metavar="X",
                   help="laplacian mode: features, G (all of G's offsets) or one G block (position, scale, ...)")
    g.add_argument("--direction", type=int, default=1, metavar="K",
                   help="sensitivity mode: PCA direction of the expression space, 1 = largest variance")
    g.add_argument("--scale-measure", choices=("size", "anisotropy"), default="size", help="scale mode")
    g.add_argument("--cmap", default="", help="colour map: viridis, turbo, coolwarm, grey (NAME_r reverses)")
    g.add_argument("--range", dest="value_range", metavar="LO,HI", help="fixed colour-map range")
    g.add_argument("--style", choices=("splats", "points", "ellipsoids"), help="draw style for any colour mode")
    g.add_argument("--point-size", type=float, default=2.0, help="disc radius in pixels of the points style")
    g.add_argument("--k", type=int, default=8, help="neighbours of the kNN graph (knn and laplacian modes)")
    g.add_argument("--knn-colour", choices=("length", "feature", "stretch"), default="length",
                   help="knn mode: colour edges by canonical length, feature difference or stretch")
    g.add_argument("--knn-around", type=int, metavar="ID", help="knn mode: only the neighbours of Gaussian ID")
    g.add_argument("--highlight", metavar="ATTR=LO,HI", help="draw Gaussians outside the range of an attribute "
                   "(opacity, size, anisotropy, feature:K, latent:K, offset, offset:F, offset:G) grey and faint")
    g.add_argument("--filter", metavar="ATTR=LO,HI", help="hide Gaussians outside the range of an attribute")
    g.add_argument("--clip-box", metavar="X0,Y0,Z0,X1,Y1,Z1", help="hide Gaussians outside this box")
    g.add_argument("--clip-plane", metavar="X,Y,Z,NX,NY,NZ",
                   help="hide Gaussians behind the plane through X,Y,Z with normal NX,NY,NZ")
    g.add_argument("--no-legend", action="store_true", help="no legend strip below the picture")
    g.add_argument("--counts", action="store_true",
                   help="print the Gaussian counts (total, in the frustum, drawn, per part) as JSON on stdout")
    p.add_argument("--expr", help="expression code .npy, (D,) or (T, D) with --frame choosing the row; or a named "
                   "expression of the avatar ('jaw open'); or blendshape weights 'jawOpen=0.8,eyeBlinkLeft=1'")
    p.add_argument("--basis", type=Path, default=None,
                   help="a blendshape basis .npz (npga-view fit-blendshapes) for the avatar: ARKit takes "
                        "go through it instead of the avatar's own")
    p.add_argument("--sequence", type=Path, help="expression sequence (.npzseq/.npz/.npy or a tracking folder) or an "
                   "ARKit take (.csv, .json) read through the avatar's blendshape basis")
    p.add_argument("--frame", type=int, default=None, help="frame of --sequence/--expr for a single image")
    p.add_argument("--head-pose", choices=("off", "relative", "absolute"), default="off",
                   help="move the head as the --sequence's tracked pose: relative to its first frame (for the "
                   "default framing) or as tracked (for a rig --camera); default off")
    p.add_argument("--no-cnn", action="store_true", help="skip the avatar's screen-space CNN refinement")
    p.add_argument("--precision", default="fp32", metavar="fp32|bf16|auto", help=PRECISION_HELP)
    p.add_argument("--timeline", type=Path, help="keyframe timeline JSON (expression and camera keys) to render as "
                   "a video (.mp4)")
    p.add_argument("--verbose", action="store_true", help="print which renderer path and OpenGL version run")
    p.add_argument("--fps", type=float, default=None, help="frame rate of a --timeline video (default 25), or of a "
                   "--sequence video: an ARKit take is resampled to it by its timecodes, other sequences play at it "
                   "(default: the sequence's own)")


def _mode(text: str) -> str:
    """argparse type of --mode: a render mode, an inspection mode, or feature:K / latent:K."""
    name, _, arg = text.partition(":")
    if text in RENDER_MODES or (text in INSPECT_MODES and ":" not in text):
        return text
    if name in ("feature", "latent") and arg.isdigit():
        return text
    raise argparse.ArgumentTypeError(f"unknown mode {text!r}; choose from {', '.join(RENDER_MODES + INSPECT_MODES)}")


def _numbers(text: str, count: int, option: str) -> tuple[float, ...]:
    """`count` finite comma-separated numbers, or RenderError naming the option."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(np.isfinite(values)):
        raise RenderError(f"{option} {text!r}: expected {count} comma-separated numbers")
    return values


def parse_range(text: str | None, option: str = "--range") -> tuple[float, float] | None:
    """'LO,HI' -> (lo, hi) with lo < hi."""
    if text is None:
        return None
    lo, hi = _numbers(text, 2, option)
    if not lo < hi:
        raise RenderError(f"{option} {text!r}: needs LO < HI")
    return lo, hi


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
        from npga_core.files.rig import load_camera
        from npga_core.files.untrusted import MAX_IMAGE_SIDE

        cam = load_camera(args.camera)  # untrusted JSON: regular file, size, depth and number bounds
        if max(cam.width, cam.height) > MAX_IMAGE_SIDE:
            raise RenderError(f"{args.camera}: image {cam.width}x{cam.height} is larger than {MAX_IMAGE_SIDE} "
                              "pixels on a side")
        if args.width or args.height:
            cam = cam.resized(args.width or cam.width, args.height or cam.height)
        return cam
    return frame_points(framing_points, args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT)


def _codes(args, avatar) -> tuple[np.ndarray | None, float, list[np.ndarray] | None]:
    """(T, D) codes to render (None: the mean code), the frame rate and, with --head-pose, each frame's head
    transform (4x4)."""
    from npga_core.posing.headpose import head_transforms

    source = args.sequence or args.expr
    if args.sequence is not None and args.expr is not None:
        raise RenderError("give either --expr or --sequence, not both")
    if args.head_pose != "off" and args.sequence is None:
        raise RenderError("--head-pose needs --sequence")
    if source is None:
        if args.frame is not None:
            raise RenderError("--frame needs --sequence or --expr")
        return None, 25.0, None
    if avatar.code_dim == 0:
        raise RenderError(f"{source}: the avatar is static (no dynamics), it takes no expression codes")
    from npga_view.cli.expr_arg import expr_code, load_with_notes

    named = None if args.expr is None else expr_code(args.expr, avatar, args.frame, RenderError)
    if named is not None:
        return named[None], 25.0, None
    seq = load_with_notes(avatar, source, args.fps)
    seq.check_dim(avatar.code_dim, source)
    frames: range | list[int]
    codes, frames = seq.codes, range(len(seq))
    if args.frame is not None:
        if not 0 <= args.frame < len(codes):
            raise RenderError(f"--frame {args.frame}: {source} has frames 0..{len(codes) - 1}")
        codes, frames = codes[args.frame:args.frame + 1], [args.frame]
    poses = None if args.head_pose == "off" else head_transforms(seq, frames, args.head_pose, source)
    return codes, seq.fps, poses


def _timeline(args, avatar, camera: Camera) -> tuple[list, list[Camera], float]:
    """Per-frame codes (None: the mean code) and cameras of --timeline at --fps over its duration."""
    from npga_core.editing.keyframes import KeyframeTimeline

    fps = 25.0 if args.fps is None else args.fps
    if not (np.isfinite(fps) and 0 < fps <= 1000):
        raise RenderError(f"--fps {fps}: must be in (0, 1000]")
    tl = KeyframeTimeline.load(args.timeline)
    if tl.expression and avatar.code_dim == 0:
        raise RenderError(f"{args.timeline}: the avatar is static (no dynamics), it takes no expression keys")
    tl.check_code_dim(avatar.code_dim, args.timeline)
    try:
        times = tl.frame_times(fps)
    except ValueError as exc:
        raise RenderError(f"{args.timeline}: {exc}") from None
    cameras = [tl.camera_at(t, camera.width, camera.height) or camera for t in times]
    return [tl.code_at(t) for t in times], cameras, float(fps)


def inspect_settings(args) -> InspectSettings:
    """The `InspectSettings` of the command line's mode and options."""
    from npga_core.inspection.inspector import InspectSettings

    mode = args.mode
    s = InspectSettings(offset_source=args.offset_source, offset_attr=args.offset_attr, laplacian_of=args.laplacian_of,
                        direction=args.direction - 1, scale_measure=args.scale_measure, cmap=args.cmap,
                        value_range=parse_range(args.value_range), point_px=args.point_size, knn_k=args.k,
                        knn_colour=args.knn_colour)
    if mode in ("points", "ellipsoids"):
        s.style = mode
    elif mode == "knn":
        s.knn_show = "picked" if args.knn_around is not None else "all"
        s.picked = args.knn_around
    elif mode != "rgb":
        s.mode = mode
    if args.style:
        s.style = args.style
    for action in ("highlight", "filter"):
        text = getattr(args, action)
        if text is not None:
            attr, eq, rng = text.partition("=")
            if not eq:
                raise RenderError(f"--{action} {text!r}: expected ATTR=LO,HI")
            s.hist_attr, s.hist_range, s.hist_action = attr, parse_range(rng, f"--{action}"), action
    if args.clip_box is not None:
        v = _numbers(args.clip_box, 6, "--clip-box")
        s.clip, s.clip_lo, s.clip_hi = "box", cast(_Vec3, v[:3]), cast(_Vec3, v[3:])
    if args.clip_plane is not None:
        v = _numbers(args.clip_plane, 6, "--clip-plane")
        s.clip, s.clip_point, s.clip_normal = "plane", cast(_Vec3, v[:3]), cast(_Vec3, v[3:])
    if s.direction < 0:
        raise RenderError(f"--direction {args.direction}: directions count from 1")
    return s


def _write_image(path: Path, picture: np.ndarray) -> None:
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 9] if path.suffix.lower() == ".png" else []
    write_image(path, np.ascontiguousarray(picture[..., ::-1]), params)


def write_image(path: Path, bgr: np.ndarray, params: list[int] | None = None) -> None:
    """`npga_core.files.image_file.write_image`, its error as a RenderError (one line, exit 2)."""
    from npga_core.files.image_file import ImageWriteError
    from npga_core.files.image_file import write_image as write

    try:
        write(path, bgr, params)
    except ImageWriteError as e:
        raise RenderError(str(e)) from None


def _progress(done: int, total: int, started: float) -> None:
    width = 30
    filled = int(width * done / total)
    rate = done / max(time.perf_counter() - started, 1e-9)
    sys.stderr.write(f"\rrendering [{'#' * filled}{'.' * (width - filled)}] {done}/{total} frames, {rate:.1f} fps")
    if done == total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def _check_output(args) -> str:
    """The --out suffix, once the output and the options that go with it agree (RenderError otherwise)."""
    out: Path = args.out
    suffix = out.suffix.lower()
    if suffix not in IMAGE_SUFFIXES + (".npy", ".mp4"):
        raise RenderError(f"--out {out}: unsupported extension (use .png, .jpg, .npy or .mp4)")
    if suffix == ".mp4" and args.sequence is None and args.timeline is None:
        raise RenderError("--out .mp4 needs --sequence or --timeline")
    if args.timeline is not None and suffix != ".mp4":
        raise RenderError("--timeline renders a video: give --out a .mp4 path")
    if args.timeline is not None and (args.sequence or args.expr or args.frame is not None):
        raise RenderError("--timeline sets the expressions itself: leave out --sequence, --expr and --frame")
    if suffix != ".mp4" and args.sequence is not None and args.frame is None:
        raise RenderError("a single image from --sequence needs --frame K (or write a .mp4)")
    if not out.parent.is_dir():
        raise RenderError(f"--out {out}: folder {out.parent} does not exist")
    from npga_core.files.atomic import check_output

    check_output(out, "the render")  # before any work: a folder, FIFO or device in its place is refused
    return suffix


def _render(args) -> int:
    from npga_core.errors import shown
    from npga_core.files.loading import load_avatar
    from npga_core.posing.headpose import posed_camera
    from npga_view.rendering.factory import create_renderer, describe
    from npga_view.rendering.gl import GLUnavailableError, create_headless_context

    out: Path = args.out
    suffix = _check_output(args)
    background = parse_background(args.background)
    from npga_core.posing.precision import check_precision

    check_precision(getattr(args, "precision", "fp32"))
    avatar = load_avatar(args.avatar, args.flame_model)
    if args.basis is not None:
        from npga_core.files.basis_file import attach_basis

        attach_basis(avatar, args.basis)
    codes: np.ndarray | list | None
    codes, fps, poses = _codes(args, avatar)
    camera = _camera(args, avatar.cloud.means)
    cameras = None if poses is None else [posed_camera(camera, t) for t in poses]
    if args.timeline is not None:
        codes, cameras, fps = _timeline(args, avatar, camera)
    try:
        ctx = create_headless_context()
        renderer = create_renderer(ctx, camera.width, camera.height)
        renderer.precise_colour = True  # written as floats: no 16-bit colour target
    except GLUnavailableError as exc:
        raise RenderError(str(exc)) from None
    if getattr(args, "verbose", False):
        print(f"renderer: {describe(renderer)}", file=sys.stderr)
    from npga_view.rendering.offscreen import OffscreenFrames
    from npga_view.signals import interruptible

    cnn = avatar.cnn  # on a helper thread: SIGTERM/SIGINT end a CNN of minutes at once
    runner = None if cnn is None else partial(interruptible, cnn.refine)
    frames = OffscreenFrames(avatar, renderer, camera if cameras is None else cameras[0], args.mode, background,
                             inspect_settings(args), legend=not args.no_legend,
                             raw_npy=str(args.out).lower().endswith(".npy"), use_cnn=not args.no_cnn,
                             precision=getattr(args, "precision", "fp32"),
                             source=str(args.timeline or args.sequence or args.expr or args.avatar),
                             cnn_runner=runner)
    if getattr(args, "verbose", False) and avatar.dynamics is not None:
        print(f"exact dynamics: {frames.poses.precision}", file=sys.stderr)
    if len(avatar.cloud) == 0:
        print(f"note: {shown(args.avatar)} has no Gaussians; the image is empty")
    if suffix != ".mp4":
        image, picture = frames.render(None if codes is None else codes[0])
        if suffix == ".npy":
            from npga_core.files.atomic import atomic_write

            atomic_write(out, lambda fh: np.save(fh, image.astype(np.float32)))
        else:
            _write_image(out, picture)
        if args.counts:
            print(json.dumps(frames.counts))
        return 0

    from npga_view.video import VideoWriter

    assert codes is not None  # _check_output: a video needs --sequence or --timeline

    # H.264 MP4 at the sequence's (or --timeline's --fps) rate; odd sizes lose their last row/column (yuv420p)
    from npga_core.inspection.legend import LEGEND_HEIGHT

    legend = LEGEND_HEIGHT if frames.inspecting and frames.legend else 0
    started = time.perf_counter()
    with VideoWriter(out, camera.width, camera.height + legend, fps=float(fps)) as writer:
        for i, code in enumerate(codes):
            if cameras is not None:
                frames.camera = cameras[i]
            _, picture = frames.render(code)
            writer.write(picture)
            _progress(i + 1, len(codes), started)
    return 0


def run(args: argparse.Namespace) -> int:
    """Run `render`; argument and input problems print one line on stderr and return 2."""
    try:
        return _render(args)
    except (RenderError, ValueError, OSError) as exc:
        print(f"npga-view render: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
