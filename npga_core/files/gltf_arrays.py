"""Arrays and node transforms of a glTF 2.0 binary (`.glb`) held in memory, read through pygltflib, every range
checked.

pygltflib parses the container and the JSON; this module turns accessors into numpy arrays (dense views and
sparse accessors, as the glTF 2.0 specification section 3.6 defines them: a sparse accessor without a buffer
view starts from zeros and has `count` values replaced at ascending `indices`) and nodes into world matrices
(T * R * S or `matrix`, parents first). Any offset, length, stride, count or index outside the binary chunk, a
cycle in the node tree or a non-finite value is a `GltfError` with one line.
"""

from __future__ import annotations

import math
import warnings
from typing import Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core.schema import SchemaError, decode

#: Most elements one accessor may claim (a LAM skin has 20k-160k vertices; 51 targets of them).
MAX_COUNT = 50_000_000
_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class GltfError(Exception):
    """A problem with a glTF file, one line."""


def parse_glb(data: bytes) -> Any:
    """The `pygltflib.GLTF2` of a binary glTF, or GltfError when pygltflib cannot read it."""
    import pygltflib

    if data[:4] != b"glTF":
        raise GltfError("not a binary glTF (no 'glTF' signature)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # unknown chunk types, versions: reported below by what is missing
            gltf = pygltflib.GLTF2.load_from_bytes(data)
    except RecursionError:
        raise GltfError("its JSON is nested too deeply") from None
    except Exception as e:  # noqa: BLE001 - pygltflib/dataclasses-json raise many types on malformed JSON
        raise GltfError(f"not a readable glTF binary ({type(e).__name__}: {str(e)[:120]})") from None
    if gltf is None:
        raise GltfError("not a readable glTF binary (no JSON chunk)")
    return gltf


# The part of glTF 2.0's JSON this module and the LAM reader use, declared (msgspec, read from pygltflib's objects;
# what else a file holds is ignored). Indices are bounded here and checked against their lists where used.
_Index = Annotated[int, Meta(ge=0, le=2**31 - 1)]
_Size = Annotated[int, Meta(ge=0, le=2**40)]
_F = Annotated[float, Meta(ge=-1e12, le=1e12)]


class BufferView(msgspec.Struct):
    byteLength: _Size
    buffer: _Index | None = None
    byteOffset: _Size | None = None
    byteStride: Annotated[int, Meta(ge=0, le=252)] | None = None


class SparseIndices(msgspec.Struct):
    bufferView: _Index
    componentType: int
    byteOffset: _Size | None = None


class SparseValues(msgspec.Struct):
    bufferView: _Index
    byteOffset: _Size | None = None


class Sparse(msgspec.Struct):
    count: _Size
    indices: SparseIndices | None = None
    values: SparseValues | None = None


class Accessor(msgspec.Struct):
    componentType: int
    count: Annotated[int, Meta(ge=0, le=MAX_COUNT)]
    type: Annotated[str, Meta(max_length=16)]
    bufferView: _Index | None = None
    byteOffset: _Size | None = None
    sparse: Sparse | None = None


class Node(msgspec.Struct):
    name: Annotated[str, Meta(max_length=4096)] | None = None
    mesh: _Index | None = None
    skin: _Index | None = None
    children: list[_Index] | None = None
    matrix: tuple[_F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F, _F] | None = None
    translation: tuple[_F, _F, _F] | None = None
    rotation: tuple[_F, _F, _F, _F] | None = None
    scale: tuple[_F, _F, _F] | None = None


class Attributes(msgspec.Struct):
    POSITION: _Index | None = None


class Target(msgspec.Struct):
    POSITION: _Index


class Primitive(msgspec.Struct):
    attributes: Attributes | None = None
    targets: list[Target] | None = None


class MeshExtras(msgspec.Struct):
    targetNames: list[Annotated[str, Meta(min_length=1, max_length=128)]] | None = None


class Mesh(msgspec.Struct):
    primitives: list[Primitive] | None = None
    extras: MeshExtras | None = None


class Skin(msgspec.Struct):
    joints: list[_Index] | None = None
    inverseBindMatrices: _Index | None = None


class Document(msgspec.Struct):
    """What of a glTF's JSON is read."""

    nodes: list[Node] | None = None
    meshes: list[Mesh] | None = None
    skins: list[Skin] | None = None
    accessors: list[Accessor] | None = None
    bufferViews: list[BufferView] | None = None


def index_in(i: int, items: list, what: str) -> int:
    """`i` if it indexes `items`, else GltfError naming `what`."""
    if not i < len(items):
        raise GltfError(f"{what} names {i}, the file has {len(items)}")
    return i


class GltfArrays:
    """Accessor arrays and node matrices of one parsed glTF binary (its JSON decoded as `Document`)."""

    def __init__(self, gltf: Any):
        self.gltf = gltf
        try:
            self.doc: Document = decode(gltf, Document)
        except SchemaError as e:
            raise GltfError(str(e)) from None
        blob = gltf.binary_blob()
        self.blob = b"" if blob is None else bytes(blob)
        self.nodes = self.doc.nodes or []

    def _view(self, index: int, what: str) -> tuple[int, int, int | None]:
        views = self.doc.bufferViews or []
        i = index_in(index, views, f"{what}'s bufferView")
        v = views[i]
        if v.buffer not in (None, 0):
            raise GltfError(f"bufferView {i} is not in the binary chunk")
        off, length = v.byteOffset or 0, v.byteLength
        if off + length > len(self.blob):
            raise GltfError(f"bufferView {i} ends at byte {off + length:,}, the binary chunk has "
                            f"{len(self.blob):,}")
        if v.byteStride and v.byteStride < 4:
            raise GltfError(f"bufferView {i}'s byteStride is {v.byteStride}, not 4..252")
        return off, length, v.byteStride or None

    def _dense(self, view: int, offset: int | None, count: int, dtype: np.dtype, width: int,
               what: str) -> np.ndarray:
        start, length, stride = self._view(view, what)
        off = offset or 0
        item = dtype.itemsize * width
        step = stride or item
        if count and off + (count - 1) * step + item > length:
            raise GltfError(f"{what} reads {count:,} elements past the end of its buffer view")
        if not count:
            return np.zeros((0, width), dtype)
        raw = np.frombuffer(self.blob, np.uint8, (count - 1) * step + item, start + off)
        rows = np.lib.stride_tricks.as_strided(raw, (count, item), (step, 1))
        return np.ascontiguousarray(rows).view(dtype.newbyteorder("<")).reshape(count, width)

    def accessor(self, index: int, what: str, types: tuple[str, ...], max_count: int = MAX_COUNT) -> np.ndarray:
        """Accessor `index` as a (count, width) array of its component type (sparse ones filled in)."""
        accessors = self.doc.accessors or []
        i = index_in(index, accessors, f"{what}'s accessor")
        a = accessors[i]
        name = f"{what} (accessor {i})"
        if a.type not in types:
            raise GltfError(f"{name} has type {a.type!r}, expected {' or '.join(types)}")
        if a.componentType not in _COMPONENTS:
            raise GltfError(f"{name} has an unknown componentType {a.componentType!r}")
        dtype, width = np.dtype(_COMPONENTS[a.componentType]), _WIDTH[a.type]
        count = a.count
        if count > max_count:
            raise GltfError(f"{name}'s count is {count:,}, more than the {max_count:,} it may have")
        if a.bufferView is None:
            out = np.zeros((count, width), dtype)
        else:
            out = self._dense(a.bufferView, a.byteOffset, count, dtype, width, name).copy()
        if a.sparse is not None:
            sp = a.sparse
            n = sp.count if count else 0
            if count and not 1 <= n <= count:
                raise GltfError(f"{name}'s sparse count is {n:,}, not 1..{count:,}")
            if sp.indices is None or sp.values is None:
                raise GltfError(f"{name}'s sparse part lacks indices or values")
            if sp.indices.componentType not in (5121, 5123, 5125):
                raise GltfError(f"{name}'s sparse indices have componentType {sp.indices.componentType!r}")
            idx = self._dense(sp.indices.bufferView, sp.indices.byteOffset, n,
                              np.dtype(_COMPONENTS[sp.indices.componentType]), 1, f"{name}'s sparse indices")
            idx = idx.reshape(-1).astype(np.int64)
            if n and (idx.max() >= count or np.any(np.diff(idx) <= 0)):
                raise GltfError(f"{name}'s sparse indices are not ascending within 0..{count - 1}")
            vals = self._dense(sp.values.bufferView, sp.values.byteOffset, n, dtype, width, f"{name}'s sparse values")
            out[idx] = vals
        if out.dtype.kind == "f" and out.size and not np.isfinite(out).all():
            raise GltfError(f"{name} has {int(out.size - np.isfinite(out).sum())} NaN/Inf values")
        return out

    def sparse_target(self, index: int, what: str, count: int) -> tuple[np.ndarray, np.ndarray]:
        """A VEC3 float morph target as (rows, values): the rows it moves (ascending) and their deltas."""
        d = self.accessor(index, what, ("VEC3",), count)
        if d.shape[0] != count or d.dtype != np.float32:
            raise GltfError(f"{what} has {d.shape[0]:,} {d.dtype} values, the mesh has {count:,} float vertices")
        rows = np.flatnonzero(np.any(d != 0.0, axis=1))
        return rows, d[rows]

    # -- nodes ------------------------------------------------------------------------------------------------
    def local_matrix(self, i: int) -> np.ndarray:
        """Node i's local transform (4x4, float64): its `matrix` (column-major) or T * R * S."""
        n = self.nodes[i]
        if n.matrix is not None:
            return np.asarray(n.matrix, np.float64).reshape(4, 4).T
        t = n.translation if n.translation is not None else (0.0, 0.0, 0.0)
        q = n.rotation if n.rotation is not None else (0.0, 0.0, 0.0, 1.0)
        s = n.scale if n.scale is not None else (1.0, 1.0, 1.0)
        x, y, z, w = q
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        if not norm > 1e-12:
            raise GltfError(f"node {i}'s rotation is a zero quaternion")
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r * np.asarray(s)[None, :]
        m[:3, 3] = t
        return m

    def parents(self) -> dict[int, int]:
        """child -> parent over the node tree; GltfError for a bad index, two parents or a cycle."""
        parent: dict[int, int] = {}
        for i, n in enumerate(self.nodes):
            for c in n.children or []:
                index_in(c, self.nodes, f"node {i}'s child")
                if c in parent or c == i:
                    raise GltfError(f"node {c} has two parents or is its own child")
                parent[c] = i
        for i in range(len(self.nodes)):
            seen, j = set(), i
            while j in parent:
                if j in seen:
                    raise GltfError(f"the node tree has a cycle through node {j}")
                seen.add(j)
                j = parent[j]
        return parent

    def world_matrix(self, i: int, parent: dict[int, int]) -> np.ndarray:
        """Node i's world transform: its ancestors' local matrices times its own."""
        m = self.local_matrix(i)
        while i in parent:
            i = parent[i]
            m = self.local_matrix(i) @ m
        return m
