"""Start an Xvfb display for window tests (used by the GUI test fixtures)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path


def _die_with_parent() -> None:
    """In the Xvfb child before exec (Linux): SIGTERM it when the test process dies, even by SIGKILL, so a
    killed test run leaves no display server behind (#16)."""
    import contextlib
    import ctypes
    import signal

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG


def start_xvfb(width: int = 1600, height: int = 1000) -> tuple[subprocess.Popen, str]:
    """Start Xvfb on a free display number; returns (process, ':N'). Raises RuntimeError if impossible."""
    exe = shutil.which("Xvfb")
    if exe is None:
        raise RuntimeError("Xvfb is not installed (apt-get install xvfb)")
    for n in range(91, 140):
        if Path(f"/tmp/.X{n}-lock").exists() or Path(f"/tmp/.X11-unix/X{n}").exists():
            continue
        # -noreset: without it the server resets whenever its last client disconnects, and a window opened
        # during that reset fails with "Failed to open display" (seen between GUI tests)
        proc = subprocess.Popen([exe, f":{n}", "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp", "-noreset"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        for _ in range(100):
            if Path(f"/tmp/.X11-unix/X{n}").exists():
                return proc, f":{n}"
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        proc.kill()
    raise RuntimeError("could not start Xvfb on any display :91..:139")


def stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()


def env_with_display(display: str) -> dict[str, str]:
    env = dict(os.environ)
    env["DISPLAY"] = display
    return env


def xvfb_display():
    """A generator for a module-scoped pytest fixture: a private Xvfb as $DISPLAY (skipped with the reason when
    Xvfb cannot start, except in CI where that is a failure), $DISPLAY restored and the server stopped after."""
    import pytest

    try:
        proc, name = start_xvfb()
    except RuntimeError as e:
        if os.environ.get("CI"):
            raise
        pytest.skip(str(e))
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = name
    try:
        yield name
    finally:
        if old is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = old
        stop(proc)
