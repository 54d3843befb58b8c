"""GUI flags that are checked before a window opens: one-line errors and exit code 2."""

from __future__ import annotations

import pytest
import torch

from npga_view.cli.main import main


@pytest.mark.parametrize("device, message", [
    ("tpu", "--device tpu: expected cpu, cuda, cuda:N, mps or auto"),
    ("cpu:1", "--device cpu:1: expected"),
])
def test_unknown_device_exits_2(device, message, capsys):
    assert main(["demo", "--device", device]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_missing_gpu_exits_2(capsys):
    assert main(["demo", "--device", "cuda"]) == 2
    assert "torch sees no CUDA GPU" in capsys.readouterr().err


def test_bad_bake_budget_exits_2(capsys):
    assert main(["demo", "--bake-budget-mb", "0"]) == 2
    assert "--bake-budget-mb must be positive" in capsys.readouterr().err
