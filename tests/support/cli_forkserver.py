"""Run many CLI invocations each in its own process, cheaply: a server that imports the project once and forks
a child per request (Linux). The hostile-file tests use it; `python -m tests.support.cli_forkserver` is the server.

Each child is a separate process with its own address-space limit (RLIMIT_AS: the address space at the fork
plus `limit_mb`), its own stdout/stderr files and a wall-clock limit (the server kills it by pid when it
runs over). It runs `npga_view.cli.main.main(argv)` exactly as the console script does (`argv` mode), or
calls `module:function(*args)` whose return value is the exit status (`call` mode, for readers that have no
command of their own, e.g. caches). The reply says how it ended: exit status, signal (a native crash), or
timed out.

Protocol: one JSON request per line on stdin, one JSON reply per line on stdout.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

LIMIT_MB = 1024  # address space a hostile case may add to what the process had
TIMEOUT_S = 120.0  # a bound on a hang, not a speed


def _address_space_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


def _child(req: dict) -> int:
    """In the forked child: limits, redirections, environment, then the CLI (or the call)."""
    import resource

    limit = _address_space_bytes() + int(req.get("limit_mb", 1024)) * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    for fd, path in ((1, req["stdout"]), (2, req["stderr"])):
        f = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(f, fd)
        os.close(f)
    sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115 - the child ends with os._exit
    sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
    os.environ.update(req.get("env", {}))
    os.chdir(req.get("cwd", os.getcwd()))
    try:
        if "argv" in req:
            from npga_view.cli.main import main

            code = main(list(req["argv"]))
        else:
            import importlib

            module, func = req["call"].split(":")
            code = getattr(importlib.import_module(module), func)(*req.get("args", []))
    except SystemExit as e:  # argparse errors, sys.exit
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:  # what Python would print for an uncaught exception
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    return int(code or 0)


def _serve() -> None:
    import cv2  # noqa: F401 - import the project and what its readers import lazily once, before forking
    import yaml  # noqa: F401

    import npga_view.app  # noqa: F401,I001 - the viewer's cases (--session, --rig, config files) open it
    import npga_view.cli.main  # noqa: F401
    from npga_core.evaluation import capture  # noqa: F401
    from npga_core.files import gha, loading  # noqa: F401
    from npga_view.cli import export, gui, importer, info, render  # noqa: F401

    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                code = _child(req)
            finally:
                os._exit(code)
        end = time.monotonic() + float(req.get("timeout", 60))
        status, timed_out = None, False
        while status is None:
            done, st = os.waitpid(pid, os.WNOHANG)
            if done:
                status = st
            elif time.monotonic() > end:
                os.kill(pid, signal.SIGKILL)
                _, status = os.waitpid(pid, 0)
                timed_out = True
            else:
                time.sleep(0.005)
        reply = {"timed_out": timed_out, "exit": os.WEXITSTATUS(status) if os.WIFEXITED(status) else None,
                 "signal": os.WTERMSIG(status) if os.WIFSIGNALED(status) else None}
        print(json.dumps(reply), flush=True)


class ForkServer:
    """The test side: start the server, `run(request) -> reply`, `close()`."""

    def __init__(self, cwd: str | Path, env: dict[str, str] | None = None):
        root = Path(__file__).resolve().parents[2]
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.support.cli_forkserver"], cwd=root, text=True,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     env={**os.environ, "PYTHONPATH": str(root), **(env or {})})
        self.cwd = str(cwd)
        self._calls = 0
        line = self.proc.stdout.readline()
        if not line.startswith("{"):
            raise RuntimeError(f"fork server did not start (exit {self.proc.poll()})")

    def run(self, request: dict) -> dict:
        self.proc.stdin.write(json.dumps({"cwd": self.cwd, **request}) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def cli(self, *argv: str, timeout: float = TIMEOUT_S, limit_mb: int = LIMIT_MB) -> tuple[dict, str, str]:
        """`npga-view ARGV` in a forked child: (the reply, its stdout, its stderr)."""
        self._calls += 1
        out, err = (Path(self.cwd) / f".forkserver-{self._calls}.{name}" for name in ("out", "err"))
        reply = self.run({"argv": list(argv), "stdout": str(out), "stderr": str(err), "timeout": timeout,
                          "limit_mb": limit_mb})
        texts = out.read_text(errors="replace"), err.read_text(errors="replace")
        out.unlink()
        err.unlink()
        return reply, *texts

    def close(self) -> None:
        self.proc.stdin.close()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.proc.stdout.close()


if __name__ == "__main__":
    _serve()
