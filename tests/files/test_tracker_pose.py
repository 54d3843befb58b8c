"""Tracked head pose as each tracker defines it: files laid out as MonoNPHM, NeRSemble and GaussianAvatars
write them, with rotations of 20-40 degrees, scale 1.15 and a 30 cm translation, read into the canonical ->
world 4x4 and checked against the trackers' own formulas (written out here with numpy, not through the
project's code); exported positions (`npga-view export --head-pose`), .npzseq conversion, bad data, and the
window showing the head turned the right way.

Sources (commits read for this test):
- MonoNPHM (SimonGiebenhain/MonoNPHM @ e9a30f5f): src/mononphm/photometric_tracking/tracking.py L1251-1253
  saves scale.npy (1,), trans.npy (1, 3), rot.npy = so3_exp_map(axis-angle) (1, 3, 3) per frame folder;
  rendering.py L100 maps world samples into NPHM space, ``pnts = scale * pnts @ R.T + trans``;
  scripts/evaluation/eval.py L456 brings the NPHM mesh to the tracking's world, ``1/s * (v - t) @ R``.
- NeRSemble (tobias-kirschstein/nersemble-benchmark @ e15f204d): src/nersemble_benchmark/data/
  benchmark_data.py L164-177 (FlameTracking: the keys and shapes); models/flame.py L78-82
  ``Pose.from_euler(rotation, translation, 'XYZ')`` with ``[:3, :3] *= scale[0]``; dreifus
  src/dreifus/matrix/pose_numpy.py L82-90: scipy ``Rotation.from_euler('XYZ')`` (intrinsic: Rx Ry Rz).
  That `rotation_matrices` equals the Euler rotation (without the scale) is assumed: no code in the
  benchmark reads or writes it, and no real file was available.
- GaussianAvatars (ShenhanQian/GaussianAvatars @ 30cc4bde): scene/flame_gaussian_model.py L61-71 and
  L222-224 (flame_param.npz keys), L121-134 (rotation, translation into FLAME); flame_model/flame.py L512
  (rotation is the root joint of the pose), L536 (translation added after LBS); flame_model/lbs.py L25-57
  (batch_rodrigues: axis-angle). FLAME rotates about its root joint J0; a non-FLAME avatar has none, so the
  rotation is applied about the origin: x_world = R x + t.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.loading import load_sequence
from npga_core.posing.headpose import head_transform
from npga_view.actions import StepFrames
from tests.support.reference_rasterizer import quat_to_rotation
from tests.support.window import run_until, settle

T = 3
SCALE = 1.15
ROTVECS = np.radians([[0.0, 25.0, 0.0], [12.0, -30.0, 8.0], [-20.0, 15.0, 35.0]])  # 25 to 40 degree turns
EULER = np.radians([[10.0, 25.0, -5.0], [-15.0, -30.0, 20.0], [25.0, 10.0, -35.0]])
TRANS = np.array([[0.3, 0.05, -0.1], [0.25, -0.08, 0.12], [-0.2, 0.1, 0.3]])


def rodrigues(v) -> np.ndarray:
    """pytorch3d so3_exp_map / FLAME batch_rodrigues: I + sin(a) K + (1 - cos(a)) K^2."""
    v = np.asarray(v, np.float64)
    a = np.linalg.norm(v)
    k = v / a
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


def euler_xyz(a) -> np.ndarray:
    """scipy Rotation.from_euler('XYZ', a): intrinsic x, then y, then z: Rx(a0) Ry(a1) Rz(a2)."""
    cx, sx, cy, sy, cz, sz = np.cos(a[0]), np.sin(a[0]), np.cos(a[1]), np.sin(a[1]), np.cos(a[2]), np.sin(a[2])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


# --- the trackers' formulas, row-vector points (N, 3) ---------------------------------------------------
def mononphm_world(x, i):
    """eval.py L456: the NPHM-space points in the tracking's world."""
    return 1 / SCALE * (x - TRANS[i]) @ rodrigues(ROTVECS[i])


