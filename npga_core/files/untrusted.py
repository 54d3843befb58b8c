"""One way to read files the project did not write itself: bounded, regular files only, never unpickled.

Every reader of user-given files goes through these helpers (`.npy`, `.npz`, JSON), so one class of hostile
file is closed everywhere at once:

- only regular files are opened (`regular_file`, `open_regular`): a FIFO, device or socket is refused before
  it is read, and the open itself does not block (O_NONBLOCK, then the descriptor is checked again);
- nothing is read without end: every read has a byte budget, and array sizes are checked from the `.npy`
  header (shape x itemsize) before anything is allocated, per member for `.npz` (with a bounded member count
  and a total budget);
- only numeric dtypes (no object, structured or complex arrays; `allow_pickle` is never set), and
  `real_floats` turns an array into finite float32/float64 values or refuses it;
- numbers are checked against the range their meaning allows (`bounded_floats` and the limits below:
  positions, log-scales, codes, translations, focal lengths, times, frame rates), and every computed output
  is checked finite before it is drawn or written (`finite_output`);
- names and paths of any encoding are shown escaped (`shown`, from npga_core.errors);
- JSON has a size bound and a nesting-depth bound checked by a non-recursive scan before parsing; NaN,
  Infinity, non-finite floats and absurdly long integers are refused. What the parsed value must look like is
  declared as a schema and checked by `npga_core.schema` (field paths in its messages).

Every failure is an `AvatarFileError(path, "one line")`.
"""

from __future__ import annotations

import io
import json
import lzma
import math
import os
import stat
import zipfile
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

import numpy as np

from npga_core.camera.cameras import MAX_FOCAL, MAX_POSITION  # noqa: F401  (shared limits: pixels, positions)
from npga_core.errors import AvatarFileError, shown  # noqa: F401  (shown: the escaping of every shown name)
from npga_core.model.expression import MAX_CODE, STD_RANGE  # noqa: F401  (codes, PCA std)

#: Largest JSON file read by default (sessions, keyframes, rigs, presets).
MAX_JSON_BYTES = 16 * 1024 * 1024
#: Deepest JSON nesting accepted by default.
MAX_JSON_DEPTH = 64
#: Most members read from one `.npz`.
MAX_NPZ_MEMBERS = 256
#: Largest image side accepted from a camera file (GL limits are checked again where targets are made).
MAX_IMAGE_SIDE = 16384
#: Most pixels of an image decoded, resized or allocated from a file's numbers (64 Mpx: 768 MB as float32 RGB);
#: `check_pixels` before any allocation (a 1x16384 image covering 550x802 would be resized to 550x9 million).
MAX_IMAGE_PIXELS = 1 << 26
#: Longest integer literal accepted in JSON (digits).
MAX_INT_DIGITS = 40
#: Largest magnitude of a log-scale (as the `.npga` reader).
MAX_LOG_SCALE = 80.0
#: Largest magnitude of a quaternion component (its square must stay far within float32).
MAX_QUAT = 1e6
#: Range of a frame rate (frames per second).
FPS_RANGE = (0.01, 1000.0)
#: Largest time (seconds) of a key or a sequence (one day).
MAX_TIME_S = 86400.0
#: Most frames a timeline or a sequence may make a command render or bake.
MAX_FRAMES = 1_000_000

_NUMERIC_KINDS = "fiu"
_NPY_MAX_HEADER = 10000


