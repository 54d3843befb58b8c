"""Baked sequences: the exact offsets of a sequence's frames, quantised, held within a memory budget.

A bake stores, per stored frame, the combined offset rows (`fastpose.OffsetLayout`) of all Gaussians quantised
to 8 or 16 bits with a per-frame, per-column affine map (lo + q * step). Playing a frame dequantises and applies
the offsets (`FastPoser.apply_into`), which is far cheaper than the networks. When the whole sequence does not
fit the budget, every s-th frame is stored (s as small as the budget allows) and the frames between are
interpolated linearly in offset space; `BakeStore.exact(frame)` tells which is which.

A finished bake can be written to a cache file (header + raw arrays, memory-mapped when reopened) named by the
key of its content: the avatar's content hash, a hash of the codes, the storage parameters and the format. A
cache is reused only when all of them match, so an edited avatar or a changed sequence is baked again.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import torch

from npga_core.errors import AvatarFileError
from npga_core.files.atomic import atomic_write
from npga_core.files.places import cache_folder_for
from npga_core.files.untrusted import file_size, open_regular, parse_json
from npga_core.schema import decode_file, number

BAKE_MAGIC = b"NPGABAKE"
BAKE_FORMAT = 1
_ALIGN = 64
_MAX_HEADER = 1 << 16  # bytes of a cache file's JSON header
_MAX_FRAMES = 10**7  # frames of a cached sequence
#: Largest magnitude of a cached offset (positions, log-scales, SH, ...: far beyond any avatar's).
MAX_OFFSET = 1e6


def bake_key(avatar_key: str, codes: np.ndarray, bits: int, budget_bytes: int) -> str:
    """Content key of a bake: avatar hash, codes, storage parameters, format."""
    h = hashlib.blake2b(digest_size=16)
    codes = np.ascontiguousarray(codes, np.float32)
    h.update(f"{BAKE_FORMAT}|{avatar_key}|{bits}|{budget_bytes}|{codes.shape}".encode())
    h.update(memoryview(codes).cast("B"))  # type: ignore[arg-type]
    return h.hexdigest()


def cache_path(avatar_path: str | Path, key: str, cache_dir: str | Path | None = None) -> Path:
    """Where the bake of `key` is cached: in `cache_dir`, else next to the avatar when its folder is writable
    and not the bundled demo, else in the user cache folder's `bakes/`."""
    p = Path(avatar_path)
    folder = Path(cache_dir) if cache_dir is not None else cache_folder_for(p, "bakes")
    return folder / f"{p.name}.bake-{key[:20]}.npgabake"


