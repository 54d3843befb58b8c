"""Live Link Face over UDP: packets decoded as the iPhone app sends them, a receiver thread, neutral capture,
per-channel gains, one-euro smoothing and recording to a take that reopens as a sequence.

Packet layout (PyLiveLinkFace, JimWest/PyLiveLinkFace pylivelinkface/pylivelinkface.py, `encode`/`decode`):

====================  =========================================================
bytes                 field
====================  =========================================================
4, little-endian u32  version (6)
37, UTF-8             device id ("$" + a 36-character UUID)
4, big-endian i32     subject name length n
n, UTF-8              subject name
4, big-endian i32     frame number (timecode frames of the day at the rate)
4, big-endian f32     sub-frame
4 + 4, big-endian     frame rate numerator, denominator (PyLiveLinkFace sends int(fps / 60),
                      0 below 60 fps: read as 1)
1, u8                 value count (61)
61 x 4, big-endian    52 ARKit shapes in `ARKIT_52` order, then head yaw, pitch, roll and the
f32                   left and right eye yaw, pitch, roll (`ANGLE_NAMES`)
====================  =========================================================

The receiver binds to loopback unless told otherwise; a controller polls `latest()` once per UI frame.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from npga_core.files.arkit_takes import Take, write_livelink_csv
from npga_core.files.blendshape_names import ANGLE_NAMES, ARKIT_52
from npga_core.posing.smoothing import Smoothing, SmoothingFilter

VALUES = 61
SHAPES = len(ARKIT_52)
CHANNELS: tuple[str, ...] = (*ARKIT_52, *ANGLE_NAMES)
DEFAULT_PORT = 11111
#: The receiver's smoothing of the weights unless told otherwise (`npga-view web`'s stream).
STREAM_SMOOTHING = Smoothing("one_euro", min_cutoff=1.0, beta=0.5)
_ID_BYTES = 37
_TAIL = struct.Struct("!ifiiB")  # frame, sub-frame, rate numerator, denominator, value count
_VALUES = struct.Struct(f"!{VALUES}f")
MAX_SUBJECT = 256
MAX_PACKET = 45 + MAX_SUBJECT + _TAIL.size + _VALUES.size
#: A packet at most this many seconds behind the last one taken is late (reordered or repeated); one further
#: behind or ahead (more than `JUMP_S`) means the sender's clock jumped (a stamp 11 hours ahead, a restart, a
#: device switched): the clock re-anchors on it and the smoothing restarts, instead of calling every later
#: packet late until the clock catches up.
REORDER_S = 1.0
JUMP_S = 2.0
#: Linux's SO_RXQ_OVFL (asm-generic/socket.h): with it set, each datagram read carries the socket's count of
#: datagrams the kernel dropped (receive buffer full) before it was queued.
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)


class PacketError(ValueError):
    """A datagram that is not a well-formed Live Link Face packet."""


@dataclass(frozen=True)
class Packet:
    """One decoded packet: 61 values (`CHANNELS`) at a frame time."""

    version: int
    device_id: str
    subject: str
    frame: int
    sub_frame: float
    rate: tuple[int, int]  # numerator, denominator
    values: np.ndarray  # (61,) float32

    @property
    def fps(self) -> float:
        return self.rate[0] / self.rate[1]

    @property
    def timestamp(self) -> float:
        """Seconds of the day of the frame (frame number plus sub-frame, at the rate)."""
        return (self.frame + self.sub_frame) / self.fps


def decode(data: bytes) -> Packet:
    """The packet in a datagram; PacketError for anything malformed (never another exception)."""
    if len(data) < 45 + _TAIL.size + _VALUES.size or len(data) > MAX_PACKET:
        raise PacketError(f"{len(data)} bytes is no Live Link Face packet size")
    version = struct.unpack_from("<I", data, 0)[0]
    (n,) = struct.unpack_from("!i", data, 41)
    if not 0 <= n <= MAX_SUBJECT or len(data) != 45 + n + _TAIL.size + _VALUES.size:
        raise PacketError(f"subject length {n} does not fit a {len(data)}-byte packet")
    try:
        device = data[4:41].decode("utf-8")
        subject = data[45:45 + n].decode("utf-8")
    except UnicodeDecodeError:
        raise PacketError("device id or subject is not UTF-8") from None
    frame, sub, num, den, count = _TAIL.unpack_from(data, 45 + n)
    if count != VALUES:
        raise PacketError(f"value count {count}, expected {VALUES}")
    den = den if den > 0 else 1
    if not (0 < num <= 1000 and den <= 1000 and frame >= 0 and math.isfinite(sub) and 0 <= sub < 1):
        raise PacketError(f"frame time {frame}+{sub} at {num}/{den} is out of range")
    values = np.array(_VALUES.unpack_from(data, 45 + n + _TAIL.size), np.float32)
    if not np.isfinite(values).all() or np.abs(values).max() > 100:
        raise PacketError("values are NaN/Inf or out of range")
    return Packet(version, device, subject, frame, float(sub), (num, den), values)


def encode(values: np.ndarray, frame: int, fps: int = 60, subject: str = "npga", device_id: str = "$" + "0" * 36,
           sub_frame: float = 0.0, version: int = 6) -> bytes:
    """A packet in the same layout (for senders and tests)."""
    name = subject.encode("utf-8")
    dev = device_id.encode("utf-8")[:_ID_BYTES].ljust(_ID_BYTES, b"0")
    return (struct.pack("<I", version) + dev + struct.pack("!i", len(name)) + name
            + _TAIL.pack(frame, sub_frame, fps, 1, VALUES) + _VALUES.pack(*np.asarray(values, np.float32)))


@dataclass
class Counters:
    """What became of every datagram: each one read is counted once as received, late, bad or ignored; each
    received packet is then either taken (`latest()` returned it), dropped (replaced by a newer one before
    `latest()` saw it) or still pending (the newest, not yet seen): received == taken + dropped + pending.
    Datagrams the OS dropped before the receiver read them (its buffer full) are `overflow` where the OS counts
    them (Linux: SO_RXQ_OVFL, as of the last datagram read), else never seen and not counted."""

    received: int = 0  # well-formed packets taken in as the newest
    late: int = 0  # well-formed but not newer than the last one taken (reordered or repeated)
    dropped: int = 0  # taken in but replaced by a newer one before `latest()` saw it
    bad: int = 0  # malformed datagrams
    jumps: int = 0  # packets whose time jumped by more than JUMP_S (or back by more than REORDER_S): re-anchored
    taken: int = 0  # packets `latest()` handed out (each once)
    ignored: int = 0  # well-formed packets of another subject than the one listened for
    overflow: int = 0  # datagrams the OS dropped before they were read (counted only where `counts_overflow`)


class LiveLinkReceiver:
    """Receives Live Link Face packets on a thread; `latest()` gives the newest processed weights.

    Processing per packet: neutral removal (``(w - n) / (1 - n)`` clipped at 0, n the captured rest weights),
    per-channel gains, then `smoothing` (`npga_core.posing.smoothing`; default the one-euro filter) over the
    packets' own frame times; None: none (the window smooths the codes itself, as its Timeline says). Head and eye
    angles (radians) are made relative to the neutral's.
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", subject: str | None = None,
                 smoothing: Smoothing | None = STREAM_SMOOTHING):
        self.subject = subject
        self.counters = Counters()
        self._lock = threading.Lock()
        self._gains = np.ones(SHAPES, np.float64)
        self._neutral = np.zeros(VALUES, np.float64)
        self._filter = SmoothingFilter(smoothing) if smoothing is not None else None
        self._raw: np.ndarray | None = None
        self._out: tuple[np.ndarray, np.ndarray, float] | None = None
        self._seen = True
        self._last_t: float | None = None
        self._fps = 60.0
        self._record: list[tuple[float, np.ndarray, np.ndarray]] | None = None
        self.on_packet: Callable[[], object] | None = None  # called (on the thread) after a packet is taken
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        with contextlib.suppress(OSError):  # room for a burst while the thread is descheduled
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        #: whether the OS reports the datagrams it drops (`Counters.overflow`): Linux only
        self.counts_overflow = False
        if sys.platform.startswith("linux") and hasattr(self._sock, "recvmsg"):
            with contextlib.suppress(OSError):
                self._sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
                self.counts_overflow = True
        self._sock.bind((host, port))
        self._sock.settimeout(0.05)
        self.address: tuple[str, int] = self._sock.getsockname()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="livelink-receiver", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ thread

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._recv()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            if self.feed(data) and self.on_packet is not None:
                with contextlib.suppress(Exception):
                    self.on_packet()

    def _recv(self) -> bytes:
        """One datagram; where the OS counts its drops, their count (cumulative) is taken as `overflow`."""
        if not self.counts_overflow:
            return self._sock.recv(MAX_PACKET + 1)
        data, ancillary, _, _ = self._sock.recvmsg(MAX_PACKET + 1, socket.CMSG_SPACE(4))
        for level, kind, raw in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(raw) >= 4:
                n = int.from_bytes(raw[:4], sys.byteorder)
                with self._lock:
                    self.counters.overflow = max(self.counters.overflow, n)
        return data

    def feed(self, data: bytes) -> bool:
        """Take one datagram (the thread calls this; tests and replays may too); True if it was used."""
        try:
            p = decode(data)
        except PacketError:
            with self._lock:
                self.counters.bad += 1
            return False
        if self.subject is not None and p.subject != self.subject:
            with self._lock:
                self.counters.ignored += 1
            return False
        with self._lock:
            t = p.timestamp
            dt = t - self._last_t if self._last_t is not None else 0.0
            if dt < -43200.0:  # past midnight
                dt += 86400.0
            if self._last_t is not None and -REORDER_S <= dt <= 0.0:
                self.counters.late += 1
                return False
            if not 0.0 <= dt <= JUMP_S:  # the clock jumped: re-anchored here, the filter restarts (dt 0)
                self.counters.jumps += 1
                dt = 0.0
            self._last_t, self._fps = t, p.fps
            self.counters.received += 1
            if not self._seen:
                self.counters.dropped += 1
            raw = p.values.astype(np.float64)
            self._raw = raw
            n = self._neutral[:SHAPES]
            w = np.clip((raw[:SHAPES] - n) / np.maximum(1.0 - n, 1e-3), 0.0, None) * self._gains
            angles = raw[SHAPES:] - self._neutral[SHAPES:]
            if self._filter is not None:
                w = self._filter.step(w, dt).astype(np.float64)
            self._out = (w.astype(np.float32), angles.astype(np.float32), t)
            self._seen = False
            if self._record is not None:
                self._record.append((t, w.astype(np.float32), angles))
        return True

    # ------------------------------------------------------------------ poll API

    def latest(self) -> tuple[np.ndarray, float] | None:
        """(weights (52,) over `ARKIT_52`, frame time in seconds) of the newest packet; None before the first."""
        with self._lock:
            if self._out is None:
                return None
            if not self._seen:
                self.counters.taken += 1
            self._seen = True
            return self._out[0].copy(), self._out[2]

    @property
    def pending(self) -> int:
        """1 while the newest packet received has not been handed out by `latest()`, else 0."""
        with self._lock:
            return int(self._out is not None and not self._seen)

    def angles(self) -> np.ndarray | None:
        """Head yaw, pitch, roll and eye angles (9,) of the newest packet, relative to the neutral."""
        with self._lock:
            return None if self._out is None else self._out[1].copy()

    def capture_neutral(self) -> bool:
        """Take the newest raw packet as the rest pose; False if none arrived yet."""
        with self._lock:
            if self._raw is None:
                return False
            self._neutral = self._raw.copy()
            if self._filter is not None:
                self._filter.reset()
            return True

    def clear_neutral(self) -> None:
        with self._lock:
            self._neutral = np.zeros(VALUES, np.float64)

    def set_gain(self, name: str, gain: float) -> None:
        """The gain of one shape (any spelling of an ARKit name)."""
        from npga_core.files.blendshape_names import canonical_arkit

        key = canonical_arkit(name)
        if key is None or not (math.isfinite(gain) and 0 <= gain <= 10):
            raise ValueError(f"no ARKit shape {name!r} or gain {gain} outside [0, 10]")
        with self._lock:
            self._gains[ARKIT_52.index(key)] = gain

    # ------------------------------------------------------------------ recording

    def start_recording(self) -> None:
        with self._lock:
            self._record = []

    @property
    def recording(self) -> bool:
        return self._record is not None

    def stop_recording(self, path: str | Path) -> int:
        """Write what was recorded as a Live Link Face CSV take (atomically); returns the frame count."""
        with self._lock:
            rows, self._record, fps = self._record or [], None, self._fps
        if not rows:
            raise ValueError("nothing was recorded")
        t0 = rows[0][0]
        times = np.array([(r[0] - t0) % 86400.0 for r in rows])
        head = np.stack([r[2][:3] for r in rows])
        eyes = np.stack([r[2][3:] for r in rows])
        take = Take(np.stack([r[1] for r in rows]), ARKIT_52, times, fps, head, eyes)
        write_livelink_csv(path, take, start=t0)
        return len(rows)

    # ------------------------------------------------------------------ lifetime

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> LiveLinkReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
