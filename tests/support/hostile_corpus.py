"""Hostile files for every reader, generated (never stored): huge claimed shapes, truncations, wrong shapes,
NaN/Inf, complex and object dtypes (pickles whose unpickling would create a marker file), FIFOs, directories,
devices, empty files, deeply nested JSON, huge numbers, wrong types.

Each builder writes its cases under a folder and returns {case name: path}. `test_hostile_files.py` runs every
case through the command line (or, for caches, through the reader the viewer's worker uses).
"""

from __future__ import annotations

import io
import json
import os
import pathlib
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from tests.support.hostile_values_corpus import _broken_stream, _floats_set, _ply_column, _pose, degenerate_avatars  # noqa: F401

MARKER = "UNPICKLED"  # created next to the corpus if anything is ever unpickled


class Bomb:
    """Unpickling this touches a marker file."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (pathlib.Path.touch, (pathlib.Path(self.marker),))


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=arr.dtype.hasobject)
    return buf.getvalue()


def npy_header(shape: tuple, descr: str = "<f4", version: tuple[int, int] = (1, 0)) -> bytes:
    """A valid .npy header claiming `shape` of `descr`, with no data after it."""
    buf = io.BytesIO()
    d = {"descr": descr, "fortran_order": False, "shape": shape}
    writer = np.lib.format.write_array_header_1_0 if version == (1, 0) else np.lib.format.write_array_header_2_0
    writer(buf, d)  # numpy's own header writer
    return buf.getvalue()


def _pickled(marker: Path) -> np.ndarray:
    a = np.empty(2, dtype=object)
    a[0], a[1] = Bomb(marker), Bomb(marker)
    return a


def _special(folder: Path, name: str) -> dict[str, Path]:
    """The kinds of path no reader may open for reading: a FIFO, a directory, a character device, nothing."""
    fifo, directory, device = folder / f"fifo-{name}", folder / f"dir-{name}", folder / f"dev-{name}"
    os.mkfifo(fifo)
    directory.mkdir()
    device.symlink_to("/dev/zero")
    return {"fifo": fifo, "directory": directory, "char device (/dev/zero)": device,
            "missing": folder / f"missing-{name}"}


def _write_all(folder: Path, suffix: str, cases: dict[str, bytes]) -> dict[str, Path]:
    out = {}
    for i, (name, content) in enumerate(cases.items()):
        p = folder / f"case{i:02d}{suffix}"
        p.write_bytes(content)
        out[name] = p
    return out


# -- arrays ----------------------------------------------------------------------------------------------------
def npy_codes(folder: Path, dim: int) -> dict[str, Path]:
    """Expression codes as .npy (`--expr`, `--sequence x.npy`)."""
    marker = folder / MARKER
    good = np.zeros((4, dim), np.float32)
    raw = _npy(good)
    cases = {
        "huge claimed shape": npy_header((10**9, 10**6)),
        "huge claimed shape, version 2 header": npy_header((2**40, dim), version=(2, 0)),
        "claims more than the file holds": npy_header((1000, dim)) + bytes(64),
        "truncated data": raw[:-7],
        "truncated header": raw[:20],
        "header is not a dict": b"\x93NUMPY\x01\x00\x10\x00" + b"__import__('os')\n",
        "4-d shape": _npy(np.zeros((2, 2, 2, dim), np.float32)),
        "0 frames": _npy(np.zeros((0, dim), np.float32)),
        "wrong code dims": _npy(np.zeros((4, dim + 1), np.float32)),
        "NaN": _npy(np.full((4, dim), np.nan, np.float32)),
        "Inf": _npy(np.full((4, dim), -np.inf, np.float64)),
        "beyond float32": _npy(np.full((4, dim), 1e300, np.float64)),
        "complex": _npy(np.ones((4, dim), np.complex64)),
        "object (pickle)": _npy(_pickled(marker)),
        "structured": _npy(np.zeros(4, dtype=[("a", "<f4", (dim,))])),
        "strings": _npy(np.array(["x"] * 4)),
        "bool": _npy(np.ones((4, dim), bool)),
        "empty file": b"",
        "garbage": os.urandom(256),
        "codes of 3e38 (finite, overflow in the dynamics)": _npy(np.full((4, dim), 3e38, np.float32)),
    }
    return {**_write_all(folder, ".npy", cases), **_special(folder, "codes.npy")}


def _zip(members: dict[str, bytes], compress: bool = False) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _zip_bomb(dim: int) -> bytes:
    """A deflated member whose header claims 4 GB of codes (zeros compress ~1000:1)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf, zf.open("codes.npy", "w", force_zip64=True) as m:
        m.write(npy_header((2**30 // dim * 4, dim)))
        zero = bytes(1 << 20)
        for _ in range(64):  # 64 MiB of zeros, ~64 KiB compressed; the header claims far more
            m.write(zero)
    return buf.getvalue()


def npz_sequences(folder: Path, dim: int) -> dict[str, Path]:
    """`.npzseq`/`.npz` sequences (`--sequence`)."""
    marker = folder / MARKER
    codes = _npy(np.zeros((4, dim), np.float32))
    good = _zip({"codes.npy": codes, "fps.npy": _npy(np.float64(25.0))})
    cases = {
        "member claims a huge shape": _zip({"codes.npy": npy_header((10**9, 10**6))}),
        "deflated member claims 4 GB": _zip_bomb(dim),
        "member truncated": _zip({"codes.npy": codes[:-9]}),
        "1000 members": _zip({f"m{i}.npy": codes for i in range(1000)}),
        "complex codes": _zip({"codes.npy": _npy(np.ones((4, dim), np.complex128))}),
        "object codes (pickle)": _zip({"codes.npy": _npy(_pickled(marker))}),
        "object fps (pickle)": _zip({"codes.npy": codes, "fps.npy": _npy(_pickled(marker))}),
        "NaN codes": _zip({"codes.npy": _npy(np.full((4, dim), np.nan, np.float32))}),
        "fps is NaN": _zip({"codes.npy": codes, "fps.npy": _npy(np.float64(np.nan))}),
        "fps is an array": _zip({"codes.npy": codes, "fps.npy": _npy(np.ones(3))}),
        "fps is huge": _zip({"codes.npy": codes, "fps.npy": _npy(np.float64(1e308))}),
        "codes are 1-d": _zip({"codes.npy": _npy(np.zeros(dim, np.float32))}),
        "no codes": _zip({"weights.npy": codes}),
        "frame names disagree": _zip({"codes.npy": codes, "frame_names.npy": _npy(np.array(["a", "b"]))}),
        "zip cut in half": good[: len(good) // 2],
        "not a zip": b"PK\x05\x06" + os.urandom(100),
        "empty file": b"",
        "codes of 3e38": _zip({"codes.npy": _npy(np.full((4, dim), 3e38, np.float32))}),
        "fps 1e-300": _zip({"codes.npy": codes, "fps.npy": _npy(np.float64(1e-300))}),
        "pose translations 1e308": _zip({"codes.npy": codes, "pose.npy": _npy(_pose(4, 1e308))}),
        "old-style translation 1e308": _zip({"codes.npy": codes, "translation.npy": _npy(np.full((4, 3), 1e308))}),
        "NeRSemble tracking, translations 1e308": _zip({
            "expression.npy": codes, "rotation.npy": _npy(np.zeros((4, 3))), "translation.npy":
            _npy(np.full((4, 3), 1e308)), "scale.npy": _npy(np.ones((1, 1))), "jaw.npy": _npy(np.zeros((4, 3))),
            "neck.npy": _npy(np.zeros((4, 3))), "eyes.npy": _npy(np.zeros((4, 6)))}),
        "GaussianAvatars flame_param, translations 1e308": _zip({
            "expr.npy": codes, "rotation.npy": _npy(np.zeros((4, 3))), "translation.npy":
            _npy(np.full((4, 3), 1e308)), "neck_pose.npy": _npy(np.zeros((4, 3))),
            "jaw_pose.npy": _npy(np.zeros((4, 3))), "eyes_pose.npy": _npy(np.zeros((4, 6)))}),
        "broken deflate stream": _broken_stream({"codes.npy": _npy(np.arange(4 * dim, dtype=np.float32)
                                                                   .reshape(4, dim))}, zipfile.ZIP_DEFLATED),
    }
    return {**_write_all(folder, ".npz", cases), **_special(folder, "seq.npz")}


def mononphm_folders(folder: Path, dim: int) -> dict[str, Path]:
    """MonoNPHM tracking folders (ROOT/00000/z_exp.npy ...; `--sequence ROOT`)."""
    marker = folder / MARKER
    ok = _npy(np.zeros((1, dim), np.float32))
    frames: dict[str, list[bytes | str]] = {
        "z_exp claims a huge shape": [npy_header((10**9, 10**6)), ok],
        "z_exp truncated": [ok, ok[:-5]],
        "z_exp complex": [ok, _npy(np.ones((1, dim), np.complex64))],
        "z_exp object (pickle)": [_npy(_pickled(marker)), ok],
        "z_exp NaN": [ok, _npy(np.full((1, dim), np.nan, np.float32))],
        "z_exp strings": [_npy(np.array(["z"] * dim)), ok],
        "codes of different sizes": [ok, _npy(np.zeros((1, dim + 3), np.float32))],
        "z_exp 3-d": [_npy(np.zeros((2, 3, dim), np.float32)), ok],
        "z_exp empty file": [b"", ok],
        "z_exp is a FIFO": ["fifo", "fifo"],
        "z_exp is a directory": ["dir", "dir"],
        "no frames at all": [],
        "z_exp of 3e38": [ok, _npy(np.full((1, dim), 3e38, np.float32))],
        "only a frame folder named with a superscript digit": [("\u00b2", ok)],
        "only a frame folder named with Arabic-Indic digits": [("\u0660\u0660\u0661", ok)],
    }
    out = {}
    for i, (name, files) in enumerate(frames.items()):
        root = folder / f"track{i:02d}"
        root.mkdir()
        for t, content in enumerate(files):
            d = root / f"{t:05d}"
            if isinstance(content, tuple):  # (folder name, content)
                d, content = root / content[0], content[1]
            d.mkdir()
            target = d / "z_exp.npy"
            if content == "fifo":
                os.mkfifo(target)
            elif content == "dir":
                target.mkdir()
            else:
                target.write_bytes(content)
        out[name] = root
    return out


# -- avatars ---------------------------------------------------------------------------------------------------
def npga_files(folder: Path, good: Path) -> dict[str, Path]:
    """`.npga` checkpoints (`info`, and autosaves through `EditSession.recover`)."""
    raw = good.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    header, data = json.loads(raw[16:16 + hlen]), raw[16 + hlen:]

    def with_header(mutate: Callable[[dict], None] | None = None, text: bytes | None = None) -> bytes:
        h = json.loads(json.dumps(header))
        if mutate is not None:
            mutate(h)
        t = text if text is not None else json.dumps(h).encode()
        t += b" " * ((-(16 + len(t))) % 64)
        return raw[:8] + len(t).to_bytes(8, "little") + t + data

    def count(h):
        h["gaussians"]["count"] = 10**12

    def shape(h):
        h["tensors"]["gaussians.means"]["shape"] = [10**12, 3]

    def dtype(h):
        h["tensors"]["gaussians.means"]["dtype"] = "complex64"

    def objdtype(h):
        h["tensors"]["gaussians.means"]["dtype"] = "object"

    def wrong_type(h):
        h["gaussians"]["count"] = "600"

    def with_values(tensor: str, value: float) -> bytes:
        """The good file with every value of `tensor` replaced (the data section, offsets from the header)."""
        spec = header["tensors"][tensor]
        body = bytearray(data)
        n = spec["nbytes"] // 4
        body[spec["offset"]:spec["offset"] + 4 * n] = np.full(n, value, np.float32).tobytes()
        return raw[:16 + hlen] + bytes(body)

    nested = b'{"format": "npga", "x": ' + b"[" * 50000 + b"]" * 50000 + b"}"
    cases = {
        "empty file": b"",
        "truncated header": raw[:40],
        "truncated data": raw[: len(raw) - 1000],
        "header length 2^63": raw[:8] + (2**63).to_bytes(8, "little") + raw[16:],
        "deeply nested header": with_header(text=nested),
        "header claims 10^12 Gaussians": with_header(count),
        "tensor claims 10^12 rows": with_header(shape),
        "complex tensor": with_header(dtype),
        "object tensor": with_header(objdtype),
        "count is a string": with_header(wrong_type),
        "NaN constant in header": with_header(text=json.dumps(header).replace('"units": "m"', '"units": NaN').encode()),
        "huge number in header": with_header(text=json.dumps(header).replace('"format_version": 1',
                                                                             '"format_version": 1e999').encode()),
        "garbage": os.urandom(4096),
        "expression std 1e-45": with_values("expression.std", 1e-45),
        "expression mean 3e38": with_values("expression.mean", 3e38),
        "integer of 5000 digits in the header": with_header(text=json.dumps(header).replace(
            '"format_version": 1', '"format_version": ' + "9" * 5000).encode()),
    }
    return {**_write_all(folder, ".npga", cases), **_special(folder, "avatar.npga")}


def ply_files(folder: Path, good: Path) -> dict[str, Path]:
    """3DGS `.ply` files (`info`)."""
    raw = good.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    head = raw[:end].decode()
    n = int(head.split("element vertex ")[1].split()[0])
    body = np.frombuffer(raw[end:], np.float32).copy()
    nan = body.copy()
    nan[0] = np.nan
    cases = {
        "10^10 vertices claimed": head.replace(f"element vertex {n}", "element vertex 9999999999").encode() + raw[end:],
        "count too long": head.replace(f"element vertex {n}", "element vertex 99999999999999999999").encode(),
        "truncated": raw[: end + 37],
        "NaN position": head.encode() + nan.tobytes(),
        "list property": head.replace("property float x\n", "property list uchar int x\n").encode() + raw[end:],
        "unknown format": head.replace("binary_little_endian", "binary_middle_endian").encode() + raw[end:],
        "no end_header, 2 MB of comments": b"ply\nformat ascii 1.0\n" + b"comment " + b"x" * (2 << 20) + b"\n",
        "ascii with a word": head.replace("binary_little_endian", "ascii").encode() + b"1 2 three\n",
        "unknown property type": head.replace("property float x\n", "property complex x\n").encode() + raw[end:],
        "non-ASCII header": head.replace("ply\n", "ply\ncomment \xff\xfe\n").encode("latin-1") + raw[end:],
        "empty file": b"",
        "only the word ply": b"ply",
        "log-scales of 100": head.encode() + _ply_column(body, head, "scale_0", 100.0),
        "quaternions of 1e30": head.encode() + _ply_column(body, head, "rot_0", 1e30),
        "positions of 1e30": head.encode() + _ply_column(body, head, "x", 1e30),
        "bare property line": head.replace("property float x\n", "property\nproperty float x\n").encode()
        + raw[end:],
        # #36: numpy's warnings (loadtxt's notices, overflow in a cast) were printed before the one line
        "ascii with no vertex rows": head.replace("binary_little_endian", "ascii").encode(),
        "ascii with empty lines only": head.replace("binary_little_endian", "ascii").encode() + b"\n\n\n",
        "ascii values of 1e300": head.replace("binary_little_endian", "ascii").encode()
        + (" ".join(["1e300"] * head.count("property ")) + "\n").encode() * n,
    }
    out = _write_all(folder, ".ply", cases)
    sparse = folder / "sparse.ply"  # claims 5e8 vertices; the file really is that long (sparse, no disk used)
    big = head.replace(f"element vertex {n}", "element vertex 500000000")
    with open(sparse, "wb") as fh:
        fh.write(big.encode())
        fh.truncate(len(big) + 500_000_000 * 4 * len(body) // max(n, 1))
    out["sparse file claiming 5e8 vertices"] = sparse
    return {**out, **_special(folder, "avatar.ply")}


# -- JSON ------------------------------------------------------------------------------------------------------
def _json_common() -> dict[str, bytes]:
    return {
        "nested 100000 deep": b"[" * 100000 + b"]" * 100000,
        "nested 100000 deep in an object": b'{"a": ' + b'{"a": ' * 100000 + b"1" + b"}" * 100001,
        "NaN": b'{"x": NaN}',
        "number 1e999": b'{"x": 1e999}',
        "integer with 5000 digits": b'{"x": ' + b"9" * 5000 + b"}",
        "not JSON": b"\x89PNG\r\n\x1a\n" + os.urandom(64),
        "invalid UTF-8": b'{"x": "\xff\xfe"}',
        "truncated": b'{"x": [1, 2',
        "20 MB of spaces": b" " * (20 << 20) + b"{}",
        "empty file": b"",
    }


def camera_json(folder: Path) -> dict[str, Path]:
    """Camera files of `render --camera` (Camera.to_dict: width, height, fx, fy, cx, cy, world_to_camera)."""
    good = {"width": 64, "height": 48, "fx": 80.0, "fy": 80.0, "cx": 32.0, "cy": 24.0,
            "world_to_camera": np.eye(4).tolist()}

    def cam(**kw) -> bytes:
        return json.dumps({**good, **kw}).encode()

    cases = {**_json_common(),
             "width 10^9": cam(width=10**9),
             "height 10^6": cam(height=10**6),
             "width 16385": cam(width=16385),
             "width 0": cam(width=0),
             "width a string": cam(width="64"),
             "width 2.5": cam(width=2.5),
             "fx negative": cam(fx=-1.0),
             "fx 1e308 times 10": cam(fx=1e308).replace(b"1e+308", b"1e309"),
             "3x3 world_to_camera": cam(world_to_camera=np.eye(3).tolist()),
             "world_to_camera strings": cam(world_to_camera=[["a"] * 4] * 4),
             "a list": b"[1, 2, 3]",
             "width true": cam(width=True),
             "fx 1e300": cam(fx=1e300, fy=1e300),
             "cx 1e300": cam(cx=1e300),
             "singular world_to_camera": cam(world_to_camera=np.diag([0.0, 0.0, 0.0, 1.0]).tolist()),
             "skewed world_to_camera": cam(world_to_camera=[[1, 5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
             "translation 1e300": cam(world_to_camera=[[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])}
    return {**_write_all(folder, ".json", cases), **_special(folder, "camera.json")}


def rig_json(folder: Path) -> dict[str, Path]:
    """NeRSemble `camera_params.json` rigs (`--rig`)."""
    k = [[800.0, 0.0, 275.0], [0.0, 800.0, 401.0], [0.0, 0.0, 1.0]]
    good = {"world_2_cam": {"220700191": np.eye(4).tolist()}, "intrinsics": k}

    def rig(**kw) -> bytes:
        return json.dumps({**good, **kw}).encode()

    huge_k = [[800.0, 0.0, 1e9], [0.0, 800.0, 1e9], [0.0, 0.0, 1.0]]
    cases = {**_json_common(),
             "image_size 10^9": rig(image_size=[10**9, 10**9]),
             "image size from cx, cy = 1e9": rig(intrinsics=huge_k),
             "image_size strings": rig(image_size=["550", "802"]),
             "intrinsics 2x2": rig(intrinsics=[[1, 0], [0, 1]]),
             "intrinsics strings": rig(intrinsics=[["a"] * 3] * 3),
             "world_2_cam a list": rig(world_2_cam=[np.eye(4).tolist()]),
             "world_2_cam 3x4": rig(world_2_cam={"a": np.eye(4)[:3].tolist()}),
             "5000 cameras": rig(world_2_cam={str(i): np.eye(4).tolist() for i in range(5000)}),
             "no cameras": rig(world_2_cam={}),
             "missing intrinsics": json.dumps({"world_2_cam": good["world_2_cam"]}).encode(),
             "focal length 1e300": rig(intrinsics=[[1e300, 0.0, 275.0], [0.0, 1e300, 401.0], [0.0, 0.0, 1.0]]),
             "singular world_2_cam": rig(world_2_cam={"a": np.diag([0.0, 0.0, 0.0, 1.0]).tolist()})}
    return {**_write_all(folder, ".json", cases), **_special(folder, "camera_params.json")}


def keyframe_json(folder: Path, dim: int) -> dict[str, Path]:
    """Keyframe timelines (`render --timeline`)."""
    cam = {"width": 64, "height": 48, "fx": 80.0, "fy": 80.0, "cx": 32.0, "cy": 24.0,
           "world_to_camera": np.eye(4).tolist()}

    def tl(expression=None, camera=None, **kw) -> bytes:
        d = {"npga_keyframes": 1, "code_dim": dim,
             "expression": expression if expression is not None else [{"time": 0.0, "code": [0.0] * dim}],
             "camera": camera or [], **kw}
        return json.dumps(d).encode()

    cases = {**_json_common(),
             "20000 keys": tl([{"time": i * 0.01, "code": [0.0] * dim} for i in range(20000)]),
             "time is a string": tl([{"time": "nan", "code": [0.0] * dim}]),
             "time negative": tl([{"time": -1.0, "code": [0.0] * dim}]),
             "code of strings": tl([{"time": 0.0, "code": ["0"] * dim}]),
             "code of wrong length": tl([{"time": 0.0, "code": [0.0] * (dim + 1)}]),
             "ease 5": tl([{"time": 0.0, "code": [0.0] * dim, "ease_in": 5.0}]),
             "camera key 10^9 wide": tl(camera=[{"time": 0.0, "camera": {**cam, "width": 10**9}}]),
             "camera key width 0": tl(camera=[{"time": 0.0, "camera": {**cam, "width": 0}}]),
             "version 2": tl(npga_keyframes=2),
             "code_dim a string": tl(code_dim="16"),
             "keys not a list": tl(expression={"a": 1}),
             "key time 1e9": tl([{"time": 0.0, "code": [0.0] * dim}, {"time": 1e9, "code": [0.0] * dim}]),
             "key time 1e308": tl([{"time": 0.0, "code": [0.0] * dim}, {"time": 1e308, "code": [0.0] * dim}]),
             "hold 1e308": tl([{"time": 0.0, "code": [0.0] * dim, "hold": 1e308}]),
             "code of 3e38": tl([{"time": 0.0, "code": [3e38] * dim}]),
             "camera key fx 1e300": tl(camera=[{"time": 0.0, "camera": {**cam, "fx": 1e300, "fy": 1e300}}]),
             "camera key singular": tl(camera=[{"time": 0.0, "camera": {**cam, "world_to_camera":
                                                                         np.zeros((4, 4)).tolist()}}])}
    return {**_write_all(folder, ".json", cases), **_special(folder, "keyframes.json")}


def session_json(folder: Path) -> dict[str, Path]:
    """Viewer sessions (`--session`, the View panel's Load)."""
    def ses(**kw) -> bytes:
        return json.dumps({"npga_view_session": 1, **kw}).encode()

    cases = {**_json_common(),
             "version 2": json.dumps({"npga_view_session": 2}).encode(),
             "avatar path is a list": ses(avatar=["a", "b"]),
             "avatar path with NUL": ses(avatar="a\u0000b"),
             "camera fov a string": ses(camera={"fov_y": "nan"}),
             "camera target of 2": ses(camera={"target": [0, 0]}),
             "camera distance 0": ses(camera={"distance": 0}),
             "sliders 100000": ses(sliders=[0.0] * 100000),
             "sliders strings": ses(sliders=["nan"]),
             "timeline speed 'inf'": ses(timeline={"speed": "inf"}),
             "background 1e308": ses(background=[1e308, 0, 0]),
             "rig_index 10^20": ses(rig_index=10**20),
             "unknown smoothing": ses(timeline={"smoothing": "cubic"}),
             "one-euro cutoff 0": ses(timeline={"smoothing": "one_euro", "euro_min_cutoff": 0.0}),
             "exponential alpha 0": ses(timeline={"smoothing": "exponential", "smooth_alpha": 0.0}),
             "bake budget 0": ses(timeline={"bake_budget_mb": 0.0, "baked": True})}
    return {**_write_all(folder, ".json", cases), **_special(folder, "session.json")}


def config_dirs(folder: Path, filename: str, cases: dict[str, bytes]) -> dict[str, Path]:
    """One XDG_CONFIG_HOME per case with `npga-view/<filename>` holding the case (or a FIFO, directory, device)."""
    out = {}
    for i, (name, content) in enumerate(cases.items()):
        home = folder / f"config{i:02d}"
        (home / "npga-view").mkdir(parents=True)
        (home / "npga-view" / filename).write_bytes(content)
        out[name] = home
    for j, kind in enumerate(("fifo", "directory", "char device (/dev/zero)")):
        home = folder / f"special{j}"
        (home / "npga-view").mkdir(parents=True)
        target = home / "npga-view" / filename
        if kind == "fifo":
            os.mkfifo(target)
        elif kind == "directory":
            target.mkdir()
        else:
            target.symlink_to("/dev/zero")
        out[kind] = home
    return out


def presets_configs(folder: Path) -> dict[str, Path]:
    """The user's expression presets (`presets.json` in the config folder, read when the viewer starts)."""
    return config_dirs(folder, "presets.json", {
        **_json_common(),
        "a list": b"[1, 2]",
        "code a string": b'{"smile": "0 1 2"}',
        "code of strings": b'{"smile": ["nan", "1"]}',
        "code empty": b'{"smile": []}',
        "code 10000 long": json.dumps({"smile": [0.0] * 10000}).encode(),
        "code nested": b'{"smile": [[1, 2]]}',
    })


def recent_configs(folder: Path) -> dict[str, Path]:
    """The recent-files list (`recent.json` in the config folder, read when the viewer starts)."""
    return config_dirs(folder, "recent.json", {
        **_json_common(),
        "an object": b'{"a": 1}',
        "a number": b"12",
    })


# -- caches (read by the pose worker; a bad cache is a miss, never a crash) ------------------------------------
def bake_caches(folder: Path, good: Path) -> dict[str, Path]:
    """`.npgabake` cache files; `good` is a valid cache whose header is rewritten."""
    raw = good.read_bytes()
    hlen = int.from_bytes(raw[8:16], "little")
    header, rest = json.loads(raw[16:16 + hlen]), raw[16 + hlen:]

    def with_header(**kw) -> bytes:
        t = json.dumps({**header, **kw}).encode()
        t += b" " * ((-(16 + len(t))) % 64)
        return raw[:8] + len(t).to_bytes(8, "little") + t + rest

    s = header["shape"]
    table = s[0] * s[2] * 4  # bytes of the lo table, then of the step table
    cases = {
        "shape claims 10^12 rows": with_header(shape=[s[0], 10**12, s[2]]),
        "frames 10^12": with_header(frames=10**12),
        "stride 0": with_header(stride=0),
        "object dtype": with_header(dtype="|O"),
        "structured dtype": with_header(dtype=[["a", "|O"]]),
        "shape of strings": with_header(shape=["1", "2", "3"]),
        "header length 2^62": raw[:8] + (2**62).to_bytes(8, "little") + raw[16:],
        "nested header": raw[:8] + (200016).to_bytes(8, "little") + b"[" * 100008 + b"]" * 100008,
        "truncated": raw[: len(raw) // 2],
        "NaN offsets and steps": raw[:16 + hlen] + np.full(len(rest) // 4, np.nan, np.float32).tobytes(),
        "empty file": b"",
        "steps of 3e38": raw[:16 + hlen] + _floats_set(rest, table, 2 * table, 3e38),
        "offsets (lo) of 3e38": raw[:16 + hlen] + _floats_set(rest, 0, table, -3e38),
    }
    return {**_write_all(folder, ".npgabake", cases), **{k: v for k, v in _special(folder, "x.npgabake").items()
                                                        if k != "missing"}}


def preview_caches(folder: Path, good: Path) -> dict[str, Path]:
    """Preview-model caches (`.npz` next to the avatar); `good` is a valid one whose members are replaced."""
    marker = folder / MARKER
    with zipfile.ZipFile(good) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    probes = np.load(io.BytesIO(members["probes.npy"]))
    neighbours = np.load(io.BytesIO(members["neighbours.npy"]))

    def with_members(**kw) -> bytes:
        return _zip({**members, **{f"{k}.npy": v for k, v in kw.items()}})

    bad_idx = neighbours.copy()
    bad_idx[0, 0] = 10**6
    cases = {
        "meta pickled": with_members(meta=_npy(_pickled(marker))),
        "probes pickled": with_members(probes=_npy(_pickled(marker))),
        "weights claim a huge shape": with_members(weights=npy_header((10**9, 8))),
        "neighbour index out of range": with_members(neighbours=_npy(bad_idx)),
        "negative probe": with_members(probes=_npy(np.r_[-1, probes[1:]])),
        "probes not ascending": with_members(probes=_npy(probes[::-1].copy())),
        "NaN weights": with_members(weights=_npy(np.full(neighbours.shape, np.nan, np.float32))),
        "complex weights": with_members(weights=_npy(np.ones(neighbours.shape, np.complex64))),
        "meta nested JSON": with_members(meta=_npy(np.frombuffer(b"[" * 5000 + b"]" * 5000, np.uint8))),
        "zip cut in half": (zb := _zip(members))[: len(zb) // 2],
        "not a zip": os.urandom(300),
        "weights of 3e38": with_members(weights=_npy(np.full(neighbours.shape, 3e38, np.float32))),
        "broken deflate stream": _broken_stream({**members, "weights.npy": _npy(
            np.linspace(0, 1, neighbours.size, dtype=np.float32).reshape(neighbours.shape))},
            zipfile.ZIP_DEFLATED),
        "broken LZMA stream": _broken_stream(members, zipfile.ZIP_LZMA),
    }
    return {**_write_all(folder, ".npz", cases), **{k: v for k, v in _special(folder, "preview.npz").items()
                                                   if k != "missing"}}


# -- functions the fork server calls for readers without a command of their own --------------------------------
def open_bake_cache(path: str, key: str) -> int:
    """0 when the hostile cache is refused (a miss), 3 when it was taken."""
    from npga_core.posing.bake import BakeStore

    return 0 if BakeStore.open(path, key) is None else 3


def load_preview_cache(path: str, key: str, n: int) -> int:
    from npga_core.posing.preview import PreviewModel

    return 0 if PreviewModel.load(path, key, n) is None else 3


def recover_autosave(source: str) -> int:
    """The Edit panel's Recover: the autosave of `source` (under XDG_CACHE_HOME) loaded; errors as the CLI prints
    them (exit 2)."""
    import sys

    from npga_core.editing.edits import EditSession
    from npga_core.errors import AvatarFileError

    try:
        EditSession.recover(source)
    except (AvatarFileError, FileNotFoundError) as e:  # what the window reports (FIFOs etc. are no autosave)
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    return 0
