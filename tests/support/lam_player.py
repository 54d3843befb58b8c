"""LAM's web player re-derived (`Player`): the posing of npm ``gaussian-splat-renderer-for-lam`` 0.0.8 (MIT), read
from ``build/gaussian-splat-renderer-for-lam.module.js`` (line numbers below), in numpy on the zip's bytes
(zipfile + pygltflib), without npga_core's rig, glTF or LAM code; the comparisons against it, and the real LAM
files the folder $NPGA_LAM_DATA names."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest

from npga_core.model.avatar import Avatar
from npga_core.posing.fastpose import FastPoser, posed_buffers
from tests.support.lam_layout import ARKIT_51

SH_C0 = 0.28209479177387814


DATA_ENV = "NPGA_LAM_DATA"


SOURCES = {
    "p2-1.zip": "github.com/aigc3d/LAM_WebRender asset/arkit/p2-1.zip (MIT)",
    "james.zip": "github.com/HumanAIGC-Engineering/OpenAvatarChat "
                 "src/handlers/client/h5_rendering_client/lam_samples/james.zip (Apache-2.0)",
    "status.zip": "github.com/HumanAIGC-Engineering/OpenAvatarChat "
                  "src/handlers/client/h5_rendering_client/lam_samples/status.zip (Apache-2.0)",
    "test_expression_1s.json": "github.com/aigc3d/LAM_WebRender asset/test_expression_1s.json (MIT)",
    "alex_rom_3.csv": "github.com/alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder anim/alex_rom_3.csv (MIT)",
}


# -- real zips -------------------------------------------------------------------------------------------------
def lam_data(name: str) -> Path:
    """A real LAM file from the folder $NPGA_LAM_DATA names; skipped (saying where to fetch it) otherwise."""
    root = os.environ.get(DATA_ENV)
    if not root:
        pytest.skip(f"real LAM files: set {DATA_ENV} to a folder holding "
                    + "; ".join(f"{k} (from {v})" for k, v in SOURCES.items()))
    path = Path(root) / name
    if not path.is_file():
        pytest.skip(f"{path} is missing ({DATA_ENV}={root}): fetch {name} from {SOURCES[name]}")
    return path
# -- LAM's player, re-derived ----------------------------------------------------------------------------------
#: The motion config's names (module.js 151828-151881: offsets, all 0) and its scales other than 1 (151882-151934).
MOTION_NAMES = frozenset(ARKIT_51) | {"tongueOut"}
MOTION_SCALE = {"jawOpen": 1.2, "mouthClose": 0.2, "mouthLowerDownLeft": 0.7, "mouthLowerDownRight": 0.7,
                "mouthShrugUpper": 0.1, "mouthDimpleLeft": 1.3, "mouthDimpleRight": 1.3, "mouthFrownLeft": 1.3,
                "mouthFrownRight": 1.3, "mouthFunnel": 1.3, "mouthLeft": 1.3, "mouthPressLeft": 1.3,
                "mouthPressRight": 1.3, "mouthRight": 1.3, "mouthRollLower": 1.3, "mouthRollUpper": 1.3,
                "mouthShrugLower": 1.3, "mouthStretchLeft": 1.3, "mouthStretchRight": 1.3, "mouthUpperUpLeft": 1.3,
                "mouthUpperUpRight": 1.3}
_COMPONENT = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _view_rows(g: Any, blob: bytes, view: int, offset: int, count: int, dtype: np.dtype, width: int) -> np.ndarray:
    """`count` elements of `width` components from a buffer view (its byteStride honoured)."""
    v = g.bufferViews[view]
    item = dtype.itemsize * width
    stride = v.byteStride or item
    start = (v.byteOffset or 0) + (offset or 0)
    raw = np.frombuffer(blob, np.uint8, (count - 1) * stride + item if count else 0, start)
    rows = raw[(np.arange(count) * stride)[:, None] + np.arange(item)[None, :]]
    return rows.copy().view(dtype).reshape(count, width)


def _accessor(g: Any, blob: bytes, index: int) -> np.ndarray:
    """Accessor `index` as three.js's GLTFLoader reads it (module.js 150139-150150 no buffer view: zeros;
    150222-150252 sparse: values written at their indices)."""
    a = g.accessors[index]
    dtype, width = np.dtype(_COMPONENT[a.componentType]), _WIDTH[a.type]
    if a.bufferView is None:
        out = np.zeros((a.count, width), dtype)
    else:
        out = _view_rows(g, blob, a.bufferView, a.byteOffset, a.count, dtype, width)
    if a.sparse is not None:
        s = a.sparse
        idx = _view_rows(g, blob, s.indices.bufferView, s.indices.byteOffset, s.count,
                         np.dtype(_COMPONENT[s.indices.componentType]), 1).reshape(-1)
        out[idx] = _view_rows(g, blob, s.values.bufferView, s.values.byteOffset, s.count, dtype, width)
    return out


def _local(node: Any) -> np.ndarray:
    """A node's matrix: `matrix` (column-major) or T * R * S (GLTFLoader 151388-151410, Object3D compose)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T
    x, y, z, w = node.rotation if node.rotation is not None else (0.0, 0.0, 0.0, 1.0)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.asarray(node.scale if node.scale is not None else (1.0, 1.0, 1.0))[None, :]
    m[:3, 3] = node.translation if node.translation is not None else (0.0, 0.0, 0.0)
    return m


