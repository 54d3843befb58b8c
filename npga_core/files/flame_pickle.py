"""The user's FLAME model pickle (`flame2023.pkl`, FLAME 2020's `generic_model.pkl`) read without running it.

A FLAME pickle is a dict of arrays, written by Python 2 (latin1 strings); FLAME 2020 holds some arrays as chumpy
`Ch` objects and the joint regressor as a scipy.sparse csc matrix. `pickle.load` would import and call whatever the
file names, so a restricted unpickler resolves only the exact names such a file needs: numpy's array
reconstruction and dtype, copyreg's object reconstruction of the two stand-in classes below, chumpy's `Ch` and
scipy's csc matrix (their state is kept as data and turned into arrays afterwards, no chumpy or scipy code runs),
`set` and `object`. Any other name (os.system, numpy's runstring, ...) stops the read before it is called: one
`AvatarFileError` line naming the file and the name. The arrays are then checked (`FlameModel`): dtypes, shapes
consistent with each other, finite, bounded sizes.
"""

from __future__ import annotations

import io
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse

from npga_core.errors import AvatarFileError, brief
from npga_core.files.untrusted import MAX_POSITION, read_bytes

#: Largest FLAME pickle read (FLAME 2023 is about 90 MB; all arrays in memory).
MAX_FLAME_BYTES = 512 * 2**20
MAX_VERTICES = 100_000
MAX_COMPONENTS = 1024


class _Ch:
    """Stand-in for chumpy's `Ch`: its state kept as data (`x` is the array)."""

    def __setstate__(self, state: Any) -> None:
        self.state = state


class _Csc:
    """Stand-in for scipy's csc matrix: its state kept as data (data, indices, indptr, shape)."""

    def __setstate__(self, state: Any) -> None:
        self.state = state


def _reconstructor(cls: type, base: type, state: Any) -> object:
    """copyreg's `_reconstructor`, for the stand-ins only."""
    if cls not in (_Ch, _Csc) or base is not object or state is not None:
        raise pickle.UnpicklingError("object reconstruction of a class a FLAME model does not hold")
    return object.__new__(cls)


def _scalar(dtype: np.dtype, data: Any = None) -> Any:
    if not isinstance(dtype, np.dtype) or dtype.hasobject or not isinstance(data, bytes):
        raise pickle.UnpicklingError("a numpy scalar that is not a plain number")
    return np.frombuffer(data, dtype, count=1)[0]


def _frombuffer(buf: Any, dtype: Any, shape: Any, order: Any) -> np.ndarray:
    """numpy's protocol-5 array reconstruction, for numeric dtypes only."""
    if not isinstance(buf, (bytes, bytearray)) or not isinstance(dtype, np.dtype) or dtype.hasobject:
        raise pickle.UnpicklingError("an array that is not plain numbers")
    return np.frombuffer(buf, dtype).reshape(shape, order="F" if order == "F" else "C").copy()


