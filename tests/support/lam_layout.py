"""Write LAM avatar zips (aigc3d/LAM) in the layout of the real ones, for tests: one folder holding `offset.ply`
(3DGS vertex layout; x, y, z offsets from mesh vertex i; f_dc plain RGB), `skin.glb` (written with pygltflib: a
skinned triangle mesh with one vertex per Gaussian, ARKit morph targets as sparse accessors named by
`mesh.extras.targetNames` in a shuffled order, a skeleton under a root node rotated +90 degrees about x and
scaled by 0.01 with `hip` and `head` bones), `animation.glb`, `vertex_order.json` and `__MACOSX/` junk.

Hostile variants: `tamper_arrays` changes the arrays before they are packed, `tamper_gltf` the pygltflib
document before it is saved, `tamper_ply` the PLY columns; `glb_container` packs any JSON text and binary chunk.
"""

from __future__ import annotations

import json
import math
import struct
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib

#: The 52 ARKit blendshape names without tongueOut: the 51 shapes a LAM skin has.
ARKIT_51: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose", "mouthFunnel",
    "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft",
    "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft", "mouthPressRight",
    "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight", "browDownLeft",
    "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff", "cheekSquintLeft",
    "cheekSquintRight", "noseSneerLeft", "noseSneerRight",
)
PLY_PROPERTIES = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                  "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
HALF_TURN_X = [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]  # (x, y, z, w): +90 degrees about x
FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125

#: The skeleton: name -> (parent, translation in cm, rotation (x, y, z, w)); the root is added above `hip`.
BONES: dict[str, tuple[str | None, list[float], list[float]]] = {
    "hip": (None, [0.0, 1.82, -105.18], [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]),
    "abdomen": ("hip", [0.0, 20.0, 0.5], [0.0, 0.0, 0.0, 1.0]),
    "neck": ("abdomen", [0.0, 35.0, -2.0], [0.0, 0.0, 0.0, 1.0]),
    "head": ("neck", [0.0, 5.0, 1.5], [0.0, 0.0, 0.0, 1.0]),
    "jaw": ("head", [0.0, -3.0, 4.0], [0.0, 0.0, 0.0, 1.0]),
    "lEye": ("head", [3.0, 5.0, 8.0], [0.0, 0.0, 0.0, 1.0]),
}
#: The skin's joint order (the head bone is not the first joint, as in the real file).
JOINTS = ("hip", "abdomen", "neck", "jaw", "head", "lEye")
#: What `move_head` does to the head bone after the inverse bind matrices were taken at rest.
MOVED_HEAD_ROTATION = (0.1, 0.2, -0.05, 0.97)  # (x, y, z, w), normalised when used
MOVED_HEAD_SHIFT = (1.5, -0.8, 2.5)  # cm, added to the head's translation


def _quat_matrix(q: list[float] | tuple[float, ...]) -> np.ndarray:
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _trs(t: list[float], q: list[float], s: list[float]) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(q) * np.asarray(s, np.float64)[None, :]
    m[:3, 3] = t
    return m


def skeleton(move_head: bool = False) -> dict[str, dict[str, Any]]:
    """Each bone's local TRS (and the root's), the head moved or not."""
    out: dict[str, dict[str, Any]] = {"Female.003": {"t": [0.0, 0.0, 0.0], "r": HALF_TURN_X, "s": [0.01] * 3}}
    for name, (_, t, r) in BONES.items():
        out[name] = {"t": list(t), "r": list(r), "s": [1.0, 1.0, 1.0]}
    if move_head:
        q = np.asarray(MOVED_HEAD_ROTATION) / np.linalg.norm(MOVED_HEAD_ROTATION)
        out["head"]["r"] = [float(v) for v in q]
        out["head"]["t"] = [a + b for a, b in zip(out["head"]["t"], MOVED_HEAD_SHIFT, strict=True)]
    return out


