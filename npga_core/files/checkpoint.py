"""The `.npga` checkpoint format: one file, a JSON header and raw little-endian arrays (read, never mapped).

Layout (see docs/FORMAT.md for every tensor):

    offset 0   8 bytes   magic b"\\x89NPGA\\r\\n\\x1a"
    offset 8   8 bytes   header length L, uint64 little-endian
    offset 16  L bytes   UTF-8 JSON header (padded with spaces)
    D = 16+L             data section; D and every tensor offset are multiples of 64

Nothing in a file is ever executed or unpickled. The reader derives the full expected tensor set with
shapes and dtypes from the header's architecture, compares it with the tensor table, bounds-checks every
range against the file size, and checks values (finite floats, usable quaternions, parts in range).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import IO, Annotated, Any

import msgspec
import numpy as np
from msgspec import Meta

from npga_core import __version__
from npga_core.errors import AvatarFileError, brief
from npga_core.files import blendshapes_field, rig_field
from npga_core.files.atomic import atomic_write
from npga_core.files.dynamics_header import (
    HeaderError,
    build_cnn,
    build_dynamics,
    check_dynamics,
    cnn_section,
    cnn_tensors,
    dynamics_section,
    dynamics_tensors,
)
from npga_core.files.untrusted import MAX_JSON_DEPTH, MAX_POSITION, open_regular, parse_json, regular_file
from npga_core.model.avatar import Avatar
from npga_core.model.cnn import CNNConfig
from npga_core.model.dynamics import Dynamics
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import GaussianCloud, sh_coeff_count
from npga_core.schema import SchemaError, Text, decode

MAGIC = b"\x89NPGA\r\n\x1a"
#: The newest version this code reads and writes; a file is written in the oldest version that holds it.
FORMAT_VERSION = 5
ALIGN = 64
MAX_HEADER_BYTES = 64 * 1024 * 1024
MAX_PARAMETER = 1e8  # largest magnitude of a network weight, input normalisation or expression value
_DTYPES: dict[str, np.dtype] = {"float32": np.dtype("<f4"), "int16": np.dtype("<i2"), "int32": np.dtype("<i4")}

Spec = dict[str, tuple[str, tuple[int, ...]]]


# The header, declared (msgspec; unknown fields are ignored; sections checked by their own modules' schemas).
class _Gaussians(msgspec.Struct):
    count: Annotated[int, Meta(ge=0, le=2**31 - 1)]
    sh_degree: Annotated[int, Meta(ge=0, le=3)]
    feature_dim: Annotated[int, Meta(ge=0, le=4096)]
    latent_dim: Annotated[int, Meta(ge=0, le=4096)]
    part_names: Annotated[list[str], Meta(max_length=32767)] = []
    blend_names: Annotated[list[str], Meta(max_length=16)] = []


class _Expression(msgspec.Struct):
    dim: Annotated[int, Meta(ge=1, le=65536)]
    n_components: Annotated[int, Meta(ge=0, le=65536)]
    named: list[str] = []


class _TensorEntry(msgspec.Struct):
    dtype: Annotated[str, Meta(max_length=16)]
    shape: Annotated[list[Annotated[int, Meta(ge=0, le=2**62)]], Meta(max_length=8)]
    offset: Annotated[int, Meta(ge=0, le=2**62)]
    nbytes: Annotated[int, Meta(ge=0, le=2**62)]


class _Header(msgspec.Struct):
    format_version: int
    gaussians: _Gaussians
    tensors: dict[str, Any]  # each a `_TensorEntry`
    units: Text = "m"
    dynamics: dict[str, Any] | None = None
    cnn: dict[str, Any] | None = None
    expression: dict[str, Any] | None = None  # an `_Expression` (or empty: none)
    provenance: dict[str, Any] | None = None
    data_nbytes: Annotated[int, Meta(ge=0, le=2**62)] | None = None


def _align(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


# --------------------------------------------------------------------------------------------------
# the expected tensors, derived from a header


def expected_tensors(header: dict) -> Spec:
    """name -> (dtype, shape) of every tensor a file with this header must hold (and no others)."""
    g = header["gaussians"]
    n, k, f, h = g["count"], sh_coeff_count(g["sh_degree"]), g["feature_dim"], g["latent_dim"]
    spec: Spec = {
        "gaussians.means": ("float32", (n, 3)),
        "gaussians.quats": ("float32", (n, 4)),
        "gaussians.log_scales": ("float32", (n, 3)),
        "gaussians.opacity_logits": ("float32", (n,)),
        "gaussians.sh": ("float32", (n, k, 3)),
        "gaussians.features": ("float32", (n, f)),
    }
    if h:
        spec["gaussians.latent"] = ("float32", (n, h))
    if g.get("part_names"):
        spec["gaussians.part_ids"] = ("int16", (n,))
    if g.get("blend_names"):
        spec["gaussians.blend_weights"] = ("float32", (n, len(g["blend_names"])))
    dyn = header.get("dynamics")
    if dyn:
        spec.update(dynamics_tensors(dyn, header.get("format_version", 1)))
    cnn = header.get("cnn")
    if cnn:
        spec.update(cnn_tensors(cnn))
    ex = header.get("expression")
    if ex:
        d, c = ex["dim"], ex["n_components"]
        spec["expression.mean"] = ("float32", (d,))
        spec["expression.basis"] = ("float32", (c, d))
        spec["expression.std"] = ("float32", (c,))
        if ex.get("named"):
            spec["expression.named"] = ("float32", (len(ex["named"]), d))
    bs = blendshapes_field.header_entry(header)
    if bs:
        spec.update(blendshapes_field.tensors(bs))
    rig = rig_field.header_entry(header)
    if rig:
        spec.update(rig_field.tensors(rig, n))
    return spec


# --------------------------------------------------------------------------------------------------
# writing


def format_version_for(avatar: Avatar) -> int:
    """The oldest format version that holds `avatar` (1 for NPGA's F and G, 2 for any other dynamics, 3 with a
    blendshape basis, 4 with a rig, 5 with a rig on a skinned mesh)."""
    if avatar.rig is not None:
        return rig_field.RIG_VERSION if avatar.rig.skin is None else rig_field.SKIN_VERSION
    if avatar.blendshapes is not None:
        return blendshapes_field.BLENDSHAPES_VERSION
    simple = (avatar.dynamics is None or avatar.dynamics.simple) and (avatar.cnn is None or avatar.cnn.config.simple)
    return 1 if simple and avatar.cloud.blend_weights is None else 2


def _avatar_header(avatar: Avatar, provenance: dict) -> tuple[dict, dict[str, np.ndarray]]:
    c = avatar.cloud
    version = format_version_for(avatar)
    header: dict[str, Any] = {
        "format": "npga",
        "format_version": version,
        "units": avatar.units,
        "gaussians": {
            "count": len(c),
            "sh_degree": c.sh_degree,
            "feature_dim": c.feature_dim,
            "latent_dim": c.latent_dim,
            "part_names": list(c.part_names) if c.part_ids is not None else [],
        },
        "dynamics": None,
        "cnn": None,
        "expression": None,
        "provenance": provenance,
    }
    arrays: dict[str, np.ndarray] = {
        "gaussians.means": c.means,
        "gaussians.quats": c.quats,
        "gaussians.log_scales": c.log_scales,
        "gaussians.opacity_logits": c.opacity_logits,
        "gaussians.sh": c.sh,
        "gaussians.features": c.features,
    }
    if c.latent is not None:
        arrays["gaussians.latent"] = c.latent
    if c.part_ids is not None:
        arrays["gaussians.part_ids"] = c.part_ids
    if c.blend_weights is not None:
        header["gaussians"]["blend_names"] = list(c.blend_names)
        arrays["gaussians.blend_weights"] = c.blend_weights
    if avatar.dynamics is not None:
        avatar.dynamics.validate_for(c)
        if avatar.dynamics.networks():
            header["dynamics"], dyn_arrays = dynamics_section(avatar.dynamics, version)
            arrays.update(dyn_arrays)
        if avatar.dynamics.rig is not None:
            header["rig"], rig_arrays = rig_field.section(avatar.dynamics.rig)
            arrays.update(rig_arrays)
    if avatar.cnn is not None:
        avatar.cnn.config.validate(c.latent_dim)
        header["cnn"], cnn_arrays = cnn_section(avatar.cnn)
        arrays.update(cnn_arrays)
    ex = avatar.expression
    if ex is not None:
        ex.validate()
        header["expression"] = {"dim": ex.dim, "n_components": ex.n_components, "named": list(ex.named)}
        arrays["expression.mean"] = ex.mean
        arrays["expression.basis"] = ex.basis
        arrays["expression.std"] = ex.std
        if ex.named:
            arrays["expression.named"] = np.stack([ex.named[k] for k in ex.named])
    if avatar.blendshapes is not None:
        header["blendshapes"], bs_arrays = blendshapes_field.section(avatar.blendshapes, avatar.code_dim,
                                                                            avatar.condition_dim)
        arrays.update(bs_arrays)
    return header, arrays


def save_avatar(avatar: Avatar, path: str | Path, provenance: dict | None = None, verify: bool = False) -> None:
    """Write `avatar` to `path` atomically (temp file in the same folder, fsync, rename).

    A crash at any point leaves either the old file or the complete new one. With `verify` (imports of other
    methods' avatars), the written file is read back by `read_avatar`, the reader every command opens it with,
    before it takes `path`: a file its own reader refuses is never written (AvatarFileError naming `path`).
    """
    path = Path(path)
    prov = dict(avatar.provenance)
    prov.update(provenance or {})
    prov.setdefault("created_at", _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"))
    prov["written_by"] = f"npga-view {__version__}"
    header, arrays = _avatar_header(avatar, prov)
    spec = expected_tensors(header)
    if set(spec) != set(arrays):
        raise ValueError(f"internal: tensors {sorted(set(spec) ^ set(arrays))} do not match the header")
    table: dict[str, dict[str, Any]] = {}
    offset = 0
    for name, (dt, shape) in spec.items():
        a = arrays[name]
        if tuple(a.shape) != shape:
            raise ValueError(f"{name} has shape {tuple(a.shape)}, the header implies {shape}")
        nbytes = int(np.prod(shape, dtype=np.int64)) * _DTYPES[dt].itemsize
        table[name] = {"dtype": dt, "shape": list(shape), "offset": offset, "nbytes": nbytes}
        offset = _align(offset + nbytes)
    header["tensors"] = table
    header["data_nbytes"] = offset
    text = json.dumps(header, indent=1, allow_nan=False).encode("utf-8")
    data_start = _align(16 + len(text))
    text += b" " * (data_start - 16 - len(text))

    def write(fh: IO[bytes]) -> None:
        fh.write(MAGIC)
        fh.write(len(text).to_bytes(8, "little"))
        fh.write(text)
        pos = 0
        for name, entry in table.items():
            fh.write(b"\0" * (entry["offset"] - pos))
            a = np.ascontiguousarray(arrays[name], dtype=_DTYPES[entry["dtype"]])
            if a.size:
                fh.write(memoryview(a.reshape(-1)).cast("B"))  # type: ignore[arg-type]
            pos = entry["offset"] + entry["nbytes"]
        fh.write(b"\0" * (offset - pos))

    def read_back(tmp: Path) -> None:
        try:
            read_avatar(tmp)
        except AvatarFileError as e:
            origin = f" (from {avatar.source})" if getattr(avatar, "source", "") else ""
            raise AvatarFileError(path, f"not written: the .npga reader would refuse this avatar{origin}: "
                                  f"{e.problem}") from None

    atomic_write(path, write, verify=read_back if verify else None)


# --------------------------------------------------------------------------------------------------
# reading


class _Invalid(Exception):
    """A problem found while validating; turned into AvatarFileError with the path."""


def read_header(path: str | Path) -> tuple[dict, int]:
    """Read and check the header; returns (header, data_start). Raises AvatarFileError."""
    path = Path(path)
    try:
        return _read_header(path)
    except _Invalid as e:
        raise AvatarFileError(path, str(e)) from None
    except OSError as e:
        raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None


def _read_header(path: Path) -> tuple[dict, int]:
    size = regular_file(path, "an .npga checkpoint").stat().st_size
    if size == 0:
        raise _Invalid("file is empty")
    with open_regular(path, "an .npga checkpoint") as fh:
        hlen = _header_length(fh, size)
        text = fh.read(hlen)
    try:  # the one bounded JSON parse (depth, NaN, 5000-digit integers, duplicate keys)
        header = parse_json(text, path, MAX_JSON_DEPTH, unique_keys=True)
    except AvatarFileError as e:
        raise _Invalid(f"header: {e.problem}") from None
    _check_version(header)
    _check_header_schema(header)
    _check_blendshapes(header)
    rig = rig_field.header_entry(header)
    if rig is not None:
        try:
            rig_field.check_section(rig, header["gaussians"]["count"], header["format_version"])
        except ValueError as e:
            raise _Invalid(str(e)) from None
    data_start = 16 + hlen
    if data_start % ALIGN:
        raise _Invalid(f"data section starts at {data_start}, not a multiple of {ALIGN}")
    return header, data_start


def _header_length(fh: IO[bytes], size: int) -> int:
    """The header length after the signature, checked against the file size."""
    magic = fh.read(8)
    if magic != MAGIC[: len(magic)] or len(magic) < 8:
        if magic == MAGIC[: len(magic)]:
            raise _Invalid(f"truncated: {size} bytes, too short for the file signature")
        raise _Invalid(f"not an .npga checkpoint (wrong magic {magic!r})")
    raw_len = fh.read(8)
    if len(raw_len) < 8:
        raise _Invalid(f"truncated: {size} bytes, the header length is cut off")
    hlen = int.from_bytes(raw_len, "little")
    if hlen > MAX_HEADER_BYTES:
        raise _Invalid(f"header length {hlen} bytes is implausible (limit {MAX_HEADER_BYTES})")
    if 16 + hlen > size:
        raise _Invalid(f"truncated: header needs {16 + hlen} bytes, the file has {size}")
    return hlen


def _check_version(header: Any) -> None:
    if not isinstance(header, dict) or header.get("format") != "npga":
        raise _Invalid("header does not declare format 'npga'")
    version = _decoded(header.get("format_version"), Annotated[int, Meta(ge=1)], "format_version")
    if version > FORMAT_VERSION:
        raise _Invalid(f"format version {version} is newer than this reader supports ({FORMAT_VERSION}); "
                       "update npga-view")


def _decoded(value: Any, schema: Any, where: str) -> Any:
    try:
        return decode(value, schema, where)
    except SchemaError as e:
        raise _Invalid(str(e)) from None


def _check_header_schema(header: dict) -> None:
    h: _Header = _decoded(header, _Header, "")
    for what, names in (("gaussians.part_names", h.gaussians.part_names),
                        ("gaussians.blend_names", h.gaussians.blend_names)):
        if len(set(names)) != len(names):
            raise _Invalid(f"{what} has duplicate names")
    if h.dynamics:
        try:
            check_dynamics(h.dynamics, h.format_version)
        except HeaderError as e:
            raise _Invalid(str(e)) from None
    if h.cnn:
        try:
            CNNConfig.from_json(h.cnn)
        except ValueError as e:
            raise _Invalid(str(e)) from None
    if h.expression:
        ex: _Expression = _decoded(h.expression, _Expression, "expression")
        if len(set(ex.named)) != len(ex.named):
            raise _Invalid("expression.named has duplicate names")
    for name, entry in h.tensors.items():
        _decoded(entry, _TensorEntry, f"tensors[{brief(name)}]")


def _check_blendshapes(header: dict) -> None:
    entry = blendshapes_field.header_entry(header)
    if entry is not None:
        try:
            blendshapes_field.check_section(entry)
        except ValueError as e:
            raise _Invalid(str(e)) from None


def _blendshapes_of(header: dict, t: dict[str, np.ndarray], dynamics: Dynamics | None) -> Any:
    entry = blendshapes_field.header_entry(header)
    if entry is None:
        return None
    code_dim = 0 if dynamics is None else dynamics.code_dim
    condition_dim = 0 if dynamics is None else dynamics.condition_dim
    try:
        return blendshapes_field.build(entry, t, code_dim, condition_dim, MAX_PARAMETER)
    except ValueError as e:
        raise _Invalid(f"blendshapes: {e}") from None


def _map_tensors(path: Path, header: dict, data_start: int) -> dict[str, np.ndarray]:
    spec = expected_tensors(header)
    table = header["tensors"]
    missing = [n for n in spec if n not in table]
    if missing:
        raise _Invalid(f"missing tensor{'s' if len(missing) > 1 else ''} {', '.join(missing[:5])}")
    extra = [n for n in table if n not in spec]
    if extra:
        raise _Invalid(f"unexpected tensor{'s' if len(extra) > 1 else ''} {', '.join(map(repr, extra[:5]))} "
                       "(not implied by the header's architecture)")
    size = path.stat().st_size
    end_needed = data_start
    entries = {}
    for name, (dt, shape) in spec.items():
        off, nbytes = _table_entry(table[name], name, dt, shape)
        entries[name] = (dt, shape, off, nbytes)
        end_needed = max(end_needed, data_start + off + nbytes)
    if end_needed > size:
        raise _Invalid(f"truncated: data needs {end_needed} bytes, the file has {size}")
    declared = header.get("data_nbytes")
    if declared is not None and data_start + declared > size:
        raise _Invalid(f"truncated: the data section is {declared} bytes, the file has {size - data_start}")
    spans = sorted((off, off + nb, n) for n, (_, _, off, nb) in entries.items() if nb)
    for (_, e0, n0), (s1, _, n1) in zip(spans, spans[1:], strict=False):
        if s1 < e0:
            raise _Invalid(f"tensors {n0} and {n1} overlap")
    data = _read_data(path, data_start, end_needed - data_start)
    out = {}
    for name, (dt, shape, off, nbytes) in entries.items():
        out[name] = data[off : off + nbytes].view(_DTYPES[dt]).reshape(shape)
    return out


def _table_entry(e: Any, name: str, dt: str, shape: tuple[int, ...]) -> tuple[int, int]:
    """(offset, nbytes) of one tensor table entry (declared by `_TensorEntry`, checked with the header), checked
    against the dtype and shape the header implies."""
    entry: _TensorEntry = _decoded(e, _TensorEntry, f"tensors[{brief(name)}]")
    if entry.dtype != dt:
        raise _Invalid(f"{name} has dtype {brief(entry.dtype)}, expected {dt}")
    if tuple(entry.shape) != shape:
        raise _Invalid(f"{name} has shape {tuple(entry.shape)}, the header implies {shape}")
    want = math.prod(shape) * _DTYPES[dt].itemsize
    if entry.nbytes != want:
        raise _Invalid(f"{name} declares {entry.nbytes} bytes, its shape needs {want}")
    if entry.offset % ALIGN:
        raise _Invalid(f"{name} offset {entry.offset} is not aligned to {ALIGN}")
    return entry.offset, entry.nbytes


def _read_data(path: Path, start: int, nbytes: int) -> np.ndarray:
    """The data section read into memory (read-only): never mapped, so a file truncated or rewritten by another
    program while it is open cannot crash the process (a mapped page past a new end is SIGBUS)."""
    buf = np.empty(nbytes, np.uint8)
    with open_regular(path, "an .npga checkpoint") as fh:
        fh.seek(start)
        got = fh.readinto(memoryview(buf)) if nbytes else 0  # type: ignore[arg-type, attr-defined]
    if got != nbytes:
        raise _Invalid(f"truncated while reading: the data needs {nbytes} bytes, {got} could be read")
    buf.setflags(write=False)
    return buf


def _check_values(t: dict[str, np.ndarray], header: dict) -> None:
    for name, a in t.items():
        if a.dtype.kind == "f" and a.size and not np.isfinite(a).all():
            bad = int(a.size - np.count_nonzero(np.isfinite(a)))
            raise _Invalid(f"{name} has {bad} NaN/Inf value{'s' if bad > 1 else ''}")
    q = t["gaussians.quats"]
    if q.size:
        nq = np.einsum("ij,ij->i", q, q)
        zero = int(np.count_nonzero(nq < 1e-16))
        if zero:
            raise _Invalid(f"gaussians.quats has {zero} zero-length quaternion{'s' if zero > 1 else ''}")
    m = t["gaussians.means"]
    if m.size and np.abs(m).max() > MAX_POSITION:  # the limit the PLY reader and every other reader apply
        raise _Invalid(f"gaussians.means reach {float(np.abs(m).max()):.3g}, beyond the +-{MAX_POSITION:g} they "
                       "may have")
    ls = t["gaussians.log_scales"]
    if ls.size and np.abs(ls).max() > 80:
        raise _Invalid("gaussians.log_scales has values beyond +-80 (scale overflows float32)")
    w = t.get("gaussians.blend_weights")
    if w is not None and w.size and (w.min() < 0.0 or w.max() > 1.0):
        raise _Invalid("gaussians.blend_weights has values outside 0..1")
    for name, a in t.items():
        if name.startswith(("dynamics.", "cnn.", "expression.")) and a.size and np.abs(a).max() > MAX_PARAMETER:
            raise _Invalid(f"{name} has values beyond +-{MAX_PARAMETER:.0e} (no trained network has them; they "
                           "overflow float32 in a forward pass)")
    if "gaussians.part_ids" in t:
        p = t["gaussians.part_ids"]
        n_parts = len(header["gaussians"]["part_names"])
        if p.size and (p.min() < -1 or p.max() >= n_parts):
            raise _Invalid(f"gaussians.part_ids has values outside -1..{n_parts - 1}")


def _build_avatar(path: Path, header: dict, t: dict[str, np.ndarray]) -> Avatar:
    g = header["gaussians"]
    cloud = GaussianCloud(
        means=t["gaussians.means"],
        quats=t["gaussians.quats"],
        log_scales=t["gaussians.log_scales"],
        opacity_logits=t["gaussians.opacity_logits"],
        sh=t["gaussians.sh"],
        features=t["gaussians.features"],
        latent=t.get("gaussians.latent"),
        part_ids=t.get("gaussians.part_ids"),
        part_names=list(g.get("part_names", [])),
        blend_weights=t.get("gaussians.blend_weights"),
        blend_names=list(g.get("blend_names", [])),
    )
    dynamics = None
    dyn = header.get("dynamics")
    if dyn:
        try:
            dynamics = build_dynamics(dyn, header["format_version"], t)
            dynamics.validate_for(cloud)
        except ValueError as e:
            raise _Invalid(f"dynamics do not fit the Gaussians: {e}") from None
    rig_entry = rig_field.header_entry(header)
    if rig_entry:
        try:
            rig = rig_field.build(rig_entry, t, len(cloud), MAX_POSITION)
        except ValueError as e:
            raise _Invalid(f"rig: {e}") from None
        if dynamics is None:
            dynamics = Dynamics(networks={}, rig=rig)
        elif rig.skin is not None:
            raise _Invalid("rig: a rig on a skinned mesh poses its avatar alone (the file also has dynamics)")
        else:
            dynamics.rig = rig
    cnn = None
    if header.get("cnn"):
        try:
            CNNConfig.from_json(header["cnn"]).validate(cloud.latent_dim)
        except ValueError as e:
            raise _Invalid(str(e) if str(e).startswith("cnn") else f"cnn: {e}") from None
        cnn = build_cnn(header["cnn"], t)
    expression = None
    ex = header.get("expression")
    if ex:
        named = {}
        if ex.get("named"):
            codes = np.array(t["expression.named"])
            named = {name: codes[i] for i, name in enumerate(ex["named"])}
        expression = ExpressionSpace(np.array(t["expression.mean"]), np.array(t["expression.basis"]),
                                     np.array(t["expression.std"]), named)
        try:
            expression.validate()
        except ValueError as e:
            raise _Invalid(f"expression space: {e}") from None
        if dynamics is not None and expression.dim != dynamics.code_dim:
            raise _Invalid(f"expression space has {expression.dim} dims, the dynamics take {dynamics.code_dim}")
    prov = header.get("provenance") or {}
    return Avatar(cloud, dynamics, cnn, expression, provenance=prov, units=str(header.get("units", "m")),
                  source=str(path), blendshapes=_blendshapes_of(header, t, dynamics))


def read_avatar(path: str | Path) -> Avatar:
    """Read and fully validate a `.npga` file; arrays are read into memory (read-only, never mapped).

    Raises AvatarFileError("path: problem") for anything wrong with the file.
    """
    path = Path(path)
    header, data_start = read_header(path)
    try:
        tensors = _map_tensors(path, header, data_start)
        _check_values(tensors, header)
        return _build_avatar(path, header, tensors)
    except _Invalid as e:
        raise AvatarFileError(path, str(e)) from None
    except (KeyError, TypeError, ValueError) as e:
        raise AvatarFileError(path, f"malformed header: {e}") from None
    except OSError as e:
        raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
