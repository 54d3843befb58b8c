"""ARKit takes read as recorded (#35): a 30 Hz take on Live Link Face's 60-count timecode is 30 fps with one frame
per row, `--fps` resamples a take, the JSON layouts found in the wild open, what did not match is a one-line note
(never a Python warning), an avatar without a basis refuses a take in one line, and `info` describes a take.

Layouts, from their authors' files and code:
- Live Link Face 30 Hz takes: alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder `anim/alex_rom_3.csv` (MIT):
  4,030 rows whose timecode frame field steps by 2 on a 60 count (``10:09:31:02.xxx``, ``...:04.xxx``).
- NVIDIA Audio2Face's blendshape export (Audio2Face user manual, "Blendshape and joint Conversion": weights
  exported as a .json file): ``{"exportFps", "trackPath", "numPoses", "numFrames", "facsNames", "weightMat"}``
  with one row of ``numPoses`` weights per frame, as consumers read it (``facsNames[i]`` keyed at frame ``fr`` to
  ``weightMat[fr][i]``).
- MediaPipe's FaceLandmarkerResult as JSON: ``{"faceBlendshapes": [[{"categoryName", "score", ...}]], ...}``.
- LAM's A2E converted for web players: ``[{"time": t, "blendshapes": {name: value}}]``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.arkit_takes import read_take, read_take_sequence
from npga_core.files.blendshape_names import ARKIT_52
from npga_core.files.loading import DEMO_AVATAR, load_sequence, load_sequence_for
from npga_core.model.blendshapes import BlendshapeBasis
from tests.support.takes import write_csv

BASIS = BlendshapeBasis(ARKIT_52[:51], np.eye(51, dtype=np.float32), np.zeros(51, np.float32))


def _thirty_hz(path, rows: int, drop: tuple[int, ...] = (), jitter: bool = False) -> np.ndarray:
    """A Live Link Face take at 30 Hz on a 60-count timecode (frame field 0, 2, 4, ...; with `jitter` a sub-frame
    fraction as the app writes); jawOpen = row / rows."""
    out, jaw = [], []
    for r in range(rows):
        if r in drop:
            continue
        s, f = divmod(2 * r, 60)
        m, sec = divmod(31 + s, 60)
        out.append((f"10:{9 + m:02d}:{sec:02d}:{f:02d}.{(r * 37) % 1000 if jitter else 0:03d}", {"JawOpen": r / rows}))
        jaw.append(r / rows)
    write_csv(path, out)
    return np.array(jaw)


def test_a_30_hz_take_on_a_60_count_timecode_is_30_fps_one_frame_per_row(tmp_path):
    p = tmp_path / "take.csv"
    jaw = _thirty_hz(p, 90, jitter=True)
    take = read_take(p)
    assert take.fps == 30.0 and len(take.times) == 90
    seq = read_take_sequence(p, BASIS)
    assert seq.fps == 30.0 and len(seq) == 90 and not seq.notes[1:]
    np.testing.assert_allclose(seq.codes[:, ARKIT_52.index("jawOpen")], jaw, atol=1e-6)  # frame K is row K


def test_dropped_rows_are_counted_and_interpolated(tmp_path):
    p = tmp_path / "gap.csv"
    _thirty_hz(p, 90, drop=(40, 41))
    seq = read_take_sequence(p, BASIS)
    assert len(seq) == 90 and seq.fps == 30.0
    assert any("2 of 90 frames" in n and str(p) in n for n in seq.notes)
    np.testing.assert_allclose(seq.codes[40, ARKIT_52.index("jawOpen")], 40 / 90, atol=1e-6)


def test_fps_resamples_a_take_by_its_timecodes(tmp_path):
    p = tmp_path / "take.csv"
    _thirty_hz(p, 91)
    seq = load_sequence(p, fps=15.0, basis=BASIS)
    assert seq.fps == 15.0 and len(seq) == 46  # 3 s at 15 fps, not the 91 rows relabelled
    np.testing.assert_allclose(seq.codes[:, ARKIT_52.index("jawOpen")], np.arange(46) * 2 / 91, atol=1e-6)
    assert any("resampled from 30 to 15 fps" in n for n in seq.notes)


def _write(path, doc) -> None:
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize("layout", ["audio2face", "names_values", "mediapipe_result", "keyed_frames"])
def test_json_layouts_in_the_wild(tmp_path, layout):
    jaw = [0.0, 0.25, 0.5, 0.75]
    blink = [1.0, 0.5, 0.0, 0.0]
    if layout == "audio2face":
        doc = {"exportFps": 60, "trackPath": "C:\\audio.wav", "numPoses": 2, "numFrames": 4,
               "facsNames": ["jawOpen", "eyeBlinkLeft"],
               "weightMat": [[j, b] for j, b in zip(jaw, blink, strict=True)]}
        fps = 60.0
    elif layout == "names_values":
        doc = {"names": ["jawOpen", "eyeBlinkLeft"], "values": [[j, b] for j, b in zip(jaw, blink, strict=True)]}
        fps = 30.0
    elif layout == "mediapipe_result":  # one face landmarker result: one frame
        doc = {"faceLandmarks": [], "faceBlendshapes": [[
            {"index": 0, "score": 0.01, "categoryName": "_neutral", "displayName": ""},
            {"index": 1, "score": 0.75, "categoryName": "jawOpen", "displayName": ""},
            {"index": 2, "score": 0.5, "categoryName": "eyeBlinkLeft", "displayName": ""}]]}
        jaw, blink, fps = [0.75], [0.5], 30.0
    else:
        doc = [{"time": i / 25, "blendshapes": {"jawOpen": j, "eyeBlinkLeft": b}}
               for i, (j, b) in enumerate(zip(jaw, blink, strict=True))]
        fps = 30.0
    p = tmp_path / f"{layout}.json"
    _write(p, doc)
    seq = load_sequence(p, basis=BASIS)
    if layout == "keyed_frames":  # timed by its own times (25 per second) at the default 30 fps
        assert seq.fps == 30.0 and len(seq) == 5
        return
    assert seq.fps == fps and len(seq) == len(jaw)
    np.testing.assert_allclose(seq.codes[:, ARKIT_52.index("jawOpen")], jaw, atol=1e-6)
    np.testing.assert_allclose(seq.codes[:, ARKIT_52.index("eyeBlinkLeft")], blink, atol=1e-6)


@pytest.mark.parametrize("doc, match", [
    ({"facsNames": ["jawOpen"], "weightMat": [[0.1, 0.2]]}, r"weightMat\[0\]: expected 1 values"),
    ({"names": ["jawOpen"], "values": "x"}, "values: expected a list"),
    ([{"time": 0, "blendshapes": {"jawOpen": 1}}, {"time": 1, "blendshapes": {"x": 1}}], "same 1 blendshapes"),
    ({"faceBlendshapes": []}, "no face"),
])
def test_bad_layouts_are_one_line(tmp_path, doc, match):
    p = tmp_path / "bad.json"
    _write(p, doc)
    with pytest.raises(AvatarFileError, match=match) as e:
        load_sequence(p, basis=BASIS)
    assert "\n" not in str(e.value) and str(p) in str(e.value)


def test_unmatched_shapes_are_a_note_not_a_warning(tmp_path):
    p = tmp_path / "take.csv"
    _thirty_hz(p, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seq = load_sequence(p, basis=BASIS)  # BASIS lacks tongueOut (LAM's 51)
    assert len(seq.notes) == 1 and "TongueOut" in seq.notes[0] and "\n" not in seq.notes[0]


def test_an_avatar_without_a_basis_refuses_a_take_in_one_line(tmp_path):
    from npga_core.model.synthetic import make_synthetic_avatar

    p = tmp_path / "take.csv"
    _thirty_hz(p, 10)
    avatar = make_synthetic_avatar(50, code_dim=8, hidden=8, depth=2)
    assert avatar.blendshapes is None
    with pytest.raises(AvatarFileError, match="no blendshape basis.*fit-blendshapes") as e:
        load_sequence_for(avatar, p)
    assert "\n" not in str(e.value)


def test_info_describes_a_take(tmp_path):
    p = tmp_path / "take.csv"
    _thirty_hz(p, 90, drop=(5,))
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "info", str(p)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert "89 rows at 30 fps" in r.stdout and "1 of 90 frames not recorded" in r.stdout
    assert "never moving (<= 0.01): 51" in r.stdout and "head pose: none recorded" in r.stdout


@pytest.mark.slow
@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_render_prints_notes_once_as_one_line_each(tmp_path):
    p = tmp_path / "take.csv"
    _thirty_hz(p, 6)
    out = tmp_path / "x.png"
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "render", "demo", "--sequence", str(p),
                        "--frame", "3", "--width", "64", "--height", "64", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    notes = [line for line in r.stderr.splitlines() if line.strip()]
    assert notes and all(line.startswith("npga-view: note: ") for line in notes), r.stderr
    assert "Warning" not in r.stderr and "loading.py" not in r.stderr


def test_notes_escape_names_from_the_file(tmp_path):
    p = tmp_path / "names.json"
    _write(p, {"names": ["jawOpen", "evil\u202e\nname\u200b"], "values": [[0.5, 0.1]]})
    seq = load_sequence(p, basis=BASIS)
    assert len(seq.notes) == 1
    note = seq.notes[0]
    assert "\u202e" not in note and "\n" not in note and "\u200b" not in note and "evil" in note
