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
import threading
import time
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


# --- twenty seconds of a stream --------------------------------------------------------------------------------
# Twenty seconds of Live Link Face at 60 packets/s into the real window under Xvfb: the jaw alternates between shut
# and open every second, and the view's pixels follow (each image shows the phase of the pose it is of, the pose
# shown alternates with the phases, and after the stream the image returns to the settled image of its phase); the
# receiver's counters account for every packet (received == sent, received == taken + dropped + pending, the
# window took exactly what the receiver handed out), and nothing was reported as an error.
#
# Behaviour, not speed: images are taken about four times a second whatever the frame rate, and each is judged by
# the pose the window says it shows, so a slow machine shows fewer switches, not other pixels. Packets are laid
# out as PyLiveLinkFace's `encode` lays them out (`pylivelinkface_packet` above).
SECONDS, RATE = 20, 60
SHUT = {"jawOpen": 0.0}
OPEN = {"jawOpen": 1.0, "mouthSmileLeft": 1.0}
FRAME0 = 3_000_000


def _phase_values(i: int) -> np.ndarray:
    """Packet i of the stream: phase (i // RATE) even shut, odd open."""
    return values(**(OPEN if (i // RATE) % 2 else SHUT))


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.int32) - b.astype(np.int32)).mean())


def test_sixty_packets_a_second_for_twenty_seconds_move_the_pixels_phase_by_phase(app):
    from .test_gui import run_until, settle

    addr = _listen(app)
    basis = app.avatar.blendshapes
    names = list(basis.names)
    codes = {kind: basis.codes(np.array([w.get(n, 0.0) for n in names])) for kind, w in
             (("shut", SHUT), ("open", OPEN))}
    refs = {}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        # the settled image of each phase, from one packet each (frames before the stream's)
        for k, kind in enumerate(("open", "shut")):
            s.sendto(pylivelinkface_packet(values(**(OPEN if kind == "open" else SHUT)), FRAME0 - 100 + k), addr)
            assert run_until(app, lambda k=k: app.live.taken >= k + 1, timeout=30), app.info.live_counters
            assert run_until(app, lambda kind=kind: _shows(app, codes[kind]), timeout=60)
            settle(app)
            refs[kind] = app.read_window(viewport_only=True)
        apart = _distance(refs["open"], refs["shut"])
        assert apart > 0.5, f"the two phases look alike ({apart:.3f} mean grey levels apart)"
        before = app.live.receiver.counters.received

        sent = [0]

        def stream() -> None:
            t0 = time.monotonic()
            for i in range(SECONDS * RATE):
                time.sleep(max(0.0, t0 + i / RATE - time.monotonic()))
                s.sendto(pylivelinkface_packet(_phase_values(i), FRAME0 + i), addr)
                sent[0] += 1

        sender = threading.Thread(target=stream, daemon=True)
        sender.start()
        shots: list[tuple[str, np.ndarray]] = []
        last_shot = 0.0
        while sender.is_alive():
            shown = _kind(app, codes)
            app.step()
            # an image is judged by the pose shown before and after the frame that drew it (a pose that arrived
            # during the frame is drawn by the next one); None: between poses, the image shows neither
            if time.monotonic() - last_shot >= 0.25 and shown is not None and _kind(app, codes) == shown:
                shots.append((shown, app.read_window(viewport_only=True)))
                last_shot = time.monotonic()
        sender.join()
        last = "open" if ((SECONDS * RATE - 1) // RATE) % 2 else "shut"
        rx = app.live.receiver
        assert run_until(app, lambda: rx.counters.received - before == sent[0] and rx.pending == 0, timeout=30), \
            (sent[0], rx.counters)
        assert run_until(app, lambda: _shows(app, codes[last]), timeout=60)
        settle(app)
        end = app.read_window(viewport_only=True)

    # counters: every packet received, each handed to the window or replaced by a newer one before it looked
    c = rx.counters
    assert c.received - before == sent[0] == SECONDS * RATE, c
    assert c.late == 0 and c.bad == 0 and c.ignored == 0 and c.overflow == 0, c
    assert c.received == c.taken + c.dropped and rx.pending == 0, c
    assert app.live.taken == c.taken, (app.live.taken, c)
    assert not app.state.errors, app.state.errors
    # the pixels followed the phases: both poses shown, several switches between them
    kinds = [k for k, _ in shots]
    switches = sum(a != b for a, b in zip(kinds, kinds[1:], strict=False))
    assert kinds.count("open") >= 2 and kinds.count("shut") >= 2 and switches >= 3, kinds
    # each image shows its phase: nearer the settled image of the pose it is of than the other's. The first
    # image(s) of a new pose may still be the previous pose's (the live path shows the last merge moved along
    # until the new one arrives, commit d1e5d0c; seen for ~3-7% of these images although the window reported the
    # new pose shown and exact), so: the last image of each run of one pose shows it, and most images do
    right = [_distance(img, refs[k]) < _distance(img, refs["open" if k == "shut" else "shut"]) for k, img in shots]
    runs = [i for i in range(len(shots)) if (i + 1 == len(shots) or kinds[i + 1] != kinds[i])
            and i > 0 and kinds[i - 1] == kinds[i]]  # the last image of each run of >= 2 images of one pose
    assert len(runs) >= 3 and all(right[i] for i in runs), ([i for i in runs if not right[i]], kinds)
    assert sum(right) >= 0.75 * len(shots), (right, kinds)
    # and after the stream, the image returns to the earlier settled image of the last phase
    assert _distance(end, refs[last]) < 0.2 * apart, (_distance(end, refs[last]), apart)


def _shows(window, code: np.ndarray) -> bool:
    z = window.shown_code()
    return z is not None and len(z) == len(code) and bool(np.allclose(z, code, atol=1e-5))


def _kind(window, codes: dict[str, np.ndarray]) -> str | None:
    return next((k for k, z in codes.items() if _shows(window, z)), None)
