"""Atomic file writes: a temp file in the target's folder, fsync, rename over the target, fsync of the folder.

The one output gate of every command and save (`check_output`, called by `atomic_write` and by writers that
cannot use it): an existing target that is not a regular file (a folder, a FIFO, a device) is refused without
being opened, the parent folders are created or the reason they cannot be is said, and every failure is one
`OutputError` line naming the file (also an OSError).

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

from npga_core.errors import OutputError

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


def _reason(e: OSError) -> str:
    return e.strerror or type(e).__name__


def check_output(path: str | Path, what: str = "a file", make_parents: bool = True) -> Path:
    """`path` as a Path once it can be written as `what`: an existing target must be a regular file (a folder,
    FIFO, device or socket is refused, never opened), its folder is created (OutputError when a file is in the
    way, permission is missing, the name is too long, ...; without `make_parents`, when it is missing)."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as e:  # a file where a folder should be, a name too long, no permission to look
        raise OutputError(path, f"cannot write {what} there ({_reason(e)})") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode) else \
            "not a regular file"
        raise OutputError(path, f"is {kind}; cannot write {what} there")
    if not make_parents:
        if not os.path.isdir(path.parent):
            raise OutputError(path, f"its folder {path.parent} is missing")
        return path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(path, f"cannot create its folder {path.parent} ({_reason(e)})") from None
    return path


def check_output_folder(path: str | Path, what: str = "a folder") -> Path:
    """`path` as a Path to an existing or newly created folder (OutputError when something else is in the way or
    it cannot be made)."""
    path = Path(path)
    try:
        if path.exists() and not path.is_dir():
            raise OutputError(path, f"is not a folder; cannot write {what} there")
        path.mkdir(parents=True, exist_ok=True)
    except OutputError:
        raise
    except OSError as e:
        raise OutputError(path, f"cannot create {what} ({_reason(e)})") from None
    return path


def atomic_write(path: str | Path, write: Callable[[BinaryIO], object],
                 verify: Callable[[Path], object] | None = None) -> None:
    """Call `write(fh)` on a temp file and move it over `path` only once it is complete and on disk.

    A crash or error at any point leaves either the old file untouched or the complete new one, and no
    temp file behind (except after a hard kill, where a hidden `.NAME.*.tmp` may remain). A replaced file
    keeps its permissions. `verify(temp path)`, when given, reads the complete temp file back (with the reader
    that will read it) before it is moved into place; what it raises leaves nothing written.
    """
    path = check_output(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:64]}.", suffix=".tmp", dir=path.parent)
    except OSError as e:
        raise OutputError(path, f"cannot write in its folder ({_reason(e)})") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        if verify is not None:
            verify(Path(tmp))
        move_into_place(tmp, path)
    except OutputError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise OutputError(path, f"could not be written ({_reason(e)})") from None
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