def _encode(text: Any, encoding: Any = "latin1") -> bytes:
    """`_codecs.encode` as Python 3 pickles bytes under protocol 2: latin1 text to bytes only."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError("_codecs.encode of something other than latin1 text")
    return text.encode("latin1")


def _names() -> dict[tuple[str, str], Any]:
    allowed: dict[tuple[str, str], Any] = {("_codecs", "encode"): _encode}
    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        allowed[(mod, "_reconstruct")] = _array_reconstruct
        allowed[(mod, "scalar")] = _scalar
    for mod in ("numpy.core.numeric", "numpy._core.numeric"):
        allowed[(mod, "_frombuffer")] = _frombuffer
    allowed[("numpy", "ndarray")] = np.ndarray
    allowed[("numpy", "dtype")] = np.dtype
    for mod in ("copy_reg", "copyreg"):
        allowed[(mod, "_reconstructor")] = _reconstructor
    for mod in ("__builtin__", "builtins"):
        allowed[(mod, "set")] = set
        allowed[(mod, "object")] = object
    allowed[("chumpy.ch", "Ch")] = _Ch
    for mod in ("scipy.sparse.csc", "scipy.sparse._csc"):
        allowed[(mod, "csc_matrix")] = _Csc
    return allowed


def _array_reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    """numpy's `_reconstruct` for plain ndarrays only (the array's state is then set by numpy)."""
    if subtype is not np.ndarray:
        raise pickle.UnpicklingError("an array of a subclass a FLAME model does not hold")
    return np.ndarray.__new__(np.ndarray, shape, dtype)


class _Restricted(pickle.Unpickler):
    allowed = _names()

    def find_class(self, module: str, name: str) -> Any:
        hit = self.allowed.get((module, name))
        if hit is None:
            raise pickle.UnpicklingError(f"refers to {brief(f'{module}.{name}', 80)}, which a FLAME model does "
                                         "not need (nothing was run)")
        return hit


@dataclass
class FlameModel:
    """The arrays of a FLAME model posing needs (float64; indices int64)."""

    v_template: np.ndarray  # (V, 3)
    shapedirs: np.ndarray  # (V, 3, S + E): shape components, then expression from column `expr_start`
    posedirs: np.ndarray  # (V, 3, 9 (J - 1))
    j_regressor: np.ndarray  # (J, V) dense
    parents: np.ndarray  # (J,) with -1 at the root
    weights: np.ndarray  # (V, J)
    faces: np.ndarray  # (F, 3)
    expr_start: int = 300


def read_flame_model(path: str | Path) -> FlameModel:
    """The FLAME model at `path`; AvatarFileError (one line naming the file) on anything unexpected."""
    data = read_bytes(path, MAX_FLAME_BYTES, "a FLAME model pickle")
    try:
        raw = _Restricted(io.BytesIO(data), encoding="latin1").load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            MemoryError, OverflowError) as e:
        raise AvatarFileError(path, f"not a readable FLAME model pickle: {str(e)[:200] or type(e).__name__}") \
            from None
    try:
        return _model(raw)
    except ValueError as e:
        raise AvatarFileError(path, f"not a FLAME model: {e}") from None


def _array(value: Any, key: str) -> np.ndarray:
    """A numeric array of the pickle (chumpy and sparse stand-ins turned into arrays), as float64, finite;
    values within +-MAX_POSITION except the kinematic tree (its root's parent is 2**32 - 1 in FLAME 2020)."""
    if isinstance(value, _Ch):
        state = value.state if isinstance(value.state, dict) else {}
        value = state.get("x")
    if isinstance(value, _Csc):
        value = _dense(value.state, key)
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiub":
        raise ValueError(f"{key} is not a numeric array")
    a = value.astype(np.float64)
    if not np.isfinite(a).all() or (key != "kintree_table" and a.size and np.abs(a).max() > MAX_POSITION):
        raise ValueError(f"{key} has NaN/Inf values or values beyond +-{MAX_POSITION:g}")
    return a


def _dense(state: Any, key: str) -> np.ndarray:
    """A csc matrix's state as a dense array, built by scipy from checked parts."""
    if not isinstance(state, dict):
        raise ValueError(f"{key} is a sparse matrix without its arrays")
    shape = state.get("_shape", state.get("shape"))
    parts = [state.get(k) for k in ("data", "indices", "indptr")]
    if not (isinstance(shape, tuple) and len(shape) == 2 and all(isinstance(s, int) and 0 < s <= MAX_VERTICES
                                                                 for s in shape)):
        raise ValueError(f"{key} has no valid sparse shape")
    if not all(isinstance(p, np.ndarray) and p.ndim == 1 for p in parts):
        raise ValueError(f"{key} is a sparse matrix without its arrays")
    data, indices, indptr = (np.asarray(p) for p in parts)
    if indices.dtype.kind not in "iu" or indptr.dtype.kind not in "iu" or len(indptr) != shape[1] + 1 \
            or len(data) != len(indices) or (len(indices) and (indices.min() < 0 or indices.max() >= shape[0])) \
            or indptr[0] != 0 or indptr[-1] != len(data) or np.any(np.diff(indptr) < 0):
        raise ValueError(f"{key} is not a consistent csc matrix")
    return scipy.sparse.csc_matrix((data, indices, indptr), shape=shape).toarray()


def _model(raw: Any) -> FlameModel:
    if not isinstance(raw, dict):
        raise ValueError("the pickle does not hold a dict of arrays")
    need = ("v_template", "shapedirs", "posedirs", "J_regressor", "kintree_table", "weights", "f")
    missing = [k for k in need if k not in raw]
    if missing:
        raise ValueError(f"missing {', '.join(missing)}")
    a = {k: _array(raw[k], k) for k in need}
    v = a["v_template"].shape[0]
    if a["v_template"].shape != (v, 3) or not 3 <= v <= MAX_VERTICES:
        raise ValueError(f"v_template has shape {a['v_template'].shape}, expected (V, 3)")
    j = a["kintree_table"].shape[-1] if a["kintree_table"].ndim == 2 else 0
    shapes = {"shapedirs": a["shapedirs"].shape[:2] == (v, 3) and a["shapedirs"].ndim == 3
              and 300 < a["shapedirs"].shape[2] <= MAX_COMPONENTS,
              "posedirs": a["posedirs"].shape == (v, 3, 9 * (j - 1)),
              "J_regressor": a["J_regressor"].shape == (j, v), "kintree_table": a["kintree_table"].shape == (2, j)
              and 2 <= j <= 64, "weights": a["weights"].shape == (v, j),
              "f": a["f"].ndim == 2 and a["f"].shape[1] == 3 and 0 < len(a["f"]) <= 4 * MAX_VERTICES}
    wrong = [k for k, ok in shapes.items() if not ok]
    if wrong:
        k = wrong[0]
        raise ValueError(f"{k} has shape {a[k].shape}, which does not fit v_template {a['v_template'].shape} "
                         f"and {j} joints")
    faces = a["f"]
    if faces.min() < 0 or faces.max() >= v or np.any(faces != np.round(faces)):
        raise ValueError(f"f indexes vertices outside 0..{v - 1}")
    parents = a["kintree_table"][0].astype(np.int64)  # 2**32 - 1 or -1 at the root
    parents[0] = -1
    if any(not 0 <= parents[i] < i for i in range(1, j)):
        raise ValueError("kintree_table does not list each joint's parent before it")
    return FlameModel(a["v_template"], a["shapedirs"], a["posedirs"], a["J_regressor"], parents, a["weights"],
                      faces.astype(np.int64))
