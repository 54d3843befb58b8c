"""CONTRIBUTING.md's worked example (a panel with one action) runs against the code as it is: its blocks marked
`python example` are executed in order and the test they define is run."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_worked_example_runs():
    text = (ROOT / "CONTRIBUTING.md").read_text()
    blocks = re.findall(r"```python example\n(.*?)```", text, re.S)
    assert len(blocks) == 3
    module = types.ModuleType("contributing_example")  # (dataclasses look their module up)
    sys.modules[module.__name__] = module
    ns = module.__dict__
    try:
        for block in blocks:
            exec(compile(block, "CONTRIBUTING.md", "exec"), ns)
    finally:
        del sys.modules[module.__name__]
    tests = [v for k, v in ns.items() if k.startswith("test_")]
    assert len(tests) == 1
    tests[0]()
    # the names the prose points at exist
    from npga_view.controllers.actions import ActionController
    from npga_view.panels import Panels

    assert "side" in dir(Panels) and hasattr(ActionController, "handlers")
    assert "h.register(A.RollBy, self._roll)" in (ROOT / "npga_view" / "controllers" / "actions.py").read_text()
