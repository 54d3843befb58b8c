"""`npga-view evaluate AVATAR --capture DIR --out REPORT/`: the avatar rendered from each captured view and scored.

Every selected (frame, camera) is rendered headless with the capture's own camera (its resolution and intrinsics,
so pixels correspond), through the CNN when the avatar has one, and scored with PSNR, SSIM and (when its weights
are on the machine) LPIPS (`npga_core.evaluation.metrics`). Masking: with the capture's masks, capture and render
are both composited on `--background` outside the mask (as the paper's evaluation does), else whole images.
Writes metrics.csv, summary.md, metrics.png (metrics over frames), the worst views' capture/render/difference
PNGs and problems.txt (one line per missing or unreadable file).

`--protocol npga` follows the paper's evaluation: 550x802 images (captures downsampled to cover, then cropped at
the centre), face masks when the capture has them (else the alpha matte, said in the summary), the frontal
camera held out (only it is scored), a summary laid out like the paper's Table 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError, CommandError
from npga_core.evaluation.report import Row
from npga_core.evaluation.views import NPGA_SIZE, frontal_camera, protocol_view


class EvaluateError(CommandError):
    """Bad arguments or inputs of `evaluate`, one line, exit code 2."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")
    p.add_argument("--capture", required=True, type=Path, help="NeRSemble sequence folder or GHA preprocessed folder")
    p.add_argument("--sequence", type=Path, help="expression codes of the capture's frames (default: neutral), or "
                   "an ARKit take (.csv, .json) of them read through the avatar's blendshape basis")
    p.add_argument("--basis", type=Path, default=None,
                   help="a blendshape basis .npz (npga-view fit-blendshapes) for the avatar: ARKit takes drive it")
    p.add_argument("--cameras", help="comma-separated camera ids (default: all)")
    p.add_argument("--frames", help="frames: A,B,C-D (default: all)")
    p.add_argument("--no-cnn", action="store_true", help="score the splat image, not the CNN's")
    p.add_argument("--background", default="1,1,1", help="background R,G,B (0..1 or 0..255); masked-out pixels")
    p.add_argument("--mask", choices=("auto", "alpha", "face", "none"), default="auto",
                   help="auto: face masks, else alpha mattes, else whole images")
    p.add_argument("--protocol", choices=("npga",), help="the paper's evaluation protocol (see module doc)")
    p.add_argument("--worst", type=int, default=3, help="views whose capture/render/difference are written")
    p.add_argument("--save-renders", action="store_true", help="also write each render as renders/F_CAM.npy")
    p.add_argument("--cache-mb", type=int, default=1024, help="memory for cached capture images")
    p.add_argument("--out", required=True, type=Path, help="report folder (created)")


def _frame_filter(text: str):
    """--frames as a test of a frame number: A,B,C-D (ranges kept as bounds, never expanded: 0-3000000000 is two
    numbers), each number within the frame limit every reader applies."""
    from npga_core.files.untrusted import MAX_FRAMES

    ranges: list[tuple[int, int]] = []
    try:
        for part in text.split(","):
            a, _, b = part.partition("-")
            lo, hi = int(a), int(b) if b else int(a)
            if not (0 <= lo <= hi <= 10 * MAX_FRAMES) or len(ranges) >= 10000:
                raise ValueError
            ranges.append((lo, hi))
    except ValueError:
        raise EvaluateError(f"--frames {text[:60]!r}: expected frame numbers 0..{10 * MAX_FRAMES} and ranges "
                            "like 0,5,10-20") from None
    return lambda f: any(lo <= f <= hi for lo, hi in ranges)


def _progress(i: int, n: int, t0: float) -> None:
    done = int(30 * i / max(n, 1))
    rate = i / max(time.perf_counter() - t0, 1e-9)
    print(f"\r[{'#' * done}{'.' * (30 - done)}] {i}/{n} views, {rate:.1f}/s", end="" if i < n else "\n",
          file=sys.stderr, flush=True)


