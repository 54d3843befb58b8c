"""The corpus's cases for the newer readers (tests/support/hostile_corpus.py holds the rest, and its helpers):
ARKit takes (#25), Gaussian-Head-Avatar checkpoint folders, configs and params (`import gha`), multi-view captures
(`evaluate`'s reader), Live Link Face UDP packets, and files that shrink while they are read.

Each builder writes its cases under a folder and returns {case name: path} (packets: {case name: bytes}).
"""

from __future__ import annotations

import io
import json
import os
import pickle
import struct
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np

from tests.support.hostile_corpus import MARKER, Bomb, _npy, _pickled, _special, _write_all

#: a small Gaussian-Head-Avatar checkpoint's sizes (the world's and the params cases')
GHA_SMALL = {"feature_dim": 12, "exp_dim": 6, "hidden": 32, "channels": 8, "freqs": 2, "capacity": 4}


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as fh:  # a hole: claims the size without writing it
        fh.truncate(size)
    return path


# == #25 ARKit takes (Live Link Face CSV, ARKit JSON), opened wherever a sequence opens ==========================
_LLF_HEADER = b"Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen,HeadYaw,HeadPitch,HeadRoll\n"


def arkit_takes(folder: Path) -> dict[str, Path]:
    """Live Link Face CSV and ARKit JSON takes (`--sequence take.csv|take.json`)."""
    row = b"10:00:00:00.000,5,0.1,0.2,0,0,0\n"
    csv_cases = {
        "csv: empty file": b"",
        "csv: header only": _LLF_HEADER,
        "csv: no Timecode column": b"Frame,EyeBlinkLeft\n0,0.1\n",
        "csv: NaN weight": _LLF_HEADER + b"10:00:00:00.000,5,nan,0.2,0,0,0\n",
        "csv: Inf head angle": _LLF_HEADER + b"10:00:00:00.000,5,0.1,0.2,inf,0,0\n",
        "csv: truncated row": _LLF_HEADER + row + b"10:00:00:01.000,5,0.1",
        "csv: bad timecode": _LLF_HEADER + b"99:99:99:99.9,5,0.1,0.2,0,0,0\n",
        "csv: timecode going back": _LLF_HEADER + row.replace(b":00.000", b":05.000") + row,
        "csv: huge weight": _LLF_HEADER + b"10:00:00:00.000,5,1e308,0.2,0,0,0\n",
        "csv: no known shape": b"Timecode,Foo,Bar\n10:00:00:00.000,0.1,0.2\n",
        "csv: not UTF-8": _LLF_HEADER + b"\xff\xfe" * 40,
        "csv: NUL bytes": b"Timecode,EyeBlinkLeft\n\x00\x00\x00\n",
        "csv: a million columns": b"Timecode," + b",".join(b"c%d" % i for i in range(100_000)) + b"\n",
        # what a take can say: two rows 23 hours apart at 240 fps fill 19.9 million frames when resampled
        "csv: two rows 23 hours apart at 240 fps": _LLF_HEADER + b"00:00:00:00.000,5,0.1,0.2,0,0,0\n"
        + b"23:00:00:239.000,5,0.1,0.2,0,0,0\n",
        "csv: head yaw 1e308": _LLF_HEADER + b"10:00:00:00.000,5,0.1,0.2,1e308,0,0\n",
        "csv: a 2 MB line": _LLF_HEADER + b"10:00:00:00.000,5," + b"1" * (2 << 20) + b",0.2,0,0,0\n",
    }
    json_cases = {
        "json: empty file": b"",
        "json: nested 100000 deep": b"[" * 100_000 + b"]" * 100_000,
        "json: NaN weight": b'{"names": ["jawOpen"], "frames": [{"weights": [NaN]}]}',
        "json: huge integer": b'{"jawOpen": [' + b"9" * 5000 + b"]}",
        "json: weights of the wrong length": b'{"names": ["jawOpen", "eyeBlinkLeft"], "frames": [{"weights": [0.1]}]}',
        "json: names not strings": b'{"names": [1, 2], "frames": []}',
        "json: fps zero": b'{"names": ["jawOpen"], "metadata": {"fps": 0}, "frames": [{"weights": [0.1]}]}',
        "json: categories without names": b'[[{"score": 0.1}]]',
        "json: series of unequal length": b'{"jawOpen": [0.1], "eyeBlinkLeft": [0.1, 0.2]}',
        "json: a number": b"42",
        "json: times going back": b'{"names": ["jawOpen"], "frames": [{"weights": [0.1], "time": 1}, '
                                  b'{"weights": [0.2], "time": 0}]}',
        "json: truncated": b'{"names": ["jawOpen"], "frames": [{"weights": [0.1',
        "json: two frames a day apart at 1000 fps": b'{"names": ["jawOpen"], "metadata": {"fps": 1000}, "frames": '
                                                    b'[{"weights": [0.1], "time": 0}, {"weights": [0.2], '
                                                    b'"time": 86000}]}',
        "json: weight 1e308": b'{"jawOpen": [1e308]}',
    }
    out = {**_write_all(folder, ".csv", csv_cases)}
    jdir = folder / "json"
    jdir.mkdir()
    out |= _write_all(jdir, ".json", json_cases)
    out["csv: 300 MB (sparse)"] = _sparse(folder / "huge.csv", 300 * 2**20)
    out["json: 300 MB (sparse)"] = _sparse(folder / "huge.json", 300 * 2**20)
    return {**out, **_special(folder, "take.csv"), **_special(jdir, "take.json")}


