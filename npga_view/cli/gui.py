"""`npga-view [view] [AVATAR] [--sequence SEQ] ...`: the interactive viewer (the default command).

SIGTERM, SIGINT and SIGHUP close the window as its close button does (unsaved edits autosaved, pose worker
stopped, shared memory unlinked); a second signal ends at once, still through the same cleanup.
"""

from __future__ import annotations

import argparse
import sys

from npga_core.errors import AvatarFileError
from npga_core.posing.precision import PRECISION_HELP
from npga_view.actions import Bake, LoadRig


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", nargs="?", default="demo", metavar="AVATAR",
                   help="a .npga, a 3DGS .ply, a LAM avatar .zip, a Gaussian-Head-Avatar folder, a GaussianAvatars "
                        "folder (with --flame-model) or 'demo' "
                        "(default: the bundled demo avatar)")
    p.add_argument("--sequence", metavar="SEQ",
                   help="expression sequence (.npzseq, .npz, .npy, a MonoNPHM/GHA tracking folder, a tracker's "
                        ".npz) or an ARKit take (Live Link Face .csv; LAM, Audio2Face, MediaPipe .json) read through "
                        "the avatar's blendshape basis")
    p.add_argument("--flame-model", metavar="FLAME_PKL", default=None,
                   help="your FLAME model (flame2023.pkl or FLAME 2020's generic_model.pkl; read without running code "
                        "from it): AVATAR may then be a GaussianAvatars output folder, imported once into the user's "
                        "cache (remembered for the Files panel and drops)")
    p.add_argument("--basis", metavar="BASIS", default=None,
                   help="a blendshape basis .npz (npga-view fit-blendshapes) for the avatar: ARKit takes "
                        "go through it instead of the avatar's own")
    p.add_argument("--play", action="store_true", help="start playing the sequence")
    p.add_argument("--bake", action="store_true",
                   help="bake the sequence at start and play from the bake (progress in the Timeline panel)")
    p.add_argument("--bake-budget-mb", type=float, default=1024.0, metavar="MB",
                   help="memory budget of a bake (default 1024)")
    p.add_argument("--session", metavar="FILE", help="restore a saved session file (.json)")
    p.add_argument("--live-link", metavar="[HOST:]PORT",
                   help="listen for a Live Link Face stream (the iPhone app, `npga-view webcam`) on PORT, on "
                   "127.0.0.1 unless HOST is given (0.0.0.0: every interface); posed through the avatar's "
                   "blendshape basis")
    p.add_argument("--rig", metavar="FILE", help="camera rig calibration (NeRSemble camera_params.json)")
    p.add_argument("--device", default="cpu",
                   help="where the dynamics run: cpu (default), cuda, mps or auto (a GPU when torch sees one)")
    p.add_argument("--precision", default="auto", metavar="fp32|bf16|auto", help=PRECISION_HELP)
    p.add_argument("--threads", type=int, default=2, metavar="N", help="torch threads of the dynamics worker")
    p.add_argument("--size", default="1360x900", metavar="WxH", help="window size (default 1360x900)")
    p.add_argument("--screenshot", metavar="PNG",
                   help="save a window screenshot and quit (after 3 frames, or --quit-after-frames)")
    p.add_argument("--quit-after-frames", type=int, metavar="N",
                   help="quit after N frames, counted once the avatar is drawn (scripted runs: bad input files "
                   "exit 2 before a window opens)")


