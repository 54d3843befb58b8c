"""`npga-view export`: the posed avatar as a standard 3DGS .ply, read back by a PLY reader written here."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.checkpoint import save_avatar
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.synthetic import make_synthetic_avatar
from npga_view.cli.main import main
from tests.support.ply_reader import read_vertices


def standard_names(degree: int) -> list[str]:
    rest = 3 * ((degree + 1) ** 2 - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    avatar = make_synthetic_avatar(250, hidden=32, depth=2, code_dim=10, n_components=5, seed=7)
    path = tmp_path_factory.mktemp("export") / "a.npga"
    save_avatar(avatar, path)
    return avatar, path


def check_ply(path, posed) -> None:
    v = read_vertices(path)
    k = posed.sh.shape[1]
    assert list(v.dtype.names) == standard_names({1: 0, 4: 1, 9: 2, 16: 3}[k])
    assert len(v) == len(posed)
    np.testing.assert_array_equal(np.column_stack([v["x"], v["y"], v["z"]]), posed.means)
    np.testing.assert_array_equal(np.column_stack([v[f"f_dc_{c}"] for c in range(3)]), posed.sh[:, 0])
    rest = np.column_stack([v[f"f_rest_{i}"] for i in range(3 * (k - 1))]).reshape(-1, 3, k - 1)
    np.testing.assert_array_equal(rest.transpose(0, 2, 1), posed.sh[:, 1:])  # channel-major f_rest
    np.testing.assert_allclose(1 / (1 + np.exp(-v["opacity"].astype(float))), posed.opacities, atol=1e-5)
    np.testing.assert_allclose(np.exp(np.column_stack([v[f"scale_{i}"] for i in range(3)])), posed.scales, rtol=1e-5)
    np.testing.assert_array_equal(np.column_stack([v[f"rot_{i}"] for i in range(4)]), posed.quats)


def test_export_at_the_mean_expression(avatar_file, tmp_path, capsys):
    avatar, path = avatar_file
    out = tmp_path / "posed.ply"
    assert main(["export", str(path), "--out", str(out)]) == 0
    assert "250" in capsys.readouterr().out
    check_ply(out, avatar.pose(None))


def test_export_from_a_sequence_frame_and_an_expr_file(avatar_file, tmp_path):
    avatar, path = avatar_file
    codes = avatar.expression.sample(np.random.default_rng(1), scale=2.0)[None] + np.zeros((3, 1), np.float32)
    codes[1] += 0.5
    seq = tmp_path / "s.npzseq"
    ExpressionSequence(codes, 25.0).save(seq)
    out = tmp_path / "f1.ply"
    assert main(["export", str(path), "--out", str(out), "--sequence", str(seq), "--frame", "1"]) == 0
    posed = avatar.pose(codes[1])
    check_ply(out, posed)
    assert not np.array_equal(posed.means, avatar.pose(None).means)
    npy = tmp_path / "z.npy"
    np.save(npy, codes[2])
    assert main(["export", str(path), "--out", str(tmp_path / "z.ply"), "--expr", str(npy)]) == 0
    check_ply(tmp_path / "z.ply", avatar.pose(codes[2]))


def test_export_errors_exit_2_with_one_line(avatar_file, tmp_path, capsys):
    avatar, path = avatar_file
    seq = tmp_path / "s.npy"
    np.save(seq, np.zeros((4, 10), np.float32))
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, np.zeros((4, 7), np.float32))
    static = tmp_path / "static.ply"
    assert main(["export", str(path), "--out", str(static)]) == 0
    out = str(tmp_path / "o.ply")
    cases = [
        ([str(tmp_path / "missing.npga"), "--out", out], "missing.npga: no such file"),
        ([str(path), "--out", str(tmp_path / "o.txt")], ".ply"),
        ([str(path), "--out", str(tmp_path / "nodir" / "o.ply")], "does not exist"),
        ([str(path), "--out", out, "--sequence", str(seq)], "--frame"),
        ([str(path), "--out", out, "--sequence", str(seq), "--frame", "4"], "frames 0..3"),
        ([str(path), "--out", out, "--sequence", str(seq), "--expr", str(seq), "--frame", "0"], "either"),
        ([str(path), "--out", out, "--frame", "0"], "--frame needs"),
        ([str(path), "--out", out, "--expr", str(wrong)], "7 dims"),
        ([str(static), "--out", out, "--expr", str(seq)], "static"),
    ]
    capsys.readouterr()
    for argv, problem in cases:
        assert main(["export", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert problem in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "o.ply").exists()