# == Gaussian-Head-Avatar: checkpoint folders (`import gha`), YAML configs (`--config`), params (`--sequence`) ====
def _torch_bytes(obj) -> bytes:
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


def _deflated_record(archive: bytes, claim: int) -> bytes:
    """The archive with its first data record replaced by `claim` zero bytes, deflated (~1000:1), in one pass."""
    src = zipfile.ZipFile(io.BytesIO(archive))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as dst:
        done = False
        for info in src.infolist():
            if not done and "/data/" in info.filename:
                zi = zipfile.ZipInfo(info.filename)
                zi.compress_type = zipfile.ZIP_DEFLATED
                with dst.open(zi, "w", force_zip64=True) as m:
                    zero = bytes(1 << 20)
                    for _ in range(claim >> 20):
                        m.write(zero)
                done = True
            else:
                dst.writestr(info, src.read(info))
    return buf.getvalue()


def gha_folders(folder: Path, head: dict, supres: dict) -> dict[str, Path]:
    """GHA checkpoint folders (`gaussianhead_latest`, `supres_latest`); `head`/`supres` are valid state dicts."""
    import torch

    marker = folder / MARKER

    def changed(**kw) -> dict:
        d = {k: v.clone() for k, v in head.items()}
        for k, v in kw.items():
            if v is None:
                d.pop(k)
            elif callable(v):
                d[k] = v(d[k])
            else:
                d[k] = v
        return d

    good = _torch_bytes(head)
    n = head["xyz"].shape[0]
    cases: dict[str, bytes | dict | str] = {
        "a __reduce__ payload in the state dict": {**head, "x": Bomb(marker)},
        "a raw pickle with a __reduce__ payload": pickle.dumps(Bomb(marker)),
        "truncated archive": good[: len(good) // 2],
        "empty file": b"",
        "a tensor claiming 10^12 elements (an expanded view of 4 bytes)": changed(
            feature=torch.zeros(1).expand(n, 10**9)),
        "a record deflated from 64 MB": _deflated_record(good, 64 << 20),
        "positions of 1e30": changed(xyz=lambda t: t * 1e30),
        "positions of 1e5 (beyond the scene's range)": changed(xyz=lambda t: t + 1e5),
        "MLP weights of 3e38": changed(**{"exp_color_mlp.conv0.weight": lambda t: t.fill_(3e38)}),
        "log-scales of 100": changed(scales=lambda t: t.fill_(100.0)),
        "quaternions of 1e7": changed(rotation=lambda t: t.fill_(1e7)),
        "complex positions": changed(xyz=lambda t: t.to(torch.complex64)),
        "NaN features": changed(feature=lambda t: t.fill_(float("nan"))),
        "0 Gaussians": {k: (v[:0] if v.dim() and v.shape[0] == n else v) for k, v in head.items()},
        "10^6 landmarks (a 1.6 GB distance table)": changed(landmarks_3d_neutral=torch.zeros(10**6, 3)),
        "no xyz": changed(xyz=None),
        "supres_latest: a __reduce__ payload": "supres-bomb",
        "gaussianhead_latest is a FIFO": "fifo",
        "gaussianhead_latest is a directory": "dir",
        "gaussianhead_latest is /dev/zero": "dev",
        # #36: network descriptions the .npga format or the renderer cannot hold
        "hidden width 0": _narrowed(head, "exp_deform_mlp", 0),
        "2 colour channels": _coloured(head, 2),
        "5000 colour channels": _coloured(head, 5000),
    }
    out = {}
    for i, (name, content) in enumerate(cases.items()):
        d = folder / f"gha{i:02d}"
        d.mkdir()
        target = d / "gaussianhead_latest"
        if content == "supres-bomb":
            target.write_bytes(good)
            (d / "supres_latest").write_bytes(_torch_bytes({**supres, "x": Bomb(marker)}))
        elif content == "fifo":
            os.mkfifo(target)
        elif content == "dir":
            target.mkdir()
        elif content == "dev":
            target.symlink_to("/dev/zero")
        else:
            target.write_bytes(content if isinstance(content, bytes) else _torch_bytes(content))
        out[name] = d
    return out


def _narrowed(head: dict, name: str, width: int) -> dict:
    """`head` with network `name`'s hidden layers `width` wide (the weights resized, zeros)."""
    import torch

    d = dict(head)
    convs = sorted(int(k.split(".conv")[1].split(".")[0]) for k in head if k.startswith(f"{name}.conv")
                   and k.endswith(".weight"))
    skip = (len(convs) + 1) // 2
    n_in = head[f"{name}.conv0.weight"].shape[1]
    for i in convs:
        w = head[f"{name}.conv{i}.weight"]
        out = w.shape[0] if i == convs[-1] else width
        cin = (n_in if i == 0 else width) + (n_in if i == skip else 0)
        d[f"{name}.conv{i}.weight"] = torch.zeros(out, cin, 1)
        d[f"{name}.conv{i}.bias"] = torch.zeros(out)
    return d


def _coloured(head: dict, channels: int) -> dict:
    """`head` whose colour networks give `channels` colour channels (exp_color's output, pose_color's too)."""
    import torch

    d = dict(head)
    for name in ("exp_color_mlp", "pose_color_mlp"):
        last = max(int(k.split(".conv")[1].split(".")[0]) for k in head if k.startswith(f"{name}.conv")
                   and k.endswith(".weight"))
        w = head[f"{name}.conv{last}.weight"]
        d[f"{name}.conv{last}.weight"] = torch.zeros(channels, w.shape[1], 1)
        d[f"{name}.conv{last}.bias"] = torch.zeros(channels)
    return d


def gha_configs(folder: Path) -> dict[str, Path]:
    """GHA YAML configs (`import gha --config`): tags that would run code, huge and deep values."""
    cases = {
        "a python/object/apply tag": f"gaussianheadmodule:\n  deform_scale: !!python/object/apply:pathlib.Path.touch "
                                     f"[{folder / MARKER}]\n".encode(),
        "a python/name tag": b"gaussianheadmodule: !!python/name:os.system\n",
        "an integer of 5000 digits": b"gaussianheadmodule:\n  deform_scale: " + b"9" * 5000 + b"\n",
        "nested 100000 deep": b"gaussianheadmodule: " + b"[" * 100_000 + b"]" * 100_000 + b"\n",
        "deform_scale .nan": b"gaussianheadmodule:\n  deform_scale: .nan\n",
        "dist_threshold_far 1e308": b"gaussianheadmodule:\n  dist_threshold_far: 1e308\n",
        "far below near": b"gaussianheadmodule:\n  dist_threshold_near: 0.3\n  dist_threshold_far: 0.1\n",
        "a !!binary value": b"gaussianheadmodule:\n  deform_scale: !!binary AAAA\n",
        "a list at the top": b"- 1\n- 2\n",
        "not UTF-8": b"gaussianheadmodule:\n  deform_scale: \xff\xfe\n",
        "2 MB of comments": b"#" + b"x" * (2 << 20) + b"\n",
        "pos_freq that does not fit": b"gaussianheadmodule:\n  pos_freq: 7\n",
        # #36: a billion laughs: safe_load shares the nodes, a repr in the error message expanded 10^9 items
        "an alias bomb as deform_scale": b"a: &a [x, x, x, x, x, x, x, x, x, x]\n" + b"".join(
            b"%c: &%c [*%c, *%c, *%c, *%c, *%c, *%c, *%c, *%c, *%c, *%c]\n" % ((98 + i, 98 + i) + (97 + i,) * 10)
            for i in range(8)) + b"gaussianheadmodule:\n  deform_scale: *i\n",
    }
    return {**_write_all(folder, ".yaml", cases), **_special(folder, "config.yaml")}


def gha_params(folder: Path, exp_dim: int) -> dict[str, Path]:
    """GHA params folders (`params/NNNN/params.npz`; `import gha --sequence`)."""
    marker = folder / MARKER
    ok = {"exp_coeff": np.zeros((1, exp_dim), np.float32), "pose": np.zeros((1, 6), np.float32),
          "scale": np.ones(1, np.float32)}
    frames = {
        "exp_coeff 1e308": {"exp_coeff": np.full((1, exp_dim), 1e308)},
        "pose NaN": {"pose": np.full((1, 6), np.nan, np.float32)},
        "translation 1e30": {"pose": np.array([[0, 0, 0, 1e30, 0, 0]], np.float32)},
        "scale 0": {"scale": np.zeros(1, np.float32)},
        "scale 1e30": {"scale": np.full(1, 1e30, np.float32)},
        "scale pickled": {"scale": _pickled(marker)},
        "exp_coeff claims 10^12 rows": "huge",
        "exp_coeff of another width": {"exp_coeff": np.zeros((1, exp_dim + 2), np.float32)},
        "exp_coeff complex": {"exp_coeff": np.ones((1, exp_dim), np.complex64)},
        "pose of 7 values": {"pose": np.zeros((1, 7), np.float32)},
        "params.npz is a FIFO": "fifo",
    }
    out = {}
    for i, (name, change) in enumerate(frames.items()):
        root = folder / f"params{i:02d}"
        for t in range(3):
            d = root / "params" / f"{t:04d}"
            d.mkdir(parents=True)
            arrays = {**ok, **change} if isinstance(change, dict) and t == 1 else ok
            members = {f"{k}.npy": _npy(np.asarray(v)) for k, v in arrays.items()}
            if change == "huge" and t == 1:
                from tests.support.hostile_corpus import npy_header

                members["exp_coeff.npy"] = npy_header((10**12, exp_dim))
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as zf:
                for k, v in members.items():
                    zf.writestr(k, v)
            if change == "fifo" and t == 1:
                os.mkfifo(d / "params.npz")
                continue
            (d / "params.npz").write_bytes(buf.getvalue())
        out[name] = root
    return out


# == multi-view captures (`evaluate --capture`; read by npga_core.evaluation.capture) ===========================
def png(width: int, height: int, rows: bytes | None = None, grey: bool = False) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    colour = 0 if grey else 2
    data = rows if rows is not None else b"".join(b"\0" + bytes(width * (1 if grey else 3)) for _ in range(height))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, colour, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(data)) + chunk(b"IEND", b""))