def run(args) -> int:
    try:
        return _evaluate(args)
    except EvaluateError as e:
        print(f"npga-view evaluate: error: {e}", file=sys.stderr)
        return 2


def _choose_views(args, capture, problems: list[str], notes: list[str]) -> tuple[list[tuple], list, str]:
    """The (frame, camera) views to score, the frames, and the mask kind, as --frames, --cameras, --protocol and
    --mask say (problems and notes collected for the report)."""
    wanted_frame = _frame_filter(args.frames) if args.frames is not None else None
    frames = [f for f in capture.frames if wanted_frame is None or wanted_frame(f)]
    cameras = capture.cameras
    if args.cameras:
        wanted = [c.strip() for c in args.cameras.split(",") if c.strip()]
        problems += [f"{args.capture}: camera {c} is not in the capture" for c in wanted if c not in cameras]
        cameras = [c for c in cameras if c in wanted]
    if args.protocol == "npga":
        held = frontal_camera(capture)
        cameras = [held]
        notes.append(f"protocol npga: {NPGA_SIZE[0]}x{NPGA_SIZE[1]} images (captures downsampled to cover, "
                     f"centre-cropped), held-out frontal camera {held} only")
    from npga_core.evaluation.views import resolve_mask_kind
    mask_kind = resolve_mask_kind(capture, args.mask)
    if mask_kind == "face" and not capture.has_face_masks:
        raise EvaluateError(f"{args.capture}: --mask face, but the capture has no face masks")
    if args.protocol == "npga" and mask_kind != "face":
        notes.append("NO FACE MASKS in this capture: scored inside the alpha matte (neck and torso included), "
                     "so the numbers are not comparable with the paper's Table 1")
    views = [(f, c) for f in frames for c in cameras if (f, c) in capture.views]
    if not views:
        raise EvaluateError(f"{args.capture}: no views left after --frames/--cameras")
    return views, frames, mask_kind


def _load_view(args, capture, v, mask_kind: str, problems: list[str]):
    """(camera, image, mask) of a capture view as scored (the npga protocol's crop applied), or None when the
    view cannot be used (the problem is recorded)."""
    from npga_core.evaluation.views import load_view
    try:
        loaded = load_view(capture, v, mask_kind)
    except AvatarFileError as e:
        problems.append(str(e))
        return None
    cam, image, mask = loaded.camera, loaded.image, loaded.mask
    if args.protocol == "npga":
        try:
            cam, image, mask = protocol_view(cam, image, mask, source=v.image_path)
        except AvatarFileError as e:
            problems.append(str(e))
            return None
    return cam, image, mask


