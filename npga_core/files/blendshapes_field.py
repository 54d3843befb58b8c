"""The optional `blendshapes` field of an `.npga` (format version 3, docs/FORMAT.md section 16).

Header key ``"blendshapes": {"names": [B names], "source": str, "dim": D}`` and tensors ``blendshapes.matrix``
(D, B) and ``blendshapes.offset`` (D,), both float32: an avatar's `BlendshapeBasis`, ``code = offset + matrix @
weights``. D is the width of the expression code the dynamics take (without a condition part). The reader checks
the header entry before anything is allocated, then the values (finite, within +-MAX_PARAMETER, like network
weights) and that D fits the avatar's code. Kept apart from `checkpoint.py`, which calls these four functions.
"""

from __future__ import annotations

from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.model.blendshapes import HEADER_KEY, MATRIX_KEY, OFFSET_KEY, BlendshapeBasis
from npga_core.schema import decode

#: The oldest format version that holds a blendshape basis.
BLENDSHAPES_VERSION = 3
MAX_SHAPES = 1024
MAX_NAME = 128
MAX_SOURCE = 4096
MAX_DIM = 65536


class Section(msgspec.Struct):
    """The header's ``blendshapes`` entry, declared."""

    names: Annotated[list[Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]],
                     Meta(min_length=1, max_length=MAX_SHAPES)]
    dim: Annotated[int, Meta(ge=1, le=MAX_DIM)]
    source: Annotated[str, Meta(max_length=MAX_SOURCE)] = ""


def check_section(entry: Any) -> None:
    """ValueError (naming the field) unless `entry` (the header's ``blendshapes``, not null) is well formed."""
    names = decode(entry, Section, "blendshapes").names
    if len(set(names)) != len(names):
        raise ValueError("blendshapes.names has duplicate names")


def tensors(entry: dict) -> dict[str, tuple[str, tuple[int, ...]]]:
    """The tensors a checked ``blendshapes`` entry implies (name -> (dtype, shape))."""
    d, b = entry["dim"], len(entry["names"])
    return {MATRIX_KEY: ("float32", (d, b)), OFFSET_KEY: ("float32", (d,))}


def section(basis: BlendshapeBasis, code_dim: int, condition_dim: int) -> tuple[dict, dict[str, np.ndarray]]:
    """The header entry and the arrays of `basis` (ValueError if it does not fit the avatar's code)."""
    fits(basis.code_dim, code_dim, condition_dim)
    return {**basis.header(), "dim": basis.code_dim}, basis.to_arrays()


def build(entry: dict, t: dict[str, np.ndarray], code_dim: int, condition_dim: int,
          limit: float) -> BlendshapeBasis:
    """The basis of a checked entry from its tensors; ValueError if a value is out of bounds or D does not fit
    the avatar's expression code (`code_dim` minus `condition_dim`; the whole frame vector is also accepted)."""
    for key in (MATRIX_KEY, OFFSET_KEY):
        a = t[key]
        if a.size and not np.isfinite(a).all():
            raise ValueError(f"{key} has NaN/Inf values")
        if a.size and np.abs(a).max() > limit:
            raise ValueError(f"{key} has values beyond +-{limit:.0e}")
    fits(entry["dim"], code_dim, condition_dim)
    return BlendshapeBasis.from_arrays(entry, t)


def fits(d: int, code_dim: int, condition_dim: int) -> None:
    """ValueError unless D-dimensional basis codes fit an avatar's frame vector."""
    if code_dim == 0:
        raise ValueError("blendshapes need an avatar with dynamics (this one is static)")
    if d not in (code_dim - condition_dim, code_dim):
        raise ValueError(f"blendshapes map to {d}-D codes, the avatar's expression code has "
                         f"{code_dim - condition_dim} dims")


def header_entry(header: dict) -> Any:
    """The header's ``blendshapes`` entry; None when absent, null or empty, or in a file older than version 3
    (where the key has no meaning and is ignored like any unknown key)."""
    if header.get("format_version", 1) < BLENDSHAPES_VERSION:  # (an integer: checked before)
        return None
    entry = header.get(HEADER_KEY)
    return entry if entry not in (None, {}) else None
