"""GaussianAvatars (ShenhanQian/GaussianAvatars, CVPR 2024) output folders as avatars, posed by FLAME.

Their output: `point_cloud/iteration_N/point_cloud.ply` (3DGS, SH degree 3, plus `binding_0`: the FLAME face each
Gaussian rides, stored as a float) and `flame_param.npz` beside it (`shape` (300,), `static_offset` (1, V', 3),
per frame `expr` (T, 100), `rotation`, `neck_pose`, `jaw_pose` (T, 3), `eyes_pose` (T, 6), `translation` (T, 3)).
The mesh is the user's FLAME model (`flame_pickle`) with their teeth (`flame_teeth`). Their xyz, log scale and
rotation are local to the face; the import puts every Gaussian on the rest mesh (shape and static offset, every
pose input 0) and keeps the mesh as a `LinearRig` with carrier "triangle" and a `Skin` (see
`npga_core.model.skinning`): expression channels `expr0` .. on the mesh vertices, then per joint (rotation =
the root, neck, jaw, eyes0 = `eyes_pose[:3]`, eyes1) 3 axis-angle inputs, then the translation. The `.npga`
written from it holds FLAME-derived data (MPI's licence).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from npga_core.errors import AvatarFileError
from npga_core.files import flame_teeth as teeth
from npga_core.files.flame_pickle import FlameModel, read_flame_model
from npga_core.files.ply import read_ply_extra
from npga_core.files.sequences import MAX_SEQUENCE_BYTES, ExpressionSequence
from npga_core.files.untrusted import is_folder, read_npz, real_floats
from npga_core.model import rotations
from npga_core.model.avatar import Avatar
from npga_core.model.dynamics import Dynamics
from npga_core.model.expression import ExpressionSpace
from npga_core.model.gaussians import GaussianCloud
from npga_core.model.linear_rig import LinearRig
from npga_core.model.skinning import Skin, face_frames

JOINTS = ("rotation", "neck", "jaw", "eyes0", "eyes1")
#: flame_param.npz keys of the pose inputs in frame-vector order (after the expression).
POSE_KEYS = (("rotation", 3), ("neck_pose", 3), ("jaw_pose", 3), ("eyes_pose", 6), ("translation", 3))
LICENCE = ("carries data derived from the FLAME model (its template, blendshapes, joint regressor, skinning "
           "weights and pose correctives), under MPI's FLAME licence: share it only as that licence allows")
SLIDER_EXPRESSIONS = 10
SLIDER_JOINTS = ("jaw", "neck", "eyes0", "eyes1")


def is_ga_folder(path: str | Path) -> bool:
    """True for a GaussianAvatars output folder (a `point_cloud/iteration_*` folder)."""
    p = Path(path)
    return is_folder(p / "point_cloud") and bool(_iterations(p))


def _iterations(folder: Path) -> list[tuple[int, Path]]:
    try:
        kids = list((folder / "point_cloud").iterdir())
    except OSError:
        return []
    return sorted((int(m.group(1)), k) for k in kids if (m := re.fullmatch(r"iteration_(\d{1,12})", k.name)))


def find_ply(src: str | Path) -> Path:
    """The point cloud of `src`: a point_cloud.ply itself, or the highest iteration's of an output folder."""
    p = Path(src)
    if not is_folder(p):
        return p
    found = _iterations(p)
    if not found:
        raise AvatarFileError(p, "not a GaussianAvatars output folder (no point_cloud/iteration_N)")
    return found[-1][1] / "point_cloud.ply"


