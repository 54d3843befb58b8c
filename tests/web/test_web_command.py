"""`npga-view web AVATAR.zip`: the page and LAM's web player served on 127.0.0.1, driven by a take or by Live Link,
opened in headless chromium (tests/support/web_player.py: the player from npm, SwiftShader WebGL); bad inputs are
one line and exit 2; the player is installed by npm into the user's cache folder on first use."""

from __future__ import annotations

import json
import os
import socket
import stat
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from npga_core.files.arkit_takes import Take, write_livelink_csv
from npga_core.files.blendshape_names import ARKIT_52
from npga_core.posing.livelink import encode
from npga_view.cli.main import main
from npga_view.web_player import MODULE, PACKAGE, pinned_version, player
from tests.support.lam_layout import big_jaw, write_lam_zip
from tests.support.web_player import ROOT, Collector, chromium_args, npm_player, start, stop

WIDTH, HEIGHT = 320, 400
JAW = ARKIT_52.index("jawOpen")


@pytest.fixture(scope="module")
def web_zip(tmp_path_factory) -> Path:
    """A small avatar whose jawOpen moves its lower part 2 cm, exported as a LAM web avatar."""
    tmp = tmp_path_factory.mktemp("webzip")
    src = write_lam_zip(tmp / "src.zip", n=3000, tamper_arrays=big_jaw)
    out = tmp / "web.zip"
    assert main(["export", str(src), "--format", "lam-zip", "--out", str(out)]) == 0
    return out


