"""`npga-view`: the viewer (the default command, also `npga-view view`) and its subcommands."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable

from npga_core import __version__
from npga_core.errors import AvatarFileError, CommandError, shown

#: Most distinct warnings a command prints (as one-line notes) when it succeeds.
MAX_NOTES = 5

# subcommand -> module with add_arguments(parser) and run(args) -> int
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "view": ("npga_view.cli.gui", "open the viewer (the default: `npga-view [AVATAR] [options]` is the same)"),
    "info": ("npga_view.cli.info", "print a summary of an avatar file"),
    "render": ("npga_view.cli.render", "render an avatar headless to PNG or MP4"),
    "bench": ("npga_view.benchmarks.bench", "measure the dynamics (exact, preview, playback) on this machine"),
    "export": ("npga_view.cli.export", "export the avatar posed at one expression as a 3DGS .ply"),
    "import": ("npga_view.cli.importer", "convert another method's checkpoint (gha) into an .npga avatar"),
    "evaluate": ("npga_view.cli.evaluate", "render the avatar from a capture's views and score it (PSNR/SSIM/LPIPS)"),
    "fit-blendshapes": ("npga_view.cli.fit_blendshapes", "fit a blendshape basis from an ARKit take and its codes"),
    "webcam": ("npga_view.cli.webcam", "drive a viewer's Live Link from a webcam (MediaPipe face landmarker)"),
    "web": ("npga_view.cli.web", "play a LAM web avatar zip in the browser (LAM's web player, served on 127.0.0.1), "
            "driven by a take or Live Link"),
}
DEFAULT = "view"
USAGE = "npga-view [AVATAR] [viewer options] | npga-view COMMAND [options]"


def _load(module: str) -> tuple[Callable, Callable]:
    import importlib

    mod = importlib.import_module(module)
    return mod.add_arguments, mod.run


def command_parser(name: str) -> argparse.ArgumentParser:
    """The parser of one subcommand (`view` is also reached without a command name)."""
    module, help_text = SUBCOMMANDS[name]
    add_arguments, _ = _load(module)
    prog = "npga-view" if name == DEFAULT else f"npga-view {name}"
    p = argparse.ArgumentParser(prog=prog, description=help_text)
    if name == DEFAULT:
        p.usage = "npga-view [view] [AVATAR] [options]"
    add_arguments(p)
    return p


def build_parser() -> argparse.ArgumentParser:
    """The full parser, whose help also lists the viewer's own options (subcommands are imported lazily)."""
    view_help = command_parser(DEFAULT).format_help().splitlines()
    start = next((i for i, line in enumerate(view_help) if line.startswith("positional")), 0)
    viewer = "\n".join(line for line in view_help[start:] if not line.lstrip().startswith("-h, --help"))
    p = argparse.ArgumentParser(
        prog="npga-view", usage=USAGE, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Viewer and editor for NPGA Gaussian head avatars.\n\n"
                    "Without a COMMAND, npga-view opens the viewer on AVATAR (default: the bundled demo) with the\n"
                    "viewer options below; `npga-view view ...` is the same. `npga-view COMMAND --help` shows a\n"
                    "command's options.",
        epilog="the viewer (`npga-view [view] [AVATAR] [options]`):\n  " + viewer.strip().replace("\n", "\n  "))
    p.add_argument("--version", action="version", version=f"npga-view {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments, _ = _load(module)
        add_arguments(sp)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (2 for bad input, with a one-line message and no traceback;
    128 + N when ended by signal N, after the same cleanup as a normal exit)."""
    from npga_view import signals

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help", "--version"):
        build_parser().parse_args(argv[:1])
        return 0
    name = argv.pop(0) if argv and argv[0] in SUBCOMMANDS else DEFAULT
    args = command_parser(name).parse_args(argv)
    _, run = _load(SUBCOMMANDS[name][0])
    # SIGTERM/SIGHUP/SIGINT unwind like Ctrl+C (finally blocks close pose engines); the viewer installs its own
    # handlers that close the window first
    restore = signals.install()
    notes: dict[str, None] = {}
    try:
        with _warnings_as_notes(notes):
            code = int(run(args) or 0)
        _print_notes(notes)
        return code
    except (AvatarFileError, CommandError) as e:  # the one line: warnings met on the way are not printed
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    except (signals.Terminated, KeyboardInterrupt) as e:
        signum = e.signum if isinstance(e, signals.Terminated) else 2
        print(f"npga-view: {name}: stopped by {signals.name(signum)}", file=sys.stderr)
        # a C call (the CNN) still running on a helper thread, or torch's own thread pools beside one that just
        # ended: interpreter shutdown is not safe beside them (once seen: "terminate called without an active
        # exception", SIGABRT instead of 128 + 15). Every finally block has run by now; end without shutdown.
        if signals.abandoned() or "torch" in sys.modules:
            import os

            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(128 + signum)
        return 128 + signum
    finally:
        restore()


@contextlib.contextmanager
def _warnings_as_notes(notes: dict[str, None]):
    """Python's and numpy's warnings (overflow in a cast, loadtxt's notices, a library's deprecations) collected
    as one-line texts instead of printed as they come (two lines each, raw): a command that fails prints only its
    error line; one that succeeds prints them after its output as notes, escaped, shortened, each once."""
    import warnings

    def collect(message, category, filename, lineno, file=None, line=None) -> None:
        if len(notes) < 100:
            notes[shown(str(message))[:200]] = None

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = collect
        yield


def _print_notes(notes: dict[str, None]) -> None:
    for text in list(notes)[:MAX_NOTES]:
        print(f"npga-view: note: {text}", file=sys.stderr)
    if len(notes) > MAX_NOTES:
        print(f"npga-view: note: {len(notes) - MAX_NOTES} more notices", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
