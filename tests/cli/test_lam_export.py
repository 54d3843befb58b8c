"""`npga-view export AVATAR --format lam-zip`: LAM web avatar zips that our reader and an independent re-derivation
of LAM's player (`Player` in tests/support/lam_player.py) read back as exported; exact for linear rigs, fitted
(and measured) for neural avatars; hostile targets and avatars beyond the player's capacity refused in one line."""

from __future__ import annotations

import json
import os
import stat
import zipfile
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from npga_core.files import lam_export
from npga_core.files.checkpoint import save_avatar
from npga_core.files.gltf_arrays import GltfArrays
from npga_core.files.lam import PLAYER_SCALE
from npga_core.files.loading import load_avatar
from npga_core.model.avatar import Avatar
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing import lam_fit
from npga_view.cli.main import main
from tests.support.lam_layout import ARKIT_51, PLY_PROPERTIES, write_lam_zip
from tests.support.lam_player import SH_C0, Player, lam_data, random_weights


def _weights(avatar: Avatar, w: dict[str, float]) -> np.ndarray:
    return np.array([w.get(c, 0.0) for c in avatar.rig.channels], np.float32)


def _size(c: np.ndarray) -> float:
    return float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))


def _export(src: Path, out: Path, *extra: str) -> int:
    return main(["export", str(src), "--format", "lam-zip", "--out", str(out), *extra])


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> tuple[Path, Path]:
    """A written LAM zip (head bone moved away from its bind pose: a non-identity rest transform) and its export."""
    folder = tmp_path_factory.mktemp("lam_export")

    def one_target_everywhere(arrays: dict) -> None:  # a target moving every vertex is written dense
        arrays["targets"][0] = (np.arange(300), np.full((300, 3), 1e-3, np.float32))

    src = write_lam_zip(folder / "src.zip", n=300, move_head=True, tamper_arrays=one_target_everywhere)
    out = folder / "web.zip"
    assert _export(src, out) == 0
    return src, out


