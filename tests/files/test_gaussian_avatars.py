"""GaussianAvatars avatars posed by FLAME (#37), against a forward written here from reading their code.

The reference below is this test's own reading of ShenhanQian/GaussianAvatars (CC BY-NC-SA; read, not copied):
`flame_model/flame.py` FlameHead.forward (lines 485-558: betas = [shape, expr] at 511, static offset added to
v_shaped at 520 before `lbs`, translation added at 536), `flame_model/lbs.py` (`lbs` at 101: joints regressed
from v_shaped, pose feature of the non-root joints at 164; `batch_rigid_transform` at 254, relative transforms
at 300), the teeth (`add_teeth`, flame.py 186-311: lbs weights at 304-305), `utils/graphics_utils.py`
`compute_face_orientation` (116-135), `scene/gaussian_model.py` get_scaling (114-123), get_rotation (126-137,
face quaternion on the left) and get_xyz (141-150), `scene/flame_gaussian_model.py` select_mesh_by_timestep
(117) and update_mesh_properties (137-147). It uses numpy in float64 and shares no code with npga_core's posing.
tests/files/test_gaussian_avatars_reference.py runs their own code when a copy is at hand.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from npga_core.files import flame_teeth
from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.files.gaussian_avatars import import_gaussian_avatars
from npga_core.files.loading import load_sequence_for
from npga_core.posing.fastpose import FastPoser, posed_buffers
from tests.support import ga_synthetic as gs

ROOT = Path(__file__).resolve().parents[2]


def their_mesh(flame: dict, p: dict, t: int) -> np.ndarray:
    """FLAME with teeth at frame t of flame_param arrays `p`, as their forward (float64)."""
    v = gs.V
    tmpl = np.concatenate([flame["v_template"], flame_teeth.teeth_vertices(flame["v_template"])])
    sd = flame["shapedirs"]
    shape_dirs = np.concatenate([sd[:, :, :300], flame_teeth.ring_mean(sd[:, :, :300])])
    expr_dirs = np.concatenate([sd[:, :, 300:400], np.zeros((120, 3, 100))])
    vs = tmpl + shape_dirs @ p["shape"] + expr_dirs @ p["expr"][t] + p["static_offset"][0]
    reg = np.concatenate([flame["J_regressor"], np.zeros((gs.J, 120))], 1)
    joints = reg @ vs
    pose = np.concatenate([p["rotation"][t], p["neck_pose"][t], p["jaw_pose"][t], p["eyes_pose"][t]])
    rot = Rotation.from_rotvec(pose.reshape(gs.J, 3)).as_matrix()
    posedirs = np.concatenate([flame["posedirs"], np.zeros((120, 3, 36))]).reshape(-1, 36).T
    vp = vs + ((rot[1:] - np.eye(3)).reshape(-1) @ posedirs).reshape(-1, 3)
    parents = [-1, 0, 1, 1, 1]
    chain = []
    for j in range(gs.J):
        m = np.eye(4)
        m[:3, :3] = rot[j]
        m[:3, 3] = joints[j] - (joints[parents[j]] if j else 0)
        chain.append(m if j == 0 else chain[parents[j]] @ m)
    a = np.stack(chain)
    a[:, :3, 3] -= np.einsum("jab,jb->ja", a[:, :3, :3], joints)
    w = np.concatenate([flame["weights"], np.zeros((120, gs.J))])
    w[v + flame_teeth.teeth_rows(flame_teeth.UPPER_ROWS), 1] += 1
    w[v + flame_teeth.teeth_rows(flame_teeth.LOWER_ROWS), 2] += 1
    tv = np.einsum("vj,jab->vab", w, a)
    return np.einsum("vab,vb->va", tv[:, :3, :3], vp) + tv[:, :3, 3] + p["translation"][t]


def their_gaussians(flame: dict, p: dict, t: int, ply: dict) -> dict:
    """Posed xyz, scales, rotation (wxyz) of their Gaussians (`ply`: x, log scales, raw quats, binding)."""
    verts = their_mesh(flame, p, t)
    faces = np.concatenate([flame["f"].astype(np.int64), flame_teeth.teeth_faces() + gs.V])[ply["binding"]]
    v0, v1, v2 = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]

    def n(x):
        return x / np.linalg.norm(x, axis=1, keepdims=True)

    a0 = n(v1 - v0)
    a1 = n(np.cross(a0, v2 - v0))
    a2 = -n(np.cross(a1, a0))
    r = np.stack([a0, a1, a2], 2)
    s = (np.linalg.norm(v1 - v0, axis=1) + np.abs((a2 * (v2 - v0)).sum(1))) / 2
    c = (v0 + v1 + v2) / 3
    xyz = np.einsum("nab,nb->na", r, ply["xyz"]) * s[:, None] + c
    qf = Rotation.from_matrix(r)
    ql = Rotation.from_quat(n(ply["rot"])[:, [1, 2, 3, 0]])  # wxyz -> scipy's xyzw
    return {"means": xyz, "scales": np.exp(ply["log_scales"]) * s[:, None], "rot": qf * ql}


def _ply(folder: Path) -> dict:
    from npga_core.files.ply import read_ply_extra

    cloud, extra = read_ply_extra(folder / "point_cloud" / "iteration_30000" / "point_cloud.ply", ("binding_0",))
    return {"xyz": cloud.means.astype(np.float64), "log_scales": cloud.log_scales.astype(np.float64),
            "rot": cloud.quats.astype(np.float64), "binding": extra["binding_0"].astype(np.int64),
            "opacity": cloud.opacity_logits, "sh": cloud.sh}


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("ga")
    flame = gs.flame_arrays(3)
    pk = {s: gs.write_flame_pickle(d / f"flame_{s}.pkl", flame, s) for s in ("numpy", "chumpy")}
    gs.write_ga_folder(d / "out", 3000, seed=5, frames=4)
    foreign = gs.flame_params(11, 3, scale=1.5)
    np.savez(d / "foreign_flame_param.npz", **foreign)
    return {"dir": d, "flame": flame, "pickles": pk, "folder": d / "out", "foreign": foreign}


def _compare(avatar, world, p, t, code, rows=None):
    ref = their_gaussians(world["flame"], p, t, _ply(world["folder"]))
    posed = avatar.pose(code)
    buf = posed_buffers(len(avatar), 16, 0)
    FastPoser(avatar).pose_into(code, buf)
    head = float(np.ptp(ref["means"], axis=0).max())
    for got_means, got_quats, got_scales in ((posed.means, posed.quats, posed.scales),
                                             (buf["means"], buf["quats"], buf["scales"])):
        assert np.abs(got_means - ref["means"]).max() <= 1e-4 * head
        np.testing.assert_allclose(got_scales, ref["scales"], rtol=2e-5, atol=1e-9)
        dot = np.abs((Rotation.from_quat(got_quats[:, [1, 2, 3, 0]]).as_quat() * ref["rot"].as_quat()).sum(1))
        assert dot.min() > 1 - 1e-6
    ply = _ply(world["folder"])
    np.testing.assert_array_equal(posed.sh, ply["sh"])
    np.testing.assert_array_equal(posed.opacities, torch.sigmoid(torch.from_numpy(ply["opacity"])).numpy())


@pytest.mark.parametrize("style", ["numpy", "chumpy"])
def test_own_frames_match_their_forward(world, style):
    avatar = import_gaussian_avatars(world["folder"], world["pickles"][style])
    p = gs.flame_params(5, 4)
    seq = load_sequence_for(avatar, world["folder"] / "point_cloud" / "iteration_30000" / "flame_param.npz")
    assert seq.codes.shape == (4, avatar.code_dim) and np.allclose(seq.pose, np.eye(4))
    for t in range(4):
        _compare(avatar, world, p, t, seq.codes[t])


def test_foreign_sequence_and_saved_file(world, tmp_path):
    avatar = import_gaussian_avatars(world["folder"], world["pickles"]["numpy"])
    save_avatar(avatar, tmp_path / "a.npga", verify=True)
    again = read_avatar(tmp_path / "a.npga")
    seq = load_sequence_for(again, world["dir"] / "foreign_flame_param.npz")
    p = dict(world["foreign"])  # shape and static offset stay the avatar's (their load_ply with motion_path)
    own = gs.flame_params(5, 4)
    p["shape"], p["static_offset"] = own["shape"], own["static_offset"]
    for t in range(3):
        _compare(again, world, p, t, seq.codes[t])


def test_rest_pose_is_the_canonical_cloud(world):
    avatar = import_gaussian_avatars(world["folder"], world["pickles"]["chumpy"])
    posed = avatar.pose(np.zeros(avatar.code_dim, np.float32))
    assert np.abs(posed.means - avatar.cloud.means).max() < 1e-6
    assert avatar.slider_channels is None and avatar.expression is not None
    assert avatar.rig is not None and avatar.rig.input_names[100:103] == ("rotation.x", "rotation.y", "rotation.z")


def test_teeth_faces_and_highest_iteration(world):
    assert flame_teeth.teeth_faces().shape == (168, 3)
    assert flame_teeth.teeth_faces().max() == 119
    avatar = import_gaussian_avatars(world["folder"], world["pickles"]["numpy"])
    assert "iteration_30000" in avatar.provenance["source"]


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "HOME": str(cwd)}
    return subprocess.run([sys.executable, "-m", "npga_view.cli.main", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


@pytest.mark.slow
def test_cli_import_and_info(world, tmp_path):
    out = tmp_path / "a.npga"
    r = _cli("import", "gaussian-avatars", world["folder"], "--flame-model", world["pickles"]["chumpy"], "--out", out,
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "MPI" in r.stdout
    info = _cli("info", out, cwd=tmp_path)
    assert info.returncode == 0 and "FLAME licence" in info.stdout and "triangles" in info.stdout


@pytest.mark.slow
def test_hostile_flame_pickles(world, tmp_path):
    """`npga-view import gaussian-avatars --flame-model BAD.pkl` (a forked child per pickle, the project's fork
    server: tests/support/cli_forkserver.py): exit 2, one line naming the pickle, nothing written, no payload run."""
    from tests.support.cli_forkserver import ForkServer
    from tests.support.hostile_readers_corpus import flame_pickles

    server = ForkServer(tmp_path, env={"DISPLAY": "", "WAYLAND_DISPLAY": "", "HOME": str(tmp_path)})
    try:
        for name, path in flame_pickles(tmp_path / "cases", world["flame"]).items():
            out = tmp_path / f"{name.replace(' ', '_')}.npga"
            reply, _, err = server.cli("import", "gaussian-avatars", str(world["folder"]), "--flame-model", str(path),
                                       "--out", str(out))
            lines = err.strip().splitlines()
            assert reply["exit"] == 2 and len(lines) == 1 and str(path) in lines[0], (name, reply, err)
            assert not out.exists() and not (tmp_path / "PWNED").exists(), name
    finally:
        server.close()


def test_fast_frame_matches_the_reference_path(world):
    """`LinearRig.frame` (torch: the correctives and skinning as matmuls) gives the face motions of the reference
    path (`reference_frame`: numpy float64) to float32 rounding, also for large poses."""
    from npga_core.model.skinning import quat_from_rotation

    avatar = import_gaussian_avatars(world["folder"], world["pickles"]["numpy"])
    rig = avatar.rig
    assert rig is not None and rig.skin is not None
    rng = np.random.default_rng(4)
    means = torch.from_numpy(avatar.cloud.means.copy())
    for scale in (0.0, 0.3, 1.5):
        x = rng.normal(0, scale, rig.n_inputs).astype(np.float32)
        ref, fast = rig.reference_frame(x), rig.frame(x)
        assert ((ref.packed - fast.packed).abs() <= 2e-5 * (1 + ref.packed.abs())).all()
        rows = np.sort(rng.choice(len(avatar), 500, replace=False))
        for name, got in rig.attribute_offsets(fast, rows, means[rows]).items():
            want = rig.attribute_offsets(ref, rows, means[rows])[name]
            assert ((got - want).abs() <= 2e-5 * (1 + want.abs())).all(), name
    turns = Rotation.random(2000, random_state=1)
    flips = Rotation.from_rotvec(np.pi * np.eye(3))  # half turns: the largest-component branch
    for r in (turns, flips):
        q = quat_from_rotation(torch.from_numpy(r.as_matrix())).numpy()
        assert np.abs(np.abs((q[:, [1, 2, 3, 0]] * r.as_quat()).sum(1)) - 1).max() < 1e-12 and (q[:, 0] >= 0).all()


def test_arkit_take_drives_through_a_fitted_flame_basis(world, tmp_path):
    """No ARKit basis ships for FLAME: a take is refused in one line naming the remedy; `fit-blendshapes --codes
    flame_param.npz --into` (a take and FLAME parameters of the same frames) gives one, and the take then drives the
    jaw as the paired parameters did."""
    from npga_core.errors import AvatarFileError
    from npga_core.files.arkit_takes import read_take, resampled
    from npga_view.cli.main import main
    from tests.support.takes import write_one_channel_take

    avatar = import_gaussian_avatars(world["folder"], world["pickles"]["numpy"])
    npga = tmp_path / "a.npga"
    save_avatar(avatar, npga)
    take = tmp_path / "take.csv"
    write_one_channel_take(take, 60, "jawOpen")
    with pytest.raises(AvatarFileError, match="fit-blendshapes --take TAKE --codes flame_param.npz"):
        load_sequence_for(avatar, take)
    t = read_take(take)
    jaw_open = resampled(t, [t.names.index("JawOpen")], take)[:, 0]
    p = gs.flame_params(5, len(jaw_open), scale=0.0)
    p["jaw_pose"][:, 0] = 0.4 * jaw_open
    p["expr"][:, 2] = -1.5 * jaw_open
    np.savez(tmp_path / "flame_param.npz", **p)
    out = tmp_path / "with_basis.npga"
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(tmp_path / "flame_param.npz"), "--into",
                 str(npga), "--out", str(out)]) == 0
    driven = read_avatar(out)
    seq = load_sequence_for(driven, take)
    names = driven.rig.input_names  # type: ignore[union-attr]
    got = seq.codes[:, names.index("jaw.x")]
    assert np.abs(got[-1] - 0.4) < 0.02 and np.abs(got[0]) < 0.02
    assert np.abs(seq.codes[-1, names.index("expr2")] + 1.5) < 0.05
