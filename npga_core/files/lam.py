"""LAM avatars (aigc3d/LAM, SIGGRAPH 2025) as their web players load them: a zip with one folder holding
`offset.ply` and `skin.glb`, read into an `Avatar` whose dynamics are a `LinearRig` driven by ARKit weights.

What the files mean follows LAM's own web player, ``gaussian-splat-renderer-for-lam`` 0.0.8 (npm, MIT; line
numbers of ``build/gaussian-splat-renderer-for-lam.module.js``):

- the folder is the zip's directory entry (``GaussianSplatRenderer.getInstance``, 152030-152045); it loads
  ``<folder>/skin.glb``, ``animation.glb`` and ``vertex_order.json`` (``loadModel``, 152345-152380) and then
  ``<folder>/offset.ply`` (152086). `vertex_order.json` is stored on the viewer and never read; `animation.glb`
  holds canned body clips played only for chat states: neither changes the face.
- `offset.ply`: a 3DGS vertex layout whose x, y, z are offsets added to mesh vertex i's rest position
  (``fillSplatCenterArray``, 55437-55480: ``center + morphedMesh[i]``, morphedMesh the skinned mesh's
  POSITION array, 139470); ``f_dc`` is the colour itself, stored as ``floor(255 f)`` clamped to 0..255 (the
  INRIA PLY parser, 57409-57432: the SH conversion is commented out); opacity a logit, scales logs, rot_0..3
  (w, x, y, z) normalised (57450). Only SH degree 0 is drawn (``sphericalHarmonicsDegree: 0``, 152077).
- `skin.glb`: the skinned mesh (one vertex per Gaussian), its morph targets (glTF: relative position deltas)
  named by ``mesh.extras.targetNames``; in the vertex shader the centre is ``center + sum_i w_i delta_i``
  (61742-61763) and then ``boneMatrix(head) * centre`` (61790-61800: only the ``head`` bone moves splats,
  ``bone.matrixWorld * boneInverse``); covariances, opacity and colour are not changed.
- weights: ``w * scale + offset`` per ARKit name from the player's motion config before use (152232-152243;
  the table at 151880-151933, offsets all 0); not clamped for the splats (the clamp at 152292 is for the hidden
  mesh); a name the skin lacks is ignored.

The zip is read through the untrusted gate: names and sizes from its central directory first (no traversal,
bounded member count and sizes), then only the two members needed, each within its claimed size.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.blendshape_names import ARKIT_52
from npga_core.files.gltf_arrays import GltfArrays, GltfError, Mesh, Primitive, Skin, index_in, parse_glb
from npga_core.files.ply import read_ply_bytes
from npga_core.files.untrusted import MAX_POSITION, read_zip_members, zip_member_names
from npga_core.model.avatar import Avatar
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.dynamics import Dynamics
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import GaussianCloud, rgb_to_sh0
from npga_core.model.linear_rig import LinearRig

ZIP_MAGIC = b"PK\x03\x04"
#: Members LAM's player loads besides offset.ply and skin.glb (loadModel, 152345-152380): without them it fails
#: (vertex_order.json: 'undefined is not valid JSON') or never draws (no animation clips); this reader needs neither.
PLAYER_MEMBERS = ("animation.glb", "vertex_order.json")
MAX_MEMBERS = 4096
MAX_PLY_BYTES = 256 * 1024 * 1024
MAX_GLB_BYTES = 1024 * 1024 * 1024
MAX_TOTAL_BYTES = MAX_PLY_BYTES + MAX_GLB_BYTES
#: Most morph targets (LAM writes the 51 ARKit shapes without tongueOut).
MAX_TARGETS = 1024
#: What LAM's player allows: its morph texture holds N (targets + 1) <= 4096 x 2048 texels.
PLAYER_TEXELS = 4096 * 2048

#: The player's per-name weight scale (``motionConfig.scale``, module.js 151880-151933); names not listed are 1.
PLAYER_SCALE: dict[str, float] = {
    "jawOpen": 1.2, "mouthClose": 0.2, "mouthLowerDownLeft": 0.7, "mouthLowerDownRight": 0.7,
    "mouthShrugUpper": 0.1,
    **{name: 1.3 for name in (
        "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight", "mouthFunnel", "mouthLeft",
        "mouthPressLeft", "mouthPressRight", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
        "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight")},
}
PLAYER = "gaussian-splat-renderer-for-lam 0.0.8"
RESCALE_NOTE = (f"weights rescaled as LAM's own player ({PLAYER}) does: w x scale per ARKit name, not clamped; "
                "the MIT fork myned-ai/gsplat-flame-avatar-renderer does not rescale")

#: Named expressions offered for a LAM avatar (ARKit weights).
NAMED_EXPRESSIONS: dict[str, dict[str, float]] = {
    "jaw open": {"jawOpen": 0.8},
    "smile": {"mouthSmileLeft": 0.9, "mouthSmileRight": 0.9, "cheekSquintLeft": 0.3, "cheekSquintRight": 0.3},
    "blink": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0},
    "surprise": {"browInnerUp": 0.9, "browOuterUpLeft": 0.9, "browOuterUpRight": 0.9, "eyeWideLeft": 0.8,
                 "eyeWideRight": 0.8, "jawOpen": 0.4},
    "pucker": {"mouthPucker": 1.0, "mouthFunnel": 0.4},
    "frown": {"browDownLeft": 0.8, "browDownRight": 0.8, "mouthFrownLeft": 0.8, "mouthFrownRight": 0.8},
}


def is_zip(head: bytes) -> bool:
    """True for the first bytes of a zip archive."""
    return head.startswith(ZIP_MAGIC) or head.startswith(b"PK\x05\x06")


def avatar_folder(path: str | Path, names: list[str]) -> str:
    """The folder (with its trailing '/', or '' at the top) holding offset.ply and skin.glb."""
    folders = {n[: -len("offset.ply")] for n in names if n.endswith("offset.ply") and n.rsplit("/", 1)[-1] ==
               "offset.ply"}
    found = sorted(f for f in folders if f + "skin.glb" in names and not f.startswith("__MACOSX/"))
    if not found:
        raise AvatarFileError(path, "is a zip archive but not a LAM avatar (no folder with offset.ply and "
                              "skin.glb)")
    if len(found) > 1:
        raise AvatarFileError(path, f"holds {len(found)} LAM avatars ({', '.join(repr(f) for f in found[:4])}); "
                              "a LAM zip has one")
    return found[0]


def read_lam_zip(path: str | Path) -> Avatar:
    """The LAM avatar in zip `path`; AvatarFileError (one line) for anything wrong."""
    names = zip_member_names(path, MAX_MEMBERS, "a LAM avatar zip")
    folder = avatar_folder(path, names)
    data = read_zip_members(path, {folder + "offset.ply": MAX_PLY_BYTES, folder + "skin.glb": MAX_GLB_BYTES},
                            MAX_TOTAL_BYTES, "a LAM avatar zip")
    where = f"{path}!{folder}"
    splats = read_ply_bytes(data[folder + "offset.ply"], where + "offset.ply")
    try:
        skin = read_skin(data[folder + "skin.glb"])
    except GltfError as e:
        raise AvatarFileError(where + "skin.glb", str(e)) from None
    extras = sorted({n.rsplit("/", 1)[-1] for n in names if n.startswith(folder) and not n.endswith("/")}
                    - {"offset.ply", "skin.glb"})
    return lam_avatar(splats, skin, str(path), where, extras)


class LamSkin:
    """What the player takes from skin.glb: rest positions, named morph targets (sparse), the head matrix."""

    def __init__(self, positions: np.ndarray, names: list[str], targets: list[tuple[np.ndarray, np.ndarray]],
                 head: np.ndarray, joints: int, has_hip: bool):
        self.positions, self.names, self.targets = positions, names, targets
        self.head, self.joints, self.has_hip = head, joints, has_hip


def read_skin(data: bytes) -> LamSkin:
    """Parse skin.glb (GltfError on anything the player could not use)."""
    g = parse_glb(data)
    arrays = GltfArrays(g)
    skinned = [(n.mesh, n.skin) for n in arrays.nodes if n.mesh is not None and n.skin is not None]
    if not skinned:
        raise GltfError("has no skinned mesh (LAM's player needs one)")
    mesh_i, skin_i = skinned[-1]  # the player keeps the last skinned mesh its traversal meets (152318)
    meshes, skins = arrays.doc.meshes or [], arrays.doc.skins or []
    mesh = meshes[index_in(mesh_i, meshes, "the skinned node's mesh")]
    skin = skins[index_in(skin_i, skins, "the skinned node's skin")]
    if not mesh.primitives:
        raise GltfError("the skinned mesh has no primitives")
    prim = mesh.primitives[0]
    if prim.attributes is None or prim.attributes.POSITION is None:
        raise GltfError("the skinned mesh has no POSITION attribute")
    pos = arrays.accessor(prim.attributes.POSITION, "POSITION", ("VEC3",))
    if pos.dtype != np.float32:
        raise GltfError(f"POSITION has component type {pos.dtype}, not float")
    if pos.size and np.abs(pos).max() > MAX_POSITION:
        raise GltfError(f"POSITION reaches {float(np.abs(pos).max()):.3g}, beyond +-{MAX_POSITION:g}")
    names, sparse = _morph_targets(arrays, mesh, prim, pos.shape[0])
    joints = list(skin.joints or [])
    head = _head_matrix(arrays, skin, joints)
    # the player looks for a Bone named 'hip' (loadModel, 152318-152321): a joint of the skin, not any node
    has_hip = any(j < len(arrays.nodes) and arrays.nodes[j].name == "hip" for j in joints)
    return LamSkin(pos, names, sparse, head, len(joints), has_hip)


def _morph_targets(arrays: GltfArrays, mesh: Mesh, prim: Primitive, n: int) -> tuple[list[str],
                   list[tuple[np.ndarray, np.ndarray]]]:
    """The morph targets' names (mesh.extras.targetNames) and sparse POSITION deltas."""
    targets = list(prim.targets or [])
    names = (mesh.extras.targetNames if mesh.extras is not None else None) or []
    if not targets:
        raise GltfError("the skinned mesh has no morph targets (a LAM skin has the ARKit shapes)")
    if len(targets) > MAX_TARGETS:
        raise GltfError(f"has {len(targets)} morph targets, more than the {MAX_TARGETS} allowed")
    if len(names) != len(targets):
        raise GltfError(f"mesh.extras.targetNames must name each of the {len(targets)} morph targets")
    if len(set(names)) != len(names):
        raise GltfError("mesh.extras.targetNames has repeated names")
    sparse = []
    for k, t in enumerate(targets):
        rows, values = arrays.sparse_target(t.POSITION, f"morph target {names[k]!r}", n)
        if values.size and np.abs(values).max() > MAX_POSITION:
            raise GltfError(f"morph target {names[k]!r} moves a vertex by {float(np.abs(values).max()):.3g}, beyond "
                            f"+-{MAX_POSITION:g}")
        sparse.append((rows, values))
    return list(names), sparse