def _kind_name(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _check_mode(path: str | Path, mode: int, what: str) -> None:
    if stat.S_ISDIR(mode):
        raise AvatarFileError(path, f"is a directory, not {what}")
    if not stat.S_ISREG(mode):
        raise AvatarFileError(path, f"is {_kind_name(mode)}, not a regular file")


def regular_file(path: str | Path, what: str = "a file") -> Path:
    """`path` as a Path if it names an existing regular file (symlinks followed); else AvatarFileError.

    Refuses directories, FIFOs, devices and sockets without opening them.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except (FileNotFoundError, NotADirectoryError):
        raise AvatarFileError(p, "no such file") from None
    except PermissionError:
        raise AvatarFileError(p, "permission denied") from None
    except (OSError, ValueError) as e:
        raise AvatarFileError(p, f"cannot open: {getattr(e, 'strerror', None) or e}") from None
    _check_mode(p, st.st_mode, what)
    return p


def is_folder(path: str | Path) -> bool:
    """Whether `path` is a folder, False for any path the system cannot look at (a name too long, a file in the
    way, no permission; pathlib's is_dir raises for some of those)."""
    try:
        return stat.S_ISDIR(os.stat(path).st_mode)
    except (OSError, ValueError):
        return False


def open_regular(path: str | Path, what: str = "a file") -> IO[bytes]:
    """Open a regular file for binary reading without ever blocking on a FIFO; AvatarFileError otherwise.

    The path is checked with stat first, opened non-blocking where the platform has it, and the open
    descriptor is checked again (a file swapped for a FIFO in between is still refused).
    """
    p = regular_file(path, what)
    flags = os.O_RDONLY | getattr(os, "O_BINARY", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(p, flags)
    except PermissionError:
        raise AvatarFileError(p, "permission denied") from None
    except OSError as e:
        raise AvatarFileError(p, f"cannot open: {e.strerror or e}") from None
    try:
        _check_mode(p, os.fstat(fd).st_mode, what)
        if getattr(os, "O_NONBLOCK", 0):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


def file_size(fh: IO[bytes]) -> int | None:
    """Size in bytes of an open regular file, None for other streams."""
    try:
        return os.fstat(fh.fileno()).st_size
    except (AttributeError, OSError, io.UnsupportedOperation):
        return None


def read_bytes(path: str | Path, max_bytes: int, what: str = "a file") -> bytes:
    """The whole content of a regular file of at most `max_bytes` bytes."""
    with open_regular(path, what) as fh:
        size = file_size(fh)
        if size is not None and size > max_bytes:
            raise AvatarFileError(path, f"is {size} bytes, more than the {max_bytes} allowed for {what}")
        try:  # what the file holds, plus one byte to see it grow (a read of the budget would allocate it all)
            data = fh.read((max_bytes if size is None else min(size, max_bytes)) + 1)
        except OSError as e:
            raise AvatarFileError(path, f"cannot read: {e.strerror or e}") from None
    if len(data) > max_bytes:
        raise AvatarFileError(path, f"is more than the {max_bytes} bytes allowed for {what}")
    if size is not None and len(data) != size:
        raise AvatarFileError(path, f"changed while it was read ({size} bytes, then {len(data)})")
    return data


# --------------------------------------------------------------------------------------------------
# .npy / .npz


def _read_exact(fh: IO[bytes], n: int) -> bytearray:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        chunk = fh.read(min(n - got, 1 << 24))
        if not chunk:
            break
        view[got:got + len(chunk)] = chunk
        got += len(chunk)
    if got != n:
        raise EOFError(f"truncated: the header claims {n} data bytes, only {got} follow")
    return buf


def _check_dtype(dtype: np.dtype, kinds: str, name: str) -> None:
    if dtype.hasobject:
        raise ValueError(f"{name} holds Python objects (pickles are never loaded)")
    if dtype.kind == "c":
        raise ValueError(f"{name} is complex ({dtype}); real numbers are expected")
    if dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f"{name} has a structured dtype; plain numbers are expected")
    if dtype.kind not in kinds:
        expected = "numbers" if set(kinds) <= set(_NUMERIC_KINDS + "b") else f"dtype kind in {kinds!r}"
        raise ValueError(f"{name} has dtype {dtype}; {expected} are expected")


def _npy_from_stream(fh: IO[bytes], max_bytes: int, name: str, kinds: str, available: int | None) -> np.ndarray:
    if available == 0:
        raise EOFError(f"{name}: the file is empty")
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh, max_header_size=_NPY_MAX_HEADER)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh, max_header_size=_NPY_MAX_HEADER)
    else:
        raise ValueError(f"{name}: unsupported .npy format version {version[0]}.{version[1]}")
    _check_dtype(dtype, kinds, name)
    if any(int(s) < 0 for s in shape):
        raise ValueError(f"{name}: negative dimension in shape {shape}")
    nbytes = math.prod(int(s) for s in shape) * dtype.itemsize
    if nbytes > max_bytes:
        raise ValueError(f"{name}: shape {tuple(shape)} of {dtype} needs {nbytes} bytes, "
                         f"more than the {max_bytes} allowed")
    if available is not None:
        left = available - fh.tell()
        if nbytes > left:
            raise EOFError(f"{name}: truncated: shape {tuple(shape)} of {dtype} needs {nbytes} bytes, "
                           f"{max(left, 0)} follow")
    buf = _read_exact(fh, nbytes)
    arr = np.frombuffer(buf, dtype=dtype)
    return arr.reshape(shape, order="F" if fortran else "C")