def mononphm_nphm(x_world, i):
    """rendering.py L100: world points into NPHM space."""
    return SCALE * x_world @ rodrigues(ROTVECS[i]).T + TRANS[i]


def nersemble_world(x, i):
    """flame.py L90-94: homogeneous points times (s R | t)^T."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = SCALE * euler_xyz(EULER[i]), TRANS[i]
    return (np.c_[x, np.ones(len(x))] @ m.T)[:, :3]


def gaussian_avatars_world(x, i):
    """flame.py L536 with the root-joint rotation taken about the origin."""
    return x @ rodrigues(ROTVECS[i]).T + TRANS[i]


# --- files as the trackers write them -------------------------------------------------------------
def write_mononphm(root, codes, stage=2):
    for i in range(T):
        f = root / f"{i:05d}"
        f.mkdir(parents=True)
        np.save(f / "z_exp.npy", codes.astype(np.float32) if stage == 2 else codes[i : i + 1].astype(np.float32))
        np.save(f / "rot.npy", rodrigues(ROTVECS[i])[None].astype(np.float32))
        np.save(f / "trans.npy", TRANS[i][None].astype(np.float32))
        np.save(f / "scale.npy", np.array([SCALE], np.float32))
    return root


def nersemble_arrays(codes, **change) -> dict:
    a = {"shape": np.zeros((1, 300), np.float32), "expression": codes.astype(np.float32),
         "rotation": EULER.astype(np.float32),
         "rotation_matrices": np.stack([euler_xyz(e) for e in EULER]).astype(np.float32),
         "translation": TRANS.astype(np.float32), "jaw": np.zeros((T, 3), np.float32),
         "frames": np.arange(T) * 3, "scale": np.full((1, 1), SCALE, np.float32),
         "neck": np.zeros((T, 3), np.float32), "eyes": np.zeros((T, 6), np.float32)}
    a.update(change)
    return {k: v for k, v in a.items() if v is not None}


def write_npz(path, arrays: dict):
    with open(path, "wb") as fh:  # np.savez would append .npz to other suffixes
        np.savez(fh, **arrays)
    return path


def gaussian_avatars_arrays(codes, v=40) -> dict:
    return {"shape": np.zeros(300, np.float32), "expr": codes.astype(np.float32),
            "rotation": ROTVECS.astype(np.float32), "neck_pose": np.zeros((T, 3), np.float32),
            "jaw_pose": np.zeros((T, 3), np.float32), "eyes_pose": np.zeros((T, 6), np.float32),
            "translation": TRANS.astype(np.float32), "static_offset": np.zeros((1, v, 3), np.float32),
            "dynamic_offset": np.zeros((T, v, 3), np.float32)}


def _apply(m, x):
    return x @ m[:3, :3].T + m[:3, 3]


POINTS = np.random.default_rng(7).uniform(-0.15, 0.15, (50, 3))


def test_mononphm_pose_is_the_inverse_of_its_world_to_nphm(tmp_path):
    seq = load_sequence(write_mononphm(tmp_path / "seq", np.zeros((T, 8))))
    assert seq.pose_source.startswith("MonoNPHM")
    for i in range(T):
        world = _apply(seq.pose[i], POINTS)
        np.testing.assert_allclose(world, mononphm_world(POINTS, i), atol=1e-6)
        np.testing.assert_allclose(mononphm_nphm(world, i), POINTS, atol=1e-6)  # the renderer's map undoes it
        wrong = SCALE * POINTS @ rodrigues(ROTVECS[i]).T + TRANS[i]  # the formula npga-view used before
        assert np.abs(world - wrong).max() > 0.2
    # relative motion M_0^-1 M_t turns the head by R_0 R_t^T (the opposite of the file's R_t)
    rel = head_transform(seq, 1)
    np.testing.assert_allclose(rel[:3, :3], rodrigues(ROTVECS[0]) @ rodrigues(ROTVECS[1]).T, atol=1e-6)
    np.testing.assert_allclose(_apply(rel, POINTS), mononphm_nphm(mononphm_world(POINTS, 1), 0), atol=1e-6)


def test_nersemble_pose_is_scaled_euler_xyz(tmp_path):
    codes = np.zeros((T, 8))
    seq = load_sequence(write_npz(tmp_path / "flame2023_tracking_v2.npz", nersemble_arrays(codes)))
    assert seq.pose_source.startswith("NeRSemble") and seq.frame_names == ["0", "3", "6"]
    for i in range(T):
        np.testing.assert_allclose(_apply(seq.pose[i], POINTS), nersemble_world(POINTS, i), atol=1e-6)
        as_axis_angle = SCALE * POINTS @ rodrigues(EULER[i]).T + TRANS[i]
        assert np.abs(_apply(seq.pose[i], POINTS) - as_axis_angle).max() > 0.01  # the conventions differ
    # Euler angles alone, and a global scale of shape (1,) or (), or one per frame, give the same
    for change in ({"rotation_matrices": None}, {"scale": np.array([SCALE])}, {"scale": np.float32(SCALE)},
                   {"scale": np.full((T, 1), SCALE, np.float32)}):
        other = load_sequence(write_npz(tmp_path / "v.npz", nersemble_arrays(codes, **change)))
        np.testing.assert_allclose(other.pose, seq.pose, atol=1e-6)


def test_gaussian_avatars_pose_is_about_the_origin(tmp_path):
    seq = load_sequence(write_npz(tmp_path / "flame_param.npz", gaussian_avatars_arrays(np.zeros((T, 8)))))
    assert "about the origin" in seq.pose_source and "root joint is not known" in seq.pose_source
    assert seq.name == tmp_path.name  # flame_param.npz takes its folder's name
    for i in range(T):
        np.testing.assert_allclose(_apply(seq.pose[i], POINTS), gaussian_avatars_world(POINTS, i), atol=1e-6)


@pytest.fixture
def avatar_file(tmp_path):
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar

    avatar = make_synthetic_avatar(400, seed=2)
    save_avatar(avatar, tmp_path / "a.npga")
    return avatar, tmp_path / "a.npga"


def _export(path, seq_path, frame, mode, out):
    from npga_core.files.ply import read_ply
    from npga_view.cli.main import main

    assert main(["export", str(path), "--out", str(out), "--sequence", str(seq_path), "--frame", str(frame),
                 "--head-pose", mode]) == 0
    return read_ply(out)


@pytest.mark.parametrize("tracker", ["mononphm", "nersemble", "gaussian_avatars"])
def test_export_absolute_puts_the_gaussians_where_the_tracker_has_them(tmp_path, avatar_file, tracker):
    """`export --head-pose absolute`: centres by the tracker's formula, Gaussian rotations turned by the
    formula's rotation, scales times its scale; the same after converting the file to .npzseq."""
    avatar, path = avatar_file
    codes = np.repeat(avatar.neutral_code()[None], T, 0)
    src, world, turn, scale = {
        "mononphm": (lambda: write_mononphm(tmp_path / "track", codes, stage=1), mononphm_world,
                     lambda i: rodrigues(ROTVECS[i]).T, 1 / SCALE),
        "nersemble": (lambda: write_npz(tmp_path / "flame2023_tracking.npz", nersemble_arrays(codes)),
                      nersemble_world, lambda i: euler_xyz(EULER[i]), SCALE),
        "gaussian_avatars": (lambda: write_npz(tmp_path / "flame_param.npz", gaussian_avatars_arrays(codes)),
                             gaussian_avatars_world, lambda i: rodrigues(ROTVECS[i]), 1.0),
    }[tracker]
    seq_path = src()
    posed = avatar.pose(codes[2])
    back = _export(path, seq_path, 2, "absolute", tmp_path / "abs.ply")
    want = world(posed.means.astype(np.float64), 2)
    np.testing.assert_allclose(back.means, want, atol=2e-6)
    assert np.abs(want - posed.means).max() > 0.1
    np.testing.assert_allclose(quat_to_rotation(back.quats.astype(np.float64)),
                               turn(2) @ quat_to_rotation(posed.quats.astype(np.float64)), atol=2e-5)
    np.testing.assert_allclose(np.exp(back.log_scales), scale * posed.scales, rtol=1e-5)
    # relative to frame 0: the frame's world pose seen from frame 0's canonical space
    rel = _export(path, seq_path, 2, "relative", tmp_path / "rel.ply")
    frame0 = load_sequence(seq_path).pose[0]
    np.testing.assert_allclose(rel.means, _apply(np.linalg.inv(frame0), want), atol=2e-6)
    # converted to .npzseq (the tracker's pose is kept, with its source)
    seq = load_sequence(seq_path)
    seq.save(tmp_path / "converted.npzseq")
    again = load_sequence(tmp_path / "converted.npzseq")
    assert np.array_equal(again.pose, seq.pose) and again.pose_source == seq.pose_source
    np.testing.assert_array_equal(_export(path, tmp_path / "converted.npzseq", 2, "absolute",
                                          tmp_path / "conv.ply").means, back.means)


