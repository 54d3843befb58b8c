"""#36: what commands write and the arguments they take, against hostile targets and values, through the command
line in the corpus's fork server (tests/support/cli_forkserver.py): `--out` that is an existing file where a folder is
wanted, a folder where a file is wanted, a path inside a file, a FIFO (never opened: it would block forever), a
name too long, a read-only folder (as an ordinary user only: root ignores permissions; see CONTRIBUTING.md);
`evaluate --frames` ranges of billions and `--background nan`; `info` on a name of 300 characters. Each must end
with exit 2 and one line naming the path (or the option), no traceback, no hang, no memory blow-up.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support import hostile_readers_corpus as hr
from tests.support.cli_forkserver import LIMIT_MB, TIMEOUT_S

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork server, FIFOs, RLIMIT_AS")


def _capture(root: Path) -> Path:
    """A NeRSemble capture of one frame and one camera, valid."""
    w2c = np.eye(4)
    w2c[2, 3] = 1.0
    rig = {"world_2_cam": {"A": w2c.tolist()}, "intrinsics": [[20.0, 0, 8.0], [0, 20.0, 6.0], [0, 0, 1.0]]}
    root.mkdir()
    (root / "camera_params.json").write_text(json.dumps(rig))
    images = root / "timesteps" / "frame_00000" / "images"
    images.mkdir(parents=True)
    (images / "cam_A.png").write_bytes(hr.png(16, 12))
    return root


def _run(world, tmp_path: Path, argv: list[str]) -> tuple[dict, str]:
    err = tmp_path / "err.txt"
    reply = world["server"].run({"argv": argv, "stdout": str(tmp_path / "out.txt"), "stderr": str(err),
                                 "limit_mb": LIMIT_MB, "timeout": TIMEOUT_S, "env": {}})
    return reply, err.read_text(errors="replace") if err.exists() else ""


def _one_line(reply: dict, text: str, names: str) -> None:
    lines = [line for line in text.splitlines() if line.strip()]
    assert not reply["timed_out"] and reply["signal"] is None, (reply, text[-500:])
    assert reply["exit"] == 2 and "Traceback" not in text, (reply, text[-2000:])
    assert len(lines) == 1 and names in lines[0], text[-2000:]


def _targets(tmp_path: Path) -> dict[str, Path]:
    """--out targets that cannot be written."""
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    folder = tmp_path / "a-folder"
    folder.mkdir()
    fifo = tmp_path / "a-fifo"
    os.mkfifo(fifo)
    return {"an existing folder": folder, "inside a file": a_file / "sub" / "x.npga", "a FIFO": fifo,
            "a name of 300 characters": tmp_path / ("n" * 300 + ".npga")}


@pytest.mark.parametrize("case", ["an existing folder", "inside a file", "a FIFO", "a name of 300 characters"])
def test_import_gha_out(case, world, tmp_path):
    target = _targets(tmp_path)[case]
    reply, text = _run(world, tmp_path, ["import", "gha", str(world["gha"]), "--out", str(target)])
    _one_line(reply, text, str(target))
    if case == "a FIFO":
        assert Path(target).exists() and not Path(target).is_file()  # left alone, never opened


@pytest.mark.parametrize("case", ["an existing file", "inside a file", "report file is a FIFO",
                                  "report file is a folder", "--frames 0-3000000000", "--background nan,nan,nan"])
def test_evaluate_outputs_and_arguments(case, world, tmp_path):
    capture = _capture(tmp_path / "capture")
    out = tmp_path / "report"
    extra: list[str] = []
    names = str(out)
    if case == "an existing file":
        out.write_text("x")
    elif case == "inside a file":
        (tmp_path / "f").write_text("x")
        out = tmp_path / "f" / "report"
        names = str(out)
    elif case.startswith("report file"):
        out.mkdir()
        names = str(out / "problems.txt")
        if "FIFO" in case:
            os.mkfifo(out / "problems.txt")
        else:
            (out / "problems.txt").mkdir()
    elif case.startswith("--frames"):
        extra, names = ["--frames", "0-3000000000"], "--frames"
    else:
        extra, names = ["--background", "nan,nan,nan"], "--background"
    reply, text = _run(world, tmp_path, ["evaluate", str(world["avatar"]), "--capture", str(capture), "--out",
                                         str(out), *extra])
    _one_line(reply, text, names)


def test_info_on_a_name_of_300_characters(world, tmp_path):
    target = tmp_path / ("a" * 300 + ".npga")
    reply, text = _run(world, tmp_path, ["info", str(target)])
    _one_line(reply, text, str(target))


def test_read_only_folder(world, tmp_path):
    """`--out` in a folder the user may not write (import gha, evaluate): one line naming the path."""
    if os.geteuid() == 0:
        pytest.skip("root ignores permissions: run as an ordinary user (CONTRIBUTING.md, hostile tests)")
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    capture = _capture(tmp_path / "capture")
    for argv, target in ((["import", "gha", str(world["gha"]), "--out"], folder / "x.npga"),
                         (["evaluate", str(world["avatar"]), "--capture", str(capture), "--out"], folder / "r")):
        reply, text = _run(world, tmp_path, [*argv, str(target)])
        _one_line(reply, text, str(target))


def test_protocol_crop_of_an_extreme_image_is_refused():
    """`--protocol npga` on a 1x16384 or 16384x12 capture image: covering 550x802 would resize it to 550x9
    million (or 1.1 million x 802) pixels, 10-60 GB; refused before OpenCV is asked, naming the image."""
    from npga_core.camera.cameras import Camera
    from npga_core.errors import AvatarFileError
    from npga_core.evaluation.views import protocol_view

    for w, h in ((1, 16384), (16384, 12)):
        cam = Camera(np.eye(4), 10.0, 10.0, w / 2, h / 2, w, h)
        with pytest.raises(AvatarFileError, match="cam_X.png.*pixels"):
            protocol_view(cam, np.zeros((h, w, 3), np.float32), None, source="cam_X.png")


def test_warnings_become_one_line_notes(capsys):
    """Python's and numpy's warnings met by a command are not printed as they come (two raw lines each, before
    the one error line): collected, then printed after a successful command as one escaped line each."""
    import warnings

    from npga_view.cli.main import _print_notes, _warnings_as_notes

    notes: dict[str, None] = {}
    with _warnings_as_notes(notes):
        np.array([1e300]).astype(np.float32)  # RuntimeWarning: overflow encountered in cast
        warnings.warn("odd \ud800\nname", UserWarning, stacklevel=1)
        warnings.warn("odd \ud800\nname", UserWarning, stacklevel=1)  # once
    assert capsys.readouterr().err == ""
    _print_notes(notes)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and all(line.startswith("npga-view: note: ") for line in lines), lines
    assert "overflow" in lines[0] and "\\ud800\\nname" in lines[1]


@pytest.mark.parametrize("command", ["render .png", "render .npy", "export .ply"])
@pytest.mark.parametrize("case", ["a FIFO", "an existing folder"])
def test_render_and_export_out(command, case, world, tmp_path):
    """The same gate for render (images, arrays; videos through VideoWriter) and export: refused before any work,
    the FIFO left alone."""
    name, suffix = command.split()
    target = tmp_path / f"target{suffix}"
    os.mkfifo(target) if case == "a FIFO" else target.mkdir()
    reply, text = _run(world, tmp_path, [name, str(world["avatar"]), "--out", str(target)])
    _one_line(reply, text, str(target))
    assert target.exists() and not target.is_file()


def test_capture_at_a_path_that_is_not_utf8(world, tmp_path):
    """OpenCV's reader died of SIGSEGV on a capture path that is not valid UTF-8: images are now decoded from bytes
    read through the gate, so a capture folder of any name is read (evaluate's reader, in a forked child)."""
    root = _capture(tmp_path / os.fsdecode(b"capture-\xff\xfe"))
    out, err = tmp_path / "out.txt", tmp_path / "err.txt"
    reply = world["server"].run({"call": "tests.support.hostile_readers_corpus:open_capture", "args": [str(root)],
                                 "stdout": str(out), "stderr": str(err), "limit_mb": LIMIT_MB, "timeout": TIMEOUT_S})
    assert reply == {"timed_out": False, "exit": 0, "signal": None}, (reply, err.read_text(errors="replace"))
    assert err.read_text() == "" and "problem" not in out.read_text(errors="replace")
