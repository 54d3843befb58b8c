"""A mypy fixture, never imported: handlers that `make typecheck` must refuse (tests/repo/test_typed_handlers.py).
Each line marked `# error:` is one mypy error, found because handlers are registered by type."""

from __future__ import annotations

from npga_view import actions as A


class Controller:
    def __init__(self) -> None:
        self.roll = 0.0

    def handlers(self) -> A.Handlers:
        h = A.Handlers()
        h.register(A.RollBy, self._roll)
        h.register(A.ZoomBy, self._roll)  # error: a handler registered for another action
        h.register(A.OrbitBy, lambda a: print(a.yawn))  # error: a lambda's action is typed too
        return h

    def _roll(self, a: A.RollBy) -> None:
        self.roll += a.degres  # error: a misspelled field
