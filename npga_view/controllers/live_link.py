"""`LiveLinkController`: the window's Live Link Face receiver (the iPhone app, `npga-view webcam`, any sender
in PyLiveLinkFace's layout).

Once per UI frame `update` polls `LiveLinkReceiver.latest()`; a new packet's weights go through the avatar's
blendshape basis (`avatar.blendshapes`, names matched by `npga_core.files.blendshape_names`) to a code, which is
smoothed as the Timeline panel smooths sequences (none, exponential or one-euro, over the packets' own frame
times) and handed to the pose controller in the same frame (`code_or`), which asks the worker for it the way it
does for sliders and playback. The head angles move the head as a take's do (`head_transform`, applied to the
view's camera by the app). Neutral, gains and recording are the receiver's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from npga_core.files.arkit_takes import head_pose
from npga_core.files.blendshape_names import ARKIT_52, NameMatch, match_names
from npga_core.posing.livelink import DEFAULT_PORT, LiveLinkReceiver
from npga_core.posing.smoothing import Smoothing, SmoothingFilter

if TYPE_CHECKING:
    from npga_core.model.avatar import Avatar
from npga_view import actions as A
from npga_view.controllers.host import ViewerHost
from npga_view.display import AppInfo

#: How long after the last packet the window keeps drawing at full rate (no idle wait between frames).
BUSY_S = 0.5


def parse_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); the host defaults to loopback. ValueError naming the problem."""
    text = str(text).strip()
    host, _, port_text = text.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"Live Link address {text!r}: expected [HOST:]PORT, e.g. {DEFAULT_PORT}") from None
    if not 0 <= port < 65536:
        raise ValueError(f"Live Link address {text!r}: port {port} is outside 0..65535")
    return host, port