class Player:
    """What LAM's player draws for a zip: per-splat colours, opacities, scales, rotations, and the centres at
    given ARKit weights (`centres`)."""

    def __init__(self, path: Path):
        with zipfile.ZipFile(path) as z:
            # 152038-152044: the avatar's folder is the zip's last directory entry (JSZip's file.dir), '/' cut
            folder = [i.filename for i in z.infolist() if i.is_dir()][-1][:-1]
            # loadModel 152347-152350: <folder>/skin.glb; 152087: <folder>/offset.ply
            skin, ply = z.read(f"{folder}/skin.glb"), z.read(f"{folder}/offset.ply")
        self._ply(ply)
        self._skin(skin)
        self.rest = self.xyz + self.positions

    def _ply(self, data: bytes) -> None:
        end = data.index(b"end_header\n") + len(b"end_header\n")
        lines = data[:end].decode("ascii").splitlines()
        assert "format binary_little_endian 1.0" in lines
        n = int(next(line for line in lines if line.startswith("element vertex")).split()[2])
        props = [line.split() for line in lines if line.startswith("property")]
        assert all(p[1] == "float" for p in props)
        t = np.frombuffer(data, np.dtype([(p[2], "<f4") for p in props]), n, end)
        col = {p[2]: t[p[2]].astype(np.float64) for p in props}
        self.n = n
        self.xyz = np.stack([col["x"], col["y"], col["z"]], 1)
        # the INRIA PLY parser, 57396-57460: exp scales; f_dc * 255 floored and clamped (the SH conversion is
        # commented out: f_dc is the colour); sigmoid opacity (x 255, floored); rot_0..3 set and normalised
        self.scales = np.exp(np.stack([col[f"scale_{i}"] for i in range(3)], 1))
        self.rgb8 = np.clip(np.floor(np.stack([col[f"f_dc_{i}"] for i in range(3)], 1) * 255), 0, 255)
        self.opacity = 1 / (1 + np.exp(-col["opacity"]))
        self.opacity8 = np.clip(np.floor(self.opacity * 255), 0, 255)
        q = np.stack([col[f"rot_{i}"] for i in range(4)], 1)
        self.quats = q / np.linalg.norm(q, axis=1, keepdims=True)

    def _skin(self, data: bytes) -> None:
        g = pygltflib.GLTF2.load_from_bytes(data)
        blob = bytes(g.binary_blob())
        parent = {c: i for i, node in enumerate(g.nodes) for c in node.children or []}

        def world(i: int) -> np.ndarray:  # Object3D.updateMatrixWorld (8241-8275): parent.matrixWorld * matrix
            return _local(g.nodes[i]) if i not in parent else world(parent[i]) @ _local(g.nodes[i])

        # loadModel 152357-152363: the last skinned mesh of skinModel.traverse (depth-first, 8189-8199)
        order: list[int] = []

        def visit(i: int) -> None:
            order.append(i)
            for c in g.nodes[i].children or []:
                visit(c)

        for i in g.scenes[g.scene or 0].nodes:
            visit(i)
        node = g.nodes[[i for i in order if g.nodes[i].mesh is not None and g.nodes[i].skin is not None][-1]]
        mesh, skin = g.meshes[node.mesh], g.skins[node.skin]
        prim = mesh.primitives[0]
        # morphedMesh is the skinned mesh's POSITION array (runMorphUpdate 139478-139480, avatarMesh: 139395)
        self.positions = _accessor(g, blob, prim.attributes.POSITION).astype(np.float64)
        # GLTFLoader 149510-149520: morphTargetDictionary[targetNames[i]] = i; buildModelTexture 64725-64745
        # stores target i at texture slot i (Object.keys order) and the weights go to slot dictionary[name]
        self.dictionary = {name: i for i, name in enumerate(mesh.extras["targetNames"])}
        self.deltas = [_accessor(g, blob, t["POSITION"]).astype(np.float64) for t in prim.targets]
        # 64589-64592: headBoneIndex is the LAST skeleton bone named 'head' (forEach overwrites)
        head = [j for j, node_i in enumerate(skin.joints) if g.nodes[node_i].name == "head"][-1]
        # the bone texture holds matrixWorld x boneInverses[i] (three.js Skeleton.update, 15501-15508); GLTFLoader
        # reads boneInverses from inverseBindMatrices column-major (151076-151078)
        ibm = _accessor(g, blob, skin.inverseBindMatrices)[head].astype(np.float64).reshape(4, 4).T
        self.head = world(skin.joints[head]) @ ibm

    def centres(self, weights: dict[str, float]) -> np.ndarray:
        """Splat centres at ARKit weights `weights` (name -> value)."""
        c = self.rest.copy()  # fillSplatCenterArray 55437-55477: PLY xyz + morphedMesh[i]
        for name, w in weights.items():
            if name in MOTION_NAMES:  # render 152232-152243: w * scale + offset, not clamped
                w = w * MOTION_SCALE.get(name, 1.0) + 0.0
            k = self.dictionary.get(name)
            if k is None:  # updateBoneMatrixTexture 64662-64667: idx undefined, the write goes nowhere
                continue
            c += w * self.deltas[k]  # vertex shader 61745-61764: splatCenter += weight_i * delta_i
        h = self.head  # 61790-61800: skinned = boneMatrix(headBoneIndex) * vec4(splatCenter, 1)
        return c @ h[:3, :3].T + h[:3, 3]