def _error(path) -> str:
    with pytest.raises(AvatarFileError) as e:
        load_sequence(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(path)), msg
    return msg


def test_bad_pose_data_is_one_line_error(tmp_path):
    codes = np.zeros((T, 8))
    sheared = np.stack([euler_xyz(e) for e in EULER]).astype(np.float32)
    sheared[1, 0, 1] += 0.05
    turned = np.stack([euler_xyz(e) for e in EULER]).astype(np.float32)
    turned[2] = turned[2] @ rodrigues([0.0, 0.0, np.radians(5.0)])
    nan = TRANS.astype(np.float32).copy()
    nan[1, 2] = np.nan
    for change, msg in [
        ({"rotation_matrices": sheared}, "rotation_matrices of frame 1 is not a rotation matrix"),
        ({"rotation_matrices": -sheared}, "determinant is not positive"),
        ({"rotation_matrices": turned}, r"disagree with rotation \(Euler XYZ\) at frame 2 by 5 degrees"),
        ({"translation": nan}, "translation has NaN/Inf values"),
        ({"scale": np.zeros((1, 1), np.float32)}, "scale must be finite and positive"),
        ({"scale": np.full((1, 1), -1.0, np.float32)}, r"scale must be finite and positive \(frame 0 is -1\)"),
        ({"scale": np.ones((1, 2), np.float32)}, "scale must be one value or one per frame"),
        ({"rotation": EULER[:2].astype(np.float32)}, r"rotation must be finite with shape \(3, 3\), got \(2, 3\)"),
    ]:
        p = write_npz(tmp_path / "bad.npz", nersemble_arrays(codes, **change))
        assert re.search(msg, _error(p)), (msg, _error(p))

    # MonoNPHM: a non-rotation matrix, a zero scale, a frame without its trans.npy
    root = write_mononphm(tmp_path / "m", codes)
    np.save(root / "00001" / "rot.npy", np.diag([1.0, 2.0, 1.0])[None].astype(np.float32))
    assert "rot.npy of frame 1 is not a rotation matrix" in _error(root)
    np.save(root / "00001" / "rot.npy", np.eye(3)[None].astype(np.float32))
    np.save(root / "00002" / "scale.npy", np.zeros(1, np.float32))
    assert "scale.npy must be finite and positive (frame 2 is 0)" in _error(root)
    np.save(root / "00002" / "scale.npy", np.ones(1, np.float32))
    (root / "00000" / "trans.npy").unlink()
    assert "has no trans.npy while other frames have one" in _error(root)

    # .npzseq with a stored pose: not a similarity, NaN, the wrong number of frames, pose and old keys both
    good = np.repeat(np.eye(4)[None], T, 0)
    for pose, extra, msg in [
        (good * np.array([1.0, 2.0, 1.0, 1.0])[:, None], {}, "pose matrix 0 is not a scaled rotation"),
        (np.where(np.arange(16).reshape(4, 4) == 3, np.nan, good), {}, "pose matrix 0 has NaN/Inf values"),
        (good[:2], {}, r"pose must have shape (3, 4, 4) for 3 frames, got (2, 4, 4)"),
        (good, {"rotation": np.zeros((T, 3))}, "has both pose and rotation"),
    ]:
        p = write_npz(tmp_path / "bad.npzseq", {"codes": codes.astype(np.float32), "pose": pose, **extra})
        assert msg in _error(p)