def world_matrices(bones: dict[str, dict[str, Any]]) -> dict[str, np.ndarray]:
    """World matrix of each bone (root: Female.003, above hip)."""
    out: dict[str, np.ndarray] = {}
    root = bones["Female.003"]
    out["Female.003"] = _trs(root["t"], root["r"], root["s"])
    for name, (parent, _, _) in BONES.items():  # parents come first in BONES
        b = bones[name]
        out[name] = out[parent or "Female.003"] @ _trs(b["t"], b["r"], b["s"])
    return out


def make_arrays(n: int = 300, seed: int = 0, names: list[str] | None = None, dense_targets: int = 3,
                joints_type: int = UBYTE) -> dict[str, Any]:
    """The skin's arrays before packing: positions (N, 3) m around a head at 1.65 m, joints, weights, triangle
    indices, target names (shuffled ARKit 51 unless given), targets as (rows, values) and which are dense."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    positions = (np.array([0.0, 1.65, 0.01]) + d * [0.09, 0.12, 0.10]).astype(np.float32)
    joints = np.zeros((n, 4), np.uint8 if joints_type == UBYTE else np.uint16)
    joints[:, 0] = JOINTS.index("head")
    joints[:, 1] = JOINTS.index("neck")
    joints[:, 2] = JOINTS.index("jaw")
    w = rng.uniform(0.0, 1.0, (n, 4)).astype(np.float32)
    w[:, 3] = 0.0
    w[:, 0] += 2.0
    weights = (w / w.sum(axis=1, keepdims=True)).astype(np.float32)
    indices = np.arange(n - n % 3, dtype=np.uint16 if n < 65536 else np.uint32)
    if names is None:
        names = list(ARKIT_51)
        rng.shuffle(names)
    targets = []
    for _ in names:
        m = int(rng.integers(max(1, n // 10), max(2, n // 2)))
        rows = np.sort(rng.choice(n, m, replace=False)).astype(np.int64)
        values = rng.normal(0.0, 2e-3, (m, 3)).astype(np.float32)
        values[values == 0] = 1e-4
        targets.append((rows, values))
    dense = set(range(len(names) - dense_targets, len(names))) if dense_targets else set()
    return {"positions": positions, "joints": joints, "weights": weights, "indices": indices, "names": list(names),
            "targets": targets, "dense": dense, "sparse_index_type": USHORT if n < 65536 else UINT}


def make_ply_columns(n: int = 300, seed: int = 0) -> dict[str, np.ndarray]:
    """offset.ply's columns: small offsets, RGB in f_dc (a few just outside 0..1: the player clamps), opacity
    logits, log scales, unnormalised quaternions (rot_0 = w)."""
    rng = np.random.default_rng(seed + 1000)
    cols = {p: np.zeros(n, np.float32) for p in PLY_PROPERTIES}
    for i, p in enumerate("xyz"):
        cols[p] = rng.uniform(-3e-3, 3e-3, n).astype(np.float32) * (1.0 + 0.5 * i)
    for c in range(3):
        rgb = rng.uniform(-0.03, 1.03, n).astype(np.float32)
        rgb[:4] = [0.0, 1.0, 0.5, 127.5 / 255.0]
        cols[f"f_dc_{c}"] = rgb
    cols["opacity"] = rng.normal(0.0, 2.5, n).astype(np.float32)
    for c in range(3):
        cols[f"scale_{c}"] = rng.uniform(-7.5, -4.0, n).astype(np.float32)
    q = rng.normal(size=(n, 4)) * rng.uniform(0.3, 3.0, (n, 1))
    for c in range(4):
        cols[f"rot_{c}"] = q[:, c].astype(np.float32)
    return cols


def ply_bytes(cols: dict[str, np.ndarray], count: int | None = None) -> bytes:
    """A binary little-endian PLY of float properties `cols` (vertex count from the columns unless given)."""
    names = list(cols)
    n = len(cols[names[0]]) if count is None else count
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {p}\n" for p in names) + "end_header\n"
    table = np.stack([np.asarray(cols[p], np.float32) for p in names], axis=1)
    return header.encode() + table.astype("<f4").tobytes()


class _Blob:
    """The binary chunk being written: arrays appended 4-byte aligned, one buffer view each."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[pygltflib.BufferView] = []

    def add(self, array: np.ndarray) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        raw = np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes()
        self.views.append(pygltflib.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw)))
        self.data += raw
        return len(self.views) - 1


