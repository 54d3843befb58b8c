"""A `BlendshapeBasis` on its own as an `.npz` (what `npga-view fit-blendshapes` writes): ``names`` (B,)
unicode, ``matrix`` (D, B) float32, ``offset`` (D,) float32, ``source`` () unicode; read with pickles refused."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.untrusted import read_npz, real_floats
from npga_core.model.avatar import Avatar
from npga_core.model.blendshapes import BlendshapeBasis

MAX_BASIS_BYTES = 64 * 2**20


def save_basis(basis: BlendshapeBasis, path: str | Path) -> None:
    """Write the basis atomically."""
    buf = io.BytesIO()
    np.savez(buf, names=np.array(basis.names, dtype=np.str_), matrix=basis.matrix.astype(np.float32),
             offset=basis.offset.astype(np.float32), source=np.str_(basis.source))
    atomic_write(Path(path), lambda fh: fh.write(buf.getvalue()))


def attach_basis(avatar: Avatar, path: str | Path) -> BlendshapeBasis:
    """Read the basis at `path` and give it to `avatar` (replacing its own); AvatarFileError in one line when it
    does not fit the avatar's expression code."""
    from npga_core.files.blendshapes_field import fits

    basis = read_basis(path)
    try:
        fits(basis.code_dim, avatar.code_dim, avatar.condition_dim)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    avatar.blendshapes = basis
    return basis


def read_basis(path: str | Path) -> BlendshapeBasis:
    """Read a basis `.npz`; AvatarFileError naming the file on anything wrong."""
    path = Path(path)
    z = read_npz(path, MAX_BASIS_BYTES, keys=("names", "matrix", "offset", "source"),
                 kinds={"names": "U", "source": "U"})
    missing = [k for k in ("names", "matrix", "offset") if k not in z]
    if missing:
        raise AvatarFileError(path, f"is no blendshape basis (no {', '.join(missing)})")
    source = str(z["source"].reshape(-1)[0]) if "source" in z and z["source"].size == 1 else ""
    try:
        return BlendshapeBasis(tuple(str(n) for n in z["names"].reshape(-1)),
                               real_floats(z["matrix"], path, "basis matrix"),
                               real_floats(z["offset"], path, "basis offset"), source)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None


#: How the demo's map is described in its basis (`npga_core.demo.basis` derives the same from the build's seed).
DEMO_SOURCE = "demo: z = M w + b of npga_core.demo.expression_map (exact)"


def read_expression_map(path: str | Path) -> BlendshapeBasis:
    """The basis of a demo build's ``expression_map.npz`` (arrays ``M`` (D, B), ``b`` (D,), ``names`` (B,))."""
    path = Path(path)
    z = read_npz(path, MAX_BASIS_BYTES, keys=("M", "b", "names"), kinds={"names": "U"})
    if not {"M", "b", "names"} <= set(z):
        raise AvatarFileError(path, "is no expression map (needs arrays M, b and names)")
    try:
        return BlendshapeBasis(tuple(str(n) for n in z["names"].reshape(-1)), real_floats(z["M"], path, "M"),
                               real_floats(z["b"], path, "b"), DEMO_SOURCE)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None


def bundled_demo_basis() -> BlendshapeBasis:
    """The bundled demo's basis (its ``expression_map.npz``)."""
    from npga_core.files.places import bundled_path

    return read_expression_map(bundled_path("demo", "expression_map.npz"))
