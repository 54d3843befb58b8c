"""Start an Xvfb display for window tests (used by the GUI test fixtures)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path


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
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
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
