"""SIGTERM, SIGINT and SIGHUP (where the platform has them) handled like a window close.

A desktop session ending, a terminal closing or a job scheduler sends one of these. Python's default for
SIGTERM and SIGHUP ends the process without running `finally` blocks, so a pose worker and its shared memory
would be left behind (the worker also notices its parent is gone, see `npga_core.posing.lifetime`, but the
parent's own cleanup, e.g. autosaving edits, would not run). With `install`, the first signal either asks the
viewer to close (at the end of its frame: edits autosaved, worker stopped, shared memory unlinked) or raises
`Terminated`, which unwinds like Ctrl+C; a second signal always raises.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable

#: The signals handled: those of SIGTERM, SIGINT, SIGHUP, SIGBREAK (Windows console) this platform has.
CLOSE_SIGNALS: tuple[int, ...] = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGINT", "SIGHUP", "SIGBREAK")
                                       if hasattr(signal, n))


class Terminated(BaseException):  # noqa: N818 - like KeyboardInterrupt, not caught by `except Exception`
    """Raised in the main thread by a close signal; the CLI exits with 128 + the signal number."""

    def __init__(self, signum: int):
        super().__init__(f"terminated by signal {signum}")
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def install(request_close: Callable[[int], None] | None = None) -> Callable[[], None]:
    """Handle the close signals in this (main) thread; returns a function that restores the previous handlers.

    With `request_close`, the first signal calls it with the signal number (it should make the program wind
    down by itself, or raise `Terminated`); without, or on a second signal, `Terminated` is raised.
    """
    seen: list[int] = []

    def handler(signum: int, frame) -> None:
        seen.append(signum)
        if request_close is None or len(seen) > 1:
            raise Terminated(signum)
        request_close(signum)

    previous = {}
    for sig in CLOSE_SIGNALS:
        with contextlib.suppress(ValueError, OSError):  # not the main thread, or not settable here
            previous[sig] = signal.signal(sig, handler)

    def restore() -> None:
        for sig, old in previous.items():
            with contextlib.suppress(ValueError, OSError, TypeError):
                signal.signal(sig, old)

    return restore
