"""`resolve_device`: the one place a device name ("cpu", "cuda", "cuda:N", "mps", "auto") becomes a torch device,
for the dynamics (the pose worker) and the screen-space CNN alike."""

from __future__ import annotations

import torch


def resolve_device(name: str | None) -> torch.device:
    """"cpu" (default), "cuda", "cuda:N", "mps" or "auto" (a GPU when torch sees one); ValueError (a one-line
    message naming the flag) if the name is unknown or the device is not there."""
    name = (name or "cpu").strip().lower()
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        mps = getattr(torch.backends, "mps", None)
        return torch.device("mps" if mps is not None and mps.is_available() else "cpu")
    kind, _, index = name.partition(":")
    if kind not in ("cpu", "cuda", "mps") or (index and (kind != "cuda" or not index.isdigit())):
        raise ValueError(f"--device {name}: expected cpu, cuda, cuda:N, mps or auto")
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"--device {name}: CUDA is not available (torch sees no CUDA GPU)")
        if index and int(index) >= torch.cuda.device_count():
            raise ValueError(f"--device {name}: torch sees {torch.cuda.device_count()} CUDA GPU(s)")
    if kind == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        raise ValueError("--device mps: MPS is not available (torch sees no MPS device)")
    return torch.device(name)
