"""The `blendshapes` field of an `.npga` (format version 3): round trip, versions, and what the reader refuses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.checkpoint import format_version_for, read_avatar, read_header, save_avatar
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.synthetic import make_synthetic_avatar

D = 12
NAMES = ("eyeBlinkLeft", "eyeBlinkRight", "jawOpen")


def _avatar(with_basis: bool = True):
    a = make_synthetic_avatar(30, code_dim=D, hidden=16, depth=3, n_components=4, seed=3)
    if with_basis:
        rng = np.random.default_rng(5)
        a.blendshapes = BlendshapeBasis(NAMES, rng.normal(size=(D, 3)), rng.normal(size=D), "test map")
    return a


def _rewrite(path: Path, out: Path, mutate_header=None, mutate_data=None) -> Path:
    """`path` with its header and/or data section changed (header re-padded to the 64-byte alignment)."""
    raw = path.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    header = json.loads(raw[16:16 + hlen])
    data = bytearray(raw[16 + hlen:])
    if mutate_header:
        mutate_header(header)
    if mutate_data:
        mutate_data(header, data)
    text = json.dumps(header).encode()
    text += b" " * ((-(16 + len(text))) % 64)
    out.write_bytes(raw[:8] + len(text).to_bytes(8, "little") + text + bytes(data))
    return out


@pytest.fixture
def saved(tmp_path) -> Path:
    path = tmp_path / "with_basis.npga"
    save_avatar(_avatar(), path)
    return path


def test_round_trip(saved):
    src = _avatar()
    back = read_avatar(saved)
    assert back.blendshapes is not None and back.blendshapes.names == NAMES
    assert back.blendshapes.source == "test map"
    np.testing.assert_array_equal(back.blendshapes.matrix, src.blendshapes.matrix)
    np.testing.assert_array_equal(back.blendshapes.offset, src.blendshapes.offset)
    header = read_header(saved)[0]
    assert header["format_version"] == 3
    assert header["blendshapes"] == {"names": list(NAMES), "source": "test map", "dim": D}
    assert header["tensors"]["blendshapes.matrix"]["shape"] == [D, 3]
    # the avatar poses the same after the round trip (its dynamics were written in the version-3 form)
    w = np.array([1.0, 0.0, 0.5], np.float32)
    z = back.blendshapes.codes(w)
    np.testing.assert_allclose(back.pose(z).means, src.pose(src.blendshapes.codes(w)).means, atol=1e-6)
    # saving again keeps it
    save_avatar(back, saved)
    assert read_avatar(saved).blendshapes.names == NAMES


def test_version_is_the_oldest_that_fits(tmp_path):
    plain = _avatar(with_basis=False)
    assert format_version_for(plain) == 1 and format_version_for(_avatar()) == 3
    path = tmp_path / "plain.npga"
    save_avatar(plain, path)
    assert read_header(path)[0]["format_version"] == 1 and read_avatar(path).blendshapes is None


def test_older_versions_ignore_the_key(tmp_path):
    """In a version-1 file `blendshapes` is an unknown key (ignored), and implies no tensors."""
    path = tmp_path / "v1.npga"
    save_avatar(_avatar(with_basis=False), path)
    out = _rewrite(path, tmp_path / "v1_key.npga", lambda h: h.update(blendshapes={"names": ["x"], "dim": D}))
    assert read_avatar(out).blendshapes is None


def _scale_matrix(value: float):
    def f(header, data):
        e = header["tensors"]["blendshapes.matrix"]
        data[e["offset"]:e["offset"] + 4] = np.float32(value).tobytes()
    return f


BAD_HEADERS = {
    "names not a list": (lambda h: h["blendshapes"].update(names="jawOpen"),
                          "blendshapes.names: expected a list, got a string"),
    "duplicate names": (lambda h: h["blendshapes"].update(names=["a", "a", "b"]), "duplicate"),
    "empty name": (lambda h: h["blendshapes"].update(names=["a", "", "b"]),
                    r"blendshapes.names\[1\]: expected a string of length >= 1"),
    "dim a string": (lambda h: h["blendshapes"].update(dim="12"), "blendshapes.dim: expected an integer, got a string"),
    "dim is a bool": (lambda h: h["blendshapes"].update(dim=True),
                      "blendshapes.dim: expected an integer, got a boolean"),
    "dim too large": (lambda h: h["blendshapes"].update(dim=10**9),
                      "blendshapes.dim: expected an integer <= 65536, got 1000000000"),
    "not an object": (lambda h: h.update(blendshapes=[1, 2]), "blendshapes: expected an object, got a list"),
    "source a number": (lambda h: h["blendshapes"].update(source=3),
                         "blendshapes.source: expected a string, got an integer"),
    "tensor missing": (lambda h: h["tensors"].pop("blendshapes.offset"), "missing tensor"),
    "names disagree with the matrix": (lambda h: h["blendshapes"].update(names=["a", "b"]), "shape"),
}


@pytest.mark.parametrize("case", sorted(BAD_HEADERS))
def test_bad_headers_are_refused(saved, tmp_path, case):
    mutate, message = BAD_HEADERS[case]
    out = _rewrite(saved, tmp_path / "bad.npga", mutate)
    with pytest.raises(AvatarFileError, match=message) as e:
        read_avatar(out)
    assert str(out) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(("value", "message"), [(np.nan, "NaN/Inf"), (np.inf, "NaN/Inf"), (3e30, "beyond")])
def test_bad_values_are_refused(saved, tmp_path, value, message):
    out = _rewrite(saved, tmp_path / "bad.npga", mutate_data=_scale_matrix(value))
    with pytest.raises(AvatarFileError, match=message):
        read_avatar(out)


def _five_dims(h):
    h["blendshapes"]["dim"] = 5
    h["tensors"]["blendshapes.matrix"].update(shape=[5, 3], nbytes=60)
    h["tensors"]["blendshapes.offset"].update(shape=[5], nbytes=20)


def test_dim_must_fit_the_code(saved, tmp_path):
    """A basis of 5-D codes in a 12-D avatar: the writer refuses it, and so does the reader (header and
    tensors consistent with each other)."""
    a = _avatar()
    rng = np.random.default_rng(1)
    a.blendshapes = BlendshapeBasis(NAMES, rng.normal(size=(5, 3)), rng.normal(size=5))
    with pytest.raises(ValueError, match="5-D codes.*12 dims"):
        save_avatar(a, tmp_path / "dim.npga")
    assert not (tmp_path / "dim.npga").exists()
    out = _rewrite(saved, tmp_path / "dim.npga", _five_dims)
    with pytest.raises(AvatarFileError, match="5-D codes.*12 dims"):
        read_avatar(out)


def test_static_avatar_with_a_basis_is_refused(saved, tmp_path):
    a = _avatar()
    a.dynamics = None
    a.expression = None
    with pytest.raises(ValueError, match="static"):
        save_avatar(a, tmp_path / "static.npga")
