"""Writing LAM-style web avatar zips: the layout LAM's web player loads (`npga_core/files/lam.py` reads it).

What is written, and why (the player is ``gaussian-splat-renderer-for-lam`` 0.0.8, npm, MIT; line numbers of
``build/gaussian-splat-renderer-for-lam.module.js``):

- one directory entry, the avatar's folder: the player takes the zip's last directory entry as the folder
  (``GaussianSplatRenderer.getInstance``, 152038-152045), so no other directory entry is written;
- ``<folder>/offset.ply``: the 3DGS vertex layout of the real files (x y z nx ny nz f_dc_0..2 opacity scale_0..2
  rot_0..3, binary little-endian floats): x, y, z are offsets from mesh vertex i (``fillSplatCenterArray``,
  55437-55480), f_dc the linear RGB colour in 0..1 (the player stores floor(255 f), 57409-57432), opacity a
  logit, log scales, rotations (w, x, y, z);
- ``<folder>/skin.glb`` (pygltflib): one skinned mesh in TRIANGLES mode (a POINTS primitive is not found by
  ``skinModel.traverse(... isSkinnedMesh)``, 152357-152363) with one vertex per Gaussian, JOINTS_0/WEIGHTS_0 (the
  player copies them into its splat geometry, 139490-139510), the morph targets named in
  ``mesh.extras.targetNames`` (GLTFLoader's morphTargetDictionary; sparse accessors where smaller); a skeleton
  with a ``hip`` bone (``this.boneRoot.updateMatrixWorld`` at 139486 throws without it) and a ``head`` joint
  (the splats are moved by ``boneMatrix(head)`` only, 61790-61800: without it every centre is multiplied by a
  zero matrix), its bind pose its rest pose (``matrixWorld x boneInverse`` = identity); no animation in it
  (``LoadGLTF`` returns a file's clips instead of its scene when it has any, 152418-152422);
- ``<folder>/animation.glb``: 12 clips in the player's chat-state layout (hello 2, idle 1, listen 0, speak 6,
  think 3: ``animationConfig``, 151941-151970; ``AnimationManager``, 145307-145357; idle indexes its clip 0 with
  no guard), each holding the ``hip`` bone at rest, so chat states move nothing;
- ``<folder>/vertex_order.json``: the vertices sorted by height, as LAM writes it (loaded, never used: 152371);
- ``<folder>/README.txt``: what the export kept and lost.

Morph deltas are stored in the player's units: it multiplies weight k by its scale s_k before use (152232-152243,
``PLAYER_SCALE``), so the written delta is the wanted displacement per unit weight divided by s_k, and a weight
means the same in the browser as in npga-view. The player's morph texture holds N (targets + 1) texels of a
4096 x 2048 texture (``buildModelTexture``, 64725-64760): larger avatars are refused (`check_capacity`).
"""

from __future__ import annotations

import io
import json
import re
import stat
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from npga_core.files.atomic import atomic_write
from npga_core.files.lam import PLAYER, PLAYER_SCALE, PLAYER_TEXELS

#: The centre of LAM's heads in its body-rig frame (metres, y up, face toward +z): the real p2-1 skin's box
#: centre, where the player's default camera (0, 1.8, 1), pitched down 10 degrees, looks (151983-151993).
LAM_HEAD_CENTRE = (0.0, 1.65, 0.0)
#: The skeleton written: hip at (0, 1, 0), head 0.5 above it (exact in float32, so the inverse bind matrices
#: are exact and the head's matrixWorld x inverseBindMatrix is the identity).
HIP_AT = (0.0, 1.0, 0.0)
HEAD_ABOVE_HIP = (0.0, 0.5, 0.0)
#: Clips per chat state, in the order the player counts them (hello, idle, listen, speak, think).
CLIPS = (("hello", 2), ("idle", 1), ("listen", 0), ("speak", 6), ("think", 3))
PLY_FIELDS = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
              "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
