"""Malformed and hostile files: one-line errors naming the file, exit code 2, nothing executed."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.loading import load_avatar
from npga_core.files.ply import save_ply
from npga_view.cli.main import main


class _Bomb:
    """Unpickling this would create a marker file: the reader must never unpickle."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _set(header, name, **kw):
    header["tensors"][name].update(kw)


def _nan_in_means(header, data):
    off = header["tensors"]["gaussians.means"]["offset"]
    data[off : off + 4] = np.float32(np.nan).tobytes()


def _inf_in_weights(header, data):
    off = header["tensors"]["dynamics.G.layers.2.weight"]["offset"]
    data[off + 40 : off + 44] = np.float32(np.inf).tobytes()


def _zero_quat(header, data):
    off = header["tensors"]["gaussians.quats"]["offset"]
    data[off : off + 16] = bytes(16)


def _drop(name):
    def f(header, data):
        del header["tensors"][name]
    return f


def _extra(header, data):
    header["tensors"]["evil.payload"] = dict(header["tensors"]["expression.std"])


def _shape(header, data):
    _set(header, "gaussians.sh", shape=[600, 9, 3])


def _count(header, data):
    header["gaussians"]["count"] = 601


def _dtype(header, data):
    _set(header, "gaussians.means", dtype="float64")


def _future(header, data):
    header["format_version"] = 99


def _overlap(header, data):
    _set(header, "gaussians.quats", offset=header["tensors"]["gaussians.means"]["offset"])


def _out_of_range(header, data):
    _set(header, "expression.mean", offset=2**40)


def _arch(header, data):
    header["dynamics"]["F"]["depth"] = 7


def _part(header, data):
    off = header["tensors"]["gaussians.part_ids"]["offset"]
    data[off : off + 2] = np.int16(99).tobytes()


TAMPERED = {
    "nan in means": (_nan_in_means, "NaN/Inf"),
    "inf in G weights": (_inf_in_weights, "NaN/Inf"),
    "zero quaternion": (_zero_quat, "zero-length"),
    "missing tensor": (_drop("dynamics.F.layers.3.bias"), "missing tensor"),
    "extra tensor": (_extra, "unexpected tensor"),
    "wrong sh shape": (_shape, "shape"),
    "count disagrees with shapes": (_count, "shape"),
    "wrong dtype": (_dtype, "dtype"),
    "future version": (_future, "newer than this reader"),
    "overlapping tensors": (_overlap, "aligned|overlap"),
    "offset beyond the file": (_out_of_range, "truncated"),
    "architecture disagrees with weights": (_arch, "missing tensor|shape"),
    "part id out of range": (_part, "part_ids"),
}


def _raw_files(tmp: Path, good: Path) -> dict[str, tuple[Path, str]]:
    raw = good.read_bytes()
    files: dict[str, tuple[bytes, str]] = {
        "empty": (b"", "empty"),
        "truncated in the data": (raw[: len(raw) // 2], "truncated"),
        "truncated in the header": (raw[:100], "truncated"),
        "only the magic": (raw[:8], "truncated"),
        "wrong magic": (b"GGUF" + raw[4:], "not an .npga"),
        "cut inside the magic": (raw[:5], "truncated"),
        "pickle bomb": (pickle.dumps(_Bomb(str(tmp / "PWNED"))), "not an .npga"),
        "json garbage header": (raw[:8] + (8).to_bytes(8, "little") + b"{]]]]]]]" + raw[24:], "JSON|aligned"),
        "huge header length": (raw[:8] + (2**60).to_bytes(8, "little") + raw[16:], "implausible"),
        "zip renamed": (b"PK\x03\x04" + bytes(60), "not an .npga"),
    }
    out = {}
    for i, (name, (content, msg)) in enumerate(files.items()):
        p = tmp / f"raw{i}.npga"
        p.write_bytes(content)
        out[name] = (p, msg)
    return out


def _ply_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    from npga_core.model.synthetic import make_synthetic_avatar

    good = tmp / "good.ply"
    save_ply(make_synthetic_avatar(30, with_f=False, with_g=False).cloud, good)
    raw = good.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    head = raw[:end].decode()
    cases = {
        "ply missing fields": (head.replace("property float opacity\n", "").encode() + raw[end:], "missing 3DGS"),
        "ply truncated": (raw[: end + 100], "truncated"),
        "ply odd f_rest": (head.replace("property float f_rest_44\n", "").encode() + raw[end:], "f_rest"),
        "ply no end_header": (raw[: end - 11], "end_header"),
        "ply list property": (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                              b"property list uchar int idx\nend_header\n\x00", "list"),
    }
    out = {}
    for i, (name, (content, msg)) in enumerate(cases.items()):
        p = tmp / f"bad{i}.ply"
        p.write_bytes(content)
        out[name] = (p, msg)
    return out


@pytest.mark.parametrize("case", list(TAMPERED))
def test_tampered_checkpoint(case, tamper, capsys):
    mutate, msg = TAMPERED[case]
    path = tamper(mutate)
    with pytest.raises(AvatarFileError, match=msg) as err:
        load_avatar(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)
    assert main(["info", str(path)]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1 and str(path) in out.err and "Traceback" not in out.err


def test_raw_and_ply_files(tmp_path, small_npga, capsys):
    cases = {**_raw_files(tmp_path, small_npga), **_ply_files(tmp_path)}
    assert len(cases) >= 12
    for name, (path, msg) in cases.items():
        with pytest.raises(AvatarFileError, match=msg):
            load_avatar(path)
        assert main(["info", str(path)]) == 2, name
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err, (name, err)
    assert not (tmp_path / "PWNED").exists()


def test_missing_file_and_directory(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.npga")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["info", str(tmp_path)]) == 2
    assert "directory" in capsys.readouterr().err


def test_real_process_exit_code_and_no_traceback(tmp_path):
    bomb = tmp_path / "bomb.npga"
    bomb.write_bytes(pickle.dumps(_Bomb(str(tmp_path / "PWNED"))))
    r = subprocess.run([sys.executable, "-m", "npga_view.cli.main", "info", str(bomb)], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr and str(bomb) in r.stderr
    assert not (tmp_path / "PWNED").exists()


@pytest.mark.parametrize("mutate,msg", [
    (lambda h, d: h["cnn"].update(residual="false"), "residual"),
    (lambda h, d: h["dynamics"]["G"].update(hidden=256.0), "integer"),
    (lambda h, d: h["dynamics"]["F"].update(pos_freqs=500), "pos_freqs"),
    (lambda h, d: h["gaussians"].update(part_names=["a", "a", "b"]), "duplicate"),
    (lambda h, d: h.update(data_nbytes=10**9), "truncated"),
])
def test_loosely_typed_headers_are_refused(tamper, mutate, msg):
    with pytest.raises(AvatarFileError, match=msg):
        load_avatar(tamper(mutate))