# -- exact: rigs -----------------------------------------------------------------------------------------------
def test_exported_rig_reads_back_to_the_same_avatar(small) -> None:
    """Our reader poses the exported zip as the source at random weights (outside 0..1 too): centres to 1e-5 of
    the head size; colours within 1/255, opacity, scales, rotations as stored."""
    a, b = load_avatar(small[0]), load_avatar(small[1])
    assert a.rig.channels == b.rig.channels and len(a) == len(b)
    for seed in range(4):
        w = random_weights(seed)
        pa, pb = a.pose(_weights(a, w)), b.pose(_weights(b, w))
        assert np.abs(pa.means - pb.means).max() <= 1e-5 * _size(pa.means)
        assert np.abs(pa.sh[:, 0] - pb.sh[:, 0]).max() * SH_C0 <= 1 / 255
        np.testing.assert_allclose(pb.opacities, pa.opacities, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(pb.scales, pa.scales, rtol=1e-5)
        np.testing.assert_allclose(np.abs(np.sum(pa.quats * pb.quats, axis=1)), 1.0, atol=1e-5)


def test_lam_player_draws_the_export_as_the_source(small) -> None:
    """The re-derived player (zip bytes, pygltflib, numpy; not our reader) draws the same centres, 8-bit colours
    and opacities for the exported zip as for the source: the player's weight scales are divided out."""
    ps, pe = Player(small[0]), Player(small[1])
    assert np.abs(pe.head - np.eye(4)).max() < 1e-6  # rest pose = bind pose
    for seed in range(3):
        w = random_weights(seed)
        ref = ps.centres(w)
        assert np.abs(pe.centres(w) - ref).max() <= 1e-5 * _size(ref)
    assert np.abs(pe.rgb8 - ps.rgb8).max() <= 1
    assert np.abs(pe.opacity8 - ps.opacity8).max() <= 1
    np.testing.assert_allclose(pe.scales, ps.scales, rtol=1e-5)


def test_written_members_are_what_the_player_loads(small) -> None:
    """One directory entry (the player's folder), offset.ply in the real layout, a skinned TRIANGLES mesh with
    JOINTS_0/WEIGHTS_0, the 51 ARKit targets by name (sparse where smaller), hip and head bones, no clip in
    skin.glb, 12 chat-state clips in animation.glb, vertex_order a permutation, a README saying what is lost."""
    with zipfile.ZipFile(small[1]) as z:
        infos = z.infolist()
        data = {i.filename: z.read(i) for i in infos}
    dirs = [i.filename for i in infos if i.is_dir()]
    assert dirs == ["web/"] and infos[0].filename == "web/"
    assert set(data) == {"web/", *(f"web/{m}" for m in ("offset.ply", "skin.glb", "animation.glb",
                                                         "vertex_order.json", "README.txt"))}
    header = data["web/offset.ply"].split(b"end_header\n")[0].decode().splitlines()
    assert [h.split()[2] for h in header if h.startswith("property")] == list(PLY_PROPERTIES)
    assert "element vertex 300" in header
    g = pygltflib.GLTF2.load_from_bytes(data["web/skin.glb"])
    assert not g.animations
    (node,) = [n for n in g.nodes if n.mesh is not None]
    assert node.skin == 0
    prim = g.meshes[0].primitives[0]
    assert prim.mode == 4 and prim.attributes.JOINTS_0 is not None and prim.attributes.WEIGHTS_0 is not None
    assert g.accessors[prim.indices].count % 3 == 0
    assert sorted(g.meshes[0].extras["targetNames"]) == sorted(ARKIT_51)
    kinds = [g.accessors[t["POSITION"]].sparse is not None for t in prim.targets]
    assert kinds.count(False) == 1  # the one target moving every vertex is dense, the others sparse
    names = [n.name for n in g.nodes]
    assert "hip" in names and [names[j] for j in g.skins[0].joints] == ["hip", "head"]
    arrays = GltfArrays(g)
    ibm = arrays.accessor(g.skins[0].inverseBindMatrices, "ibm", ("MAT4",))[1].reshape(4, 4).T
    assert np.array_equal(arrays.world_matrix(names.index("head"), arrays.parents()) @ ibm, np.eye(4))
    clips = pygltflib.GLTF2.load_from_bytes(data["web/animation.glb"]).animations
    assert len(clips) == 12 and clips[2].name == "idle_1"
    assert sorted(json.loads(data["web/vertex_order.json"])) == list(range(300))
    readme = data["web/README.txt"].decode()
    assert "exact" in readme and "spherical harmonics above degree 0" in readme


def test_deltas_are_stored_divided_by_the_player_scale(small) -> None:
    """jawOpen (x1.2 in the player) and mouthShrugUpper (x0.1): the glTF delta is the displacement per unit
    weight divided by the player's scale, so w means the same in the browser."""
    ps, pe = Player(small[0]), Player(small[1])
    for name in ("jawOpen", "mouthShrugUpper", "eyeBlinkLeft"):
        moved = pe.centres({name: 1.0}) - pe.centres({})
        stored = pe.deltas[pe.dictionary[name]] @ pe.head[:3, :3].T
        np.testing.assert_allclose(moved, stored * PLAYER_SCALE.get(name, 1.0), atol=1e-7)
        np.testing.assert_allclose(moved, ps.centres({name: 1.0}) - ps.centres({}), atol=2e-6)


def test_any_rig_is_exported_exactly() -> None:
    """A rig on the Gaussians themselves with ICT-style names (eyeBlink_L, browInnerUp split into halves), its own
    runtime scales and bias, a basis with an offset, a rest transform (turn, scale, shift) and a head far from
    LAM's: the export, at ARKit weights, draws the source's centres moved by the reported translation."""
    from npga_core.model.dynamics import Dynamics
    from npga_core.model.linear_rig import LinearRig
    from npga_core.model.rotations import matrix_from_rotvec

    rng = np.random.default_rng(4)
    cloud = make_synthetic_avatar(400, with_f=False, with_g=False, sh_degree=0, seed=4).cloud
    channels = ("eyeBlink_L", "eyeBlink_R", "jawOpen", "browInnerUp_L", "browInnerUp_R", "mouthClose", "notArkit")
    support = np.sort(rng.choice(400, 250, replace=False))
    m = np.eye(4)
    m[:3, :3] = 1.3 * matrix_from_rotvec(np.array([0.2, -0.4, 0.1]))
    m[:3, 3] = [0.3, -0.2, 0.1]
    rig = LinearRig(channels, support, rng.normal(0, 3e-3, (7, 250, 3)), 400, scale=rng.uniform(0.5, 2, 7),
                    bias=rng.normal(0, 0.2, 7), transform=m)
    basis = BlendshapeBasis(channels, np.diag(rng.uniform(0.5, 1.5, 7)) + 0.1 * rng.normal(size=(7, 7)),
                            rng.normal(0, 0.3, 7))
    avatar = Avatar(cloud, Dynamics(networks={}, rig=rig), blendshapes=basis)
    names = lam_fit.target_names(avatar)
    web, shift = lam_fit.exact_web_avatar(avatar, names)
    assert np.linalg.norm(shift) > 1.0  # moved to where the player looks
    for seed in range(3):
        w = random_weights(seed)
        arkit = np.array([[w.get(n, 0.0) for n in names]])
        ref = avatar.pose(lam_fit.frame_vectors(avatar, names, arkit)[0]).means
        assert np.abs(web.centres(w) - shift - ref).max() <= 1e-5 * _size(ref)
    assert "notArkit" in web.notes["export"]  # a channel no ARKit name drives is said to be left out


def test_fitting_a_linear_rig_recovers_its_deltas(tmp_path) -> None:
    """The fit, run on an avatar that IS linear (a LAM rig), recovers the exact deltas from the generated
    frames (up to the small ridge's bias): its held-out error is under 1e-5 of the head size."""
    avatar = load_avatar(write_lam_zip(tmp_path / "src.zip", n=200))
    names = lam_fit.target_names(avatar)
    train, test = lam_fit.plan_frames([], None, names, 120, 40)
    centres = lam_fit.Centres(avatar, names)
    web, shift, info = lam_fit.fit_web_avatar(avatar, names, train, centres)
    exact, _ = lam_fit.exact_web_avatar(avatar, names)
    assert info["frames"] == 120 and not info["channels_never_moved_in_training"]
    assert np.abs(web.deltas - exact.deltas).max() < 1e-3 * np.abs(exact.deltas).max()  # the ridge's bias
    fid = lam_fit.measure(web, shift, centres, test)
    assert fid["frames"] == 40 and fid["p99_of_head"] < 1e-5


# -- fitted: neural avatars ------------------------------------------------------------------------------------
NAMES_USED = ARKIT_51[:30]


def neural_avatar(seed: int = 5) -> Avatar:
    """A small synthetic F/G avatar with a random ARKit blendshape basis over 30 names (colour, scale, opacity,
    rotation and SH degree 1 moved by G)."""
    a = make_synthetic_avatar(500, code_dim=12, hidden=48, depth=3, n_components=6, sh_degree=1, seed=seed)
    rng = np.random.default_rng(seed)
    a.blendshapes = BlendshapeBasis(NAMES_USED, rng.normal(0, 1.5, (12, len(NAMES_USED))), rng.normal(0, 0.3, 12),
                                    source="test")
    return a


@pytest.fixture(scope="module")
def neural(tmp_path_factory) -> tuple[Avatar, Path, Path]:
    folder = tmp_path_factory.mktemp("neural")
    avatar = neural_avatar()
    src = folder / "neural.npga"
    save_avatar(avatar, src)
    out = folder / "neural.zip"
    assert _export(src, out, "--frames", "120") == 0
    return avatar, src, out


def test_fitted_export_reads_back_as_measured(neural) -> None:
    """Our reader and the re-derived player pose the fitted zip the same (what fidelity.json measured is what the
    file holds); at zero weights the export is the avatar's exact neutral centres, moved into LAM's frame."""
    avatar, _, out = neural
    doc = json.loads(out.with_name("neural.fidelity.json").read_text())
    shift = np.asarray(doc["translation_m"])
    assert doc["export"] == "fitted" and np.linalg.norm(shift) > 1.0  # a head at the origin goes to y 1.65
    back, player = load_avatar(out), Player(out)
    names = lam_fit.target_names(avatar)
    neutral = lam_fit.Centres(avatar, names)(np.zeros(len(names)))
    assert np.abs(back.pose(np.zeros(51, np.float32)).means - (neutral + shift)).max() < 1e-6
    w = random_weights(3)
    ours = back.pose(_weights(back, w)).means
    assert np.abs(ours - player.centres(w)).max() < 1e-6
    # colours (degree-1 SH baked as seen from 1 m in front of the head), opacity, scales at the neutral expression
    z0 = lam_fit.frame_vectors(avatar, names, np.zeros((1, len(names))))[0]
    posed = avatar.pose(z0)
    eye = (posed.means.max(axis=0) + posed.means.min(axis=0)) / 2 + [0.0, 0.0, 1.0]
    d = posed.means - eye
    x, y, z = (d / np.linalg.norm(d, axis=1, keepdims=True)).T[:, :, None]
    c1 = 0.4886025119029199
    sh = posed.sh
    rgb = np.clip(0.5 + SH_C0 * sh[:, 0] - c1 * y * sh[:, 1] + c1 * z * sh[:, 2] - c1 * x * sh[:, 3], 0, 1)
    assert np.abs(player.rgb8 / 255 - rgb).max() <= 1 / 255 + 1e-5
    assert np.abs(rgb - np.clip(0.5 + SH_C0 * sh[:, 0], 0, 1)).max() > 2 / 255  # the bake is not the DC colour
    np.testing.assert_allclose(player.scales, posed.scales, rtol=1e-4)


def test_fitted_fidelity_is_reported(neural) -> None:
    """fidelity.json: held-out generated frames, RMS <= p99 <= max, well under how far the centres move, and in
    units of the head size; the channels the basis lacks are reported as never moving."""
    avatar, _, out = neural
    doc = json.loads(out.with_name("neural.fidelity.json").read_text())
    fid = doc["held_out"]
    assert fid["frames"] == 60 and "seed 1" in fid["frames_from"]  # generated apart from the training frames
    assert 0 < fid["rms_m"] <= fid["p99_m"] <= fid["max_m"]
    assert fid["rms_m"] < 0.5 * fid["motion_rms_m"]
    assert fid["rms_of_head"] == pytest.approx(fid["rms_m"] / fid["head_size_m"])
    assert doc["fit"]["frames"] == 120 and "unit activations" in doc["fit"]["frames_from"]
    assert set(doc["fit"]["channels_never_moved_in_training"]) == set()  # generated frames move every channel
    assert "CNN" in doc["lost"] and "spherical harmonics above degree 0" in doc["lost"]
    with zipfile.ZipFile(out) as z:
        readme = z.read("neural/README.txt").decode()
    assert "fitted" in readme and "held-out centre error" in readme and "CNN" in readme


def test_fitted_export_prints_what_is_lost(neural, tmp_path, capsys) -> None:
    _, src, _ = neural
    capsys.readouterr()
    assert _export(src, tmp_path / "x.zip", "--frames", "60") == 0
    printed = capsys.readouterr().out
    assert "fitted on 60 frames" in printed and "held-out centre error" in printed and "lost:" in printed


def test_frames_from_takes(tmp_path) -> None:
    """One take: its first 80% trains, its last 20% is held out; two takes: the last is held out; a take that
    names no ARKit shape is one line."""
    names = tuple(ARKIT_51)
    header = "Timecode,BlendShapeCount," + ",".join(n[0].upper() + n[1:] for n in names)
    rows = [f"00:00:{i // 30:02d}:{i % 30:02d}.000,51," + ",".join(f"{(i * 7 + k) % 10 / 10:.2f}"
                                                                 for k in range(51)) for i in range(100)]
    take = tmp_path / "take.csv"
    take.write_text(header + "\n" + "\n".join(rows) + "\n")
    train, test = lam_fit.plan_frames([str(take)], None, names, 1000, 1000)
    assert len(train.weights) == 80 and len(test.weights) == 20 and "last 20%" in test.label
    np.testing.assert_allclose(train.weights[5], [(5 * 7 + k) % 10 / 10 for k in range(51)], atol=1e-6)
    train, test = lam_fit.plan_frames([str(take), "generated", str(take)], None, names, 90, 10)
    assert len(test.weights) == 10 and test.label == str(take) and "generated" in train.label
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"names": ["foo", "bar"], "frames": [{"weights": [0, 1], "time": 0}]}))
    from npga_core.errors import AvatarFileError

    with pytest.raises(AvatarFileError):
        lam_fit.plan_frames([str(bad)], None, names, 100, 10)