def _render_view(renderer, avatar, cam, background, use_cnn: bool, shape: tuple[int, ...]) -> np.ndarray:
    """The avatar's image for `cam` (through its CNN when `use_cnn`), at the capture image's `shape`."""
    render = renderer.render(cam, background)
    if use_cnn:
        from npga_view.rendering.pipeline import refine_frame
        from npga_view.signals import interruptible
        render = refine_frame(renderer, avatar.cnn, cam, background, rgb=render,
                              runner=lambda x: interruptible(avatar.cnn.refine, x))
        if render.shape[:2] != shape[:2]:  # a CNN that upsamples: area-filtered to the capture's size
            import cv2
            render = cv2.resize(render, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return np.clip(render, 0.0, 1.0)


def _evaluate(args) -> int:
    from npga_core.evaluation.capture import load_capture
    from npga_core.evaluation.metrics import Lpips, lpips_status, score
    from npga_core.evaluation.report import write_report
    from npga_core.evaluation.views import frame_code
    from npga_core.files.image_file import ImageWriteError
    from npga_core.files.loading import load_avatar
    from npga_view.cli.render import parse_background
    from npga_view.rendering.factory import create_renderer
    from npga_view.rendering.gl import GLUnavailableError, create_headless_context

    background = parse_background(args.background)
    capture = load_capture(args.capture, budget_bytes=args.cache_mb << 20)
    problems = list(capture.problems)
    avatar = load_avatar(args.avatar)
    if args.basis is not None:
        from npga_core.files.basis_file import attach_basis

        attach_basis(avatar, args.basis)
    seq = None
    if args.sequence is not None:
        from npga_view.cli.expr_arg import load_with_notes

        seq = load_with_notes(avatar, args.sequence)  # (a take through the avatar's basis)
        seq.check_dim(avatar.code_dim, args.sequence)
    notes: list[str] = []
    views, frames, mask_kind = _choose_views(args, capture, problems, notes)
    ok, lp_note = lpips_status()
    notes.append(lp_note)
    lp = Lpips() if ok else None
    use_cnn = avatar.cnn is not None and not args.no_cnn
    notes.append("images through the avatar's CNN" if use_cnn else "splat images (no CNN)")
    from npga_core.files.atomic import check_output, check_output_folder
    out: Path = check_output_folder(args.out, "the report")
    for name in ("metrics.csv", "summary.md", "metrics.png", "problems.txt"):  # before any view is rendered
        check_output(out / name, "the report")
    if args.save_renders:
        check_output_folder(out / "renders", "the renders")
    try:
        ctx = create_headless_context()
        first = capture.views[views[0]].camera
        renderer = create_renderer(ctx, first.width, first.height)
        renderer.precise_colour = True  # scored as floats: no 16-bit colour target
    except GLUnavailableError as exc:
        raise EvaluateError(str(exc)) from None
    rows: list[Row] = []
    keep: list[tuple[float, int, str, np.ndarray, np.ndarray]] = []
    posed_frame = None
    printed = 0
    t0 = time.perf_counter()
    for i, (f, c) in enumerate(views):
        loaded = _load_view(args, capture, capture.views[(f, c)], mask_kind, problems)
        if loaded is None:
            continue
        cam, image, mask = loaded
        if posed_frame != f:
            found, code = frame_code(seq, frames, f)
            if not found:
                problems.append(f"{args.sequence}: no expression code for frame {f}")
                continue
            renderer.set_gaussians(avatar.pose(code))
            posed_frame = f
        render = _render_view(renderer, avatar, cam, background, use_cnn, image.shape)
        if args.save_renders:
            _save_npy(out / "renders" / f"{f}_{c}.npy", render.astype(np.float32))
        s = score(render, image, mask, background, lp)
        rows.append(Row(f, c, s.psnr, s.ssim, s.lpips, mask_kind if s.masked else "none"))
        keep.append((s.psnr, f, c, image if mask is None else _comp(image, mask, background),
                     render if mask is None else _comp(render, mask, background)))
        keep = sorted(keep, key=lambda k: k[0])[:max(args.worst, 0)]
        _progress(i + 1, len(views), t0)
        printed = i + 1
    if printed < len(views):  # the line ends even when the last views were problems
        _progress(len(views), len(views), t0)
    elapsed = time.perf_counter() - t0
    notes.append(f"{len(rows)} views in {elapsed:.1f} s ({elapsed / max(len(rows), 1) * 1e3:.0f} ms a view)")
    try:
        summary = write_report(out, rows, keep, problems, notes, protocol=args.protocol, avatar=str(args.avatar))
    except ImageWriteError as e:
        raise EvaluateError(str(e)) from None
    print(summary)
    for line in problems:
        print(f"problem: {line}", file=sys.stderr)
    if not rows:
        raise EvaluateError(f"{args.capture}: no view could be scored ({len(problems)} problems, see problems.txt)")
    return 0


def _save_npy(path: Path, array: np.ndarray) -> None:
    from npga_core.files.atomic import atomic_write
    atomic_write(path, lambda fh: np.save(fh, array))


def _comp(image: np.ndarray, mask: np.ndarray, background) -> np.ndarray:
    from npga_core.evaluation.metrics import composite_background
    return composite_background(image, mask, background).astype(np.float32)
