"""Handlers are registered by type, so `make typecheck` (mypy with pyproject.toml's settings) refuses a
handler that reads a misspelled field or is registered for another action; both packages ship `py.typed`."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BAD, GOOD = "tests/support/typecheck_bad_handler.py", "tests/support/typecheck_good_handler.py"


def test_mypy_refuses_a_misspelled_field_and_accepts_the_right_one():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "pyproject.toml", BAD, GOOD],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    errors = re.findall(r"^(tests/\S+\.py):(\d+): error: (.*)$", run.stdout, re.M)
    assert run.returncode == 1, run.stdout + run.stderr
    marked = [i + 1 for i, line in enumerate((ROOT / BAD).read_text().splitlines()) if "  # error:" in line]
    assert sorted(int(n) for f, n, _ in errors if f == BAD) == marked, run.stdout
    assert [e for e in errors if e[0] == GOOD] == [], run.stdout
    text = " ".join(msg for _, _, msg in errors)
    assert '"RollBy" has no attribute "degres"' in text and '"OrbitBy" has no attribute "yawn"' in text


def test_both_packages_are_marked_typed_for_the_wheel():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    for pkg in ("npga_core", "npga_view"):
        assert (ROOT / pkg / "py.typed").is_file()
        assert "py.typed" in data[pkg]
