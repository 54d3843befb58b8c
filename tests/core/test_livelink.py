"""Live Link Face UDP: packets in PyLiveLinkFace's layout over loopback, malformed datagrams, neutral, gains,
smoothing and recording to a take that reopens as a sequence.

Packets are built here exactly as PyLiveLinkFace's `encode` builds them (JimWest/PyLiveLinkFace,
pylivelinkface/pylivelinkface.py lines 139-152: ``<I`` version 6, the "$"-prefixed 37-byte uuid, ``!i`` name
length, name, ``!II`` frames and sub-frame 1056060032, ``!II`` fps and int(fps / 60), ``!B61f`` 61 and the
values), and its `decode` (lines 220-243) reads the sub-frame as ``!f``; the 61 values follow its
`FaceBlendShape` order (lines 12-73).
"""

from __future__ import annotations

import socket
import struct
import time
import warnings

import numpy as np
import pytest

from npga_core.files.blendshape_names import ARKIT_52, match_names
from npga_core.files.loading import load_sequence
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.posing.livelink import LiveLinkReceiver, PacketError, decode, encode
from npga_core.posing.smoothing import Smoothing, SmoothingFilter

UUID = "$" + "12345678-9abc-11ee-8000-0242ac120002"


def pylivelinkface_packet(values, frames: int, fps: int = 60, name: str = "iPhone") -> bytes:
    return (struct.pack("<I", 6) + bytes(UUID, "utf-8") + struct.pack("!i", len(name)) + bytes(name, "utf-8")
            + struct.pack("!II", frames, 1056060032) + struct.pack("!II", fps, int(fps / 60))
            + struct.pack("!B61f", 61, *values))