def _jpeg(width: int, height: int) -> bytes:
    import cv2

    rng = np.random.default_rng(1)
    return cv2.imencode(".jpg", rng.integers(0, 255, (height, width, 3), dtype=np.uint8))[1].tobytes()


def _jpeg_cut_inside() -> bytes:
    """A JPEG cut in the middle of its image data with the end marker put back (libjpeg decodes it, grey below the
    cut, and says so only on stderr)."""
    j = _jpeg(64, 48)
    mid = (j.index(b"\xff\xda") + len(j)) // 2
    return j[:mid] + j[-2:]


def captures(folder: Path) -> dict[str, Path]:
    """NeRSemble (camera_params.json + timesteps/frame_N/images/cam_S.png) and GHA (images/N/image_C.png +
    cameras/N/camera_C.npz) capture folders with hostile rigs, cameras and images. Names starting with
    "partial:" are captures whose other views are usable (the bad file is one problem line)."""
    k = [[20.0, 0.0, 8.0], [0.0, 20.0, 6.0], [0.0, 0.0, 1.0]]
    w2c = np.eye(4)
    w2c[2, 3] = 1.0
    rig = {"world_2_cam": {"A": w2c.tolist(), "B": w2c.tolist()}, "intrinsics": k}
    good = png(16, 12)
    nersemble: dict[str, tuple[bytes | dict, dict[str, bytes | str]]] = {
        "rig: an integer of 5000 digits": (json.dumps(rig).replace("20.0", "9" * 5000, 1).encode(), {}),
        "rig: NaN intrinsics": (json.dumps(rig).replace("20.0", "NaN", 1).encode(), {}),
        "rig: focal length 1e300": (json.dumps(rig).replace("20.0", "1e300").encode(), {}),
        "rig: singular world_2_cam": ({**rig, "world_2_cam": {"A": np.zeros((4, 4)).tolist()}}, {}),
        "rig: missing": (b"", {"A": good}),
        "no images at all": (rig, {}),
        "partial: camera B's image missing": (rig, {"A": good}),
        "partial: camera B's image a FIFO": (rig, {"A": good, "B": "fifo"}),
        "partial: camera B's image truncated": (rig, {"A": good, "B": good[:40]}),
        "partial: camera B's PNG claims 100000x100000": (rig, {"A": good, "B": png(100000, 100000, b"\0")}),
        "partial: camera B's image is text": (rig, {"A": good, "B": b"not an image"}),
        # #36: libjpeg decodes a cut JPEG as grey and says so only on stderr: it was scored silently
        "partial: camera B's JPEG truncated": (rig, {"A": good, "B": _jpeg(16, 12)[:-40]}),
        "partial: camera B's JPEG cut inside, its end marker kept": (rig, {"A": good, "B": _jpeg_cut_inside()}),
    }
    out = {}
    for i, (name, (rig_json, images)) in enumerate(nersemble.items()):
        root = folder / f"nersemble{i:02d}"
        imgs = root / "timesteps" / "frame_00000" / "images-2x"
        imgs.mkdir(parents=True)
        if rig_json != b"":
            (root / "camera_params.json").write_bytes(rig_json if isinstance(rig_json, bytes)
                                                      else json.dumps(rig_json).encode())
        for serial, content in images.items():
            target = imgs / f"cam_{serial}.png"
            if content == "fifo":
                os.mkfifo(target)
            else:
                target.write_bytes(content)
        if not images:
            (imgs / "readme.txt").write_text("no images")
        out[name] = root
    ext = np.eye(4)[:3].copy()
    ext[2, 3] = 1.0
    kk = np.array(k)
    gha: dict[str, tuple[dict | str, bytes | str]] = {
        "partial: camera 01 focal length 0": ({"extrinsic": ext, "intrinsic": kk * [[0], [1], [1]]}, good),
        "partial: camera 01 extrinsic singular": ({"extrinsic": np.zeros((3, 4)), "intrinsic": kk}, good),
        "partial: camera 01 translation 1e300": ({"extrinsic": ext + [[0, 0, 0, 1e300]] * 3, "intrinsic": kk}, good),
        "partial: camera 01 pickled": ("pickle", good),
        "partial: camera 01 missing": ("missing", good),
        "partial: image 01 a FIFO": ({"extrinsic": ext, "intrinsic": kk}, "fifo"),
        "partial: image 01 claims 100000x100000": ({"extrinsic": ext, "intrinsic": kk}, png(100000, 100000, b"\0")),
        # #36: OpenCV's reader crashed (SIGSEGV) on a path that is not UTF-8; camera 01 here is a usable view named
        # by an undecodable byte, the problem line is camera 02's (no camera file)
        "partial: a camera id that is not UTF-8": ("undecodable", good),
    }
    for i, (name, (camera, image)) in enumerate(gha.items()):
        root = folder / f"gha{i:02d}"
        if camera == "undecodable":
            for cam_id in ("00", os.fsdecode(b"\xff\xfe"), "02"):
                (root / "images" / "0000").mkdir(parents=True, exist_ok=True)
                (root / "cameras" / "0000").mkdir(parents=True, exist_ok=True)
                (root / "images" / "0000" / f"image_{cam_id}.png").write_bytes(good)
                if cam_id != "02":
                    np.savez(root / "cameras" / "0000" / f"camera_{cam_id}.npz", extrinsic=ext, intrinsic=kk)
            out[name] = root
            continue
        for cam_id in ("00", "01"):
            (root / "images" / "0000").mkdir(parents=True, exist_ok=True)
            (root / "cameras" / "0000").mkdir(parents=True, exist_ok=True)
            img = root / "images" / "0000" / f"image_{cam_id}.png"
            npz = root / "cameras" / "0000" / f"camera_{cam_id}.npz"
            bad = cam_id == "01"
            if bad and image == "fifo":
                os.mkfifo(img)
            else:
                img.write_bytes(image if bad else good)
            if bad and camera == "missing":
                continue
            if bad and camera == "pickle":
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w") as zf:
                    zf.writestr("extrinsic.npy", _npy(_pickled(folder / MARKER)))
                    zf.writestr("intrinsic.npy", _npy(kk))
                npz.write_bytes(buf.getvalue())
                continue
            arrays = camera if bad and isinstance(camera, dict) else {"extrinsic": ext, "intrinsic": kk}
            np.savez(npz, **arrays)
        out[name] = root
    return out