def read_npy(source: str | Path | IO[bytes], max_bytes: int, name: str | None = None,
             kinds: str = _NUMERIC_KINDS, path: str | Path | None = None) -> np.ndarray:
    """Read one `.npy` array, its size checked from the header against `max_bytes` before allocating.

    `source` is a path (opened with `open_regular`) or a binary file object positioned at the magic.
    `kinds` are the accepted numpy dtype kinds (default real numbers "fiu"; add "U" for strings, "b" for bool);
    object, complex and structured dtypes are always refused. `path` names the file in errors when `source`
    is a stream. The array is writable and owns its memory.
    """
    where = path if path is not None else (source if isinstance(source, str | Path) else "<stream>")
    label = name or "array"
    try:
        if isinstance(source, str | Path):
            with open_regular(source, "an .npy array") as fh:
                return _npy_from_stream(fh, max_bytes, label, kinds, file_size(fh))
        return _npy_from_stream(source, max_bytes, label, kinds, None)
    except AvatarFileError:
        raise
    except MemoryError:
        raise AvatarFileError(where, f"{label}: not enough memory to read it") from None
    except (ValueError, OSError, EOFError, SyntaxError, TypeError, OverflowError) as e:
        msg = str(e) if str(e).startswith(label) else f"{label}: {e}"
        raise AvatarFileError(where, f"not a readable .npy array ({msg})") from None