def wait_for(cond, seconds: float = 20.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


def values(**named: float) -> list[float]:
    v = [0.0] * 61
    for k, x in named.items():
        v[ARKIT_52.index(k)] = x
    return v


def test_decode_reads_pylivelinkface_packets():
    p = decode(pylivelinkface_packet(values(jawOpen=0.5, mouthLeft=0.25), 3_000_000, name="Subject"))
    assert p.version == 6 and p.subject == "Subject" and p.device_id == UUID
    assert p.rate == (60, 1) and p.frame == 3_000_000
    assert p.sub_frame == pytest.approx(struct.unpack("!f", struct.pack("!I", 1056060032))[0])
    assert p.values[ARKIT_52.index("jawOpen")] == 0.5 and p.values[ARKIT_52.index("mouthLeft")] == 0.25
    assert p.timestamp == pytest.approx((3_000_000 + p.sub_frame) / 60)
    assert decode(pylivelinkface_packet(values(), 10, fps=30)).fps == 30.0  # int(30 / 60) = 0 read as 1
    again = decode(encode(p.values, p.frame, subject="Subject"))
    np.testing.assert_array_equal(again.values, p.values)


def malformed(rng: np.random.Generator, good: bytes) -> bytes:
    kind = rng.integers(6)
    if kind == 0:
        return rng.bytes(int(rng.integers(0, 700)))
    if kind == 1:
        return good[:int(rng.integers(0, len(good)))]
    if kind == 2:
        return good + rng.bytes(int(rng.integers(1, 8)))
    b = bytearray(good)
    if kind == 3:
        b[41:45] = struct.pack("!i", int(rng.integers(-2**31, 2**31)))  # name length
    elif kind == 4:
        b[len(b) - 245] = int(rng.integers(0, 256)) if rng.random() < 0.5 else 60  # value count
        if b[len(b) - 245] == 61:
            b[len(b) - 245] = 62
    else:
        b[-4:] = struct.pack("!f", float("nan"))
    return bytes(b)


def test_receiver_over_loopback_counts_and_ignores_10000_malformed_packets():
    rng = np.random.default_rng(0)
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        assert rx.address[0] == "127.0.0.1"
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            good = pylivelinkface_packet(values(eyeBlinkLeft=1.0), 1000)
            sent = 0
            for _batch in range(500):  # small batches: a loopback buffer never overflows
                for _ in range(20):
                    tx.sendto(malformed(rng, good), rx.address)
                sent += 20
                assert wait_for(lambda s=sent: rx.counters.bad == s), (rx.counters, sent)
            assert rx.latest() is None and rx.counters.received == 0
            for k in range(5):
                tx.sendto(pylivelinkface_packet(values(eyeBlinkLeft=0.2 * k), 1000 + k), rx.address)
            assert wait_for(lambda: rx.counters.received == 5)
            w, t = rx.latest()
            assert w[ARKIT_52.index("eyeBlinkLeft")] == pytest.approx(0.8)
            assert t == pytest.approx((1004 + 0.47265625) / 60)
        finally:
            tx.close()
        assert rx.counters.bad == 10_000


def test_late_packets_neutral_gains_and_dropped():
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        assert rx.feed(pylivelinkface_packet(values(jawOpen=0.2, eyeBlinkLeft=0.1), 100))
        assert not rx.feed(pylivelinkface_packet(values(jawOpen=0.9), 99))  # older frame
        assert rx.counters.late == 1
        assert rx.capture_neutral()
        rx.feed(pylivelinkface_packet(values(jawOpen=0.6, eyeBlinkLeft=0.05), 101))
        assert rx.counters.dropped == 1  # frame 100's result was never polled
        w, _ = rx.latest()
        assert w[ARKIT_52.index("jawOpen")] == pytest.approx((0.6 - 0.2) / 0.8)
        assert w[ARKIT_52.index("eyeBlinkLeft")] == 0.0  # below the neutral: clipped
        rx.set_gain("JawOpen", 2.0)
        rx.feed(pylivelinkface_packet(values(jawOpen=0.6), 102))
        assert rx.latest()[0][ARKIT_52.index("jawOpen")] == pytest.approx(1.0)
        with pytest.raises(ValueError):
            rx.set_gain("tongue", 1.0)


def test_streamed_smoothing_is_the_one_euro_filter():
    x = np.random.default_rng(1).uniform(0, 1, (30, 61)).astype(np.float32)
    with LiveLinkReceiver(port=0, smoothing=Smoothing("one_euro", min_cutoff=1.0, beta=0.5)) as rx:
        out = []
        for k in range(30):
            rx.feed(pylivelinkface_packet(x[k], 500 + k))
            out.append(rx.latest()[0])
    euro = SmoothingFilter(Smoothing("one_euro", min_cutoff=1.0, beta=0.5))
    np.testing.assert_allclose(np.stack(out), euro.run(x[:, :52], 60.0), atol=1e-5)


def test_recording_reopens_as_a_sequence(tmp_path):
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, (90, 61)).astype(np.float32)
    x[:, 52:] = rng.uniform(-0.3, 0.3, (90, 9))
    with LiveLinkReceiver(port=0, smoothing=None) as rx:
        rx.start_recording()
        for k in range(90):
            rx.feed(pylivelinkface_packet(x[k], 60 * 3600 + 30 + k))
        path = tmp_path / "rec.csv"
        assert rx.stop_recording(path) == 90
        with pytest.raises(ValueError):
            rx.stop_recording(path)
    names = ("eyeBlink_L", "jawOpen", "browInnerUp_L", "browInnerUp_R")
    basis = BlendshapeBasis(names, np.eye(4), np.zeros(4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = load_sequence(path, basis=basis)
    assert len(seq) == 90 and seq.fps == 60.0
    expect = match_names(ARKIT_52, names).apply(x[:, :52])
    np.testing.assert_allclose(seq.codes, expect, atol=1e-5)
    assert seq.pose is not None


def test_decode_never_raises_other_errors():
    rng = np.random.default_rng(3)
    for _ in range(2000):
        with pytest.raises(PacketError):
            decode(rng.bytes(int(rng.integers(0, 400))))


def test_a_clock_jump_re_anchors_the_stream():
    """#36: one packet stamped 11 hours ahead (60 fps) made every later valid packet "late" until the clock caught
    up: the stream froze. A jump (ahead by more than JUMP_S, or back by more than REORDER_S) re-anchors the clock
    on the packet and restarts the smoothing; a packet slightly behind is still late."""
    with LiveLinkReceiver(port=0, smoothing=Smoothing("one_euro", min_cutoff=1.0, beta=0.5)) as rx:
        assert rx.feed(pylivelinkface_packet(values(jawOpen=0.1), 1000))
        assert rx.feed(pylivelinkface_packet(values(jawOpen=0.2), 1000 + 11 * 3600 * 60))  # 11 hours ahead
        for k in range(1, 6):
            assert rx.feed(pylivelinkface_packet(values(jawOpen=0.3 + 0.1 * k), 1000 + k))
        assert rx.counters.late == 0 and rx.counters.jumps == 2 and rx.counters.received == 7
        assert not rx.feed(pylivelinkface_packet(values(jawOpen=0.9), 1003))  # reordered: late
        assert rx.counters.late == 1
        w, t = rx.latest()
        assert 1005 / 60 <= t < 1006 / 60
