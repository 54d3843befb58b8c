"""`npga-view web AVATAR.zip [--sequence TAKE | --live-link [PORT]]`: a LAM web avatar (`export --format lam-zip`,
or LAM's own) played by LAM's web player in the browser, served from 127.0.0.1 (`npga_view/web_server.py`) and
driven by a take at its own rate or by the Live Link stream, until Ctrl+C."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from npga_core.errors import CommandError

DEFAULT_WEB_PORT = 8738


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("avatar", type=Path, help="a LAM web avatar zip (npga-view export AVATAR --format lam-zip, or "
                   "LAM's own)")
    drive = p.add_mutually_exclusive_group()
    drive.add_argument("--sequence", type=Path, metavar="TAKE", help="play an ARKit take (Live Link Face .csv, "
                       "ARKit .json) at its own rate, looped")
    drive.add_argument("--live-link", "--livelink", dest="live_link", nargs="?", const="11111",
                       metavar="[HOST:]PORT", help="drive it by the Live Link Face stream received on PORT (default "
                       "11111; 127.0.0.1 unless HOST is given)")
    p.add_argument("--port", type=int, default=DEFAULT_WEB_PORT, help=f"the page's port on 127.0.0.1 (default "
                   f"{DEFAULT_WEB_PORT}; 0: any free port)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser (print the address only)")
    p.add_argument("--player", type=Path, metavar="DIR", help="LAM's web player (npm gaussian-splat-renderer-for-lam"
                   "): its build folder or a folder it is installed in; default: installed by npm into the user's "
                   "cache folder on first use")


def _check_zip(path: Path) -> None:
    from npga_core.files.lam import MAX_MEMBERS, avatar_folder
    from npga_core.files.untrusted import zip_member_names

    if not path.exists():
        raise CommandError(f"{path}: no such file")
    if not path.is_file():
        raise CommandError(f"{path}: not a regular file")
    avatar_folder(path, zip_member_names(path, MAX_MEMBERS, "a LAM avatar zip"))


def _live(address: str):
    from npga_core.posing.livelink import LiveLinkReceiver
    from npga_view.controllers.live_link import parse_address
    from npga_view.web_server import LiveWeights

    try:
        host, port = parse_address(address)
    except ValueError as e:
        raise CommandError(f"--live-link: {e}") from None
    try:
        receiver = LiveLinkReceiver(port, host)
    except OSError as e:
        raise CommandError(f"--live-link {address}: cannot listen on {host}:{port} ({e.strerror or e})") from None
    return receiver, LiveWeights(receiver)


def _serve(args: argparse.Namespace, take: dict | None, receiver, live) -> int:
    from npga_view.web_player import player
    from npga_view.web_server import WebServer

    build = player(args.player)
    try:
        server = WebServer(args.avatar, build, args.port, take, live)
    except OSError as e:
        raise CommandError(f"--port {args.port}: cannot serve on 127.0.0.1:{args.port} ({e.strerror or e}; give "
                           "another --port, 0 for any free one)") from None
    try:
        what = (f"the take {args.sequence} at {take['fps']:g} fps ({len(take['frames'])} frames, looped)" if take
                else f"Live Link on {receiver.address[0]}:{receiver.address[1]}" if receiver else "neutral")
        print(f"npga-view web: {args.avatar} driven by {what} at {server.url} (Ctrl+C to stop)", flush=True)
        if not args.no_browser:
            import webbrowser

            if not webbrowser.open(server.url):
                print("npga-view web: no browser found: open the address above", flush=True)
        while True:
            time.sleep(3600)
    finally:
        server.close()


def run(args: argparse.Namespace) -> int:
    """Serve until stopped (Ctrl+C, SIGTERM: main() returns 128 + N); one line and exit 2 for bad inputs."""
    from npga_view.web_server import take_document

    if not 0 <= args.port < 65536:
        raise CommandError(f"--port {args.port}: outside 0..65535")
    _check_zip(args.avatar)
    take = take_document(args.sequence) if args.sequence is not None else None
    receiver, live = _live(args.live_link) if args.live_link is not None else (None, None)
    try:
        return _serve(args, take, receiver, live)
    finally:
        if receiver is not None:
            receiver.close()