def _head_matrix(arrays: GltfArrays, skin: Skin, joints: list[int]) -> np.ndarray:
    """matrixWorld x inverseBindMatrix of the joint named 'head' (what the player's shader applies)."""
    parent = arrays.parents()
    heads = [j for j, node_i in enumerate(joints) if node_i < len(arrays.nodes) and arrays.nodes[node_i].name == "head"]
    if not heads:
        raise GltfError("the skin has no joint named 'head' (LAM's player moves every splat by it)")
    if skin.inverseBindMatrices is None:
        head_inv = np.eye(4)
    else:
        ibm = arrays.accessor(skin.inverseBindMatrices, "inverseBindMatrices", ("MAT4",), len(joints))
        if ibm.shape[0] != len(joints) or ibm.dtype != np.float32:
            raise GltfError(f"inverseBindMatrices has {ibm.shape[0]} float matrices for {len(joints)} joints")
        head_inv = ibm[heads[-1]].astype(np.float64).reshape(4, 4).T
    # the last joint named 'head' wins, as the player's forEach over the bones (64589-64592)
    head = arrays.world_matrix(joints[heads[-1]], parent) @ head_inv
    if not np.isfinite(head).all() or not np.allclose(head[3], [0, 0, 0, 1], atol=1e-6):
        raise GltfError("the head joint's matrix is not a finite affine transform")
    sv = np.linalg.svd(head[:3, :3], compute_uv=False)
    if not (sv.min() >= 1e-3 and sv.max() <= 1e3 and np.abs(head[:3, 3]).max() <= MAX_POSITION):
        raise GltfError(f"the head joint's matrix scales by {sv.min():.3g}..{sv.max():.3g} or moves by "
                        f"{np.abs(head[:3, 3]).max():.3g}: beyond what a head rig does "
                        f"(0.001..1000, +-{MAX_POSITION:g})")
    head[3] = [0.0, 0.0, 0.0, 1.0]
    return head


