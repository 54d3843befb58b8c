"""`npga-view info` on good files."""

from __future__ import annotations

import re

from npga_core.files.ply import save_ply
from npga_view.cli.main import main


def test_info_npga(small_npga, capsys):
    assert main(["info", str(small_npga)]) == 0
    out = capsys.readouterr().out
    assert "gaussians: 600" in out and "SH degree: 3" in out and "features f: 8" in out and "latent h: 4" in out
    assert re.search(r"F: 6 layers 111 -> 256 -> 256 -> 256 -> 256 -> 256 -> 3", out)
    assert "G: 6 layers" in out and "CNN: 3 layers" in out
    assert "expression dim: 100" in out and "PCA components: 30" in out
    assert re.search(r"size on disk: [\d.]+ MB, loaded in \d+ ms", out)


def test_info_ply(tmp_path, small_avatar, capsys):
    save_ply(small_avatar.cloud, tmp_path / "x.ply")
    assert main(["info", str(tmp_path / "x.ply")]) == 0
    out = capsys.readouterr().out
    assert "gaussians: 600" in out and "dynamics: none" in out and "expression dim: 0" in out
