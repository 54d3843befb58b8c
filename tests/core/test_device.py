"""One `resolve_device` for the dynamics and the CNN: "auto" picks CUDA, then MPS, else the CPU; a device that
is not there is a one-line error naming the flag."""

from __future__ import annotations

import pytest
import torch

from npga_core.posing.device import resolve_device


def test_auto_picks_cuda_then_mps_then_cpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("mps")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device(None) == resolve_device("CPU ") == torch.device("cpu")


def test_unknown_or_missing_devices_are_refused(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    with pytest.raises(ValueError, match="--device tpu: expected cpu, cuda, cuda:N, mps or auto"):
        resolve_device("tpu")
    with pytest.raises(ValueError, match="--device cuda: CUDA is not available"):
        resolve_device("cuda")
    with pytest.raises(ValueError, match="--device mps: MPS is not available"):
        resolve_device("mps")


def test_the_window_cnn_follows_the_device_flag(monkeypatch):
    """The app hands `resolve_device(--device)` to the CNN (before: anything but cuda ran it on the CPU)."""
    import ast
    from pathlib import Path

    src = (Path(__file__).resolve().parents[2] / "npga_view" / "app.py").read_text()
    calls = [n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Refiner"]
    assert calls and all(ast.unparse(c.args[1]) == "resolve_device(device)" for c in calls)
