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
LEGEND_HEIGHT = 64
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


def _fmt(v: float) -> str:
    return f"{v:.3g}" if v == 0 or 1e-3 <= abs(v) < 1e4 else f"{v:.2e}"


def _wrap(text: str, width_px: int, scale: float) -> list[str]:
    import cv2

    lines, line = [], ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > width_px:
            lines.append(line)
            line = word
        else:
            line = trial
    return lines + ([line] if line else [])


def legend_strip(width: int, label: str, cmap: str | None = None, lo: float = 0.0, hi: float = 1.0,
                 notes: tuple[str, ...] = (), height: int = LEGEND_HEIGHT) -> np.ndarray:
    """An (height, width, 3) uint8 RGB legend: the label, then a colour bar from lo to hi with their values (when
    `cmap` is given) or the notes as text."""
    import cv2

    from npga_core.inspection.colouring import colour_map

    strip = np.full((height, width, 3), 24, np.uint8)
    font, scale, white = cv2.FONT_HERSHEY_SIMPLEX, 0.38, (235, 235, 235)
    y = 14
    for line in _wrap(label, width - 16, scale)[:2]:
        cv2.putText(strip, line, (8, y), font, scale, white, 1, cv2.LINE_AA)
        y += 14
    if cmap is not None:
        bar = colour_map(np.linspace(0.0, 1.0, width - 16), cmap)
        y0 = min(y - 6, height - 30)
        strip[y0:y0 + 12, 8:width - 8] = (bar * 255 + 0.5).astype(np.uint8)[None]
        ty = y0 + 26
        cv2.putText(strip, _fmt(lo), (8, ty), font, scale, white, 1, cv2.LINE_AA)
        mid = _fmt(0.5 * (lo + hi))
        tw = cv2.getTextSize(mid, font, scale, 1)[0][0]
        cv2.putText(strip, mid, ((width - tw) // 2, ty), font, scale, white, 1, cv2.LINE_AA)
        tw = cv2.getTextSize(_fmt(hi), font, scale, 1)[0][0]
        cv2.putText(strip, _fmt(hi), (width - 8 - tw, ty), font, scale, white, 1, cv2.LINE_AA)
    else:
        for note in notes:
            for line in _wrap(note, width - 16, scale):
                if y < height - 2:
                    cv2.putText(strip, line, (8, y), font, scale, (190, 190, 190), 1, cv2.LINE_AA)
                y += 14
    return strip


class _Frames:
    """Renders the avatar at a code in the requested mode."""

    def __init__(self, avatar, renderer, camera: Camera, args, background) -> None:
        from npga_core.inspection.inspector import Inspector
        from npga_core.posing.oneshot import ExactPoses

        self.avatar, self.renderer, self.camera = avatar, renderer, camera
        self.poses = ExactPoses(avatar, getattr(args, "precision", "fp32"))
        self.source = args.timeline or args.sequence or args.expr or args.avatar  # named when a pose overflows
        self.mode, self.background, self.legend = args.mode, background, not args.no_legend
        self.raw_npy = str(args.out).lower().endswith(".npy")
        self.use_cnn = not args.no_cnn and self.mode == "rgb" and avatar.cnn is not None
        self.settings = inspect_settings(args)
        shaping = self.settings.style != "splats" or self.settings.hist_action != "off" or self.settings.clip != "off"
        self.inspecting = ((self.mode not in ("rgb", "alpha") or shaping)
                           and not (self.raw_npy and self.mode in ("depth", "latent")))
        if self.mode in ("depth", "latent"):
            self.settings.mode = self.mode
        self.inspector = Inspector(avatar)
        self.counts: dict | None = None

    def render(self, code: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(raw float image, uint8 RGB picture); AvatarFileError naming `self.source` when the posed Gaussians
        are not finite (the file's numbers overflow in the dynamics or the pose)."""
        from npga_core.files.untrusted import finite_output

        r, cam = self.renderer, self.camera
        posed = self.poses.pose(code)
        finite_output({k: getattr(posed, k) for k in ("means", "quats", "scales", "opacities", "sh")},
                      self.source, "the posed Gaussians")
        if self.inspecting:
            return self._inspect(posed, code)
        r.set_gaussians(posed)
        if self.mode == "latent":
            if r.latent_dim == 0:
                raise RenderError("--mode latent: the avatar has no latent features")
            image = r.render_latent(cam)
            self._count(posed)
            return image, to_display(image, "latent")
        if self.mode == "depth":
            image = r.render(cam, mode="depth")
            self._count(posed)
            return image, to_display(image, "depth", r.render(cam, mode="alpha"))
        image = r.render(cam, self.background, self.mode)
        self._count(posed)
        if self.use_cnn:  # the window's Refiner takes the same path (npga_view/rendering/refinement.py)
            from npga_view.cli.signals import interruptible
            from npga_view.rendering.refinement import refine_frame

            cnn = self.avatar.cnn  # on a helper thread: SIGTERM/SIGINT end a CNN of minutes at once
            image = refine_frame(r, cnn, cam, self.background, rgb=image, runner=lambda x: interruptible(cnn.refine, x))
        return image, to_display(image, self.mode)

    def _inspect(self, posed, code) -> tuple[np.ndarray, np.ndarray]:
        r, cam, s = self.renderer, self.camera, self.settings
        frame = self.inspector.frame(s, posed, code, cam)
        r.show(frame)
        image = r.render(cam, self.background)
        self._count(posed)
        picture = to_display(image, "rgb")
        c = frame.colouring
        if c is not None and s.value_range is None and c.cmap is not None:
            s.value_range = (c.lo, c.hi)  # later frames of a video keep the first frame's range
        if self.legend:
            picture = np.concatenate([picture, self._legend(frame, posed)], axis=0)
        return image, picture

    def _visibility_note(self) -> str:
        s = self.settings
        notes = []
        if s.hist_action != "off":
            lo, hi = cast(tuple[float, float], s.hist_range)  # set with the action
            notes.append(f"{s.hist_attr} {_fmt(lo)}..{_fmt(hi)} {'only' if s.hist_action == 'filter' else 'bright'}")
        if s.clip == "box":
            notes.append("clipped to a box")
        elif s.clip == "plane":
            notes.append(f"clipped by the plane n = {_fmt(s.clip_normal[0])}, {_fmt(s.clip_normal[1])}, "
                         f"{_fmt(s.clip_normal[2])}")
        return "; ".join(notes)

    def _legend(self, frame, posed) -> np.ndarray:
        legend = self._legend_of(frame, posed)
        note = self._visibility_note()
        if note:
            import cv2

            cv2.putText(legend, note, (8, legend.shape[0] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.33, (255, 210, 80), 1,
                        cv2.LINE_AA)
        return legend

    def _legend_of(self, frame, posed) -> np.ndarray:
        s, w = self.settings, self.camera.width
        if self.mode == "knn" and s.knn_show == "all":
            from npga_core.inspection.graph import knn_edges

            edges = knn_edges(self.inspector.graph(s.knn_k))
            c = self.inspector.edge_colouring(s.knn_colour, edges, posed.means)
            return legend_strip(w, f"{c.label}, k = {s.knn_k}, {len(edges):,} edges", c.cmap, c.lo, c.hi)
        if self.mode == "knn":
            return legend_strip(w, f"the {s.knn_k} nearest neighbours of Gaussian {s.picked} (canonical kNN graph)")
        c = frame.colouring
        if c is None:
            if frame.style == "splats":
                return legend_strip(w, "colour: the Gaussians' own (SH) colour")
            what = {"points": f"points: opaque discs of {s.point_px:g} px",
                    "ellipsoids": "ellipsoids: the 1-sigma ellipse of each Gaussian, shaded"}[frame.style]
            return legend_strip(w, what, notes=(f"SH colour; opacity < {self.renderer.style_min_opacity:g} hidden",))
        return legend_strip(w, c.label, c.cmap, c.lo, c.hi, c.notes)

    def _count(self, posed) -> None:
        if self.counts is None:
            from npga_view.rendering.renderer import NEAR

            c = self.inspector.counts(self.camera, posed, self.renderer.drawn_mask(), NEAR)
            self.counts = {"total": c.total, "in_frustum": c.in_frustum, "drawn": c.drawn,
                           "parts": {name: {"total": t, "in_frustum": f, "drawn": d} for name, t, f, d in c.parts}}


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
    except GLUnavailableError as exc:
        raise RenderError(str(exc)) from None
    if getattr(args, "verbose", False):
        print(f"renderer: {describe(renderer)}", file=sys.stderr)
    frames = _Frames(avatar, renderer, camera if cameras is None else cameras[0], args, background)
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
