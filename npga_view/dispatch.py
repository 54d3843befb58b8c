"""The machinery that runs actions: the `Action` base, the field check, typed handler tables and the
`Dispatcher` (the action types themselves are in npga_view/actions.py, which re-exports these names).

A controller fills a `Handlers` table with typed registrations, as viser registers its message handlers::

    handlers.register(OrbitBy, self._orbit)      # def _orbit(self, a: OrbitBy) -> None

`register(cls: type[T], handler: Callable[[T], None])` lets mypy check the handler against the action it
runs, so a handler reading a misspelled field, or registered for the wrong action type, fails `make typecheck`
(tests/repo/test_typed_handlers.py). The app `include`s each controller's table in its `Dispatcher`.

An action type nobody handles, a queued object that is not an action, or a field of the wrong type is an
`ActionError`: raised in tests (``NPGA_VIEW_STRICT_ACTIONS=1``, set by tests/conftest.py), logged and shown in
the window otherwise; never a silent no-op. Nothing here touches GL, glfw or imgui.
"""

from __future__ import annotations

import dataclasses
import logging
import numbers
import os
import types
import typing
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

log = logging.getLogger("npga_view.actions")
STRICT_ENV = "NPGA_VIEW_STRICT_ACTIONS"


class ActionError(Exception):
    """An action nobody handles, or one whose fields have the wrong types (a programming error)."""


@dataclass(frozen=True)
class Action:
    """Base of every action; subclasses are frozen dataclasses whose fields are checked by `check_fields`."""


ActionT = TypeVar("ActionT", bound=Action)


def _matches(value: object, tp: Any) -> bool:
    """Whether `value` fits the annotation `tp` (the few kinds actions use)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is typing.Any or tp is object:
        return True
    if tp is type(None):
        return value is None
    if origin in (typing.Union, types.UnionType):
        return any(_matches(value, a) for a in args)
    if origin is Literal:
        return value in args
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if tp is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if tp is str:
        return isinstance(value, str)
    if origin is tuple:
        if not isinstance(value, tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_matches(v, args[0]) for v in value)
        return len(value) == len(args) and all(_matches(v, a) for v, a in zip(value, args, strict=True))
    if origin in (Mapping, dict) or tp in (Mapping, dict):
        return isinstance(value, Mapping)
    raise TypeError(f"actions cannot check fields of type {tp!r}")


_HINTS: dict[type, dict[str, Any]] = {}


def check_fields(action: object) -> None:
    """ActionError unless `action` is an `Action` whose every field has its annotated type."""
    if not isinstance(action, Action):
        raise ActionError(f"not an action: {action!r:.80}")
    cls = type(action)
    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls)
    for f in dataclasses.fields(action):
        value = getattr(action, f.name)
        if not _matches(value, hints[f.name]):
            raise ActionError(f"{cls.__name__}.{f.name}: expected {hints[f.name]}, got {value!r:.80}")


class Handlers:
    """A table of action type -> handler, filled by typed `register` calls (see the module docstring)."""

    def __init__(self) -> None:
        self.table: dict[type[Action], Callable[[Any], None]] = {}

    def register(self, cls: type[ActionT], handler: Callable[[ActionT], None]) -> None:
        """Run `handler` for every action of type `cls`; an action type handled twice is an ActionError."""
        if cls in self.table:
            raise ActionError(f"actions handled twice: {cls.__name__}")
        self.table[cls] = handler

    def include(self, other: Handlers) -> None:
        """Add another table (a controller's `handlers()`); an action type handled twice is an ActionError."""
        twice = sorted(t.__name__ for t in other.table if t in self.table)
        if twice:
            raise ActionError(f"actions handled twice: {', '.join(twice)}")
        self.table.update(other.table)

    def __iter__(self) -> Iterator[type[Action]]:
        return iter(self.table)

    def __len__(self) -> int:
        return len(self.table)


class Dispatcher(Handlers):
    """Runs each action by the handler registered for its type; see the module docstring."""

    def __init__(self, strict: bool | None = None) -> None:
        super().__init__()
        self.strict = os.environ.get(STRICT_ENV) == "1" if strict is None else strict

    def dispatch(self, action: object) -> None:
        """Check `action` and run its handler; ActionError for an unknown type or bad fields. Errors of the
        handler (a bad file, a refused edit) propagate for the caller to report."""
        check_fields(action)
        assert isinstance(action, Action)  # (check_fields said so)
        handler = self.table.get(type(action))
        if handler is None:
            raise ActionError(f"no handler for the action {type(action).__name__}")
        handler(action)

    def run_all(self, actions: Sequence[object], report: Callable[[str], None],
                expected: tuple[type[BaseException], ...] = ()) -> None:
        """Dispatch each action; `expected` errors (bad files, refused edits) and, unless strict, ActionErrors go
        to `report` (the window's error list); a strict dispatcher raises ActionError."""
        for action in actions:
            try:
                self.dispatch(action)
            except ActionError as e:
                if self.strict:
                    raise
                log.error("%s", e)
                report(f"internal error: {e}")
            except expected as e:
                report(str(e))