#: Zip members beside the four the player loads.
README = "README.txt"


class LamExportError(ValueError):
    """A LAM export that cannot be written (a hostile target, beyond the player's capacity), one line."""


@dataclass
class WebAvatar:
    """Everything a LAM zip holds, in LAM's frame: per Gaussian its mesh vertex and offset (PLY xyz), RGB in 0..1,
    opacity logit, log scales, rotation (w, x, y, z); morph targets `names` with deltas (K, N, 3) per unit weight
    as the player applies them (already divided by its scales)."""

    vertices: np.ndarray  # (N, 3) float32
    offsets: np.ndarray  # (N, 3) float32
    rgb: np.ndarray  # (N, 3) float32 in 0..1
    opacity_logits: np.ndarray  # (N,) float32
    log_scales: np.ndarray  # (N, 3) float32
    quats: np.ndarray  # (N, 4) float32 (w, x, y, z)
    names: tuple[str, ...]
    deltas: np.ndarray  # (K, N, 3) float32, in the player's units
    notes: dict[str, str] = field(default_factory=dict)  # what README.txt says beside the fixed text

    def __post_init__(self) -> None:
        n = len(self.vertices)
        shapes = {"vertices": (n, 3), "offsets": (n, 3), "rgb": (n, 3), "opacity_logits": (n,),
                  "log_scales": (n, 3), "quats": (n, 4), "deltas": (len(self.names), n, 3)}
        for name, shape in shapes.items():
            a = np.ascontiguousarray(getattr(self, name), np.float32)
            if a.shape != shape:
                raise ValueError(f"web avatar {name} has shape {a.shape}, expected {shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"web avatar {name} has NaN/Inf values")
            setattr(self, name, a)
        if n == 0 or not self.names or len(set(self.names)) != len(self.names):
            raise ValueError("a web avatar needs Gaussians and distinct morph target names")
        self.names = tuple(self.names)

    def __len__(self) -> int:
        return len(self.vertices)

    def rest(self) -> np.ndarray:
        """The centres at zero weights (vertex + offset), float64."""
        return self.vertices.astype(np.float64) + self.offsets

    def centres(self, weights: dict[str, float]) -> np.ndarray:
        """The centres the player draws at ARKit weights (name -> value; scaled as the player scales them)."""
        c = self.rest()
        for k, name in enumerate(self.names):
            w = weights.get(name, 0.0)
            if w:
                c += (w * PLAYER_SCALE.get(name, 1.0)) * self.deltas[k].astype(np.float64)
        return c


def texels(n: int, targets: int) -> int:
    """Texels of the player's morph texture an avatar of n Gaussians and `targets` morph targets fills."""
    return n * (targets + 1)


def check_capacity(n: int, targets: int) -> None:
    """LamExportError (one line) when the player's 4096 x 2048 morph texture cannot hold the avatar."""
    if texels(n, targets) > PLAYER_TEXELS:
        most = PLAYER_TEXELS // (targets + 1)
        raise LamExportError(f"{n:,} Gaussians x ({targets} morph targets + 1) = {texels(n, targets):,} texels, more "
                             f"than the {PLAYER_TEXELS:,} of LAM's player's morph texture (at most {most:,} "
                             f"Gaussians at {targets} targets; {PLAYER})")


def check_target(path: Path, what: str = "--out") -> None:
    """LamExportError (one line) unless `path` can be written atomically: its folder exists and is a folder, and
    the path is not a directory, a FIFO, a device or a socket (an existing regular file is replaced)."""
    parent = path.parent
    try:
        if not parent.exists():
            raise LamExportError(f"{what} {path}: folder {parent} does not exist")
        if not parent.is_dir():
            raise LamExportError(f"{what} {path}: {parent} is not a folder")
        try:
            mode = path.lstat().st_mode
        except FileNotFoundError:
            return
        if stat.S_ISDIR(mode):
            raise LamExportError(f"{what} {path}: is an existing folder")
        if stat.S_ISLNK(mode):
            raise LamExportError(f"{what} {path}: is a symbolic link (give the real path)")
        if not stat.S_ISREG(mode):
            raise LamExportError(f"{what} {path}: is not a regular file (a FIFO, device or socket)")
    except OSError as e:  # a path through a file (ENOTDIR), too long a name, no permission to look
        raise LamExportError(f"{what} {path}: {e.strerror or e}") from None


def folder_name(path: Path) -> str:
    """The zip's folder: the file's stem with anything but letters, digits, '-', '_' and '.' replaced."""
    name = re.sub(r"[^A-Za-z0-9._-]", "_", path.stem).strip("._") or "avatar"
    return name[:64]


# -- offset.ply ------------------------------------------------------------------------------------------------
def ply_bytes(web: WebAvatar) -> bytes:
    """offset.ply in the real files' layout (normals zero)."""
    n = len(web)
    table = np.zeros((n, len(PLY_FIELDS)), "<f4")
    table[:, 0:3] = web.offsets
    table[:, 6:9] = web.rgb
    table[:, 9] = web.opacity_logits
    table[:, 10:13] = web.log_scales
    table[:, 13:17] = web.quats
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {p}\n" for p in PLY_FIELDS) + "end_header\n"
    return header.encode("ascii") + table.tobytes()


# -- glTF binaries ---------------------------------------------------------------------------------------------
class _Glb:
    """A glTF document being built: arrays appended 4-byte aligned to one binary chunk, one view each."""

    def __init__(self) -> None:
        import pygltflib

        self.g = pygltflib
        self.blob = bytearray()
        self.views: list = []
        self.accessors: list = []

    def view(self, array: np.ndarray, target: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        raw = np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes()
        self.views.append(self.g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(raw), target=target))
        self.blob += raw
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, typ: str, component: int, minmax: bool = False,
                 target: int | None = None) -> int:
        a = np.asarray(array)
        acc = self.g.Accessor(bufferView=self.view(a, target), byteOffset=0, componentType=component, count=len(a),
                              type=typ)
        if minmax:
            flat = a.reshape(len(a), -1)
            acc.min = [float(v) for v in flat.min(axis=0)]
            acc.max = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def target(self, delta: np.ndarray) -> int:
        """A morph target's POSITION accessor: no data for an all-zero delta, sparse where that is smaller."""
        n = len(delta)
        rows = np.flatnonzero(np.any(delta != 0.0, axis=1))
        index_type, index_dtype = (USHORT, np.uint16) if n <= 65535 else (UINT, np.uint32)
        acc = self.g.Accessor(byteOffset=0, componentType=FLOAT, count=n, type="VEC3")
        if len(rows) and len(rows) * (12 + np.dtype(index_dtype).itemsize) >= n * 12:
            return self.accessor(delta.astype(np.float32), "VEC3", FLOAT, minmax=True, target=ARRAY_BUFFER)
        if len(rows):
            values = delta[rows].astype(np.float32)
            acc.sparse = self.g.Sparse(
                count=len(rows),
                indices=self.g.AccessorSparseIndices(bufferView=self.view(rows.astype(index_dtype)), byteOffset=0,
                                                     componentType=index_type),
                values=self.g.AccessorSparseValues(bufferView=self.view(values), byteOffset=0))
            acc.min = [float(v) for v in np.minimum(values.min(axis=0), 0.0)]
            acc.max = [float(v) for v in np.maximum(values.max(axis=0), 0.0)]
        else:
            acc.min, acc.max = [0.0] * 3, [0.0] * 3
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def save(self, doc: Any) -> bytes:
        doc.accessors, doc.bufferViews = self.accessors, self.views
        doc.buffers = [self.g.Buffer(byteLength=len(self.blob))]
        doc.set_binary_blob(bytes(self.blob))
        out = doc.save_to_bytes()
        return b"".join(out) if isinstance(out, list) else bytes(out)