def read_npz(path: str | Path, max_bytes: int, keys: Iterable[str] | None = None,
             max_members: int = MAX_NPZ_MEMBERS, kinds: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """Read the arrays of an `.npz` (as numpy.savez writes it), within a total budget of `max_bytes`.

    Each member's `.npy` header is checked before its data is read; member count, every member's claimed
    size and the total are bounded. `keys` limits which members are read (others are skipped unread);
    `kinds` maps a member name to its accepted dtype kinds (default real numbers).
    """
    p = Path(path)
    wanted = None if keys is None else set(keys)
    out: dict[str, np.ndarray] = {}
    try:
        with open_regular(p, "an .npz archive") as fh, zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
            if len(infos) > max_members:
                raise AvatarFileError(p, f"has {len(infos)} members, more than the {max_members} allowed")
            left = max_bytes
            for info in infos:
                key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                if wanted is not None and key not in wanted:
                    continue
                if key in out:
                    raise AvatarFileError(p, f"member {key!r} appears twice")
                if info.file_size > left + _NPY_MAX_HEADER + 128:
                    raise AvatarFileError(p, f"member {key!r} claims {info.file_size} bytes, more than the "
                                          f"{max_bytes} allowed in all")
                with zf.open(info) as member:
                    arr = _npy_from_stream(member, left, key, (kinds or {}).get(key, _NUMERIC_KINDS), None)
                out[key] = arr
                left -= arr.nbytes
    except AvatarFileError:
        raise
    except MemoryError:
        raise AvatarFileError(p, "not enough memory to read it") from None
    except (ValueError, OSError, EOFError, SyntaxError, TypeError, OverflowError, zipfile.BadZipFile,
            NotImplementedError, RuntimeError, zlib.error, lzma.LZMAError) as e:
        raise AvatarFileError(p, f"not a readable npz ({e})") from None
    return out


def npz_names(path: str | Path, max_members: int = MAX_NPZ_MEMBERS) -> list[str]:
    """The array names in an `.npz` (member names without `.npy`), read from the zip directory only."""
    p = Path(path)
    try:
        with open_regular(p, "an .npz archive") as fh, zipfile.ZipFile(fh) as zf:
            names = zf.namelist()
    except AvatarFileError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as e:
        raise AvatarFileError(p, f"not a readable npz ({e})") from None
    if len(names) > max_members:
        raise AvatarFileError(p, f"has {len(names)} members, more than the {max_members} allowed")
    return [n[:-4] if n.endswith(".npy") else n for n in names]


def zip_member_names(path: str | Path, max_members: int, what: str = "a zip archive") -> list[str]:
    """The member names of a zip archive from its central directory only, refused when there are more than
    `max_members` or one is not a plain relative path (absolute, a drive, a backslash, '..', a NUL byte)."""
    p = Path(path)
    try:
        with open_regular(p, what) as fh, zipfile.ZipFile(fh) as zf:
            names = [i.filename for i in zf.infolist()]
    except AvatarFileError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as e:
        raise AvatarFileError(p, f"not a readable zip archive ({e})") from None
    if len(names) > max_members:
        raise AvatarFileError(p, f"has {len(names)} members, more than the {max_members} allowed")
    for name in names:
        parts = name.split("/")
        if (name.startswith("/") or "\\" in name or "\0" in name or ".." in parts
                or (len(name) > 1 and name[1] == ":")):
            raise AvatarFileError(p, f"member {shown(name)!r} is not a plain relative path (refused)")
    return names


def read_zip_members(path: str | Path, names: dict[str, int], max_total: int,
                     what: str = "a zip archive") -> dict[str, bytes]:
    """The bytes of the members `names` (name -> most bytes allowed) of a zip archive whose names were checked by
    `zip_member_names`: each member's size is taken from the central directory before it is read, reads stop one
    byte past the claim (a member that inflates beyond it is refused), and all of them within `max_total`."""
    p = Path(path)
    out: dict[str, bytes] = {}
    try:
        with open_regular(p, what) as fh, zipfile.ZipFile(fh) as zf:
            left = max_total
            for name, limit in names.items():
                info = zf.getinfo(name)
                if info.file_size > min(limit, left):
                    raise AvatarFileError(p, f"member {shown(name)!r} claims {info.file_size:,} bytes, more than "
                                          f"the {min(limit, left):,} allowed")
                with zf.open(info) as member:
                    data = member.read(info.file_size + 1)
                if len(data) != info.file_size:
                    raise AvatarFileError(p, f"member {shown(name)!r} holds {len(data):,} bytes, its directory "
                                          f"entry says {info.file_size:,}")
                out[name] = data
                left -= len(data)
    except AvatarFileError:
        raise
    except MemoryError:
        raise AvatarFileError(p, "not enough memory to read it") from None
    except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile, NotImplementedError, RuntimeError,
            zlib.error, lzma.LZMAError) as e:
        raise AvatarFileError(p, f"not a readable zip archive ({e})") from None
    return out


def real_floats(arr: Any, path: str | Path, what: str, dtype: Any = np.float32) -> np.ndarray:
    """`arr` as finite real floats of `dtype`; AvatarFileError for complex, non-numeric, NaN/Inf or overflow."""
    a = np.asarray(arr) if not isinstance(arr, np.ndarray) else arr
    if a.dtype.kind == "c":
        raise AvatarFileError(path, f"{what} are complex numbers ({a.dtype}); real numbers are expected")
    if a.dtype.kind not in _NUMERIC_KINDS:
        raise AvatarFileError(path, f"{what} have dtype {a.dtype}; real numbers are expected")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise AvatarFileError(path, f"{what} have {int((~np.isfinite(a)).sum())} NaN/Inf values")
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.asarray(a, dtype=dtype)
    if not np.isfinite(out).all():
        raise AvatarFileError(path, f"{what} have values beyond the range of {np.dtype(dtype).name}")
    return out


def bounded_floats(arr: Any, path: str | Path, what: str, limit: float, dtype: Any = np.float32) -> np.ndarray:
    """`real_floats` whose magnitudes are at most `limit` (the range the values' meaning allows)."""
    out = real_floats(arr, path, what, dtype)
    if out.size:
        peak = float(np.abs(out).max())
        if not peak <= limit:
            raise AvatarFileError(path, f"{what} reach {peak:.3g}, beyond the +-{limit:g} they may have")
    return out


def finite_output(arrays: dict[str, Any], source: str | Path, what: str) -> None:
    """AvatarFileError naming `source` and the first field of `arrays` holding NaN/Inf (a computed output,
    checked before it is drawn or written)."""
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.size and a.dtype.kind == "f" and not np.isfinite(a).all():
            bad = int(a.size - np.count_nonzero(np.isfinite(a)))
            raise AvatarFileError(source, f"{what}: {name} has {bad} NaN/Inf values (the file's numbers "
                                  "overflow when used); nothing was written")


