"""Round trips of the .npga format and the posed output."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.checkpoint import FORMAT_VERSION, read_avatar, save_avatar
from npga_core.files.loading import load_avatar
from npga_core.model.gaussians import PER_GAUSSIAN_FIELDS
from npga_core.model.synthetic import make_synthetic_avatar


def test_round_trip_arrays_identical(small_avatar, small_npga):
    b = read_avatar(small_npga)
    for name in PER_GAUSSIAN_FIELDS:
        x, y = getattr(small_avatar.cloud, name), getattr(b.cloud, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert b.cloud.part_names == small_avatar.cloud.part_names
    for key, net in small_avatar.dynamics.networks().items():
        other = b.dynamics.networks()[key]
        assert net.config == other.config
        for (k1, t1), (k2, t2) in zip(net.state_dict().items(), other.state_dict().items(), strict=True):
            assert k1 == k2 and np.array_equal(t1.numpy(), t2.numpy()), k1
    ex, ey = small_avatar.expression, b.expression
    assert np.array_equal(ex.mean, ey.mean) and np.array_equal(ex.basis, ey.basis) and np.array_equal(ex.std, ey.std)
    assert list(ex.named) == list(ey.named)
    assert b.provenance["source"] == "synthetic"


def test_round_trip_posed_output_identical(small_avatar, small_npga):
    b = read_avatar(small_npga)
    rng = np.random.default_rng(0)
    for _ in range(3):
        z = small_avatar.expression.sample(rng)
        p, q = small_avatar.pose(z), b.pose(z)
        for name in ("means", "quats", "scales", "opacities", "sh", "latent"):
            assert np.array_equal(getattr(p, name), getattr(q, name)), name


def test_cnn_round_trip(small_avatar, small_npga):
    b = read_avatar(small_npga)
    img = np.random.default_rng(1).random((12, 10, 7), dtype=np.float32)
    assert np.array_equal(small_avatar.cnn.refine(img), b.cnn.refine(img))


def test_arrays_are_read_into_memory_and_read_only(small_npga, tmp_path):
    b = read_avatar(small_npga)
    assert not isinstance(b.cloud.means.base, np.memmap) and not isinstance(b.cloud.means, np.memmap)
    with pytest.raises(ValueError):
        b.cloud.means[0, 0] = 1.0
    # nothing stays mapped: truncating the file afterwards (another program rewriting it) cannot crash the reader
    copy = tmp_path / "copy.npga"
    copy.write_bytes(small_npga.read_bytes())
    c = read_avatar(copy)
    with open(copy, "r+b") as fh:
        fh.truncate(100)
    assert np.isfinite(c.cloud.sh).all() and np.array_equal(c.cloud.means, b.cloud.means)


def test_static_and_minimal_avatars_round_trip(tmp_path):
    a = make_synthetic_avatar(50, sh_degree=0, feature_dim=0, with_f=False, with_g=False, parts=False)
    save_avatar(a, tmp_path / "s.npga")
    b = read_avatar(tmp_path / "s.npga")
    assert b.dynamics is None and b.expression is None and b.code_dim == 0
    assert np.array_equal(b.pose().means, a.cloud.means)
    g_only = make_synthetic_avatar(40, sh_degree=1, with_f=False, feature_dim=3, code_dim=7, hidden=16, depth=3)
    save_avatar(g_only, tmp_path / "g.npga")
    c = read_avatar(tmp_path / "g.npga")
    z = np.ones(7, np.float32)
    assert np.array_equal(c.pose(z).means, g_only.pose(z).means)
    empty = a.cloud.subset(np.zeros(0, int))
    a.cloud = empty
    save_avatar(a, tmp_path / "e.npga")
    assert len(read_avatar(tmp_path / "e.npga").cloud) == 0


def test_save_is_atomic_and_leaves_no_temp_files(tmp_path, small_avatar, monkeypatch):
    target = tmp_path / "a.npga"
    save_avatar(small_avatar, target)
    before = target.read_bytes()

    import npga_core.files.atomic as atomic

    def explode(*a, **k):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(atomic.os, "fsync", explode)
    with pytest.raises(OSError):
        save_avatar(make_synthetic_avatar(10, seed=9), target)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["a.npga"]


def test_header_records_version_architecture_provenance(small_npga):
    from npga_core.files.checkpoint import read_header

    header, start = read_header(small_npga)
    # NPGA's own F and G are written in the oldest version that holds them, so older readers open them
    assert header["format_version"] == 1 <= FORMAT_VERSION and start % 64 == 0
    assert header["dynamics"]["F"]["depth"] == 6 and header["dynamics"]["G"]["hidden"] == 256
    assert header["expression"]["dim"] == 100
    assert "created_at" in header["provenance"] and "written_by" in header["provenance"]


def test_load_avatar_dispatches_on_content_not_name(tmp_path, small_npga):
    renamed = tmp_path / "avatar.ply"
    renamed.write_bytes(small_npga.read_bytes())
    assert load_avatar(renamed).code_dim == 100


def test_saved_files_get_umask_permissions(tmp_path, small_avatar):
    import os

    save_avatar(small_avatar, tmp_path / "p.npga")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "p.npga").stat().st_mode & 0o777 == 0o666 & ~mask