def _bones(g: Any) -> tuple[list, int, int]:
    """The skeleton's nodes (root, hip, head) and the hip's and head's indices."""
    root = g.Node(name="Armature", children=[1, 3])
    hip = g.Node(name="hip", translation=list(HIP_AT), children=[2])
    head = g.Node(name="head", translation=list(HEAD_ABOVE_HIP))
    return [root, hip, head], 1, 2


def skin_glb(web: WebAvatar) -> bytes:
    """skin.glb: the skinned triangle mesh of one vertex per Gaussian with the morph targets, and its skeleton."""
    b = _Glb()
    g = b.g
    n = len(web)
    joints = np.zeros((n, 4), np.uint8)
    joints[:, 0] = 1  # the head joint (skin.joints = [hip, head])
    weights = np.zeros((n, 4), np.float32)
    weights[:, 0] = 1.0
    attributes = g.Attributes(POSITION=b.accessor(web.vertices, "VEC3", FLOAT, True, ARRAY_BUFFER),
                              JOINTS_0=b.accessor(joints, "VEC4", UBYTE, False, ARRAY_BUFFER),
                              WEIGHTS_0=b.accessor(weights, "VEC4", FLOAT, False, ARRAY_BUFFER))
    # triangles through consecutive vertices (the mesh itself is hidden: skinModel.visible = false, 152378)
    count = n + (-n % 3)
    index = np.minimum(np.arange(count), n - 1).astype(np.uint16 if n <= 65535 else np.uint32)
    indices = b.accessor(index, "SCALAR", USHORT if n <= 65535 else UINT, False, ELEMENT_ARRAY_BUFFER)
    targets = [{"POSITION": b.target(web.deltas[k])} for k in range(len(web.names))]
    hip_world = np.eye(4)
    hip_world[:3, 3] = HIP_AT
    head_world = hip_world.copy()
    head_world[:3, 3] += HEAD_ABOVE_HIP
    ibm = np.stack([np.linalg.inv(m).T.reshape(16) for m in (hip_world, head_world)]).astype(np.float32)
    ibm_accessor = b.accessor(ibm, "MAT4", FLOAT)
    bones, hip, head = _bones(g)
    mesh_node = g.Node(name="avatar", mesh=0, skin=0)
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator="npga-view (LAM web avatar export)"),
        scene=0, scenes=[g.Scene(name="Scene", nodes=[0])], nodes=[*bones, mesh_node],
        meshes=[g.Mesh(name="avatar", extras={"targetNames": list(web.names)},
                       weights=[0.0] * len(web.names),
                       primitives=[g.Primitive(attributes=attributes, indices=indices, mode=4, targets=targets)])],
        skins=[g.Skin(name="Armature", joints=[hip, head], skeleton=hip, inverseBindMatrices=ibm_accessor)])
    return b.save(doc)


