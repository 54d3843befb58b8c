"""The code stays as CONTRIBUTING.md asks: `ruff check .` and `make typecheck` (mypy) clean, so that a finding fails
the test run (and CI) instead of waiting for someone to run them (a ruff finding once landed in a test file)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff is not installed (pip install .[test])")
def test_ruff_finds_nothing():
    r = _run("ruff", "check", "--no-cache", ".")
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed (pip install .[test])")
def test_mypy_finds_nothing(tmp_path):
    r = _run("mypy", "--cache-dir", str(tmp_path / "mypy"), "npga_core", "npga_view")
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
