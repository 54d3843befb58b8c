"""Standard 3D Gaussian Splatting `.ply` files, in and out.

The layout written (and expected) is the one of the reference 3DGS code, one float32 vertex element:
``x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3`` where K = (degree+1)^2,
opacity is a logit, scales are logs, rot is (w, x, y, z), and f_rest is channel-major:
``f_rest[c*(K-1) + j]`` is SH coefficient j+1 of colour channel c.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import IO

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.untrusted import MAX_LOG_SCALE, MAX_POSITION, MAX_QUAT, open_regular, regular_file
from npga_core.model.gaussians import GaussianCloud, PosedGaussians, logit, sh_coeff_count

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
MAX_HEADER_BYTES = 1 << 20
#: Most vertices read from one PLY (a claim is checked against this before the file size or any read).
MAX_VERTICES = 50_000_000
#: Largest magnitude of each stored attribute, the range its meaning allows (positions in scene units).
_LIMITS = {"means": MAX_POSITION, "quats": MAX_QUAT, "log_scales": MAX_LOG_SCALE, "opacity_logits": 1e4,
           "sh": 1e4}


def standard_fields(sh_degree: int) -> list[str]:
    """Property names of the 3DGS vertex element, in order."""
    k = sh_coeff_count(sh_degree)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(3 * (k - 1))]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


class _Bad(Exception):
    pass


_Elements = list[tuple[str, int, list[tuple[str, str]]]]


def _parse_header(fh: IO[bytes]) -> tuple[str, _Elements, int]:
    first = fh.readline(64)
    if first.rstrip(b"\r\n") != b"ply":
        raise _Bad("not a PLY file (first line is not 'ply')")
    fmt = None
    elements: _Elements = []
    total = len(first)
    while True:
        line = fh.readline(4096)
        total += len(line)
        if not line:
            raise _Bad("truncated: the header has no end_header line")
        if total > MAX_HEADER_BYTES:
            raise _Bad("header is longer than 1 MiB")
        try:
            words = line.decode("ascii").split()
        except UnicodeDecodeError:
            raise _Bad("header has non-ASCII bytes") from None
        if words and words[0] == "end_header":
            break
        fmt = _header_line(words, elements) or fmt
    if fmt is None:
        raise _Bad("header has no format line")
    return fmt, elements, total


def _header_line(words: list[str], elements: _Elements) -> str | None:
    """Take one header line (its words) into `elements`; the format for a format line, else None."""
    if not words or words[0] in ("comment", "obj_info"):
        return None
    if words[0] == "format":
        if len(words) != 3 or words[1] not in ("binary_little_endian", "binary_big_endian", "ascii"):
            raise _Bad(f"unsupported format line {' '.join(words)!r}")
        return words[1]
    if words[0] == "element":
        if len(words) != 3 or not re.fullmatch(r"\d{1,10}", words[2]):
            raise _Bad(f"malformed element line {' '.join(words)!r}")
        elements.append((words[1], int(words[2]), []))
    elif words[0] == "property":
        if len(words) < 3:
            raise _Bad(f"malformed property line {' '.join(words)!r}")
        if not elements:
            raise _Bad("property before any element")
        if words[1] == "list":
            elements[-1][2].append((words[-1], "list"))
        elif len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise _Bad(f"malformed property line {' '.join(words)!r}")
    else:
        raise _Bad(f"unknown header line {' '.join(words)!r}")
    return None


def read_ply(path: str | Path) -> GaussianCloud:
    """Read a 3DGS `.ply` as a static cloud (no features, no dynamics); AvatarFileError on bad input."""
    return read_ply_extra(path, ())[0]


def read_ply_bytes(data: bytes, where: str | Path) -> GaussianCloud:
    """A 3DGS `.ply` held in memory (a member of an archive, named `where` in errors) as a static cloud."""
    try:
        if not data:
            raise _Bad("file is empty")
        return _read_stream(io.BytesIO(data), len(data))
    except _Bad as e:
        raise AvatarFileError(where, str(e)) from None
    except MemoryError:
        raise AvatarFileError(where, "not enough memory to read its vertices") from None


def read_ply_extra(path: str | Path, extra: tuple[str, ...]) -> tuple[GaussianCloud, dict[str, np.ndarray]]:
    """`read_ply` and the float64 columns of the `extra` properties the file has (GaussianAvatars' `binding_0`;
    each checked finite)."""
    path = Path(path)
    found: dict[str, np.ndarray] = {}
    try:
        cloud = _read_ply(path, extra, found)
    except _Bad as e:
        raise AvatarFileError(path, str(e)) from None
    except FileNotFoundError:
        raise AvatarFileError(path, "no such file") from None
    except MemoryError:
        raise AvatarFileError(path, "not enough memory to read its vertices") from None
    except OSError as e:
        raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
    return cloud, found


def _read_ply(path: Path, extra: tuple[str, ...] = (), found: dict | None = None) -> GaussianCloud:
    size = regular_file(path, "a PLY file").stat().st_size
    if size == 0:
        raise _Bad("file is empty")
    with open_regular(path, "a PLY file") as fh:
        return _read_stream(fh, size, extra, found)


def _read_stream(fh: IO[bytes], size: int, extra: tuple[str, ...] = (), found: dict | None = None) -> GaussianCloud:
    fmt, elements, header_len = _parse_header(fh)
    n, props = _vertex_element(elements)
    names = [p for p, _ in props]
    cols = (_ascii_columns(fh, n, names) if fmt == "ascii"
            else _binary_columns(fh, fmt, n, props, size - header_len))
    cloud = _cloud(cols, names, n)
    for name in extra:
        if name in cols and found is not None:
            column = np.asarray(cols[name], np.float64)
            if not np.isfinite(column).all():
                raise _Bad(f"{name} has NaN/Inf values")
            found[name] = column
    return cloud


def _vertex_element(elements: _Elements) -> tuple[int, list[tuple[str, str]]]:
    """(count, properties) of the vertex element, checked: bounded count, named scalar properties."""
    if not elements or elements[0][0] != "vertex":
        raise _Bad("the first element is not 'vertex'")
    _, n, props = elements[0]
    if n > MAX_VERTICES:
        raise _Bad(f"claims {n} vertices, more than the {MAX_VERTICES} allowed")
    if not props:
        raise _Bad("the vertex element has no properties")
    if any(t == "list" for _, t in props):
        raise _Bad("vertex element has list properties; not a 3DGS file")
    names = [p for p, _ in props]
    if len(set(names)) != len(names):
        raise _Bad("vertex element has duplicate property names")
    return n, props


def _ascii_columns(fh: IO[bytes], n: int, names: list[str]) -> dict[str, np.ndarray]:
    if n == 0:
        return {name: np.zeros(0) for name in names}
    try:
        rows = np.loadtxt(fh, dtype=np.float64, max_rows=n, ndmin=2)
    except ValueError as e:
        raise _Bad(f"malformed ASCII vertex data: {e}") from None
    if rows.shape[0] != n or rows.shape[1] != len(names):
        raise _Bad(f"truncated: {rows.shape[0]} of {n} vertex rows")
    return {name: rows[:, i] for i, name in enumerate(names)}


def _binary_columns(fh: IO[bytes], fmt: str, n: int, props: list[tuple[str, str]], available: int) -> dict[str,
                    np.ndarray]:
    end = "<" if fmt == "binary_little_endian" else ">"
    dt = np.dtype([(p, end + t) for p, t in props])
    if available < n * dt.itemsize:
        raise _Bad(f"truncated: {n} vertices need {n * dt.itemsize} bytes after the header, the file has {available}")
    if isinstance(fh, io.BytesIO):  # an archive member in memory
        start = fh.tell()
        data = np.frombuffer(fh.getbuffer(), dtype=dt, count=n, offset=start).copy()
    else:
        data = np.fromfile(fh, dtype=dt, count=n)
    if data.shape[0] != n:  # the file shrank while it was read
        raise _Bad(f"truncated: {data.shape[0]} of {n} vertices could be read")
    return {name: data[name] for name, _ in props}


def _cloud(cols: dict[str, np.ndarray], names: list[str], n: int) -> GaussianCloud:
    """The cloud of the vertex columns (3DGS names), every attribute checked within the range it may have."""
    missing = [f for f in standard_fields(0) if f not in cols and f not in ("nx", "ny", "nz")]
    if missing:
        raise _Bad(f"missing 3DGS vertex properties: {', '.join(missing)}")
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))
    k = 1 + n_rest // 3
    if n_rest % 3 or k not in (1, 4, 9, 16):
        raise _Bad(f"{n_rest} f_rest properties do not match an SH degree 0..3 (expect 0, 9, 24 or 45)")
    absent = [f"f_rest_{i}" for i in range(n_rest) if f"f_rest_{i}" not in cols]
    if absent:
        raise _Bad(f"f_rest properties are not numbered 0..{n_rest - 1} (missing {absent[0]})")

    def stack(keys: list[str]) -> np.ndarray:
        return np.stack([np.asarray(cols[k], dtype=np.float32) for k in keys], axis=1) if keys else \
            np.zeros((n, 0), np.float32)

    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0, :] = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    if k > 1:
        rest = stack([f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k - 1)
        sh[:, 1:, :] = rest.transpose(0, 2, 1)
    cloud = GaussianCloud(
        means=stack(["x", "y", "z"]),
        quats=stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
        log_scales=stack(["scale_0", "scale_1", "scale_2"]),
        opacity_logits=np.asarray(cols["opacity"], dtype=np.float32).copy(),
        sh=sh,
        features=np.zeros((n, 0), np.float32),
    )
    for name, limit in _LIMITS.items():
        a = getattr(cloud, name)
        if not np.isfinite(a).all():
            raise _Bad(f"{name} has {int(a.size - np.isfinite(a).sum())} NaN/Inf values")
        if a.size and not np.abs(a).max() <= limit:
            raise _Bad(f"{name} reach {float(np.abs(a).max()):.3g}, beyond the +-{limit:g} they may have")
    if n and (np.einsum("ij,ij->i", cloud.quats, cloud.quats) < 1e-16).any():
        raise _Bad("some rotations are zero-length quaternions")
    return cloud


def write_ply(path: str | Path, means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray,
              opacity_logits: np.ndarray, sh: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write stored-form attributes in the standard 3DGS layout, atomically; `extra` adds float properties (one
    column each) after the standard ones, which 3DGS readers skip."""
    path = Path(path)
    n, k = sh.shape[0], sh.shape[1]
    deg = {1: 0, 4: 1, 9: 2, 16: 3}[k]
    extra = extra or {}
    fields = standard_fields(deg) + list(extra)
    data = np.empty((n, len(fields)), dtype="<f4")
    data[:, 0:3] = means
    data[:, 3:6] = 0.0
    data[:, 6:9] = sh[:, 0, :]
    o = 9
    if k > 1:
        data[:, o : o + 3 * (k - 1)] = np.asarray(sh[:, 1:, :]).transpose(0, 2, 1).reshape(n, 3 * (k - 1))
        o += 3 * (k - 1)
    data[:, o] = opacity_logits
    data[:, o + 1 : o + 4] = log_scales
    data[:, o + 4 : o + 8] = quats
    for i, column in enumerate(extra.values()):
        data[:, o + 8 + i] = column
    header = "ply\nformat binary_little_endian 1.0\n"
    header += "comment written by npga-view\n"
    header += f"element vertex {n}\n" + "".join(f"property float {f}\n" for f in fields) + "end_header\n"
    def write(fh: IO[bytes]) -> None:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())

    atomic_write(path, write)


def save_ply(cloud: GaussianCloud, path: str | Path) -> None:
    """Export a cloud's canonical Gaussians as a standard 3DGS PLY (features and latent are not kept)."""
    write_ply(path, cloud.means, cloud.quats, cloud.log_scales, cloud.opacity_logits, cloud.sh)


def save_posed_ply(posed: PosedGaussians, path: str | Path) -> None:
    """Export posed (activated) Gaussians as a standard 3DGS PLY; latent channels (the K colour channels of a
    Gaussian-Head-Avatar avatar) follow as extra properties `latent_0` .. `latent_{K-1}`."""
    extra = {} if posed.latent is None else {f"latent_{i}": posed.latent[:, i] for i in range(posed.latent.shape[1])}
    write_ply(path, posed.means, posed.quats, np.log(np.maximum(posed.scales, 1e-30)), logit(posed.opacities),
              posed.sh, extra)