def animation_glb(seconds: float = 1.0) -> bytes:
    """animation.glb: the player's 12 chat-state clips, each holding the hip bone at its rest pose."""
    b = _Glb()
    g = b.g
    times = b.accessor(np.array([0.0, seconds], np.float32), "SCALAR", FLOAT, True)
    where = b.accessor(np.array([HIP_AT, HIP_AT], np.float32), "VEC3", FLOAT)
    turn = b.accessor(np.array([[0.0, 0.0, 0.0, 1.0]] * 2, np.float32), "VEC4", FLOAT)
    clips = []
    for state, count in CLIPS:
        for i in range(count):
            samplers = [g.AnimationSampler(input=times, output=where, interpolation="LINEAR"),
                        g.AnimationSampler(input=times, output=turn, interpolation="LINEAR")]
            channels = [g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=1, path="translation")),
                        g.AnimationChannel(sampler=1, target=g.AnimationChannelTarget(node=1, path="rotation"))]
            clips.append(g.Animation(name=f"{state}_{i + 1}", samplers=samplers, channels=channels))
    bones, _, _ = _bones(g)
    bones[0].children = [1]
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="npga-view (LAM web avatar export)"), scene=0,
                  scenes=[g.Scene(name="Scene", nodes=[0])], nodes=bones, animations=clips)
    return b.save(doc)


