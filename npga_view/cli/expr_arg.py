"""`--expr` given as words instead of a `.npy` file: a named expression of the avatar ("jaw open") or named
blendshape weights ("jawOpen=0.8,eyeBlinkLeft=1") through the avatar's basis (a rig's own channels for LAM)."""

from __future__ import annotations

import math
import os

import numpy as np

from npga_core.errors import shown
from npga_core.files.blendshape_names import match_names


class ExprError(ValueError):
    """An --expr text that names no expression or weights the avatar knows (one line)."""


def expr_code(text: object, avatar, frame: int | None, error: type[Exception]) -> np.ndarray | None:
    """`named_code` for a command's --expr (None: a file path), its problems raised as `error` (one line);
    a named expression is one code, so --frame cannot choose among its rows."""
    try:
        named = named_code(str(text), avatar)
    except ExprError as e:
        raise error(str(e)) from None
    if named is not None and frame is not None:
        raise error("--frame needs --sequence or an --expr file of several codes")
    return named


def load_with_notes(avatar, source, fps: float | None = None):
    """The sequence `source` for `avatar` (`load_sequence_for`), its reader's notes printed once each."""
    import sys

    from npga_core.files.loading import load_sequence_for

    seq = load_sequence_for(avatar, source, fps)
    for note in seq.notes:
        print(f"npga-view: note: {note}", file=sys.stderr)
    return seq


def named_code(text: str, avatar) -> np.ndarray | None:
    """The code `text` names, or None when `text` is a file path (an existing file or one ending in .npy)."""
    if os.path.exists(text) or text.lower().endswith((".npy", ".npz", ".npzseq")):
        return None
    ex = avatar.expression
    if ex is not None and text in ex.named:
        return np.asarray(ex.named[text], np.float32)
    if "=" not in text:
        known = ", ".join(shown(n) for n in (ex.named if ex is not None else {}))
        raise ExprError(f"--expr {shown(text)}: no such file, nor a named expression of the avatar"
                        + (f" ({known})" if known else "") + ", nor NAME=WEIGHT,... blendshape weights")
    basis = avatar.blendshapes
    if basis is None:
        raise ExprError(f"--expr {shown(text)}: the avatar has no blendshape basis to take named weights")
    names, values = [], []
    for part in text.split(","):
        name, _, value = part.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not name.strip() or not math.isfinite(v) or abs(v) > 100:
            raise ExprError(f"--expr {shown(text)}: {shown(part)!r} is not NAME=WEIGHT (a finite weight)")
        names.append(name.strip())
        values.append(v)
    try:
        match = match_names(names, basis.names)
    except ValueError as e:
        raise ExprError(f"--expr {shown(text)}: {e}") from None
    if match.missing:
        raise ExprError(f"--expr {shown(text)}: the avatar has no shape "
                        f"{', '.join(shown(n) for n in match.missing)}")
    return basis.codes(match.matrix @ np.asarray(values, np.float64))
