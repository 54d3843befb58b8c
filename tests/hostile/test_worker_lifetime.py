"""No orphaned pose worker and no leaked shared memory, however the process that owns a PoseEngine ends.

Each test starts an owner in a subprocess (a small script holding a PoseEngine, `npga-view bench`, or the viewer
under Xvfb), finds its worker and the /dev/shm segments the worker maps, ends the owner with a signal, and
waits (generous bounds: conditions, not speed) until the worker is gone and every segment is unlinked. The
viewer must also treat SIGTERM/SIGINT/SIGHUP as a window close: its unsaved edits are autosaved.

Linux only: processes and mappings are read from /proc.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.model.synthetic import make_synthetic_avatar
from tests.support.xvfb import xvfb_display

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 60.0  # bound on waiting for a condition (the worker notices a lost parent within ~0.5 s)

OWNER = """
import faulthandler, json, signal, sys, time
import numpy as np
from npga_core.files.checkpoint import read_avatar
from npga_core.posing.engine import PoseEngine

def main():
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # the test's dump when the owner does not end
    # SIGINT as a program started from a terminal has it: twice in the full suite (xdist) the owner inherited it
    # ignored or blocked from the test process and slept on through the signal (its stack, dumped)
    inherited = {"sigint": str(signal.getsignal(signal.SIGINT)),
                 "blocked": sorted(int(s) for s in signal.pthread_sigmask(signal.SIG_BLOCK, []))}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT, signal.SIGTERM])
    a = read_avatar(sys.argv[1])
    eng = PoseEngine(sys.argv[1], len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1)
    eng.request(a.expression.sample(np.random.default_rng(0)))
    assert eng.wait(300) is not None, eng.last_error
    print(json.dumps({"worker": eng.pid, "inherited": inherited}), flush=True)
    while True:
        time.sleep(1)

if __name__ == "__main__":
    main()
"""

VIEWER = """
import json, sys
import npga_view.app as app_mod
import npga_view.controllers.editing as editing
from npga_view.actions import ScaleSelectionOpacity, SelectAll
from npga_view.cli.main import main

editing.AUTOSAVE_EVERY_S = 1e9  # only the close path may autosave in this test
_step, _done = app_mod.ViewerApp.step, {}

def step(self):
    _step(self)
    s = self.edits.session
    if "edit" not in _done and s is not None:
        self.state.actions += [SelectAll(), ScaleSelectionOpacity(0.5)]
        _done["edit"] = True
    if "told" not in _done and s is not None and s.dirty and self.engine is not None and self.engine.ready:
        s.discard_autosave()
        print(json.dumps({"worker": self.engine.pid, "autosave": str(s.autosave_path())}), flush=True)
        _done["told"] = True

app_mod.ViewerApp.step = step
if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
"""


# -- /proc helpers -------------------------------------------------------------------------------------------
def _alive(pid: int) -> bool:
    """Running (a zombie waiting to be reaped counts as gone)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return not re.search(r"^State:\s+Z", status, re.MULTILINE)


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _descendants(pid: int) -> list[int]:
    """Children, grandchildren, ... of `pid` (the pose worker, helpers, multiprocessing's resource tracker)."""
    out, todo = [], [pid]
    while todo:
        kids = _children(todo.pop())
        out += kids
        todo += kids
    return out


def _shm_segments(pid: int) -> set[str]:
    """The /dev/shm files a process maps (its shared-memory slots, the queues' semaphores)."""
    try:
        maps = Path(f"/proc/{pid}/maps").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return set()
    return {m.group(1) for m in re.finditer(r"(/dev/shm/\S+)", maps)}


def _wait(cond, timeout: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def _wait_or_dump(proc: subprocess.Popen, note: str = "") -> None:
    """Wait for the owner to end; if it does not, fail with its threads' stacks (its SIGUSR1 dump) and stderr."""
    try:
        proc.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGUSR1)
        time.sleep(2.0)
        proc.kill()
        _, err = proc.communicate(timeout=WAIT_S)
        raise AssertionError(f"the owner did not end within {WAIT_S:.0f} s of the signal ({note}); its stderr and "
                             f"threads:\n{err[-6000:]}") from None


def _read_line(proc: subprocess.Popen, timeout: float = 600.0) -> dict:
    """The JSON line the owner prints once its worker is up (generous: the worker imports torch)."""
    import selectors

    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        if sel.select(timeout=1.0):
            line = proc.stdout.readline()
            if line.startswith("{"):
                return json.loads(line)
    raise AssertionError(f"the owner never reported its worker (exit {proc.poll()}): {proc.stderr.read()[-2000:]}")


