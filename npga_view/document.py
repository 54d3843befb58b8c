"""`Document`: the open avatar and what goes with it (its pose worker, the open sequence, the posed cloud on screen
and its content version), and the events the window's parts subscribe to when it changes.

What happens when an avatar opens is decided here once: the old worker stops, a new one starts for an animatable
avatar, the cloud on screen is forgotten, then `AvatarOpened` goes to every subscriber in the order they were
included; an edit of the canonical cloud (`change_cloud`) has the running worker open the edited copy (a new worker
only where the cloud outgrew its slots) and sends `CloudChanged`; opening or closing a sequence sends
`SequenceChanged`. A part subscribes with a typed table, as its action handlers are
registered (npga_view/dispatch.py)::

    def subscriptions(self) -> Subscriptions:
        s = Subscriptions()
        s.subscribe(AvatarOpened, self._opened)      # def _opened(self, e: AvatarOpened) -> None
        return s

and the app `include`s each part's table once (`ViewerApp.__init__`: the one list of what resets on open). mypy
checks each handler against its event. Nothing here touches GL, glfw or imgui.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from npga_core.files.sequences import ExpressionSequence
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import PosedGaussians
from npga_core.posing.engine import PoseEngine


@dataclass(frozen=True)
class Event:
    """Base of the document's events."""


@dataclass(frozen=True)
class AvatarOpened(Event):
    """`avatar` is the open avatar now (its worker, if any, is started): forget what was of the last one."""

    avatar: Avatar


@dataclass(frozen=True)
class CloudChanged(Event):
    """The open avatar's canonical cloud was edited (its worker, if any, now on the edited copy). `kept`: a mask
    over the cloud before of the rows the edited cloud consists of, unchanged (a deletion; None otherwise): their
    last pose is the pose of the edited cloud, since every Gaussian's dynamics are its own."""

    avatar: Avatar
    kept: np.ndarray | None = None


@dataclass(frozen=True)
class SequenceChanged(Event):
    """A sequence was opened (`sequence`) or closed (None)."""

    sequence: ExpressionSequence | None


EventT = TypeVar("EventT", bound=Event)


class Subscriptions:
    """A table of event type -> handlers (in order), filled by typed `subscribe` calls."""

    def __init__(self) -> None:
        self.table: dict[type[Event], list[Callable[[Any], None]]] = {}

    def subscribe(self, cls: type[EventT], handler: Callable[[EventT], None]) -> None:
        """Run `handler` for every event of type `cls`, after the handlers subscribed before it."""
        self.table.setdefault(cls, []).append(handler)

    def include(self, other: Subscriptions) -> None:
        """Add another table's handlers after this one's (a part's `subscriptions()`)."""
        for cls, handlers in other.table.items():
            self.table.setdefault(cls, []).extend(handlers)

    def handlers(self, cls: type[Event]) -> tuple[Callable[[Any], None], ...]:
        return tuple(self.table.get(cls, ()))


@dataclass(frozen=True)
class EngineOptions:
    """How the pose worker runs: its threads, device ("cpu", "cuda", "mps", "auto") and number format."""

    threads: int = 2
    device: str = "cpu"
    precision: str = "auto"


class Document(Subscriptions):
    """The open avatar, its worker and sequence, the posed cloud on screen; see the module docstring."""

    def __init__(self, engine_options: EngineOptions | None = None) -> None:
        super().__init__()
        self.engine_options = engine_options or EngineOptions()
        self.avatar: Avatar | None = None
        self.engine: PoseEngine | None = None
        self.sequence: ExpressionSequence | None = None
        self.posed: PosedGaussians | None = None  # the cloud on screen, before highlighting (None until shown)
        self.code: np.ndarray | None = None  # the expression code it is of (None: canonical or static)
        self.version = 0  # bumped by every cloud shown (or coloured anew): what the drawn images are of

    def emit(self, event: Event) -> None:
        """Hand `event` to its handlers in order."""
        for handler in self.table.get(type(event), ()):
            handler(event)

    # ---------------------------------------------------------------------------------------------- changes
    def open(self, avatar: Avatar) -> None:
        """Make `avatar` the open one: the last worker stops, one starts for an animatable avatar with a file,
        the cloud on screen is forgotten; then `AvatarOpened`."""
        self.close_engine(wait=False)
        self.avatar = avatar
        self.posed = self.code = None
        if avatar.dynamics is not None and avatar.source:
            self._start_engine(avatar.source)
        self.emit(AvatarOpened(avatar))

    def change_cloud(self, worker_path: str | None, kept: np.ndarray | None = None) -> None:
        """The canonical cloud was edited: the worker opens `worker_path` (the edited copy; None for a static
        avatar) in place, or a new worker starts on it where the posed cloud outgrew the old one's slots; then
        `CloudChanged` (with `kept`: the rows of the cloud before that the edited one keeps unchanged, a deletion)."""
        a = self.avatar
        assert a is not None
        if worker_path is not None and not (
                self.engine is not None
                and self.engine.reopen(worker_path, len(a), a.cloud.sh.shape[1], a.cloud.latent_dim)):
            self._start_engine(worker_path)
        self.emit(CloudChanged(a, kept))

    def set_sequence(self, sequence: ExpressionSequence | None) -> None:
        """Open `sequence` (None: close it), then `SequenceChanged`."""
        self.sequence = sequence
        self.emit(SequenceChanged(sequence))

    def shown(self, posed: PosedGaussians, code: np.ndarray | None) -> int:
        """`posed` (of `code`) is the cloud on screen now; returns its content version."""
        self.posed, self.code = posed, code
        self.version += 1
        return self.version

    def _start_engine(self, path: str) -> None:
        self.close_engine(wait=False)
        a = self.avatar
        assert a is not None
        o = self.engine_options
        self.engine = PoseEngine(path, len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=o.threads,
                                 device=o.device, precision=o.precision)

    def close_engine(self, wait: bool = True) -> None:
        """Stop the worker (its shared memory unlinked); safe to call twice. `wait=False` (a worker replaced by
        another avatar's or an edited cloud's): it stops in the background, the frame goes on."""
        if self.engine is not None:
            self.engine.close(wait)
            self.engine = None

    # ---------------------------------------------------------------------------------------------- reads
    def shown_means(self) -> np.ndarray:
        """Centres of the Gaussians on screen (canonical ones until the first pose, or after a deletion)."""
        assert self.avatar is not None
        if self.posed is not None and len(self.posed) == len(self.avatar):
            return self.posed.means
        return np.asarray(self.avatar.cloud.means)