def open_capture(root: str) -> int:
    """The capture reader as `evaluate` uses it (list the views, read every image): refused in one line naming a
    file (exit 2), or, for a capture with usable views, every problem one line naming a file on stdout (exit 0)."""
    from npga_core.errors import AvatarFileError
    from npga_core.evaluation.capture import load_capture

    try:
        capture = load_capture(root)
    except AvatarFileError as e:
        print(f"npga-view: error: {e}", file=sys.stderr)
        return 2
    problems = list(capture.problems)
    for view in capture.views.values():
        try:
            capture.image(view.image_path)
        except AvatarFileError as e:
            problems.append(str(e))
    for line in problems:
        print(f"problem: {line}")
    return 0


# == Live Link Face UDP packets (npga_core.posing.livelink.decode) ===============================================
def udp_packets() -> dict[str, bytes]:
    """Datagrams a hostile or broken sender may send to the Live Link receiver."""
    from npga_core.posing.livelink import _TAIL, VALUES, encode

    good = encode(np.zeros(VALUES, np.float32), 10)
    n_at = 41

    def with_length(n: int) -> bytes:
        return good[:n_at] + struct.pack("!i", n) + good[n_at + 4:]

    def with_values(value: float) -> bytes:
        return good[: len(good) - 4 * VALUES] + struct.pack(f"!{VALUES}f", *([value] * VALUES))

    tail_at = 45 + 4  # subject "npga"

    def with_tail(frame=10, sub=0.0, num=60, den=1, count=VALUES) -> bytes:
        return good[:tail_at] + _TAIL.pack(frame, sub, num, den, count) + good[tail_at + _TAIL.size:]

    return {
        "empty": b"", "one byte": b"\0", "truncated by one byte": good[:-1], "one byte more": good + b"\0",
        "subject length 2^31 - 1": with_length(2**31 - 1), "subject length -1": with_length(-1),
        "subject length 10^6": with_length(10**6), "NaN values": with_values(float("nan")),
        "Inf values": with_values(float("inf")), "values 3e38": with_values(3e38),
        "sub-frame NaN": with_tail(sub=float("nan")), "sub-frame 1e30": with_tail(sub=1e30),
        "rate 0/0": with_tail(num=0, den=0), "rate -60/1": with_tail(num=-60), "rate 10^9/1": with_tail(num=10**9),
        "frame -1": with_tail(frame=-1), "value count 255": with_tail(count=255), "value count 0": with_tail(count=0),
        "subject not UTF-8": good[:45] + b"\xff\xfe\xed\xa0" + good[49:],
        "subject a lone surrogate in UTF-8": good[:45] + b"\xed\xa0\x80a" + good[49:],
        "64 kB of zeros": bytes(65507), "random": np.random.default_rng(0).bytes(len(good)),
    }


