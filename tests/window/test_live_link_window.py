"""The Live Link Face stream into the real window under Xvfb: packets in the community decoder's layout over
loopback pose the avatar on the pixels, 10,000 malformed packets are counted and ignored, and a recorded take
reopens with the sent weights.

The packets are built as PyLiveLinkFace builds them (JimWest/PyLiveLinkFace at 28804bd,
pylivelinkface/pylivelinkface.py): `encode` (lines 141-158) packs ``'<I'`` version 6, the UUID ``'$'`` + 36
characters, ``'!i'`` name length and the name, ``'!II'`` timecode frames and ``_sub_frame`` = 1056060032 (line 96,
an integer whose bits read as a float sub-frame), ``'!II'`` fps and ``int(fps / 60)`` (line 97), ``'!B61f'`` 61
and the values in `FaceBlendShape` order (lines 10-71: EyeBlinkLeft = 0 ... TongueOut = 51, HeadYaw = 52 ...
RightEyeRoll = 60).
"""

from __future__ import annotations

import socket
import struct
import uuid

import numpy as np
import pytest

from npga_core.files.arkit_takes import read_take
from npga_core.files.blendshape_names import ARKIT_52, canonical_arkit
from npga_core.files.checkpoint import save_avatar
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.synthetic import make_synthetic_avatar

pytestmark = pytest.mark.gui

NAMES = ("jawOpen", "eyeBlinkLeft", "mouthSmileLeft", "browInnerUp")


def pylivelinkface_packet(values: np.ndarray, frames: int, fps: int = 60, name: str = "iPhone") -> bytes:
    """A datagram laid out exactly as PyLiveLinkFace.encode lays it out (see the module docstring)."""
    dev = "$" + str(uuid.uuid1())
    return (struct.pack("<I", 6) + dev.encode("utf-8") + struct.pack("!i", len(name)) + name.encode("utf-8")
            + struct.pack("!II", frames, 1056060032) + struct.pack("!II", fps, int(fps / 60))
            + struct.pack("!B61f", 61, *np.asarray(values, np.float32)))


def values(**weights: float) -> np.ndarray:
    v = np.zeros(61, np.float32)
    for k, w in weights.items():
        v[ARKIT_52.index(k)] = w
    return v


@pytest.fixture(scope="module")
def display():
    from tests.support.xvfb import xvfb_display

    yield from xvfb_display()