def _component(a: np.ndarray) -> int:
    return {np.dtype(np.float32): FLOAT, np.dtype(np.uint8): UBYTE, np.dtype(np.uint16): USHORT,
            np.dtype(np.uint32): UINT}[a.dtype]


def skin_gltf(arrays: dict[str, Any], move_head: bool = False, use_matrix: bool = False) -> pygltflib.GLTF2:
    """The pygltflib document of skin.glb (binary blob set)."""
    blob = _Blob()
    accessors: list[pygltflib.Accessor] = []

    def dense(a: np.ndarray, typ: str, minmax: bool = False) -> int:
        a = np.asarray(a)
        view = blob.add(a)
        acc = pygltflib.Accessor(bufferView=view, byteOffset=0, componentType=_component(a), count=len(a), type=typ)
        if minmax:
            acc.min = [float(v) for v in a.min(axis=0)]
            acc.max = [float(v) for v in a.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    n = len(arrays["positions"])
    attributes = pygltflib.Attributes(POSITION=dense(arrays["positions"], "VEC3", True),
                                      JOINTS_0=dense(arrays["joints"], "VEC4"),
                                      WEIGHTS_0=dense(arrays["weights"], "VEC4"))
    indices = dense(arrays["indices"], "SCALAR")
    idx_dtype = {UBYTE: np.uint8, USHORT: np.uint16, UINT: np.uint32}[arrays["sparse_index_type"]]
    targets = []
    for k, (rows, values) in enumerate(arrays["targets"]):
        values = np.asarray(values, np.float32).reshape(-1, 3)
        if k in arrays["dense"]:
            full = np.zeros((n, 3), np.float32)
            full[np.asarray(rows, np.int64)] = values
            targets.append({"POSITION": dense(full, "VEC3")})
            continue
        iv = blob.add(np.asarray(rows).astype(idx_dtype))
        vv = blob.add(values)
        sparse = pygltflib.Sparse(count=len(values),
                                  indices=pygltflib.AccessorSparseIndices(bufferView=iv, byteOffset=0,
                                                                          componentType=arrays["sparse_index_type"]),
                                  values=pygltflib.AccessorSparseValues(bufferView=vv, byteOffset=0))
        accessors.append(pygltflib.Accessor(bufferView=None, byteOffset=0, componentType=FLOAT, count=n,
                                            type="VEC3", sparse=sparse))
        targets.append({"POSITION": len(accessors) - 1})

    # nodes, children before parents as in the real file; the root (Female.003) last
    rest = world_matrices(skeleton(False))
    posed = skeleton(move_head)
    order = ["lEye", "jaw", "head", "neck", "abdomen", "hip", "head_final", "Female.003"]
    at = {name: i for i, name in enumerate(order)}
    children: dict[str, list[str]] = {name: [] for name in order}
    for name, (parent, _, _) in BONES.items():
        children[parent or "Female.003"].append(name)
    children["Female.003"].insert(0, "head_final")
    nodes = []
    for name in order:
        node = pygltflib.Node(name=name, children=[at[c] for c in children[name]])
        if name == "head_final":
            node.mesh, node.skin = 0, 0
        else:
            b = posed[name]
            if use_matrix:
                node.matrix = [float(v) for v in _trs(b["t"], b["r"], b["s"]).T.reshape(-1)]
            else:
                node.translation, node.rotation, node.scale = b["t"], b["r"], b["s"]
        nodes.append(node)
    ibm = np.stack([np.linalg.inv(rest[j]).T.astype(np.float32) for j in JOINTS]).reshape(-1, 16)
    ibm_accessor = dense(ibm, "MAT4")
    g = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0", generator="npga-view tests (LAM layout)"),
        scene=0, scenes=[pygltflib.Scene(name="Scene", nodes=[at["Female.003"]])], nodes=nodes,
        meshes=[pygltflib.Mesh(name="head_mesh", extras={"targetNames": list(arrays["names"])},
                               primitives=[pygltflib.Primitive(attributes=attributes, indices=indices, mode=4,
                                                               targets=targets)])],
        skins=[pygltflib.Skin(name="Female.003", joints=[at[j] for j in JOINTS], inverseBindMatrices=ibm_accessor)],
        accessors=accessors, bufferViews=blob.views, buffers=[pygltflib.Buffer(byteLength=len(blob.data))])
    g.set_binary_blob(bytes(blob.data))
    return g


