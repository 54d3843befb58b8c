"""`bench --window --beside-load N`: the busy processes it starts are ended by it, and never outlive it."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from npga_view.benchmarks.bench_window import start_load, stop_load


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def test_load_processes_are_busy_and_stopped():
    procs = start_load(2)
    try:
        time.sleep(0.5)
        assert all(p.poll() is None for p in procs)
    finally:
        stop_load(procs)
    assert all(p.returncode is not None for p in procs)


def test_load_processes_end_with_their_parent(tmp_path):
    code = ("import sys; from npga_view.benchmarks.bench_window import start_load; "
            "print(' '.join(str(p.pid) for p in start_load(2)), flush=True)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": os.getcwd()})
    pids = [int(x) for x in r.stdout.split()]
    assert len(pids) == 2
    end = time.monotonic() + 30
    while time.monotonic() < end and any(_alive(p) for p in pids):
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids), "a busy process outlived the bench"