# == files that shrink while they are read =========================================================================
def while_shrinking(target: str, argv_json: str) -> int:
    """`npga-view ARGV` with `target`, as the readers open it through `open_regular`, shrinking to half its size
    right before the first read that reaches past that half (another program truncating it between the size
    check and the read; a read by descriptor, as numpy's, counts from the first `fileno()` after the start): the
    readers must refuse it in one line naming it (exit 2)."""
    import npga_core.files.untrusted as untrusted
    from npga_view.cli.main import main

    original = untrusted.open_regular
    wanted = os.path.realpath(target)

    class Shrinking(io.BufferedReader):
        half = -1
        path = ""

        def _maybe_shrink(self, want: int | None) -> None:
            if self.half >= 0 and self.tell() + (want if want is not None and want >= 0 else 1 << 62) > self.half:
                os.truncate(self.path, self.half)
                self.half = -1

        def read(self, size=-1):
            self._maybe_shrink(size)
            return super().read(size)

        def readinto(self, b):
            self._maybe_shrink(len(b))
            return super().readinto(b)

        def readline(self, size=-1):
            self._maybe_shrink(size if size and size > 0 else 1 << 16)
            return super().readline(size)

        def fileno(self):
            if self.tell() > 0:
                self._maybe_shrink(None)
            return super().fileno()

    def shrinking_open(path, what="a file"):
        fh = original(path, what)
        if os.path.realpath(path) != wanted:
            return fh
        out = Shrinking(io.FileIO(os.dup(fh.fileno()), "rb"))
        fh.close()
        out.half, out.path = os.fstat(out.raw.fileno()).st_size // 2, wanted
        return out

    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("npga_") and getattr(module, "open_regular", None) is original:
            module.open_regular = shrinking_open
    return main(json.loads(argv_json))


