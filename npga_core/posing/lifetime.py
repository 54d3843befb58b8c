"""Lifetime of worker processes: a worker never outlives the process that started it, and a stopped one
leaves no shared memory behind.

- In the worker, `start_parent_watch` runs a thread that notices within about `poll_s` seconds that the parent
  is gone (SIGKILL, crash, or its engine dropped), unlinks the shared-memory segments the parent can no longer
  unlink, and exits the worker at once (`ORPHAN_EXIT`).
- In the parent, `shutdown_worker` (run by `PoseEngine.close`, by garbage collection of the engine and at
  interpreter exit through `weakref.finalize`) asks the worker to stop, kills it after 5 s, and unlinks;
  `shutdown_in_background` does the same in a thread for a worker being replaced (an edit, another avatar), and
  interpreter exit waits for those.
"""

from __future__ import annotations

import atexit
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


_PENDING: list[threading.Thread] = []  # shutdowns running in the background (`shutdown_in_background`)


def shutdown_in_background(proc: mp.process.BaseProcess, req: mp.queues.Queue | None,
                           shms: list[shared_memory.SharedMemory], *keep: object) -> threading.Thread:
    """`shutdown_worker` in a thread, for a worker being replaced: the UI does not wait for it to finish its job
    and exit (0.6-1.6 s for the demo's worker). `keep`: the other objects the worker was started with (its result
    queue, shared arrays), held until it has exited: a worker still starting unpickles their semaphores, which
    vanish with the last reference. Interpreter exit waits for every pending one (atexit)."""
    t = threading.Thread(target=_shutdown_keeping, args=(proc, req, shms, keep), name="npga-worker-shutdown",
                         daemon=True)
    _PENDING[:] = [p for p in _PENDING if p.is_alive()]
    _PENDING.append(t)
    t.start()
    return t


def _shutdown_keeping(proc: mp.process.BaseProcess, req: mp.queues.Queue | None,
                      shms: list[shared_memory.SharedMemory], keep: tuple[object, ...]) -> None:
    shutdown_worker(proc, req, shms)
    del keep  # (released only now that the worker is gone)


def wait_for_shutdowns(timeout_s: float = 15.0) -> None:
    """Wait (bounded) for the background shutdowns: their workers stopped, their slots unlinked."""
    end = time.monotonic() + timeout_s
    for t in list(_PENDING):
        t.join(max(0.0, end - time.monotonic()))


atexit.register(wait_for_shutdowns)