def test_cli_reports_bad_pose_on_one_line(tmp_path, avatar_file, capsys):
    from npga_view.cli.main import main

    _, path = avatar_file
    p = write_npz(tmp_path / "flame2023_tracking.npz",
                  nersemble_arrays(np.zeros((T, 100)), scale=np.zeros((1, 1), np.float32)))
    assert main(["export", str(path), "--out", str(tmp_path / "o.ply"), "--sequence", str(p), "--frame", "0",
                 "--head-pose", "absolute"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scale must be finite and positive" in err and str(p) in err


@pytest.mark.slow
@pytest.mark.gui
def test_window_turns_a_mononphm_head_the_right_way(app, avatar_path, tmp_path):
    """The demo head in the window, a MonoNPHM sequence whose frame 1 has rot.npy = a 30-degree turn about y:
    with the orbit camera the view at frame 1 is the head moved by the tracker's own formulas (frame 1 to the
    world, then into frame 0's NPHM space), not the opposite turn the old formula gave."""
    from npga_core.camera.cameras import Camera

    assert app.open_avatar(avatar_path)
    code = app.avatar.neutral_code()
    root = tmp_path / "turn"
    t = np.array([0.02, -0.01, 0.03])
    for i, deg in enumerate((0.0, 30.0)):
        f = root / f"{i:05d}"
        f.mkdir(parents=True)
        np.save(f / "z_exp.npy", code[None].astype(np.float32))
        np.save(f / "rot.npy", (rodrigues([0.0, np.radians(deg) + 1e-12, 0.0]))[None].astype(np.float32))
        np.save(f / "trans.npy", t[None].astype(np.float32))
        np.save(f / "scale.npy", np.array([SCALE], np.float32))
    settle(app)
    base = app.current_camera()
    assert app.open_sequence(str(root))
    settle(app)
    np.testing.assert_allclose(app.current_camera().world_to_camera, base.world_to_camera, atol=1e-9)
    app.state.actions.append(StepFrames(1))
    assert run_until(app, lambda: app.poses.shown_frame == 1)
    settle(app)
    shot = app.screenshot(str(tmp_path / "turned.png"))
    print("window screenshot:", shot)
    cam = app.current_camera()

    r1 = rodrigues([0.0, np.radians(30.0), 0.0])

    def right(x):  # eval.py L456 for frame 1, then rendering.py L100 for frame 0 (R_0 = I)
        return SCALE * ((x - t) / SCALE @ r1) + t

    def wrong(x):  # the old reading, s R x + t, relative to frame 0
        return ((SCALE * x @ r1.T + t) - t) / SCALE

    pts = np.asarray(app.shown_posed().means, np.float64)
    np.testing.assert_allclose(cam.project(pts), base.project(right(pts)), atol=1e-3)  # pixels
    assert np.abs(cam.project(pts) - base.project(wrong(pts))).max() > 20

    def moved(f) -> Camera:  # the camera that shows the Gaussians moved by the affine map f
        m = np.eye(4)
        m[:3, 3] = f(np.zeros((1, 3)))[0]
        m[:3, :3] = (f(np.eye(3)) - m[:3, 3]).T
        return Camera(base.world_to_camera @ m, base.fx, base.fy, base.cx, base.cy, base.width, base.height)

    window = app.read_window(viewport_only=True).astype(np.float64)
    bg = app.state.background
    want = np.clip(app.renderer.render(moved(right), bg) * 255.0, 0, 255)
    other = np.clip(app.renderer.render(moved(wrong), bg) * 255.0, 0, 255)
    err_right, err_wrong = np.abs(window - want).mean(), np.abs(window - other).mean()
    print(f"mean |window - render| per channel: tracker's formula {err_right:.2f}, old formula {err_wrong:.2f}")
    assert err_right < 0.5 * err_wrong, (err_right, err_wrong)
