"""Degenerate but valid avatars through `render` in a fresh process (GL in a forked child of the corpus's fork
server is not reliable): an empty image, a note saying so, exit 0, no traceback or warning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.support import hostile_corpus as hc

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
    root = Path(__file__).resolve().parents[2]
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


def test_video_at_a_path_with_undecodable_bytes(tmp_path):
    """A guard (today's PyAV took it too): the temp file is ASCII, the video lands at its undecodable name."""
    from npga_view.video import VideoWriter

    out = tmp_path / os.fsdecode(b"clip-\xff\xfe.mp4")  # a lone surrogate in Python's view of the name
    with VideoWriter(out, 32, 32, fps=10) as w:
        for _ in range(3):
            w.write(np.zeros((32, 32, 3), np.uint8))
    assert out.is_file() and out.stat().st_size > 0


def test_render_to_a_path_with_undecodable_bytes(degenerate, tmp_path):
    """`render --out` at a name with an undecodable byte: written (OpenCV's imwrite crashed with SIGSEGV)."""
    out = os.fsencode(tmp_path) + b"/render-\xff.png"
    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "npga_view.cli", "render", str(degenerate["all at one point"]),
                        "--out", os.fsdecode(out), "--width", "32", "--height", "24"], capture_output=True, text=True,
                       timeout=300, cwd=root, env={**os.environ, "PYTHONPATH": str(root), "DISPLAY": ""})
    assert r.returncode == 0 and "Traceback" not in r.stderr, (r.returncode, r.stderr[-2000:])
    assert os.path.getsize(out) > 0


def test_video_rate_that_rounds_to_zero_is_one_line():
    from npga_view.video import VideoWriter

    with pytest.raises(ValueError, match="frame rate"):
        VideoWriter(Path("x.mp4"), 32, 32, fps=1e-300)


def test_errors_escape_what_they_name():
    """AvatarFileError escapes lone surrogates, undecodable bytes and newlines in the path and the problem, so
    the message can be printed, drawn by imgui and encoded as UTF-8."""
    from npga_core.errors import AvatarFileError, shown

    err = AvatarFileError(os.fsdecode(b"a\xff\nb.npga"), "part \ud800 name\nis odd")
    text = str(err)
    text.encode("utf-8")  # no lone surrogate left
    assert "\n" not in text and "\\udcff" in text and "\\n" in text and "\\ud800" in text
    assert shown("plain name ✓.npga") == "plain name ✓.npga"


def test_outputs_are_checked_finite_before_they_are_written():
    """The last line of defence of export/render: a NaN/Inf in a computed output is one line naming the input
    and the field."""
    from npga_core.errors import AvatarFileError
    from npga_core.files.untrusted import bounded_floats, finite_output

    finite_output({"means": np.zeros((3, 3), np.float32)}, "in.npy", "posed")
    with pytest.raises(AvatarFileError, match=r"in\.npy: posed: scales has 1 NaN/Inf"):
        finite_output({"means": np.zeros((3, 3)), "scales": np.array([1.0, np.inf])}, "in.npy", "posed")
    with pytest.raises(AvatarFileError, match=r"codes reach 3e\+38"):
        bounded_floats(np.full(4, 3e38, np.float32), "c.npy", "codes", 1e4)


def test_stage2_rows_do_not_pin_their_tables(tmp_path):
    """A stage-2 MonoNPHM frame file holds the whole (T, D) table: each frame keeps only its own row, converted
    alone (no float64 copy of the table, no view keeping it alive)."""
    from npga_core.files.tracking import _row, load_mononphm_folder

    table = np.arange(3 * 5, dtype=np.float32).reshape(3, 5)
    for t in range(3):
        (tmp_path / f"{t:05d}").mkdir()
        np.save(tmp_path / f"{t:05d}" / "z_exp.npy", table)
    row = _row(tmp_path / "00001" / "z_exp.npy", 1, 3, ())
    assert row.base is None or row.base.nbytes == row.nbytes  # its own memory, not a view of the table
    assert row.dtype == np.float64 and row.tolist() == table[1].tolist()
    seq = load_mononphm_folder(tmp_path)
    assert np.array_equal(seq.codes, table)
    budget = [table.nbytes * 2]  # room for two of the three tables
    for t in range(2):
        _row(tmp_path / f"{t:05d}" / "z_exp.npy", t, 3, (), budget)
    with pytest.raises(Exception, match="z_exp.npy"):
        _row(tmp_path / "00002" / "z_exp.npy", 2, 3, (), budget)


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.slow
def test_sigterm_ends_a_render_inside_a_cnn_of_minutes(tmp_path):
    """A valid avatar whose CNN's costs are within the header bounds but take minutes on a CPU (a 15x15
    convolution of 192 -> 192 channels at 800x600, one call into C of ~3 CPU-minutes): SIGTERM while the render
    is inside it ends the render at once (the CNN runs on a helper thread, `interruptible` in npga_view/signals.py)
    with one line, exit 128 + 15 and nothing written. Before, the signal waited for the convolution to end.
    The avatar has 13 latent channels (a cheap latent pass): the same render with a CNN of two 3x3 layers of 8
    channels takes ~3.1 CPU-s in all (imports, pose, splats, latent, CNN, PNG; measured 25 Nov 2026), so at
    6 CPU-s the render is inside the big convolution."""
    import signal
    import time

    import torch

    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.cnn import CNNConfig, ConvLayer, ScreenCNN
    from npga_core.model.synthetic import make_synthetic_avatar

    avatar = make_synthetic_avatar(200, seed=2, latent_dim=13, code_dim=16, hidden=32, depth=2)
    cnn = ScreenCNN(CNNConfig([ConvLayer(16, 192, 3, "relu"), ConvLayer(192, 192, 15, "relu"),
                               ConvLayer(192, 3, 15, None)]))
    with torch.no_grad():
        for p in cnn.parameters():
            p.mul_(0.01)
    avatar.cnn = cnn.eval()
    src, out = tmp_path / "big-cnn.npga", tmp_path / "o.png"
    save_avatar(avatar, src)
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-m", "npga_view.cli", "render", str(src), "--out", str(out),
                             "--width", "800", "--height", "600"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=root, env={**os.environ, "PYTHONPATH": str(root), "DISPLAY": ""})
    try:
        deadline = time.monotonic() + 300
        while proc.poll() is None and _cpu_seconds(proc.pid) < 6.0 and time.monotonic() < deadline:
            time.sleep(0.1)  # everything before the big convolution takes less than ~3 CPU-s (docstring)
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)  # a bound on a hang; the convolution alone takes minutes here
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "stopped by SIGTERM" in lines[0] and "Traceback" not in err, err[-2000:]
    assert not out.exists()


def test_messages_never_repr_untrusted_values():
    """#36: a value from a file in an error message is shortened and escaped (`brief`), never its repr: a YAML
    alias bomb's repr expanded to billions of items, an integer of 5000 digits cannot be printed, a long string
    made a message of megabytes; AvatarFileError caps what is left."""
    from npga_core.errors import MAX_PROBLEM, AvatarFileError, brief

    bomb: list = ["x"] * 10
    for _ in range(9):
        bomb = [bomb] * 10  # 10^10 leaves, shared (what yaml.safe_load makes of aliases)
    assert brief(bomb) == "a list of 10 items"
    assert brief(10**5000) == "an integer of 16610 bits"
    assert brief("a\ud800" * 1000).startswith("'a\\\\ud800") and brief("a" * 1000).endswith("(1000 characters)")
    assert len(str(AvatarFileError("f.json", "x" * 10**6))) < MAX_PROBLEM + 20