def run(args: argparse.Namespace) -> int:
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        print(f"npga-view: error: --size {args.size!r} is not WxH", file=sys.stderr)
        return 2
    if args.screenshot and args.quit_after_frames is None:
        args.quit_after_frames = 3
    try:
        from npga_core.posing.device import resolve_device
        from npga_core.posing.precision import check_precision

        resolve_device(args.device)
        args.precision = check_precision(getattr(args, "precision", "auto"))
    except ValueError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    from npga_core.posing.smoothing import BAKE_BUDGET_MB

    if not BAKE_BUDGET_MB[0] <= args.bake_budget_mb <= BAKE_BUDGET_MB[1]:  # NaN too (0 made a bake wait forever)
        print(f"npga-view: error: --bake-budget-mb must be positive ({BAKE_BUDGET_MB[0]:g} to {BAKE_BUDGET_MB[1]:g} "
              f"MB), got {args.bake_budget_mb:g}", file=sys.stderr)
        return 2
    if args.live_link is not None:
        from npga_view.controllers.live_link import parse_address

        try:
            parse_address(args.live_link)
        except ValueError as e:
            print(f"npga-view: error: --live-link: {e}", file=sys.stderr)
            return 2
    if args.quit_after_frames is not None:
        check_files(args)
    from npga_view import signals

    holder: dict = {}

    def close_on_signal(signum: int) -> None:
        holder["signal"] = signum
        if "app" not in holder:  # no window yet: nothing to save, unwind
            raise signals.Terminated(signum)
        holder["app"].request_close(signum)

    restore = signals.install(close_on_signal)
    try:
        code = _open_and_run(args, w, h, holder)
    finally:
        restore()
    return 128 + holder["signal"] if "signal" in holder else code


def _open_and_run(args: argparse.Namespace, w: int, h: int, holder: dict) -> int:
    from npga_view.app import ViewerApp

    try:
        app = ViewerApp(w, h, threads=args.threads, device=args.device, precision=args.precision)
    except RuntimeError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    holder["app"] = app
    try:
        if args.flame_model:
            from pathlib import Path

            app.state.flame_model = str(Path(args.flame_model).resolve())
            if app.opener.remember_recent:
                app.state.save_flame_model()
        opened = app.open_avatar(args.avatar)
        if args.basis and opened and app.avatar is not None:
            from npga_core.files.basis_file import attach_basis

            try:
                attach_basis(app.avatar, args.basis)
            except AvatarFileError as e:
                app.state.report(str(e))
        if args.sequence and opened:
            app.open_sequence(args.sequence)
            app.state.timeline.playing = bool(args.play)
            app.state.timeline.bake_budget_mb = args.bake_budget_mb
            if args.bake:
                app.state.actions.append(Bake())
        if args.rig:
            app.state.actions.append(LoadRig(args.rig))
        if args.live_link is not None and opened:
            app.panels.timeline.live.address = args.live_link
            app.live.start(args.live_link)
        if args.session:
            try:
                app.load_session(args.session)
            except (ValueError, AvatarFileError) as e:
                app.state.report(str(e))
    except BaseException:
        app.close()
        raise
    if args.quit_after_frames is not None and _scripted_failure(app):
        app.close()
        return 2
    return app.run(args.screenshot, args.quit_after_frames)


def _scripted_failure(app) -> bool:
    """A scripted run says what opening its files did (a take's unmatched shapes: notes, no failure) and fails
    loudly on bad input instead of screenshotting an error (True: the last error printed)."""
    for note in app.state.notices:
        print(f"npga-view: note: {note}", file=sys.stderr)
    if app.state.errors:
        print(f"npga-view: error: {app.state.errors[-1]}", file=sys.stderr)
        return True
    return False


def check_files(args: argparse.Namespace) -> None:
    """Scripted runs (--quit-after-frames/--screenshot): read the files named on the command line and the
    user's presets and recent-files lists with the window's own readers before a window opens, so that bad
    input fails at once (AvatarFileError: one line, exit 2). The avatar itself is read once, by the window."""
    import os

    from npga_core.files.loading import load_sequence
    from npga_core.files.rig import load_rig
    from npga_view.controllers.actions import ActionController, read_presets
    from npga_view.state import ViewerState, flame_model_file, read_flame_setting, read_recent, recent_file

    if args.basis:
        from npga_core.files.basis_file import read_basis

        read_basis(args.basis)
    if args.sequence and not args.basis:  # (a take is read through the basis once the window has it)
        load_sequence(args.sequence)
    if args.rig:
        load_rig(args.rig)
    if args.session:
        ViewerState().load_session(args.session)
    presets, recent = ActionController.presets_file(), recent_file()
    if os.path.lexists(presets):
        read_presets(presets)
    if os.path.lexists(recent):
        read_recent(recent)
    if os.path.lexists(flame_model_file()):
        read_flame_setting(flame_model_file())
    if getattr(args, "flame_model", None):
        from npga_core.files.flame_pickle import read_flame_model

        read_flame_model(args.flame_model)  # a hostile or broken pickle: one line, exit 2, before any window