# -- refusals --------------------------------------------------------------------------------------------------
def _one_line_exit_2(argv: list[str], capsys) -> str:
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_hostile_targets_are_refused(small, tmp_path, capsys) -> None:
    """An existing folder, a path inside a file, a FIFO, a symlink, a missing folder, not .zip: one line, exit 2,
    nothing written; an existing regular file is replaced atomically (no temp file left)."""
    src = small[0]
    (tmp_path / "folder.zip").mkdir()
    (tmp_path / "file").write_bytes(b"x")
    os.mkfifo(tmp_path / "fifo.zip")
    (tmp_path / "link.zip").symlink_to(tmp_path / "elsewhere.zip")
    cases = {"folder.zip": "existing folder", "file/x.zip": "not a folder", "fifo.zip": "not a regular file",
             "link.zip": "symbolic link", "nowhere/x.zip": "does not exist", "x.ply": ".zip"}
    before = sorted(p.name for p in tmp_path.iterdir())
    for target, words in cases.items():
        line = _one_line_exit_2(["export", str(src), "--format", "lam-zip", "--out", str(tmp_path / target)], capsys)
        assert words in line and target.split("/")[0] in line
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    fifo_report = tmp_path / "r.zip"
    os.mkfifo(tmp_path / "r.fidelity.json")
    assert "fidelity report" in _one_line_exit_2(["export", str(src), "--format", "lam-zip", "--out",
                                                  str(fifo_report)], capsys)
    assert not fifo_report.exists()
    old = tmp_path / "old.zip"
    old.write_bytes(b"old")
    assert _export(src, old) == 0 and zipfile.is_zipfile(old)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_one_line(small, tmp_path, capsys) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        line = _one_line_exit_2(["export", str(small[0]), "--format", "lam-zip", "--out", str(folder / "x.zip")],
                                capsys)
        assert "x.zip" in line
    finally:
        folder.chmod(0o755)


