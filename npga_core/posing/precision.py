"""Which number format the exact dynamics run in: float32 everywhere, bfloat16 where the CPU multiplies it natively.

CPUs with AMX (amx_bf16) or AVX-512 BF16 multiply bfloat16 matrices several times faster than float32 through
oneDNN (measured on this project's Xeon: 3.5x for a plain 80k x 256 x 256 product, 7-10x for one lane's packed
linear); elsewhere bfloat16 is emulated and far slower. `"auto"` takes bfloat16 only where it is native AND the
avatar's networks pass a fidelity check against float32 (`FastPoser` runs it on a sample of rows; the images
are then checked by tests/core/test_precision.py and the bench).
"""

from __future__ import annotations

import functools
import platform
from pathlib import Path

PRECISIONS = ("auto", "fp32", "bf16")
#: The `--precision` option's help (viewer, render, export, bench).
PRECISION_HELP = ("number format of the exact dynamics: fp32, bf16 (bfloat16, on CPUs with AMX or AVX-512 BF16) "
                  "or auto (bf16 where native and close to fp32, else fp32); default %(default)s")

#: The CPU flags (Linux /proc/cpuinfo names) that make bfloat16 matrix products native.
BF16_FLAGS = ("amx_bf16", "avx512_bf16")
#: The flags reported by `cpu_flags` (what the bench and PERFORMANCE.md record).
REPORTED_FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_vnni", "amx_tile", "amx_bf16", "amx_int8")


@functools.cache
def cpu_flags() -> tuple[str, ...]:
    """The reported flags this CPU has: from /proc/cpuinfo on Linux, else from torch's own CPU checks."""
    found: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
            if line.startswith("flags"):
                found.update(line.partition(":")[2].split())
                break
    except OSError:
        pass
    if not found:  # macOS, Windows: torch's cpuinfo-based checks
        import torch

        cpu = getattr(torch, "cpu", None)
        checks = {"avx2": "_is_avx2_supported", "avx512f": "_is_avx512_supported",
                  "avx512_bf16": "_is_avx512_bf16_supported", "avx512_vnni": "_is_vnni_supported",
                  "amx_tile": "_is_amx_tile_supported"}
        for flag, name in checks.items():
            fn = getattr(cpu, name, None)
            try:
                if fn is not None and fn():
                    found.add(flag)
            except RuntimeError:
                pass
        if "amx_tile" in found:
            found.update(("amx_bf16", "amx_int8"))
    return tuple(f for f in REPORTED_FLAGS if f in found)


def bf16_native() -> bool:
    """True when this machine multiplies bfloat16 natively (AMX or AVX-512 BF16 on an x86-64 CPU)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    return any(f in cpu_flags() for f in BF16_FLAGS)


def check_precision(name: str | None) -> str:
    """The precision name, lower-cased ("auto" for None); ValueError naming the flag when unknown."""
    value = (name or "auto").strip().lower()
    if value not in PRECISIONS:
        raise ValueError(f"--precision {name}: expected fp32, bf16 or auto")
    return value


def describe() -> str:
    """One line for `info` and the overlay: the flags and what "auto" would take."""
    flags = ", ".join(cpu_flags()) or "none of " + ", ".join(REPORTED_FLAGS)
    native = "bf16 native" if bf16_native() else "no native bf16: fp32"
    return f"CPU {platform.machine()} ({flags}); {native}"
