"""Lifetime of worker processes: a worker never outlives the process that started it, and a stopped one
leaves no shared memory behind.

- In the worker, `start_parent_watch` runs a thread that notices within about `poll_s` seconds that the parent
  is gone (SIGKILL, crash, or its engine dropped), unlinks the shared-memory segments the parent can no longer
  unlink, and exits the worker at once (`ORPHAN_EXIT`).
- In the parent, `shutdown_worker` (run by `PoseEngine.close`, by garbage collection of the engine and at
  interpreter exit through `weakref.finalize`) asks the worker to stop, kills it after 5 s, and unlinks.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import threading
import time
from multiprocessing import connection as mp_connection
from multiprocessing import shared_memory

ORPHAN_EXIT = 3  # exit status of a worker that found its parent gone


def watch_parent(parent_pid: int, names: list[str], poll_s: float = 0.5) -> None:
    """Worker thread: once the process that started this one is gone (killed, crashed, or its engine dropped),
    unlink the shared-memory slots it can no longer unlink and exit at once.

    Two signals, either is enough: the parent sentinel of `multiprocessing` (a pipe whose write end only the
    parent holds on POSIX, the parent's process handle on Windows: ready when the parent is gone, on every
    platform), and, where parents can change, `os.getppid()` no longer being the parent's pid (re-parented).
    """
    parent = mp.parent_process()
    sentinel = parent.sentinel if parent is not None else None
    while True:
        if sentinel is not None:
            gone = bool(mp_connection.wait([sentinel], timeout=poll_s))
        else:
            time.sleep(poll_s)
            gone = False
        if not gone and os.name == "posix" and os.getppid() != parent_pid:
            gone = True
        if gone:
            for n in names:
                with contextlib.suppress(Exception):
                    shm = shared_memory.SharedMemory(name=n)
                    shm.close()
                    shm.unlink()  # also unregisters it from the resource tracker
            os._exit(ORPHAN_EXIT)


def start_parent_watch(parent_pid: int, names: list[str], poll_s: float = 0.5) -> threading.Thread:
    """Start `watch_parent` in a daemon thread of this (worker) process."""
    t = threading.Thread(target=watch_parent, args=(parent_pid, names, poll_s), name="npga-parent-watch",
                         daemon=True)
    t.start()
    return t


def shutdown_worker(proc: mp.process.BaseProcess, req: mp.queues.Queue | None,
                    shms: list[shared_memory.SharedMemory]) -> None:
    """Stop the worker (stop message, then kill after 5 s) and unlink the slots."""
    with contextlib.suppress(Exception):
        if proc.pid is not None and proc.is_alive():
            if req is not None:
                with contextlib.suppress(Exception):
                    req.put(None)
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=5)
    for s in shms:
        with contextlib.suppress(Exception):
            s.close()
        with contextlib.suppress(FileNotFoundError):
            s.unlink()
