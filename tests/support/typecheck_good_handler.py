"""A mypy fixture, never imported: the handlers of tests/support/typecheck_bad_handler.py written right, which
`make typecheck` accepts (tests/repo/test_typed_handlers.py)."""

from __future__ import annotations

from npga_view import actions as A


class Controller:
    def __init__(self) -> None:
        self.roll = 0.0

    def handlers(self) -> A.Handlers:
        h = A.Handlers()
        h.register(A.RollBy, self._roll)
        h.register(A.ZoomBy, self._zoom)
        h.register(A.OrbitBy, lambda a: print(a.yaw))
        return h

    def _roll(self, a: A.RollBy) -> None:
        self.roll += a.degrees

    def _zoom(self, a: A.ZoomBy) -> None:
        self.roll += a.steps
