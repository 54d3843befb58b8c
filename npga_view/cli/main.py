"""`npga-view`: the viewer (default) and its subcommands."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from npga_core import __version__
from npga_core.errors import AvatarFileError

# subcommand -> module with add_arguments(parser) and run(args) -> int
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "info": ("npga_view.cli.info", "print a summary of an avatar file"),
    "render": ("npga_view.cli.render", "render an avatar headless to PNG or MP4"),
    "bench": ("npga_view.cli.bench", "measure the dynamics (exact, preview, playback) on this machine"),
    "export": ("npga_view.cli.export", "export the avatar posed at one expression as a 3DGS .ply"),
}


def _load(module: str) -> tuple[Callable, Callable]:
    import importlib

    mod = importlib.import_module(module)
    return mod.add_arguments, mod.run


def build_parser() -> argparse.ArgumentParser:
    """The full parser (subcommands are imported lazily when used)."""
    p = argparse.ArgumentParser(prog="npga-view", description="Viewer and editor for NPGA Gaussian head avatars.")
    p.add_argument("--version", action="version", version=f"npga-view {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments, _ = _load(module)
        add_arguments(sp)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (2 for bad input, with a one-line message and no traceback)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:
        name = argv[0]
        module, help_text = SUBCOMMANDS[name]
        add_arguments, run = _load(module)
        parser = argparse.ArgumentParser(prog=f"npga-view {name}", description=help_text)
        add_arguments(parser)
        args = parser.parse_args(argv[1:])
    elif argv and argv[0] in ("-h", "--help", "--version"):
        build_parser().parse_args(argv)
        return 0
    else:
        from npga_view.cli import gui as cli_gui

        parser = argparse.ArgumentParser(prog="npga-view", description="Open the viewer (default: the demo avatar). "
                                         f"Subcommands: {', '.join(SUBCOMMANDS)}.")
        cli_gui.add_arguments(parser)
        args = parser.parse_args(argv)
        run = cli_gui.run
    try:
        return int(run(args) or 0)
    except AvatarFileError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
