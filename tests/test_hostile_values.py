"""Degenerate but valid avatars through `render` in a fresh process (GL in a forked child of the corpus's fork
server is not reliable): an empty image, a note saying so, exit 0, no traceback or warning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from . import hostile_corpus as hc

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="headless GL on Linux")


@pytest.fixture(scope="module")
def degenerate(tmp_path_factory) -> dict[str, Path]:
    from npga_core.files.checkpoint import save_avatar
    from npga_core.files.ply import save_ply
    from npga_core.model.synthetic import make_synthetic_avatar

    root = tmp_path_factory.mktemp("degenerate")
    good_npga, good_ply = root / "good.npga", root / "good.ply"
    save_avatar(make_synthetic_avatar(60, seed=5), good_npga)
    save_ply(make_synthetic_avatar(50, with_f=False, with_g=False).cloud, good_ply)
    cases = root / "cases"
    cases.mkdir()
    return hc.degenerate_avatars(cases, good_ply, good_npga, guards=True)


@pytest.mark.parametrize("case", ["avatar of 0 Gaussians", "ASCII PLY of 0 vertices", "all at one point"])
def test_render_degenerate_avatar(case, degenerate, tmp_path):
    src, out = degenerate[case], tmp_path / "o.npy"
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "npga_view.cli", "render", str(src), "--out", str(out),
                        "--width", "32", "--height", "24"], capture_output=True, text=True, timeout=300, cwd=root,
                       env={**os.environ, "PYTHONPATH": str(root), "DISPLAY": ""})
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "warning" not in r.stderr.lower(), r.stderr
    image = np.load(out)
    assert np.isfinite(image).all()
    if "0" in case:
        assert "no Gaussians" in r.stdout
        assert np.abs(image).max() == 0.0 or np.ptp(image) == 0.0  # only the background
