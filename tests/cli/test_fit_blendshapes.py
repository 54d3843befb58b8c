"""`npga-view fit-blendshapes`: least squares from a paired ARKit take and code sequence; the basis file."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.arkit_takes import Take, write_livelink_csv
from npga_core.files.basis_file import read_basis, save_basis
from npga_core.files.blendshape_names import ARKIT_52
from npga_core.files.loading import load_sequence
from npga_core.files.sequences import ExpressionSequence
from npga_core.model.blendshapes import BlendshapeBasis
from npga_view.cli.main import main


@pytest.fixture
def paired(tmp_path):
    rng = np.random.default_rng(5)
    truth = BlendshapeBasis(ARKIT_52, rng.standard_normal((16, 52)), rng.standard_normal(16), "truth")
    w = rng.uniform(0, 1, (150, 52)).astype(np.float32)
    take = tmp_path / "take.csv"
    write_livelink_csv(take, Take(w, ARKIT_52, np.arange(150) / 60.0, 60.0), start=36000.0)
    codes = tmp_path / "codes.npzseq"
    ExpressionSequence(truth.codes(w), 60.0, "tracked").save(codes)
    return truth, w, take, codes


def test_fit_recovers_the_basis_and_reports_its_error(paired, tmp_path, capsys):
    truth, w, take, codes = paired
    out = tmp_path / "basis.npz"
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out", str(out)]) == 0
    assert "RMS residual" in capsys.readouterr().out
    basis = read_basis(out)
    assert basis.names == ARKIT_52
    np.testing.assert_allclose(basis.matrix, truth.matrix, atol=2e-3)
    np.testing.assert_allclose(basis.codes(w), truth.codes(w), atol=2e-3)
    seq = load_sequence(take, basis=basis)  # the fitted basis drives the take
    np.testing.assert_allclose(seq.codes, truth.codes(w), atol=2e-3)


def test_fit_refuses_unpaired_takes_and_bad_outputs(paired, tmp_path, capsys):
    _, _, take, codes = paired
    short = tmp_path / "short.npzseq"
    ExpressionSequence(np.zeros((10, 16), np.float32), 60.0).save(short)
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(short), "--out",
                 str(tmp_path / "b.npz")]) == 2
    assert "paired" in capsys.readouterr().err
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out",
                 str(tmp_path / "b.txt")]) == 2


def test_basis_file_refuses_pickles_and_bad_shapes(tmp_path):
    p = tmp_path / "b.npz"
    np.savez(p, names=np.array([{"a": 1}], dtype=object), matrix=np.zeros((3, 1)), offset=np.zeros(3))
    with pytest.raises(AvatarFileError, match="b.npz"):
        read_basis(p)
    np.savez(p, names=np.array(["a", "b"]), matrix=np.zeros((3, 1)), offset=np.zeros(3))
    with pytest.raises(AvatarFileError, match="disagree"):
        read_basis(p)
    good = BlendshapeBasis(("a",), np.ones((3, 1)), np.zeros(3), "x")
    save_basis(good, p)
    assert read_basis(p).source == "x"


def test_fit_into_an_avatar_writes_a_copy_that_takes_drive(paired, tmp_path, capsys):
    """`--into A.npga --out B.npga`: B is A with the fitted basis (version 3), A is unchanged, and a take then
    drives B through it (render's --sequence) and the basis file through --basis."""
    from npga_core.files.checkpoint import read_avatar, save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar

    truth, w, take, codes = paired
    avatar = make_synthetic_avatar(200, code_dim=16, hidden=16, depth=2, n_components=4, seed=9)
    a_path, b_path = tmp_path / "a.npga", tmp_path / "b.npga"
    save_avatar(avatar, a_path)
    before = a_path.read_bytes()
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--into", str(a_path),
                 "--out", str(b_path)]) == 0
    assert a_path.read_bytes() == before
    b = read_avatar(b_path)
    assert b.blendshapes is not None and b.blendshapes.names == ARKIT_52
    np.testing.assert_allclose(b.blendshapes.codes(w), truth.codes(w), atol=2e-3)
    capsys.readouterr()
    out = tmp_path / "x.ply"
    assert main(["export", str(b_path), "--sequence", str(take), "--frame", "3", "--out", str(out)]) == 0
    basis = tmp_path / "basis.npz"
    save_basis(truth, basis)
    out2 = tmp_path / "y.ply"  # the original avatar with the basis given on the command line
    assert main(["export", str(a_path), "--basis", str(basis), "--sequence", str(take), "--frame", "3",
                 "--out", str(out2)]) == 0
    from npga_core.files.ply import read_ply

    np.testing.assert_allclose(read_ply(out).means, read_ply(out2).means, atol=1e-3)
    assert main(["export", str(a_path), "--sequence", str(take), "--frame", "3", "--out", str(out2)]) == 2
    assert "no blendshape basis" in capsys.readouterr().err  # no detour through the demo's map


def test_unexcited_shapes_are_listed_and_left_out(tmp_path, capsys):
    rng = np.random.default_rng(2)
    w = rng.uniform(0, 1, (120, 52)).astype(np.float32)
    dead = [ARKIT_52.index(n) for n in ("tongueOut", "cheekPuff", "noseSneerLeft")]
    w[:, dead] = 0.004
    truth = BlendshapeBasis(ARKIT_52, rng.standard_normal((8, 52)), rng.standard_normal(8), "truth")
    take, codes = tmp_path / "take.csv", tmp_path / "codes.npzseq"
    write_livelink_csv(take, Take(w, ARKIT_52, np.arange(120) / 30.0, 30.0), start=36000.0)
    ExpressionSequence(truth.codes(w), 30.0).save(codes)
    out = tmp_path / "b.npz"
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fitted 49 shapes" in text and "3 shapes never move" in text and "tongueOut" in text
    assert "tongueOut" not in read_basis(out).names
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out", str(out),
                 "--keep-unexcited"]) == 0
    assert "fitted 52 shapes" in capsys.readouterr().out and len(read_basis(out).names) == 52


def test_fit_refuses_ridge_0_and_a_take_spanning_a_day(tmp_path, capsys):
    take = tmp_path / "long.csv"
    w = np.random.default_rng(0).uniform(0, 1, (3, 52)).astype(np.float32)
    write_livelink_csv(take, Take(w, ARKIT_52, np.array([0.0, 1.0, 82800.0]), 60.0), start=0.0)
    codes = tmp_path / "c.npy"
    np.save(codes, np.zeros((3, 4), np.float32))
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out",
                 str(tmp_path / "b.npz"), "--ridge", "0"]) == 2
    assert "--ridge" in capsys.readouterr().err
    assert main(["fit-blendshapes", "--take", str(take), "--codes", str(codes), "--out",
                 str(tmp_path / "b.npz")]) == 2  # 23 hours of frames: bounded like any take, no 10 GB resample
    err = capsys.readouterr().err
    assert "frames" in err and len(err.strip().splitlines()) == 1