def test_a_failing_write_is_one_line(small, tmp_path, capsys, monkeypatch) -> None:
    """A file system that refuses the write (a read-only folder for a non-root user, a full disk): one line."""
    def refuse(path, write) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(lam_export, "atomic_write", refuse)
    line = _one_line_exit_2(["export", str(small[0]), "--format", "lam-zip", "--out", str(tmp_path / "x.zip")],
                            capsys)
    assert "x.zip" in line and "Permission denied" in line


def test_beyond_the_player_capacity_is_one_line(small, tmp_path, capsys, monkeypatch) -> None:
    """N x (targets + 1) texels beyond the player's morph texture: refused before any fitting (here with the
    texture shrunk to 300 x 52 - 1 texels); 161,319 Gaussians at 51 targets fit, 161,320 do not."""
    lam_export.check_capacity(161_319, 51)
    with pytest.raises(lam_export.LamExportError, match="161,319"):
        lam_export.check_capacity(161_320, 51)
    monkeypatch.setattr(lam_export, "PLAYER_TEXELS", 300 * 52 - 1)
    line = _one_line_exit_2(["export", str(small[0]), "--format", "lam-zip", "--out", str(tmp_path / "x.zip")],
                            capsys)
    assert "15,600 texels" in line and not (tmp_path / "x.zip").exists()


