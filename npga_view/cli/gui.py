"""`npga-view [AVATAR] [--sequence SEQ]`: the interactive viewer."""

from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", nargs="?", default="demo", help="a .npga, a 3DGS .ply or 'demo' (default)")
    p.add_argument("--sequence", help="expression sequence (.npzseq, .npz, .npy or a MonoNPHM folder)")
    p.add_argument("--session", help="restore a saved session file")
    p.add_argument("--rig", help="camera rig calibration (NeRSemble camera_params.json)")
    p.add_argument("--play", action="store_true", help="start playing the sequence")
    p.add_argument("--size", default="1360x900", help="window size WxH (default 1360x900)")
    p.add_argument("--screenshot", help="save a window screenshot (PNG) and quit (with --quit-after-frames)")
    p.add_argument("--quit-after-frames", type=int, help="quit after N frames, counted once the avatar is drawn")
    p.add_argument("--threads", type=int, default=2, help="torch threads of the dynamics worker")
    p.add_argument("--device", default="cpu",
                   help="where the dynamics run: cpu (default), cuda, mps or auto (a GPU when torch sees one)")
    p.add_argument("--bake", action="store_true",
                   help="bake the sequence at start and play from the bake (progress in the Timeline panel)")
    p.add_argument("--bake-budget-mb", type=float, default=1024.0, help="memory budget of a bake (default 1024)")


def run(args: argparse.Namespace) -> int:
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"npga-view: error: --size {args.size!r} is not WxH", file=sys.stderr)
        return 2
    if args.screenshot and args.quit_after_frames is None:
        args.quit_after_frames = 3
    try:
        from npga_core.posing.fastpose import resolve_device

        resolve_device(args.device)
    except ValueError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    if args.bake_budget_mb <= 0:
        print("npga-view: error: --bake-budget-mb must be positive", file=sys.stderr)
        return 2
    from npga_view.app import ViewerApp

    try:
        app = ViewerApp(w, h, threads=args.threads, device=args.device)
    except RuntimeError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    opened = app.open_avatar(args.avatar)
    if args.sequence and opened:
        app.open_sequence(args.sequence)
        app.state.timeline.playing = bool(args.play)
        app.state.timeline.bake_budget_mb = args.bake_budget_mb
        if args.bake:
            app.state.actions.append(("bake", None))
    if args.rig:
        app.state.actions.append(("load_rig", args.rig))
    if args.session:
        try:
            app.load_session(args.session)
        except ValueError as e:
            app.state.report(str(e))
    if args.quit_after_frames is not None and app.state.errors:
        # scripted runs fail loudly on bad input instead of screenshotting an error
        msg = app.state.errors[-1]
        app.close()
        print(f"npga-view: error: {msg}", file=sys.stderr)
        return 2
    return app.run(args.screenshot, args.quit_after_frames)