@pytest.fixture
def app(display, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    from npga_view.app import ViewerApp

    avatar = make_synthetic_avatar(1500, code_dim=8, n_components=8, seed=5)
    rng = np.random.default_rng(9)
    avatar.blendshapes = BlendshapeBasis(NAMES, 2.5 * rng.standard_normal((8, len(NAMES))), avatar.expression.mean,
                                         "test")
    path = tmp_path / "live.npga"
    save_avatar(avatar, path)
    a = ViewerApp(1000, 990, vsync=False, threads=1, remember_recent=False)
    assert a.open_avatar(str(path))
    yield a
    a.close()


def _listen(app):
    from tests.support.window import click, run_until, settle

    settle(app)
    app.panels.timeline.live.address = "127.0.0.1:0"  # a free port
    click(app, "live_start")
    assert app.live.receiver is not None, app.state.errors
    assert run_until(app, lambda: app.info.live_listening, timeout=10)
    return app.live.receiver.address


def _sender():
    return socket.socket(socket.AF_INET, socket.SOCK_DGRAM)


def test_packets_pose_the_avatar_on_the_pixels(app):
    from tests.support.window import run_until, settle

    addr = _listen(app)
    assert addr[0] == "127.0.0.1"  # loopback unless asked otherwise
    before = app.read_window(viewport_only=True)
    sent = values(jawOpen=1.0, eyeBlinkLeft=0.8, browInnerUp=0.6)
    basis = app.avatar.blendshapes
    want = basis.codes(np.array([1.0, 0.8, 0.0, 0.6]))
    with _sender() as s:
        s.sendto(pylivelinkface_packet(sent, 3_000_000), addr)
        assert run_until(app, lambda: app.live.taken >= 1, timeout=20)
    # the pose controller asked for the live code in the frame that took the packet
    np.testing.assert_allclose(app.poses.requested, want, atol=1e-5)
    assert run_until(app, lambda: app.shown_code() is not None and np.allclose(app.shown_code(), want, atol=1e-5),
                     timeout=60)
    settle(app)
    after = app.read_window(viewport_only=True)
    changed = np.abs(after.astype(int) - before.astype(int)).max(axis=2) > 8
    assert changed.mean() > 0.002, f"only {changed.mean():.4%} of the pixels changed"
    assert "1 received" in app.info.live_counters and "0 bad" in app.info.live_counters


def test_ten_thousand_malformed_packets_leave_the_window_running(app):
    from tests.support.window import run_until

    addr = _listen(app)
    rng = np.random.default_rng(1)
    good = pylivelinkface_packet(values(jawOpen=0.5), 3_000_000)
    bad = [
        lambda: rng.bytes(int(rng.integers(0, 400))),  # noise of any length
        lambda: good[: int(rng.integers(0, len(good)))],  # truncated
        lambda: good + b"x",  # one byte too many
        lambda: good[:41] + struct.pack("!i", -5) + good[45:],  # negative name length
        lambda: good[:41] + struct.pack("!i", 2**31 - 1) + good[45:],  # huge name length
        lambda: good[:-245] + struct.pack("!B", 60) + good[-244:],  # value count 60
        lambda: good[:-244] + struct.pack("!61f", *([np.nan] * 61)),  # NaN weights
        lambda: good[:-244] + struct.pack("!61f", *([1e30] * 61)),  # absurd weights
        lambda: good[:-253] + struct.pack("!II", 0, 1) + good[-245:],  # frame rate 0
    ]
    with _sender() as s:
        for batch in range(100):
            for k in range(100):
                s.sendto(bad[(batch * 100 + k) % len(bad)](), addr)
            app.step()
            assert not app.should_close and app.window is not None
        assert run_until(app, lambda: app.live.receiver.counters.bad >= 5000, timeout=30), app.info.live_counters
        # still listening, and a good packet still poses
        s.sendto(good, addr)
        assert run_until(app, lambda: app.live.receiver.counters.received >= 1, timeout=20)
    assert app.live.receiver.counters.received == 1
    assert run_until(app, lambda: app.live.taken >= 1, timeout=20)
    assert "bad" in app.info.live_counters and not app.state.errors


def test_recorded_take_reopens_with_the_sent_weights(app, tmp_path):
    from npga_core.files.loading import load_sequence
    from tests.support.window import click, run_until

    addr = _listen(app)
    take = tmp_path / "rec.csv"
    app.panels.timeline.live.take_path = str(take)
    click(app, "live_record")
    assert run_until(app, lambda: app.info.live_recording, timeout=10)
    rng = np.random.default_rng(3)
    sent = [values(**{n: float(rng.uniform(0, 1)) for n in NAMES}) for _ in range(6)]
    with _sender() as s:
        for k, v in enumerate(sent):
            s.sendto(pylivelinkface_packet(v, 3_000_000 + k), addr)
            assert run_until(app, lambda k=k: app.live.receiver.counters.received >= k + 1, timeout=20)
    click(app, "live_record")  # stop: the take is written
    assert run_until(app, lambda: take.is_file(), timeout=10), app.state.errors
    t = read_take(take)
    keys = [canonical_arkit(n) for n in t.names]
    got = t.weights[:, [keys.index(n) for n in ARKIT_52]]
    np.testing.assert_allclose(got, np.stack(sent)[:, :52], atol=1e-5)
    assert t.fps == 60.0 and len(t.weights) == 6
    seq = load_sequence(take, basis=app.avatar.blendshapes)
    assert len(seq) == 6
    click(app, "live_open_take")
    assert app.sequence is not None and len(app.sequence) == 6, app.state.errors


def test_neutral_and_gains_act_on_the_stream(app):
    """Neutral: the packet on hand becomes the rest pose (the same packet then poses the basis offset); a gain
    scales its channel."""
    from npga_view import actions as A
    from tests.support.window import click, run_until

    addr = _listen(app)
    basis = app.avatar.blendshapes
    with _sender() as s:
        s.sendto(pylivelinkface_packet(values(jawOpen=0.5), 3_000_000), addr)
        assert run_until(app, lambda: app.live.taken >= 1, timeout=20)
        click(app, "live_neutral")
        s.sendto(pylivelinkface_packet(values(jawOpen=0.5), 3_000_001), addr)
        assert run_until(app, lambda: app.live.taken >= 2, timeout=20)
        np.testing.assert_allclose(app.live.code, basis.offset, atol=1e-5)
        app.state.actions.append(A.LiveLinkGain("JawOpen", 2.0))
        app.step()
        s.sendto(pylivelinkface_packet(values(jawOpen=0.75), 3_000_002), addr)  # (0.75 - 0.5) / 0.5 = 0.5
        assert run_until(app, lambda: app.live.taken >= 3, timeout=20)
    np.testing.assert_allclose(app.live.code, basis.codes(np.array([1.0, 0.0, 0.0, 0.0])), atol=1e-5)


def test_bad_live_link_address_is_one_line_and_exit_2(capsys):
    from npga_view.cli.main import main

    assert main(["view", "demo", "--live-link", "localhost:http", "--quit-after-frames", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--live-link" in err and "[HOST:]PORT" in err


def test_head_angles_move_the_head(app):
    """HeadYaw/HeadPitch/HeadRoll (channels 52-54) move the head as a take's head angles do."""
    from npga_core.files.arkit_takes import head_pose
    from tests.support.window import run_until

    addr = _listen(app)
    plain = app.current_camera().world_to_camera.copy()
    v = values(jawOpen=0.2)
    v[52:55] = (0.3, -0.1, 0.05)
    with _sender() as s:
        s.sendto(pylivelinkface_packet(v, 3_000_000), addr)
        assert run_until(app, lambda: app.live.taken >= 1, timeout=20)
    moved = app.current_camera().world_to_camera
    np.testing.assert_allclose(moved, plain @ head_pose(np.array([[0.3, -0.1, 0.05]]))[0], atol=1e-5)
    app.state.timeline.head_pose = False  # the Timeline's Head pose switch turns it off
    np.testing.assert_allclose(app.current_camera().world_to_camera, plain, atol=1e-9)