def test_avatars_that_cannot_be_driven_are_one_line(tmp_path, capsys) -> None:
    """A static avatar (a PLY) and a neural avatar without a blendshape basis: one line each."""
    from npga_core.files.ply import save_ply

    a = neural_avatar()
    save_ply(a.cloud, tmp_path / "static.ply")
    a.blendshapes = None
    save_avatar(a, tmp_path / "nobasis.npga")
    for name, words in (("static.ply", "static"), ("nobasis.npga", "fit-blendshapes")):
        line = _one_line_exit_2(["export", str(tmp_path / name), "--format", "lam-zip", "--out",
                                 str(tmp_path / "x.zip")], capsys)
        assert words in line
    line = _one_line_exit_2(["export", "demo", "--format", "lam-zip", "--expr", "jawOpen=1", "--out",
                             str(tmp_path / "x.zip")], capsys)
    assert "--expr" in line


# -- the real LAM avatar ---------------------------------------------------------------------------------------
def test_real_p2_1_round_trips(tmp_path) -> None:
    """aigc3d/LAM_WebRender's p2-1.zip: import to .npga, export, read back: the same centres at random weights
    (<= 1e-5 of the head size, by our reader and by the re-derived player), colours within 1/255."""
    src = lam_data("p2-1.zip")
    npga = tmp_path / "p2-1.npga"
    assert main(["import", "lam", str(src), "--out", str(npga)]) == 0
    out = tmp_path / "p2-1.zip"
    assert _export(npga, out) == 0
    a, b = load_avatar(src), load_avatar(out)
    ps, pe = Player(src), Player(out)
    for seed in range(3):
        w = random_weights(seed)
        ref = ps.centres(w)
        size = _size(ref)
        assert np.abs(b.pose(_weights(b, w)).means - a.pose(_weights(a, w)).means).max() <= 1e-5 * size
        assert np.abs(pe.centres(w) - ref).max() <= 1e-5 * size
    assert np.abs(pe.rgb8 - ps.rgb8).max() <= 1 and np.abs(pe.opacity8 - ps.opacity8).max() <= 1
    doc = json.loads(out.with_name("p2-1.fidelity.json").read_text())
    assert doc["export"] == "exact" and doc["translation_m"] == [0.0, 0.0, 0.0]
    assert doc["held_out"]["max_m"] <= 1e-5 * doc["held_out"]["head_size_m"]