def glb_bytes(g: pygltflib.GLTF2) -> bytes:
    """A pygltflib document as a .glb file."""
    out = g.save_to_bytes()
    return b"".join(out) if isinstance(out, list) else bytes(out)


def glb_container(json_text: bytes, binary: bytes = b"") -> bytes:
    """A .glb of any JSON text and binary chunk (for hostile JSON pygltflib would not write)."""
    json_text += b" " * (-len(json_text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(json_text), b"JSON") + json_text
    if binary:
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def animation_glb() -> bytes:
    """A stub animation.glb (the player plays its clips for chat states only)."""
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"), scene=0, scenes=[pygltflib.Scene(nodes=[0])],
                        nodes=[pygltflib.Node(name="hip")])
    return glb_bytes(g)


def write_lam_zip(path: str | Path, n: int = 300, seed: int = 0, folder: str = "avatar", move_head: bool = False,
                  use_matrix: bool = False, names: list[str] | None = None, dense_targets: int = 3,
                  joints_type: int = UBYTE, extras: bool = True, macosx: bool = True,
                  tamper_arrays: Callable[[dict[str, Any]], None] | None = None,
                  tamper_gltf: Callable[[pygltflib.GLTF2], None] | None = None,
                  tamper_ply: Callable[[dict[str, np.ndarray]], None] | None = None,
                  skin: bytes | None = None, ply: bytes | None = None,
                  compression: int = zipfile.ZIP_DEFLATED) -> Path:
    """Write a LAM avatar zip of `n` Gaussians at `path` (the hooks and raw `skin`/`ply` bytes make hostile
    variants) and return the path."""
    path = Path(path)
    if skin is None:
        arrays = make_arrays(n, seed, names, dense_targets, joints_type)
        if tamper_arrays:
            tamper_arrays(arrays)
        g = skin_gltf(arrays, move_head, use_matrix)
        if tamper_gltf:
            tamper_gltf(g)
        skin = glb_bytes(g)
    if ply is None:
        cols = make_ply_columns(n, seed)
        if tamper_ply:
            tamper_ply(cols)
        ply = ply_bytes(cols)
    with zipfile.ZipFile(path, "w", compression) as z:
        z.writestr(zipfile.ZipInfo(folder + "/"), b"")
        if macosx:
            z.writestr(f"__MACOSX/._{folder}", b"\0\5\26\7" + bytes(60))
            z.writestr(f"{folder}/.DS_Store", b"\0\0\0\1Bud1" + bytes(32))
        z.writestr(f"{folder}/skin.glb", skin)
        if macosx:
            z.writestr(f"__MACOSX/{folder}/._skin.glb", b"\0\5\26\7" + bytes(40))
        z.writestr(f"{folder}/offset.ply", ply)
        if macosx:
            z.writestr(f"__MACOSX/{folder}/._offset.ply", b"\0\5\26\7" + bytes(40))
        if extras:
            z.writestr(f"{folder}/animation.glb", animation_glb())
            z.writestr(f"{folder}/vertex_order.json", json.dumps(list(range(n))))
    return path


def big_jaw(arrays: dict) -> None:
    """jawOpen moves its vertices 2 cm down: the player's x1.2 on it is plainly visible."""
    k = arrays["names"].index("jawOpen")
    rows = np.flatnonzero(arrays["positions"][:, 1] < 1.62)
    arrays["targets"][k] = (rows, np.tile(np.float32([0.0, -0.02, 0.004]), (len(rows), 1)))