def vertex_order(web: WebAvatar) -> bytes:
    """vertex_order.json: the vertices sorted by height (LAM's own file is; the player never reads it)."""
    order = np.argsort(web.vertices[:, 1], kind="stable")
    return json.dumps([int(i) for i in order]).encode("ascii")


# -- the zip ---------------------------------------------------------------------------------------------------
LOST_NEURAL = ("the screen-space CNN (if the avatar has one); the networks' per-expression changes of rotation, "
               "scale, opacity and colour (held at the neutral expression); spherical harmonics above degree 0 "
               "(the player draws one colour per Gaussian: view-dependent colour is baked as seen from 1 m in "
               "front of the face); the expression dynamics beyond a linear fit of the centres (see fidelity)")
LOST_EXACT = ("spherical harmonics above degree 0 (the player draws one colour per Gaussian: view-dependent colour, "
              "if any, is baked as seen from 1 m in front of the face); colours become 8-bit in the player")


def readme_text(web: WebAvatar, source: str) -> str:
    """README.txt inside the zip."""
    lines = [
        f"LAM-style web avatar written by npga-view from {source}.",
        "",
        f"Play it with LAM's web player ({PLAYER}, npm, MIT) or an app built on it (OpenAvatarChat): it is",
        "driven live by ARKit blendshape weights (Live Link Face, LAM Audio2Expression, MediaPipe).",
        "",
        "Members:",
        "  offset.ply        per Gaussian: xyz = offset from its mesh vertex, f_dc = linear RGB in 0..1,",
        "                    opacity logit, log scales, rotation (w, x, y, z)",
        f"  skin.glb          one mesh vertex per Gaussian, {len(web.names)} ARKit morph targets",
        "                    (mesh.extras.targetNames), a hip and a head bone at rest",
        "  animation.glb     chat-state clips that hold the body at rest",
        "  vertex_order.json the vertices sorted by height (the player does not use it)",
        "",
        "The player rescales about 20 mouth weights before use (jawOpen x1.2, mouthClose x0.2, ...); the",
        "morph deltas are stored divided by those scales, so a weight means the same here as in npga-view.",
        "",
    ]
    for key, text in web.notes.items():
        lines.append(f"{key}: {text}")
    return "\n".join(lines) + "\n"


def zip_bytes(web: WebAvatar, folder: str, source: str) -> bytes:
    """The whole zip in memory: the folder entry, then offset.ply, skin.glb, animation.glb, vertex_order.json,
    README.txt."""
    check_capacity(len(web), len(web.names))
    members = {"skin.glb": skin_glb(web), "animation.glb": animation_glb(), "offset.ply": ply_bytes(web),
               "vertex_order.json": vertex_order(web), README: readme_text(web, source).encode("utf-8")}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=6) as z:
        z.writestr(zipfile.ZipInfo(folder + "/", date_time=(2025, 1, 1, 0, 0, 0)), b"")
        for name, data in members.items():
            info = zipfile.ZipInfo(f"{folder}/{name}", date_time=(2025, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
    return buf.getvalue()


def write_lam_zip(path: str | Path, web: WebAvatar, source: str) -> int:
    """Write the zip at `path` atomically (LamExportError for a hostile target or an avatar beyond the player's
    capacity, OSError from the file system); returns its size in bytes."""
    path = Path(path)
    check_target(path)
    data = zip_bytes(web, folder_name(path), source)
    atomic_write(path, lambda fh: fh.write(data))
    return len(data)


def write_json(path: str | Path, doc: dict) -> None:
    """A JSON report written atomically (the same target checks as the zip)."""
    path = Path(path)
    check_target(path)
    text = json.dumps(doc, indent=2, sort_keys=False) + "\n"
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))
