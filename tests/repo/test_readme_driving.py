"""README "Driving ... Your own avatar": the commands of its code block run as written on the stand-ins that
scripts/driving_example.py writes (each exit 0), except the window (`npga-view AVATAR ...`, covered by the window
tests) and the video render (150 frames of a neural avatar: minutes on a busy machine; `export` checks the same
basis path frame by frame)."""

from __future__ import annotations

import re
import runpy
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _block() -> list[str]:
    text = (ROOT / "README.md").read_text()
    start = text.index("**Your own avatar**")
    block = re.search(r"```bash\n(.*?)```", text[start:], re.S)
    assert block is not None
    return [ln.split("  #")[0].strip() for ln in block.group(1).splitlines() if ln.strip()]


def test_the_readme_commands_for_your_own_avatar_run(tmp_path, monkeypatch, capsys):
    from npga_view.cli.main import main

    lines = _block()
    assert any("--into" in ln for ln in lines) and any("--basis" in ln for ln in lines)
    text = (ROOT / "README.md").read_text()
    assert "python scripts/driving_example.py example && cd example" in text
    monkeypatch.setattr(sys, "argv", ["driving_example.py", str(tmp_path / "example")])
    try:
        runpy.run_path(str(ROOT / "scripts" / "driving_example.py"), run_name="__main__")
    except SystemExit as e:
        assert e.code == 0
    monkeypatch.chdir(tmp_path / "example")
    ran = 0
    for line in lines:
        argv = shlex.split(line)
        assert argv[0] == "npga-view", line
        if argv[1] in ("render",) or argv[1].endswith(".npga"):
            continue
        assert main(argv[1:]) == 0, (line, capsys.readouterr().err)
        ran += 1
        out = capsys.readouterr().out
        if argv[1] == "info" and argv[2].endswith(".npga"):  # the line's comment quotes what info prints
            quoted = re.search(r'"(.*)"', text[text.index(line):].splitlines()[0])
            assert quoted is not None and quoted.group(1) in out, out
    assert ran == 5
    assert Path("my_arkit.npga").is_file() and Path("basis.npz").is_file() and Path("f40.ply").is_file()


def test_the_window_line_opens_the_take_with_a_note_not_a_failure(tmp_path, monkeypatch):
    """`npga-view my_arkit.npga --sequence other_take.csv` scripted (--quit-after-frames): the take's note (the
    avatar has no tongueOut) is said once on stderr and is no failure (it was exit 2: notes were errors)."""
    import os
    import subprocess

    import pytest

    from tests.support.xvfb import start_xvfb, stop

    try:
        proc, disp = start_xvfb()
    except RuntimeError as e:
        pytest.skip(str(e))
    try:
        monkeypatch.setattr(sys, "argv", ["driving_example.py", str(tmp_path)])
        try:
            runpy.run_path(str(ROOT / "scripts" / "driving_example.py"), run_name="__main__")
        except SystemExit as e:
            assert e.code == 0
        from npga_view.cli.main import main

        monkeypatch.chdir(tmp_path)
        assert main(["fit-blendshapes", "--take", "session.csv", "--codes", "gha_data", "--into", "gha_ckpt",
                     "--out", "my_arkit.npga"]) == 0
        line = next(ln for ln in _block() if shlex.split(ln)[1].endswith(".npga"))
        env = dict(os.environ, DISPLAY=disp, XDG_CONFIG_HOME=str(tmp_path / "cfg"),
                   PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        r = subprocess.run([sys.executable, "-m", "npga_view.cli", *shlex.split(line)[1:], "--quit-after-frames", "3"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    finally:
        stop(proc)
    assert r.returncode == 0, r.stderr[-2000:]
    notes = [ln for ln in r.stderr.splitlines() if "tongueOut" in ln]
    assert len(notes) == 1 and notes[0].startswith("npga-view: note:"), r.stderr[-2000:]
