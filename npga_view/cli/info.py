"""`npga-view info PATH`: a readable summary of an avatar file."""

from __future__ import annotations

import argparse
import time

from npga_core.files.loading import load_avatar
from npga_core.files.summary import summary, take_summary
from npga_core.model.avatar import Avatar


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", help="a .npga checkpoint, a 3DGS .ply, or 'demo'")
    p.add_argument("--flame-model", default=None, help="your FLAME model pickle: opens a GaussianAvatars output "
                   "folder (or its point_cloud.ply) as the avatar")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from npga_core.files.arkit_takes import TAKE_SUFFIXES

    if Path(args.path).suffix.lower() in TAKE_SUFFIXES and not Path(args.path).is_dir():
        print(take_summary(args.path))
        return 0
    t0 = time.perf_counter()
    avatar = load_avatar(args.path, args.flame_model)
    dt = time.perf_counter() - t0
    print(summary(avatar, avatar.source or args.path, dt))
    from npga_view.rendering.factory import headless_path_line

    print(headless_path_line())
    print(precision_line(avatar))
    return 0


def precision_line(avatar: Avatar) -> str:
    """Which number format the exact dynamics take here with `--precision auto`, and why."""
    from npga_core.posing.precision import describe

    if avatar.dynamics is None or len(avatar) == 0:
        return f"exact dynamics: none ({describe()})"
    from npga_core.posing.fastpose import FastPoser

    poser = FastPoser(avatar, threads=1, precision="auto")
    err = "" if poser.fidelity_error is None else \
        f", bf16 error {poser.fidelity_error:.3f} (limit {FastPoser.BF16_TOLERANCE})"
    return f"exact dynamics: {poser.precision} with --precision auto ({describe()}{err})"
