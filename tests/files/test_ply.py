"""3DGS PLY: standard field names and order, round trip, an independent reader."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.files.loading import load_avatar
from npga_core.files.ply import read_ply, save_ply, save_posed_ply, standard_fields
from npga_core.model.synthetic import make_synthetic_avatar


def _independent_read(path):
    """A minimal PLY reader written from the PLY spec, sharing no code with npga_core.files.ply."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0"
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    names = [ln.split()[2] for ln in lines if ln.startswith("property float")]
    data = np.frombuffer(raw[end:], dtype="<f4").reshape(n, len(names))
    return names, data


def test_standard_names_and_order():
    assert standard_fields(3)[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert standard_fields(3)[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert standard_fields(3)[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2",
                                       "rot_3"]
    assert len(standard_fields(0)) == 17


@pytest.mark.parametrize("deg", [0, 1, 2, 3])
def test_round_trip_and_channel_major_f_rest(tmp_path, deg):
    cloud = make_synthetic_avatar(200, sh_degree=deg, with_f=False, with_g=False, seed=deg).cloud
    path = tmp_path / "c.ply"
    save_ply(cloud, path)
    back = read_ply(path)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert np.array_equal(getattr(back, name), getattr(cloud, name)), name
    names, data = _independent_read(path)
    assert names == standard_fields(deg)
    k = (deg + 1) ** 2
    if k > 1:
        # f_rest_{c*(K-1)+j} is coefficient j+1 of channel c
        c, j = 2, k - 2
        col = names.index(f"f_rest_{c * (k - 1) + j}")
        assert np.array_equal(data[:, col], cloud.sh[:, j + 1, c])
    assert np.array_equal(data[:, names.index("opacity")], cloud.opacity_logits)
    assert np.array_equal(data[:, names.index("rot_0")], cloud.quats[:, 0])


def test_posed_export_reads_back(tmp_path):
    a = make_synthetic_avatar(100, seed=4)
    posed = a.pose(a.expression.sample(np.random.default_rng(0)))
    save_posed_ply(posed, tmp_path / "p.ply")
    back = load_avatar(tmp_path / "p.ply").pose()
    np.testing.assert_allclose(back.means, posed.means)
    np.testing.assert_allclose(back.scales, posed.scales, rtol=1e-5)
    np.testing.assert_allclose(back.opacities, posed.opacities, atol=1e-5)
    np.testing.assert_allclose(back.quats, posed.quats, atol=1e-6)


def test_reads_ascii_big_endian_and_extra_properties(tmp_path):
    fields = standard_fields(0)
    rng = np.random.default_rng(0)
    vals = rng.standard_normal((3, len(fields))).astype(np.float32)
    vals[:, fields.index("rot_0")] = 1.0
    extra = "property uchar red\n"
    head = "ply\nformat {fmt} 1.0\nelement vertex 3\n" + "".join(f"property float {f}\n" for f in fields) + extra
    head += "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
    (tmp_path / "a.ply").write_text(head.format(fmt="ascii") + "\n".join(
        " ".join(f"{v:.9g}" for v in row) + " 7" for row in vals) + "\n")
    rec = np.zeros(3, dtype=[(f, ">f4") for f in fields] + [("red", "u1")])
    for i, f in enumerate(fields):
        rec[f] = vals[:, i]
    (tmp_path / "b.ply").write_bytes(head.format(fmt="binary_big_endian").encode() + rec.tobytes())
    for name in ("a.ply", "b.ply"):
        c = read_ply(tmp_path / name)
        np.testing.assert_allclose(c.means, vals[:, :3], rtol=1e-6)
        np.testing.assert_allclose(c.sh[:, 0], vals[:, 6:9], rtol=1e-6)