def _serve(args: list[str]) -> tuple:
    """`npga-view web ... --no-browser --port 0` in a child; (process, the page's URL)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = start([sys.executable, "-m", "npga_view.cli.main", "web", *args, "--no-browser", "--port", "0"], env=env,
                 stdout=-1)
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()
    if "http://127.0.0.1:" not in line:
        raise AssertionError(f"npga-view web printed {line!r}; stderr {stop(proc)[-600:]}")
    return proc, line[line.index("http://"):].split()[0]


def _changed(a: np.ndarray, b: np.ndarray) -> float:
    """The fraction of pixels that differ by more than 24 levels in a channel."""
    return float((np.abs(a.astype(int) - b.astype(int)).max(axis=2) > 24).mean())


def _watch(url: str, profile: Path, drive) -> tuple[dict, dict, dict]:
    """The page at `url` in chromium reporting a frame every 400 ms: (closed, closed again, open) jaw frames, the
    jaw set by `drive(open: bool)` before each wait."""
    collector = Collector()
    page = f"{url}index.html?report={collector.url}&every=400&width={WIDTH}&height={HEIGHT}"
    browser = start(chromium_args(page, WIDTH, HEIGHT, profile))
    try:
        drive(False)
        closed = collector.wait_for(lambda f: f["weights"].get("jawOpen", -1) == 0.0, 240, "the jaw closed")
        again = collector.wait_for(lambda f: f["weights"].get("jawOpen", -1) == 0.0, 60, "the jaw closed again")
        drive(True)
        opened = collector.wait_for(lambda f: f["weights"].get("jawOpen", 0) >= 0.97, 120, "the jaw open")
    finally:
        stop(browser)
        collector.close()
    return closed, again, opened


@pytest.mark.slow
def test_web_plays_a_take(web_zip: Path, tmp_path: Path) -> None:
    """A take at 30 fps: 2 s with the jaw closed, 2 s open, looped; the page draws the frames of both halves (the
    weights it reports having drawn are the take's), and the open jaw changes the picture where the same closed
    frame twice does not."""
    build = npm_player()
    weights = np.zeros((120, 52), np.float32)
    weights[60:, JAW] = 1.0
    take = tmp_path / "take.csv"
    write_livelink_csv(take, Take(weights, ARKIT_52, np.arange(120) / 30.0, 30.0))
    server, url = _serve([str(web_zip), "--sequence", str(take), "--player", str(build)])
    try:
        closed, again, opened = _watch(url, tmp_path / "profile", lambda _: None)
    finally:
        stop(server)
    assert closed["frame"] < 60 <= opened["frame"]
    assert _changed(closed["image"], again["image"]) < 0.002
    assert _changed(closed["image"], opened["image"]) > 0.01, _changed(closed["image"], opened["image"])


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
def test_web_follows_live_link(web_zip: Path, tmp_path: Path) -> None:
    """Live Link Face packets (60/s) sent to --live-link PORT drive the page: jawOpen 0 then 1 (after the
    receiver's smoothing) change the picture."""
    build = npm_player()
    port = _free_udp_port()
    server, url = _serve([str(web_zip), "--live-link", str(port), "--player", str(build)])
    state = {"jaw": 0.0, "run": True}

    def send() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            frame = 0
            while state["run"]:
                values = np.zeros(61, np.float32)
                values[JAW] = state["jaw"]
                s.sendto(encode(values, frame), ("127.0.0.1", port))
                frame += 1
                time.sleep(1 / 60)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        closed, again, opened = _watch(url, tmp_path / "profile", lambda on: state.update(jaw=1.0 if on else 0.0))
    finally:
        state["run"] = False
        sender.join(5)
        stop(server)
    assert closed["seq"] > 0 and opened["seq"] > again["seq"]
    assert _changed(closed["image"], again["image"]) < 0.002
    assert _changed(closed["image"], opened["image"]) > 0.01


@pytest.fixture
def fake_player(tmp_path: Path) -> Path:
    folder = tmp_path / "player"
    folder.mkdir()
    (folder / MODULE).write_text("export {};\n")
    return folder


def _one_line_error(capsys, argv: list[str], *words: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("npga-view: error:"), err
    for w in words:
        assert w in err, err


def test_bad_inputs_are_one_line(web_zip: Path, tmp_path: Path, fake_player: Path, capsys) -> None:
    _one_line_error(capsys, ["web", str(tmp_path / "missing.zip"), "--no-browser"], "no such file")
    text = tmp_path / "not.zip"
    text.write_text("hello")
    _one_line_error(capsys, ["web", str(text), "--no-browser"], "not a readable zip")
    _one_line_error(capsys, ["web", str(tmp_path), "--no-browser"], "not a regular file")
    _one_line_error(capsys, ["web", str(web_zip), "--no-browser", "--port", "70000"], "--port")
    _one_line_error(capsys, ["web", str(web_zip), "--no-browser", "--player", str(tmp_path / "nowhere")], "--player")
    _one_line_error(capsys, ["web", str(web_zip), "--no-browser", "--sequence", str(text)], "take")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        _one_line_error(capsys, ["web", str(web_zip), "--no-browser", "--player", str(fake_player), "--port",
                                 str(port)], "--port", "in use")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.bind(("127.0.0.1", 0))
        _one_line_error(capsys, ["web", str(web_zip), "--no-browser", "--live-link", str(udp.getsockname()[1])],
                        "--live-link")


def _fake_npm(folder: Path, version: str, calls: Path) -> Path:
    """An `npm` that installs a stand-in player as `npm install` would, and counts its calls."""
    npm = folder / "npm"
    npm.write_text(f"""#!/bin/sh
echo run >> "{calls}"
/bin/mkdir -p node_modules/{PACKAGE}/build
echo '{{"version": "{version}"}}' > node_modules/{PACKAGE}/package.json
echo 'export {{}};' > node_modules/{PACKAGE}/build/{MODULE}
""")
    npm.chmod(npm.stat().st_mode | stat.S_IXUSR)
    return npm


def test_player_is_installed_into_the_cache_once(tmp_path: Path, monkeypatch, capsys) -> None:
    """Without --player: npm installs the pinned player into the user's cache folder on first use (one line
    saying so), later runs find it there; without npm, one line says what to install."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls"
    _fake_npm(bin_dir, pinned_version(), calls)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("PATH", str(bin_dir))
    build = player(None)
    assert (build / MODULE).is_file() and str(build).startswith(str(tmp_path / "cache"))
    assert "installing LAM's web player" in capsys.readouterr().err
    assert player(None) == build
    assert calls.read_text().split() == ["run"]
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache2"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    _one_line_error(capsys, ["web", str(tmp_path / "x.zip"), "--no-browser"], "no such file")
    zip_path = write_lam_zip(tmp_path / "a.zip", n=30)
    _one_line_error(capsys, ["web", str(zip_path), "--no-browser"], "npm is not found")
    assert json.loads((ROOT / "npga_view" / "web" / "package.json").read_text())["dependencies"][PACKAGE]