# -- comparing -------------------------------------------------------------------------------------------------
def frame_vector(avatar: Avatar, weights: dict[str, float]) -> np.ndarray:
    """The weights in the rig's channel order (names it lacks dropped, channels not named 0)."""
    return np.array([weights.get(c, 0.0) for c in avatar.rig.channels], np.float32)


def assert_static_as_player(avatar: Avatar, player: Player) -> None:
    """Colours (8-bit in the player), opacities, scales and rotations as the player stores them."""
    posed = avatar.pose(frame_vector(avatar, {}))
    assert len(posed) == player.n
    rgb = 0.5 + SH_C0 * posed.sh[:, 0, :].astype(np.float64)
    assert np.abs(rgb - player.rgb8 / 255).max() <= 1 / 255 + 1e-6
    np.testing.assert_allclose(posed.opacities, player.opacity, rtol=1e-5, atol=1e-7)
    assert np.abs(posed.opacities * 255.0 - player.opacity8).max() < 1 + 1e-3
    np.testing.assert_allclose(posed.scales, player.scales, rtol=1e-5)
    sign = np.sign(np.sum(posed.quats * player.quats, axis=1))[:, None]
    np.testing.assert_allclose(posed.quats * sign, player.quats, atol=2e-6)


def assert_centres_as_player(avatar: Avatar, player: Player, weights: dict[str, float],
                             poser: FastPoser | None = None) -> float:
    """pose(z) (and the FastPoser's means) against the player's centres, to 1e-5 of the head's size; returns the
    largest error in units of that size."""
    ref = player.centres(weights)
    size = float(np.linalg.norm(ref.max(axis=0) - ref.min(axis=0)))
    z = frame_vector(avatar, weights)
    means = avatar.pose(z).means
    err = float(np.abs(means - ref).max()) / size
    assert err <= 1e-5, f"pose(z) centres off by {err:.3g} of the head size"
    if poser is not None:
        dest = posed_buffers(len(avatar), 1, 0)
        assert poser.pose_into(z, dest)
        fast = float(np.abs(dest["means"] - ref).max()) / size
        assert fast <= 1e-5, f"FastPoser centres off by {fast:.3g} of the head size"
    return err


def random_weights(seed: int) -> dict[str, float]:
    """Weights for every ARKit name, many outside 0..1, and names no LAM skin has."""
    rng = np.random.default_rng(seed)
    w = {name: float(v) for name, v in zip(ARKIT_51, rng.uniform(-0.6, 1.8, len(ARKIT_51)), strict=True)}
    return {**w, "tongueOut": 0.9, "headYaw": 0.4, "notAShape": 7.0}