# --------------------------------------------------------------------------------------------------
# JSON


def json_depth(data: bytes, stop_above: int | None = None, chunk: int = 1 << 20) -> int:
    """Deepest bracket nesting of JSON text (UTF-8 bytes), computed without recursion, in bounded memory.

    Brackets inside strings are not counted (a quote after an odd run of backslashes is escaped). Exact for
    valid JSON; for invalid text it is only an estimate (the parser refuses such text anyway). With
    `stop_above`, returns as soon as the depth exceeds it.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    in_string, depth, deepest, run = 0, 0, 0, 0  # carried from one chunk to the next
    for start in range(0, buf.size, chunk):
        b = buf[start:start + chunk]
        idx = np.arange(b.size, dtype=np.int64)
        backslash = b == ord("\\")
        last_plain = np.maximum.accumulate(np.where(~backslash, idx, -1))  # last non-backslash at or before i
        before = np.empty(b.size, dtype=np.int64)  # length of the backslash run right before position i
        before[0] = run
        prev = last_plain[:-1]
        before[1:] = np.where(prev >= 0, idx[:-1] - prev, idx[1:] + run)
        quote = (b == ord('"')) & (before % 2 == 0)
        count = np.cumsum(quote, dtype=np.int64)
        inside = (in_string + count - quote) % 2 == 1
        step = np.zeros(b.size, dtype=np.int64)
        step[(b == ord("[")) | (b == ord("{"))] = 1
        step[(b == ord("]")) | (b == ord("}"))] = -1
        step[inside] = 0
        levels = depth + np.cumsum(step)
        deepest = max(deepest, int(levels.max()))
        if stop_above is not None and deepest > stop_above:
            return deepest
        in_string = int((in_string + count[-1]) % 2)
        depth = int(levels[-1])
        run = int(b.size - 1 - last_plain[-1]) + (run if last_plain[-1] < 0 else 0)
    return deepest


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number")


def _finite_float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"number {text[:20]}... is out of range")
    return v


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"integer with {len(text)} digits is out of range")
    return int(text)


def _unique_pairs(pairs: list) -> dict:
    out = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"the key {shown(k)[:60]!r} appears twice")
        out[k] = v
    return out


def parse_json(data: bytes | str, path: str | Path, max_depth: int = MAX_JSON_DEPTH, unique_keys: bool = False) -> Any:
    """Parse JSON text with a nesting bound, refusing NaN/Infinity, non-finite floats and integers of more than
    `MAX_INT_DIGITS` digits (Python's own limit, 4300, is a ValueError far from the file); with `unique_keys`, an
    object naming a key twice is refused too."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise AvatarFileError(path, f"not UTF-8 text ({e.reason} at byte {e.start})") from None
    depth = json_depth(raw, stop_above=max_depth)
    if depth > max_depth:
        raise AvatarFileError(path, f"JSON nested {depth} levels deep, more than the {max_depth} allowed")
    try:
        return json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float,
                          parse_int=_bounded_int, object_pairs_hook=_unique_pairs if unique_keys else None)
    except json.JSONDecodeError as e:
        raise AvatarFileError(path, f"not valid JSON ({e})") from None
    except (ValueError, RecursionError) as e:
        raise AvatarFileError(path, f"not valid JSON ({e})") from None


def read_json(path: str | Path, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH,
              what: str = "a JSON file") -> Any:
    """Read a regular JSON file of at most `max_bytes` and nesting at most `max_depth`."""
    return parse_json(read_bytes(path, max_bytes, what), path, max_depth)


# --------------------------------------------------------------------------------------------------
# images


def check_pixels(width: int, height: int, path: str | Path, what: str = "an image of") -> None:
    """AvatarFileError naming `path` when WxH pixels exceed `MAX_IMAGE_PIXELS` (checked before an image is
    decoded, resized or allocated)."""
    if width * height > MAX_IMAGE_PIXELS:
        raise AvatarFileError(path, f"{what} {width}x{height} pixels, more than the {MAX_IMAGE_PIXELS:,} allowed")
