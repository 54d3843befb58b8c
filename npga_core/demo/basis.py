"""The demo avatar's `BlendshapeBasis`: exactly the map its codes are built with (`expression_map.py`).

The demo is built with ``z = M w + b`` over the ICT-FaceKit's 53 shapes (`ExpressionMap.from_seed(seed,
names)`), so its basis is that map. It is derived here from the build's seed and the shape names in the
avatar's provenance (no ICT data needed), or read from the bundled ``expression_map.npz`` the build writes.
"""

from __future__ import annotations

from pathlib import Path

from npga_core.demo.expression_map import ExpressionMap
from npga_core.errors import AvatarFileError
from npga_core.files.basis_file import DEMO_SOURCE, bundled_demo_basis
from npga_core.model.blendshapes import BlendshapeBasis

SOURCE = DEMO_SOURCE


def basis_of_map(emap: ExpressionMap) -> BlendshapeBasis:
    """The basis of an expression map (the same matrix and offset)."""
    return BlendshapeBasis(tuple(emap.names), emap.matrix, emap.offset, SOURCE)


def basis_from_provenance(provenance: dict, where: str | Path = "demo") -> BlendshapeBasis:
    """The demo's basis from a built avatar's provenance (its ``seed`` and ``expression_map.names``)."""
    info = provenance.get("expression_map") if isinstance(provenance, dict) else None
    seed = provenance.get("seed") if isinstance(provenance, dict) else None
    names = info.get("names") if isinstance(info, dict) else None
    if not isinstance(seed, int) or not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise AvatarFileError(where, "has no demo expression map in its provenance (seed and names)")
    return basis_of_map(ExpressionMap.from_seed(seed, names))


def bundled_basis() -> BlendshapeBasis:
    """The bundled demo's basis, read from its ``expression_map.npz`` (pickles refused)."""
    return bundled_demo_basis()