# == #37 FLAME model pickles (`import gaussian-avatars --flame-model`, `--flame-model` wherever an avatar opens) ==
_RUNSTRING_IN_CH = (b"(dp0\nS'shapedirs'\np1\nccopy_reg\n_reconstructor\np2\n(cchumpy.ch\nCh\np3\nc__builtin__\n"
                    b"object\np4\nNtp5\nRp6\n(dp7\nS'x'\np8\ncnumpy.testing._private.utils\nrunstring\np9\n"
                    b"(S\"open('PWNED', 'w').write('x')\"\np10\n(dp11\ntp12\nRp13\nsbs.")


class _System:
    def __reduce__(self):
        return (os.system, ("touch PWNED",))


def flame_pickles(folder: Path, arrays: dict) -> dict[str, Path]:
    """FLAME pickles that must be refused in one line, nothing run: payloads (os.system; numpy's runstring inside a
    chumpy object, protocol 0 as Python 2 wrote FLAME 2020; builtins.eval; an object array), wrong shapes, NaN,
    faces beyond the vertices, not a dict, truncated, empty, a FIFO, a folder. A payload that ran leaves `PWNED`
    in the working folder."""
    folder.mkdir(parents=True, exist_ok=True)
    narrow = dict(arrays, shapedirs=arrays["shapedirs"][:, :, :50])
    bad_weights = dict(arrays, weights=arrays["weights"][:, :3])
    nan = dict(arrays, v_template=np.where(np.arange(len(arrays["v_template"]))[:, None] == 7, np.nan,
                                           arrays["v_template"]))
    far_faces = dict(arrays, f=np.where(arrays["f"] == 0, 10**6, arrays["f"]).astype(np.uint32))
    cases = {
        "os.system payload": pickle.dumps({"v_template": _System()}, protocol=2),
        "runstring inside a chumpy object": _RUNSTRING_IN_CH,
        "builtins.eval": b"(dp0\nS'v_template'\np1\ncbuiltins\neval\n(S\"open('PWNED', 'w')\"\ntRs.",
        "object array holding a payload": pickle.dumps(dict(arrays, posedirs=np.array([_System()], object)),
                                                       protocol=2),
        "NaN in the template": pickle.dumps(nan, protocol=2),
        "faces beyond the vertices": pickle.dumps(far_faces, protocol=2),
        "shapedirs of 50 components": pickle.dumps(narrow, protocol=2),
        "weights for 3 joints": pickle.dumps(bad_weights, protocol=2),
        "a list, not a dict": pickle.dumps([1, 2, 3], protocol=2),
        "truncated": pickle.dumps(arrays, protocol=2)[:5000],
        "empty": b"",
    }
    out = {}
    for name, data in cases.items():
        path = folder / (name.replace(" ", "_").replace(",", "") + ".pkl")
        path.write_bytes(data)
        out[name] = path
    out["a FIFO"] = folder / "fifo.pkl"
    os.mkfifo(out["a FIFO"])
    out["a folder"] = folder / "folder.pkl"
    out["a folder"].mkdir()
    return out
