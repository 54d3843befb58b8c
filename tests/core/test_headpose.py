"""Head pose of tracked sequences: the matrices, and a moved camera renders what moved Gaussians would."""

from __future__ import annotations

import json

import numpy as np
import pytest

from npga_core.camera.cameras import frame_points, look_at
from npga_core.errors import AvatarFileError
from npga_core.files.loading import load_sequence
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.rotations import matrix_from_rotvec
from npga_core.model.sh import rotate_sh
from npga_core.posing.headpose import (
    has_head_pose,
    head_transform,
    pose_description,
    pose_matrix,
    posed_camera,
    transform_posed,
)
from tests.support.reference_rasterizer import rasterize, sh_to_rgb
from tests.support.render import psnr, random_cloud


@pytest.fixture
def renderer(ctx):
    from npga_view.rendering.renderer import SplatRenderer

    r = SplatRenderer(ctx, 128, 160)
    yield r
    r.release()


def _pose_parts(t: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    return ((0.3 * rng.standard_normal((t, 3))).astype(np.float32),
            (0.05 * rng.standard_normal((t, 3))).astype(np.float32), rng.uniform(0.9, 1.1, t).astype(np.float32))


def _sequence(t: int = 5) -> ExpressionSequence:
    """A sequence whose pose is given as rotation (axis-angle), translation and scale: x_world = s R x + t."""
    rotation, translation, scale = _pose_parts(t)
    return ExpressionSequence(np.zeros((t, 4), np.float32), 25.0, "nod", rotation=rotation,
                              translation=translation, scale=scale)


def _avatar_with_sequence(folder, n: int, t: int):
    """A saved synthetic avatar (a.npga) and a posed sequence of its neutral code (s.npzseq) in `folder`."""
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar

    avatar = make_synthetic_avatar(n, seed=2)
    path = folder / "a.npga"
    save_avatar(avatar, path)
    seq = _sequence(t)
    seq.codes = np.repeat(avatar.neutral_code()[None], t, 0)
    seq.save(folder / "s.npzseq")
    return avatar, path, seq


def test_pose_matrix_and_relative_transform():
    seq = _sequence()
    rotation, translation, scale = _pose_parts()
    x = np.array([0.1, -0.2, 0.3])
    m = pose_matrix(rotation[2], translation[2], float(scale[2]))
    want = scale[2] * matrix_from_rotvec(rotation[2]) @ x + translation[2]
    np.testing.assert_allclose((m @ np.append(x, 1.0))[:3], want, atol=1e-6)
    np.testing.assert_allclose(seq.pose[2], m, atol=1e-12)
    np.testing.assert_allclose(head_transform(seq, 0), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(head_transform(seq, 2, relative=False), m)
    t0 = head_transform(seq, 0, relative=False)
    np.testing.assert_allclose(t0 @ head_transform(seq, 3), head_transform(seq, 3, relative=False), atol=1e-12)
    assert has_head_pose(seq) and not has_head_pose(ExpressionSequence(seq.codes)) and not has_head_pose(None)
    assert pose_description(seq) == "x_world = s R x + t (rotation axis-angle)"


def test_only_rotation_is_a_pose():
    seq = ExpressionSequence(np.zeros((2, 3), np.float32), rotation=np.array([[0, 0, 0], [0, 0.5, 0]], np.float32))
    m = head_transform(seq, 1)
    np.testing.assert_allclose(m[:3, :3], matrix_from_rotvec([0, 0.5, 0]))
    np.testing.assert_allclose(m[:3, 3], 0.0)
    with pytest.raises(ValueError, match="not both"):
        ExpressionSequence(seq.codes, rotation=np.zeros((2, 3)), pose=seq.pose)


def test_moved_camera_renders_the_moved_gaussians(renderer):
    """V T drawn from the canonical cloud against the reference rasterizer drawing the cloud moved by T: means,
    rotations, scales and the degree-1 SH band (a colour linear in the view direction, which turns with the
    head) are moved in numpy here. Checks covariances, depth order and the SH view direction under a scaled
    camera matrix."""
    g = random_cloud(1200, seed=4, sh_degree=1, spread=0.4, sh_rest=0.6)
    rotation, translation, scale = np.array([0.2, 0.5, -0.1]), np.array([0.05, -0.1, 0.2]), 1.15
    t = pose_matrix(rotation, translation, scale)
    cam = look_at((0.3, 0.2, 3.2), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 128, 160)
    renderer.set_gaussians(g)
    image = renderer.render(posed_camera(cam, t))

    r = matrix_from_rotvec(rotation)
    angle = np.linalg.norm(rotation)
    w, (x, y, z) = np.cos(angle / 2), np.sin(angle / 2) * rotation / angle
    q = g.quats.astype(np.float64)  # q_moved = q_R * q (Hamilton product, w first)
    moved_q = np.stack([w * q[:, 0] - x * q[:, 1] - y * q[:, 2] - z * q[:, 3],
                        w * q[:, 1] + x * q[:, 0] + y * q[:, 3] - z * q[:, 2],
                        w * q[:, 2] - x * q[:, 3] + y * q[:, 0] + z * q[:, 1],
                        w * q[:, 3] + x * q[:, 2] - y * q[:, 1] + z * q[:, 0]], axis=1)
    means = scale * g.means.astype(np.float64) @ r.T + translation
    # band 1 adds C1 (-y c1 + z c2 - x c3) for a unit direction (x, y, z), i.e. d . a with a = (-c3, -c1, c2):
    # the moved head needs a' = R a so that (R d) . a' = d . a
    sh = g.sh.astype(np.float64).copy()
    a = np.stack([-sh[:, 3], -sh[:, 1], sh[:, 2]], axis=1)  # (n, 3 axes, 3 channels)
    a = np.einsum("ij,njc->nic", r, a)
    sh[:, 1], sh[:, 2], sh[:, 3] = -a[:, 1], a[:, 2], -a[:, 0]
    ref = rasterize(means.astype(np.float32), moved_q.astype(np.float32), (scale * g.scales).astype(np.float32),
                    g.opacities, sh.astype(np.float32), cam)
    assert np.mean(ref["alpha"]) > 0.05
    assert psnr(image, ref["rgb"]) >= 40.0
    unturned = rasterize(means.astype(np.float32), moved_q.astype(np.float32),
                         (scale * g.scales).astype(np.float32), g.opacities, g.sh, cam)
    assert psnr(image, unturned["rgb"]) < psnr(image, ref["rgb"]) - 3.0  # the SH check has teeth


def test_bad_scale_is_refused(tmp_path):
    """An .npzseq written before the 4x4 pose (rotation/translation/scale arrays) with a zero scale."""
    rotation, translation, scale = _pose_parts()
    scale[1] = 0.0
    with open(tmp_path / "s.npzseq", "wb") as fh:  # np.savez would append .npz to a path
        np.savez(fh, codes=np.zeros((5, 4), np.float32), rotation=rotation, translation=translation, scale=scale)
    with pytest.raises(AvatarFileError, match="scale must be finite and positive .frame 1 is 0") as e:
        load_sequence(tmp_path / "s.npzseq")
    assert "\n" not in str(e.value) and str(tmp_path / "s.npzseq") in str(e.value)


@pytest.mark.slow
def test_render_cli_head_pose(tmp_path, capsys):
    """`render --head-pose`: frame 0 relative is the unmoved picture; the absolute pose of frame k equals
    rendering with the camera moved by T_k (npy output: exact floats); errors are one line, exit 2."""
    from npga_view.cli.main import main

    avatar, path, seq = _avatar_with_sequence(tmp_path, 800, 4)
    size = ["--width", "96", "--height", "120"]

    def render(*extra) -> np.ndarray:
        out = tmp_path / f"r{len(list(tmp_path.glob('r*.npy')))}.npy"
        assert main(["render", str(path), "--out", str(out), "--sequence", str(tmp_path / "s.npzseq"),
                     *size, *extra]) == 0
        return np.load(out)

    plain = render("--frame", "0")
    assert np.array_equal(render("--frame", "0", "--head-pose", "relative"), plain)
    moved = render("--frame", "2", "--head-pose", "absolute")
    assert np.abs(moved - plain).max() > 0.1
    cam_json = tmp_path / "cam.json"
    cam = frame_points(avatar.cloud.means, 96, 120)
    cam_json.write_text(json.dumps(posed_camera(cam, head_transform(seq, 2, False)).to_dict()))
    np.testing.assert_allclose(render("--frame", "2", "--camera", str(cam_json)), moved, atol=1e-6)

    still = tmp_path / "still.npzseq"
    ExpressionSequence(seq.codes).save(still)
    for argv, message in (
        (["--head-pose", "relative"], "--head-pose needs --sequence"),
        (["--sequence", str(still), "--frame", "0", "--head-pose", "relative"], "has no head pose"),
    ):
        assert main(["render", str(path), "--out", str(tmp_path / "x.png"), *argv]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


def test_rotate_sh_turns_the_colour_with_the_head():
    """colour'(R d) = colour(d) for degree-3 SH, evaluated by the reference rasterizer's own SH code."""
    rng = np.random.default_rng(5)
    sh = (0.3 * rng.standard_normal((50, 16, 3))).astype(np.float32)
    r = matrix_from_rotvec([0.4, -0.9, 0.3])
    d = rng.standard_normal((50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    turned = rotate_sh(sh, r)
    np.testing.assert_allclose(sh_to_rgb(turned.astype(np.float64), d @ r.T), sh_to_rgb(sh.astype(np.float64), d),
                               atol=1e-5)
    np.testing.assert_array_equal(turned[:, 0], sh[:, 0])
    assert np.abs(turned - sh).max() > 0.05
    with pytest.raises(ValueError, match="expected 1, 4, 9 or 16"):
        rotate_sh(np.zeros((2, 5, 3), np.float32), r)


def test_moved_gaussians_render_like_the_moved_camera(renderer):
    """transform_posed (centres, rotations, scales, degree-3 SH) seen by V against the canonical cloud seen by
    V T: the same picture; and against the reference rasterizer drawing the moved Gaussians."""
    g = random_cloud(1000, seed=6, sh_degree=3, spread=0.4, sh_rest=0.5)
    t = pose_matrix(np.array([-0.3, 0.7, 0.2]), np.array([0.1, 0.05, -0.2]), 0.9)
    cam = look_at((0.2, 0.3, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 128, 160)
    renderer.set_gaussians(g)
    by_camera = renderer.render(posed_camera(cam, t))
    moved = transform_posed(g, t)
    renderer.set_gaussians(moved)
    by_gaussians = renderer.render(cam)
    assert psnr(by_gaussians, by_camera) >= 60.0
    ref = rasterize(moved.means, moved.quats, moved.scales, moved.opacities, moved.sh, cam)
    assert np.mean(ref["alpha"]) > 0.05 and psnr(by_camera, ref["rgb"]) >= 40.0
    np.testing.assert_allclose(np.linalg.norm(moved.quats, axis=1), 1.0, atol=1e-6)


def test_export_cli_head_pose(tmp_path, capsys):
    """`export --head-pose absolute` writes the frame's Gaussians moved into the tracking's world."""
    from npga_core.files.ply import read_ply
    from npga_view.cli.main import main

    avatar, path, seq = _avatar_with_sequence(tmp_path, 300, 3)
    out = tmp_path / "posed.ply"
    assert main(["export", str(path), "--out", str(out), "--sequence", str(tmp_path / "s.npzseq"), "--frame", "2",
                 "--head-pose", "absolute"]) == 0
    want = transform_posed(avatar.pose(seq.codes[2]), head_transform(seq, 2, relative=False))
    back = read_ply(out)
    np.testing.assert_allclose(back.means, want.means, atol=1e-6)
    np.testing.assert_allclose(back.sh, want.sh, atol=1e-6)
    capsys.readouterr()
    assert main(["export", str(path), "--out", str(out), "--head-pose", "relative"]) == 2
    err = capsys.readouterr().err
    assert "--head-pose needs --sequence" in err and len(err.strip().splitlines()) == 1
