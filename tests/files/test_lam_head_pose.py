"""LAM_WebRender's expression JSON carries a ``head_pose`` whose convention no code of its authors defines: it is
ignored, and `info` and the opening note say so in one line.

What was searched (the authors' code, at the commits fetched for #35):
- aigc3d/LAM_WebRender at 12174e9: asset/test_expression_1s.json has top-level ``names`` (52), ``frames`` (973 x
  ``{"weights", "time", "rotation": []}``) and ``head_pose`` (973 x 3 numbers of at most ~0.07); the only reader,
  src/gaussianAvatar.ts lines 53-66, takes ``bsData["names"]`` and ``bsData["frames"][i]["weights"]`` and nothing
  else; the player it drives (npm gaussian-splat-renderer-for-lam 0.0.8, build/*.module.js) gets only that
  name -> weight dict through ``getExpressionData`` and contains no "head_pose"/"headPose".
- aigc3d/LAM_Audio2Expression at 02a703c, the model that makes these files: engines/infer.py line 233 returns
  ``"headpose": None``; models/utils.py lines 123 and 136 only initialise ``previous_headpose``/``headpose`` to None.
- aigc3d/LAM at 3395736 and HumanAIGC-Engineering/OpenAvatarChat at b4e8d15: no "head_pose" or "headpose".
So the three numbers' order, axes, units and frame (absolute, relative to what) are not determinable; guessing
would turn the head wrongly on every LAM take. The file's weights still drive the avatar.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from npga_core.files.arkit_takes import LAM_HEAD_POSE_IGNORED, read_take, take_sequence
from npga_core.files.blendshape_names import ARKIT_52
from npga_core.model.blendshapes import BlendshapeBasis


def _lam_webrender_excerpt(path: Path, frames: int = 12) -> np.ndarray:
    """A file in test_expression_1s.json's layout (see the module docstring): 30 fps times, empty rotations."""
    rng = np.random.default_rng(4)
    w = rng.uniform(0, 0.6, (frames, 52))
    doc = {"names": list(ARKIT_52),
           "frames": [{"weights": row.tolist(), "time": k / 30, "rotation": []} for k, row in enumerate(w)],
           "head_pose": (0.02 * rng.standard_normal((frames, 3))).tolist()}
    path.write_text(json.dumps(doc))
    return w


def test_head_pose_is_ignored_and_said_so_once(tmp_path, capsys):
    from npga_view.cli.main import main

    p = tmp_path / "lam_expression.json"
    w = _lam_webrender_excerpt(p)
    take = read_take(p)
    assert take.head is None and take.ignored == LAM_HEAD_POSE_IGNORED
    assert take.fps == 30 and len(take.times) == len(w)
    basis = BlendshapeBasis(ARKIT_52, np.eye(52)[:8], np.zeros(8), "test")
    seq, _ = take_sequence(take, basis, p)
    np.testing.assert_allclose(seq.codes, w[:, :8], atol=1e-6)  # the weights drive as before
    assert seq.pose is None
    notes = [n for n in seq.notes if "head_pose" in n]
    assert len(notes) == 1 and "\n" not in notes[0] and "ignored" in notes[0]
    assert main(["info", str(p)]) == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if "head_pose ignored" in ln]
    assert len(lines) == 1 and "ignored" in lines[0] and "unknown" in lines[0]
    # a LAM file without head_pose (LAM_Audio2Expression's own output) says nothing about it
    doc = json.loads(p.read_text())
    del doc["head_pose"]
    p.write_text(json.dumps(doc))
    assert read_take(p).ignored == ""


def test_the_real_file_when_present():
    """The real asset (NPGA_LAM_DATA=folder holding test_expression_1s.json, as tests/files/test_lam_zip.py uses)."""
    root = os.environ.get("NPGA_LAM_DATA")
    p = Path(root) / "test_expression_1s.json" if root else None
    if p is None or not p.is_file():
        pytest.skip("NPGA_LAM_DATA/test_expression_1s.json not present")
    take = read_take(p)
    assert len(take.times) == 973 and take.head is None and take.ignored == LAM_HEAD_POSE_IGNORED