def plan_stride(frames: int, rows: int, width: int, bits: int, budget_bytes: int) -> int:
    """Smallest frame stride whose stored frames fit the budget (ValueError if not even two frames fit)."""
    per_frame = rows * width * (bits // 8) + 2 * width * 4
    fit = budget_bytes // max(1, per_frame)
    if fit >= frames:
        return 1
    if fit < 2:
        raise ValueError(f"a bake budget of {budget_bytes / 2**20:.0f} MB holds fewer than 2 frames "
                         f"({per_frame / 2**20:.1f} MB each)")
    return max(1, math.ceil((frames - 1) / (fit - 1)))


@dataclass
class BakeStore:
    """Quantised offsets of the stored frames of one sequence (see the module docstring)."""

    key: str
    frames: int  # frames in the sequence
    stride: int  # every stride-th frame is stored (and the last one)
    data: np.ndarray  # (stored, N, width) uint8 or uint16
    lo: np.ndarray  # (stored, width) float32
    step: np.ndarray  # (stored, width) float32
    done: np.ndarray  # (stored,) bool

    @staticmethod
    def create(key: str, frames: int, rows: int, width: int, bits: int = 8, budget_bytes: int = 1 << 30,
               ) -> BakeStore:
        if bits not in (8, 16):
            raise ValueError(f"bake bits must be 8 or 16, got {bits}")
        stride = plan_stride(frames, rows, width, bits, budget_bytes)
        stored = len(_stored_frames(frames, stride))
        dtype = np.uint8 if bits == 8 else np.uint16
        return BakeStore(key, frames, stride, np.zeros((stored, rows, width), dtype),
                         np.zeros((stored, width), np.float32), np.zeros((stored, width), np.float32),
                         np.zeros(stored, bool))

    @property
    def stored_frames(self) -> list[int]:
        """Sequence frame of each stored slot."""
        return _stored_frames(self.frames, self.stride)

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    @property
    def nbytes(self) -> int:
        return int(self.data.nbytes + self.lo.nbytes + self.step.nbytes)

    def exact(self, frame: int) -> bool:
        """True when `frame` is stored (only quantised), False when interpolated between stored frames."""
        return frame % self.stride == 0 or frame == self.frames - 1

    def put(self, slot: int, offsets: torch.Tensor) -> None:
        """Quantise the offsets (N, width) of stored slot `slot`."""
        levels = float(np.iinfo(self.data.dtype).max)
        lo = offsets.amin(0)
        step = (offsets.amax(0) - lo).clamp_min(1e-30) / levels
        q = ((offsets - lo) / step).round_().clamp_(0, levels)
        self.data[slot] = q.numpy().astype(self.data.dtype)
        self.lo[slot], self.step[slot] = lo.numpy(), step.numpy()
        self.done[slot] = True

    def _dequantise(self, slot: int, s: int, e: int) -> torch.Tensor:
        q = torch.from_numpy(np.asarray(self.data[slot, s:e], np.float32))
        return q.mul_(torch.from_numpy(self.step[slot])).add_(torch.from_numpy(self.lo[slot]))

    def offsets_into(self, frame: int, out: torch.Tensor, chunk: int = 16384) -> None:
        """Offsets (N, width) of sequence frame `frame` into `out`, interpolated between stored frames."""
        if not 0 <= frame < self.frames:
            raise ValueError(f"frame {frame} outside 0..{self.frames - 1}")
        a = min(frame // self.stride, len(self.done) - 1)
        fa = self.stored_frames[a]
        t = 0.0 if frame == fa else (frame - fa) / (self.stored_frames[a + 1] - fa)
        if not self.done[a] or (t and not self.done[a + 1]):
            raise ValueError(f"frame {frame} is not baked yet")
        n = out.shape[0]
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            rows = self._dequantise(a, s, e)
            if t:
                rows.mul_(1.0 - t).add_(self._dequantise(a + 1, s, e), alpha=t)
            out[s:e].copy_(rows)

    # -- cache file ----------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the complete bake atomically (header, lo, step, data)."""
        if not self.complete:
            raise ValueError("only a complete bake can be saved")
        header = {"format": BAKE_FORMAT, "key": self.key, "frames": self.frames, "stride": self.stride,
                  "shape": list(self.data.shape), "dtype": self.data.dtype.str}
        text = json.dumps(header).encode()
        text += b" " * ((-(len(BAKE_MAGIC) + 8 + len(text))) % _ALIGN)

        def write(fh: IO[bytes]) -> None:
            fh.write(BAKE_MAGIC + len(text).to_bytes(8, "little") + text)
            fh.write(np.ascontiguousarray(self.lo).tobytes())
            fh.write(np.ascontiguousarray(self.step).tobytes())
            for slot in range(self.data.shape[0]):
                fh.write(np.ascontiguousarray(self.data[slot]).tobytes())

        atomic_write(path, write)

    @staticmethod
    def open(path: str | Path, key: str, rows: int | None = None, width: int | None = None) -> BakeStore | None:
        """The cached bake at `path` (memory-mapped) if it holds content `key` (and `rows` x `width` offsets
        per frame, when given), else None.

        The cache is untrusted (`npga_core.files.untrusted`): a regular file only, header size and depth
        bounded, shape, dtype and frame counts checked against the file size; anything wrong is a miss (None).
        """
        path = Path(path)
        try:
            with open_regular(path, "a bake cache") as fh:
                if fh.read(len(BAKE_MAGIC)) != BAKE_MAGIC:
                    return None
                hlen = int.from_bytes(fh.read(8), "little")
                if hlen > _MAX_HEADER:
                    return None
                header = decode_file(parse_json(fh.read(hlen), path, max_depth=4), dict[str, Any], path, "bake header")
                size = file_size(fh) or 0
            if header.get("format") != BAKE_FORMAT or header.get("key") != key:
                return None
            shape, dtype = header.get("shape"), header.get("dtype")
            if dtype not in ("|u1", "<u2") or not isinstance(shape, list) or len(shape) != 3:
                return None
            stored, n_rows, n_width = (number(v, "bake shape", 1, 2**40, whole=True) for v in shape)
            frames = number(header.get("frames"), "bake frames", 1, _MAX_FRAMES, whole=True)
            stride = number(header.get("stride"), "bake stride", 1, _MAX_FRAMES, whole=True)
            if _stored_count(frames, stride) != stored or (n_rows, n_width) != (rows or n_rows, width or n_width):
                return None
            start = len(BAKE_MAGIC) + 8 + hlen
            table = stored * n_width * 4
            if start + 2 * table + stored * n_rows * n_width * np.dtype(dtype).itemsize > size:
                return None  # truncated (or a header claiming more than the file holds)
            lo = np.fromfile(path, np.float32, stored * n_width, offset=start).reshape(stored, n_width)
            step = np.fromfile(path, np.float32, stored * n_width, offset=start + table).reshape(stored, n_width)
            if not (np.all(np.abs(lo) <= MAX_OFFSET) and np.all((step >= 0) & (step <= MAX_OFFSET / 255.0))):
                return None  # NaN/Inf, or offsets no avatar has (3e38 steps make the avatar vanish)
            data = np.memmap(path, np.dtype(dtype), "r", start + 2 * table, (stored, n_rows, n_width))
            store = BakeStore(key, frames, stride, data, lo, step, np.ones(stored, bool))
        except (AvatarFileError, OSError, ValueError, KeyError, TypeError, MemoryError):
            return None
        return store


def _stored_count(frames: int, stride: int) -> int:
    """len(_stored_frames(frames, stride)) without building the list."""
    return (frames - 1) // stride + 1 + (1 if (frames - 1) % stride else 0)


def _stored_frames(frames: int, stride: int) -> list[int]:
    out = list(range(0, frames, stride))
    if out[-1] != frames - 1:
        out.append(frames - 1)
    return out
