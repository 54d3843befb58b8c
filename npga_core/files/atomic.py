"""Atomic file writes: a temp file in the target's folder, fsync, rename over the target, fsync of the folder.

Portable: `os.replace` renames over an existing file on POSIX and Windows alike; permissions are set through
the path (`os.chmod`, which every platform has; `os.fchmod` exists on Windows only from Python 3.13) and only
where they mean something (POSIX); the folder is synced only where a folder can be opened (POSIX).
"""

from __future__ import annotations

import contextlib
import functools
import os
import stat
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

POSIX = os.name == "posix"
#: Windows refuses to rename over a file another program holds open (an indexer or a virus scanner for a
#: moment): the rename is retried for about this long before the error is raised.
REPLACE_RETRY_S = 1.0


@functools.cache
def _umask() -> int:
    """The process umask (read once: reading it means setting it, briefly)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _mode_for(path: Path) -> int:
    """Permissions of the saved file: those of the file it replaces, else the usual ones (0666 & ~umask)."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~_umask()


def _replace(src: str, dst: Path) -> None:
    deadline = time.monotonic() + (0.0 if POSIX else REPLACE_RETRY_S)
    while True:
        try:
            os.replace(src, dst)
            return
        except PermissionError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.05)


def atomic_write(path: str | Path, write: Callable[[BinaryIO], object]) -> None:
    """Call `write(fh)` on a temp file and move it over `path` only once it is complete and on disk.

    A crash or error at any point leaves either the old file untouched or the complete new one, and no
    temp file behind (except after a hard kill, where a hidden `.NAME.*.tmp` may remain). A replaced file
    keeps its permissions.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        move_into_place(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def move_into_place(tmp: str | Path, path: str | Path) -> None:
    """Give the complete temp file `tmp` (made by mkstemp in `path`'s folder, already synced) the permissions
    `path` has or would get, rename it over `path` and sync the folder: the end of an atomic save, for writers
    that cannot hand `atomic_write` a callback (a video encoder writing frame by frame)."""
    path = Path(path)
    if POSIX:  # mkstemp makes 0600
        os.chmod(tmp, _mode_for(path))
    _replace(str(tmp), path)
    if POSIX:  # make the rename itself durable
        with contextlib.suppress(OSError):
            dfd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
