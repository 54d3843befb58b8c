"""Loading the ICT-FaceKit light head (one npz) and posing it with blendshape weights and eye gaze.

Everything here is in metres. The kit moves the eyes with bones, not blendshapes (its ``eyeLook*`` shapes
only move the lids), so `pose_vertices` adds a rotation of each eyeball about its fitted centre driven by
the ``eyeLook*`` weights; that rotation is part of the deformation the demo's F learns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

ICT_ENV = "NPGA_ICT_DIR"  # the kit's folder (or npz), when no path is given
#: where the kit is looked for last: this folder next to the checkout (the folder holding pyproject.toml)
ICT_BESIDE_CHECKOUT = Path("..", "shared", "data", "ict_facekit")
ICT_FILE = "ict_facekit_light.npz"
ICT_WHERE = f"pass --ict PATH, set ${ICT_ENV}, or put the kit in {ICT_BESIDE_CHECKOUT.as_posix()} beside the checkout"
CM = 0.01

#: Gaussian part names of the demo avatar, in part-id order.
PART_NAMES: tuple[str, ...] = (
    "face", "head_neck", "mouth_socket", "eye_socket_l", "eye_socket_r", "gums_tongue", "teeth",
    "sclera_l", "iris_l", "sclera_r", "iris_r",
)
#: The kit's eye is an outer shell (material Sclera*, with the cornea bulge) around an inner ball (Iris*). The demo
#: samples only the outer shell and paints the iris on it; `iris_*` Gaussians are the ones inside the limbus.
_EYE_SHELLS = {"M_ScleraLeft": "sclera_l", "M_ScleraRight": "sclera_r"}
#: Angular radius of the limbus (iris edge) seen from the eyeball centre, where the cornea bulge starts.
LIMBUS_ANGLE = np.radians(27.0)

#: Largest gaze angles (radians) reached at eyeLook* weight 1.
GAZE_YAW = np.radians(30.0)
GAZE_UP = np.radians(22.0)
GAZE_DOWN = np.radians(26.0)


@dataclass
class IctHead:
    """The kit's neutral head and expression shapes, with the demo's per-triangle part labels."""

    vertices: np.ndarray  # (V, 3) float32, metres
    faces: np.ndarray  # (T, 3) int64
    tri_part: np.ndarray  # (T,) int16 index into PART_NAMES, -1 for surfaces the demo does not sample
    vertex_part: np.ndarray  # (V,) int16 ICT part index
    ict_part_names: list[str]
    expression_names: list[str]
    deltas: np.ndarray  # (E, V, 3) float32, metres
    landmarks: np.ndarray  # (68,) vertex indices (Multi-PIE order)
    eye_centres: np.ndarray  # (2, 3) centres of the left (+x) and right eyeball
    eye_axes: np.ndarray  # (2, 3) unit optical axes (centre towards the cornea apex)
    eye_vertices: tuple[np.ndarray, np.ndarray]  # vertex indices of the left and right eyeball
    source: Path

    @property
    def n_expressions(self) -> int:
        return len(self.expression_names)

    def expression_index(self, name: str) -> int:
        return self.expression_names.index(name)

    def landmark_points(self, ids: list[int] | range) -> np.ndarray:
        return self.vertices[self.landmarks[list(ids)]]

    def triangle_areas(self) -> np.ndarray:
        v = self.vertices.astype(np.float64)
        f = self.faces
        return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)

    def vertex_normals(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """Area-weighted unit vertex normals (V, 3)."""
        v = (self.vertices if vertices is None else vertices).astype(np.float64)
        f = self.faces
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        vn = np.zeros_like(v)
        for c in range(3):
            np.add.at(vn, f[:, c], fn)
        return (vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-20)).astype(np.float32)


def _fit_sphere(points: np.ndarray) -> np.ndarray:
    """Least-squares sphere centre of points (M, 3)."""
    p = points.astype(np.float64)
    a = np.c_[2 * p, np.ones(len(p))]
    sol, *_ = np.linalg.lstsq(a, (p**2).sum(axis=1), rcond=None)
    return sol[:3]


def _fit_eye(points: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Centre and unit axis of an eye shell: a sphere fitted away from the cornea, axis through its apex."""
    p = points.astype(np.float64)
    centre = _fit_sphere(p)
    for _ in range(iterations):
        d = p - centre
        r = np.linalg.norm(d, axis=1)
        apex = d[r >= np.percentile(r, 97)].mean(axis=0)
        axis = apex / np.linalg.norm(apex)
        away = (d @ axis) / r < np.cos(np.radians(50.0))
        centre = _fit_sphere(p[away])
    d = p - centre
    r = np.linalg.norm(d, axis=1)
    apex = d[r >= np.percentile(r, 97)].mean(axis=0)
    return centre, apex / np.linalg.norm(apex)


def checkout_root() -> Path | None:
    """The checkout this module runs from (the folder holding pyproject.toml), None for an installed wheel."""
    for parent in Path(__file__).resolve().parents:
        if (parent / "pyproject.toml").is_file():
            return parent
    return None


def ict_candidates(path: str | Path | None = None) -> list[tuple[Path, str]]:
    """Where the kit is looked for, in order, each with how it was named: `path` (--ict) if given, else
    $NPGA_ICT_DIR if set, else ../shared/data/ict_facekit relative to the checkout."""
    if path is not None:
        return [(Path(path), "--ict")]
    if os.environ.get(ICT_ENV):
        return [(Path(os.environ[ICT_ENV]), f"${ICT_ENV}")]
    root = checkout_root()
    return [] if root is None else [((root / ICT_BESIDE_CHECKOUT).resolve(), "beside the checkout")]


