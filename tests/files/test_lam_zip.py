"""LAM avatar zips: posed like LAM's own web player, loading facts, and hostile zips refused in one line.

The reference (`Player`) re-derives the posing of LAM's player, npm ``gaussian-splat-renderer-for-lam`` 0.0.8
(MIT), from reading ``build/gaussian-splat-renderer-for-lam.module.js`` (line numbers below), in numpy on the
zip's bytes (zipfile + pygltflib), without npga_core's rig, glTF or LAM code. It is compared with
`load_avatar(zip).pose(z)` and `FastPoser.pose_into` on zips written by tests/support/lam_layout.py and, where the
folder
named by $NPGA_LAM_DATA holds them, on real LAM zips driven by frames of real ARKit takes.
"""

from __future__ import annotations

import csv
import functools
import json
import os
import re
import struct
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.loading import load_avatar
from npga_core.model.avatar import Avatar
from npga_core.posing.fastpose import FastPoser
from tests.support.lam_layout import ARKIT_51, USHORT, glb_container, make_ply_columns, ply_bytes, write_lam_zip
from tests.support.lam_player import (
    DATA_ENV,
    MOTION_SCALE,
    Player,
    assert_centres_as_player,
    assert_static_as_player,
    lam_data,
    random_weights,
)

ROOT = Path(__file__).resolve().parents[2]
# -- written zips ----------------------------------------------------------------------------------------------
_SHUFFLED = list(ARKIT_51[:40])
np.random.default_rng(5).shuffle(_SHUFFLED)
VARIANTS: dict[str, dict[str, Any]] = {
    "head at rest": {},
    "head moved": {"move_head": True},
    "head moved, node matrices": {"move_head": True, "use_matrix": True},
    "all targets sparse, uint16 joints": {"dense_targets": 0, "joints_type": USHORT, "move_head": True},
    "40 ARKit names and a custom one": {"names": [*_SHUFFLED[:20], "customShape", *_SHUFFLED[20:]],
                                        "move_head": True},
    "head bone scaled unevenly (not rigid)": {"tamper_gltf": lambda g: setattr(
        next(n for n in g.nodes if n.name == "head"), "scale", [1.0, 1.3, 0.8])},
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_written_zip_poses_as_lam_player(variant: str, tmp_path: Path) -> None:
    """pose(z) and FastPoser on a written LAM zip match the re-derived player, weights outside 0..1 included."""
    path = write_lam_zip(tmp_path / "small.zip", **VARIANTS[variant])
    player, avatar = Player(path), load_avatar(path)
    if VARIANTS[variant].get("move_head") or "tamper_gltf" in VARIANTS[variant]:
        assert np.abs(player.head - np.eye(4)).max() > 0.05  # a real rigid transform, not the identity
    else:
        assert np.abs(player.head - np.eye(4)).max() < 1e-5
    assert_static_as_player(avatar, player)
    poser = FastPoser(avatar, threads=2)
    for seed in range(3):
        weights = random_weights(seed)
        assert np.abs(player.centres(weights) - player.centres({})).max() > 1e-3  # the weights do move splats
        assert_centres_as_player(avatar, player, weights, poser)
    assert_centres_as_player(avatar, player, {"jawOpen": 1.0, "mouthShrugUpper": -2.0}, poser)
    assert_centres_as_player(avatar, player, {}, poser)


def test_two_head_joints_use_the_last_as_the_player(tmp_path: Path) -> None:
    """A skin with two joints named 'head' (the neck renamed): the player moves the splats by the last one."""

    def rename_neck(g: pygltflib.GLTF2) -> None:
        next(n for n in g.nodes if n.name == "neck").name = "head"

    path = write_lam_zip(tmp_path / "two_heads.zip", move_head=True, tamper_gltf=rename_neck)
    player, avatar = Player(path), load_avatar(path)
    assert np.abs(player.head - np.eye(4)).max() > 0.05
    assert_centres_as_player(avatar, player, random_weights(1))


def _huge_jaw_delta(arrays: dict[str, Any]) -> None:
    arrays["targets"][arrays["names"].index("jawOpen")][1][0] = 3e38


def _scaled_root(g: pygltflib.GLTF2) -> None:
    next(n for n in g.nodes if n.name == "Female.003").scale = [1e6] * 3  # after the inverse binds: head x 1e8


@pytest.mark.parametrize("case", ["morph delta of 3e38", "head matrix scaling by 1e8"])
def test_out_of_range_rig_refused_or_bounded(case: str, tmp_path: Path) -> None:
    """A skin whose morph deltas or head matrix throw splats beyond the scene's range (the bound POSITION and
    offset.ply have) is refused in one line, or at least poses to finite centres within that range at weights of
    -2..2."""
    kw = {"tamper_arrays": _huge_jaw_delta} if case.startswith("morph") else {"tamper_gltf": _scaled_root}
    path = write_lam_zip(tmp_path / "far.zip", n=60, **kw)
    try:
        avatar = load_avatar(path)
    except AvatarFileError as e:
        assert "\n" not in str(e) and str(path) in str(e)
        return
    for w in (-2.0, 1.0, 2.0):
        with np.errstate(all="ignore"):
            means = avatar.pose(np.full(avatar.code_dim, w, np.float32)).means
        assert np.isfinite(means).all() and np.abs(means).max() <= 1e4, (w, float(np.abs(means).max()))


def test_written_zip_loading_facts(tmp_path: Path) -> None:
    """51 channels in ARKit order, the basis over the same names, the player's scales in the rig."""
    path = write_lam_zip(tmp_path / "small.zip")
    avatar = load_avatar(path)
    assert len(avatar) == 300 and len(avatar.rig.channels) == 51 == avatar.code_dim
    assert set(avatar.rig.channels) == set(ARKIT_51)
    assert list(avatar.rig.channels) == list(ARKIT_51)  # ARKit's order, not the skin's shuffled one
    assert tuple(avatar.blendshapes.names) == tuple(avatar.rig.channels)
    scale = dict(zip(avatar.rig.channels, avatar.rig.scale.tolist(), strict=True))
    assert scale["jawOpen"] == pytest.approx(1.2) and scale["mouthShrugUpper"] == pytest.approx(0.1)
    assert {k: v for k, v in scale.items() if v != 1.0} == pytest.approx(MOTION_SCALE)


def _optional(name: str) -> Path | None:
    root = os.environ.get(DATA_ENV)
    path = Path(root) / name if root else None
    return path if path is not None and path.is_file() else None


def _picks(count: int, column: np.ndarray) -> list[int]:
    """Five frames: spread over the take, and the one with the widest-open jaw."""
    return sorted({0, count // 3, 2 * count // 3, count - 1, int(np.argmax(column))})


@functools.cache
def take_frames() -> tuple[tuple[str, dict[str, float]], ...]:
    """Frames of the real takes present: LAM's A2E JSON and a Live Link Face CSV (PascalCase -> camelCase)."""
    out: list[tuple[str, dict[str, float]]] = []
    if p := _optional("test_expression_1s.json"):
        doc = json.loads(p.read_text())
        names, frames = doc["names"], doc["frames"]
        jaw = np.array([f["weights"][names.index("jawOpen")] for f in frames])
        for i in _picks(len(frames), jaw):
            out.append((f"{p.name} frame {i}", dict(zip(names, map(float, frames[i]["weights"]), strict=True))))
    if p := _optional("alex_rom_3.csv"):
        with p.open(newline="") as fh:
            rows = list(csv.reader(fh))
        header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
        names = [h[0].lower() + h[1:] for h in header]
        cols = [i for i, h in enumerate(header) if h not in ("Timecode", "BlendShapeCount")]
        jaw = np.array([float(r[header.index("JawOpen")]) for r in body])
        for i in _picks(len(body), jaw):
            out.append((f"{p.name} row {i}", {names[c]: float(body[i][c]) for c in cols}))
    return tuple(out)


@functools.cache
def real(name: str) -> tuple[Avatar, Player]:
    path = lam_data(name)
    return load_avatar(path), Player(path)


REAL = ["p2-1.zip", "james.zip", "status.zip"]


@pytest.mark.parametrize("name", REAL)
def test_real_zip_poses_as_lam_player(name: str) -> None:
    """A real LAM zip under frames of real takes (and random weights) matches the re-derived player: pose(z)
    and the FastPoser."""
    avatar, player = real(name)
    assert np.abs(player.head - np.eye(4)).max() < 1e-4  # the real head bone: world x inverse bind ~ identity
    assert_static_as_player(avatar, player)
    poser = FastPoser(avatar, threads=2)
    frames = [*take_frames(), ("random", random_weights(7))]
    for label, weights in frames:
        try:
            assert_centres_as_player(avatar, player, weights, poser)
        except AssertionError as e:
            raise AssertionError(f"{name}, {label}: {e}") from None
    jaw = [w for label, w in frames if "jawOpen" in w and label != "random"]
    if jaw:  # the takes' frames do open the jaw
        widest = max(jaw, key=lambda w: w["jawOpen"])
        assert np.abs(player.centres(widest) - player.centres({})).max() > 1e-3


@pytest.mark.parametrize("name", REAL)
def test_real_zip_loading_facts(name: str) -> None:
    """51 ARKit channels, one Gaussian per PLY vertex (p2-1: 20,018), the player's scales."""
    avatar, player = real(name)
    assert len(avatar) == player.n and len(avatar.rig.channels) == 51
    if name == "p2-1.zip":
        assert len(avatar) == 20_018
    assert set(avatar.rig.channels) == set(ARKIT_51)
    assert tuple(avatar.blendshapes.names) == tuple(avatar.rig.channels)
    scale = dict(zip(avatar.rig.channels, avatar.rig.scale.tolist(), strict=True))
    assert scale["jawOpen"] == pytest.approx(1.2) and scale["mouthShrugUpper"] == pytest.approx(0.1)


# -- hostile zips ----------------------------------------------------------------------------------------------
def _small(path: Path, **kw: Any) -> Path:
    return write_lam_zip(path, n=60, **kw)


def _members(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(zipfile.ZipInfo(name), data)
    return path


def _good_members(path: Path) -> dict[str, bytes]:
    """skin.glb and offset.ply of a small valid zip."""
    src = _small(path.with_name(path.stem + "_src.zip"))
    with zipfile.ZipFile(src) as z:
        return {"skin.glb": z.read("avatar/skin.glb"), "offset.ply": z.read("avatar/offset.ply")}


def _patch_size(path: Path, member: str, size: int, compressed: bool) -> Path:
    """Claim `size` bytes for `member` in the central directory and the local header (sizes patched in place)."""
    data = bytearray(path.read_bytes())
    eocd = data.rindex(b"PK\x05\x06")
    entries, _, pos = struct.unpack_from("<HII", data, eocd + 10)
    for _ in range(entries):
        fields = struct.unpack_from("<4s6H3I5HII", data, pos)
        nlen, xlen, clen, local = fields[10], fields[11], fields[12], fields[16]
        if data[pos + 46 : pos + 46 + nlen].decode() == member:
            struct.pack_into("<I", data, pos + 24, size)
            struct.pack_into("<I", data, local + 22, size)
            if compressed:
                struct.pack_into("<I", data, pos + 20, size)
                struct.pack_into("<I", data, local + 18, size)
        pos += 46 + nlen + xlen + clen
    path.write_bytes(bytes(data))
    return path


def _targets(change: Callable[[list], None]) -> Callable[[dict[str, Any]], None]:
    def f(arrays: dict[str, Any]) -> None:
        change(arrays["targets"])
    return f


def _nan_sparse(t: list) -> None:
    t[0][1][1, 1] = np.nan


def _nan_dense(t: list) -> None:
    t[-1][1][0, 2] = np.nan


def _index_out_of_range(t: list) -> None:
    t[0][0][-1] = 60 + 3


def _indices_descending(t: list) -> None:
    t[0] = (t[0][0][::-1].copy(), t[0][1])


def _node(g: pygltflib.GLTF2, name: str) -> pygltflib.Node:
    return next(n for n in g.nodes if n.name == name)


def _index(g: pygltflib.GLTF2, name: str) -> int:
    return next(i for i, n in enumerate(g.nodes) if n.name == name)


def _cycle(g: pygltflib.GLTF2) -> None:
    """neck -> head -> neck, cut off from the root."""
    _node(g, "abdomen").children = []
    _node(g, "head").children = [*_node(g, "head").children, _index(g, "neck")]


def _own_child(g: pygltflib.GLTF2) -> None:
    _node(g, "head").children = [*_node(g, "head").children, _index(g, "head")]


def _no_head(g: pygltflib.GLTF2) -> None:
    _node(g, "head").name = "Head"


def _fewer_names(g: pygltflib.GLTF2) -> None:
    g.meshes[0].extras["targetNames"] = g.meshes[0].extras["targetNames"][:-1]


def _position_offset(g: pygltflib.GLTF2) -> None:
    g.accessors[g.meshes[0].primitives[0].attributes.POSITION].byteOffset = 2**31


def _sparse_view_past(g: pygltflib.GLTF2) -> None:
    acc = g.accessors[g.meshes[0].primitives[0].targets[0]["POSITION"]]
    g.bufferViews[acc.sparse.values.bufferView].byteLength = 10**8


def _ibm_count(g: pygltflib.GLTF2) -> None:
    g.accessors[g.skins[0].inverseBindMatrices].count = 5_000


def _sparse_count(g: pygltflib.GLTF2) -> None:
    g.accessors[g.meshes[0].primitives[0].targets[0]["POSITION"]].sparse.count = 10**6


def _nested(depth: int) -> bytes:
    return glb_container(b'{"asset":{"version":"2.0"},"extras":' + b"[" * depth + b"]" * depth + b"}")


def _two_avatars(path: Path) -> Path:
    good = _good_members(path)
    return _members(path, {"a/": b"", "b/": b"", **{f"{d}/{k}": v for d in "ab" for k, v in good.items()}})


def _many(path: Path) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        z.writestr(zipfile.ZipInfo("avatar/"), b"")
        for i in range(100_000):
            z.writestr(zipfile.ZipInfo(f"avatar/{i}"), b"")
    return path


def _truncated(path: Path) -> Path:
    _small(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


_rng = np.random.default_rng(11)
#: name -> (writer of the hostile zip at a path, what the one-line message must say: a regex)
HOSTILE: dict[str, tuple[Callable[[Path], Path], str]] = {
    "traversal ../": (lambda p: _members(p, {"../evil/": b"", **{f"../evil/{k}": v for k, v in
                                                                 _good_members(p).items()}}), "plain relative path"),
    "absolute member names": (lambda p: _members(p, {"/abs/": b"", **{f"/abs/{k}": v for k, v in
                                                                      _good_members(p).items()}}),
                              "plain relative path"),
    "member claims 4 GB": (lambda p: _patch_size(_small(p, compression=zipfile.ZIP_STORED), "avatar/offset.ply",
                                                 4_000_000_000, compressed=False), "claims 4,000,000,000 bytes"),
    "member claims 4 GB (both sizes)": (lambda p: _patch_size(_small(p, compression=zipfile.ZIP_STORED),
                                                              "avatar/skin.glb", 4_000_000_000, compressed=True),
                                        "claims 4,000,000,000 bytes"),
    "member inflates past its claim": (lambda p: _patch_size(_small(p), "avatar/skin.glb", 100, compressed=False),
                                       "holds|CRC|not a readable zip|unreadable zip"),
    "100,000 members": (_many, r"100001 members, more than"),
    "two avatar folders": (_two_avatars, "2 LAM avatars"),
    "not a LAM avatar": (lambda p: _members(p, {"model/": b"", "model/mesh.obj": b"v 0 0 0\n",
                                                "model/readme.txt": b"hello"}), "not a LAM avatar"),
    "truncated zip": (_truncated, "not a readable zip|unreadable zip archive"),
    "POSITION byteOffset past its buffer view": (lambda p: _small(p, tamper_gltf=_position_offset),
                                                 "POSITION.*past the end"),
    "sparse values' buffer view past the binary chunk": (lambda p: _small(p, tamper_gltf=_sparse_view_past),
                                                         "bufferView \\d+ ends at byte"),
    "inverseBindMatrices count past its buffer view": (lambda p: _small(p, tamper_gltf=_ibm_count),
                                                       "inverseBindMatrices"),
    "sparse count larger than the accessor": (lambda p: _small(p, tamper_gltf=_sparse_count), "sparse count"),
    "sparse index out of range": (lambda p: _small(p, tamper_arrays=_targets(_index_out_of_range)),
                                  "sparse indices"),
    "sparse indices descending": (lambda p: _small(p, tamper_arrays=_targets(_indices_descending)),
                                  "sparse indices"),
    "targets and targetNames differ in count": (lambda p: _small(p, tamper_gltf=_fewer_names), "targetNames"),
    "NaN in a sparse morph delta": (lambda p: _small(p, tamper_arrays=_targets(_nan_sparse)), "NaN"),
    "NaN in a dense morph delta": (lambda p: _small(p, tamper_arrays=_targets(_nan_dense)), "NaN"),
    "NaN in offset.ply": (lambda p: _small(p, tamper_ply=lambda c: c["x"].__setitem__(7, np.nan)), "NaN"),
    "offset.ply one row short of the mesh": (lambda p: _small(p, tamper_ply=lambda c: c.update(
        {k: v[:-1] for k, v in c.items()})), "59 Gaussians.*60 vertices"),
    "no joint named head": (lambda p: _small(p, tamper_gltf=_no_head), "'head'"),
    "garbage skin.glb": (lambda p: _small(p, skin=_rng.bytes(5000)), "skin.glb.*glTF"),
    "glTF signature then garbage": (lambda p: _small(p, skin=b"glTF" + struct.pack("<II", 2, 5012)
                                                     + _rng.bytes(5000)), "skin.glb"),
    "JSON nested 100,000 deep": (lambda p: _small(p, skin=_nested(100_000)), "skin.glb.*nested|skin.glb.*readable"),
    "node tree with a cycle": (lambda p: _small(p, tamper_gltf=_cycle), "cycle|two parents"),
    "node that is its own child": (lambda p: _small(p, tamper_gltf=_own_child), "own child|cycle"),
    "garbage offset.ply": (lambda p: _small(p, ply=b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\n"
                                              b"property float x\nend_header\n" + bytes(64)), "offset.ply"),
    "offset.ply cut short": (lambda p: _small(p, ply=ply_bytes(make_ply_columns(60))[:-100]), "offset.ply"),
    "empty skin.glb": (lambda p: _small(p, skin=b""), "skin.glb"),
}


@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every hostile zip, written once."""
    folder = tmp_path_factory.mktemp("hostile_lam")
    return {name: make(folder / f"case{i:02d}.zip") for i, (name, (make, _)) in enumerate(HOSTILE.items())}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_zip_is_one_line_error(case: str, hostile: dict[str, Path]) -> None:
    """load_avatar refuses each hostile zip with an AvatarFileError of one line naming the zip, for its reason."""
    path = hostile[case]
    with pytest.raises(AvatarFileError) as info:
        load_avatar(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text, text
    assert re.search(HOSTILE[case][1], text, re.IGNORECASE), text


@pytest.fixture(scope="module")
def cli(tmp_path_factory: pytest.TempPathFactory):
    """The project's fork server (tests/support/cli_forkserver.py): `npga-view` runs in a forked child per call."""
    from tests.support.cli_forkserver import ForkServer

    folder = tmp_path_factory.mktemp("lam_cli")
    server = ForkServer(folder, env={"DISPLAY": "", "WAYLAND_DISPLAY": "", "XDG_CONFIG_HOME": str(folder / "cfg"),
                                     "XDG_CACHE_HOME": str(folder / "cache")})
    yield server, folder
    server.close()


@pytest.mark.slow
def test_hostile_zips_through_npga_view_info(hostile: dict[str, Path], cli) -> None:
    """`npga-view info BAD.zip` (a forked child per zip, 1 GiB address-space limit): exit 2, one line on stderr
    naming the zip, no traceback."""
    server, folder = cli
    failures = []
    for i, (case, path) in enumerate(hostile.items()):
        out, err = folder / f"{i}.out", folder / f"{i}.err"
        reply = server.run({"argv": ["info", str(path)], "stdout": str(out), "stderr": str(err), "limit_mb": 1024,
                            "timeout": 60})
        text = err.read_text(errors="replace")
        lines = [line for line in text.splitlines() if line.strip()]
        if (reply["exit"] != 2 or len(lines) != 1 or str(path) not in lines[0] or "Traceback" in text):
            failures.append(f"{case}: {reply} {text[-400:]!r}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("case", ["written zip", "traversal ../"])
def test_npga_view_info_console(case: str, hostile: dict[str, Path], tmp_path: Path) -> None:
    """`python -m npga_view.cli.main info` in a fresh process: the Gaussian count for a LAM zip (exit 0); exit 2
    and one line for a hostile one."""
    path = write_lam_zip(tmp_path / "small.zip") if case == "written zip" else hostile[case]
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "info", str(path)], capture_output=True,
                       text=True, timeout=120, cwd=ROOT, env={**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert "Traceback" not in r.stderr, r.stderr
    if case == "written zip":
        assert r.returncode == 0, r.stderr
        assert re.search(r"gaussians:\s*300\b", r.stdout), r.stdout
    else:
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and str(path) in r.stderr, r.stderr


def test_info_says_when_the_player_could_not_load_the_zip(tmp_path: Path) -> None:
    """A zip without animation.glb and vertex_order.json opens here, and the rig's notes (printed by `info`) say
    that LAM's player needs them (it fails on vertex_order.json, and never draws without clips)."""
    full = load_avatar(write_lam_zip(tmp_path / "full.zip", n=60))
    assert full.rig is not None and "player" not in full.rig.notes
    bare = load_avatar(write_lam_zip(tmp_path / "bare.zip", n=60, extras=False))
    assert bare.rig is not None and "animation.glb and vertex_order.json" in bare.rig.notes["player"]
