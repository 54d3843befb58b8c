"""SIGTERM, SIGINT and SIGHUP (where the platform has them) handled like a window close.

A desktop session ending, a terminal closing or a job scheduler sends one of these. Python's default for
SIGTERM and SIGHUP ends the process without running `finally` blocks, so a pose worker and its shared memory
would be left behind (the worker also notices its parent is gone, see `npga_core.posing.lifetime`, but the
parent's own cleanup, e.g. autosaving edits, would not run). With `install`, the first signal either asks the
viewer to close (at the end of its frame: edits autosaved, worker stopped, shared memory unlinked) or raises
`Terminated`, which unwinds like Ctrl+C; a second signal always raises.

A handler only runs when the main thread is back in Python, so one long call into C (a convolution of a CNN
whose header claims the largest costs allowed, minutes on a CPU) would hold a signal back for as long as it
runs: `interruptible` runs such a call on a helper thread while the main thread waits in short slices, so
the signal unwinds at once; the abandoned call is then ended with the process (`abandoned`, see
`npga_view.cli.main`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

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


_abandoned: list[threading.Thread] = []


def interruptible(func: Callable[..., T], *args: Any) -> T:
    """`func(*args)` on a helper (daemon) thread while this thread waits in slices of 50 ms, so that a close
    signal raises `Terminated` here at once even while `func` is inside one long C call. The result or the
    exception of `func` is returned or raised here; after a signal the helper is abandoned (`abandoned()`)."""
    box: dict[str, Any] = {}

    def work() -> None:
        try:
            box["value"] = func(*args)
        except BaseException as e:  # noqa: BLE001 - handed to the waiting thread
            box["error"] = e

    thread = threading.Thread(target=work, name="npga-interruptible", daemon=True)
    thread.start()
    try:
        while thread.is_alive():
            thread.join(0.05)
    except BaseException:
        if thread.is_alive():
            _abandoned.append(thread)
        raise
    if "error" in box:
        raise box["error"]
    return box["value"]


def abandoned() -> bool:
    """True when a call `interruptible` ran is still running after a signal unwound past it (the process should
    then end with `os._exit` once its own cleanup is done: the C call cannot be stopped, and interpreter
    shutdown beside it is not safe)."""
    return any(t.is_alive() for t in _abandoned)


def name(signum: int) -> str:
    """SIGTERM, SIGINT, ... for a signal number."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