def read_flame_param(path: str | Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named arrays of a flame_param.npz, finite float64 (the per-frame offsets are not read)."""
    z = read_npz(path, MAX_SEQUENCE_BYTES, keys=keys)
    missing = [k for k in keys if k not in z]
    if missing:
        raise AvatarFileError(path, f"not a GaussianAvatars flame_param.npz: no {', '.join(missing)}")
    return {k: real_floats(z[k], path, k, np.float64) for k in keys}


def pose_inputs(param: dict[str, np.ndarray], path: str | Path) -> np.ndarray:
    """(T, 18) pose inputs [rotation, neck, jaw, eyes (6), translation] of flame_param arrays."""
    t = param["expr"].shape[0]
    cols = []
    for key, width in POSE_KEYS:
        a = param[key]
        if a.size != t * width:
            raise AvatarFileError(path, f"{key} has shape {a.shape}, expected ({t}, {width})")
        cols.append(a.reshape(t, width))
    return np.concatenate(cols, axis=1)


def flame_codes(param: dict[str, np.ndarray], n_expr: int, path: str | Path) -> tuple[np.ndarray, list[str]]:
    """Frame vectors (T, n_expr + 18) of a flame_param's frames for an avatar with `n_expr` expression channels
    (fewer are padded with zeros, more cut), and notes saying so."""
    expr = param["expr"]
    if expr.ndim != 2 or expr.shape[0] < 1:
        raise AvatarFileError(path, f"expr has shape {expr.shape}, expected (T, E)")
    notes = []
    if expr.shape[1] != n_expr:
        notes.append(f"{path}: {expr.shape[1]} expression parameters for an avatar of {n_expr} "
                     + ("(the rest are 0)" if expr.shape[1] < n_expr else "(the rest are dropped)"))
    e = np.zeros((expr.shape[0], n_expr))
    e[:, : min(n_expr, expr.shape[1])] = expr[:, :n_expr]
    return np.concatenate([e, pose_inputs(param, path)], axis=1).astype(np.float32), notes


def flame_mesh(model: FlameModel, shape: np.ndarray, static_offset: np.ndarray, n_expr: int,
               where: str | Path) -> dict[str, np.ndarray]:
    """FLAME with their teeth at one identity: rest vertices, expression deltas, joints, skinning, faces."""
    v = model.v_template.shape[0]
    n_shape = min(len(shape), model.expr_start)
    if model.shapedirs.shape[2] < model.expr_start + n_expr:
        raise AvatarFileError(where, f"the FLAME model has {model.shapedirs.shape[2] - model.expr_start} "
                              f"expression components, the avatar uses {n_expr}")
    shape_dirs = model.shapedirs[:, :, :n_shape]
    template = np.concatenate([model.v_template, teeth.teeth_vertices(model.v_template)])
    shape_dirs = np.concatenate([shape_dirs, teeth.ring_mean(shape_dirs)])
    vt = v + teeth.N_TEETH_VERTICES
    offset = np.zeros((vt, 3))
    so = static_offset.reshape(-1, 3)
    if len(so) not in (v, vt):
        raise AvatarFileError(where, f"static_offset has {len(so)} vertices, FLAME with teeth has {vt}")
    offset[: len(so)] = so
    rest = template + shape_dirs @ shape[:n_shape] + offset
    deltas = np.zeros((n_expr, vt, 3))
    deltas[:, :v] = np.moveaxis(model.shapedirs[:, :, model.expr_start : model.expr_start + n_expr], 2, 0)
    regressor = model.j_regressor
    weights = np.concatenate([model.weights, np.zeros((teeth.N_TEETH_VERTICES, model.weights.shape[1]))])
    weights[v + teeth.teeth_rows(teeth.UPPER_ROWS), teeth.NECK] = 1.0
    weights[v + teeth.teeth_rows(teeth.LOWER_ROWS), teeth.JAW] = 1.0
    posedirs = np.zeros((model.posedirs.shape[2], vt, 3))
    posedirs[:, :v] = np.moveaxis(model.posedirs, 2, 0)
    faces = np.concatenate([model.faces, teeth.teeth_faces() + v])
    return {"rest": rest, "deltas": deltas, "joints": regressor @ rest[:v],
            "joint_deltas": np.einsum("jv,kvc->kjc", regressor, deltas[:, :v]), "parents": model.parents,
            "weights": weights, "posedirs": posedirs, "faces": faces}


def import_gaussian_avatars(src: str | Path, flame_model: str | Path,
                            flame_param: str | Path | None = None) -> Avatar:
    """The avatar of a GaussianAvatars output folder (or point_cloud.ply) posed by the FLAME model at
    `flame_model`; `flame_param`: its flame_param.npz (default: beside the PLY)."""
    ply = find_ply(src)
    param_path = Path(flame_param) if flame_param is not None else ply.parent / "flame_param.npz"
    model = read_flame_model(flame_model)  # first: a hostile pickle stops everything else
    local, extra = read_ply_extra(ply, ("binding_0",))
    if "binding_0" not in extra:
        raise AvatarFileError(ply, "has no binding_0 property: not a GaussianAvatars point cloud")
    param = read_flame_param(param_path, ("shape", "static_offset", "expr") + tuple(k for k, _ in POSE_KEYS))
    n_expr = param["expr"].shape[1] if param["expr"].ndim == 2 else 0
    if not 1 <= n_expr <= model.shapedirs.shape[2] - model.expr_start:
        raise AvatarFileError(param_path, f"expr has shape {param['expr'].shape}")
    mesh = flame_mesh(model, param["shape"].reshape(-1), param["static_offset"], n_expr, param_path)
    mesh["rest"] = mesh["rest"].astype(np.float32)  # as the rig keeps it: the canonical cloud sits on this mesh
    binding = extra["binding_0"]
    n_faces = len(mesh["faces"])
    if np.any(binding != np.round(binding)) or binding.min(initial=0) < 0 or binding.max(initial=0) >= n_faces:
        raise AvatarFileError(ply, f"binding_0 must name faces 0..{n_faces - 1} of FLAME with teeth")
    cloud = _on_rest_mesh(local, binding.astype(np.int64), mesh, ply)
    skin = Skin(JOINTS, mesh["joints"], mesh["joint_deltas"], mesh["parents"], mesh["weights"], mesh["posedirs"],
                mesh["faces"], binding.astype(np.int64))
    vt = len(mesh["rest"])
    channels = tuple(f"expr{i}" for i in range(n_expr))
    rig = LinearRig(channels, np.arange(vt), mesh["deltas"].astype(np.float32), vt, carrier="triangle",
                    vertices=mesh["rest"], turns_covariance=True, skin=skin, source="GaussianAvatars + FLAME",
                    notes={"licence": "this avatar " + LICENCE,
                           "colour": "SH evaluated as stored, not turned with the faces (as their renderer)"})
    codes, _ = flame_codes(param, n_expr, param_path)
    prov = {"format": "gaussian-avatars", "source": str(ply), "flame_param": str(param_path), "licence": LICENCE}
    return Avatar(cloud, Dynamics(networks={}, rig=rig), expression=_sliders(codes, rig), provenance=prov,
                  source=str(src))


def _on_rest_mesh(local: GaussianCloud, binding: np.ndarray, mesh: dict, where: Path) -> GaussianCloud:
    """Their face-local Gaussians placed on the rest mesh: mu = s0 R0 x + c0, log s = l + log s0,
    q = q0 (x) normalize(q_local)."""
    r0, s0, c0 = face_frames(mesh["rest"], mesh["faces"])
    if not (s0[binding] > 1e-9).all():
        raise AvatarFileError(where, "some Gaussians ride a degenerate FLAME triangle at rest")
    r, s, c = r0[binding], s0[binding], c0[binding]
    means = np.einsum("nab,nb->na", r, local.means.astype(np.float64)) * s[:, None] + c
    q = local.quats.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    quats = rotations.quat_product(rotations.quat_from_matrix(r, proper=True), q)
    f32 = np.float32
    return GaussianCloud(means=means.astype(f32), quats=quats.astype(f32),
                         log_scales=(local.log_scales + np.log(s)[:, None]).astype(f32),
                         opacity_logits=local.opacity_logits, sh=local.sh,
                         features=np.zeros((len(binding), 0), f32))


def _sliders(codes: np.ndarray, rig: LinearRig) -> ExpressionSpace:
    """The sliders: the first expression channels and the jaw, neck and eyes, each in the spread of the
    avatar's own frames (mean: the rest pose)."""
    names = rig.input_names
    pick = [names.index(f"expr{i}") for i in range(min(SLIDER_EXPRESSIONS, rig.n_channels))]
    pick += [names.index(f"{j}.{a}") for j in SLIDER_JOINTS for a in "xyz"]
    basis = np.eye(len(names), dtype=np.float32)[pick]
    std = np.clip(codes.std(axis=0)[pick] if len(codes) > 1 else np.ones(len(pick)), 0.05, 10.0)
    named = {"tracked frame 0": codes[0]} if len(codes) else {}
    return ExpressionSpace(np.zeros(len(names), np.float32), basis, std.astype(np.float32), named)


def flame_sequence(avatar: Avatar, seq: ExpressionSequence) -> ExpressionSequence:
    """A GaussianAvatars sequence for an avatar posed by FLAME: the frame vectors of their forward (the head's
    rotation about the root joint and translation inside), the camera not moved (identity pose)."""
    rig = avatar.rig
    assert rig is not None and rig.skin is not None and seq.flame is not None
    codes, notes = flame_codes(seq.flame, rig.n_channels, seq.name)
    pose = np.broadcast_to(np.eye(4), (len(codes), 4, 4)).copy()
    return ExpressionSequence(codes, seq.fps, seq.name, frame_names=seq.frame_names, pose=pose,
                              pose_source=FLAME_POSE, notes=seq.notes + notes)


FLAME_POSE = ("GaussianAvatars through the avatar's FLAME rig: rotation about the root joint, then translation, "
              "in the frame vector (as their forward; the camera is not moved)")
