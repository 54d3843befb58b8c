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