class LiveLinkController:
    """Owned by the app; see the module docstring. `status` and `counters_line` feed the panel and overlay."""

    def __init__(self, host: ViewerHost, wake: Callable[[], None] | None = None):
        self.host = host
        self.wake = wake  # called from the receiver thread when a packet arrives (wakes an idle window)
        self.receiver: LiveLinkReceiver | None = None
        self.code: np.ndarray | None = None  # the newest (smoothed) code
        self.head: np.ndarray | None = None  # canonical -> world 4x4 of the newest packet's head angles
        self.status = "off"
        self.unmatched = ""  # the names the avatar's basis lacks (reported once per start)
        self.last_packet_t: float | None = None  # frame time of the newest packet taken
        self.taken = 0  # packets turned into codes (at most one per UI frame)
        self._last_arrival = -math.inf
        self._match: tuple[int, NameMatch] | None = None
        self._filter: SmoothingFilter | None = None  # the Timeline's smoothing, one packet at a time

    # ------------------------------------------------------------------------------------ listening
    @property
    def listening(self) -> bool:
        return self.receiver is not None

    def start(self, address: str | int) -> bool:
        """Listen on ``[HOST:]PORT`` (loopback by default); problems are reported, False returned."""
        self.stop()
        st = self.host.state
        try:
            host, port = parse_address(str(address))
            basis = self._basis()
            self.receiver = LiveLinkReceiver(port=port, host=host, smoothing=None)
        except (ValueError, OSError) as e:
            msg = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            st.report(f"Live Link: {msg}")
            self.status = "off"
            return False
        self.receiver.on_packet = self._arrived
        self.unmatched = match_names(ARKIT_52, basis.names).report() if basis is not None else ""
        self.status = f"listening on {self.receiver.address[0]}:{self.receiver.address[1]}"
        self.code, self.last_packet_t, self.taken = None, None, 0
        self._filter = None
        st.follow_sequence = False
        return True

    def stop(self) -> None:
        if self.receiver is not None:
            self.receiver.close()
        self.receiver, self.code, self.head = None, None, None
        self.status = "off"

    close = stop

    def _arrived(self) -> None:
        self._last_arrival = time.monotonic()
        if self.wake is not None:
            self.wake()

    def busy(self) -> bool:
        """Packets are arriving: the window should not idle between frames."""
        return self.receiver is not None and time.monotonic() - self._last_arrival < BUSY_S

    # ------------------------------------------------------------------------------------ per frame
    def _basis(self):
        a = self.host.doc.avatar
        if a is None or a.code_dim == 0:
            raise ValueError("open an animatable avatar first")
        if a.blendshapes is None:
            raise ValueError("this avatar has no blendshape basis (fit one with `npga-view fit-blendshapes`)")
        return a.blendshapes

    def update(self) -> None:
        """Take the newest packet (if a new one arrived) as the live code."""
        rx = self.receiver
        if rx is None:
            return
        got = rx.latest()
        if got is None or got[1] == self.last_packet_t:
            return
        weights, t = got
        a = self.host.doc.avatar
        basis = a.blendshapes if a is not None else None
        av = cast("Avatar", a)  # there is a basis only with an avatar
        if basis is None or basis.code_dim not in (av.code_dim, av.code_dim - av.condition_dim):
            self.status = "no blendshape basis for this avatar"
            return
        if self._match is None or self._match[0] != id(basis):
            self._match = (id(basis), match_names(ARKIT_52, basis.names))
        code = basis.codes(self._match[1].apply(weights[None]))[0]
        dt = 0.0 if self.last_packet_t is None else (t - self.last_packet_t) % 86400.0
        self.code = self._smooth(code, dt)
        angles = rx.angles()
        head = angles[:3] if angles is not None else None
        # the head yaw, pitch and roll move the head as a take's do (arkit_takes.head_pose); all 0: none sent
        self.head = head_pose(head[None])[0] if head is not None and np.any(head) else None
        self.last_packet_t = t
        self.taken += 1

    def _smooth(self, code: np.ndarray, dt: float) -> np.ndarray:
        """The Timeline panel's smoothing (the filter sequences are smoothed with), one sample at a time; it
        starts afresh when its settings change."""
        settings = Smoothing.of(self.host.state.timeline)
        if self._filter is None or self._filter.settings != settings:
            self._filter = SmoothingFilter(settings)
        return self._filter.step(code, dt)

    def head_transform(self) -> np.ndarray | None:
        """The live head pose to apply to the view (None when not listening or no head angles came)."""
        return self.head if self.receiver is not None and self.host.state.timeline.head_pose else None

    def code_or(self, fallback: Callable[[], np.ndarray | None]) -> Callable[[], np.ndarray | None]:
        """A code source for the pose controller: the live code while listening, else `fallback`'s."""
        def source() -> np.ndarray | None:
            a, z = self.host.doc.avatar, self.code
            if self.receiver is not None and z is not None and a is not None \
                    and len(z) in (a.code_dim, a.code_dim - a.condition_dim):
                return z
            return fallback()
        return source

    # ------------------------------------------------------------------------------------ controls
    def counters_line(self) -> str:
        if self.receiver is None:
            return ""
        c = self.receiver.counters
        return (f"Live Link: {c.received} received, {c.dropped} dropped, {c.late} late, {c.bad} bad"
                + (" (recording)" if self.receiver.recording else ""))

    def neutral(self) -> None:
        if self.receiver is None or not self.receiver.capture_neutral():
            raise ValueError("Live Link: no packet yet to take as the neutral")
        self._filter = None

    def set_gain(self, name: str, gain: float) -> None:
        if self.receiver is not None:
            self.receiver.set_gain(name, gain)

    def record(self, path: str | None) -> str | None:
        """Start recording (path None) or stop and write the take to `path`; returns what was done."""
        rx = self.receiver
        if rx is None:
            raise ValueError("Live Link: not listening")
        if path is None:
            rx.start_recording()
            return None
        p = Path(path).expanduser()
        if p.suffix.lower() != ".csv":
            raise ValueError(f"{p}: a Live Link Face take is written as .csv")
        n = rx.stop_recording(p)
        return f"recorded {n} frames to {p}"

    def handlers(self) -> A.Handlers:
        """The Live Link actions (npga_view/actions.py) this controller carries out, each by a typed method."""
        h = A.Handlers()
        h.register(A.LiveLinkStart, self._start)
        h.register(A.LiveLinkStop, self._stop)
        h.register(A.LiveLinkNeutral, self._neutral)
        h.register(A.LiveLinkGain, self._gain)
        h.register(A.LiveLinkRecord, self._record)
        return h

    def _start(self, a: A.LiveLinkStart) -> None:
        self.start(a.address)

    def _stop(self, a: A.LiveLinkStop) -> None:
        self.stop()

    def _neutral(self, a: A.LiveLinkNeutral) -> None:
        self.neutral()

    def _gain(self, a: A.LiveLinkGain) -> None:
        self.set_gain(a.name, a.gain)

    def _record(self, a: A.LiveLinkRecord) -> None:
        msg = self.record(a.path)
        if msg:
            self.status = msg

    def publish(self, info: AppInfo) -> None:
        """Copy what the panel and the overlay show into the frame's display snapshot."""
        info.live_link, info.live_counters = self.status, self.counters_line()
        info.live_listening = self.receiver is not None
        info.live_recording = self.receiver is not None and self.receiver.recording
        info.live_unmatched = self.unmatched
