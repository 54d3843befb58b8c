"""Typed access to a moderngl program's uniforms.

moderngl types `program[name]` as a union of member kinds (uniform, uniform block, attribute, varying, ...), so
setting `.value` or calling `.write` on it needed an ignore of mypy's union-attr check at every use; `uniform` checks
the kind once and returns a `moderngl.Uniform`.
"""

from __future__ import annotations

import moderngl
import numpy as np


def uniform(program: moderngl.Program | moderngl.ComputeShader, name: str) -> moderngl.Uniform:
    """The uniform `name` of `program` (KeyError when the program has no such member, as `program[name]`;
    TypeError when the member is not a uniform)."""
    member = program[name]
    if not isinstance(member, moderngl.Uniform):
        raise TypeError(f"{name} is a {type(member).__name__} of the program, not a uniform")
    return member


def mat4_bytes(m: np.ndarray) -> bytes:
    """Column-major float32 bytes of a row-major 4x4 matrix, as GLSL mat4 uniforms expect."""
    return np.ascontiguousarray(np.asarray(m, dtype=np.float32).T).tobytes()
