"""`npga-view export AVATAR --format lam-zip --out AVATAR.zip`: the avatar as a LAM-style web avatar zip that LAM's
web player plays live from ARKit weights, and `AVATAR.fidelity.json` beside it with the held-out centre error."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

FIDELITY_SUFFIX = ".fidelity.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--take", action="append", default=[], metavar="TAKE",
                   help="with --format lam-zip: an ARKit take (Live Link Face .csv, ARKit .json) whose frames train "
                   "the fitted morph targets of a neural avatar (repeatable; 'generated' adds generated frames). "
                   "Default: generated frames (each ARKit shape at 1, then random sparse combinations)")
    p.add_argument("--test-take", metavar="TAKE", help="with --format lam-zip: the take held out to measure the "
                   "export's centre error (default: the last of several --take, the last 20%% of one, else "
                   "generated frames)")
    p.add_argument("--frames", type=int, default=240, metavar="N", help="with --format lam-zip: at most N training "
                   "frames, spread over the takes (default 240; the held-out set at most N/2)")


def fidelity_path(out: Path) -> Path:
    return out.with_name(out.stem + FIDELITY_SUFFIX)


class _Ticker:
    """Progress on stderr, at most once a second."""

    def __init__(self, what: str):
        self.what, self.last = what, 0.0

    def __call__(self, done: int, total: int) -> None:
        if not sys.stderr.isatty():
            return
        now = time.monotonic()
        if now - self.last >= 1.0 or done == total:
            self.last = now
            end = "\n" if done == total else "\r"
            print(f"npga-view export: {self.what} {done}/{total}", end=end, file=sys.stderr, flush=True)


def _check(args: argparse.Namespace) -> None:
    from npga_core.files.lam_export import LamExportError, check_target

    out: Path = args.out
    for flag in ("expr", "sequence", "frame"):
        if getattr(args, flag, None) is not None:
            raise LamExportError(f"--{flag} is for --format ply (a LAM zip is driven live by ARKit weights)")
    if getattr(args, "head_pose", "off") != "off":
        raise LamExportError("--head-pose is for --format ply")
    if out.suffix.lower() != ".zip":
        raise LamExportError(f"--out {out}: a LAM web avatar is a .zip file")
    if not 8 <= args.frames <= 100_000:
        raise LamExportError(f"--frames {args.frames}: give 8..100000")
    check_target(out)
    check_target(fidelity_path(out), "fidelity report")


def build(avatar, args: argparse.Namespace) -> tuple:
    """(web avatar, translation, fit info or None, fidelity dict)."""
    from npga_core.files.lam_export import check_capacity
    from npga_core.posing import lam_fit

    names = lam_fit.target_names(avatar)
    check_capacity(len(avatar), len(names))
    lam_fit.require_drivable(avatar)
    train, test = lam_fit.plan_frames(list(args.take), args.test_take, names, args.frames, max(args.frames // 2, 4))
    centres = lam_fit.Centres(avatar, names)
    info = None
    if lam_fit.is_exact(avatar):
        web, shift = lam_fit.exact_web_avatar(avatar, names)
    else:
        web, shift, info = lam_fit.fit_web_avatar(avatar, names, train, centres, _Ticker("posing training frames"))
    fidelity = lam_fit.measure(web, shift, centres, test, _Ticker("posing held-out frames"))
    return web, shift, info, fidelity


def _report(avatar_name: str, web, shift: np.ndarray, info: dict | None, fid: dict) -> dict:
    from npga_core.files.lam import PLAYER
    from npga_core.files.lam_export import LOST_EXACT, LOST_NEURAL, texels

    exact = info is None
    return {"avatar": avatar_name, "player": PLAYER, "gaussians": len(web), "morph_targets": list(web.names),
            "texels": texels(len(web), len(web.names)), "export": "exact" if exact else "fitted",
            "translation_m": [float(v) for v in shift],
            "lost": LOST_EXACT if exact else LOST_NEURAL, "fit": info, "held_out": fid}


def fidelity_line(fid: dict) -> str:
    return (f"held-out centre error over {fid['frames']} frames of {fid['frames_from']}: RMS "
            f"{fid['rms_m'] * 1e3:.4f} mm, p99 {fid['p99_m'] * 1e3:.4f} mm, max {fid['max_m'] * 1e3:.4f} mm "
            f"({fid['rms_of_head']:.2e} / {fid['p99_of_head']:.2e} of the head size {fid['head_size_m'] * 1e3:.0f} "
            f"mm; the exact centres move {fid['motion_rms_m'] * 1e3:.3f} mm RMS)")


def _summary(doc: dict) -> list[str]:
    fid = doc["held_out"]
    lines = [f"export: {doc['export']} ({doc['gaussians']:,} Gaussians, {len(doc['morph_targets'])} ARKit morph "
             f"targets, {doc['texels']:,} of the player's 8,388,608 texels)"]
    if doc["fit"]:
        fit = doc["fit"]
        lines.append(f"fitted on {fit['frames']} frames: {fit['frames_from']}")
        if fit["channels_never_moved_in_training"]:
            lines.append("never moved in training (their targets stay near 0): "
                         + ", ".join(fit["channels_never_moved_in_training"]))
    lines.append(fidelity_line(fid))
    if any(doc["translation_m"]):
        t = doc["translation_m"]
        lines.append(f"moved by ({t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}) m into LAM's frame (head at y 1.65 m, where the "
                     "player's camera looks)")
    lines.append(f"lost: {doc['lost']}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Write the zip and its fidelity report; one line and exit 2 for bad arguments, targets or avatars."""
    from npga_core.files.lam_export import LamExportError, write_json, write_lam_zip
    from npga_core.files.loading import load_avatar
    from npga_core.posing.lam_fit import FitError

    out: Path = args.out
    try:
        _check(args)
        avatar = load_avatar(args.avatar)
        web, shift, info, fid = build(avatar, args)
        doc = _report(str(args.avatar), web, shift, info, fid)
        web.notes["fidelity"] = fidelity_line(fid)
        if any(shift):
            web.notes["placed"] = f"translated by {[round(float(v), 5) for v in shift]} m into LAM's frame"
        web.notes["lost"] = doc["lost"]
        size = write_lam_zip(out, web, str(args.avatar))
        write_json(fidelity_path(out), doc)
    except (LamExportError, FitError) as e:
        print(f"npga-view export: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"npga-view export: error: {out}: {e.strerror or e}", file=sys.stderr)
        return 2
    for line in _summary(doc):
        print(line)
    print(f"wrote {out} ({size / 2**20:.1f} MiB) and {fidelity_path(out)}")
    return 0