def _env(tmp_path: Path, **extra) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), XDG_CONFIG_HOME=str(tmp_path / "config"),
               XDG_CACHE_HOME=str(tmp_path / "cache"), **extra)
    return env


class _Tree:
    """What an owner process started (recorded before it is signalled) and the /dev/shm files they map."""

    def __init__(self, owner: int):
        self.pids = _descendants(owner)
        self.segments = set().union(*(_shm_segments(p) for p in self.pids)) if self.pids else set()

    def assert_nothing_left(self) -> None:
        left = lambda: [p for p in self.pids if _alive(p)]  # noqa: E731
        assert _wait(lambda: not left()), f"outlived their owner: {left()}"
        assert _wait(lambda: not any(os.path.exists(s) for s in self.segments)), \
            f"leaked: {sorted(s for s in self.segments if os.path.exists(s))}"


def _cleanup(proc: subprocess.Popen, tree: _Tree | None) -> None:
    """After a failure: end what this test started, by pid."""
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=30)
    for pid in tree.pids if tree is not None else []:
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lifetime") / "a.npga"
    save_avatar(make_synthetic_avatar(2000, seed=5), path)
    return path


# -- an owner without any signal handling ---------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT], ids=lambda s: s.name)
def test_worker_exits_when_its_owner_dies(sig, avatar_file, tmp_path):
    script = tmp_path / "owner.py"
    script.write_text(OWNER)
    proc = subprocess.Popen([sys.executable, str(script), str(avatar_file)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env(tmp_path))
    tree = None
    try:
        line = _read_line(proc)
        worker = line["worker"]
        tree = _Tree(proc.pid)
        assert worker in tree.pids
        assert any("/psm_" in s for s in _shm_segments(worker))  # the result slots
        os.kill(proc.pid, sig)
        _wait_or_dump(proc, f"inherited from the test process: {line['inherited']}")
        tree.assert_nothing_left()
    finally:
        _cleanup(proc, tree)


# -- npga-view bench: the CLI's handlers unwind (engine closed by its `with`) ---------------------------------
@pytest.mark.slow
def test_bench_ended_by_sigterm_stops_its_worker(avatar_file, tmp_path):
    cmd = [sys.executable, "-m", "npga_view.cli", "bench", str(avatar_file), "--gaussians", "--no-render",
           "--threads", "1", "--repeat", "1", "--moves", "2", "--live-seconds", "600", "--bake-frames", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(tmp_path))
    tree = None
    try:
        def engine_up() -> bool:  # bench's helper process and, under it, the pose worker map the slots
            return proc.poll() is not None or sum(
                any("/psm_" in s for s in _shm_segments(p)) for p in _descendants(proc.pid)) >= 2

        assert _wait(engine_up, 600) and proc.poll() is None, proc.stderr.read()[-2000:] if proc.poll() else ""
        tree = _Tree(proc.pid)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
        tree.assert_nothing_left()
    finally:
        _cleanup(proc, tree)


# -- the viewer: close signals are a window close -----------------------------------------------------------
@pytest.fixture(scope="module")
def display():
    yield from xvfb_display()


@pytest.mark.slow
@pytest.mark.gui
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGKILL], ids=lambda s: s.name)
def test_viewer_ended_by_a_signal(sig, avatar_file, tmp_path, display):
    script = tmp_path / "viewer.py"
    script.write_text(VIEWER)
    cmd = [sys.executable, str(script), str(avatar_file), "--size", "640x480", "--threads", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(tmp_path, DISPLAY=display))
    tree = None
    try:
        info = _read_line(proc)
        worker, autosave = info["worker"], Path(info["autosave"])
        tree = _Tree(proc.pid)
        assert worker in tree.pids and any("/psm_" in s for s in _shm_segments(worker)) and not autosave.exists()
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=WAIT_S)
        tree.assert_nothing_left()
        if sig == signal.SIGKILL:
            return
        assert proc.returncode == 128 + sig, err[-2000:]
        assert "Traceback" not in err, err[-2000:]
        from npga_core.files.loading import load_avatar  # the unsaved edit was autosaved on the way out

        saved, original = load_avatar(autosave), load_avatar(avatar_file)
        assert not np.allclose(saved.cloud.opacity_logits, original.cloud.opacity_logits)
    finally:
        _cleanup(proc, tree)