def find_ict(path: str | Path | None = None) -> Path:
    """The kit's npz (see `ict_candidates`); FileNotFoundError saying where it was looked for and how to say
    where it is."""
    tried = []
    for p, how in ict_candidates(path):
        npz = p / ICT_FILE if p.is_dir() else p
        if npz.is_file():
            return npz
        tried.append(f"{npz} ({how})")
    where = "; ".join(tried) or "nowhere (no checkout, no $NPGA_ICT_DIR)"
    raise FileNotFoundError(f"ICT-FaceKit data not found: looked in {where}. {ICT_WHERE}")


def load_ict(path: str | Path | None = None) -> IctHead:
    """Read the kit (a folder holding ict_facekit_light.npz, or the npz itself; found by `find_ict`) and convert
    to metres."""
    p = find_ict(path)
    d = np.load(p, allow_pickle=False)
    verts = d["neutral"].astype(np.float32) * CM
    faces = d["faces"].astype(np.int64)
    ict_parts = [str(s) for s in d["part_names"]]
    ranges = d["part_ranges"]
    vpart = np.full(len(verts), -1, np.int16)
    for i, (a, b) in enumerate(ranges):
        vpart[a:b] = i
    # a triangle belongs to the part most of its corners belong to
    corner = vpart[faces]
    major = np.where(corner[:, 1] == corner[:, 2], corner[:, 1], corner[:, 0])
    materials = [str(s) for s in d["materials"]]
    mat = d["face_material"]
    tri_part = np.full(len(faces), -1, np.int16)
    for i, name in enumerate(PART_NAMES):
        if name in ict_parts:
            tri_part[major == ict_parts.index(name)] = i
    for m, name in _EYE_SHELLS.items():
        tri_part[mat == materials.index(m)] = PART_NAMES.index(name)
    eye_v = tuple(np.arange(*ranges[ict_parts.index(n)]) for n in ("eyeball_l", "eyeball_r"))
    eyes = [_fit_eye(verts[np.unique(faces[mat == materials.index(m)])]) for m in _EYE_SHELLS]
    centres = np.stack([c for c, _ in eyes]).astype(np.float32)
    axes = np.stack([a for _, a in eyes]).astype(np.float32)
    return IctHead(
        vertices=verts,
        faces=faces,
        tri_part=tri_part,
        vertex_part=vpart,
        ict_part_names=ict_parts,
        expression_names=[str(s) for s in d["expression_names"]],
        deltas=d["expression_deltas"].astype(np.float32) * CM,
        landmarks=d["landmarks_68"].astype(np.int64),
        eye_centres=centres,
        eye_axes=axes,
        eye_vertices=eye_v,  # type: ignore[arg-type]
        source=p,
    )


def _rot_x(a: torch.Tensor) -> torch.Tensor:
    c, s, o, z = torch.cos(a), torch.sin(a), torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([o, z, z, z, c, -s, z, s, c], dim=-1).reshape(*a.shape, 3, 3)


def _rot_y(a: torch.Tensor) -> torch.Tensor:
    c, s, o, z = torch.cos(a), torch.sin(a), torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([c, z, s, z, o, z, -s, z, c], dim=-1).reshape(*a.shape, 3, 3)


class GazeModel:
    """Eyeball rotations (B, 2, 3, 3) from blendshape weights (B, E): yaw from In/Out, pitch from Up/Down."""

    def __init__(self, names: list[str]):
        def ix(n: str) -> int:
            return names.index(n)

        self.out_l, self.in_l = ix("eyeLookOut_L"), ix("eyeLookIn_L")
        self.out_r, self.in_r = ix("eyeLookOut_R"), ix("eyeLookIn_R")
        self.up = (ix("eyeLookUp_L"), ix("eyeLookUp_R"))
        self.down = (ix("eyeLookDown_L"), ix("eyeLookDown_R"))

    def rotations(self, w: torch.Tensor) -> torch.Tensor:
        # +x is the subject's left: the left eye looks "out" towards +x, the right eye looks "in" towards +x
        yaw = torch.stack([w[:, self.out_l] - w[:, self.in_l], w[:, self.in_r] - w[:, self.out_r]], dim=1)
        pitch = torch.stack([GAZE_UP * w[:, self.up[i]] - GAZE_DOWN * w[:, self.down[i]] for i in range(2)], dim=1)
        # rotating +z towards +y is a negative rotation about x
        return _rot_y(yaw * GAZE_YAW) @ _rot_x(-pitch)


def pose_vertices(head: IctHead, w: torch.Tensor, deltas: torch.Tensor | None = None,
                  gaze: GazeModel | None = None) -> torch.Tensor:
    """Posed vertices (B, V, 3) for weights (B, E): blendshapes plus the eyeball gaze rotation."""
    if deltas is None:
        deltas = torch.from_numpy(head.deltas)
    base = torch.from_numpy(head.vertices)
    v = base + torch.einsum("be,evc->bvc", w, deltas)
    rot = (gaze or GazeModel(head.expression_names)).rotations(w)
    centres = torch.from_numpy(head.eye_centres)
    for e, idx in enumerate(head.eye_vertices):
        it = torch.from_numpy(idx)
        local = v[:, it] - centres[e]
        v[:, it] = centres[e] + torch.einsum("bij,bvj->bvi", rot[:, e], local)
    return v