def _channel_order(names: list[str]) -> list[str]:
    """The skin's target names in ARKit's order (Live Link's packet order), unknown names after, as found."""
    known = [n for n in ARKIT_52 if n in names]
    return known + [n for n in names if n not in known]


def lam_avatar(splats: GaussianCloud, skin: LamSkin, source: str, where: str, extras: list[str]) -> Avatar:
    """The avatar of a LAM splat cloud (offsets, RGB in f_dc) and its skin."""
    n = len(splats)
    if skin.positions.shape[0] != n:
        raise AvatarFileError(where, f"offset.ply has {n:,} Gaussians, skin.glb {skin.positions.shape[0]:,} "
                              "vertices (a LAM avatar pairs them one to one)")
    vertices = skin.positions.astype(np.float32)
    means = (vertices.astype(np.float64) + splats.means).astype(np.float32)
    rgb = np.clip(splats.sh[:, 0, :], 0.0, 1.0)  # the player stores floor(255 f) clamped to 0..255
    sh = rgb_to_sh0(rgb)[:, None, :]
    cloud = GaussianCloud(means=means, quats=splats.quats, log_scales=splats.log_scales,
                          opacity_logits=splats.opacity_logits, sh=sh, features=np.zeros((n, 0), np.float32))
    order = _channel_order(skin.names)
    by_name = dict(zip(skin.names, skin.targets, strict=True))
    support = np.unique(np.concatenate([by_name[c][0] for c in order])) if order else np.zeros(0, np.int64)
    deltas = np.zeros((len(order), len(support), 3), np.float32)
    for k, c in enumerate(order):
        rows, vals = by_name[c]
        deltas[k, np.searchsorted(support, rows)] = vals
    scale = np.array([PLAYER_SCALE.get(c, 1.0) for c in order], np.float32)
    rig = LinearRig(tuple(order), support, deltas, n, scale=scale, carrier="vertex", vertices=vertices,
                    transform=skin.head.astype(np.float32).astype(np.float64), source="LAM skin.glb",
                    notes={"weights": RESCALE_NOTE,
                           "player capacity": f"{n * (len(order) + 1):,} of the {PLAYER_TEXELS:,} morph texels "
                                              "its player holds",
                           "not read": ", ".join(extras) or "nothing",
                           **({"player": "LAM's player cannot load this zip: it also needs "
                                         + " and ".join(m for m in PLAYER_MEMBERS if m not in extras)}
                              if any(m not in extras for m in PLAYER_MEMBERS) else {}),
                           "skeleton": f"{skin.joints} joints; only 'head' moves the splats"
                                       + ("" if skin.has_hip else "; no 'hip' bone (LAM's player needs one)")})
    k = len(order)
    named = {}
    for label, weights in NAMED_EXPRESSIONS.items():
        code = np.zeros(k, np.float32)
        for c, v in weights.items():
            if c in order:
                code[order.index(c)] = v
        if code.any():
            named[label] = code
    expression = ExpressionSpace(np.zeros(k, np.float32), np.eye(k, dtype=np.float32), np.ones(k, np.float32),
                                 named)
    basis = BlendshapeBasis(tuple(order), np.eye(k, dtype=np.float32), np.zeros(k, np.float32),
                            source="the rig's own channels (LAM: ARKit)")
    prov = {"format": "lam-zip", "source": source, "player": PLAYER}
    return Avatar(cloud, Dynamics(networks={}, rig=rig), expression=expression, provenance=prov, source=source,
                  blendshapes=basis)
